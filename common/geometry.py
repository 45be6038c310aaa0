"""Quaternion helpers every service shares (``[x, y, z, w]``, body -> world, as in ``Odometry``)."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["quaternion_to_matrix", "yaw_of_quaternion"]


def quaternion_to_matrix(q: list[float] | np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion ``[x, y, z, w]`` (normalised first; ValueError if zero)."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0.0:
        raise ValueError(f"quaternion {list(q)} has zero norm")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def yaw_of_quaternion(q: list[float]) -> float:
    """Yaw (rad, about z) of a quaternion ``[x, y, z, w]``."""
    x, y, z, w = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
