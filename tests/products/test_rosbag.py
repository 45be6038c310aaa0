"""Nothing lost on import (raw carry), and `poseidon export` to Foxglove, ROS 2 and ROS 1 bags."""
from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import RecordingWriter, read_messages
from common.messages import (
    Depth,
    ExperienceEvent,
    ExperienceImage,
    ExperienceLink,
    ExperienceMap,
    ExperienceNode,
    Header,
    Image,
    Imu,
    LaserScan,
    LinkquestDvl,
    LocalViewCell,
    LocalViewCells,
    NavSatFix,
    NeocortexSdr,
    Odometry,
    PoseStamped,
    RangeImageBeam,
    RawMessage,
    Sdr,
    TFMessage,
    TransformStamped,
    key_type,
)
from missions.importers.cli import import_sources
from products.cli import main as export_main
from products.foxglove import export_foxglove
from products.rosbag import ExportError, export_rosbag

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
BAGS = DATA / "ros1_bags"
needs_bags = pytest.mark.skipif(not BAGS.is_dir(), reason=f"real ROS1 bags not present at {BAGS}")
T0 = 1_700_000_000_000_000_000


def _bag_payloads(path: Path) -> dict[str, list[bytes]]:
    """Topic -> serialised payloads, in bag order."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list[bytes]] = defaultdict(list)
    with AnyReader([path]) as r:
        for conn, _t, raw in r.messages():
            out[conn.topic].append(bytes(raw))
    return dict(out)


def _bag_counts_decoded(path: Path) -> dict[str, int]:
    """Topic -> count, every message deserialised (fails on a payload that does not fit its type)."""
    from rosbags.highlevel import AnyReader

    counts: dict[str, int] = defaultdict(int)
    with AnyReader([path]) as r:
        for conn, _t, raw in r.messages():
            r.deserialize(raw, conn.msgtype)
            counts[conn.topic] += 1
    return dict(counts)


# --------------------------------------------------------------------------- real bags


_REAL_BAGS = sorted(p.name for p in BAGS.glob("*.bag")) if BAGS.is_dir() else ["absent"]


@needs_bags
@pytest.mark.parametrize("name", _REAL_BAGS)
def test_real_bag_every_message_and_raw_reexport_byte_identical(tmp_path: Path, name: str) -> None:
    bag = BAGS / name
    own = {t: len(p) for t, p in _bag_payloads(bag).items()}
    # default import: every topic mapped, per topic equal to the bag's own count
    s = import_sources([bag], tmp_path / "mapped.mcap", progress=False)
    assert s["rejected"] == []
    assert {t: v["mapped"] + v["raw"] for t, v in s["topics"].items()} == own
    assert {t: v["in_source"] for t, v in s["topics"].items()} == own
    # the ROS 2 export of the mapped import reads back with the same counts per topic
    ros2 = export_rosbag(tmp_path / "mapped.mcap", tmp_path / "ros2", ros2=True)
    assert _bag_counts_decoded(tmp_path / "ros2") == own == {t: v["count"] for t, v in ros2["topics"].items()}
    # every topic carried raw, written back to a ROS 1 bag: the very same bytes, in the same order
    s = import_sources([bag], tmp_path / "raw.mcap", progress=False, raw_topics={"*"})
    assert {t: (v["raw"], v["as"]) for t, v in s["topics"].items()} == {t: (n, "raw") for t, n in own.items()}
    export_rosbag(tmp_path / "raw.mcap", tmp_path / "back.bag", ros2=False)
    assert _bag_payloads(tmp_path / "back.bag") == _bag_payloads(bag)
    # ... and to ROS 2 (CDR): converted, same counts, every message decodes
    export_rosbag(tmp_path / "raw.mcap", tmp_path / "raw_ros2", ros2=True)
    assert _bag_counts_decoded(tmp_path / "raw_ros2") == own


# --------------------------------------------------------------------------- vendor types, both bag kinds

_VENDOR = "vendor_msgs/msg/ThrusterStatus"
_VENDOR_DEF = "std_msgs/Header header\nfloat32[] rpm\nstring mode\nuint8 FAULT=2\nuint8 state\n"


def _vendor_bag(path: Path, ros2: bool, n: int = 5) -> list[bytes]:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(_VENDOR_DEF, _VENDOR))
    store.register(get_types_from_msg("uint32 a\nbool b\n", "vendor_msgs/msg/NoHeader"))
    T = store.types
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    writer: Writer1 | Writer2 = Writer2(path, version=9) if ros2 else Writer1(path)
    payloads = []
    with writer:
        c = writer.add_connection("/thrusters/status", _VENDOR, typestore=store)
        d = writer.add_connection("/counter", "vendor_msgs/msg/NoHeader", typestore=store)
        for i in range(n):
            st = T["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=5)
            hdr = T["std_msgs/msg/Header"](stamp=st, frame_id="thr") if ros2 else \
                T["std_msgs/msg/Header"](seq=i, stamp=st, frame_id="thr")
            m = T[_VENDOR](header=hdr, rpm=np.array([100.0 * i, -50.0], np.float32), mode="auto", state=i % 3)
            raw = bytes(store.serialize_cdr(m, _VENDOR) if ros2 else store.serialize_ros1(m, _VENDOR))
            payloads.append(raw)
            writer.write(c, T0 + i * 1000, raw)
            k = T["vendor_msgs/msg/NoHeader"](a=i, b=bool(i % 2))
            writer.write(d, T0 + i * 1000 + 1, store.serialize_cdr(k, "vendor_msgs/msg/NoHeader") if ros2
                         else store.serialize_ros1(k, "vendor_msgs/msg/NoHeader"))
    return payloads


@pytest.mark.parametrize("ros2", [False, True], ids=["ros1", "ros2"])
def test_vendor_types_carried_raw_and_written_back(tmp_path: Path, ros2: bool) -> None:
    src = tmp_path / ("v2" if ros2 else "v.bag")
    payloads = _vendor_bag(src, ros2)
    s = import_sources([src], tmp_path / "run.mcap", progress=False)
    t = s["topics"]["/thrusters/status"]
    assert (t["raw"], t["mapped"], t["raw_key"], t["as"]) == (5, 0, "raw/thrusters/status", "raw")
    recs = [r for r in read_messages(tmp_path / "run.mcap") if r.key == "raw/thrusters/status"]
    msgs: list[Any] = [r.message() for r in recs]
    assert all(isinstance(m, RawMessage) for m in msgs) and key_type("raw/thrusters/status") is RawMessage
    assert [m.data for m in msgs] == payloads
    # the ROS header stamp is the event time; a type without a header keeps the bag time
    assert [m.header.stamp for m in msgs] == [(1_700_000_000 + i) * 1_000_000_000 + 5 for i in range(5)]
    assert msgs[0].header.frame_id == "thr" and msgs[0].serialization == ("cdr" if ros2 else "ros1")
    assert [r.stamp for r in read_messages(tmp_path / "run.mcap") if r.key == "raw/counter"] == \
        [T0 + i * 1000 + 1 for i in range(5)]
    # same kind of bag: byte for byte; other kind: converted, and decodes there
    same, other = (tmp_path / "same", tmp_path / "other.bag") if ros2 else (tmp_path / "same.bag", tmp_path / "other")
    export_rosbag(tmp_path / "run.mcap", same, ros2=ros2)
    assert _bag_payloads(same) == _bag_payloads(src)
    e = export_rosbag(tmp_path / "run.mcap", other, ros2=not ros2)
    assert e["raw_converted"] == {"/thrusters/status": 5, "/counter": 5}
    from rosbags.highlevel import AnyReader

    with AnyReader([other]) as r:
        got: list[Any] = [r.deserialize(raw, c.msgtype) for c, _t, raw in r.messages() if c.topic == "/thrusters/status"]
    assert [list(m.rpm) for m in got] == [[100.0 * i, -50.0] for i in range(5)]
    assert [m.state for m in got] == [i % 3 for i in range(5)] and got[2].header.frame_id == "thr"


def test_player_replays_and_recorder_records_raw_keys(tmp_path: Path) -> None:
    """A raw key goes through player -> bus -> recorder unchanged (no registration needed)."""
    from launcher.run import run_embedded
    from system.config import PoseidonConfig

    src = tmp_path / "v.bag"
    _vendor_bag(src, ros2=False)
    import_sources([src], tmp_path / "run.mcap", progress=False)
    result = run_embedded(PoseidonConfig(), tmp_path / "run.mcap", tmp_path / "replayed.mcap", services=[],
                          progress=False, timeout_s=60)
    assert result.recording["counts"] == {"raw/thrusters/status": 5, "raw/counter": 5}
    a = [(r.key, r.type_name, r.payload) for r in read_messages(tmp_path / "run.mcap")]
    b = [(r.key, r.type_name, r.payload) for r in read_messages(tmp_path / "replayed.mcap")]
    assert sorted(a) == sorted(b) and a[0][1] == "poseidon_msgs/RawMessage"


# --------------------------------------------------------------------------- a small run, exported


def _h(i: int, frame: str = "", dt_ms: int = 100) -> Header:
    return Header(seq=i, stamp=T0 + i * dt_ms * 1_000_000, frame_id=frame)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, int]]:
    """A run with every kind of stream: images, sonar, Odometry track, map, events, LVC ids, raw."""
    path = tmp_path_factory.mktemp("run") / "run.mcap"
    rng = np.random.default_rng(0)
    with RecordingWriter(path) as w:
        for i in range(4):
            img = rng.integers(0, 255, (6, 8, 3), dtype=np.uint8)
            w.write("camera/image_raw", Image(header=_h(i, "camera", 250), height=6, width=8, encoding="rgb8", data=img))
            w.write("experience_image", ExperienceImage(header=_h(i, "camera", 250), height=6, width=8, encoding="mono8",
                                                        data=img[:, :, 0].copy(), source_stamp=_h(i).stamp))
            w.write("local_view_cells", LocalViewCells(
                header=_h(i, "camera", 250), most_active_cell=i % 3, is_new=i < 3, intersection=0 if i < 3 else 17,
                active_cells=[LocalViewCell(id=i % 3, rate=0.5), LocalViewCell(id=7, rate=0.25)]))
            sdr = Sdr(header=_h(i), modality="camera", size=64, active=np.array([1, 5, 9], np.uint32))
            w.write("neocortex/sdr", NeocortexSdr(header=_h(i), modalities=[sdr], fused=sdr, fusion_mode="union"))
        for i in range(12):
            w.write("sonar_micron", RangeImageBeam(header=_h(i, "micron", 50), angle_grad=3.0 * i, angle_rad=0.05 * i,
                                                   nbins=10, max_range=20, beam_data=np.arange(10, dtype=np.int32) * i))
            w.write("Odometry", Odometry(header=_h(i, "world", 500), child_frame_id="base_link",
                                         position=[0.5 * i, 0.1 * i, -2.0], orientation=[0.0, 0.0, 0.0, 1.0]))
            w.write("dead_reckoning", PoseStamped(header=_h(i, "world", 500), position=[0.5 * i, 0.0, -2.0], yaw=0.1 * i))
            w.write("imu_adis_ros", Imu(header=_h(i, "imu", 50), roll=0.0, pitch=0.0, yaw=0.1, qx=0.0, qy=0.0,
                                        qz=0.05, qw=0.99875, az=9.81))
            w.write("depth_sensor", Depth(header=_h(i, "depth", 50), depth=2.0 + 0.01 * i))
        w.write("sonar_micron_ros", LaserScan(header=_h(0, "micron"), angle_min=0.0, angle_max=0.1, angle_increment=0.1,
                                              range_min=0.5, range_max=20.0, ranges=np.array([1.0, 2.0], np.float32),
                                              intensities=np.array([3.0, 4.0], np.float32)))
        w.write("dvl_linkquest", LinkquestDvl(
            header=_h(1, "dvl"), datagood=[1, 1, 1, 1], altitudebeam=[2.0] * 4, bottomvelocitybeam=[0.1] * 4,
            watervelocitybeam=[0.0] * 4, watervelocitycredit=[0.0] * 4, velocityinst=[0.3, 0.0, 0.0],
            velocityinstflag=1, velocityearth=[0.0] * 3, velocityearthflag=0, watervelocityinst=[0.0] * 3,
            watervelocityinstflag=0, watervelocityearth=[0.0] * 3, watervelocityearthflag=0, roll=0.0, pitch=0.0,
            heading=90.0, altitude=2.0, temperature=15.0, pressure=1.0, salinity=0.0, soundspeed=1500.0))
        w.write("fix", NavSatFix(header=_h(2, "gps"), status=0, latitude=41.95, longitude=3.22, altitude=0.5))
        w.write("tf", TFMessage(header=_h(2), transforms=[TransformStamped(
            header=_h(2, "world"), child_frame_id="base_link", translation=[1.0, 2.0, 3.0], rotation=[0, 0, 0, 1])]))
        for i in range(3):
            w.write("experience_event", ExperienceEvent(header=_h(i, "world", 1000), lvc_id=i, pc_centroid=[i, 0, 0, 0],
                                                        odom_position=[0.5 * i, 0, -2], odom_yaw=0.0, gate="vpr",
                                                        vpr_count=i))
            nodes = [ExperienceNode(id=k, lvc_id=k, position=[2.0 * k, 0.0, -2.0], yaw=0.0, stamp=_h(k).stamp)
                     for k in range(i + 2)]
            links = [ExperienceLink(source=k, target=k + 1, delta=[2.0, 0.0, 0.0], duration_s=1.0, weight=1.0)
                     for k in range(i + 1)]
            if i == 2:
                links.append(ExperienceLink(source=3, target=0, delta=[-6.0, 0, 0], duration_s=1.0, weight=1.0,
                                            loop_closure=True))
            w.write("map", ExperienceMap(header=_h(i, "world", 1000), nodes=nodes, links=links, current=i + 1))
        counts = dict(w.counts)
    # a raw-carried vendor message from a ROS 1 bag, appended through the importer's own path
    vendor = path.parent / "v.bag"
    _vendor_bag(vendor, ros2=False, n=3)
    import_sources([vendor], path.parent / "vendor.mcap", progress=False)
    with RecordingWriter(path.parent / "all.mcap") as w:
        for src in (path, path.parent / "vendor.mcap"):
            for r in read_messages(src):
                w.write_encoded(r.key, r.type_name, r.payload, r.stamp, r.seq)
        counts = dict(w.counts)
    return path.parent / "all.mcap", counts


_EXPECTED_SCHEMAS = {
    "/camera/image_raw": "foxglove.RawImage", "/experience_image": "foxglove.RawImage",
    "/sonar_micron": "foxglove.PointCloud", "/sonar_micron_ros": "foxglove.LaserScan",
    "/Odometry": "foxglove.PoseInFrame", "/Odometry/path": "foxglove.PosesInFrame",
    "/dead_reckoning": "foxglove.PoseInFrame", "/dead_reckoning/path": "foxglove.PosesInFrame",
    "/map": "foxglove.SceneUpdate", "/local_view_cells": "foxglove.Log", "/experience_event": "foxglove.Log",
    "/fix": "foxglove.LocationFix", "/imu_adis_ros": "sensor_msgs/msg/Imu",
    "/depth_sensor": "cirs_girona_cala_viuda/msg/Depth", "/dvl_linkquest": "cirs_girona_cala_viuda/msg/LinkquestDvl",
    "/neocortex/sdr": "poseidon_msgs/msg/NeocortexSdr", "/tf": "tf2_msgs/msg/TFMessage",
    "/thrusters/status": _VENDOR, "/counter": "vendor_msgs/msg/NoHeader",
}


def _messages(path: Path, keys: list[str] | None = None) -> list[Any]:
    """The decoded messages of a recording (typed loosely: each test reads its type's fields)."""
    return [r.message() for r in read_messages(path, keys=keys)]


def _decode_all(path: Path) -> dict[str, list[tuple[str, Any]]]:
    """Every message of a Foxglove export decoded against the schema stored in the file."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    decoded: defaultdict[str, list[tuple[str, Any]]] = defaultdict(list)
    classes: dict[int, Callable[[bytes], Any]] = {}
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f, validate_crcs=True).iter_messages():
            assert schema is not None, channel.topic
            if schema.id not in classes:
                if schema.encoding == "protobuf":
                    assert channel.message_encoding == "protobuf"
                    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                    pool = descriptor_pool.DescriptorPool()
                    for fd in fds.file:
                        pool.Add(fd)
                    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
                    classes[schema.id] = cls.FromString
                else:  # ROS definitions as stored: a fresh typestore knows nothing but the schema text
                    is2 = schema.encoding == "ros2msg"
                    assert (schema.encoding, channel.message_encoding) in (("ros2msg", "cdr"), ("ros1msg", "ros1"))
                    store = get_typestore(Stores.EMPTY)
                    store.register(get_types_from_msg(schema.data.decode(), schema.name))

                    def ros_decode(b: bytes, s: Any = store, n: str = schema.name, is2: bool = is2) -> Any:
                        return s.deserialize_cdr(b, n) if is2 else s.deserialize_ros1(b, n)

                    classes[schema.id] = ros_decode
            decoded[channel.topic].append((schema.name, classes[schema.id](msg.data)))
    return dict(decoded)


def test_foxglove_export_well_known_schemas_and_every_payload_decodes(small_run: tuple[Path, dict[str, int]], tmp_path: Path) -> None:
    run, counts = small_run
    out = tmp_path / "fox.mcap"
    summary = export_foxglove(run, out)
    assert {t: v["schema"] for t, v in summary["topics"].items()} == _EXPECTED_SCHEMAS
    got = _decode_all(out)
    assert {t: v[0][0] for t, v in got.items()} == _EXPECTED_SCHEMAS
    for key, n in counts.items():  # every message of the run is in the export once (paths come on top)
        topic = {"raw/thrusters/status": "/thrusters/status", "raw/counter": "/counter"}.get(key, "/" + key)
        assert len(got[topic]) == n, topic
    # content survives
    src: dict[str, list[Any]] = {k: [r.message() for r in read_messages(run) if r.key == k] for k in counts}
    img = got["/camera/image_raw"][1][1]
    assert (img.width, img.height, img.encoding, img.step) == (8, 6, "rgb8", 24)
    assert img.data == np.asarray(src["camera/image_raw"][1].data).tobytes()
    assert got["/experience_image"][0][1].encoding == "mono8"
    cloud = got["/sonar_micron"][5][1]
    pts = np.frombuffer(cloud.data, "<f4").reshape(-1, 4)
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"] and pts.shape == (10, 4)
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), (np.arange(10) + 0.5) * 2.0, rtol=1e-6)
    np.testing.assert_array_equal(pts[:, 3], np.arange(10) * 5)
    pose = got["/Odometry"][4][1]
    assert (pose.frame_id, pose.pose.position.x, pose.pose.position.z) == ("world", 2.0, -2.0)
    paths = got["/Odometry/path"]
    assert len(paths[-1][1].poses) >= 2 and paths[-1][1].poses[-1].position.x == 5.5  # ends at the last pose
    scene = got["/map"][-1][1]
    ent, = scene.entities
    assert ent.id == "experience_map" and len(ent.spheres) == 4
    assert sorted(len(line.points) for line in ent.lines) == [2, 6]  # 1 loop closure, 3 odometry links
    logs = [m.message for _, m in got["/local_view_cells"]]
    assert logs[0].startswith("LVC 0 new") and "LVC 0 I=17" in logs[3]
    assert "LVC 2 gate=vpr" in got["/experience_event"][2][1].message
    assert got["/fix"][0][1].latitude == 41.95
    assert got["/neocortex/sdr"][0][1].fused.active.tolist() == [1, 5, 9]
    assert [m.state for _, m in got["/thrusters/status"]] == [0, 1, 2]


def test_ros2_export_reads_back_with_same_counts(small_run: tuple[Path, dict[str, int]], tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    run, counts = small_run
    summary = export_rosbag(run, tmp_path / "bag2", ros2=True)
    want = {({"raw/thrusters/status": "/thrusters/status", "raw/counter": "/counter"}.get(k, "/" + k)): n
            for k, n in counts.items()}
    assert _bag_counts_decoded(tmp_path / "bag2") == want
    types = {t: v["type"] for t, v in summary["topics"].items()}
    assert types["/camera/image_raw"] == "sensor_msgs/msg/Image" and types["/Odometry"] == "nav_msgs/msg/Odometry"
    assert types["/local_view_cells"] == "poseidon_msgs/msg/LocalViewCells"
    assert types["/sonar_micron"] == "cirs_girona_cala_viuda/msg/RangeImageBeam"
    assert types["/dead_reckoning"] == "geometry_msgs/msg/PoseStamped" and types["/thrusters/status"] == _VENDOR
    with AnyReader([tmp_path / "bag2"]) as r:  # the reader knows poseidon_msgs from the bag's own definitions
        msgs: defaultdict[str, list[tuple[int, Any]]] = defaultdict(list)
        for c, t, raw in r.messages():
            msgs[c.topic].append((t, r.deserialize(raw, c.msgtype)))
    lvc = msgs["/local_view_cells"][3][1]
    assert (lvc.most_active_cell, lvc.is_new, lvc.intersection, [c.id for c in lvc.active_cells]) == (0, False, 17, [0, 7])
    m = msgs["/map"][2][1]
    assert len(m.nodes) == 4 and [k.loop_closure for k in m.links] == [False] * 3 + [True]
    img = msgs["/camera/image_raw"][2][1]
    src = _messages(run, keys=["camera/image_raw"])[2]
    assert bytes(img.data) == np.asarray(src.data).tobytes() and img.step == 24
    t0, odo = msgs["/Odometry"][3]
    assert t0 == T0 + 3 * 500_000_000 and odo.pose.pose.position.x == 1.5 and odo.header.frame_id == "world"


def test_ros1_export_of_the_run(small_run: tuple[Path, dict[str, int]], tmp_path: Path) -> None:
    run, counts = small_run
    export_rosbag(run, tmp_path / "run.bag", ros2=False)
    assert sum(_bag_counts_decoded(tmp_path / "run.bag").values()) == sum(counts.values())


def test_export_cli(small_run: tuple[Path, dict[str, int]], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run, counts = small_run
    rc = export_main([str(run), "--foxglove", str(tmp_path / "f.mcap"), "--ros2", str(tmp_path / "b2"), "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert [e["format"] for e in out["exports"]] == ["foxglove", "ros2"]
    assert sum(v["count"] for v in out["exports"][1]["topics"].values()) == sum(counts.values())
    # existing output, missing input: exit 2 naming the file
    assert export_main([str(run), "--ros2", str(tmp_path / "b2")]) == 2
    assert "b2: exists" in capsys.readouterr().err
    assert export_main([str(tmp_path / "nope.mcap"), "--foxglove", str(tmp_path / "g.mcap")]) == 2
    assert "nope.mcap" in capsys.readouterr().err and not (tmp_path / "g.mcap").exists()
    with pytest.raises(ExportError, match="exists"):
        export_foxglove(run, tmp_path / "f.mcap")


def test_corrupt_chunk_rejected_with_offset_and_the_rest_imported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Only records the reader cannot read are rejected: with the reason and the chunk's byte offset."""
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    from missions.importers.cli import main as import_main

    st = get_typestore(Stores.ROS1_NOETIC)
    T = st.types
    bag = tmp_path / "c.bag"
    w = Writer(bag)
    w.chunk_threshold = 1000  # several chunks of about 13 messages
    with w:
        c = w.add_connection("/pressure", "sensor_msgs/msg/FluidPressure", typestore=st)
        for i in range(60):
            h = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=0),
                                         frame_id="p")
            w.write(c, (1_700_000_000 + i) * 10**9, st.serialize_ros1(
                T["sensor_msgs/msg/FluidPressure"](header=h, fluid_pressure=1e5 + i, variance=0.0),
                "sensor_msgs/msg/FluidPressure"))
    with Reader(bag) as r:
        infos = sorted(r.chunk_infos, key=lambda ci: ci.pos)
        bad = infos[2]
        in_bad = sum(bad.connection_counts.values())
        datapos = r.chunks[bad.pos].datapos
    data = bytearray(bag.read_bytes())
    data[datapos:datapos + 4] = b"\xff\xff\xff\x7f"  # the first record header of the chunk claims 2 GB
    bag.write_bytes(bytes(data))
    rc = import_main([str(bag), "--out", str(tmp_path / "out.mcap"), "--json", "--no-progress"])
    assert rc == 1
    s = json.loads(capsys.readouterr().out)
    rej, = s["rejected"]
    assert rej["offset"]["byte"] == bad.pos and rej["messages"] == {"/pressure": in_bad} and "ReaderError" in rej["reason"]
    t = s["topics"]["/pressure"]
    assert (t["mapped"], t["rejected"], t["in_source"]) == (60 - in_bad, in_bad, 60) and 0 < in_bad < 30
    got = [m.fluid_pressure for m in _messages(tmp_path / "out.mcap")]
    assert len(got) == 60 - in_bad and got[-1] == 1e5 + 59  # chunks after the damaged one are imported


