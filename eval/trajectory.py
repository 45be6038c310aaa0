"""Trajectories and trajectory error.

Two series of poses, for two contracts: :class:`Trajectory` is a position track in NED
(with yaw) that the errors against ground truth and the report's figures use;
:class:`PoseSeries` keeps poses exactly as a recording published them (frame unchanged,
full orientation as quaternions, SLERP between samples) for the relation error
(:mod:`eval.relations`) and the TUM export (:mod:`eval.corrected`).

Frames.  Every trajectory evaluated here is held in the world **NED** frame (x north,
y east, z down, metres), the frame of ``truth/pose`` (``missions/sim``: "world NED",
quaternion body->world, body FRD).  ``Odometry`` is published by ``robot_state`` in the
frame of Table 4.1's ``axis_remap``/``axis_sign_z`` (default ``yxz``, ``-1``: **ENU**, x
east, y north, z up); :func:`common.geometry.published_to_ned` undoes that remap (with the
defaults ``ned = (enu_y, enu_x, -enu_z)`` and ``yaw_ned = pi/2 - yaw_enu``; the conventions
are in :mod:`common.geometry`).  The experience map (``map`` node positions,
``experience_event.odom_position``) integrates the published ``Odometry`` and is therefore
in the same published frame.

Errors (the dissertation lacks them; ``../shared/design/EVALUATION.md``):

- :func:`align_rigid`: rotation R and translation t minimising sum |R p_i + t - q_i|^2
  (Umeyama 1991 / Kabsch, **no scale**; reflections excluded);
- :func:`ate`: absolute trajectory error after that alignment, over time-aligned pairs
  (the estimate interpolated at the reference stamps): RMSE, mean, max, final (m);
- :func:`rpe`: relative position error over a time step ``delta_s``: for every pair of
  stamps (t, t') with t' the first stamp >= t + delta_s, |(e(t') - e(t)) - (g(t') - g(t))|
  with the estimate rotated by the ATE alignment (the translation cancels): RMSE and mean
  (m per ``delta_s``);
- :func:`anchored_errors`: the dead-reckoning figures of ``poseidon deadreckon``: the
  estimate translated so that it starts at the true start (no rotation: both headings are
  absolute), errors at the truth stamps; drift % = final error / true distance travelled.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from common.geometry import normalise_quaternions, yaws_of_quaternions
from common.map_correction import interpolate_poses
from common.messages import Odometry

__all__ = ["NS", "Trajectory", "PoseSeries", "pose_series", "align_rigid", "align_trajectory", "ate", "rpe",
           "anchored_errors", "drift_pct"]

NS = 1_000_000_000


class Trajectory:
    """Samples (stamp ns, NED position m, yaw rad) with linear interpolation; ``source`` names
    the key they came from (e.g. ``truth/pose``, ``Odometry``, ``map``).

    Stamps must be non-decreasing (samples are sorted by stamp, stable).  ``yaw`` is
    unwrapped so that interpolation never crosses the +-pi seam the long way.
    """

    def __init__(self, stamps: Sequence[int] | np.ndarray, positions: Sequence[Sequence[float]] | Sequence[np.ndarray] | np.ndarray,
                 yaws: Sequence[float] | np.ndarray | None = None, source: str = "") -> None:
        t = np.asarray(stamps, dtype=np.int64).reshape(-1)
        p = np.asarray(positions, dtype=float).reshape(-1, 3)
        if len(t) != len(p):
            raise ValueError(f"Trajectory: {len(t)} stamps but {len(p)} positions")
        y = np.zeros(len(t)) if yaws is None else np.asarray(yaws, dtype=float).reshape(-1)
        if len(y) != len(t):
            raise ValueError(f"Trajectory: {len(t)} stamps but {len(y)} yaws")
        order = np.argsort(t, kind="stable")
        self.t = t[order]
        self.p = p[order]
        self.yaw = np.unwrap(y[order]) if len(y) else y
        self.source = source

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration_s(self) -> float:
        return float((self.t[-1] - self.t[0]) / NS) if len(self.t) else 0.0

    def covers(self, stamp: int) -> bool:
        """True when ``stamp`` (ns) lies within [first, last] stamp."""
        return len(self.t) > 0 and int(self.t[0]) <= stamp <= int(self.t[-1])

    def covered(self, stamps: Iterable[int]) -> np.ndarray:
        """Boolean mask of the ``stamps`` this trajectory covers."""
        s = np.asarray(list(stamps) if not isinstance(stamps, np.ndarray) else stamps, dtype=np.int64)
        if not len(self.t):
            return np.zeros(len(s), dtype=bool)
        inside: np.ndarray = (s >= self.t[0]) & (s <= self.t[-1])
        return inside

    def _seconds(self, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (self.t - self.t[0]) / NS, (np.asarray(stamps, dtype=np.int64) - self.t[0]) / NS

    def positions_at(self, stamps: Sequence[int] | np.ndarray) -> np.ndarray:
        """Positions (n, 3) interpolated linearly at ``stamps`` (clamped outside the span)."""
        if not len(self.t):
            raise ValueError("Trajectory is empty")
        st = np.asarray(stamps, dtype=np.int64)
        if st.shape == self.t.shape and np.array_equal(st, self.t):
            return self.p.copy()  # at its own samples (exact even with repeated stamps)
        ts, s = self._seconds(st)
        return np.column_stack([np.interp(s, ts, self.p[:, k]) for k in range(3)])

    def yaws_at(self, stamps: Sequence[int] | np.ndarray) -> np.ndarray:
        """Yaws (rad, unwrapped) interpolated linearly at ``stamps``."""
        if not len(self.t):
            raise ValueError("Trajectory is empty")
        st = np.asarray(stamps, dtype=np.int64)
        if st.shape == self.t.shape and np.array_equal(st, self.t):
            return self.yaw.copy()
        ts, s = self._seconds(st)
        yaw: np.ndarray = np.interp(s, ts, self.yaw)
        return yaw

    def positions_within(self, stamps: Sequence[int] | np.ndarray) -> np.ndarray:
        """Positions (n, 3) interpolated linearly at ``stamps`` (ns); NaN rows outside the
        covered span (where :meth:`positions_at` clamps)."""
        t = np.asarray(stamps, dtype=np.int64)
        out = np.full((len(t), 3), np.nan)
        if not len(self.t):
            return out
        inside = (t >= self.t[0]) & (t <= self.t[-1])
        ref = (self.t - self.t[0]).astype(np.float64)
        q = (t[inside] - self.t[0]).astype(np.float64)
        for k in range(3):
            out[inside, k] = np.interp(q, ref, self.p[:, k])
        return out

    def at(self, stamp: int) -> tuple[np.ndarray, float]:
        """Position and yaw at one stamp."""
        return self.positions_at([stamp])[0], float(self.yaws_at([stamp])[0])

    def resampled(self, stamps: Sequence[int] | np.ndarray) -> Trajectory:
        """A new trajectory sampled at ``stamps``."""
        s = np.asarray(stamps, dtype=np.int64)
        return Trajectory(s, self.positions_at(s), self.yaws_at(s))

    def translated(self, offset: np.ndarray) -> Trajectory:
        """The same samples moved by ``offset`` (3,) metres."""
        return Trajectory(self.t, self.p + offset, self.yaw, self.source)

    def cumulative_distance(self) -> np.ndarray:
        """Distance travelled (m, raw sample steps) from the first sample to each sample."""
        if not len(self.p):
            return np.zeros(0)
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.p, axis=0), axis=1))])

    def window(self, t0: int, t1: int) -> Trajectory:
        """The samples with t0 <= stamp <= t1."""
        m = (self.t >= t0) & (self.t <= t1)
        return Trajectory(self.t[m], self.p[m], self.yaw[m])

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> Trajectory:
        """Positions mapped by p -> R p + t (yaw turned by R's rotation about z)."""
        r = np.asarray(rotation, dtype=float)
        dyaw = math.atan2(r[1, 0], r[0, 0])
        return Trajectory(self.t, self.p @ r.T + np.asarray(translation, dtype=float), self.yaw + dyaw)

    def distance(self, step_s: float | None = 1.0) -> float:
        """3D path length (m).  With ``step_s`` the trajectory is first resampled every
        ``step_s`` seconds (so that 10 Hz sensor jitter, e.g. depth noise, does not inflate
        it); ``None`` sums the raw sample-to-sample steps."""
        if len(self.p) < 2:
            return 0.0
        if step_s is None:
            return float(np.linalg.norm(np.diff(self.p, axis=0), axis=1).sum())
        ts = (self.t - self.t[0]) / NS
        grid = np.append(np.arange(0.0, ts[-1], step_s), ts[-1])
        q = np.column_stack([np.interp(grid, ts, self.p[:, k]) for k in range(3)])
        return float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum())

    def travelled_at(self, stamps: Sequence[int] | np.ndarray) -> np.ndarray:
        """Distance travelled (m, raw sample steps) from the first sample up to each stamp."""
        if not len(self.t):
            raise ValueError("Trajectory is empty")
        seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(self.p, axis=0), axis=1))]
        ts, s = self._seconds(np.asarray(stamps, dtype=np.int64))
        travelled: np.ndarray = np.interp(s, ts, seg)
        return travelled


