"""One pass over a run recording: the one run model of ``eval`` and the report.

:func:`load_run` reads an MCAP recording (``poseidon run`` output, or any recording with
some of the keys below) and returns a :class:`RunData`.  Only the keys the metrics and
figures use are decoded (:data:`DECODED`); the heavy ones are reduced on the way (camera
frames to their stamps, ``experience_image`` to header + ``source_stamp``, ``map`` to its
last message, ``neocortex/sdr`` to its fused active bits); every key is counted.  A live
run's ``live/latency`` report is kept as it is (``RunData.latency``).

Frames and units: positions are NED metres (:mod:`common.geometry`).  ``truth/pose`` is NED
already; ``Odometry`` and ``dead_reckoning`` are published in ``robot_state``'s frame and
are taken back to NED with the run's ``axis_remap``/``axis_sign_z`` (:meth:`RunData.to_ned`,
also for the ``map`` nodes).  ``Odometry`` and ``wheel_odometry`` are also kept as
published poses for the relation error (:mod:`eval.relations`).  Stamps are event times
in ns.

Configuration: the one recorded in the run's ``poseidon`` metadata (``config``), unless one
is given; the defaults when the recording has none; ``config_source`` says which was used.
``metadata`` holds every field of the ``poseidon`` record, JSON values decoded.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydantic import ValidationError

from common.codec import DecodeError, decode
from common.config import ConfigError, migrate_renamed
from common.geometry import published_to_ned, yaw_of_quaternion
from common.live import LATENCY_KEY
from common.mcap_io import RecordedMessage, RecordingError, read_messages, read_metadata
from common.messages import (
    ExperienceEvent,
    ExperienceImage,
    ExperienceMap,
    LatencyReport,
    LocalViewCells,
    MapSessions,
    Message,
    NeocortexSdr,
    Odometry,
    PoseStamped,
    RevisitTruth,
    ScanPose,
    message_type,
)
from eval.trajectory import PoseSeries, Trajectory, pose_series
from system.config import PoseidonConfig, load_config

__all__ = ["RunData", "EvidenceRecord", "SdrRecord", "DECODED", "load_run", "config_of_recording",
           "metadata_of_recording", "add_config_args", "config_from_args", "report_cli"]

#: keys decoded into messages (every other key is only counted and its header seq kept; ``map`` is
#: decoded for its last message only, like ``map_sessions``; ``experience_image`` without keeping its pixels)
DECODED = ("truth/pose", "truth/revisits", "local_view_cells", "Odometry", "experience_event", "wheel_odometry",
           "dead_reckoning", "neocortex/sdr", "scan_pose")


@dataclass(frozen=True)
class EvidenceRecord:
    """An ``experience_image`` without its pixels: header seq, stamp (ns) and the stamp of
    the camera frame used as evidence (ns)."""

    seq: int
    stamp: int
    source_stamp: int


@dataclass(frozen=True)
class SdrRecord:
    """The fused SDR of one ``neocortex/sdr`` message: header stamp (ns), sorted active bit
    indices (int64) and the SDR size (bits)."""

    stamp: int
    active: np.ndarray
    size: int


@dataclass
class RunData:
    """One run recording, decoded once (module docstring)."""

    path: Path
    config: PoseidonConfig
    config_source: str
    metadata: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    seqs: dict[str, list[int]] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    truth: Trajectory | None = None  # truth/pose (NED)
    revisits: dict[int, RevisitTruth] = field(default_factory=dict)
    camera_stamps: list[int] = field(default_factory=list)
    lvcs: list[LocalViewCells] = field(default_factory=list)
    odometry: Trajectory | None = None  # Odometry, taken to NED
    dead_reckoning: Trajectory | None = None  # dead_reckoning, taken to NED
    odometry_poses: PoseSeries | None = None  # Odometry as published (frame, quaternions kept)
    wheel_odometry: PoseSeries | None = None  # wheel_odometry (e.g. a CARMEN import), as recorded
    events: list[ExperienceEvent] = field(default_factory=list)
    images: list[EvidenceRecord] = field(default_factory=list)
    sdrs: list[SdrRecord] = field(default_factory=list)
    final_map: ExperienceMap | None = None
    map_messages: int = 0
    scan_poses: list[ScanPose] = field(default_factory=list)  # scan_pose (a laser map's registered scans)
    final_sessions: MapSessions | None = None  # the last map_sessions (a map of several sessions)
    latency: LatencyReport | None = None  # live/latency: a live run's latency per stage (common.live)
    truth_yaw: np.ndarray | None = None  # truth/pose yaw (NED, rad) at ``truth`` stamps

    @property
    def loaded_nodes(self) -> int:
        """Map nodes loaded from an earlier mission's map (their stamps are that mission's)."""
        return self.final_sessions.loaded_nodes if self.final_sessions is not None else 0

    @property
    def duration_s(self) -> float:
        """First to last message stamp of any key (s)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def has_truth(self) -> bool:
        """True when the run carries at least one ``truth/pose``."""
        return self.truth is not None and len(self.truth) > 0

    def to_ned(self, positions: np.ndarray) -> np.ndarray:
        """Published-frame positions (Odometry, map nodes) -> NED, with this run's remap."""
        rs = self.config.robot_state
        return published_to_ned(positions, rs.axis_remap, rs.axis_sign_z)


