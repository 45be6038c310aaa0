"""CARMEN robot logs (``.clf``, ``.clf.bz2``, ``.clf.gz``) -> one PoseidonSLAM recording.

``poseidon import LOG.clf[.bz2|.gz] --out FILE.mcap [--json]`` (:mod:`missions.importers.cli`
dispatches on the suffix; a CARMEN log is imported on its own, not merged with other sources).

Mapping (a contract the SLAM services depend on):

==============  ==================  ============================================================
line            key                 message
==============  ==================  ============================================================
``ODOM``        ``wheel_odometry``  :class:`~common.messages.Odometry`: frame ``odom``, child
                                    ``base_link``, position ``[x, y, 0]``, orientation the
                                    quaternion ``[0, 0, sin(theta/2), cos(theta/2)]`` (x y z w),
                                    ``linear_velocity [tv, 0, 0]``, ``angular_velocity
                                    [0, 0, rv]``; ``accel`` is not kept
``FLASER``      ``scan``            :class:`~common.messages.LaserScan` (frame ``front_laser``)
``RLASER``      ``scan_rear``       the same (frame ``rear_laser``)
``ROBOTLASER1`` ``scan``            the same, with the line's own start angle, resolution and
                                    maximum range (``angle_max = start + (n - 1) * res``; the
                                    line's fov is not needed)
``PARAM``       --                  metadata record ``carmen_params`` (name -> value; a name
                                    given twice keeps its last value, as CARMEN's parameter
                                    server does)
==============  ==================  ============================================================

Odometry without ``ODOM`` lines: a log with no (valid) ``ODOM`` line gets its
``wheel_odometry`` from the robot odometry pose each laser line carries (``odom_x odom_y
odom_theta`` of ``FLASER``, else ``robot_x robot_y robot_theta`` of ``ROBOTLASER1``), one
message per laser line with the laser line's stamp (mit-csail: FLASER only; fr-clinic:
ROBOTLASER1 only).  ``FLASER`` carries no velocities: those messages have zero velocities
and ``status ["velocity_unknown"]``; ``ROBOTLASER1`` carries ``tv rv``.  The ``--json``
key ``odometry_from`` says which: ``"ODOM"`` | ``"FLASER"`` | ``"ROBOTLASER1"`` (null: none).

Beam geometry of ``FLASER``/``RLASER`` (the line gives only the count n), as CARMEN's own
reader guesses it (``carmen_laser_guess_angle_increment`` in ``readlog.c``): first beam at
``angle_min = -pi/2``; increment pi/180 (1 deg) for n = 180 or 181, pi/360 (0.5 deg) for
n = 360 or 361, pi/720 for n = 400 or 401, else pi/(n - 1); ``angle_max = angle_min +
(n - 1) * increment`` (n = 180: -90 .. +89 deg; 181: -90 .. +90; 360: -90 .. +89.5;
361: -90 .. +90).
``range_min`` 0; ``range_max`` from the log's ``PARAM robot_front_laser_max`` (``scan``) /
``robot_rear_laser_max`` (``scan_rear``), else :data:`DEFAULT_RANGE_MAX_M` = 81.9 m (a SICK
LMS reports "no return" as 81.91 m, just beyond it).  Ranges float32, intensities an empty
float32 array.  The laser pose on each line (x y theta) is not a LaserScan field; its offset
from the robot pose in the robot frame (median over the log) is in the ``--json`` key
``laser_offsets`` and the ``poseidon`` metadata.

Stamps: ``header.stamp = round(ipc_ts * 1e9)`` ns, computed from the decimal text, so
``t = stamp / 1e9`` (printed with 9 decimals, :func:`ns_to_text`) reproduces ``ipc_ts`` to
1 ns (:mod:`common.stamps`).  Messages are written in chronological order (equal stamps:
file order); ``seq`` counts per key from 0 in that order.  ``PARAM`` lines take either ``PARAM name value ipc_ts host
logger_ts`` or, as in older logs, ``PARAM name value host logger_ts`` (no ipc timestamp).

Every line is accounted for (``--json``):

- ``lines``: lines in the file; ``comments`` (``#``), ``blank``;
- ``line_types``: per type seen ``{lines, mapped, unused, rejected}`` (``mapped``: turned
  into messages or metadata; ``unused``: a known CARMEN type this importer does not map,
  e.g. ``TRUEPOS``, ``SYNC``, ``NMEAGGA``); ``known_unused``: their total;
- ``rejected``: ``[{line, type, reason}]`` for malformed lines (wrong field count, n not
  matching the fields, non-numeric or non-finite value, negative stamp); the import goes on
  and the command exits 1;
- ``unknown``: ``{TYPE: {lines, first_line}}`` for line types CARMEN does not define;
- ``accounted``: comments + blank + every type's lines + unknown lines (= ``lines``);
- ``out``, ``input``, ``format`` (``"carmen"``), ``odometry_from``, ``written`` (key ->
  messages), ``scan_geometry`` (key -> list of the distinct ``{n, angle_min, angle_max,
  angle_increment, range_max, lines}``), ``range_max_from`` (key -> ``"PARAM <name>"`` |
  ``"default"`` | ``"line"``), ``laser_offsets`` (key -> ``{dx, dy, dtheta, max_deviation_m}``), ``params``
  (PARAM names kept), ``start_ns``, ``end_ns``, ``duration_s``.
"""
from __future__ import annotations

