"""A small hand-made 2D building for the range-scan tests: a corridor ring with features,
a ray-casting laser and a drifting wheel odometry (deterministic, fast)."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from services.expmap.pose_graph import compose, relative_pose, wrap_angle


def _box(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def ring_world() -> np.ndarray:
    """Segments (k x 4: x0 y0 x1 y1) of a 24 x 16 m building around a 16 x 8 m block, so a
    4 m wide corridor ring, with irregular pillars and alcoves so no two places look alike."""
    segs = _box(-12, -8, 12, 8) + _box(-8, -4, 8, 4)
    for x0, y0, w, h in ((-10.5, -7.5, 0.6, 0.6), (-2.0, -7.6, 1.2, 0.4), (5.0, -7.4, 0.4, 1.0),
                         (10.8, -3.0, 0.8, 0.5), (10.6, 2.5, 1.0, 1.5), (3.0, 7.2, 0.5, 0.5),
                         (-4.5, 7.0, 2.0, 0.6), (-11.2, 1.0, 0.8, 0.8), (-11.5, -4.0, 0.5, 2.0),
                         (-6.0, -4.6, 1.5, 0.6), (6.5, 4.0, 0.7, 0.8)):
        segs += _box(x0, y0, x0 + w, y0 + h)
    return np.asarray(segs, np.float64)


def raycast(segs: np.ndarray, pose: Sequence[float] | np.ndarray, n_beams: int = 181, max_range: float = 30.0, noise: float = 0.0,
            rng: np.random.Generator | None = None) -> np.ndarray:
    """Ranges of a 180-degree laser (angles -90..+90 deg) at ``pose``; max_range = no return."""
    ang = pose[2] + np.linspace(-math.pi / 2, math.pi / 2, n_beams)
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    p = np.asarray(pose[:2], np.float64)
    a, b = segs[:, :2], segs[:, 2:]
    e = b - a
    # solve p + t d = a + u e for every beam x segment
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    w = a[None, :, :] - p[None, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
    t = np.where((np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1), t, np.inf)
    r = np.minimum(t.min(axis=1), max_range)
    if noise > 0 and rng is not None:
        r = np.where(r < max_range, r + rng.normal(0.0, noise, r.size), r)
    out: np.ndarray = r
    return out


def ring_route(laps: int = 2, step: float = 0.4) -> np.ndarray:
    """True poses (x, y, yaw) every ``step`` m along the corridor's centre line (10 x 6 m half sides)."""
    corners = [(-10.0, -6.0), (10.0, -6.0), (10.0, 6.0), (-10.0, 6.0)]
    poses = []
    for _ in range(laps):
        for k in range(4):
            (x0, y0), (x1, y1) = corners[k], corners[(k + 1) % 4]
            length = math.hypot(x1 - x0, y1 - y0)
            yaw = math.atan2(y1 - y0, x1 - x0)
            for s in np.arange(0.0, length, step):
                poses.append((x0 + (x1 - x0) * s / length, y0 + (y1 - y0) * s / length, yaw))
    return np.asarray(poses)


def drifting_odometry(truth: np.ndarray, yaw_drift_deg_per_m: float = 0.4, scale: float = 1.01,
                      seed: int = 0) -> np.ndarray:
    """Wheel odometry of a true route: each step's length scaled and its heading biased, plus noise."""
    rng = np.random.default_rng(seed)
    odo = [truth[0].copy()]
    for k in range(1, len(truth)):
        d = relative_pose(truth[k - 1], truth[k])
        step = math.hypot(d[0], d[1])
        d = d * np.array([scale, scale, 1.0])
        d[2] = wrap_angle(d[2] + math.radians(yaw_drift_deg_per_m) * step + rng.normal(0, math.radians(0.2)))
        odo.append(compose(odo[-1], d))
    return np.asarray(odo)
