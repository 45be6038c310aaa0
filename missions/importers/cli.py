"""``poseidon import SRC [SRC ...] --out FILE.mcap [--topic TOPIC=KEY ...] [--topic-map FILE.yaml] [--json]``.

Sources, merged into one recording in chronological order (the camera bag and the
sensor bag of the caves dataset become one recording):

- ROS1 ``.bag``; ROS2 bag folders (``metadata.yaml``) or their ``.db3`` / ``.mcap`` file
  (type mapping: :mod:`missions.importers.rosbags_io`);
- rostopic-echo CSV logs (``.csv``; kind detected from the columns, key = kind:
  ``dvl_linkquest``, ``depth_sensor``, ``imu_adis``; :mod:`missions.importers.rostopic_csv`);
- a folder of image frames (key ``camera/image_raw``; :mod:`missions.importers.frames`): stamped
  by its timestamps file, or without one in file-name order at ``--frame-rate`` frames/s
  (default 1); the metadata keeps the frames' file names in order (``frames``);
- a CARMEN robot log (``.clf``, ``.clf.bz2``, ``.clf.gz``; :mod:`missions.importers.carmen`,
  which documents its mapping and its own ``--json`` keys): imported on its own, not
  merged with other sources; ``--topic-map``, ``--raw`` and ``--frames-timestamps`` do
  not apply to it.  Exit 1 when a line was rejected, as for a bag's unreadable records.

Topics map to keys by :data:`~missions.importers.rosbags_io.DEFAULT_TOPIC_MAP`, other
topics to the topic without its leading slash.  ``--topic TOPIC=KEY`` (repeatable) imports a
bag topic under one of our keys, e.g. ``--topic /imu/data=imu_adis_ros`` for a robot whose IMU
is not named as the services expect (``poseidon run`` names the mapping a recording needs);
a key the services read (:data:`common.messages.KEYS`) takes only a topic whose type converts
to that key's message, else the import stops (exit 2) naming both.  ``--topic-map`` is a YAML
mapping ``topic: key`` (overrides; ``topic: null`` drops a topic); ``--topic`` wins over it.
The recording's ``poseidon`` metadata keeps the sources, the topic map and each bag topic's
ROS type and key (``topics``).

Nothing is lost: a message whose type has a model (table in
:mod:`missions.importers.rosbags_io`) is converted; any other message -- a type without a
model, a payload that does not decode against its own definition, or content with no
lossless conversion (e.g. an image encoding we do not model) -- is *carried raw*: its
serialised bytes, ROS type and message definition as a :class:`common.messages.RawMessage`
on the key ``raw/<key>`` (``/vendor/status`` -> ``raw/vendor/status``), which the player
replays and ``poseidon export`` writes back byte for byte.  ``--raw TOPIC`` (repeatable,
``'*'`` = all) carries a topic raw even when a model exists.  Only records the bag reader
cannot read at all (a corrupt chunk) are *rejected*, with the reason and where: in a ROS 1
bag the chunk's byte offset, and reading goes on after that chunk; in a ROS 2 bag the rest of
the bag after the last readable message.  The import keeps everything else and exits with 1.

``--json`` summary keys: ``out``; ``inputs`` (path, format, per-topic type and count in
the source); ``read`` (messages read per topic / CSV key / frames key); ``written``
(messages written per key); ``topics`` (bag topic -> ``type``, ``key``, ``in_source``
(the bag's own count), ``read``, ``mapped``, ``raw``, ``dropped``, ``raw_key``,
``rejected``, ``raw_reasons`` (reason -> count), ``as``: the non-zero ones of ``mapped``,
``raw``, ``dropped``, ``rejected`` joined by ``+``); ``dropped_topics`` (topic -> count,
dropped by the topic map); ``rejected`` (list of ``{paths, reason, after_messages, offset:
{byte (ROS 1: the unreadable chunk), message_index, bag_time_ns (last good message)},
messages: {topic: count} or "the rest of the bag"}``);
``start_ns``, ``end_ns``, ``duration_s``.
"""
from __future__ import annotations

import argparse
import heapq
import json
import logging
import struct
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError
from tqdm import tqdm

