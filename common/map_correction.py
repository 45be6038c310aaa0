"""Pose interpolation and the experience map's correction of the dead reckoning, on plain arrays.

One implementation for :func:`eval.corrected.map_corrected` (``poseidon export --tum``, the map
exports) and the ROS 1 bridge's live occupancy grid; the definition is in :mod:`eval.corrected`.
Poses: stamps (n,) int64 ns sorted, positions (n, 3) m, unit quaternions (n, 4) ``[x, y, z, w]``.
"""
from __future__ import annotations

import numpy as np

from common.geometry import normalise_quaternions, quat_multiply, slerp, wrap_angle, yaws_of_quaternions

__all__ = ["interpolate_poses", "blend_corrections"]


def interpolate_poses(stamps: np.ndarray, positions: np.ndarray, quaternions: np.ndarray,
                      at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions, quaternions) at ``at``: position linear, orientation SLERP between the bracketing
    samples (the last of samples with equal stamps counts); clamped outside the span.

    :raises ValueError: no samples.
    """
    if not len(stamps):
        raise ValueError("no poses to interpolate")
    q = np.asarray(at, dtype=np.int64).reshape(-1)
    if len(stamps) == 1:
        return np.repeat(positions, len(q), 0), np.repeat(quaternions, len(q), 0)
    i = np.clip(np.searchsorted(stamps, q, side="right") - 1, 0, len(stamps) - 2)
    t0, t1 = stamps[i], stamps[i + 1]
    span = (t1 - t0).astype(np.float64)
    f = np.where(span > 0, (q - t0).astype(np.float64) / np.where(span > 0, span, 1.0), 1.0)
    f = np.clip(f, 0.0, 1.0)
    p = positions[i] + f[:, None] * (positions[i + 1] - positions[i])
    return p, slerp(quaternions[i], quaternions[i + 1], f)


def blend_corrections(stamps: np.ndarray, positions: np.ndarray, quaternions: np.ndarray, node_stamps: np.ndarray,
                      node_positions: np.ndarray, node_yaws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map-corrected (positions, quaternions) at every odometry sample (:mod:`eval.corrected`,
    steps 1-4); nodes sorted by (stamp, id), at least one, and at least one odometry sample."""
    nt = np.asarray(node_stamps, dtype=np.int64)
    at_p, at_q = interpolate_poses(stamps, positions, quaternions, nt)
    dpsi = np.asarray(node_yaws, dtype=float) - yaws_of_quaternions(at_q)
    m_pos = np.asarray(node_positions, dtype=float).reshape(-1, 3)

    def through(e: np.ndarray) -> np.ndarray:
        """Odometry positions corrected by node e's correction."""
        c, s = np.cos(dpsi[e]), np.sin(dpsi[e])
        d = positions - at_p[e]
        corrected: np.ndarray = np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]]) + m_pos[e]
        return corrected

    e = np.clip(np.searchsorted(nt, stamps, side="right") - 1, 0, len(nt) - 1)
    e1 = np.minimum(e + 1, len(nt) - 1)
    span = (nt[e1] - nt[e]).astype(np.float64)
    f = np.where(span > 0, (stamps - nt[e]).astype(np.float64) / np.where(span > 0, span, 1.0), 0.0)
    f = np.clip(f, 0.0, 1.0)
    p = (1.0 - f)[:, None] * through(e) + f[:, None] * through(e1)
    psi = dpsi[e] + f * wrap_angle(dpsi[e1] - dpsi[e])
    qz = np.column_stack([np.zeros(len(e)), np.zeros(len(e)), np.sin(psi / 2), np.cos(psi / 2)])
    return p, normalise_quaternions(quat_multiply(qz, quaternions))
