"""msgpack codec for :mod:`common.messages`.

Numpy arrays travel as ``{"__nd__": [dtype, shape], "b": <raw bytes>}``: packing reads the
array's own buffer (no intermediate ``tobytes`` copy for contiguous arrays) and unpacking
wraps the received bytes with ``np.frombuffer`` (no copy; the array is read-only).

Wire frames (:func:`encode_frame`) add a one-byte tag so data, event-time watermarks and
end-of-stream travel in order on the same key: ``D`` + type name + message, ``W`` +
int64 stamp, ``E`` (end of stream).  Publishers of a run number their data frames per key
(``S`` + uint64 index + type name + message: the *transport index*, 0, 1, 2 ... in publish
order), so a consumer can drop a frame it already has when a restarted service or a replay
sends it again; ``R`` + uint64 index starts a replay ("the next data frame on this key is
index n"), see :mod:`common.resume`.  A replay at full speed may carry several consecutive
frames of one key in one sample, ``B`` + per frame a uint32 length and the frame
(:func:`encode_bundle`); every receiver splits it (:func:`split_frames`, done by
:meth:`common.bus.Bus.subscribe`) and sees the same frames in the same order.

Robustness contract: :func:`decode_frame`, :func:`decode_dict`, :func:`decode` and
:meth:`Frame.message` raise :class:`DecodeError` (a ``ValueError``) for *any* malformed
input -- truncated frames, bytes that are not UTF-8, unknown types, msgpack garbage, arrays
whose bytes do not fill their shape, fields that contradict each other -- and nothing
else, so a receiver can count and skip a bad frame with one ``except DecodeError``
(fuzzed by ``tests/common/test_fuzz.py``).
"""
from __future__ import annotations

import struct
from typing import Any, TypeVar

import msgpack
import numpy as np
from pydantic import ValidationError

from common.messages import MESSAGE_TYPES, Message

__all__ = [
    "encode", "decode", "decode_dict", "pack_obj", "unpack_obj", "encode_frame", "encode_watermark",
    "ENCODED_EOS", "decode_frame", "Frame", "DecodeError", "encode_sequenced", "encode_replay_start",
    "decode_header", "encode_bundle", "split_frames", "BUNDLE_TAG",
]


M = TypeVar("M", bound=Message)

class DecodeError(ValueError):
    """Bytes that are not a valid message; the text says what is wrong."""


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        arr = obj if obj.flags.c_contiguous else np.ascontiguousarray(obj)
        if arr.dtype.byteorder == ">":
            arr = arr.astype(arr.dtype.newbyteorder("<"))
        return {"__nd__": [arr.dtype.str, list(arr.shape)], "b": arr.data.cast("B")}
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _object_hook(obj: dict[str, Any]) -> Any:
    nd = obj.get("__nd__")
    if nd is not None:
        dtype, shape = nd
        dt = np.dtype(dtype)
        if dt.hasobject:
            raise TypeError(f"array dtype {dt.str} holds Python objects")
        return np.frombuffer(obj["b"], dtype=dt).reshape(shape)
    return obj


def pack_obj(obj: Any) -> bytes:
    """msgpack-encode plain Python data that may contain numpy arrays."""
    out = msgpack.packb(obj, default=_default, use_bin_type=True)
    if not isinstance(out, bytes):
        raise TypeError(f"msgpack.packb returned {type(out).__name__}, not bytes")
    return out


def unpack_obj(data: bytes | memoryview) -> Any:
    """Inverse of :func:`pack_obj`."""
    return msgpack.unpackb(data, object_hook=_object_hook, raw=False, strict_map_key=False)


def _dump(msg: Message) -> dict[str, Any]:
    return msg.model_dump(mode="python", round_trip=True)


def encode(msg: Message) -> bytes:
    """Message -> msgpack bytes (the payload recorded in MCAP)."""
    return pack_obj(_dump(msg))


def decode_dict(data: bytes | memoryview) -> dict[str, Any]:
    """msgpack bytes -> plain dict (arrays as read-only numpy views)."""
    try:
        obj = unpack_obj(data)
    except Exception as exc:  # msgpack raises several unrelated types
        raise DecodeError(f"not msgpack: {exc}") from None
    if not isinstance(obj, dict):
        raise DecodeError(f"expected a map, got {type(obj).__name__}")
    return obj


#: bytes of a payload read for its header first: every message's first field, a few dozen bytes
_HEADER_WINDOW = 256


