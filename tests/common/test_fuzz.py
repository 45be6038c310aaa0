"""Property-based fuzzing (hypothesis) of the bus's decode paths and each service's input
handling: random and mutated frames never raise anything but a counted
rejection.  Each test prints how many cases it tried and how many were rejected
(``pytest -s`` shows them)."""
from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.bus import Bus, open_local_session
from common.codec import DecodeError, decode, decode_frame, encode, encode_frame
from common.messages import (
    MESSAGE_TYPES,
    Depth,
    DiagnosticArray,
    ExperienceEvent,
    ExperienceImage,
    ExperienceMap,
    FluidPressure,
    Header,
    Image,
    Imu,
    LaserScan,
    LatencyReport,
    LocalViewCells,
    MagneticField,
    MapSessions,
    NavSatFix,
    NeocortexSdr,
    Odometry,
    PoseCellActivity,
    PoseStamped,
    PoseWithCovarianceStamped,
    RangeImageBeam,
    RawMessage,
    RevisitTruth,
    ScanPose,
    Sdr,
    Temperature,
    TFMessage,
    TwistStamped,
)
from common.ordering import EventTimeMerger
from common.runtime import NodeRunner
from system.config import PoseidonConfig
from system.services import available_services
from tests.common.recordings import dvl

FUZZ = settings(max_examples=300, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
H = Header(seq=3, stamp=1_000_000_000, frame_id="f")


def examples() -> dict[str, object]:
    """One valid message of every registered type."""
    sdr = Sdr(header=H, modality="camera", size=64, active=np.array([1, 7, 30], np.uint32))
    msgs = [
        Image(header=H, height=6, width=8, encoding="rgb8", data=np.arange(144, dtype=np.uint8).reshape(6, 8, 3)),
        RangeImageBeam(header=H, angle_grad=10.0, angle_rad=0.157, nbins=8, max_range=20,
                       beam_data=np.arange(8, dtype=np.int32)),
        LaserScan(header=H, angle_min=0.1, angle_max=0.1, angle_increment=0.03, range_min=0.0, range_max=20.0,
                  ranges=np.linspace(0.5, 20, 8).astype(np.float32), intensities=np.arange(8, dtype=np.float32)),
        dvl(H), Imu(header=H, roll=0.0, pitch=0.0, yaw=0.1, qx=0.0, qy=0.0, qz=0.05, qw=0.9987),
        Depth(header=H, depth=3.5), Odometry(header=H, position=[1.0, 2.0, 3.0], orientation=[0.0, 0.0, 0.0, 1.0]),
        PoseStamped(header=H, position=[1.0, 2.0, -3.0], yaw=0.2), sdr,
        ScanPose(header=H, experience_id=3, pose=[0.2, -0.1, 0.05], score=0.7),
        NeocortexSdr(header=H, modalities=[sdr], fused=sdr, fusion_mode="union"),
        LocalViewCells(header=H, most_active_cell=2, active_cells=[{"id": 2, "rate": 0.5}], is_new=False,
                       intersection=4),
        ExperienceEvent(header=H, lvc_id=1, pc_centroid=[0.0, 0.0, 0.0, 0.0], odom_position=[0.0, 0.0, 0.0],
                        odom_yaw=0.0, gate="vpr", vpr_count=3),
        PoseCellActivity(header=H, xy=np.arange(12, dtype=np.uint8).reshape(3, 4), xy_scale=0.004,
                         zyaw=np.arange(6, dtype=np.uint8).reshape(3, 2), zyaw_scale=0.01,
                         centroid=[0.1, 0.2, 0.0, 0.5], spacing=[0.1, 0.1, 0.1], steps=7),
        ExperienceMap(header=H, nodes=[{"id": 0, "lvc_id": 1, "position": [0.0, 0.0, 0.0], "yaw": 0.0, "stamp": 1}],
                      links=[]),
        ExperienceImage(header=H, height=2, width=2, encoding="mono8", data=np.zeros((2, 2), np.uint8),
                        source_stamp=5),
        MapSessions(header=H, node_session=[0, 1], loaded_nodes=1,
                    links=[{"session": 1, "to_session": 0, "source": 0, "target": 1, "stamp": 1,
                            "delta": [0.1, 0.0, 0.0], "shift": [5.0, 0.0, 0.0], "rotation_deg": 0.2,
                            "inlier_fraction": 0.8}], rejections={"untrusted": 2}),
        RevisitTruth(header=H, frame_index=4, same_place=np.array([0, 2], np.int32)),
        NavSatFix(header=H, status=0, latitude=41.9, longitude=3.2, altitude=2.0),
        FluidPressure(header=H, fluid_pressure=101325.0, variance=4.0),
        Temperature(header=H, temperature=15.5, variance=0.01),
        MagneticField(header=H, magnetic_field=[2e-5, 1e-6, -4e-5]),
        PoseWithCovarianceStamped(header=H, position=[1.0, 2.0, -3.0], orientation=[0.0, 0.0, 0.0, 1.0]),
        TwistStamped(header=H, linear=[0.3, 0.0, 0.0], angular=[0.0, 0.0, 0.01]),
        TFMessage(header=H, transforms=[{"header": {"seq": 0, "stamp": 1, "frame_id": "base"}, "child_frame_id": "dvl",
                                         "translation": [0.1, 0.0, 0.2], "rotation": [0.0, 0.0, 0.0, 1.0]}]),
        DiagnosticArray(header=H, status=[{"level": 0, "name": "dvl", "message": "ok",
                                           "values": [{"key": "beams", "value": "4"}]}]),
        RawMessage(header=H, topic="/vendor/status", ros_type="vendor_msgs/msg/Status", serialization="ros1",
                   definition="uint8 code", data=b"\x01"),
        LatencyReport(header=H, source="live_player", rate=4.0,
                      stages={"lvc": {"n": 3, "unmatched": 0, "p50_ms": 60.0, "p95_ms": 90.0, "p99_ms": 99.0,
                                      "max_ms": 120.0}, "map": {"n": 0, "unmatched": 1}}),
    ]
    out = {type(m).type_name: m for m in msgs}
    missing = set(MESSAGE_TYPES) - set(out)
    assert not missing, f"add an example of {sorted(missing)} to the fuzz tests"
    return out


EXAMPLES = examples()
FRAMES = [encode_frame(m) for m in EXAMPLES.values()]


class Tally:
    def __init__(self, what: str):
        self.what, self.tried, self.rejected = what, 0, 0

    def report(self) -> None:
        print(f"\n[fuzz] {self.what}: {self.tried} cases tried, {self.rejected} rejected (counted), "
              f"{self.tried - self.rejected} accepted")
        assert self.tried > 0


def _mutate(data: bytes, ops: list[tuple[int, int, int]]) -> bytes:
    """Apply (kind, position, byte) edits: 0 flip a byte, 1 delete, 2 insert, 3 truncate."""
    b = bytearray(data)
    for kind, pos, val in ops:
        if not b:
            break
        i = pos % len(b)
        if kind == 0:
            b[i] = val
        elif kind == 1:
            del b[i]
        elif kind == 2:
            b.insert(i, val)
        else:
            del b[i:]
    return bytes(b)


mutations = st.lists(st.tuples(st.integers(0, 3), st.integers(0, 1 << 20), st.integers(0, 255)), min_size=1,
                     max_size=6)


def _decode_all_the_way(data: bytes) -> object:
    frame = decode_frame(data)
    return frame.message() if frame.kind == "data" else frame


def test_frame_codec_random_bytes():
    tally = Tally("decode_frame + message on random bytes")

    @FUZZ
    @given(st.one_of(st.binary(max_size=64), st.binary(max_size=8).map(lambda b: b"D" + b),
                     st.sampled_from([b"D", b"W", b"E"]).flatmap(lambda t: st.binary(max_size=40).map(lambda b: t + b))))
    def check(data):
        tally.tried += 1
        try:
            _decode_all_the_way(data)
        except DecodeError:
            tally.rejected += 1

    check()
    tally.report()


def test_frame_codec_mutated_valid_frames():
    tally = Tally("decode_frame + message on mutated valid frames of every type")

    @FUZZ
    @given(st.sampled_from(FRAMES), mutations)
    def check(frame, ops):
        tally.tried += 1
        data = _mutate(frame, ops)
        try:
            msg = _decode_all_the_way(data)
        except DecodeError:
            tally.rejected += 1
            return
        if hasattr(msg, "header"):  # whatever is accepted is a valid message that round-trips
            again = encode(msg)
            assert encode(decode(again, type(msg))) == again

    check()
    tally.report()


# msgpack-level values: what a hostile publisher can put in any field
leaf = st.one_of(st.none(), st.booleans(), st.integers(-(1 << 64), (1 << 64) - 1), st.floats(allow_nan=True),
                 st.text(max_size=8), st.binary(max_size=16))
values = st.recursive(leaf, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                    st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                      max_leaves=12)
nd = st.fixed_dictionaries({"__nd__": st.tuples(st.sampled_from(["<u1", "<i4", "<f4", "<f8", "|b1", "<U2", "|O",
                                                                  "V3", "<c8", "bogus", ""]),
                                                st.lists(st.integers(-2, 5000), max_size=3)),
                            "b": st.binary(max_size=64)})


@pytest.mark.parametrize("type_name", sorted(MESSAGE_TYPES))
def test_every_message_type_decoder(type_name):
    cls = MESSAGE_TYPES[type_name]
    base = msgpack.unpackb(encode(EXAMPLES[type_name]), raw=False)
    fields = sorted(base)
    tally = Tally(f"decode {type_name} with fields replaced by hostile values")

    @settings(max_examples=60, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(st.dictionaries(st.sampled_from(fields + ["extra", "header"]), st.one_of(values, nd), max_size=3),
           st.sets(st.sampled_from(fields), max_size=2))
    def check(replace, drop):
        tally.tried += 1
        obj = {k: v for k, v in base.items() if k not in drop}
        obj.update(replace)
        try:
            payload = msgpack.packb(obj, use_bin_type=True)
        except (OverflowError, ValueError, TypeError):
            payload = b"\xc1"
        try:
            msg = decode(payload, cls)
        except DecodeError:
            tally.rejected += 1
            return
        assert isinstance(msg, cls)

    check()
    tally.report()


# ------------------------------------------------------------------ each service's input handling

extreme = st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, -1e300, math.inf, -math.inf, math.nan, 3.14159,
                           1e9, -7.5])


