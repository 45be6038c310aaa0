"""Occupancy grids of horizontal range returns: the one implementation behind
``poseidon export --grid`` (:mod:`products.grid`) and the ROS 1 bridge's live ``/map``
(:mod:`services.bridge_ros1.grid`).

Returns.  Each return is a ray from its sensor origin to its end point (x, y in m, any frame).
A laser beam's end point is :func:`scan_endpoints` (laser frame) placed by :func:`laser_points`
(the laser at ``offset`` = dx, dy, dtheta of the robot frame, turned by the pose's yaw); a sonar
beam's is :func:`sonar_body` (body frame) turned by the pose's orientation (:func:`rotate`),
from the pose's position.

Grid (:class:`GridFrame`, :func:`frame_of`).  Square cells of ``resolution`` m over the
bounding box of every origin and end point grown by ``MARGIN_M``; the origin (lower-left
corner of the lower-left cell) is that box's corner floored to a multiple of the resolution.
Cell (i, j) covers x in [origin_x + i r, origin_x + (i+1) r), likewise y; arrays are indexed
``[row from the bottom, column]``.

Counts (:func:`accumulate`).  Every ray is traced through the cells by Bresenham's line
(numba): its end cell gets ``weight`` hits, each cell before it ``weight`` misses (weight 1
unless the returns were thinned, one return then standing for several).  A cell's log-odds is
``hits * logit(0.7) + misses * logit(0.4)`` (OctoMap's sensor model), its occupancy probability
the logistic of that (:func:`probability`; 0.5 never observed).  :func:`trinary`: occupied
(p > ``OCCUPIED_THRESH`` 0.65), free (p < ``FREE_THRESH`` 0.196), else unknown -- ``map_saver``'s
thresholds.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.special import expit

from common.messages import LaserScan

__all__ = ["GridFrame", "frame_of", "accumulate", "probability", "trinary", "scan_endpoints", "laser_points",
           "sonar_body", "rotate", "DEFAULT_RESOLUTION_M", "OCCUPIED_THRESH", "FREE_THRESH", "L_HIT", "L_MISS",
           "MARGIN_M", "MAX_CELLS", "MAX_LASER_RANGE_M"]

DEFAULT_RESOLUTION_M = 0.05
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
L_HIT = math.log(0.7 / 0.3)
L_MISS = math.log(0.4 / 0.6)
MARGIN_M = 1.0
MAX_CELLS = 200_000_000
#: laser beams beyond this are not drawn (m)
MAX_LASER_RANGE_M = 30.0


@njit(cache=True, nogil=True)
def _trace(i0: np.ndarray, j0: np.ndarray, i1: np.ndarray, j1: np.ndarray, w: np.ndarray, hits: np.ndarray,
           misses: np.ndarray) -> None:  # pragma: no cover - numba
    """Bresenham rays (i0, j0) -> (i1, j1) (column, row from the bottom): ``w`` misses before the end cell,
    ``w`` hits in it."""
    for k in range(i0.shape[0]):
        x, y, x1, y1 = i0[k], j0[k], i1[k], j1[k]
        dx = abs(x1 - x)
        dy = -abs(y1 - y)
        sx = 1 if x < x1 else -1
        sy = 1 if y < y1 else -1
        err = dx + dy
        while x != x1 or y != y1:
            misses[y, x] += w[k]
            e2 = 2 * err
            if e2 >= dy:
                err += dy
                x += sx
            if e2 <= dx:
                err += dx
                y += sy
        hits[y1, x1] += w[k]


@dataclass(frozen=True)
class GridFrame:
    """Where the cells are: ``resolution`` m, ``origin`` (x, y) of the lower-left corner (m), size in cells."""

    resolution: float
    origin: tuple[float, float]
    width: int
    height: int

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(column, row from the bottom) of points (n, >=2), clipped to the grid."""
        ij = np.floor((xy[:, :2] - np.asarray(self.origin)) / self.resolution).astype(np.int64)
        return np.clip(ij[:, 0], 0, self.width - 1), np.clip(ij[:, 1], 0, self.height - 1)


def frame_of(xy: np.ndarray, resolution: float, max_cells: int = MAX_CELLS) -> GridFrame:
    """The grid over points ``xy`` (n >= 1, >= 2 columns: origins and end points) (module docstring).

    :raises ValueError: a resolution that is not a positive number, or more than ``max_cells`` cells.
    """
    if not (resolution > 0 and math.isfinite(resolution)):
        raise ValueError(f"resolution must be a positive number of metres, got {resolution}")
    lo = np.floor((xy[:, :2].min(axis=0) - MARGIN_M) / resolution) * resolution
    hi = xy[:, :2].max(axis=0) + MARGIN_M
    w, h = (int(v) for v in np.ceil((hi - lo) / resolution))
    if w * h > max_cells:
        raise ValueError(f"a {w} x {h} grid at resolution {resolution} m is over {max_cells} cells")
    return GridFrame(float(resolution), (float(lo[0]), float(lo[1])), w, h)