import bz2
import gzip
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from common.geometry import quaternion_of_yaw, wrap_angle
from common.mcap_io import RecordingWriter
from common.messages import Header, LaserScan, Message, Odometry
from common.stamps import ns_to_text, seconds_to_ns
from missions.importers.errors import InputFormatError

__all__ = ["CARMEN_SUFFIXES", "DEFAULT_RANGE_MAX_M", "KNOWN_UNUSED", "is_carmen_log", "import_carmen",
           "parse_carmen", "seconds_to_ns", "ns_to_text", "flaser_geometry", "CarmenLog"]

#: suffixes dispatched to this importer
CARMEN_SUFFIXES = (".clf", ".clf.bz2", ".clf.gz")
#: ``range_max`` of FLASER/RLASER scans when the log has no PARAM for it (m)
DEFAULT_RANGE_MAX_M = 81.9
#: CARMEN line types known but not mapped (counted as ``unused``)
KNOWN_UNUSED = frozenset({
    "SYNC", "TRUEPOS", "NMEAGGA", "NMEA-GGA", "NMEARMC", "NMEA-RMC", "RAWLASER1", "RAWLASER2", "RAWLASER3",
    "RAWLASER4", "ROBOTLASER0", "ROBOTLASER2", "ROBOTLASER3", "ROBOTLASER4", "LASER", "LASER3", "LASER4",
    "REMISSIONFLASER", "REMISSIONRLASER", "SONAR", "BUMPER", "SCANMARK", "POSITIONLASER", "IMU", "VELOCITY",
    "VECTORMOVE", "ROBOTVELOCITY", "GPSNMEA", "ODOM_ACK", "TRUEPOS_ACK", "ROBOTVELOCITY_ACK",
})
MAPPED = ("ODOM", "FLASER", "RLASER", "ROBOTLASER1", "PARAM")
_LASER_KEY = {"FLASER": "scan", "RLASER": "scan_rear", "ROBOTLASER1": "scan"}
_LASER_FRAME = {"FLASER": "front_laser", "RLASER": "rear_laser", "ROBOTLASER1": "front_laser"}
_RANGE_PARAM = {"FLASER": "robot_front_laser_max", "RLASER": "robot_rear_laser_max"}


class _Reject(ValueError):
    """A malformed line: the reason goes into ``rejected``."""


def flaser_geometry(n: int) -> tuple[float, float, float]:
    """(angle_min, angle_max, angle_increment) in rad of an n-beam FLASER/RLASER (module docstring)."""
    if n in (180, 181):
        inc = math.pi / 180.0
    elif n in (360, 361):
        inc = math.pi / 360.0
    elif n in (400, 401):
        inc = math.pi / 720.0
    else:
        inc = math.pi / (n - 1) if n > 1 else 0.0
    a0 = -math.pi / 2.0
    return a0, a0 + (n - 1) * inc, inc


