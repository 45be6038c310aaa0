import numpy as np
import pytest

from common.codec import DecodeError, decode, decode_frame, encode, encode_frame, encode_watermark
from common.messages import (
    KEYS,
    MESSAGE_TYPES,
    Depth,
    ExperienceEvent,
    Header,
    Image,
    LocalViewCells,
    NeocortexSdr,
    Odometry,
    Sdr,
    key_type,
    message_type,
)
from tests.common.recordings import dvl


def test_every_key_has_a_registered_type_and_json_schema():
    for key, cls in KEYS.items():
        assert message_type(cls.type_name) is cls
        schema = cls.model_json_schema()
        assert "header" in schema["properties"], key
    with pytest.raises(KeyError, match="unknown key 'nope'"):
        key_type("nope")


def test_image_round_trip_keeps_bytes_and_does_not_copy():
    data = np.random.default_rng(1).integers(0, 255, (288, 384, 3), dtype=np.uint8)
    img = Image(header=Header(seq=3, stamp=10, frame_id="camera"), height=288, width=384, data=data)
    payload = encode(img)
    back = decode(payload, Image)
    assert back.header == img.header
    assert np.array_equal(back.data, data) and back.data.dtype == np.uint8
    # the decoded array is a read-only view on the received buffer, not a copy
    assert not back.data.flags.writeable and back.data.base is not None
    assert len(payload) < data.nbytes + 200


def test_nested_messages_round_trip():
    sdr = Sdr(header=Header(seq=0, stamp=1), modality="camera", size=2048,
              active=np.array([1, 5, 9], dtype=np.uint32))
    msg = NeocortexSdr(header=Header(seq=1, stamp=2), modalities=[sdr], fused=sdr, fusion_mode="union")
    back = decode(encode(msg), NeocortexSdr)
    assert back.fused.active.tolist() == [1, 5, 9] and back.modalities[0].modality == "camera"
    lvc = LocalViewCells(header=Header(seq=0, stamp=5), most_active_cell=0,
                         active_cells=[{"id": 0, "rate": 0.8}], is_new=False, intersection=12)
    assert decode(encode(lvc), LocalViewCells) == lvc
    for m in (dvl(Header(seq=0, stamp=1)), Odometry(header=Header(seq=0, stamp=1), position=[1, 2, 3],
                                                    orientation=[0, 0, 0, 1]),
              ExperienceEvent(header=Header(seq=0, stamp=1), lvc_id=3, pc_centroid=[0, 0, 0, 0],
                              odom_position=[0, 0, 0], odom_yaw=0.0, gate="vpr", vpr_count=3)):
        assert decode(encode(m), type(m)) == m


def test_invalid_payload_names_the_field():
    payload = encode(Depth(header=Header(seq=0, stamp=1), depth=2.0)).replace(b"depth\xcb", b"dapth\xcb")
    with pytest.raises(DecodeError, match="Depth: field"):
        decode(payload, Depth)
    with pytest.raises(DecodeError, match="not msgpack"):
        decode(b"\xc1", Depth)
    with pytest.raises(Exception, match="stamp"):
        Header(seq=0, stamp=-5)


def test_wire_frames():
    msg = Depth(header=Header(seq=7, stamp=99), depth=1.5)
    f = decode_frame(encode_frame(msg))
    assert f.kind == "data" and f.type_name == "poseidon_msgs/Depth" and f.message() == msg
    w = decode_frame(encode_watermark(123456789))
    assert w.kind == "watermark" and w.stamp == 123456789
    assert decode_frame(b"E").kind == "eos"
    with pytest.raises(DecodeError):
        decode_frame(b"Zjunk")
    assert set(MESSAGE_TYPES) >= {c.type_name for c in KEYS.values()}
