"""The map-corrected trajectory of a run, and TUM trajectory files.

One definition serves ``poseidon export RUN --tum OUT.txt`` and ``poseidon eval RUN
--relations FILE`` (:mod:`eval.relations`): :func:`map_corrected`.

Frames: everything stays in the frame the run publishes (``Odometry`` and the ``map``
nodes share it, :mod:`eval.trajectory`); nothing is converted to NED.  Yaw is the rotation
about +z of the ``[x, y, z, w]`` orientation quaternion (:func:`common.geometry.yaws_of_quaternions`).

Definition.  Input: the ``Odometry`` stream (the ``robot_state`` dead reckoning) and the
nodes of the run's **last** ``map`` message (id, position[3], yaw, stamp).  One output pose
per ``Odometry`` stamp t:

1. e = the latest node with stamp <= t (nodes ordered by stamp, then id); before the first
   node, the first node; e' = the node after e (e itself after the last node);
2. the odometry pose at a node's stamp, interpolated from the ``Odometry`` stream between the
   bracketing samples (position linear, orientation SLERP, so yaw moves by the shortest
   angle; clamped to the first / last sample outside the stream's span);
3. a node's correction C = T_map(node) * T_odom(node)^-1, restricted to a rotation about the
   vertical axis: R = Rz(yaw_map - yaw_odom), C(p) = R (p - p_odom(node)) + p_map(node);
4. the pose at t blends the two corrections by time, f = (t - t_e) / (t_e' - t_e) in [0, 1]:
   position (1 - f) C_e(p_odom(t)) + f C_e'(p_odom(t)), heading correction
   psi_e + f wrap(psi_e' - psi_e), orientation q_psi * q_odom(t) (pre-multiplied by the yaw
   rotation), so roll and pitch of a 3D (underwater) odometry are carried through and z is
   shifted by the blended p_map.z - p_odom.z.  At a node's stamp the pose is the node's;
   between nodes the dead reckoning is corrected by a correction that moves smoothly from
   one experience's to the next (a correction held constant until the next node jumps
   there: chosen on ACES, 0.044 vs 0.051 m and 0.90 vs 1.28 deg relation error; on FR079,
   which did not choose it, 0.661 vs 0.666 m and 5.28 vs 5.92 deg; same runs).

Without a map message (or with an empty map) the trajectory is the dead reckoning itself.

TUM file (:func:`write_tum`): one line ``t x y z qx qy qz qw`` per pose, t = stamp / 1e9 in
seconds on the input's own clock with exactly 9 decimals (for a CARMEN import that is the
log's ipc timestamp, :mod:`missions.importers.carmen`), the rest with 9 significant
decimals; a ``#`` header line names the columns.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from common.codec import DecodeError, decode
from common.geometry import wrap_angle, yaws_of_quaternions
from common.mcap_io import RecordedMessage, RecordingError, read_messages
from common.messages import ExperienceMap, ExperienceNode, Odometry, message_type
from common.stamps import ns_to_text, seconds_to_ns

__all__ = ["PoseSeries", "pose_series", "slerp", "quat_multiply", "map_corrected", "corrected_from_recording",
           "write_tum", "read_tum"]

NS = 1_000_000_000


@dataclass(frozen=True)
class PoseSeries:
    """Poses over time: ``stamps`` (n,) int64 ns non-decreasing, ``positions`` (n, 3) m,
    ``quaternions`` (n, 4) ``[x, y, z, w]`` of unit norm."""

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

    def interpolate(self, stamps: Sequence[int] | np.ndarray) -> "PoseSeries":
        """Poses at ``stamps``: position linear, orientation SLERP between the bracketing samples
        (the last of samples with equal stamps counts); clamped outside the span."""
        if not len(self):
            raise ValueError("PoseSeries is empty")
        q = np.asarray(stamps, dtype=np.int64).reshape(-1)
        if len(self) == 1:
            return PoseSeries(q, np.repeat(self.positions, len(q), 0), np.repeat(self.quaternions, len(q), 0))
        i = np.clip(np.searchsorted(self.stamps, q, side="right") - 1, 0, len(self) - 2)
        t0, t1 = self.stamps[i], self.stamps[i + 1]
        span = (t1 - t0).astype(np.float64)
        f = np.where(span > 0, (q - t0).astype(np.float64) / np.where(span > 0, span, 1.0), 1.0)
        f = np.clip(f, 0.0, 1.0)
        p = self.positions[i] + f[:, None] * (self.positions[i + 1] - self.positions[i])
        return PoseSeries(q, p, slerp(self.quaternions[i], self.quaternions[i + 1], f))


def _normalised(q: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(~(n > 0)):
        raise ValueError("quaternion of zero norm")
    return q / n


def pose_series(messages: Iterable[Odometry]) -> PoseSeries:
    """The poses of ``Odometry`` messages, sorted by stamp (stable)."""
    ms = list(messages)
    t = np.array([m.header.stamp for m in ms], dtype=np.int64)
    order = np.argsort(t, kind="stable")
    p = np.array([m.position for m in ms], dtype=float).reshape(-1, 3)[order]
    q = np.array([m.orientation for m in ms], dtype=float).reshape(-1, 4)[order]
    return PoseSeries(t[order], p, _normalised(q) if len(q) else q)


def slerp(q0: np.ndarray, q1: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (n, 4) at fractions f (n,), shortest arc."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float).copy()
    f = np.asarray(f, dtype=float)[:, None]
    d = np.sum(q0 * q1, axis=1)
    q1[d < 0] *= -1.0
    d = np.abs(d)[:, None]
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s[:, 0] < 1e-9
    w0 = np.where(small[:, None], 1.0 - f, np.sin((1.0 - f) * theta) / np.where(small[:, None], 1.0, s))
    w1 = np.where(small[:, None], f, np.sin(f * theta) / np.where(small[:, None], 1.0, s))
    return _normalised(w0 * q0 + w1 * q1)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of quaternions (..., 4) ``[x, y, z, w]``."""
    ax, ay, az, aw = (a[..., k] for k in range(4))
    bx, by, bz, bw = (b[..., k] for k in range(4))
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def map_corrected(odom: PoseSeries, nodes: Sequence[ExperienceNode] | None) -> PoseSeries:
    """The map-corrected pose at every odometry stamp (module docstring); ``odom`` itself
    when there are no nodes."""
    if not nodes or not len(odom):
        return odom
    ns = sorted(nodes, key=lambda n: (n.stamp, n.id))
    nt = np.array([n.stamp for n in ns], dtype=np.int64)
    at_nodes = odom.interpolate(nt)
    dpsi = np.array([n.yaw for n in ns], dtype=float) - at_nodes.yaws
    m_pos = np.array([n.position for n in ns], dtype=float)

    def through(e: np.ndarray) -> np.ndarray:
        """Odometry positions corrected by node e's correction."""
        c, s = np.cos(dpsi[e]), np.sin(dpsi[e])
        d = odom.positions - at_nodes.positions[e]
        return np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]]) + m_pos[e]

    e = np.clip(np.searchsorted(nt, odom.stamps, side="right") - 1, 0, len(ns) - 1)
    e1 = np.minimum(e + 1, len(ns) - 1)
    span = (nt[e1] - nt[e]).astype(np.float64)
    f = np.where(span > 0, (odom.stamps - nt[e]).astype(np.float64) / np.where(span > 0, span, 1.0), 0.0)
    f = np.clip(f, 0.0, 1.0)
    p = (1.0 - f)[:, None] * through(e) + f[:, None] * through(e1)
    psi = dpsi[e] + f * wrap_angle(dpsi[e1] - dpsi[e])
    qz = np.column_stack([np.zeros(len(e)), np.zeros(len(e)), np.sin(psi / 2), np.cos(psi / 2)])
    return PoseSeries(odom.stamps.copy(), p, _normalised(quat_multiply(qz, odom.quaternions)))