from common.mcap_io import RecordingWriter
from common.messages import KEYS, RAW_KEY_PREFIX, Message
from common.ros_convert import key_of, raw_message, stamped_header
from missions.importers import frames as frames_mod
from missions.importers.carmen import import_carmen, is_carmen_log
from missions.importers.errors import InputFormatError
from missions.importers.rosbags_io import (
    CONVERTERS,
    DEFAULT_TOPIC_MAP,
    ConversionError,
    connection_definition,
    iter_bag,
    normalise_type,
    open_bags,
)
from missions.importers.rostopic_csv import read_rostopic_csv

__all__ = ["main", "import_sources", "load_topic_map", "parse_topic_args"]

log = logging.getLogger(__name__)


def load_topic_map(path: str | Path | None) -> dict[str, str | None]:
    """The default topic map updated with a YAML ``topic: key`` mapping."""
    tm: dict[str, str | None] = dict(DEFAULT_TOPIC_MAP)
    if path is None:
        return tm
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except FileNotFoundError:
        raise InputFormatError(f"{p}: no such topic map") from None
    except yaml.YAMLError as exc:
        raise InputFormatError(f"{p}: not valid YAML: {exc}") from None
    if data is None:
        return tm
    if not isinstance(data, dict):
        raise InputFormatError(f"{p}: the topic map must be a mapping 'topic: key', got {type(data).__name__}")
    for topic, key in data.items():
        if key is not None and (not isinstance(key, str) or not key or key.startswith("/")):
            raise InputFormatError(f"{p}: topic {topic!r}: key must be a non-empty string without a leading "
                                   f"slash or null, got {key!r}")
        tm[str(topic)] = key
    return tm


def parse_topic_args(pairs: list[str]) -> dict[str, str]:
    """``--topic TOPIC=KEY`` arguments as ``{topic: key}``; :class:`InputFormatError` naming a bad one."""
    out: dict[str, str] = {}
    for pair in pairs:
        topic, sep, key = pair.partition("=")
        topic, key = topic.strip(), key.strip()
        if not sep or not topic or not key or key.startswith("/"):
            raise InputFormatError(f"--topic {pair!r}: give TOPIC=KEY, e.g. --topic /imu/data=imu_adis_ros "
                                   f"(KEY without a leading slash)")
        out[topic if topic.startswith("/") else "/" + topic] = key
    return out


def _check_key_type(topic: str, key: str, msg: Message) -> None:
    """A message for one of the services' keys must be that key's type (:data:`common.messages.KEYS`)."""
    want = KEYS.get(key)
    if want is not None and not isinstance(msg, want):
        raise InputFormatError(f"topic {topic} converts to {type(msg).__name__}, but key {key!r} carries "
                               f"{want.__name__}; map it to a key of that type")


class _Stats:
    def __init__(self) -> None:
        self.inputs: list[dict[str, Any]] = []
        self.read: dict[str, int] = {}
        self.dropped: dict[str, int] = {}
        self.topics: dict[str, dict[str, Any]] = {}
        self.rejected: list[dict[str, Any]] = []

    def bump(self, d: dict[str, int], k: str) -> None:
        d[k] = d.get(k, 0) + 1

    def topic(self, topic: str, msgtype: str, key: str | None) -> dict[str, Any]:
        t = self.topics.get(topic)
        if t is None:
            t = self.topics[topic] = {"type": msgtype, "key": key, "in_source": 0, "read": 0, "mapped": 0, "raw": 0,
                                      "dropped": 0, "rejected": 0, "raw_key": None, "raw_reasons": {}}
        return t