def is_carmen_log(path: str | Path) -> bool:
    """Whether the file name ends in one of :data:`CARMEN_SUFFIXES` (case-insensitive)."""
    return str(path).lower().endswith(CARMEN_SUFFIXES)


def _open_text(path: Path) -> IO[str]:
    name = path.name.lower()
    if name.endswith(".bz2"):
        return bz2.open(path, "rt", encoding="latin-1", newline="")
    if name.endswith(".gz"):
        return gzip.open(path, "rt", encoding="latin-1", newline="")
    return open(path, encoding="latin-1", newline="")


def _floats(tokens: list[str], what: str) -> np.ndarray:
    try:
        a = np.asarray(tokens, dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise _Reject(f"{what}: {bad!r} is not a number") from None
    if not np.all(np.isfinite(a)):
        raise _Reject(f"{what}: non-finite value {tokens[int(np.flatnonzero(~np.isfinite(a))[0])]!r}")
    return a


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def _int(token: str, what: str) -> int:
    try:
        v = int(token)
    except ValueError:
        raise _Reject(f"{what}: {token!r} is not an integer") from None
    if v < 0:
        raise _Reject(f"{what}: {v} is negative")
    return v


def _stamp(token: str) -> int:
    try:
        ns = seconds_to_ns(token)
    except ValueError as exc:
        raise _Reject(f"ipc_timestamp: {exc}") from None
    if ns < 0:
        raise _Reject(f"ipc_timestamp {token} is negative")
    return ns


def _count(tokens: list[str], expected: int, form: str) -> None:
    if len(tokens) != expected:
        raise _Reject(f"{len(tokens)} fields, expected {expected} ({form})")


@dataclass
class _Laser:
    """One parsed laser line."""

    kind: str
    stamp: int
    line: int
    ranges: np.ndarray
    laser_pose: np.ndarray
    robot_pose: np.ndarray
    start: float | None = None  # ROBOTLASER1: the line's own geometry
    fov: float | None = None
    res: float | None = None
    max_range: float | None = None
    tv: float = 0.0
    rv: float = 0.0


@dataclass
class _Odom:
    stamp: int
    line: int
    pose: np.ndarray
    tv: float
    rv: float


@dataclass
class CarmenLog:
    """Every line of a CARMEN log, parsed and accounted for (see the module docstring)."""

    path: Path
    lines: int = 0
    comments: int = 0
    blank: int = 0
    types: dict[str, dict[str, int]] = field(default_factory=dict)
    unknown: dict[str, dict[str, int]] = field(default_factory=dict)
    rejected: list[dict[str, Any]] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)
    odom: list[_Odom] = field(default_factory=list)
    lasers: list[_Laser] = field(default_factory=list)

    def _type(self, kind: str) -> dict[str, int]:
        t = self.types.get(kind)
        if t is None:
            t = self.types[kind] = {"lines": 0, "mapped": 0, "unused": 0, "rejected": 0}
        return t

    @property
    def odometry_from(self) -> str | None:
        """``ODOM`` when the log has valid ODOM lines, else the laser type carrying the odometry."""
        if self.odom:
            return "ODOM"
        for kind in ("FLASER", "ROBOTLASER1"):
            if any(x.kind == kind for x in self.lasers):
                return kind
        return None

    @property
    def accounted(self) -> int:
        return (self.comments + self.blank + sum(t["lines"] for t in self.types.values())
                + sum(u["lines"] for u in self.unknown.values()))


def _parse_odom(tok: list[str], line: int) -> _Odom:
    _count(tok, 10, "ODOM x y theta tv rv accel ipc_ts host logger_ts")
    v = _floats(tok[1:7], "ODOM x y theta tv rv accel")
    return _Odom(_stamp(tok[7]), line, v[0:3], float(v[3]), float(v[4]))


