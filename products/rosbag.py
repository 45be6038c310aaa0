"""A PoseidonSLAM recording -> ROS 2 bag (CDR, sqlite3) or ROS 1 bag (via rosbags).

Topic of a message = ``/`` + its key (``camera/image_raw`` -> ``/camera/image_raw``); a
raw-carried message (key ``raw/...``) goes back to its original topic with its original
type.  Bag time = the message's event time (header stamp).  Types: see
:mod:`products.ros_types`.  A raw-carried message whose source bag was of the same
kind is written with its original bytes and definition (ROS 1: the original md5sum too).
"""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from common.mcap_io import read_messages
from common.messages import RawMessage
from common.ros_encode import to_ros
from products.ros_types import RawConverter, make_export_typestore

__all__ = ["ExportError", "export_rosbag"]


class ExportError(ValueError):
    """An export that cannot be made; the message names the file and the reason."""


def export_rosbag(run: str | Path, out: str | Path, ros2: bool = True, overwrite: bool = False) -> dict[str, Any]:
    """Write every message of ``run`` into a ROS 2 bag folder (``ros2``) or a ROS 1 ``.bag``.

    Returns ``{"out", "format", "topics": {topic: {"type", "count", "key"}}, "raw_converted":
    {topic: count}}`` (``raw_converted``: raw messages re-serialised because the source bag was
    of the other ROS kind).
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    run, out = Path(run), Path(out)
    if not run.is_file():
        raise ExportError(f"{run}: no such recording")
    if out.exists():
        if not overwrite:
            raise ExportError(f"{out}: exists (pass --overwrite to replace it)")
        shutil.rmtree(out) if out.is_dir() else out.unlink()
    store = make_export_typestore(ros2)
    raw = RawConverter(store, ros2)
    writer = Writer2(out, version=9) if ros2 else Writer1(out)
    conns: dict[tuple[str, str], Any] = {}
    topics: dict[str, dict[str, Any]] = {}
    converted: dict[str, int] = {}
    ok = False
    writer.open()
    try:
        for rec in read_messages(run, strict=True):
            msg = rec.message()
            if isinstance(msg, RawMessage):
                topic, msgtype = msg.topic, msg.ros_type
                if (topic, msgtype) not in conns:
                    if raw.same_kind(msg) and isinstance(writer, Writer1) and msg.digest:
                        conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, msgdef=msg.definition,
                                                                        md5sum=msg.digest)
                    else:
                        raw.register_for_writer(msg)
                        conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, typestore=store)
                data = raw.convert(msg)
                if not raw.same_kind(msg):
                    converted[topic] = converted.get(topic, 0) + 1
            else:
                topic = "/" + rec.key
                msgtype, ros = to_ros(store, ros2, msg)
                if (topic, msgtype) not in conns:
                    conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, typestore=store)
                data = store.serialize_cdr(ros, msgtype) if ros2 else store.serialize_ros1(ros, msgtype)
            writer.write(conns[(topic, msgtype)], rec.stamp, data)
            t = topics.setdefault(topic, {"type": msgtype, "count": 0, "key": rec.key})
            t["count"] += 1
        ok = True
    finally:
        writer.close()
        if not ok:
            shutil.rmtree(out, ignore_errors=True) if out.is_dir() else out.unlink(missing_ok=True)
    return {"out": str(out), "format": "ros2" if ros2 else "ros1", "topics": dict(sorted(topics.items())),
            "raw_converted": converted}
