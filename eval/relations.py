"""Relation-based trajectory error: the metric of the Freiburg SLAM benchmark.

Kümmerle et al., "On measuring the accuracy of SLAM algorithms", Autonomous Robots 27(4),
2009 (the benchmark's own ``metricEvaluator`` computes the same).

Relations file: one relation per line, ``t_i t_j dx dy dz roll pitch dyaw``: the reference
motion from the robot pose at time t_i to the pose at t_j (s, the log's ipc timestamps),
expressed in the frame of the pose at t_i (x forward, y left, dyaw counter-clockwise, m and
rad); ``dz roll pitch`` are read and ignored (planar benchmark).  Blank lines and ``#``
lines are skipped; any other malformed line is a ``ValueError`` naming file, line and field.

Error of a trajectory (stamps ns, planar x, y m and yaw rad about +z, counter-clockwise:
CARMEN's frame, ENU, or any right-handed frame with z up):

- the pose at time t is interpolated between the bracketing samples: x, y linear, yaw by
  the shortest angle (:func:`interpolate_planar`); a relation with t_i or t_j outside the
  trajectory's [first, last] stamp is counted in ``outside`` and excluded;
- estimated relation: ``(R(yaw_i)^T (p_j - p_i), wrap(yaw_j - yaw_i))``;
- error: component-wise difference from the reference, ``ex = dx_est - dx``, ``ey = dy_est -
  dy``, ``eyaw = wrap(dyaw_est - dyaw)``;
- ``trans_abs = sqrt(ex^2 + ey^2)`` (m), ``rot_abs = |eyaw|`` (deg), ``trans_sq = ex^2 +
  ey^2`` (m^2); over all used relations the mean and the population standard deviation.

:func:`relation_summary` gives ``{count, outside, trans_abs_m: {mean, std}, rot_abs_deg:
{mean, std}, trans_sq_m2: {mean, std}}`` (``count`` = relations used; mean and std null when
none is), the block of ``poseidon eval --relations`` (:mod:`eval.run_eval`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.geometry import wrap_angles as wrap
from common.stamps import seconds_to_ns
from eval.results import MeanStd, RelationFigures

__all__ = ["Relations", "read_relations", "interpolate_planar", "relation_errors", "relation_summary"]

_FIELDS = ("t_i", "t_j", "dx", "dy", "dz", "roll", "pitch", "dyaw")


@dataclass(frozen=True)
class Relations:
    """Reference relations: stamps ``t_i``, ``t_j`` (int64 ns) and ``dx``, ``dy``, ``dyaw`` (m, rad)."""

    t_i: np.ndarray
    t_j: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    dyaw: np.ndarray

    def __len__(self) -> int:
        return len(self.t_i)


def read_relations(path: str | Path) -> Relations:
    """Read a relations file (module docstring).

    :raises ValueError: missing file or a malformed line (file:line: field and reason).
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ValueError(f"{p}: cannot read the relations file: {exc.strerror}") from None
    ti: list[int] = []
    tj: list[int] = []
    vals: list[tuple[float, float, float]] = []
    for k, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        if len(tok) != 8:
            raise ValueError(f"{p}:{k}: {len(tok)} fields, expected 8 ({' '.join(_FIELDS)})")
        try:
            a, b = seconds_to_ns(tok[0]), seconds_to_ns(tok[1])
        except ValueError as exc:
            raise ValueError(f"{p}:{k}: field {'t_i' if not _number(tok[0]) else 't_j'}: {exc}") from None
        row = []
        for name, v in zip(_FIELDS[2:], tok[2:]):
            try:
                x = float(v)
            except ValueError:
                raise ValueError(f"{p}:{k}: field {name}: {v!r} is not a number") from None
            if not math.isfinite(x):
                raise ValueError(f"{p}:{k}: field {name}: {v!r} is not finite")
            row.append(x)
        ti.append(a)
        tj.append(b)
        vals.append((row[0], row[1], row[5]))
    table = np.array(vals, dtype=float).reshape(-1, 3)
    return Relations(np.array(ti, dtype=np.int64), np.array(tj, dtype=np.int64), table[:, 0], table[:, 1],
                     table[:, 2])


def _number(s: str) -> bool:
    try:
        seconds_to_ns(s)
    except ValueError:
        return False
    return True


def interpolate_planar(stamps: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                       query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y, yaw at ``query`` stamps (ns, inside [stamps[0], stamps[-1]]): linear between the
    bracketing samples (the last of equal stamps counts), yaw by the shortest angle.

    :param stamps: (n,) int64 ns, non-decreasing, n >= 1
    """
    q = np.asarray(query, dtype=np.int64)
    if len(stamps) == 1:
        return np.full(len(q), x[0]), np.full(len(q), y[0]), np.full(len(q), wrap(yaw[0]))
    i = np.clip(np.searchsorted(stamps, q, side="right") - 1, 0, len(stamps) - 2)
    t0, t1 = stamps[i], stamps[i + 1]
    span = (t1 - t0).astype(np.float64)
    f = np.where(span > 0, (q - t0).astype(np.float64) / np.where(span > 0, span, 1.0), 1.0)
    f = np.clip(f, 0.0, 1.0)
    dyaw = wrap(yaw[i + 1] - yaw[i])
    return (x[i] + f * (x[i + 1] - x[i]), y[i] + f * (y[i + 1] - y[i]), wrap(yaw[i] + f * dyaw))


def relation_errors(stamps: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                    rel: Relations) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per relation (ex, ey, eyaw) and the mask of relations inside the trajectory's span
    (errors are NaN outside it).  Trajectory: (n,) stamps ns non-decreasing, x, y m, yaw rad."""
    n = len(rel)
    ex, ey, ea = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    inside = np.zeros(n, dtype=bool)
    if len(stamps) == 0 or n == 0:
        return ex, ey, ea, inside
    t0, t1 = stamps[0], stamps[-1]
    inside = (rel.t_i >= t0) & (rel.t_i <= t1) & (rel.t_j >= t0) & (rel.t_j <= t1)
    if not inside.any():
        return ex, ey, ea, inside
    xi, yi, ai = interpolate_planar(stamps, x, y, yaw, rel.t_i[inside])
    xj, yj, aj = interpolate_planar(stamps, x, y, yaw, rel.t_j[inside])
    dx, dy = xj - xi, yj - yi
    c, s = np.cos(ai), np.sin(ai)
    ex[inside] = c * dx + s * dy - rel.dx[inside]
    ey[inside] = -s * dx + c * dy - rel.dy[inside]
    ea[inside] = wrap(wrap(aj - ai) - rel.dyaw[inside])
    return ex, ey, ea, inside


def _ms(v: np.ndarray) -> MeanStd:
    if not len(v):
        return {"mean": None, "std": None}
    return {"mean": round(float(np.mean(v)), 6), "std": round(float(np.std(v)), 6)}


def relation_summary(stamps: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                     rel: Relations) -> RelationFigures:
    """``{count, outside, trans_abs_m, rot_abs_deg, trans_sq_m2}`` (module docstring)."""
    ex, ey, ea, inside = relation_errors(stamps, x, y, yaw, rel)
    sq = ex[inside] ** 2 + ey[inside] ** 2
    return {"count": int(inside.sum()), "outside": int((~inside).sum()),
            "trans_abs_m": _ms(np.sqrt(sq)), "rot_abs_deg": _ms(np.degrees(np.abs(ea[inside]))),
            "trans_sq_m2": _ms(sq)}