def test_topic_partly_mapped_partly_raw(tmp_path: Path) -> None:
    """An image topic whose frames are mostly rgb8 but one is yuv422 (no model): the odd frame is
    carried raw on raw/<key>; every export keeps all of them."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    st = get_typestore(Stores.ROS1_NOETIC)
    T = st.types
    bag = tmp_path / "cam.bag"
    with Writer(bag) as w:
        c = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=st)
        for i in range(4):
            h = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=0),
                                         frame_id="camera")
            enc = "yuv422" if i == 2 else "rgb8"
            m = T["sensor_msgs/msg/Image"](header=h, height=2, width=2, encoding=enc, is_bigendian=0,
                                           step=4 if i == 2 else 6, data=np.arange(8 if i == 2 else 12, dtype=np.uint8))
            w.write(c, (1_700_000_000 + i) * 10**9, st.serialize_ros1(m, "sensor_msgs/msg/Image"))
    s = import_sources([bag], tmp_path / "run.mcap", progress=False)
    t = s["topics"]["/camera/image_raw"]
    assert (t["mapped"], t["raw"], t["as"], t["raw_key"]) == (3, 1, "mapped+raw", "raw/camera/image_raw")
    assert "yuv422" in next(iter(t["raw_reasons"]))
    fox = export_foxglove(tmp_path / "run.mcap", tmp_path / "f.mcap")["topics"]
    assert fox == {"/camera/image_raw": {"schema": "foxglove.RawImage", "count": 3},
                   "/raw/camera/image_raw": {"schema": "sensor_msgs/msg/Image", "count": 1}}
    assert len(_decode_all(tmp_path / "f.mcap")["/raw/camera/image_raw"]) == 1
    export_rosbag(tmp_path / "run.mcap", tmp_path / "b2", ros2=True)
    assert _bag_counts_decoded(tmp_path / "b2") == {"/camera/image_raw": 4}
    export_rosbag(tmp_path / "run.mcap", tmp_path / "b1.bag", ros2=False)
    assert _bag_payloads(tmp_path / "b1.bag")["/camera/image_raw"][2] == _bag_payloads(bag)["/camera/image_raw"][2]


def test_import_cli_raw_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--raw TOPIC carries a topic with a model raw (exact bytes), the others stay mapped."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from missions.importers.cli import main as import_main

    st = get_typestore(Stores.ROS1_NOETIC)
    T = st.types
    with Writer(tmp_path / "p.bag") as w:
        c = w.add_connection("/pressure", "sensor_msgs/msg/FluidPressure", typestore=st)
        d = w.add_connection("/temp", "sensor_msgs/msg/Temperature", typestore=st)
        for i in range(3):
            h = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=0),
                                         frame_id="p")
            w.write(c, T0 + i, st.serialize_ros1(T["sensor_msgs/msg/FluidPressure"](header=h, fluid_pressure=1e5,
                                                                                   variance=1.0),
                                                 "sensor_msgs/msg/FluidPressure"))
            w.write(d, T0 + i, st.serialize_ros1(T["sensor_msgs/msg/Temperature"](header=h, temperature=12.5 + i,
                                                                                 variance=0.0),
                                                 "sensor_msgs/msg/Temperature"))
    assert import_main([str(tmp_path / "p.bag"), "--out", str(tmp_path / "o.mcap"), "--raw", "/pressure", "--json",
                        "--no-progress"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["written"] == {"raw/pressure": 3, "temp": 3}
    assert s["topics"]["/pressure"]["raw_reasons"] == {"carried raw on request (--raw)": 3}
    temps = [m.temperature for m in _messages(tmp_path / "o.mcap", keys=["temp"])]
    assert temps == [12.5, 13.5, 14.5]
