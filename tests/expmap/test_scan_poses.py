"""Scan poses: every scan registered against the newest experience's local map."""
from __future__ import annotations

import math

import numpy as np

from services.expmap.config import ScanGraphConfig
from services.expmap.laser_match import scan_points
from services.expmap.pose_graph import compose, relative_pose, wrap_angle
from services.expmap.scan_graph import ScanGraph
from services.expmap.scan_poses import ScanPoses
from tests.expmap.laser_world import drifting_odometry, raycast, ring_route, ring_world

SEC = 1_000_000_000


def _scan(world: np.ndarray, pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return scan_points(raycast(world, pose, noise=0.01, rng=rng), -math.pi / 2, math.pi / 180, 0.05, 29.9)


def _graph(world: np.ndarray, truth: np.ndarray, odo: np.ndarray, cfg: ScanGraphConfig) -> ScanGraph:
    rng = np.random.default_rng(3)
    g = ScanGraph(cfg)
    for k, (t, o) in enumerate(zip(truth, odo)):
        g.add_event(k * SEC, k, [0.0] * 4, [o[0], o[1], 0.0], o[2], sweep=_scan(world, t, rng))
    return g


def test_a_scan_between_experiences_gets_its_heading_from_the_walls_not_the_odometry() -> None:
    world = ring_world()
    truth = ring_route(laps=1, step=0.25)[:30]
    odo = drifting_odometry(truth, yaw_drift_deg_per_m=0.4, scale=1.01)
    g = _graph(world, truth, odo, ScanGraphConfig(local_map_experiences=25))
    poses = ScanPoses(g.cfg)
    rng = np.random.default_rng(5)
    e = g.n_nodes - 1
    errs_scan, errs_odom = [], []
    for k, turn_deg in enumerate((-2.5, -1.0, 1.5, 3.0)):
        # 0.1 m on from the last experience, the robot turned; the odometry says it did not
        step = np.array([0.1 + 0.02 * k, 0.0, math.radians(turn_deg)])
        true_pose = compose(truth[e], step)
        odom_pose = compose(odo[e], np.array([step[0], step[1], 0.0]))
        sp = poses.place(g, _scan(world, true_pose, rng), odom_pose)
        assert sp is not None and sp.experience == e
        true_rel = relative_pose(truth[e], true_pose)
        errs_scan.append(abs(math.degrees(float(wrap_angle(sp.pose[2] - true_rel[2])))))
        errs_odom.append(abs(math.degrees(float(wrap_angle(relative_pose(odo[e], odom_pose)[2] - true_rel[2])))))
        assert math.hypot(*(sp.pose[:2] - true_rel[:2])) < 0.05
    assert max(errs_scan) < 0.4 and max(errs_odom) > 2.4
    assert poses.counters["scan_pose"] == 4


def test_along_a_corridor_the_translation_is_the_odometrys_and_the_heading_registered() -> None:
    """Walls on both sides fix the heading, not the slide: the odometry's prior keeps its translation."""
    world = np.array([(-60.0, -1.5, 60.0, -1.5), (-60.0, 1.5, 60.0, 1.5)])   # two endless walls
    truth = np.array([(0.25 * k, 0.0, 0.0) for k in range(12)])
    cfg = ScanGraphConfig(local_map_experiences=12)
    g = _graph(world, truth, truth, cfg)
    poses = ScanPoses(cfg)
    true_pose = compose(truth[-1], np.array([0.1, 0.0, math.radians(2.0)]))
    odom_pose = compose(truth[-1], np.array([0.18, 0.0, 0.0]))              # the wheels slipped
    sp = poses.place(g, _scan(world, true_pose, np.random.default_rng(1)), odom_pose)
    assert sp is not None
    assert np.allclose(sp.pose[:2], [0.18, 0.0], atol=0.03) and abs(math.degrees(sp.pose[2]) - 2.0) < 0.5


def test_no_pose_without_an_experience_or_with_too_few_points() -> None:
    cfg = ScanGraphConfig()
    poses = ScanPoses(cfg)
    g = ScanGraph(cfg)
    few = np.array([[1.0, 0.0], [1.0, 0.5]])
    assert poses.place(g, few, np.zeros(3)) is None
    world = ring_world()
    truth = ring_route(laps=1, step=0.25)[:3]
    g = _graph(world, truth, truth, cfg)
    assert poses.place(g, few, truth[-1]) is None
    assert poses.counters["scan_pose_unplaced"] == 1


def test_the_local_maps_fields_follow_a_map_correction() -> None:
    """The fields are rebuilt when the map moved (a relaxation): the key holds the corrections count."""
    world = ring_world()
    truth = ring_route(laps=1, step=0.25)[:12]
    g = _graph(world, truth, truth, ScanGraphConfig())
    poses = ScanPoses(g.cfg)
    scan = _scan(world, truth[-1], np.random.default_rng(2))
    first = poses.place(g, scan, truth[-1])
    fields = poses._fields
    again = poses.place(g, scan, truth[-1])
    assert first is not None and again is not None and np.array_equal(again.pose, first.pose)
    assert poses._fields is fields
    g.corrections += 1
    poses.place(g, scan, truth[-1])
    assert poses._fields is not fields
