"""GTSAM's relaxations (services/expmap/gtsam_graph.py) against ours on graphs with a known truth."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from services.expmap.config import ExpMapConfig, ScanGraphConfig
from services.expmap.graph import EventResult, ExperienceMap
from services.expmap.gtsam_graph import relax_planar, relax_se2_gtsam, relaxation_optimum, solve_optimum_gtsam
from services.expmap.pose_graph import compose, relative_pose, relax_se2, wrap_angle
from services.expmap.relaxation import solve_optimum
from services.expmap.scan_graph import ScanGraph
from system.config import PoseidonConfig
from tests.conftest import REPO

SEC = 1_000_000_000
INFO = np.array([1e4, 1e4, 1.0 / 0.005 ** 2])   # 1 cm, 0.29 deg


def drifting_loop(false_edge_m: float | None, n: int = 120) -> tuple[np.ndarray, ...]:
    """A 10 m circle measured by chain edges with noise and a heading bias (drift), three true
    loop edges and, when ``false_edge_m`` is given, a false one that far from the truth:
    (truth, initial poses chained from the edges, ei, ej, z, w)."""
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    truth = np.column_stack([10.0 * np.cos(t), 10.0 * np.sin(t), wrap_angle(t + math.pi / 2)])
    ei, ej = list(range(n - 1)), list(range(1, n))
    z = [relative_pose(truth[i], truth[i + 1]) + rng.normal(0.0, [0.01, 0.01, 0.005]) + [0.0, 0.0, 0.002]
         for i in range(n - 1)]
    pairs = [(0, n - 1), (n // 20, n - n // 20), (n // 4, 3 * n // 4)]
    for a, b in pairs:
        ei.append(a)
        ej.append(b)
        z.append(relative_pose(truth[a], truth[b]))
    if false_edge_m is not None:
        ei.append(20)
        ej.append(70)
        z.append(relative_pose(truth[20], truth[70]) + [false_edge_m, 0.5, 0.05])
    chained = [truth[0]]
    for k in range(n - 1):
        chained.append(compose(chained[-1], z[k]))
    return truth, np.asarray(chained), np.asarray(ei), np.asarray(ej), np.asarray(z), np.tile(INFO, (len(ei), 1))


def pose_gap(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Largest translation (m) and heading (rad) difference of two pose arrays."""
    return float(np.max(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1]))), float(np.max(np.abs(wrap_angle(a[:, 2] - b[:, 2]))))


@pytest.mark.parametrize("false_edge_m", [None, 2.0])
@pytest.mark.parametrize("huber", [0.0, 3.0])
def test_both_optimisers_reach_the_same_optimum(false_edge_m: float | None, huber: float) -> None:
    truth, init, ei, ej, z, w = drifting_loop(false_edge_m)
    ours, it_ours = relax_se2(init, ei, ej, z, w, huber=huber, iterations=200, tol=1e-9)
    theirs, it_gtsam = relax_se2_gtsam(init, ei, ej, z, w, huber=huber, iterations=200, tol=1e-9)
    assert 1 <= it_ours < 200 and 1 <= it_gtsam < 200          # both converged
    # the same optimum: the residuals differ (Log of SE(2) against the component difference) by a
    # factor 1 + O(dtheta^2) of the false edge's large residual, 0.1 mm and 0.001 deg here
    dm, dr = pose_gap(ours, theirs)
    assert dm < 2e-4 and dr < 1e-4, (dm, dr)
    # the relaxation did something: the chained map is metres off, the optimum is not
    assert pose_gap(init, truth)[0] > 1.0
    assert pose_gap(theirs, truth)[0] < pose_gap(init, truth)[0]
    # node 0 stays where it was, exactly
    np.testing.assert_array_equal(theirs[0], init[0])
    assert np.all(theirs[:, 2] >= -math.pi) and np.all(theirs[:, 2] < math.pi)


def test_node_0_stays_fixed_off_the_origin() -> None:
    _truth, init, ei, ej, z, w = drifting_loop(None, n=40)
    init = compose(np.array([3.0, -2.0, 1.0]), init)          # the whole graph moved and turned
    out, _ = relax_se2_gtsam(init, ei, ej, z, w, huber=3.0)
    np.testing.assert_array_equal(out[0], init[0])
    ours, _ = relax_se2(init, ei, ej, z, w, huber=3.0, iterations=50, tol=1e-10)
    assert pose_gap(out, ours)[0] < 1e-4


