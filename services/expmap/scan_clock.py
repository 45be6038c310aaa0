"""The offset between a range sensor's clock and the wheel odometry's, measured from the data.

A ground robot's laser and its odometry are stamped by different processes: the scan when it
has been read out, the odometry when the base reported it.  The Freiburg logs show the
difference: the odometry, interpolated at a scan's stamp, is where the robot was about 0.1 s
before that scan was taken (ACES 0.09 s, FR079 0.15 s measured here; docs/LASER.md).  During
a turn of 30 deg/s that is 3 degrees, the heading error of every scan placed with the
odometry at its stamp, and of every pose of the trajectory at a scan's stamp.

:func:`estimate_scan_time_offset` measures it without any ground truth, as Kalibr-style
temporal calibration does with two sensors that both see the motion: scan pairs
``pair_gap`` scans apart during a turn (the odometry turns between ``min_turn_deg`` and
``max_turn_deg``) are registered against each other (:func:`services.expmap.laser_match.match_scan`);
each clear registration (fine score >= ``min_score``, no corridor slide) measures the turn
between the two scan instants.  The offset ``d`` is the one, on a grid of ``step_s`` within
+-``max_offset_s``, for which the odometry's turn between ``t_i - d`` and ``t_j - d`` agrees
best with the registered turns (least median of absolute differences).  The pairs are taken
evenly over the recording (every k-th candidate, at most ``max_pairs``): deterministic.

``robot_state.wheel_time_offset_s`` (null: measured by this at the start of a run,
``system.calibration.calibrate_from_input``) shifts the published ``Odometry`` onto the scans' clock.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from services.expmap.laser_match import match_scan, voxel_filter
from services.expmap.pose_graph import relative_pose

__all__ = ["ScanClockEstimate", "estimate_scan_time_offset"]


@dataclass(frozen=True)
class ScanClockEstimate:
    """Result of :func:`estimate_scan_time_offset`."""

    offset_s: float | None     # scan stamp - odometry stamp of the same instant (s); None: too few pairs
    pairs: int                 # registered scan pairs used
    residual_deg: float        # median |odometry turn - registered turn| at the offset (deg)
    residual_at_zero_deg: float  # the same with no offset (deg)


def _interp_pose(t: np.ndarray, stamps: np.ndarray, xy_yaw: np.ndarray) -> np.ndarray:
    """Odometry (x, y, unwrapped yaw) interpolated at stamps t (ns), clamped at the ends."""
    tf = t.astype(np.float64)
    st = stamps.astype(np.float64)
    return np.stack([np.interp(tf, st, xy_yaw[:, k]) for k in range(3)], axis=-1)


def estimate_scan_time_offset(odom_stamps: np.ndarray, odom_poses: np.ndarray,
                              scan_stamps: Sequence[int], scans: Sequence[np.ndarray], *,
                              pair_gap: int = 2, min_turn_deg: float = 2.0, max_turn_deg: float = 30.0,
                              max_pairs: int = 300, min_pairs: int = 30, min_score: float = 0.5,
                              max_spread_m: float = 0.1, max_offset_s: float = 0.3, step_s: float = 0.005,
                              voxel_m: float = 0.05) -> ScanClockEstimate:
    """Measure the scan clock's offset from the odometry's (module doc).

    :param odom_stamps: (n,) ns, non-decreasing
    :param odom_poses: (n, 3) x m, y m, yaw rad of the wheel odometry
    :param scan_stamps: one stamp (ns) per scan
    :param scans: per scan its returns (k x 2, m) in the robot frame
    """
    st = np.asarray(odom_stamps, np.int64)
    if st.size < 2 or len(scans) <= pair_gap:
        return ScanClockEstimate(None, 0, math.nan, math.nan)
    poses = np.asarray(odom_poses, np.float64).reshape(-1, 3).copy()
    poses[:, 2] = np.unwrap(poses[:, 2])
    ts = np.asarray(scan_stamps, np.int64)
    at = _interp_pose(ts, st, poses)
    turn = np.abs(at[pair_gap:, 2] - at[:-pair_gap, 2])
    cand = np.flatnonzero((turn > math.radians(min_turn_deg)) & (turn < math.radians(max_turn_deg)))
    if cand.size > max_pairs:
        cand = cand[np.linspace(0, cand.size - 1, max_pairs).round().astype(np.int64)]
    meas: list[tuple[int, int, float]] = []
    for i in cand.tolist():
        j = i + pair_gap
        a, b = voxel_filter(scans[i], voxel_m), voxel_filter(scans[j], voxel_m)
        if len(a) < 50 or len(b) < 50:
            continue
        prior = relative_pose(at[i], at[j])
        m = match_scan(a, b, prior, window_xy_m=0.3, window_yaw_deg=8.0, coarse_cell_m=0.05, coarse_sigma_m=0.1,
                       fine_yaw_step_deg=0.1, refine_peaks=1)
        if m.score >= min_score and m.spread_m <= max_spread_m:
            meas.append((int(ts[i]), int(ts[j]), float(m.pose[2])))
    if len(meas) < min_pairs:
        return ScanClockEstimate(None, len(meas), math.nan, math.nan)
    mt = np.asarray(meas)
    ti, tj, reg = mt[:, 0], mt[:, 1], mt[:, 2]

    def residual(d: float) -> float:
        shift = d * 1e9
        turn_odom = np.interp(tj - shift, st, poses[:, 2]) - np.interp(ti - shift, st, poses[:, 2])
        return float(np.median(np.abs((turn_odom - reg + math.pi) % (2 * math.pi) - math.pi)))

    grid = np.round(np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s), 6)
    res = np.array([residual(float(d)) for d in grid])
    best = int(np.argmin(res))       # ties: the first (most negative) offset
    return ScanClockEstimate(float(grid[best]), len(meas), math.degrees(float(res[best])), math.degrees(residual(0.0)))