def _bag_stream(paths: list[Path], tm: dict[str, str | None], stats: _Stats,
                raw_topics: set[str] | None) -> Iterator[tuple[int, int, str, Message]]:
    """Every message of the bags: converted to our model when a converter exists (and the topic
    is not in ``raw_topics``; ``{"*"}`` = all), else carried raw on ``raw/<key>``."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Rosbag1Error
    from rosbags.rosbag2 import ReaderError as Rosbag2Error

    reader, info = open_bags(paths)
    topics: dict[str, dict[str, Any]] = {}
    for c in reader.connections:
        t = topics.setdefault(c.topic, {"type": c.msgtype, "count": 0})
        t["count"] += c.msgcount
        stats.topic(c.topic, normalise_type(c.msgtype), key_of(c.topic, tm))["in_source"] += c.msgcount
    stats.inputs.append({"paths": info["paths"], "format": info["kind"], "topics": topics})
    seqs: dict[str, int] = {}
    definitions: dict[int, tuple[str, str, str]] = {}
    force_all = raw_topics is not None and "*" in raw_topics
    n = 0
    last_ns: int | None = None
    start: int | None = None
    try:
        while True:
            try:
                for bm in iter_bag(reader, start):
                    n += 1
                    last_ns = bm.record_ns
                    yield from _one_bag_message(bm, reader, tm, stats, raw_topics, force_all, seqs, definitions)
                break
            except (AnyReaderError, Rosbag1Error, Rosbag2Error, struct.error, EOFError) as exc:
                reason = f"{type(exc).__name__}: {exc} (truncated or corrupt bag?)"
                bad = None if reader.is2 else _bad_ros1_chunk(reader, last_ns)
                if bad is None:  # ROS 2, or no index to step over the damage: the rest is rejected
                    stats.rejected.append({"paths": info["paths"], "reason": reason, "after_messages": n,
                                           "offset": {"message_index": n, "bag_time_ns": last_ns},
                                           "messages": "the rest of the bag"})
                    log.error("import: %s: unreadable after %d messages (bag time %s ns): %s; the rest is rejected",
                              ", ".join(info["paths"]), n, last_ns, reason)
                    break
                path, pos, end_ns, lost = bad
                stats.rejected.append({"paths": [path], "reason": reason, "after_messages": n,
                                       "offset": {"byte": pos, "message_index": n, "bag_time_ns": last_ns},
                                       "messages": lost})
                for topic, k in lost.items():
                    stats.topic(topic, "", key_of(topic, tm))["rejected"] += k
                log.error("import: %s: chunk at byte %d unreadable (%s); its messages up to bag time %d ns are "
                          "rejected (%s), reading on after it", path, pos, reason, end_ns, lost)
                start = end_ns + 1
    finally:
        reader.close()


def _bad_ros1_chunk(reader: Any, last_ns: int | None) -> tuple[str, int, int, dict[str, int]] | None:
    """The ROS 1 chunk holding the first message after ``last_ns`` (the one that failed):
    (bag path, byte offset of the chunk, its end time, messages per topic skipped by resuming
    after it -- every indexed message in (last_ns, end time], of any chunk)."""
    after = -1 if last_ns is None else last_ns
    best = None
    for r in getattr(reader, "readers", []):
        for entries in getattr(r, "indexes", {}).values():
            e = next((x for x in entries if x.time > after), None)  # entries are sorted by time
            if e is not None and (best is None or e.time < best[1].time):
                best = (r, e)
    if best is None:
        return None
    r, e = best
    info = next((c for c in r.chunk_infos if c.pos == e.chunk_pos), None)
    if info is None:
        return None
    lost: dict[str, int] = {}
    for rr in reader.readers:
        topic_of = {c.id: c.topic for c in rr.connections}
        for cid, entries in rr.indexes.items():
            k = sum(1 for x in entries if after < x.time <= info.end_time)
            if k:
                lost[topic_of[cid]] = lost.get(topic_of[cid], 0) + k
    return str(r.path), int(e.chunk_pos), int(info.end_time), lost


def _one_bag_message(bm: Any, reader: Any, tm: dict[str, str | None], stats: _Stats, raw_topics: set[str] | None,
                     force_all: bool, seqs: dict[str, int],
                     definitions: dict[int, tuple[str, str, str]]) -> Iterator[tuple[int, int, str, Message]]:
    """The one recording entry of a bag message: mapped, carried raw, or none (dropped)."""
    stats.bump(stats.read, bm.topic)
    key = key_of(bm.topic, tm)
    ts = stats.topic(bm.topic, bm.msgtype, key)
    ts["read"] += 1
    if key is None:
        stats.bump(stats.dropped, bm.topic)
        ts["dropped"] += 1
        return
    conv = CONVERTERS.get(bm.msgtype)
    if force_all or (raw_topics is not None and bm.topic in raw_topics):
        conv, why = None, "carried raw on request (--raw)"
    else:
        why = f"no model for {bm.msgtype}"
    ros: Any = None
    try:
        ros = reader.deserialize(bm.raw, bm.connection.msgtype)
    except Exception as exc:
        conv, why = None, f"payload does not decode against its definition: {type(exc).__name__}: {exc}"
    if conv is not None:
        header = stamped_header(ros, bm.msgtype, bm.record_ns, seqs, key)
        try:
            msg = conv(ros, header)
        except (ConversionError, ValidationError, TypeError, ValueError) as exc:
            why = f"no lossless conversion to our model: {str(exc).splitlines()[0]}"
        else:
            if not ts["mapped"]:
                _check_key_type(bm.topic, key, msg)
            ts["mapped"] += 1
            yield bm.record_ns, 0, key, msg
            return
    # carried raw: the serialised bytes and the definition, unchanged
    raw_key = RAW_KEY_PREFIX + key
    d = definitions.get(bm.connection.id)
    if d is None:
        d = definitions[bm.connection.id] = connection_definition(reader, bm.connection)
    seq = seqs.get(raw_key, 0)
    seqs[raw_key] = seq + 1
    ts["raw"] += 1
    ts["raw_key"] = raw_key
    ts["raw_reasons"][why] = ts["raw_reasons"].get(why, 0) + 1
    yield bm.record_ns, 0, raw_key, raw_message(bm.topic, bm.connection.msgtype, bm.raw, ros, d, reader.is2,
                                                   bm.record_ns, seq)


def _list_stream(items: list[tuple[str, Message]], order: int) -> Iterator[tuple[int, int, str, Message]]:
    for key, msg in sorted(items, key=lambda km: km[1].header.stamp):
        yield msg.header.stamp, order, key, msg


def _frames_stream(plan: list[tuple[int, int, Path]], order: int) -> Iterator[tuple[int, int, str, Message]]:
    for stamp, key, img in frames_mod.iter_frames(plan):
        yield stamp, order, key, img


def import_sources(sources: list[str | Path], out: str | Path, topic_map: dict[str, str | None] | None = None,
                   frames_timestamps: str | Path | None = None, progress: bool = True,
                   raw_topics: set[str] | None = None, frame_rate: float | None = None) -> dict[str, Any]:
    """Import every source into one recording at ``out``; returns the summary (see module doc).
    ``raw_topics``: bag topics carried raw even when a model exists (``{"*"}``: every topic);
    ``frame_rate``: frames/s of a frames folder without a timestamps file."""
    tm: dict[str, str | None] = topic_map if topic_map is not None else dict(DEFAULT_TOPIC_MAP)
    stats = _Stats()
    bags: list[Path] = []
    streams: list[Iterator[tuple[int, int, str, Message]]] = []
    frame_names: list[tuple[int, str]] = []
    if not sources:
        raise InputFormatError("no sources given")
    for i, s in enumerate(sources):
        p = Path(s)
        if not p.exists():
            raise InputFormatError(f"{p}: no such file or folder")
        if p.is_file() and p.suffix.lower() == ".csv":
            recs = read_rostopic_csv(p)
            key0 = recs[0][0] if recs else p.stem
            key = key_of("/" + key0, tm) if ("/" + key0) in tm else key0
            stats.inputs.append({"paths": [str(p)], "format": "rostopic_csv", "topics": {key0: {"type": key0, "count": len(recs)}}})
            stats.read[key0] = stats.read.get(key0, 0) + len(recs)
            if key is None:
                stats.dropped[key0] = len(recs)
                continue
            streams.append(_list_stream([(key, m) for _, m in recs], i + 1))
        elif p.is_dir() and not (p / "metadata.yaml").exists():
            plan = frames_mod.frames_plan(p, frames_timestamps, frame_rate)
            frame_names += [(stamp, path.name) for stamp, _seq, path in plan]
            stats.inputs.append({"paths": [str(p)], "format": "frames", "topics": {"camera/image_raw": {"type": "image", "count": len(plan)}}})
            stats.read["camera/image_raw"] = stats.read.get("camera/image_raw", 0) + len(plan)
            streams.append(_frames_stream(plan, i + 1))
        else:
            bags.append(p)
    if bags:
        ros1 = [b for b in bags if b.suffix.lower() == ".bag"]
        ros2 = [b for b in bags if b.suffix.lower() != ".bag"]
        if ros1:
            streams.append(_bag_stream(ros1, tm, stats, raw_topics))
        if ros2:
            streams.append(_bag_stream(ros2, tm, stats, raw_topics))
    out = Path(out)
    part = out.with_name(out.name + ".part")  # renamed on success, removed on failure
    writer = RecordingWriter(part)
    first = last = None
    bar = tqdm(desc="import", unit="msg", disable=not progress)
    ok = False
    try:
        for _, _, key, msg in heapq.merge(*streams, key=lambda x: (x[0], x[1])):
            writer.write(key, msg)
            st = msg.header.stamp
            first = st if first is None else min(first, st)
            last = st if last is None else max(last, st)
            bar.update(1)
        writer.add_metadata("poseidon", {"tool": "poseidon import", "sources": [str(s) for s in sources],
                                         "topic_map": tm, "topics": {t: {"type": v["type"], "key": v["key"]}
                                                                     for t, v in sorted(stats.topics.items())},
                                         **({"frames": [n for _s, n in sorted(frame_names)]} if frame_names else {})})
        ok = True
    finally:
        bar.close()
        writer.close()
        if ok:
            part.replace(out)
        else:
            part.unlink(missing_ok=True)
    topics = {}
    for topic, t in sorted(stats.topics.items()):
        t = dict(t)
        t["as"] = "+".join(k for k in ("mapped", "raw", "dropped", "rejected") if t[k]) or "none"
        topics[topic] = t
    return {
        "out": str(out), "inputs": stats.inputs, "read": dict(sorted(stats.read.items())),
        "written": dict(sorted(writer.counts.items())), "topics": topics, "dropped_topics": stats.dropped,
        "rejected": stats.rejected, "start_ns": first, "end_ns": last,
        "duration_s": (last - first) / 1e9 if first is not None and last is not None else 0.0,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon import", description=__doc__.split("\n\n")[0])
    ap.add_argument("sources", nargs="+",
                    help="ROS1 .bag, ROS2 bag folder/.db3/.mcap, rostopic CSV, frames folder, or one CARMEN log "
                         "(.clf, .clf.bz2, .clf.gz)")
    ap.add_argument("--out", required=True, help="output MCAP recording")
    ap.add_argument("--topic", action="append", default=[], metavar="TOPIC=KEY",
                    help="import bag topic TOPIC under our key KEY, e.g. --topic /imu/data=imu_adis_ros (repeatable)")
    ap.add_argument("--topic-map", default=None, help="YAML mapping 'topic: key' (null drops a topic)")
    ap.add_argument("--frames-timestamps", default=None, help="timestamps file of a frames folder")
    ap.add_argument("--frame-rate", type=float, default=None, metavar="HZ",
                    help="frames/s of a frames folder without a timestamps file: frames in file-name order (default 1)")
    ap.add_argument("--raw", action="append", default=None, metavar="TOPIC",
                    help="carry this bag topic raw (bytes + definition) even when a model exists; '*' = every topic "
                         "(repeatable)")
    ap.add_argument("--json", action="store_true", help="print the JSON summary on stdout")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if any(is_carmen_log(s) for s in args.sources):
        return _main_carmen(ap, args)
    try:
        topic_map = {**load_topic_map(args.topic_map), **parse_topic_args(args.topic)}
        summary = import_sources(args.sources, args.out, topic_map, args.frames_timestamps,
                                 progress=not args.no_progress, raw_topics=set(args.raw) if args.raw else None,
                                 frame_rate=args.frame_rate)
    except InputFormatError as exc:
        print(f"poseidon import: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        raw = {t: v["raw"] for t, v in summary["topics"].items() if v["raw"]}
        print(f"wrote {args.out}: {sum(summary['written'].values())} messages {summary['written']}; "
              f"carried raw (no model or no lossless conversion) {raw}; rejected {summary['rejected']}",
              file=sys.stderr)
    return 1 if summary["rejected"] else 0


def _main_carmen(ap: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``poseidon import LOG.clf[.bz2|.gz] --out FILE.mcap``: one CARMEN log on its own."""
    if len(args.sources) != 1:
        ap.error(f"a CARMEN log is imported on its own, got {len(args.sources)} sources: {args.sources}")
    if args.topic_map or args.topic or args.raw or args.frames_timestamps or args.frame_rate:
        ap.error("--topic, --topic-map, --raw, --frames-timestamps and --frame-rate do not apply to a CARMEN log")
    try:
        summary = import_carmen(args.sources[0], args.out)
    except InputFormatError as exc:
        print(f"poseidon import: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(f"wrote {args.out}: {sum(summary['written'].values())} messages {summary['written']} from "
              f"{summary['lines']} lines (odometry from {summary['odometry_from']}); "
              f"{len(summary['rejected'])} lines rejected, unknown types {summary['unknown']}", file=sys.stderr)
        for r in summary["rejected"][:10]:
            print(f"  {args.sources[0]}:{r['line']}: {r['type']}: {r['reason']}", file=sys.stderr)
    return 1 if summary["rejected"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