def metadata_of_recording(path: str | Path) -> dict[str, Any]:
    """The recording's ``poseidon`` metadata record, JSON values decoded (plain strings kept as
    they are, see ``RecordingWriter.add_metadata``)."""
    out: dict[str, Any] = {}
    for k, v in read_metadata(path).get("poseidon", {}).items():
        try:
            out[k] = json.loads(v)
        except (json.JSONDecodeError, TypeError):
            out[k] = v
    return out


def _config_of_metadata(path: str | Path, meta: dict[str, Any]) -> PoseidonConfig | None:
    raw = meta.get("config")
    if raw is None:
        return None
    try:   # a recording of an older version stores keys renamed since: read under their new names
        return PoseidonConfig.model_validate(migrate_renamed(json.loads(raw) if isinstance(raw, str) else raw))
    except (ValueError, ValidationError) as exc:
        raise RecordingError(f"{path}: metadata 'poseidon' field 'config' is not a valid configuration: "
                             f"{exc}") from None


def config_of_recording(path: str | Path) -> PoseidonConfig | None:
    """The configuration stored in a recording's ``poseidon`` metadata, or None when absent.

    Raises :class:`RecordingError` (naming the file) when it is present but invalid.
    """
    return _config_of_metadata(path, metadata_of_recording(path))


def _decode(rec: RecordedMessage, path: Path) -> Message:
    try:
        return decode(rec.payload, message_type(rec.type_name))
    except (DecodeError, KeyError) as exc:
        raise RecordingError(f"{path}: key {rec.key!r} message seq {rec.seq} stamped {rec.stamp}: {exc}") from None


def _poses(msgs: list[Odometry], path: Path, key: str) -> PoseSeries:
    try:
        return pose_series(msgs)
    except ValueError as exc:  # a zero quaternion
        raise RecordingError(f"{path}: key {key!r}: {exc}") from None


