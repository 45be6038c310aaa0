"""ROS1 ``.bag``, ROS2 ``.db3`` and ROS2 ``.mcap`` bags, read with rosbags.

The type mapping to our messages is :mod:`common.ros_convert` (shared with the live ROS 1
bridge); its names are re-exported here for the importer.
"""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from common.ros_convert import (
    CALA_VIUDA_MSGS,
    CONVERTERS,
    DEFAULT_TOPIC_MAP,
    ConversionError,
    make_typestore,
    normalise_type,
    ros_header,
    rpy_from_quaternion,
)
from missions.importers.errors import InputFormatError

__all__ = ["CALA_VIUDA_MSGS", "make_typestore", "CONVERTERS", "ConversionError", "normalise_type", "open_bags",
           "BagMessage", "rpy_from_quaternion", "DEFAULT_TOPIC_MAP", "ros_header", "connection_definition"]


class BagMessage:
    """One raw message of a bag (decoded lazily)."""

    __slots__ = ("topic", "msgtype", "record_ns", "raw", "connection")

    def __init__(self, topic: str, msgtype: str, record_ns: int, raw: bytes, connection: Any):
        self.topic, self.msgtype, self.record_ns, self.raw, self.connection = topic, msgtype, record_ns, raw, connection


def _bag_kind(path: Path) -> str:
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return "ros2"
        raise InputFormatError(f"{path}: a folder without metadata.yaml is not a ROS2 bag")
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return "ros1"
    if suffix in (".db3", ".mcap"):
        return "ros2"
    raise InputFormatError(f"{path}: unknown bag format (expected .bag, .db3, .mcap or a ROS2 bag folder)")


def _ros2_dir(path: Path) -> Path:
    """rosbags reads ROS2 bags by folder; a bare .db3/.mcap file needs its folder with metadata.yaml."""
    if path.is_dir():
        return path
    if (path.parent / "metadata.yaml").exists():
        return path.parent
    raise InputFormatError(f"{path}: ROS2 bag file without a metadata.yaml next to it (rosbags needs the bag folder)")


def open_bags(paths: list[Path]) -> tuple[Any, dict[str, Any]]:
    """An opened rosbags AnyReader over ``paths`` (ROS1 and ROS2 may not be mixed in one
    reader) and per-path info; raises :class:`InputFormatError` naming the file."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    kinds = {_bag_kind(p) for p in paths}
    if len(kinds) > 1:
        raise InputFormatError(f"{[str(p) for p in paths]}: mixes ROS1 and ROS2 bags in one reader")
    kind = kinds.pop()
    real = [(_ros2_dir(p) if kind == "ros2" else p) for p in paths]
    for p in real:
        if not p.exists():
            raise InputFormatError(f"{p}: no such bag")
    reader = AnyReader(real, default_typestore=make_typestore(ros2=(kind == "ros2")))
    try:
        reader.open()
    except AnyReaderError as exc:
        raise InputFormatError(f"{', '.join(map(str, real))}: cannot read {kind.upper()} bag: {exc} "
                               f"(truncated, not indexed or not a bag?)") from None
    return reader, {"kind": kind, "paths": [str(p) for p in real]}


def iter_bag(reader: Any, start: int | None = None) -> Iterator[BagMessage]:
    """Every message of an opened reader in bag-time order (from bag time ``start``, ns)."""
    for conn, t, raw in reader.messages(start=start):
        yield BagMessage(conn.topic, normalise_type(conn.msgtype), int(t), raw, conn)


def connection_definition(reader: Any, conn: Any) -> tuple[str, str, str]:
    """(definition text, format ``msg``/``idl``, digest) of a bag connection, as the bag stored
    it; a ROS2 bag without definitions gets the one rosbags generates from its typestore."""
    md = conn.msgdef
    text = getattr(md, "data", md) or ""
    fmt = getattr(getattr(md, "format", None), "name", "MSG").lower()
    if not text:
        text, _ = reader.typestore.generate_msgdef(conn.msgtype, ros_version=2 if reader.is2 else 1)
        fmt = "msg"
    return str(text), ("idl" if fmt == "idl" else "msg"), str(conn.digest or "")
