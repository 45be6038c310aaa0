"""Correlative scan registration (services/expmap/laser_match.py) on ray-cast scans."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest

from services.expmap.laser_match import LikelihoodField, match_scan, scan_points, transform_points, voxel_filter
from services.expmap.pose_graph import relative_pose
from tests.expmap.laser_world import raycast, ring_world


def points_at(pose: Sequence[float] | np.ndarray, rng: np.random.Generator | None = None,
              noise: float = 0.0) -> np.ndarray:
    r = raycast(ring_world(), pose, noise=noise, rng=rng)
    return scan_points(r, -math.pi / 2, math.pi / 180, 0.05, 29.9)


def test_scan_points_drop_no_returns_and_keep_geometry() -> None:
    pts = scan_points(np.array([1.0, 50.0, 2.0]), -math.pi / 2, math.pi / 2, 0.05, 40.0)
    np.testing.assert_allclose(pts, [[0.0, -1.0], [0.0, 2.0]], atol=1e-12)


def test_voxel_filter_keeps_one_point_per_cell() -> None:
    p = np.array([[0.01, 0.01], [0.02, 0.03], [0.35, 0.01], [0.36, 0.02]])
    assert voxel_filter(p, 0.1).shape == (2, 2)


def test_likelihood_is_one_on_the_reference_and_falls_off() -> None:
    ref = np.array([[0.0, 0.0], [1.0, 0.0]])
    f = LikelihoodField(ref, 0.01, 0.05, margin_m=0.3)
    assert f.score(ref, np.zeros(3)) > 0.95
    assert f.score(ref, np.array([0.0, 0.1, 0.0])) < 0.2


@pytest.mark.parametrize("offset", [(0.35, -0.2, 4.0), (-0.6, 0.4, -9.0)])
def test_registration_recovers_a_known_offset(offset: tuple[float, float, float]) -> None:
    rng = np.random.default_rng(3)
    a = np.array([7.5, -5.0, 0.4])                  # near a corner: both axes constrained
    b = np.array([a[0] + offset[0], a[1] + offset[1], a[2] + math.radians(offset[2])])
    ref, query = points_at(a, rng, 0.01), points_at(b, rng, 0.01)
    truth = relative_pose(a, b)
    m = match_scan(ref, query, np.zeros(3), window_xy_m=1.5, window_yaw_deg=12.0)
    assert np.hypot(*(m.pose[:2] - truth[:2])) < 0.03
    assert abs(math.degrees(m.pose[2] - truth[2])) < 0.5
    assert m.score > 0.6


def test_a_corridor_is_ambiguous_along_its_axis() -> None:
    x = np.arange(-10.0, 10.0, 0.05)
    walls = np.vstack([np.stack([x, np.full_like(x, -1.5)], 1), np.stack([x, np.full_like(x, 1.5)], 1)])
    query = walls[np.abs(walls[:, 0]) < 5.0]
    m = match_scan(walls, query, np.zeros(3), window_xy_m=1.0, window_yaw_deg=2.0)
    assert m.spread_m > 0.3
    assert abs(m.pose[1]) < 0.03     # across the corridor it is still well determined


def test_repeated_structure_shows_a_second_peak() -> None:
    posts = np.array([[x + dx, y] for x in np.arange(-20.0, 21.0, 2.0) for y in (-1.5, 1.5)
                      for dx in np.arange(-0.2, 0.21, 0.05)])
    query = posts[np.abs(posts[:, 0]) < 5.0]
    m = match_scan(posts, query, np.zeros(3), window_xy_m=3.0, window_yaw_deg=2.0)
    assert m.second_ratio > 0.9


def test_other_place_scores_low() -> None:
    rng = np.random.default_rng(5)
    ref = points_at(np.array([-6.0, -6.0, 0.0]), rng, 0.01)
    query = points_at(np.array([10.0, 2.0, math.pi / 2]), rng, 0.01)
    m = match_scan(ref, query, np.zeros(3), window_xy_m=2.0, window_yaw_deg=10.0)
    assert m.score < 0.4


def test_transform_points_round_trip() -> None:
    p = np.array([[1.0, 2.0], [-0.5, 0.25]])
    pose = np.array([3.0, -1.0, 0.7])
    back = transform_points(transform_points(p, pose), relative_pose(pose, np.zeros(3)))
    np.testing.assert_allclose(back, p, atol=1e-12)
