"""decode_frame: every frame kind and every malformation, from bytes, bytearray and memoryview."""
import struct

import pytest

from common.codec import (
    ENCODED_EOS,
    DecodeError,
    decode_frame,
    encode,
    encode_bundle,
    encode_frame,
    encode_replay_start,
    encode_sequenced,
    encode_watermark,
    split_frames,
)
from common.messages import Depth, Header

MSG = Depth(header=Header(seq=3, stamp=77), depth=1.5)
NAME = b"poseidon_msgs/Depth"

GOOD = [
    (encode_frame(MSG), ("data", "poseidon_msgs/Depth", encode(MSG), 0, -1)),
    (encode_sequenced(41, MSG.type_name, encode(MSG)), ("data", "poseidon_msgs/Depth", encode(MSG), 0, 41)),
    (encode_watermark(123456789), ("watermark", "", b"", 123456789, -1)),
    (encode_replay_start(7), ("replay", "", b"", 0, 7)),
    (encode_replay_start(7, "htm"), ("replay", "htm", b"", 0, 7)),
    (ENCODED_EOS, ("eos", "", b"", 0, -1)),
]

BAD = [
    (b"", "empty frame"),
    (b"S" + b"\0" * 8, "sequenced data frame of 9 bytes (no index and type name)"),
    (b"S" + struct.pack("<Q", 1 << 63) + b"\x01", f"transport index {1 << 63} out of range"),
    (b"D", "data frame of 1 byte (no type name)"),
    (b"D\x05abc", "data frame of 5 bytes truncated inside its 5-byte type name"),
    (b"S" + struct.pack("<Q", 2) + b"\x05abc", "data frame of 5 bytes truncated inside its 5-byte type name"),
    (b"D\x02\xff\xfe\x01", r"type name b'\xff\xfe' is not ASCII"),
    (b"D\x03abc\x01", "unknown message type 'abc'"),
    (b"D" + bytes([len(NAME)]) + NAME, "poseidon_msgs/Depth frame without a payload"),
    (b"W" + b"\0" * 7, "watermark frame of 8 bytes (expected 9)"),
    (b"W" + struct.pack("<q", -1), "negative watermark -1"),
    (b"R" + b"\0" * 74, "replay frame of 75 bytes (expected 9, or up to 64 more naming its asker)"),
    (b"R" + b"\0" * 8 + b"\xff", "replay frame: its asker is not ASCII"),
    (b"R" + struct.pack("<Q", 1 << 63), f"replay start {1 << 63} out of range"),
    (b"EE", "end-of-stream frame of 2 bytes (expected 1)"),
    (b"Zjunk", "unknown frame tag b'Z'"),
    (b"B", "empty bundle frame"),
    (b"B\x01\x00", "bundle frame truncated at byte 1 of 3 (no frame length)"),
    (b"B" + struct.pack("<I", 5) + b"ab", "bundle frame: a frame of 5 bytes at byte 5 of 7"),
    (b"B" + struct.pack("<I", 0), "bundle frame: a frame of 0 bytes at byte 5 of 5"),
    (encode_bundle([ENCODED_EOS]), "a bundle of frames (6 bytes) where one frame was expected: split_frames splits it"),
]


@pytest.mark.parametrize("form", [bytes, bytearray, memoryview])
def test_every_frame_kind(form):
    for data, (kind, type_name, payload, stamp, index) in GOOD:
        f = decode_frame(form(data))
        assert (f.kind, f.type_name, bytes(f.payload), f.stamp, f.index) == (kind, type_name, payload, stamp, index)
        if kind == "data":
            assert isinstance(f.payload, memoryview) and f.message() == MSG


@pytest.mark.parametrize("form", [bytes, bytearray, memoryview])
def test_every_malformation_names_what_is_wrong(form):
    for data, text in BAD:
        with pytest.raises(DecodeError) as err:
            decode_frame(form(data))
        assert str(err.value) == text


def test_decode_header_reads_the_header_alone_and_falls_back_to_the_whole_payload():
    """The recorder's header read: equal to the whole decode's header, for a short message, an
    image (the body far beyond the read window), a header longer than the window and a map whose
    first field is not the header; no header map is a DecodeError."""
    import msgpack
    import numpy as np

    from common.codec import decode_dict, decode_header, pack_obj
    from common.messages import Image

    image = Image(header=Header(seq=9, stamp=5, frame_id="camera"), height=64, width=64, encoding="rgb8",
                  data=np.zeros((64, 64, 3), np.uint8))
    long_id = Depth(header=Header(seq=1, stamp=2, frame_id="x" * 600), depth=0.5)
    for payload in (encode(MSG), encode(image), encode(long_id)):
        assert decode_header(payload) == decode_dict(payload)["header"]
        assert decode_header(memoryview(payload)) == decode_dict(payload)["header"]
    reordered = pack_obj({"depth": 1.0, "header": {"seq": 4, "stamp": 8, "frame_id": ""}})
    assert decode_header(reordered) == {"seq": 4, "stamp": 8, "frame_id": ""}
    for bad in (b"", b"\x80", b"\xc1", b"\x81\xa6header\x05", msgpack.packb([1, 2]), pack_obj({"depth": 1.0})):
        with pytest.raises(DecodeError):
            decode_header(bad)


def test_a_bundle_splits_into_the_same_frames_in_order():
    frames = [data for data, _ in GOOD]
    assert split_frames(encode_bundle(frames)) == frames
    assert split_frames(encode_bundle(frames[:1])) == frames[:1]
    for data in frames:  # a frame that is no bundle is its own only frame
        assert split_frames(data) == [data]
    with pytest.raises(DecodeError, match="truncated at byte"):
        split_frames(encode_bundle(frames)[:-len(ENCODED_EOS) - 2])