@st.composite
def weird_valid(draw, cls):
    """A message of ``cls`` that passes validation but has extreme contents (nan, inf, huge,
    empty arrays, 1x1 images, zero bins...): what a faulty sensor may legitimately send."""
    base = EXAMPLES[cls.type_name]
    update = {}
    for name in cls.model_fields:
        if name == "header" or not draw(st.booleans()):
            continue
        value = getattr(base, name)
        if isinstance(value, float):
            update[name] = draw(extreme)
        elif isinstance(value, list) and value and isinstance(value[0], float):
            update[name] = [draw(extreme) for _ in value]
    if cls is Image:
        h, w = draw(st.integers(1, 40)), draw(st.integers(1, 40))
        enc = draw(st.sampled_from(["rgb8", "bgr8", "mono8", "rgba8", "bgra8", "mono16"]))
        ch = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4, "mono16": 1}[enc]
        dt = np.uint16 if enc == "mono16" else np.uint8
        shape = (h, w) if ch == 1 and draw(st.booleans()) else (h, w, ch)
        fill = draw(st.sampled_from([0, 1, 255]))
        update.update(height=h, width=w, encoding=enc, data=np.full(shape, fill, dt))
    elif cls is RangeImageBeam:
        n = draw(st.integers(0, 64))
        update.update(nbins=n, beam_data=np.full(n, draw(st.sampled_from([0, -5, 2**31 - 1])), np.int32),
                      max_range=draw(st.integers(0, 200)))
    elif cls is LaserScan:
        n = draw(st.integers(0, 32))
        update.update(ranges=np.full(n, draw(extreme), np.float32),
                      intensities=np.full(n if draw(st.booleans()) else 0, draw(extreme), np.float32))
    elif cls is NeocortexSdr:
        size = draw(st.sampled_from([1, 16, 64, 256, 4096]))
        mods = []
        for modality in draw(st.lists(st.sampled_from(["camera", "sonar"]), max_size=2, unique=True)):
            idx = np.array(sorted(draw(st.sets(st.integers(0, size - 1), max_size=40))), np.uint32)
            mods.append(Sdr(header=H, modality=modality, size=size, active=idx))
        fused_idx = np.array(sorted(draw(st.sets(st.integers(0, size - 1), max_size=60))), np.uint32)
        update.update(modalities=mods, fused=Sdr(header=H, modality="fused", size=size, active=fused_idx))
    data = {**base.model_dump(mode="python", round_trip=True), **update}
    try:
        return cls.model_validate(data)
    except ValueError:  # an update the validators reject (e.g. angle_max < angle_min): keep the example
        return base