@dataclass(frozen=True)
class PoseSeries:
    """Poses over time in the frame they were published in: ``stamps`` (n,) int64 ns
    non-decreasing, ``positions`` (n, 3) m, ``quaternions`` (n, 4) ``[x, y, z, w]`` of unit norm."""

    stamps: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.stamps)
        if self.stamps.ndim != 1 or self.positions.shape != (n, 3) or self.quaternions.shape != (n, 4):
            raise ValueError(f"PoseSeries: stamps {self.stamps.shape}, positions {self.positions.shape}, "
                             f"quaternions {self.quaternions.shape} do not agree")
        if n > 1 and np.any(np.diff(self.stamps) < 0):
            raise ValueError("PoseSeries: stamps must be non-decreasing")

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def yaws(self) -> np.ndarray:
        """Yaw (rad, about +z) of every orientation, in [-pi, pi]."""
        return yaws_of_quaternions(self.quaternions)

    def interpolate(self, stamps: Sequence[int] | np.ndarray) -> PoseSeries:
        """Poses at ``stamps``: position linear, orientation SLERP between the bracketing samples
        (the last of samples with equal stamps counts); clamped outside the span."""
        if not len(self):
            raise ValueError("PoseSeries is empty")
        q = np.asarray(stamps, dtype=np.int64).reshape(-1)
        p, quat = interpolate_poses(self.stamps, self.positions, self.quaternions, q)
        return PoseSeries(q, p, quat)


