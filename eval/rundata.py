"""One pass over a run recording: everything the evaluation modules need, decoded once.

:func:`load_run` reads an MCAP recording (``poseidon run`` output, or any recording with
some of the keys below) and returns a :class:`RunData`.  Only the keys the metrics use are
decoded; the heavy ones are reduced on the way (camera frames to their stamps,
``experience_image`` to header + ``source_stamp``, ``map`` to its last message;
``Odometry`` and ``wheel_odometry`` are also kept as published poses for the relation
error, :mod:`eval.relations`).  The
configuration is the one recorded in the run's ``poseidon`` metadata (``config``), unless
one is given; ``config_source`` says which was used.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable
import numpy as np
from pydantic import ValidationError

from common.codec import DecodeError, decode
from common.config import ConfigError, PoseidonConfig, load_config
from common.mcap_io import RecordedMessage, RecordingError, read_messages, read_metadata
from common.messages import (ExperienceEvent, ExperienceImage, ExperienceMap, LocalViewCells, Message, Odometry,
                             RevisitTruth, message_type)
from eval.corrected import PoseSeries, pose_series
from eval.trajectory import Trajectory, published_to_ned

__all__ = ["RunData", "EvidenceRecord", "load_run", "config_of_recording", "add_config_args", "config_from_args"]

#: keys decoded into messages (every other key is only counted and its header seq kept)
DECODED = ("truth/pose", "truth/revisits", "local_view_cells", "Odometry", "experience_event", "wheel_odometry")


@dataclass(frozen=True)
class EvidenceRecord:
    """An ``experience_image`` without its pixels: header seq, stamp (ns) and the stamp of
    the camera frame used as evidence (ns)."""

    seq: int
    stamp: int
    source_stamp: int


@dataclass
class RunData:
    path: Path
    config: PoseidonConfig
    config_source: str
    counts: dict[str, int] = field(default_factory=dict)
    seqs: dict[str, list[int]] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    truth: Trajectory | None = None
    revisits: dict[int, RevisitTruth] = field(default_factory=dict)
    camera_stamps: list[int] = field(default_factory=list)
    lvcs: list[LocalViewCells] = field(default_factory=list)
    odometry: Trajectory | None = None
    odometry_poses: PoseSeries | None = None  # Odometry as published (frame, quaternions kept)
    wheel_odometry: PoseSeries | None = None  # wheel_odometry (e.g. a CARMEN import), as recorded
    events: list[ExperienceEvent] = field(default_factory=list)
    images: list[EvidenceRecord] = field(default_factory=list)
    final_map: ExperienceMap | None = None
    map_messages: int = 0

    @property
    def duration_s(self) -> float:
        """First to last message stamp of any key (s)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def has_truth(self) -> bool:
        return self.truth is not None and len(self.truth) > 0

    def to_ned(self, positions: np.ndarray) -> np.ndarray:
        """Published-frame positions (Odometry, map nodes) -> NED, with this run's remap."""
        rs = self.config.robot_state
        return published_to_ned(positions, rs.axis_remap, rs.axis_sign_z)


def config_of_recording(path: str | Path) -> PoseidonConfig | None:
    """The configuration stored in a recording's ``poseidon`` metadata, or None when absent.

    Raises :class:`RecordingError` (naming the file) when it is present but invalid.
    """
    meta = read_metadata(path).get("poseidon", {})
    raw = meta.get("config")
    if raw is None:
        return None
    try:
        return PoseidonConfig.model_validate(json.loads(raw) if isinstance(raw, str) else raw)
    except (ValueError, ValidationError) as exc:
        raise RecordingError(f"{path}: metadata 'poseidon' field 'config' is not a valid configuration: {exc}") from None


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


def load_run(path: str | Path, config: PoseidonConfig | None = None) -> RunData:
    """Read ``path`` once (see the module docstring)."""
    p = Path(path)
    source = "given"
    if config is None:
        config = config_of_recording(p)
        source = "recording"
        if config is None:
            config, source = PoseidonConfig(), "defaults"
    run = RunData(path=p, config=config, config_source=source)
    poses: list[Odometry] = []
    odom: list[Odometry] = []
    wheel: list[Odometry] = []
    last_map: RecordedMessage | None = None
    for rec in read_messages(p):
        run.counts[rec.key] = run.counts.get(rec.key, 0) + 1
        run.seqs.setdefault(rec.key, []).append(rec.seq)
        run.start_ns = rec.stamp if run.start_ns is None else min(run.start_ns, rec.stamp)
        run.end_ns = rec.stamp if run.end_ns is None else max(run.end_ns, rec.stamp)
        if rec.key == "camera/image_raw":
            run.camera_stamps.append(rec.stamp)
        elif rec.key == "map":
            last_map = rec
            run.map_messages += 1
        elif rec.key == "experience_image":
            m = _decode(rec, p)
            assert isinstance(m, ExperienceImage)
            run.images.append(EvidenceRecord(m.header.seq, m.header.stamp, m.source_stamp))
        elif rec.key in DECODED:
            m = _decode(rec, p)
            if rec.key == "truth/pose":
                poses.append(m)  # type: ignore[arg-type]
            elif rec.key == "truth/revisits":
                assert isinstance(m, RevisitTruth)
                run.revisits[m.frame_index] = m
            elif rec.key == "local_view_cells":
                run.lvcs.append(m)  # type: ignore[arg-type]
            elif rec.key == "Odometry":
                odom.append(m)  # type: ignore[arg-type]
            elif rec.key == "wheel_odometry":
                wheel.append(m)  # type: ignore[arg-type]
            else:
                run.events.append(m)  # type: ignore[arg-type]
    if poses:
        # truth/pose is NED already (missions/sim: "world NED")
        run.truth = Trajectory([m.header.stamp for m in poses], [m.position for m in poses])
    if odom:
        run.odometry = Trajectory([m.header.stamp for m in odom], run.to_ned(np.array([m.position for m in odom])))
        run.odometry_poses = _poses(odom, p, "Odometry")
    if wheel:
        run.wheel_odometry = _poses(wheel, p, "wheel_odometry")
    if last_map is not None:
        m = _decode(last_map, p)
        assert isinstance(m, ExperienceMap)
        run.final_map = m
    return run



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


def report_cli(command: str, compute: Callable[[], dict[str, Any]], fmt: Callable[[dict[str, Any]], list[str]],
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