def decode_header(data: bytes | memoryview) -> dict[str, Any]:
    """The ``header`` map of an encoded message, without decoding the rest of it.

    Every message is packed with ``header`` as its first field (:class:`common.messages.Message`),
    so only the payload's first :data:`_HEADER_WINDOW` bytes are read; a payload laid out
    otherwise (or with a longer header) is decoded whole.  Only the header is checked:
    the body is checked by the receivers that decode it (:func:`decode`).  Raises
    :class:`DecodeError` when there is no header map."""
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=False, max_buffer_size=_HEADER_WINDOW)
    unpacker.feed(data[:_HEADER_WINDOW])
    try:
        unpacker.read_map_header()
        first = unpacker.unpack()
        header = unpacker.unpack() if first == "header" else None
    except Exception:  # msgpack raises several unrelated types (OutOfData, ExtraData, ValueError ...)
        header = None
    if header is None:
        header = decode_dict(data).get("header")
    if not isinstance(header, dict):
        raise DecodeError("no header")
    return header


def decode(data: bytes | memoryview, cls: type[M]) -> M:
    """msgpack bytes -> validated message of type ``cls``; raises DecodeError naming the field."""
    obj = decode_dict(data)
    try:
        return cls.model_validate(obj)
    except ValidationError as err:
        first = err.errors()[0]
        loc = ".".join(str(p) for p in first["loc"]) or "<message>"
        raise DecodeError(f"{cls.type_name}: field {loc}: {first['msg']}") from None
    except Exception as exc:
        raise DecodeError(f"{cls.type_name}: {type(exc).__name__}: {exc}") from None


_TAG_DATA, _TAG_WM, _TAG_EOS, _TAG_SEQ, _TAG_REPLAY, _TAG_BUNDLE = b"D", b"W", b"E", b"S", b"R", b"B"
_PACK_Q = struct.Struct("<Q").pack
_PACK_I = struct.Struct("<I").pack
_UNPACK_I = struct.Struct("<I").unpack_from
ENCODED_EOS = _TAG_EOS
BUNDLE_TAG = _TAG_BUNDLE  # the first byte of a bundle (:func:`encode_bundle`)


def encode_frame(msg: Message) -> bytes:
    """Wire frame of a data message: tag, type name, payload."""
    name = msg.type_name.encode()
    return _TAG_DATA + bytes([len(name)]) + name + encode(msg)


def encode_sequenced(index: int, type_name: str | bytes, payload: bytes | memoryview) -> bytes:
    """Wire frame of a data message with its transport index (``S`` frame)."""
    name = type_name.encode() if isinstance(type_name, str) else type_name
    # one join: the payload (up to an image) is copied once, not once per concatenation
    return b"".join((_TAG_SEQ, _PACK_Q(index), bytes([len(name)]), name, payload))


def encode_bundle(frames: list[bytes]) -> bytes:
    """One wire sample carrying several frames of one key, in order (``B`` + per frame a uint32
    length and the frame); :func:`split_frames` gives them back one by one."""
    parts = [_TAG_BUNDLE]
    for f in frames:
        parts.append(_PACK_I(len(f)))
        parts.append(f)
    return b"".join(parts)


def split_frames(data: bytes) -> list[bytes]:
    """The frames of one wire sample: those of a bundle (:func:`encode_bundle`), or the sample
    itself.  A bundle that does not split exactly raises :class:`DecodeError`."""
    if not data or data[0] != _T_BUNDLE:
        return [data]
    out: list[bytes] = []
    pos, size = 1, len(data)
    while pos < size:
        if pos + 4 > size:
            raise DecodeError(f"bundle frame truncated at byte {pos} of {size} (no frame length)")
        n = _UNPACK_I(data, pos)[0]
        pos += 4
        if n == 0 or pos + n > size:
            raise DecodeError(f"bundle frame: a frame of {n} bytes at byte {pos} of {size}")
        out.append(data[pos:pos + n])
        pos += n
    if not out:
        raise DecodeError("empty bundle frame")
    return out


def encode_replay_start(index: int, by: str = "") -> bytes:
    """Wire frame opening a replay: the next data frame on this key has transport index ``index``;
    ``by``: the consumer that asked for it (ASCII, at most 64 bytes; '' for a replay nobody asked
    for).  Decoded, the asker is the frame's ``type_name``."""
    name = by.encode("ascii")
    if len(name) > 64:
        raise ValueError(f"replay asker {by!r} longer than 64 bytes")
    return _TAG_REPLAY + struct.pack("<Q", index) + name


def encode_watermark(stamp: int) -> bytes:
    """Wire frame promising that nothing older than ``stamp`` (ns) follows on this key."""
    return _TAG_WM + struct.pack("<q", stamp)