def _decode(rec: RecordedMessage, path: Path) -> object:
    try:
        return decode(rec.payload, message_type(rec.type_name))
    except (DecodeError, KeyError) as exc:
        raise RecordingError(f"{path}: key {rec.key!r} message seq {rec.seq} stamped {rec.stamp}: {exc}") from None


def corrected_from_recording(path: str | Path, key: str = "Odometry") -> tuple[PoseSeries, bool]:
    """(:func:`map_corrected` of the run at ``path``, whether it had a map message).

    :raises RecordingError: unreadable recording, or no ``key`` messages in it.
    """
    p = Path(path)
    odo: list[Odometry] = []
    last_map: RecordedMessage | None = None
    for rec in read_messages(p, keys=[key, "map"]):
        if rec.key == "map":
            last_map = rec
        else:
            m = _decode(rec, p)
            if not isinstance(m, Odometry):
                raise RecordingError(f"{p}: key {key!r} carries {rec.type_name}, not Odometry")
            odo.append(m)
    if not odo:
        raise RecordingError(f"{p}: no {key!r} messages: nothing to export (is it a run recording?)")
    nodes = None
    if last_map is not None:
        mp = _decode(last_map, p)
        assert isinstance(mp, ExperienceMap)
        nodes = mp.nodes
    try:
        odom = pose_series(odo)
    except ValueError as exc:  # a zero quaternion
        raise RecordingError(f"{p}: key {key!r}: {exc}") from None
    return map_corrected(odom, nodes), last_map is not None


def write_tum(path: str | Path, poses: PoseSeries) -> int:
    """Write ``poses`` as a TUM trajectory file (module docstring); returns the line count."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w") as f:
        f.write("# t x y z qx qy qz qw\n")
        for t, pp, q in zip(poses.stamps, poses.positions, poses.quaternions):
            f.write(f"{ns_to_text(int(t))} {' '.join(f'{v:.9f}' for v in pp)} {' '.join(f'{v:.9f}' for v in q)}\n")
    return len(poses)


def read_tum(path: str | Path) -> PoseSeries:
    """Read a TUM trajectory file (``#`` lines and blank lines skipped).

    :raises ValueError: a line without 8 numbers (names the file and line).
    """
    p = Path(path)
    t: list[int] = []
    rows: list[list[float]] = []
    for k, line in enumerate(p.read_text().splitlines(), 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        if len(tok) != 8:
            raise ValueError(f"{p}:{k}: {len(tok)} fields, expected 8 (t x y z qx qy qz qw)")
        try:
            t.append(seconds_to_ns(tok[0]))
            rows.append([float(v) for v in tok[1:]])
        except ValueError as exc:
            raise ValueError(f"{p}:{k}: {exc}") from None
    a = np.array(rows, dtype=float).reshape(-1, 7)
    return PoseSeries(np.array(t, dtype=np.int64), a[:, :3], a[:, 3:])