def _parse_flaser(tok: list[str], line: int) -> _Laser:
    if len(tok) < 2:
        raise _Reject(f"{len(tok)} fields: no beam count")
    n = _int(tok[1], f"{tok[0]} num_readings")
    _count(tok, n + 11, f"{tok[0]} n r1..rn x y theta odom_x odom_y odom_theta ipc_ts host logger_ts with n = {n}")
    ranges = _floats(tok[2:2 + n], f"{tok[0]} ranges")
    pose = _floats(tok[2 + n:8 + n], f"{tok[0]} x y theta odom_x odom_y odom_theta")
    return _Laser(tok[0], _stamp(tok[8 + n]), line, ranges, pose[0:3], pose[3:6])


def _parse_robotlaser(tok: list[str], line: int) -> _Laser:
    if len(tok) < 10:
        raise _Reject(f"{len(tok)} fields: too few for ROBOTLASER1's header")
    head = _floats(tok[2:7], "ROBOTLASER1 start_angle fov angular_res max_range accuracy")
    n = _int(tok[8], "ROBOTLASER1 num_readings")
    if len(tok) < 10 + n:
        raise _Reject(f"{len(tok)} fields: too few for n = {n} readings")
    n_rem = _int(tok[9 + n], "ROBOTLASER1 num_remissions")
    _count(tok, 24 + n + n_rem, f"ROBOTLASER1 ... n r1..rn n_rem rem.. laser_x .. turn_axis ipc_ts host logger_ts "
                                f"with n = {n}, n_rem = {n_rem}")
    ranges = _floats(tok[9:9 + n], "ROBOTLASER1 ranges")
    o = 10 + n + n_rem
    tail = _floats(tok[o:o + 11], "ROBOTLASER1 laser/robot pose tv rv safety turn_axis")
    if head[3] < 0:
        raise _Reject(f"ROBOTLASER1 max_range {head[3]} is negative")
    return _Laser("ROBOTLASER1", _stamp(tok[o + 11]), line, ranges, tail[0:3], tail[3:6], start=float(head[0]),
                  fov=float(head[1]), res=float(head[2]), max_range=float(head[3]), tv=float(tail[6]),
                  rv=float(tail[7]))


def _parse_param(tok: list[str], log: CarmenLog) -> None:
    """``PARAM name value [ipc_ts] host logger_ts`` (value may hold spaces)."""
    if len(tok) < 5:
        raise _Reject(f"{len(tok)} fields, expected PARAM name value [ipc_ts] host logger_ts")
    with_ipc = len(tok) >= 6 and _is_float(tok[-3])
    value = " ".join(tok[2:-3] if with_ipc else tok[2:-2])
    if not value:
        raise _Reject("PARAM without a value")
    log.params[tok[1]] = value


def parse_carmen(path: str | Path) -> CarmenLog:
    """Read every line of a CARMEN log (plain, bzip2 or gzip).

    :raises InputFormatError: the file is missing or its compression is damaged (names the
        file and the last line read).
    """
    p = Path(path)
    if not p.is_file():
        raise InputFormatError(f"{p}: no such file")
    log = CarmenLog(path=p)
    try:
        with _open_text(p) as f:
            for lineno, text in enumerate(f, 1):
                log.lines = lineno
                _parse_line(log, text, lineno)
    except (OSError, EOFError) as exc:
        raise InputFormatError(f"{p}: unreadable after line {log.lines}: {type(exc).__name__}: {exc}") from None
    return log


def _parse_line(log: CarmenLog, text: str, lineno: int) -> None:
    tok = text.split()
    if not tok:
        log.blank += 1
        return
    if tok[0].startswith("#"):
        log.comments += 1
        return
    kind = tok[0]
    if kind not in MAPPED and kind not in KNOWN_UNUSED:
        u = log.unknown.setdefault(kind, {"lines": 0, "first_line": lineno})
        u["lines"] += 1
        return
    t = log._type(kind)
    t["lines"] += 1
    if kind in KNOWN_UNUSED:
        t["unused"] += 1
        return
    try:
        if kind == "ODOM":
            log.odom.append(_parse_odom(tok, lineno))
        elif kind in ("FLASER", "RLASER"):
            log.lasers.append(_parse_flaser(tok, lineno))
        elif kind == "ROBOTLASER1":
            log.lasers.append(_parse_robotlaser(tok, lineno))
        else:
            _parse_param(tok, log)
    except _Reject as exc:
        t["rejected"] += 1
        log.rejected.append({"line": lineno, "type": kind, "reason": str(exc)})
        return
    t["mapped"] += 1