def test_empty_and_single_node_graphs() -> None:
    one = np.array([[1.0, 2.0, 0.5]])
    out, it = relax_se2_gtsam(one, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    assert it == 0
    np.testing.assert_array_equal(out, one)
    pos, solved = solve_optimum_gtsam(np.zeros((1, 3)), np.zeros(1), [], [], np.array([1.0, 2.0, 3.0]))
    assert not solved
    np.testing.assert_array_equal(pos, [[1.0, 2.0, 3.0]])


def test_eq_4_20_optimum_matches_the_series_reduction() -> None:
    """Positions only, a session break (weight 1e-6) in the chain, loops of several weights."""
    rng = np.random.default_rng(9)
    n = 300
    inc = rng.normal(0.0, 0.3, (n, 3))
    inc[0] = 0.0
    cum = np.cumsum(inc, axis=0)
    cumres = np.arange(n, dtype=np.float64)
    cumres[200:] += 1e6 - 1.0
    loops = [(5, 250, 5.0, 0), (100, 280, 5.0, 0), (20, 299, 1.0, 0), (150, 151, 2.0, 0)]
    deltas = [np.array([0.1, 0.2, 0.0]), np.array([1.0, -1.0, 0.5]), np.zeros(3), np.array([0.3, 0.0, 0.0])]
    fixed = np.array([1.0, 2.0, 3.0])
    ours, solved_ours = solve_optimum(cum, cumres, loops, deltas, fixed)
    theirs, solved = solve_optimum_gtsam(cum, cumres, loops, deltas, fixed)
    assert solved and solved_ours
    np.testing.assert_allclose(theirs, ours, atol=1e-6)
    np.testing.assert_array_equal(theirs[0], fixed)


def test_config_chooses_the_optimiser() -> None:
    assert ExpMapConfig().scan_graph.optimizer == "gauss_newton"          # ours stays the default
    assert ExpMapConfig().corrections.optimizer == "series_reduction"
    with pytest.raises(ValidationError):
        ExpMapConfig.model_validate({"scan_graph": {"optimizer": "isam2"}})
    with pytest.raises(ValidationError):
        ExpMapConfig.model_validate({"corrections": {"optimizer": "gauss_newton"}})
    with pytest.raises(ValueError, match="unknown planar optimizer"):
        relax_planar("ceres", np.zeros((2, 3)), np.array([0]), np.array([1]), np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="unknown relaxation optimizer"):
        relaxation_optimum("ceres", np.zeros((2, 3)), np.arange(2.0), [], [], np.zeros(3))


def test_experience_map_relaxes_by_gtsam_when_configured() -> None:
    maps = {}
    for opt in ("series_reduction", "gtsam_lm"):
        rng = np.random.default_rng(3)
        em = ExperienceMap(ExpMapConfig(min_experience_age=10_000).updated({"corrections.optimizer": opt}))
        for i in range(60):
            em.add_event(i * SEC, i, [0, 0, 0, 0], list(rng.normal(0, 1, 3) + [i, 0, 0]), 0.0)
        for m, k, wl in [(0, 20, 1.0), (5, 59, 2.0), (30, 45, 0.5)]:
            em.add_loop_edge(m, k, wl, 0)
        maps[opt] = em.optimum()
    np.testing.assert_allclose(maps["gtsam_lm"], maps["series_reduction"], atol=1e-6)


def test_scan_graph_closes_a_loop_by_gtsam_when_configured() -> None:
    """The laser map's closure relaxes by the configured optimiser: the same map either way."""
    truth, _init, _ei, _ej, z, _w = drifting_loop(None, n=60)
    out = {}
    for opt in ("gauss_newton", "gtsam_lm"):
        g = ScanGraph(ScanGraphConfig(optimizer=opt, relax_iterations=50))
        odom = [truth[0]]
        for k in range(59):
            odom.append(compose(odom[-1], z[k]))
        for k, o in enumerate(odom):
            g.add_event(k * SEC, k, [0, 0, 0, 0], [o[0], o[1], 0.0], float(o[2]))
        res = EventResult(node=59)
        g._close([(0, 59, relative_pose(truth[0], truth[59])), (5, 55, relative_pose(truth[5], truth[55]))], res)
        assert res.loop_closed and res.settled and res.iterations >= 1
        out[opt] = np.column_stack([g.positions[:, :2], g.yaws])
    dm, dr = pose_gap(out["gauss_newton"], out["gtsam_lm"])
    assert dm < 1e-4 and dr < 1e-5, (dm, dr)
    np.testing.assert_array_equal(out["gtsam_lm"][0], truth[0])


def test_benchmark_offline_replay_on_small_maps(tmp_path: Path) -> None:
    """benchmarks/bench_optimizers.py re-solves a saved laser map and a saved 3D map by both."""
    spec = importlib.util.spec_from_file_location("bench_optimizers", REPO / "benchmarks" / "bench_optimizers.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    cfg = PoseidonConfig()
    truth, _init, _ei, _ej, z, _w = drifting_loop(None, n=40)
    g = ScanGraph(cfg.expmap.scan_graph)
    odom = [truth[0]]
    for k in range(39):
        odom.append(compose(odom[-1], z[k]))
    for k, o in enumerate(odom):
        g.add_event(k * SEC, k, [0, 0, 0, 0], [o[0], o[1], 0.0], float(o[2]))
    g._close([(0, 39, relative_pose(truth[0], truth[39])), (2, 37, relative_pose(truth[2], truth[37]))],
             EventResult(node=39))
    g.save(tmp_path / "laser.npz")
    laser = bench.replay_scan_graph(tmp_path / "laser.npz", cfg)
    assert laser["loop_edges"] == 2 and laser["optima_differ_m"] < 1e-4 and laser["optima_differ_deg"] < 1e-3
    em = ExperienceMap(cfg.expmap.updated({"min_experience_age": 10_000}))
    for i in range(30):
        em.add_event(i * SEC, i, [0, 0, 0, 0], [i + 0.1 * (i % 3), 0.0, 0.0], 0.0)
    em.add_loop_edge(0, 25, 1.0, 0)
    em.save(tmp_path / "map.npz")
    sim = bench.replay_experience_map(tmp_path / "map.npz", cfg)
    assert sim["loop_edges"] == 1 and sim["optima_differ_m"] < 1e-6
