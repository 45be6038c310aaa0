"""Our messages -> ROS messages (rosbags typestores), for ROS 1/ROS 2 bags and Foxglove.

The mapping itself is :mod:`common.ros_encode` (:func:`~common.ros_encode.to_ros`), shared with
the live ROS 1 bridge; this module adds the ``poseidon_msgs`` definitions and raw-carried messages.

The table of what maps to which ROS type, and what each loses, is in :mod:`common.ros_convert`.
One row is this module's own:

=========================== ====================================================== =====================
key type (ours)             ROS type                                               loses
=========================== ====================================================== =====================
RawMessage                  its original type, bytes unchanged (converted         -
                            between ROS 1 and CDR only when the bag kind differs)
=========================== ====================================================== =====================
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.messages import RawMessage
from common.ros_convert import CALA_VIUDA_MSGS

__all__ = ["MSG_DIR", "POSEIDON_MSGS", "make_export_typestore", "RawConverter"]

#: the .msg files of poseidon_msgs
MSG_DIR = Path(__file__).resolve().parent / "msg"


def _load_msgs() -> dict[str, str]:
    out = {}
    for f in sorted((MSG_DIR / "poseidon_msgs").glob("*.msg")):
        out[f"poseidon_msgs/msg/{f.stem}"] = f.read_text()
    if not out:
        raise FileNotFoundError(f"{MSG_DIR}: no poseidon_msgs .msg definitions (broken installation?)")
    return out


POSEIDON_MSGS: dict[str, str] = _load_msgs()


def make_export_typestore(ros2: bool) -> Any:
    """ROS 2 Humble or ROS 1 Noetic types + Cala Viuda + poseidon_msgs."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    extra = {} if "tf2_msgs/msg/TFMessage" in store.types else {  # absent from rosbags' Noetic store
        "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n"}
    for name, text in {**CALA_VIUDA_MSGS, **POSEIDON_MSGS, **extra}.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


class RawConverter:
    """Raw-carried ROS messages into a bag of kind ``ros2`` (CDR) or ROS 1.

    Same kind as the source: the bytes go out unchanged with the source's definition.  Other
    kind: the type is registered from the carried definition and the payload converted with
    rosbags (ROS 1 <-> CDR; ``std_msgs/Header`` gains or loses ``seq``).
    """

    def __init__(self, dst_store: Any, ros2: bool):
        from rosbags.typesys import Stores, get_typestore

        self.dst = dst_store
        self.ros2 = ros2
        self._src: dict[bool, Any] = {}
        self._get_typestore, self._stores = get_typestore, Stores
        self._fn: dict[tuple[str, str], Callable[[bytes], bytes]] = {}

    def same_kind(self, rm: RawMessage) -> bool:
        return (rm.serialization == "cdr") == self.ros2

    def _src_store(self, is2: bool) -> Any:
        if is2 not in self._src:
            self._src[is2] = self._get_typestore(self._stores.ROS2_HUMBLE if is2 else self._stores.ROS1_NOETIC)
        return self._src[is2]

    @staticmethod
    def _register(store: Any, definition: str, fmt: str, msgtype: str) -> None:
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        types = get_types_from_idl(definition) if fmt == "idl" else get_types_from_msg(definition, msgtype)
        types.pop("std_msgs/msg/Header", None)
        store.register({k: v for k, v in types.items() if k not in store.fielddefs})

    def register_for_writer(self, rm: RawMessage) -> None:
        """Make ``rm.ros_type`` known to the destination store (for the connection's definition)."""
        if rm.ros_type not in self.dst.fielddefs:
            self._register(self.dst, rm.definition, rm.definition_format, rm.ros_type)

    def convert(self, rm: RawMessage) -> bytes:
        """The payload for the destination bag kind."""
        if self.same_kind(rm):
            return rm.data
        key = (rm.ros_type, rm.serialization)
        fn = self._fn.get(key)
        if fn is None:
            from rosbags.convert.converter import is_same_wireformat, migrate_message

            src_is2 = rm.serialization == "cdr"
            src = self._src_store(src_is2)
            if rm.ros_type not in src.fielddefs:
                self._register(src, rm.definition, rm.definition_format, rm.ros_type)
            self.register_for_writer(rm)
            t = rm.ros_type
            if is_same_wireformat(src, self.dst, t, t):
                fn = ((lambda b, t=t: bytes(src.cdr_to_ros1(b, t))) if src_is2
                      else (lambda b, t=t: bytes(self.dst.ros1_to_cdr(b, t))))
            else:
                cache: dict[str, object] = {}

                def fn(b: bytes, t: str = t) -> bytes:
                    m = src.deserialize_cdr(b, t) if src_is2 else src.deserialize_ros1(b, t)
                    d = migrate_message(src, self.dst, t, t, cache, m)
                    return bytes(self.dst.serialize_cdr(d, t) if self.ros2 else self.dst.serialize_ros1(d, t))
            self._fn[key] = fn
        return fn(rm.data)