def pose_series(messages: Iterable[Odometry]) -> PoseSeries:
    """The poses of ``Odometry`` messages, sorted by stamp (stable)."""
    ms = list(messages)
    t = np.array([m.header.stamp for m in ms], dtype=np.int64)
    order = np.argsort(t, kind="stable")
    p = np.array([m.position for m in ms], dtype=float).reshape(-1, 3)[order]
    q = np.array([m.orientation for m in ms], dtype=float).reshape(-1, 4)[order]
    return PoseSeries(t[order], p, normalise_quaternions(q) if len(q) else q)


def align_rigid(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R (3x3, det +1) and translation t minimising sum |R src_i + t - dst_i|^2.

    Umeyama's closed form without scale (Kabsch): SVD of the cross-covariance of the
    centred point sets, the sign of the last singular direction fixed so that R is a proper
    rotation.  Fewer than 3 pairs (or collinear points) still give a valid minimiser.
    """
    a = np.asarray(src, dtype=float).reshape(-1, 3)
    b = np.asarray(dst, dtype=float).reshape(-1, 3)
    if len(a) != len(b) or not len(a):
        raise ValueError(f"align_rigid: need equal, non-empty point sets (got {len(a)} and {len(b)})")
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ma).T @ (b - mb)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, mb - r @ ma


def align_trajectory(est: Trajectory, ref: Trajectory, stamps: Sequence[int] | np.ndarray | None = None) -> Trajectory:
    """``est`` moved by the rigid alignment (:func:`align_rigid`) of its time-aligned pairs
    with ``ref`` (at ``stamps``, default the reference stamps both cover): what :func:`ate`
    measures, e.g. for plotting an estimate over the ground truth."""
    _, e, g = _pairs(est, ref, None if stamps is None else np.asarray(stamps, dtype=np.int64))
    r, t = align_rigid(e, g)
    return est.transformed(r, t)


def _pairs(est: Trajectory, ref: Trajectory, stamps: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = ref.t if stamps is None else np.asarray(stamps, dtype=np.int64)
    s = s[est.covered(s) & ref.covered(s)]
    if not len(s):
        raise ValueError("the estimate and the reference share no stamps (no time overlap)")
    return s, est.positions_at(s), ref.positions_at(s)


def ate(est: Trajectory, ref: Trajectory, stamps: Sequence[int] | np.ndarray | None = None,
        align: bool = True) -> dict[str, float | int]:
    """Time-aligned absolute trajectory error of ``est`` against ``ref`` (m).

    Both are interpolated at ``stamps`` (default: the reference stamps), keeping only the
    stamps both cover; with ``align`` the estimate is first moved by :func:`align_rigid`.
    Returns ``rmse_m, mean_m, max_m, final_m`` and ``n`` (pairs used).
    """
    _, e, g = _pairs(est, ref, None if stamps is None else np.asarray(stamps, dtype=np.int64))
    if align:
        r, t = align_rigid(e, g)
        e = e @ r.T + t
    err = np.linalg.norm(e - g, axis=1)
    return {"rmse_m": float(np.sqrt(np.mean(err ** 2))), "mean_m": float(err.mean()), "max_m": float(err.max()),
            "final_m": float(err[-1]), "n": int(len(err))}


def rpe(est: Trajectory, ref: Trajectory, delta_s: float = 10.0, stamps: Sequence[int] | np.ndarray | None = None,
        align: bool = True) -> dict[str, float | int | None]:
    """Relative position error over ``delta_s`` seconds (m): for each stamp t with a stamp
    at least ``delta_s`` later, the first such stamp t' gives |(e(t')-e(t)) - (g(t')-g(t))|,
    the estimate rotated by the ATE alignment when ``align``.  ``rmse_m, mean_m, n``."""
    s, e, g = _pairs(est, ref, None if stamps is None else np.asarray(stamps, dtype=np.int64))
    if align:
        r, _ = align_rigid(e, g)
        e = e @ r.T
    j = np.searchsorted(s, s + int(round(delta_s * NS)), side="left")
    ok = j < len(s)
    if not ok.any():
        return {"rmse_m": None, "mean_m": None, "n": 0, "delta_s": delta_s}
    i, j = np.flatnonzero(ok), j[ok]
    err = np.linalg.norm((e[j] - e[i]) - (g[j] - g[i]), axis=1)
    return {"rmse_m": float(np.sqrt(np.mean(err ** 2))), "mean_m": float(err.mean()), "n": int(len(err)),
            "delta_s": delta_s}


def drift_pct(final_error_m: float, distance_m: float) -> float | None:
    """Final error as a percentage of the distance travelled (None for zero distance)."""
    return 100.0 * final_error_m / distance_m if distance_m > 0 else None


def anchored_errors(est: Trajectory, truth: Trajectory) -> dict[str, float]:
    """Errors of an estimate translated to start at the true start (no rotation), at the
    truth stamps within the estimate's span: ``ate_rmse_m, final_error_m, final_drift_pct,
    max_error_m, truth_distance_m`` (the ``truth`` block of ``poseidon deadreckon``)."""
    mask = truth.covered(truth.t) & est.covered(truth.t)
    tt, tp = truth.t[mask], truth.p[mask]
    if not len(tt):
        raise ValueError("the estimate and the truth share no stamps (no time overlap)")
    e = est.positions_at(tt)
    e += tp[0] - e[0]
    err = np.linalg.norm(e - tp, axis=1)
    dist = float(np.linalg.norm(np.diff(tp, axis=0), axis=1).sum())
    d = drift_pct(float(err[-1]), dist)
    return {"ate_rmse_m": float(np.sqrt(np.mean(err ** 2))), "final_error_m": float(err[-1]),
            "final_drift_pct": float("nan") if d is None else d,
            "max_error_m": float(err.max()), "truth_distance_m": dist}
