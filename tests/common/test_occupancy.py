"""The occupancy grid core (common/occupancy.py) and the map correction on arrays
(common/map_correction.py) that ``poseidon export --grid`` and the ROS 1 bridge's ``/map`` share."""
from __future__ import annotations

import math

import numpy as np
import pytest

from common.geometry import quaternion_of_yaw, yaws_of_quaternions
from common.map_correction import blend_corrections, interpolate_poses
from common.occupancy import (
    FREE_THRESH,
    MARGIN_M,
    OCCUPIED_THRESH,
    accumulate,
    frame_of,
    probability,
    trinary,
)


def test_a_ray_misses_every_cell_before_its_end_and_hits_the_end_cell_weighted() -> None:
    origins, ends = np.array([[0.01, 0.01]]), np.array([[0.51, 0.01]])
    frame = frame_of(np.vstack([origins, ends]), 0.1)
    assert frame.origin == pytest.approx((-1.0, -1.0)) and (frame.width, frame.height) == (26, 21)
    hits, misses = accumulate(frame, origins, ends, np.array([5]))   # one ray standing for 5
    row = int((0.01 - frame.origin[1]) / 0.1)
    c0, c1 = int((0.01 - frame.origin[0]) / 0.1), int((0.51 - frame.origin[0]) / 0.1)
    assert hits.sum() == 5 and hits[row, c1] == 5
    assert misses.sum() == 5 * (c1 - c0) and np.all(misses[row, c0:c1] == 5)
    p = probability(hits, misses)   # 5 misses: free (3 would still be undecided, p 0.23)
    img = trinary(p, 100, 0, -1, np.int8)
    assert img[row, c1] == 100 and img[row, c0] == 0 and img[0, 0] == -1 and p[0, 0] == 0.5
    assert OCCUPIED_THRESH > 0.5 > FREE_THRESH and MARGIN_M == 1.0


def test_a_bad_resolution_or_a_huge_grid_is_refused_by_name() -> None:
    xy = np.array([[0.0, 0.0], [100.0, 100.0]])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="resolution must be a positive number of metres"):
            frame_of(xy, bad)
    with pytest.raises(ValueError, match="over 1000 cells"):
        frame_of(xy, 0.05, max_cells=1000)


def test_corrections_are_identity_at_the_dead_reckoning_and_turn_about_a_moved_node() -> None:
    t = np.arange(0, 11, dtype=np.int64) * 1_000_000_000
    p = np.column_stack([np.arange(11.0), np.zeros(11), np.zeros(11)])
    q = np.array([quaternion_of_yaw(0.0)] * 11)
    cp, cq = blend_corrections(t, p, q, t[[0, 5, 10]], p[[0, 5, 10]], np.zeros(3))
    assert np.allclose(cp, p) and np.allclose(cq, q)
    # every node turned by 90 deg about the origin: the whole trajectory with it
    turned = np.column_stack([-p[:, 1], p[:, 0], p[:, 2]])
    cp, cq = blend_corrections(t, p, q, t[[0, 5, 10]], turned[[0, 5, 10]], np.full(3, math.pi / 2))
    assert np.allclose(cp, turned) and np.allclose(yaws_of_quaternions(cq), math.pi / 2)
    mid_p, _mid_q = interpolate_poses(t, p, q, np.array([1_500_000_000, -5, 10**12]))
    assert np.allclose(mid_p[:, 0], [1.5, 0.0, 10.0])   # linear inside, clamped outside