class Frame:
    """A decoded wire frame: ``kind`` is 'data', 'watermark', 'eos' or 'replay'.

    ``index``: the transport index of an ``S`` data frame (-1 for an unnumbered ``D`` frame),
    the first index of a replay for 'replay'."""

    __slots__ = ("kind", "type_name", "payload", "stamp", "index")

    def __init__(self, kind: str, type_name: str = "", payload: memoryview | bytes = b"", stamp: int = 0,
                 index: int = -1):
        self.kind = kind
        self.type_name = type_name
        self.payload = payload
        self.stamp = stamp
        self.index = index

    def message(self) -> Message:
        """The validated message of a data frame; DecodeError for anything malformed."""
        cls = MESSAGE_TYPES.get(self.type_name)
        if cls is None:
            raise DecodeError(f"unknown message type {self.type_name!r}")
        return decode(self.payload, cls)


_UNPACK_Q = struct.Struct("<Q").unpack_from
_UNPACK_q = struct.Struct("<q").unpack_from
_T_DATA, _T_WM, _T_EOS, _T_SEQ, _T_REPLAY, _T_BUNDLE = (_TAG_DATA[0], _TAG_WM[0], _TAG_EOS[0], _TAG_SEQ[0],
                                                     _TAG_REPLAY[0], _TAG_BUNDLE[0])
_TYPE_NAMES: dict[bytes, str] = {}  # encoded type name -> type name, for the known types seen so far


def decode_frame(data: bytes | memoryview) -> Frame:
    """Parse a wire frame (no message validation: see :meth:`Frame.message`).

    Raises :class:`DecodeError` for every malformed frame: empty, truncated, a type name
    that is not ASCII or not a known message type, a watermark that is not 8 bytes or is
    negative, an end-of-stream with trailing bytes, an index above int64, an unknown tag.
    """
    buf = data if isinstance(data, (bytes, bytearray)) else memoryview(data).cast("B")
    size = len(buf)
    if size == 0:
        raise DecodeError("empty frame")
    tag = buf[0]
    if tag == _T_WM:
        if size != 9:
            raise DecodeError(f"watermark frame of {size} bytes (expected 9)")
        stamp = _UNPACK_q(buf, 1)[0]
        if stamp < 0:
            raise DecodeError(f"negative watermark {stamp}")
        return Frame("watermark", stamp=stamp)
    index = -1
    start = 0  # where the data frame's tag would be
    if tag == _T_SEQ:
        if size < 10:
            raise DecodeError(f"sequenced data frame of {size} bytes (no index and type name)")
        index = _UNPACK_Q(buf, 1)[0]
        if index >= 1 << 63:
            raise DecodeError(f"transport index {index} out of range")
        start = 8
        tag = _T_DATA
    if tag == _T_DATA:
        length = size - start
        if length < 2:
            raise DecodeError("data frame of 1 byte (no type name)")
        n = buf[start + 1]
        if length < 2 + n:
            raise DecodeError(f"data frame of {length} bytes truncated inside its {n}-byte type name")
        raw = bytes(buf[start + 2:start + 2 + n])
        type_name = _TYPE_NAMES.get(raw)
        if type_name is None:
            try:
                type_name = raw.decode("ascii")
            except UnicodeDecodeError:
                raise DecodeError(f"type name {raw[:40]!r} is not ASCII") from None
            if type_name not in MESSAGE_TYPES:
                raise DecodeError(f"unknown message type {type_name[:60]!r}")
            _TYPE_NAMES[raw] = type_name
        elif type_name not in MESSAGE_TYPES:  # (the registry only grows; checked to stay exact)
            raise DecodeError(f"unknown message type {type_name[:60]!r}")
        if length == 2 + n:
            raise DecodeError(f"{type_name} frame without a payload")
        return Frame("data", type_name, memoryview(buf)[start + 2 + n:], index=index)
    if tag == _T_REPLAY:
        if size < 9 or size > 9 + 64:
            raise DecodeError(f"replay frame of {size} bytes (expected 9, or up to 64 more naming its asker)")
        first = _UNPACK_Q(buf, 1)[0]
        if first >= 1 << 63:
            raise DecodeError(f"replay start {first} out of range")
        try:
            by = bytes(buf[9:]).decode("ascii")
        except UnicodeDecodeError:
            raise DecodeError("replay frame: its asker is not ASCII") from None
        return Frame("replay", type_name=by, index=first)
    if tag == _T_EOS:
        if size != 1:
            raise DecodeError(f"end-of-stream frame of {size} bytes (expected 1)")
        return Frame("eos")
    if tag == _T_BUNDLE:
        split_frames(bytes(buf))  # raises naming what is wrong with a malformed bundle
        raise DecodeError(f"a bundle of frames ({size} bytes) where one frame was expected: split_frames splits it")
    raise DecodeError(f"unknown frame tag {bytes([tag])!r}")
