"""The scan clock's offset from the odometry's, measured from scans of a turning robot."""
from __future__ import annotations

import math

import numpy as np
import pytest

from services.expmap.scan_clock import estimate_scan_time_offset

# walls of an irregular room (segments x0 y0 x1 y1, m): no symmetry a turn could alias
WALLS = np.array([[-4, -3, 5, -3], [5, -3, 5, 2], [5, 2, 1, 4], [1, 4, -4, 4], [-4, 4, -4, -3],
                  [-1, -1, 0.5, -1.5], [2, 1, 3, 0.2], [-3, 2, -2, 3]], float)


def _scan(pose: np.ndarray, n: int = 181) -> np.ndarray:
    """Returns (k x 2, robot frame) of a 180-degree scan at ``pose`` (ray casting on WALLS)."""
    ang = np.linspace(-math.pi / 2, math.pi / 2, n)
    dx, dy = np.cos(pose[2] + ang)[:, None], np.sin(pose[2] + ang)[:, None]
    x0, y0, x1, y1 = (WALLS[:, k][None, :] for k in range(4))
    ex, ey = x1 - x0, y1 - y0
    px, py = x0 - pose[0], y0 - pose[1]
    det = -dx * ey + dy * ex                          # ray p + r d = wall start + s e, by Cramer's rule
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (-px * ey + py * ex) / det
        s = (dx * py - dy * px) / det
    r = np.where((np.abs(det) > 1e-12) & (r > 0.05) & (s >= 0) & (s <= 1), r, np.inf).min(axis=1)
    ok = r < 15
    return np.column_stack([r[ok] * np.cos(ang[ok]), r[ok] * np.sin(ang[ok])])


def _truth(t: np.ndarray) -> np.ndarray:
    """A robot turning back and forth on a small circle (x m, y m, yaw rad) at times t (s)."""
    yaw = 0.9 * np.sin(0.6 * t) + 0.3 * np.sin(1.7 * t)
    return np.column_stack([0.3 * np.cos(0.2 * t), 0.3 * np.sin(0.2 * t), yaw])


def _data(offset_s: float, seconds: float = 60.0) -> tuple[np.ndarray, np.ndarray, list[int], list[np.ndarray]]:
    """Odometry at 20 Hz stamped ``offset_s`` before the instant it describes; scans at 5 Hz."""
    t_odom = np.arange(0.0, seconds, 0.05)
    odom = _truth(t_odom)
    odom_stamps = np.round((t_odom - offset_s) * 1e9).astype(np.int64)
    t_scan = np.arange(1.0, seconds - 1.0, 0.2)
    scans = [_scan(p) for p in _truth(t_scan)]
    return odom_stamps, odom, [int(round(t * 1e9)) for t in t_scan], scans


@pytest.mark.parametrize("offset_s", [0.0, 0.12, -0.08])
def test_the_offset_between_the_odometry_and_the_scans_is_recovered(offset_s: float) -> None:
    st, odom, scan_st, scans = _data(offset_s)
    est = estimate_scan_time_offset(st, odom, scan_st, scans)
    assert est.offset_s is not None and est.pairs >= 30
    assert est.offset_s == pytest.approx(offset_s, abs=0.011)
    assert est.residual_deg < 0.3
    if offset_s != 0.0:
        assert est.residual_at_zero_deg > 2 * est.residual_deg


def test_too_few_turns_give_no_estimate() -> None:
    st, odom, scan_st, scans = _data(0.1, seconds=6.0)
    est = estimate_scan_time_offset(st, odom, scan_st, scans)
    assert est.offset_s is None and est.pairs < 30
