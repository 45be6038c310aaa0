"""Planar pose-graph relaxation (services/expmap/pose_graph.py) on hand-made graphs."""
from __future__ import annotations

import math

import numpy as np

from services.expmap.pose_graph import compose, relative_pose, relax_se2, wrap_angle


def square(nodes_per_side: int = 4, side: float = 10.0) -> np.ndarray:
    poses, p = [], np.zeros(3)
    step = side / nodes_per_side
    for k in range(4 * nodes_per_side):
        poses.append(p.copy())
        turn = math.pi / 2 if (k + 1) % nodes_per_side == 0 else 0.0
        p = compose(p, np.array([step, 0.0, turn]))
    return np.asarray(poses)


def chain_edges(truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(truth)
    ei, ej = np.arange(n - 1), np.arange(1, n)
    z = relative_pose(truth[ei], truth[ej])
    return ei, ej, z


def test_compose_and_relative_pose_are_inverse() -> None:
    a, b = np.array([1.0, -2.0, 2.9]), np.array([-3.0, 0.5, -2.8])
    np.testing.assert_allclose(compose(a, relative_pose(a, b)), b, atol=1e-12)
    assert abs(float(wrap_angle(math.pi + 0.1)) - (-math.pi + 0.1)) < 1e-12


def test_consistent_loop_stays_put() -> None:
    truth = square()
    ei, ej, z = chain_edges(truth)
    ei, ej = np.append(ei, len(truth) - 1), np.append(ej, 0)
    z = np.vstack([z, relative_pose(truth[-1], truth[0])])
    out, _ = relax_se2(truth, ei, ej, z, np.tile([100.0, 100.0, 1000.0], (len(ei), 1)))
    np.testing.assert_allclose(out, truth, atol=1e-9)


def test_long_side_error_is_spread_over_every_edge() -> None:
    """One side measured 10 % long (1 m over a 10 m side): the loop edge pulls the error
    back, spread over the chain; node 0 does not move."""
    truth = square()
    ei, ej, z = chain_edges(truth)
    z[1:4, 0] *= 1.1 * 4 / 3          # side 0 (edges 0..3, 2.5 m each) is 1 m long in total
    z[0, 0] = 2.5
    chained = [truth[0]]
    for zz in z:
        chained.append(compose(chained[-1], zz))
    init = np.asarray(chained)
    ei, ej = np.append(ei, len(truth) - 1), np.append(ej, 0)
    z = np.vstack([z, relative_pose(truth[-1], truth[0])])
    w = np.tile([1.0, 1.0, 100.0], (len(ei), 1))
    before = np.hypot(*relative_pose(init[-1], init[0])[:2] - z[-1, :2])
    out, it = relax_se2(init, ei, ej, z, w)
    assert it >= 1
    np.testing.assert_allclose(out[0], truth[0])
    res = relative_pose(out[ei], out[ej]) - z
    norms = np.hypot(res[:, 0], res[:, 1])
    assert before > 0.9
    assert norms.max() < 0.2 * before          # no edge keeps the error
    assert norms[-1] < 0.25                    # the loop edge keeps only its share
    assert np.count_nonzero(norms > 0.01) >= 10    # the error is shared by many edges


def test_huber_limits_a_wrong_loop_edge() -> None:
    """Several right loop edges and one 3 m wrong: the Huber kernel keeps the map near the truth."""
    truth = square()
    ei, ej, z = chain_edges(truth)
    pairs = [(0, 8), (2, 10), (4, 12), (6, 14), (1, 9), (3, 11), (5, 13), (7, 15)]
    for i, j in pairs:
        ei, ej = np.append(ei, i), np.append(ej, j)
        z = np.vstack([z, relative_pose(truth[i], truth[j])])
    ei, ej = np.append(ei, 15), np.append(ej, 0)
    z = np.vstack([z, relative_pose(truth[15], truth[0]) + np.array([3.0, 0.0, 0.0])])
    w = np.tile([400.0, 400.0, 3000.0], (len(ei), 1))
    plain, _ = relax_se2(truth, ei, ej, z, w)
    robust, _ = relax_se2(truth, ei, ej, z, w, huber=3.0, iterations=30)

    def err(p: np.ndarray) -> float:
        return float(np.max(np.hypot(p[:, 0] - truth[:, 0], p[:, 1] - truth[:, 1])))

    assert err(plain) > 0.1
    assert err(robust) < 0.5 * err(plain)
