"""Planar experience map of registered scans (services/expmap/scan_graph.py) on a hand-made
building with a drifting wheel odometry."""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from services.expmap.config import ScanGraphConfig
from services.expmap.laser_match import scan_points
from services.expmap.pose_graph import compose, relative_pose, wrap_angle
from services.expmap.scan_graph import ScanGraph, local_points
from tests.expmap.laser_world import drifting_odometry, raycast, ring_route, ring_world

SEC = 1_000_000_000


def drive(graph: ScanGraph, truth: np.ndarray, odo: np.ndarray, world: np.ndarray, seed: int = 1,
          lvc_of: Callable[[int], int] = lambda k: k) -> None:
    rng = np.random.default_rng(seed)
    for k, (t, o) in enumerate(zip(truth, odo)):
        pts = scan_points(raycast(world, t, noise=0.01, rng=rng), -math.pi / 2, math.pi / 180, 0.05, 29.9)
        graph.add_event(k * SEC, lvc_of(k), [0.0] * 4, [o[0], o[1], 0.0], o[2], sweep=pts)


def errors(est: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Largest position (m) and heading (deg) error after anchoring both at the first pose."""
    a = relative_pose(np.repeat(est[:1], len(est), 0), est)
    b = relative_pose(np.repeat(truth[:1], len(truth), 0), truth)
    d = a - b
    return float(np.max(np.hypot(d[:, 0], d[:, 1]))), float(np.degrees(np.max(np.abs(wrap_angle(d[:, 2])))))


@pytest.fixture(scope="module")
def lap_and_a_bit() -> tuple[ScanGraph, np.ndarray, np.ndarray]:
    truth = ring_route(laps=2, step=0.5)[:170]        # one lap is 128 poses: the loop is driven again
    odo = drifting_odometry(truth, yaw_drift_deg_per_m=0.4, scale=1.01)
    g = ScanGraph(ScanGraphConfig())
    drive(g, truth, odo, ring_world())
    return g, truth, odo


def test_loops_close_and_the_map_beats_odometry(lap_and_a_bit: tuple[ScanGraph, np.ndarray, np.ndarray]) -> None:
    g, truth, odo = lap_and_a_bit
    odo_m, odo_deg = errors(odo, truth)
    map_m, map_deg = errors(np.column_stack([g.positions[:, :2], g.yaws]), truth)
    assert g.corrections >= 1 and len(g.loops) >= 2
    assert odo_m > 2.0 and odo_deg > 10.0
    assert map_m < 0.25 and map_deg < 2.0
    assert g.counters["chain_scan"] >= 160


def test_every_loop_edge_measures_the_true_relative_pose(lap_and_a_bit: tuple[ScanGraph, np.ndarray, np.ndarray]) -> None:
    g, truth, _ = lap_and_a_bit
    loops = [k for k, lp in enumerate(g.is_loop) if lp]
    assert loops
    for k in loops:
        m, n = g.ei[k], g.ej[k]
        d = g.z[k] - relative_pose(truth[m], truth[n])
        assert math.hypot(d[0], d[1]) < 0.1 and abs(math.degrees(float(wrap_angle(d[2])))) < 1.0
        assert n - m >= 100


def test_map_interface_matches_the_experience_map(lap_and_a_bit: tuple[ScanGraph, np.ndarray, np.ndarray]) -> None:
    g, _truth, _odo = lap_and_a_bit
    edges = g.edges()
    assert len(edges) == g.n_nodes - 1 + len(g.loops)
    assert sum(1 for e in edges if e[5]) == len(g.loop_deltas)
    assert g.positions.shape == (g.n_nodes, 3) and g.stamps[-1] == (g.n_nodes - 1) * SEC
    assert not g.pending and g.settle() == 0


def other_building() -> np.ndarray:
    """Another building the same route fits in: other corridor widths, other pillars."""
    def box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
        return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]

    segs = box(-13, -9, 13, 9) + box(-7.5, -3.5, 7.5, 3.5)
    for x0, y0 in ((-12.0, -8.5), (-4.0, -8.7), (2.5, -4.2), (12.0, 0.0), (8.0, 8.2), (-9.0, 3.8), (-12.6, -2.0)):
        segs += box(x0, y0, x0 + 0.7, y0 + 0.5)
    return np.asarray(segs, np.float64)


def _preset_scan_graph() -> ScanGraphConfig:
    from system.config import load_config
    return load_config(Path(__file__).resolve().parents[2] / "deploy/presets/laser2d.yaml", []).expmap.scan_graph


@pytest.mark.parametrize("which", ["default", "laser preset"])
def test_another_building_gives_no_loop(which: str) -> None:
    """The second lap runs through another building: its candidates are tried and every one
    is rejected by the registration (or its confirmation), so no loop edge is made; also with
    the laser preset's looser free-space check (10 % of the points, not 5 %)."""
    truth = ring_route(laps=2, step=0.5)[:170]
    odo = drifting_odometry(truth, yaw_drift_deg_per_m=0.05, scale=1.0)
    cfg = ScanGraphConfig() if which == "default" else _preset_scan_graph()
    if which != "default":
        assert cfg.loop_max_free_space > ScanGraphConfig().loop_max_free_space
    g = ScanGraph(cfg)
    rng = np.random.default_rng(2)
    for k, (t, o) in enumerate(zip(truth, odo)):
        world = ring_world() if k < 128 else other_building()
        pts = scan_points(raycast(world, t, noise=0.01, rng=rng), -math.pi / 2, math.pi / 180, 0.05, 29.9)
        g.add_event(k * SEC, k, [0.0] * 4, [o[0], o[1], 0.0], o[2], sweep=pts)
    assert g.counters["loop_tried"] > 0
    assert g.loops == []


def test_save_load_continue_equals_one_run(tmp_path: Path) -> None:
    truth = ring_route(laps=2, step=0.5)[:150]
    odo = drifting_odometry(truth, yaw_drift_deg_per_m=0.4, scale=1.01)
    one = ScanGraph(ScanGraphConfig())
    drive(one, truth, odo, ring_world())
    first = ScanGraph(ScanGraphConfig())
    drive(first, truth[:120], odo[:120], ring_world())
    first.save(tmp_path / "map.npz")
    second = ScanGraph.load(tmp_path / "map.npz", ScanGraphConfig())
    rng = np.random.default_rng(1)
    for k in range(120):                   # the same noise stream as the uninterrupted run
        raycast(ring_world(), truth[k], noise=0.01, rng=rng)
    for k in range(120, 150):
        t, o = truth[k], odo[k]
        pts = scan_points(raycast(ring_world(), t, noise=0.01, rng=rng), -math.pi / 2, math.pi / 180, 0.05, 29.9)
        second.add_event(k * SEC, k, [0.0] * 4, [o[0], o[1], 0.0], o[2], sweep=pts)
    np.testing.assert_allclose(second.positions, one.positions, atol=1e-9)
    np.testing.assert_allclose(second.yaws, one.yaws, atol=1e-9)
    assert second.loops == one.loops and second.counters == one.counters


def test_load_rejects_a_sonar_map_file(tmp_path: Path) -> None:
    path = tmp_path / "x.npz"
    np.savez(path, meta=np.frombuffer(b'{"format": 1}', np.uint8))
    with pytest.raises(ValueError, match="not a scan-graph map"):
        ScanGraph.load(path, ScanGraphConfig())


def test_event_with_non_finite_odometry_is_refused() -> None:
    g = ScanGraph(ScanGraphConfig())
    with pytest.raises(ValueError, match="finite"):
        g.add_event(0, 0, [0.0] * 4, [0.0, float("nan"), 0.0], 0.0)


def _backing_up_route() -> tuple[np.ndarray, np.ndarray]:
    """The robot drives 6 m along the ring's first side, backs up 3 m (heading unchanged), drives
    on; its wheel odometry reports the backing up as forward motion (a speed without sign)."""
    side = ring_route(laps=1, step=0.25)[:40]                     # 10 m of the first side, facing +x
    truth = np.concatenate([side[:25], side[23:11:-1], side[12:40]])
    truth[:, 2] = side[0, 2]
    odo = [truth[0].copy()]
    for k in range(1, len(truth)):
        d = relative_pose(truth[k - 1], truth[k])
        odo.append(compose(odo[-1], np.array([abs(d[0]), d[1], d[2]])))
    return truth, np.asarray(odo)


def test_laser_preset_follows_the_scans_when_the_odometry_reports_the_wrong_direction() -> None:
    """deploy/presets/laser2d.yaml (as FR079 needs): no translation prior and a 0.8 m window let the
    scans decide a step the odometry got backwards; the default chain (0.3 m window, 0.2 m prior)
    keeps the odometry's error."""
    preset = _preset_scan_graph()
    truth, odo = _backing_up_route()
    worst = {}
    for name, cfg in (("preset", preset), ("default", ScanGraphConfig())):
        g = ScanGraph(cfg)
        drive(g, truth, odo, ring_world())
        worst[name] = errors(np.column_stack([g.positions[:, :2], g.yaws]), truth)[0]
    assert errors(odo, truth)[0] > 5.0                 # the odometry went 6 m the wrong way
    assert worst["preset"] < 0.15, worst
    assert worst["default"] > 1.0, worst


def test_local_map_keeps_the_wall_of_the_experience_nearest_the_frame() -> None:
    """Three experiences saw the same wall; the map put the oldest 2 cm off.  In every voxel the
    local map keeps the point of the experience nearest the frame, so the wall stays where the
    newest scan puts it (the oldest scan of the window would otherwise decide it)."""
    wall = np.column_stack([np.full(40, 2.0), np.linspace(-1.0, 1.0, 40)])     # x = 2 m, seen from each
    poses = [np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])]
    scans = [wall + [0.02, 0.0], wall, wall]            # experience 0 placed 2 cm off by the map
    for frame, others in ((2, [0, 1, 2]), (1, [0, 1, 2]), (0, [2, 1, 0])):
        pts = local_points(scans, poses, others, frame, voxel_m=0.05)
        assert pts is not None
        expect = 2.02 if frame == 0 else 2.0
        assert np.allclose(pts[:, 0], expect), (frame, np.unique(np.round(pts[:, 0], 3)))
    assert local_points([None, None], poses[:2], [0, 1], 1, voxel_m=0.05) is None