class _Reader:
    """The messages of one pass, kept until :meth:`finish` builds the trajectories."""

    def __init__(self, run: RunData) -> None:
        self.run = run
        self.truth: list[Odometry | PoseStamped] = []
        self.odom: list[Odometry] = []
        self.dead_reckoning: list[Odometry | PoseStamped] = []
        self.wheel: list[Odometry] = []
        self.last_map: RecordedMessage | None = None
        self.last_sessions: RecordedMessage | None = None

    def add(self, rec: RecordedMessage) -> None:
        run, p = self.run, self.run.path
        run.counts[rec.key] = run.counts.get(rec.key, 0) + 1
        run.seqs.setdefault(rec.key, []).append(rec.seq)
        run.start_ns = rec.stamp if run.start_ns is None else min(run.start_ns, rec.stamp)
        run.end_ns = rec.stamp if run.end_ns is None else max(run.end_ns, rec.stamp)
        if rec.key == "camera/image_raw":
            run.camera_stamps.append(rec.stamp)
        elif rec.key == "map":
            self.last_map = rec
            run.map_messages += 1
        elif rec.key == "map_sessions":
            self.last_sessions = rec
        elif rec.key == LATENCY_KEY:
            m = _decode(rec, p)
            assert isinstance(m, LatencyReport)
            run.latency = m
        elif rec.key == "experience_image":
            m = _decode(rec, p)
            assert isinstance(m, ExperienceImage)
            run.images.append(EvidenceRecord(m.header.seq, m.header.stamp, m.source_stamp))
        elif rec.key in DECODED:
            self._decoded(rec.key, _decode(rec, p))

    def _decoded(self, key: str, m: Message) -> None:
        run = self.run
        if key == "truth/revisits":
            assert isinstance(m, RevisitTruth)
            run.revisits[m.frame_index] = m
        elif key == "local_view_cells":
            run.lvcs.append(m)  # type: ignore[arg-type]
        elif key == "experience_event":
            run.events.append(m)  # type: ignore[arg-type]
        elif key == "scan_pose":
            run.scan_poses.append(m)  # type: ignore[arg-type]
        elif key == "neocortex/sdr":
            assert isinstance(m, NeocortexSdr)
            run.sdrs.append(SdrRecord(m.header.stamp, np.asarray(m.fused.active, dtype=np.int64), m.fused.size))
        else:
            # poses need an orientation; truth and dead reckoning only a position
            want: tuple[type[Message], ...] = (Odometry,) if key in ("Odometry", "wheel_odometry") else \
                (Odometry, PoseStamped)
            if not isinstance(m, want):
                raise RecordingError(f"{run.path}: key {key!r} carries {m.type_name}, not "
                                     f"{' or '.join(w.type_name for w in want)}")
            lists: dict[str, list[Any]] = {"truth/pose": self.truth, "Odometry": self.odom,
                                           "dead_reckoning": self.dead_reckoning, "wheel_odometry": self.wheel}
            lists[key].append(m)

    def _published(self, msgs: Sequence[Odometry | PoseStamped], key: str) -> Trajectory:
        return Trajectory([m.header.stamp for m in msgs], self.run.to_ned(np.array([m.position for m in msgs])),
                          source=key)

    def finish(self) -> RunData:
        run, p = self.run, self.run.path
        if self.truth:
            # truth/pose is NED already (missions/sim: "world NED")
            run.truth = Trajectory([m.header.stamp for m in self.truth], [m.position for m in self.truth],
                                   source="truth/pose")
            run.truth_yaw = np.array([yaw_of_quaternion(m.orientation) if isinstance(m, Odometry) else math.nan
                                      for m in self.truth])
        if self.odom:
            run.odometry = self._published(self.odom, "Odometry")
            run.odometry_poses = _poses(self.odom, p, "Odometry")
        if self.dead_reckoning:
            run.dead_reckoning = self._published(self.dead_reckoning, "dead_reckoning")
        if self.wheel:
            run.wheel_odometry = _poses(self.wheel, p, "wheel_odometry")
        if self.last_map is not None:
            m = _decode(self.last_map, p)
            assert isinstance(m, ExperienceMap)
            run.final_map = m
        if self.last_sessions is not None:
            s = _decode(self.last_sessions, p)
            assert isinstance(s, MapSessions)
            run.final_sessions = s
        return run


def load_run(path: str | Path, config: PoseidonConfig | None = None, keys: Sequence[str] | None = None) -> RunData:
    """Read ``path`` once (see the module docstring); ``config`` replaces the recorded one;
    ``keys`` limits the pass to those keys (counts and stamps then cover only them).

    :raises RecordingError: unreadable recording, undecodable message or invalid recorded
        configuration (the message names the file).
    """
    p = Path(path)
    metadata = metadata_of_recording(p)
    source = "given"
    if config is None:
        config = _config_of_metadata(p, metadata)
        source = "recording"
        if config is None:
            config, source = PoseidonConfig(), "defaults"
    reader = _Reader(RunData(path=p, config=config, config_source=source, metadata=metadata))
    for rec in read_messages(p, keys=None if keys is None else list(keys)):
        reader.add(rec)
    return reader.finish()


def add_config_args(ap: argparse.ArgumentParser) -> None:
    """``--config FILE`` / ``--set K=V`` of the evaluation commands."""
    ap.add_argument("--config", type=Path, default=None,
                    help="configuration YAML to judge with instead of the one recorded in the run")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="K=V",
                    help="override one field (implies --config defaults when no file is given)")


def config_from_args(args: argparse.Namespace) -> PoseidonConfig | None:
    """The configuration named by ``--config``/``--set``, or None (use the recorded one)."""
    if args.config is None and not args.overrides:
        return None
    return load_config(args.config, args.overrides)


_Result = TypeVar("_Result")


def report_cli(command: str, compute: Callable[[], _Result], fmt: Callable[[_Result], list[str]],
               as_json: bool) -> int:
    """The common tail of the evaluation commands: ``compute()``, then the result as JSON or
    as text lines; a bad recording, configuration or value is exit 2 with ``poseidon COMMAND:``."""
    try:
        result = compute()
    except (RecordingError, ConfigError, ValueError) as exc:
        print(f"poseidon {command}: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2) if as_json else "\n".join(fmt(result)))
    return 0