def accumulate(frame: GridFrame, origins: np.ndarray, points: np.ndarray,
               weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(hits, misses) int32 ``[row, column]`` of the rays ``origins`` -> ``points`` (n, >= 2) on ``frame``."""
    hits = np.zeros((frame.height, frame.width), dtype=np.int32)
    misses = np.zeros((frame.height, frame.width), dtype=np.int32)
    oi, oj = frame.cells(origins)
    ei, ej = frame.cells(points)
    w = np.ones(len(oi), dtype=np.int32) if weights is None else np.asarray(weights, dtype=np.int32)
    _trace(oi, oj, ei, ej, w, hits, misses)
    return hits, misses


def probability(hits: np.ndarray, misses: np.ndarray) -> np.ndarray:
    """Occupancy probability per cell (0.5 where never observed)."""
    p: np.ndarray = expit(hits.astype(np.float64) * L_HIT + misses.astype(np.float64) * L_MISS)
    return p


def trinary(p: np.ndarray, occupied: int, free: int, unknown: int, dtype: type = np.uint8) -> np.ndarray:
    """``occupied`` where p > :data:`OCCUPIED_THRESH`, ``free`` where p < :data:`FREE_THRESH`, else ``unknown``."""
    out: np.ndarray = np.full(p.shape, unknown, dtype=dtype)
    out[p > OCCUPIED_THRESH] = occupied
    out[p < FREE_THRESH] = free
    return out


def scan_endpoints(scans: Sequence[LaserScan], max_range: float = MAX_LASER_RANGE_M) -> tuple[np.ndarray, list[np.ndarray]]:
    """Stamps (ns) and, per scan, the valid beam end points (k, 2) in the laser frame (m): no return at
    or beyond ``range_max``, at or below ``range_min``, nor beyond ``max_range``."""
    stamps = np.array([s.header.stamp for s in scans], dtype=np.int64)
    pts: list[np.ndarray] = []
    for s in scans:
        r = np.asarray(s.ranges, dtype=np.float64)
        a = s.angle_min + s.angle_increment * np.arange(len(r))
        ok = np.isfinite(r) & (r > s.range_min) & (r < s.range_max) & (r <= max_range)
        pts.append(np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])]))
    return stamps, pts


def laser_points(positions: np.ndarray, yaws: np.ndarray, local: Sequence[np.ndarray],
                 offset: tuple[float, float, float]) -> np.ndarray:
    """End points (m, 2) of scans ``local[k]`` (laser frame) with the robot at ``positions[k]``
    (x, y), heading ``yaws[k]``, the laser at ``offset`` (dx, dy, dtheta) of the robot frame."""
    out = []
    for k, p in enumerate(local):
        if not len(p):
            continue
        c, s = math.cos(yaws[k]), math.sin(yaws[k])
        lx = positions[k, 0] + c * offset[0] - s * offset[1]
        ly = positions[k, 1] + s * offset[0] + c * offset[1]
        la = yaws[k] + offset[2]
        ca, sa = math.cos(la), math.sin(la)
        out.append(np.column_stack([lx + ca * p[:, 0] - sa * p[:, 1], ly + sa * p[:, 0] + ca * p[:, 1]]))
    return np.concatenate(out) if out else np.zeros((0, 2))


def sonar_body(ranges: np.ndarray, angles: np.ndarray, head_sign: float, horizontal: bool) -> np.ndarray:
    """Sonar echoes (m, 3) in the published body frame: a horizontal head (Micron) turns from body +x
    towards +y, a vertical one (SeaKing) from +y towards +z (FRD), y and z times ``head_sign``."""
    r, a = ranges, angles
    if horizontal:
        return np.column_stack([r * np.cos(a), head_sign * r * np.sin(a), np.zeros(len(r))])
    return np.column_stack([np.zeros(len(r)), head_sign * r * np.cos(a), head_sign * r * np.sin(a)])


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v (n, 3) turned by unit quaternions q (n, 4) ``[x, y, z, w]``."""
    u, w = q[:, :3], q[:, 3:4]
    t = 2.0 * np.cross(u, v)
    out: np.ndarray = v + w * t + np.cross(u, t)
    return out