def _odometry(stamp: int, seq: int, pose: np.ndarray, tv: float, rv: float, status: list[str]) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=stamp, frame_id="odom"), child_frame_id="base_link",
                    position=[float(pose[0]), float(pose[1]), 0.0], orientation=quaternion_of_yaw(float(pose[2])),
                    linear_velocity=[tv, 0.0, 0.0], angular_velocity=[0.0, 0.0, rv], status=status)


def _range_max(log: CarmenLog, kind: str) -> tuple[float, str]:
    name = _RANGE_PARAM.get(kind)
    if name is not None and name in log.params:
        try:
            v = float(log.params[name])
        except ValueError:
            raise InputFormatError(f"{log.path}: PARAM {name} = {log.params[name]!r} is not a number") from None
        if math.isfinite(v) and v > 0:
            return v, f"PARAM {name}"
        raise InputFormatError(f"{log.path}: PARAM {name} = {log.params[name]!r} is not a positive range")
    return DEFAULT_RANGE_MAX_M, "default"


def _angles(x: _Laser) -> tuple[float, float, float]:
    """(angle_min, angle_max, angle_increment) of a laser line: its own (ROBOTLASER1) or CARMEN's guess."""
    n = len(x.ranges)
    if x.start is None or x.res is None:
        return flaser_geometry(n)
    return x.start, max(x.start, x.start + (n - 1) * x.res), x.res


def _scan(x: _Laser, seq: int, range_max: float) -> LaserScan:
    a0, a1, inc = _angles(x)
    return LaserScan(header=Header(seq=seq, stamp=x.stamp, frame_id=_LASER_FRAME[x.kind]), angle_min=a0,
                     angle_max=a1, angle_increment=inc, range_min=0.0, range_max=range_max,
                     ranges=x.ranges.astype(np.float32), intensities=np.zeros(0, dtype=np.float32))


def _records(log: CarmenLog) -> list[tuple[int, int, str, Any]]:
    """(stamp, line, key, parsed line) in chronological order (stable: file order)."""
    recs: list[tuple[int, int, str, Any]] = [(o.stamp, o.line, "wheel_odometry", o) for o in log.odom]
    src = log.odometry_from
    for x in log.lasers:
        recs.append((x.stamp, x.line, _LASER_KEY[x.kind], x))
        if src == x.kind:
            recs.append((x.stamp, x.line, "wheel_odometry", x))
    recs.sort(key=lambda r: (r[0], r[1]))
    return recs


def _messages(log: CarmenLog, range_max: dict[str, float]) -> Iterator[tuple[str, Message]]:
    seqs: dict[str, int] = {}
    for _, _, key, rec in _records(log):
        seq = seqs.get(key, 0)
        seqs[key] = seq + 1
        if isinstance(rec, _Odom):
            yield key, _odometry(rec.stamp, seq, rec.pose, rec.tv, rec.rv, [])
        elif key == "wheel_odometry":
            status = ["velocity_unknown"] if rec.kind == "FLASER" else []
            yield key, _odometry(rec.stamp, seq, rec.robot_pose, rec.tv, rec.rv, status)
        else:
            yield key, _scan(rec, seq, rec.max_range if rec.max_range is not None else range_max[rec.kind])


