"""Sonar sweeps of experiences and their registration: the displacement of a loop edge.

Eq. 4.20 asks every edge for a displacement Delta p_ij.  For a loop-closure edge the
dissertation (after RatSLAM) uses zero: an LVC match says "the same place".  In a tunnel a
recognised place is a stretch several metres long, so two experiences joined by a loop are
often 1-2 m apart, and a zero-displacement edge then pulls a good dead reckoning (DVL + AHRS
drift ~0.2 % of distance) *away* from the truth.  A horizontal mechanically scanned imaging
sonar (MSIS, ``sonar_micron``) sees the walls around the vehicle; registering the sweep kept
with each of the two experiences measures their displacement to a few centimetres, as in
scan-matching SLAM with MSIS (Mallios et al.).  This module is that measurement; the
experience map (:mod:`services.expmap.graph`) uses it for a loop edge's Delta p when both
experiences have a sweep and the registration is trustworthy, and falls back to the
dissertation's zero displacement otherwise.

- :func:`echo_range`: the range of a beam's wall echo = the strongest bin beyond
  ``scan.min_range_m`` (the transducer ring-down) if its intensity reaches
  ``scan.echo_threshold``, else no echo.
- :class:`SweepBuffer`: beams become points in the dead-reckoning frame with the latest
  ``Odometry`` pose carried forward to the beam's own stamp by the odometry's velocity and
  turn rate (at most ``MAX_EXTRAPOLATION_S``; the beam direction is the body-frame head angle
  turned by the published attitude): the Micron's beams come at ~23 Hz, the odometry at
  ``robot_state.publish_rate_hz``, and a beam placed with a pose 0.1-0.2 s old during a turn
  lands tens of centimetres off at 10 m.  :meth:`SweepBuffer.sweep` returns the points of the
  last full turn of the head (accumulated head travel >= ``scan.sweep_deg``), relative to a given position:
  an experience's sweep, motion-compensated by dead reckoning (locally accurate).
- :func:`register_sweeps`: the translation t (and a small rotation) that lays the current
  sweep onto the stored one, by exhaustive search of the truncated chamfer cost
  ``mean_k min(dist(R q_k + t, ref), tau)`` on a distance transform of the stored sweep
  (cell ``scan.cell_m``, tau = 5 cells), over a box covering both hypotheses (the places
  coincide, and the map's current separation) grown by ``scan.search_radius_m``, then refined
  to a quarter cell.  t is p_n - p_m (the current experience seen from the stored one).
  Trust: at least ``scan.min_points`` points in each sweep and ``scan.min_inlier_fraction`` of
  the current points within 2 cells of a stored point after alignment.  Degenerate geometry (a
  straight tunnel constrains only across-track) shows as a valley of near-best costs: the
  near-best translations (cost <= best + ``scan.ambiguity_margin_m``) have a spread; along a
  principal axis whose spread (std) exceeds ``scan.max_ambiguity_m`` the registration says
  nothing, and the loop edge keeps the map's current separation along that axis.  Both axes
  ambiguous: not trusted.  Too few inliers: ``inconsistent`` (the sweeps do not show the
  same walls), which the map uses to reject the loop closure (geometric verification).

Only horizontal (x, y) is registered; the vertical component of the loop displacement comes
from the odometry (pressure depth is absolute).  The published frame must keep z vertical
(``robot_state.axis_remap`` ending in ``z``); the sonar's lever arm is neglected (the same
at both visits).  Everything is deterministic (fixed search order, ties to the first).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit
from scipy.ndimage import distance_transform_edt

__all__ = ["echo_range", "SweepBuffer", "Registration", "register_sweeps", "MAX_EXTRAPOLATION_S"]

#: a beam is placed with the pose carried forward to its stamp by at most this much event time [s]
MAX_EXTRAPOLATION_S = 0.5


def echo_range(beam_data: np.ndarray, max_range_m: float, min_range_m: float, threshold: float) -> float:
    """Range (m) of the strongest bin at >= min_range_m if it reaches ``threshold``, else nan."""
    nb = int(beam_data.shape[0])
    if nb == 0 or max_range_m <= 0:
        return math.nan
    dr = float(max_range_m) / nb
    b0 = max(0, int(math.ceil(min_range_m / dr - 0.5)))
    if b0 >= nb:
        return math.nan
    seg = beam_data[b0:]
    k = int(np.argmax(seg))
    if float(seg[k]) < threshold:
        return math.nan
    return (b0 + k + 0.5) * dr


class SweepBuffer:
    """The recent sonar beams as points in the dead-reckoning frame (see the module doc)."""

    def __init__(self, capacity: int = 2048, head_sign: float = -1.0, sweep_deg: float = 360.0):
        self.capacity = int(capacity)
        self.head_sign = float(head_sign)      # published body y = head_sign * FRD y (robot_state.axis_sign_z)
        self.sweep_rad = math.radians(float(sweep_deg))
        self._angle = np.zeros(self.capacity)
        self._xy = np.full((self.capacity, 2), np.nan)
        self._n = 0                             # beams ever added
        self._pos: np.ndarray | None = None
        self._rot: np.ndarray | None = None
        self._stamp: int | None = None          # of the pose (ns); None: beams take the pose as it is
        self._vel = np.zeros(2)                 # horizontal velocity in the odometry frame (m/s)
        self._yaw_rate = 0.0                    # turn rate about the vertical (rad/s)

    def add_pose(self, position: npt.ArrayLike, rotation: np.ndarray, stamp: int | None = None,
                 velocity: npt.ArrayLike | None = None, angular_velocity: npt.ArrayLike | None = None) -> None:
        """The latest dead-reckoning pose: position (3, m) and body->world rotation (3x3); with its
        ``stamp`` (ns) and the body-frame ``velocity`` (3, m/s) and ``angular_velocity`` (3, rad/s),
        later beams are placed at the pose carried forward to their own stamps."""
        self._pos = np.asarray(position, np.float64)[:3].copy()
        self._rot = np.asarray(rotation, np.float64).reshape(3, 3).copy()
        self._stamp = None if stamp is None or velocity is None or angular_velocity is None else int(stamp)
        if self._stamp is not None:
            v = self._rot @ np.asarray(velocity, np.float64)[:3]
            w = self._rot @ np.asarray(angular_velocity, np.float64)[:3]
            if np.all(np.isfinite(v)) and np.all(np.isfinite(w)):
                self._vel, self._yaw_rate = v[:2].copy(), float(w[2])
            else:
                self._stamp = None

    def add_beam(self, head_angle_rad: float, range_m: float, stamp: int | None = None) -> bool:
        """One beam (head angle from body +x towards starboard, echo range or nan), stamped ``stamp``
        (ns; None: placed with the latest pose as it is). False: no pose yet."""
        if self._pos is None:
            return False
        i = self._n % self.capacity
        self._angle[i] = head_angle_rad
        if math.isfinite(range_m):
            assert self._rot is not None
            d = self._rot @ np.array([math.cos(head_angle_rad), self.head_sign * math.sin(head_angle_rad), 0.0])
            h = math.hypot(d[0], d[1])
            dx, dy = float(d[0]), float(d[1])
            x, y = float(self._pos[0]), float(self._pos[1])
            if stamp is not None and self._stamp is not None:
                dt = min(max((stamp - self._stamp) * 1e-9, 0.0), MAX_EXTRAPOLATION_S)
                a = self._yaw_rate * dt
                c, s = math.cos(a), math.sin(a)
                dx, dy = c * dx - s * dy, s * dx + c * dy
                x, y = x + float(self._vel[0]) * dt, y + float(self._vel[1]) * dt
            self._xy[i] = (x + range_m * dx / h, y + range_m * dy / h) if h > 1e-9 else np.nan
        else:
            self._xy[i] = np.nan
        self._n += 1
        return True

    def sweep(self, origin_xy: npt.ArrayLike) -> np.ndarray:
        """Points (k x 2, float32, m) of the last full head turn relative to ``origin_xy``;
        empty when the buffer holds less than a full turn."""
        n = min(self._n, self.capacity)
        if n < 2:
            return np.zeros((0, 2), np.float32)
        idx = (self._n - 1 - np.arange(n)) % self.capacity          # newest first
        ang = self._angle[idx]
        step = np.abs(np.angle(np.exp(1j * (ang[:-1] - ang[1:]))))  # wrapped head travel between beams
        travel = np.concatenate([[0.0], np.cumsum(step)])
        full = np.nonzero(travel >= self.sweep_rad - 1e-9)[0]
        if full.size == 0:
            return np.zeros((0, 2), np.float32)
        take = idx[: full[0] + 1]
        xy = self._xy[take]
        xy = xy[np.isfinite(xy[:, 0])]
        out: np.ndarray = (xy - np.asarray(origin_xy, np.float64)[:2]).astype(np.float32)
        return out


@dataclass
class Registration:
    """The outcome of :func:`register_sweeps`."""

    translation: np.ndarray          # (2,) m: p_n - p_m in the map frame (valid axes only, see ``ambiguous_axis``)
    rotation_deg: float              # rotation of the current sweep that fitted best
    cost_m: float                    # mean truncated distance at the optimum (m)
    inlier_fraction: float
    spread_m: tuple[float, float]    # std of the near-best translations along the principal axes (m)
    ambiguous_axis: np.ndarray | None   # unit vector along which the registration says nothing (or None)
    trusted: bool
    reason: str = ""
    inconsistent: bool = False       # enough echoes, but the sweeps do not fit: not the same walls


@njit(cache=True)
def _chamfer_grid(dt: np.ndarray, gx0: float, gy0: float, cell: float, tau: float, pts: np.ndarray,
                  tx0: float, ty0: float, step: float, nx: int, ny: int) -> np.ndarray:
    """cost[i, j] = mean_k min(dt(pts_k + (tx0 + i step, ty0 + j step)), tau) (nearest cell)."""
    cost = np.empty((nx, ny))
    H, W = dt.shape
    k = pts.shape[0]
    for i in range(nx):
        tx = tx0 + i * step
        for j in range(ny):
            ty = ty0 + j * step
            s = 0.0
            for q in range(k):
                gi = int(math.floor((pts[q, 0] + tx - gx0) / cell + 0.5))
                gj = int(math.floor((pts[q, 1] + ty - gy0) / cell + 0.5))
                if gi < 0 or gj < 0 or gi >= H or gj >= W:
                    s += tau
                else:
                    v = dt[gi, gj]
                    s += v if v < tau else tau
            cost[i, j] = s / k
    return cost


def _rotate(pts: np.ndarray, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    out: np.ndarray = pts @ np.array([[c, s], [-s, c]])
    return out


def register_sweeps(ref: np.ndarray, cur: np.ndarray, map_separation: npt.ArrayLike, *, cell_m: float = 0.1,
                    search_radius_m: float = 4.0, max_rotation_deg: float = 2.0, rotation_step_deg: float = 1.0,
                    min_points: int = 50, min_inlier_fraction: float = 0.65, ambiguity_margin_m: float = 0.01,
                    max_ambiguity_m: float = 0.3, max_window_m: float = 12.0) -> Registration:
    """Translation p_n - p_m laying the current sweep ``cur`` onto the stored one ``ref``
    (both relative to their experience's odometry position); see the module doc."""
    ref = np.asarray(ref, np.float64).reshape(-1, 2)
    cur = np.asarray(cur, np.float64).reshape(-1, 2)
    dsep = np.asarray(map_separation, np.float64)[:2]
    none = Registration(np.zeros(2), 0.0, math.inf, 0.0, (math.inf, math.inf), None, False)
    if len(ref) < min_points or len(cur) < min_points:
        none.reason = f"too few sweep points ({len(ref)}, {len(cur)} < {min_points})"
        return none
    tau = 5.0 * cell_m
    # search box: both hypotheses (t = 0, t = map separation) grown by the radius, at most max_window_m wide
    lo = np.minimum(0.0, dsep) - search_radius_m
    hi = np.maximum(0.0, dsep) + search_radius_m
    mid = 0.5 * (lo + hi)
    half = np.minimum(0.5 * (hi - lo), 0.5 * max_window_m)
    lo, hi = mid - half, mid + half
    # distance transform of the stored sweep, covering every placement of the current one
    gx0, gy0 = ref[:, 0].min() - tau, ref[:, 1].min() - tau
    H = int(math.ceil((ref[:, 0].max() + tau - gx0) / cell_m)) + 1
    W = int(math.ceil((ref[:, 1].max() + tau - gy0) / cell_m)) + 1
    occ = np.zeros((H, W), bool)
    occ[np.floor((ref[:, 0] - gx0) / cell_m + 0.5).astype(np.int64),
        np.floor((ref[:, 1] - gy0) / cell_m + 0.5).astype(np.int64)] = True
    dt = distance_transform_edt(~occ) * cell_m
    nx = int(math.floor((hi[0] - lo[0]) / cell_m)) + 1
    ny = int(math.floor((hi[1] - lo[1]) / cell_m)) + 1
    n_rot = int(round(max_rotation_deg / rotation_step_deg)) if rotation_step_deg > 0 else 0
    rots = [0.0] + [s * k * rotation_step_deg for k in range(1, n_rot + 1) for s in (1.0, -1.0)]
    best: tuple[float, float, np.ndarray | None] = (math.inf, 0.0, None)
    for r in rots:
        c = _chamfer_grid(dt, gx0, gy0, cell_m, tau, _rotate(cur, r), lo[0], lo[1], cell_m, nx, ny)
        k = int(np.argmin(c))
        if c.flat[k] < best[0] - 1e-12:
            best = (float(c.flat[k]), r, c)
    cost, rot, grid = best
    if grid is None:
        raise ValueError("register_sweeps: no finite chamfer cost at any rotation")
    i, j = np.unravel_index(int(np.argmin(grid)), grid.shape)
    t = np.array([lo[0] + i * cell_m, lo[1] + j * cell_m])
    # refinement to a quarter cell around the optimum
    q = cell_m / 4.0
    fine = _chamfer_grid(dt, gx0, gy0, cell_m, tau, _rotate(cur, rot), t[0] - cell_m, t[1] - cell_m, q, 9, 9)
    fi, fj = np.unravel_index(int(np.argmin(fine)), fine.shape)
    if fine[fi, fj] < cost:
        t = np.array([t[0] - cell_m + fi * q, t[1] - cell_m + fj * q])
        cost = float(fine[fi, fj])
    # inliers at the optimum
    moved = _rotate(cur, rot) + t
    gi = np.floor((moved[:, 0] - gx0) / cell_m + 0.5).astype(np.int64)
    gj = np.floor((moved[:, 1] - gy0) / cell_m + 0.5).astype(np.int64)
    inside = (gi >= 0) & (gj >= 0) & (gi < H) & (gj < W)
    d = np.full(len(moved), np.inf)
    d[inside] = dt[gi[inside], gj[inside]]
    inl = float(np.mean(d <= 2.0 * cell_m))
    # spread of the near-best translations (same rotation)
    near = np.argwhere(grid <= grid.min() + ambiguity_margin_m)
    pts = np.column_stack([lo[0] + near[:, 0] * cell_m, lo[1] + near[:, 1] * cell_m])
    cov = np.cov(pts.T) if len(pts) > 1 else np.zeros((2, 2))
    w, v = np.linalg.eigh(cov)
    spread = (float(math.sqrt(max(w[0], 0.0))), float(math.sqrt(max(w[1], 0.0))))
    res = Registration(t, rot, cost, inl, spread, None, False)
    if inl < min_inlier_fraction:
        res.reason = f"inlier fraction {inl:.2f} < {min_inlier_fraction}"
        res.inconsistent = True
        return res
    if spread[0] > max_ambiguity_m:
        res.reason = f"ambiguous in every direction (spread {spread[0]:.2f}, {spread[1]:.2f} m)"
        return res
    if spread[1] > max_ambiguity_m:
        res.ambiguous_axis = v[:, 1].copy()
    res.trusted = True
    return res