def _service_config(tmp_path_factory) -> PoseidonConfig:
    from services.encoder.config import EncoderConfig
    tmp = tmp_path_factory.mktemp("fuzzsvc")
    enc = {"lsbh": {"matrix_path": str(tmp / "lsbh_{backbone}_{modality}.npy")}, "sp_columns": 256,
           "pool_grid": 2, "sonar": {"polar_width": 32, "polar_height": 32}, "torch_threads": 1}
    if "untrained" in EncoderConfig.model_fields:  # a seeded network: fuzzing needs no weights file
        enc["untrained"] = True
    return PoseidonConfig.model_validate({
        "encoder": enc,
        "htm": {"input_size": 64, "sp": {"columns": 128, "num_active_columns": 8, "potential_radius": 32}}})


def _valid_inputs(key: str, cls: type) -> list[object]:
    ex = [m for m in EXAMPLES.values() if isinstance(m, cls) and type(m) is cls]
    return ex


@pytest.fixture(scope="module")
def service_config(tmp_path_factory):
    return _service_config(tmp_path_factory)


@pytest.mark.parametrize("service", [s for s in ("encoder", "htm", "robot_state") if s in available_services()])
def test_service_input_handling(service, service_config):
    """Random and mutated frames on every input key go through the runtime's decode and the
    node's process: every bad frame is a counted rejection, the node never raises."""
    from common.messages import KEYS
    from system.services import build_node

    try:
        node = build_node(service, service_config)
    except Exception as exc:  # noqa: BLE001 - a service that cannot be built here is reported, not hidden
        pytest.fail(f"{service} cannot be built for fuzzing: {exc}")
    session = open_local_session()
    bus = Bus(session=session)
    try:
        runner = NodeRunner(node, bus)
        inputs = list(node.inputs)
        stamp = [1_000_000_000]
        tally = Tally(f"{service} input handling ({', '.join(inputs)})")
        good = {k: encode_frame(EXAMPLES[KEYS[k].type_name]) if KEYS[k].type_name in EXAMPLES else None
                for k in inputs}

        def restamp(frame: bytes) -> bytes:
            """A valid frame of the key with a fresh, increasing stamp (so it is not 'late')."""
            f = decode_frame(frame)
            msg = f.message()
            stamp[0] += 10_000_000
            return encode_frame(msg.model_copy(update={"header": Header(seq=msg.header.seq, stamp=stamp[0])}))

        @settings(max_examples=80, deadline=None, derandomize=True,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
        @given(st.sampled_from(inputs), st.one_of(st.binary(max_size=48), mutations, st.data()), st.booleans())
        def check(key, mutation, then_valid):
            tally.tried += 1
            merger = EventTimeMerger(inputs)
            for other in inputs:
                if other != key:
                    merger.advance(other, stamp[0] + 10**12)  # only this key holds messages back
            if isinstance(mutation, bytes):
                data = mutation
            elif isinstance(mutation, list):
                data = _mutate(restamp(good[key]) if good[key] else b"D", mutation)
            else:  # a valid message with extreme contents
                data = restamp(encode_frame(mutation.draw(weird_valid(KEYS[key]))))
            before = sum(runner.stats.invalid.values())
            runner.accept(merger, key, data)
            if sum(runner.stats.invalid.values()) > before:
                tally.rejected += 1
            if then_valid and good[key]:
                runner.accept(merger, key, restamp(good[key]))
            merger.end(key)
            for in_key, _stamp, msg in merger.pop_ready():
                runner.process(in_key, msg)  # a node exception fails the test (ServiceError)

        check()
        tally.report()
        print(f"[fuzz] {service} rejections by reason: {runner.stats.rejected}; node counters: {node.counters}")
    finally:
        bus.close()
        session.close()