def laser_offsets(log: CarmenLog) -> dict[str, dict[str, float]]:
    """Per scan key: the median laser pose relative to the robot pose, in the robot frame
    (dx forward, dy left m, dtheta rad), and the largest distance of a line's offset from it (m)."""
    out: dict[str, dict[str, float]] = {}
    for key in sorted(set(_LASER_KEY[x.kind] for x in log.lasers)):
        xs = [x for x in log.lasers if _LASER_KEY[x.kind] == key]
        lp = np.array([x.laser_pose for x in xs])
        rp = np.array([x.robot_pose for x in xs])
        d = lp[:, :2] - rp[:, :2]
        c, s = np.cos(rp[:, 2]), np.sin(rp[:, 2])
        fwd, left = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        dth = wrap_angle(lp[:, 2] - rp[:, 2])
        med = np.array([np.median(fwd), np.median(left)])
        dev = float(np.max(np.hypot(fwd - med[0], left - med[1])))
        out[key] = {"dx": round(float(med[0]), 6), "dy": round(float(med[1]), 6),
                    "dtheta": round(float(np.median(dth)), 6), "max_deviation_m": round(dev, 6)}
    return out


def _geometry(log: CarmenLog, range_max: dict[str, float]) -> dict[str, list[dict[str, float]]]:
    """Per scan key, every distinct beam geometry with the number of lines that have it."""
    out: dict[str, dict[tuple[float, ...], dict[str, float]]] = {}
    for x in log.lasers:
        a0, a1, inc = _angles(x)
        g = {"n": len(x.ranges), "angle_min": round(a0, 9), "angle_max": round(a1, 9),
             "angle_increment": round(inc, 9),
             "range_max": x.max_range if x.max_range is not None else range_max[x.kind]}
        row = out.setdefault(_LASER_KEY[x.kind], {}).setdefault(tuple(g.values()), dict(g, lines=0))
        row["lines"] += 1
    return {k: list(v.values()) for k, v in out.items()}


def import_carmen(path: str | Path, out: str | Path) -> dict[str, Any]:
    """Import one CARMEN log into the recording ``out``; returns the summary (module docstring).

    :raises InputFormatError: missing or unreadable file, no line of a known type, or an
        invalid range PARAM.
    """
    log = parse_carmen(path)
    if not log.types:
        raise InputFormatError(f"{log.path}: not a CARMEN log: none of its {log.lines} lines has a known CARMEN type "
                               f"(unknown: {sorted(log.unknown)[:5]})")
    range_max: dict[str, float] = {}
    range_from: dict[str, str] = {}
    for kind in ("FLASER", "RLASER"):
        range_max[kind], how = _range_max(log, kind)
        if any(x.kind == kind for x in log.lasers):
            range_from[_LASER_KEY[kind]] = how
    if any(x.kind == "ROBOTLASER1" for x in log.lasers):
        range_from["scan"] = "line"
    offsets = laser_offsets(log)
    out = Path(out)
    part = out.with_name(out.name + ".part")  # renamed on success, removed on failure
    writer = RecordingWriter(part)
    first = last = None
    ok = False
    try:
        for key, msg in _messages(log, range_max):
            writer.write(key, msg)
            first = msg.header.stamp if first is None else first
            last = msg.header.stamp
        writer.add_metadata("carmen_params", log.params)
        writer.add_metadata("poseidon", {
            "tool": "poseidon import", "sources": [str(log.path)], "source_format": "CARMEN log",
            "odometry_from": log.odometry_from, "laser_offsets": offsets,
            "stamps": "header.stamp = round(ipc_timestamp * 1e9) ns"})
        ok = True
    finally:
        writer.close()
        if ok:
            part.replace(out)
        else:
            part.unlink(missing_ok=True)
    return {
        "out": str(out), "input": str(log.path), "format": "carmen", "odometry_from": log.odometry_from,
        "lines": log.lines, "comments": log.comments, "blank": log.blank,
        "line_types": dict(sorted(log.types.items())),
        "known_unused": sum(t["unused"] for t in log.types.values()),
        "rejected": log.rejected, "unknown": log.unknown, "accounted": log.accounted,
        "written": dict(sorted(writer.counts.items())), "scan_geometry": _geometry(log, range_max),
        "range_max_from": range_from, "laser_offsets": offsets, "params": len(log.params),
        "start_ns": first, "end_ns": last, "duration_s": (last - first) / 1e9 if first is not None and last is not None else 0.0,
    }
