"""`poseidon import`: real ROS1 bags, bags written here with the Cala Viuda types, bad input."""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import read_messages
from common.messages import Depth, Image, Imu, LaserScan, LinkquestDvl, NavSatFix, Odometry, RangeImageBeam, RawMessage
from missions.importers.cli import import_sources, load_topic_map, main
from missions.importers.errors import InputFormatError
from missions.importers.rosbags_io import make_typestore, rpy_from_quaternion

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
BAGS = DATA / "ros1_bags"
needs_bags = pytest.mark.skipif(not BAGS.is_dir(), reason=f"real ROS1 bags not present at {BAGS}")


def _bag_counts(path: Path) -> dict[str, tuple[str, int]]:
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        return {c.topic: (c.msgtype, c.msgcount) for c in r.connections}


def _recorded(path: Path) -> dict[str, list[Any]]:
    """Every message by key (typed loosely: each test reads the fields of its key's type)."""
    out: dict[str, list[Any]] = {}
    for r in read_messages(path):
        out.setdefault(r.key, []).append(r.message())
    return out


@needs_bags
@pytest.mark.parametrize("name", ["robot_localization_test1.bag", "robot_localization_test2.bag"])
def test_real_ros1_bags_every_message(tmp_path: Path, name: str) -> None:
    bag = BAGS / name
    own = _bag_counts(bag)
    summary = import_sources([bag], tmp_path / "out.mcap", progress=False)
    rec = _recorded(tmp_path / "out.mcap")
    for topic, (_msgtype, count) in own.items():  # every message of every topic, mapped to a model
        assert summary["read"][topic] == count
        t = summary["topics"][topic]
        assert (t["in_source"], t["mapped"], t["raw"], t["as"]) == (count, count, 0, "mapped"), topic
        assert len(rec[topic.lstrip("/")]) == count, topic
    assert summary["rejected"] == []
    if name.endswith("test1.bag"):  # the README's counts
        assert summary["read"] == {"/fix": 989, "/husky_velocity_controller/odom": 3952, "/imu/data": 11865}
        assert summary["written"] == {"fix": 989, "husky_velocity_controller/odom": 3952, "imu/data": 11865}
        fix = rec["fix"][0]
        assert isinstance(fix, NavSatFix) and -90 <= fix.latitude <= 90 and fix.header.frame_id
    imu = rec["imu/data"][0]
    assert isinstance(imu, Imu)
    r, p, y = rpy_from_quaternion(imu.qx, imu.qy, imu.qz, imu.qw)
    assert (imu.roll, imu.pitch, imu.yaw) == (r, p, y)
    odom_keys = [t.lstrip("/") for t, (mt, _) in own.items() if mt.endswith("Odometry")]
    assert odom_keys and all(isinstance(rec[k][0], Odometry) for k in odom_keys)


def _header(store: Any, seq: int, stamp_ns: int, frame: str, ros2: bool) -> Any:
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    t = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    return Header(stamp=t, frame_id=frame) if ros2 else Header(seq=seq, stamp=t, frame_id=frame)


#: (topic, msgtype, stamp, message, expected fields)
Row = tuple[str, str, int, Any, dict[str, Any]]


def _cala_viuda_msgs(store: Any, ros2: bool, n: int = 3) -> list[Row]:
    """(topic, msgtype, stamp, message, expected dict) of every custom and a few standard types."""
    T = store.types
    rows: list[Row] = []
    for k in range(n):
        st = 1_372_687_208_000_000_000 + k * 100_000_000
        def h(off: int, fr: str, k: int = k, st: int = st) -> Any:
            return _header(store, 10 + k, st + off, fr, ros2)

        dvl: dict[str, Any] = dict(errcode="ok", datagood=np.array([1, 0, 1, 1], np.int32), altitudebeam=np.array([2.0, 2.1, 2.2, 2.3]),
                   bottomvelocitybeam=np.array([0.1, 0.2, 0.3, 0.4]) * k, watervelocitybeam=np.zeros(4),
                   watervelocitycredit=np.ones(4), velocityinst=np.array([0.25, -0.1, 0.01 * k]),
                   velocityinstflag=1, velocityearth=np.array([0.2, 0.1, 0.0]), velocityearthflag=1,
                   watervelocityinst=np.zeros(3), watervelocityinstflag=0, watervelocityearth=np.zeros(3),
                   watervelocityearthflag=0, roll=1.5, pitch=-2.0, heading=123.0 + k, altitude=2.05, temperature=15.0,
                   pressure=2853823.582, salinity=0.0, soundspeed=1500.0, rawdata=f"raw{k}")
        rows.append(("/dvl_linkquest", "cirs_girona_cala_viuda/msg/LinkquestDvl", st + 1,
                     T["cirs_girona_cala_viuda/msg/LinkquestDvl"](header=h(1, "dvl"), **dvl), dvl))
        rows.append(("/depth_sensor", "cirs_girona_cala_viuda/msg/Depth", st + 2,
                     T["cirs_girona_cala_viuda/msg/Depth"](header=h(2, "depth"), depth=12.5 + k), {"depth": 12.5 + k}))
        imu: dict[str, Any] = {f: float(i + k) / 7 for i, f in enumerate(
            "roll pitch yaw qx qy qz qw temp mx my mz ax ay az gx gy gz bx by bz".split())}
        rows.append(("/imu_adis", "cirs_girona_cala_viuda/msg/Imu", st + 3,
                     T["cirs_girona_cala_viuda/msg/Imu"](header=h(3, "imu"), **imu), imu))
        beam: dict[str, Any] = dict(angle_grad=10.0 * k, angle_rad=0.157 * k, nbins=5, max_range=20,
                    beam_data=np.array([0, 5, 100, 191, k], np.int32))
        rows.append(("/sonar_micron", "cirs_girona_cala_viuda/msg/RangeImageBeam", st + 4,
                     T["cirs_girona_cala_viuda/msg/RangeImageBeam"](header=h(4, "micron"), **beam), beam))
        img = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3) + k
        rows.append(("/camera/image_raw", "sensor_msgs/msg/Image", st + 5,
                     T["sensor_msgs/msg/Image"](header=h(5, "camera"), height=4, width=6, encoding="rgb8",
                                                is_bigendian=0, step=18, data=img.reshape(-1)),
                     {"height": 4, "width": 6, "encoding": "rgb8", "data": img}))
        import io

        from PIL import Image as PILImage

        png = io.BytesIO()
        PILImage.fromarray(img).save(png, format="PNG")
        rows.append(("/camera/image_compressed", "sensor_msgs/msg/CompressedImage", st + 7,
                     T["sensor_msgs/msg/CompressedImage"](header=h(7, "camera"), format="png",
                                                          data=np.frombuffer(png.getvalue(), np.uint8)),
                     {"height": 4, "width": 6, "encoding": "rgb8", "data": img}))
        scan: dict[str, Any] = dict(angle_min=0.125 * k, angle_max=0.125 * k, angle_increment=0.03125, time_increment=0.0, scan_time=0.0625,  # float32-exact
                    range_min=0.0, range_max=20.0, ranges=np.array([1.0, 2.0], np.float32),
                    intensities=np.array([10.0, 20.0], np.float32))
        rows.append(("/sonar_micron_ros", "sensor_msgs/msg/LaserScan", st + 6,
                     T["sensor_msgs/msg/LaserScan"](header=h(6, "micron"), **scan), scan))
    return rows


def _write_bag(path: Path, ros2: bool, extra_unknown: int = 0, mcap: bool = False) -> list[Row]:
    store = make_typestore(ros2=ros2)
    if extra_unknown:
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg("float64 value\nstring note\n", "foo_msgs/msg/Bar"))
    rows = _cala_viuda_msgs(store, ros2)
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    writer: Writer1 | Writer2 = (
        Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3) if ros2
        else Writer1(path))
    with writer:
        conns: dict[str, Any] = {}
        for topic, msgtype, *_ in rows:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
        for topic, msgtype, stamp, msg, _ in rows:
            raw = store.serialize_cdr(msg, msgtype) if ros2 else store.serialize_ros1(msg, msgtype)
            writer.write(conns[topic], stamp, raw)
        if extra_unknown:
            c = writer.add_connection("/bar", "foo_msgs/msg/Bar", typestore=store)
            Bar = store.types["foo_msgs/msg/Bar"]
            for i in range(extra_unknown):
                m = Bar(value=float(i), note="x")
                writer.write(c, 1_372_687_208_000_000_000 + i,
                             store.serialize_cdr(m, "foo_msgs/msg/Bar") if ros2 else store.serialize_ros1(m, "foo_msgs/msg/Bar"))
    return rows


def _check_field_by_field(out: Path, rows: list[Row], ros2: bool) -> None:
    rec = _recorded(out)
    by_key: dict[str, list[tuple[Any, dict[str, Any]]]] = {}
    for topic, _msgtype, _stamp, msg, exp in rows:
        by_key.setdefault(topic.lstrip("/"), []).append((msg, exp))
    assert set(rec) == set(by_key)
    types = {"dvl_linkquest": LinkquestDvl, "depth_sensor": Depth, "imu_adis": Imu, "sonar_micron": RangeImageBeam,
             "camera/image_raw": Image, "sonar_micron_ros": LaserScan, "camera/image_compressed": Image}
    for key, items in by_key.items():
        got = rec[key]
        assert len(got) == len(items)
        for i, (g, (ros, exp)) in enumerate(zip(got, items)):
            assert isinstance(g, types[key])
            stamp = ros.header.stamp.sec * 1_000_000_000 + ros.header.stamp.nanosec
            assert g.header.stamp == stamp
            assert g.header.frame_id == ros.header.frame_id
            assert g.header.seq == (i if ros2 else ros.header.seq)
            for f, v in exp.items():
                gv = getattr(g, f)
                if isinstance(v, np.ndarray):
                    np.testing.assert_array_equal(np.asarray(gv), v, err_msg=f"{key}.{f}")
                else:
                    assert gv == v, f"{key}.{f}: {gv!r} != {v!r}"


def test_ros1_bag_with_cala_viuda_types_field_by_field(tmp_path: Path) -> None:
    rows = _write_bag(tmp_path / "cv.bag", ros2=False)
    summary = import_sources([tmp_path / "cv.bag"], tmp_path / "out.mcap", progress=False)
    assert {t["as"] for t in summary["topics"].values()} == {"mapped"} and summary["rejected"] == []
    _check_field_by_field(tmp_path / "out.mcap", rows, ros2=False)


def test_ros2_bag_with_cala_viuda_types_field_by_field(tmp_path: Path) -> None:
    rows = _write_bag(tmp_path / "cv2", ros2=True)
    db3 = next((tmp_path / "cv2").glob("*.db3"))
    for src in (tmp_path / "cv2", db3):  # the bag folder or its .db3 file
        summary = import_sources([src], tmp_path / "out.mcap", progress=False)
        assert summary["inputs"][0]["format"] == "ros2"
        _check_field_by_field(tmp_path / "out.mcap", rows, ros2=True)


def test_ros2_mcap_bag(tmp_path: Path) -> None:
    rows = _write_bag(tmp_path / "cv3", ros2=True, mcap=True)
    src = next((tmp_path / "cv3").glob("*.mcap"))
    summary = import_sources([src], tmp_path / "out.mcap", progress=False)
    assert summary["inputs"][0]["format"] == "ros2"
    _check_field_by_field(tmp_path / "out.mcap", rows, ros2=True)


def test_merge_bag_and_csv_chronologically(tmp_path: Path) -> None:
    _write_bag(tmp_path / "cv.bag", ros2=False)
    csv = tmp_path / "depth.csv"
    csv.write_text("%time,field.header.seq,field.header.stamp,field.depth\n"
                   "0,0,1372687208050000000,1.5\n0,1,1372687208150000000,1.6\n")
    summary = import_sources([tmp_path / "cv.bag", csv], tmp_path / "out.mcap", progress=False)
    assert summary["written"]["depth_sensor"] == 3 + 2
    stamps = [m.header.stamp for m in _recorded(tmp_path / "out.mcap")["depth_sensor"]]
    assert stamps == sorted(stamps) and 1372687208050000000 in stamps


def test_unknown_type_is_carried_raw_and_rest_imported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = _write_bag(tmp_path / "u.bag", ros2=False, extra_unknown=7)
    rc = main([str(tmp_path / "u.bag"), "--out", str(tmp_path / "out.mcap"), "--json", "--no-progress"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    bar = summary["topics"]["/bar"]
    assert (bar["type"], bar["raw"], bar["mapped"], bar["as"], bar["raw_key"]) == ("foo_msgs/Bar", 7, 0, "raw", "raw/bar")
    assert bar["raw_reasons"] == {"no model for foo_msgs/Bar": 7}
    assert summary["written"]["raw/bar"] == 7
    assert sum(summary["written"].values()) == len(rows) + 7
    raw = _recorded(tmp_path / "out.mcap")["raw/bar"]
    assert all(isinstance(m, RawMessage) and m.ros_type == "foo_msgs/msg/Bar" and m.serialization == "ros1"
               and "float64 value" in m.definition for m in raw)


def test_topic_map_renames_and_drops(tmp_path: Path) -> None:
    _write_bag(tmp_path / "cv.bag", ros2=False)
    tm = tmp_path / "map.yaml"
    tm.write_text("/imu_adis: imu_adis_ros\n/sonar_micron_ros: null\n")
    summary = import_sources([tmp_path / "cv.bag"], tmp_path / "out.mcap", load_topic_map(tm), progress=False)
    assert "imu_adis_ros" in summary["written"] and "imu_adis" not in summary["written"]
    assert summary["dropped_topics"] == {"/sonar_micron_ros": 3}  # 3 messages per topic in the test bag
    bad = tmp_path / "bad.yaml"
    bad.write_text("/imu_adis: /with/slash\n")
    with pytest.raises(InputFormatError, match=r"bad\.yaml.*/imu_adis"):
        load_topic_map(bad)


@needs_bags
def test_truncated_bag_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = BAGS / "robot_localization_test2.bag"
    cut = tmp_path / "cut.bag"
    data = src.read_bytes()
    cut.write_bytes(data[: len(data) * 6 // 10])
    with pytest.raises(InputFormatError, match=r"cut\.bag.*(truncated|unreadable|cannot read)"):
        import_sources([cut], tmp_path / "out.mcap", progress=False)
    assert main([str(cut), "--out", str(tmp_path / "o2.mcap"), "--no-progress"]) == 2
    assert "cut.bag" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.mcap*"))  # no partial recording left behind


def test_frames_folder(tmp_path: Path) -> None:
    from PIL import Image as PILImage

    d = tmp_path / "frames"
    d.mkdir()
    lines = []
    for i in range(3):
        PILImage.fromarray(np.full((8, 10, 3), 40 * i, np.uint8)).save(d / f"frame_{i:06d}.png")
        lines.append(f"frame_{i:06d}.png\t1372687208.{617629 + i * 100000:06d}")
    (tmp_path / "camera_frame_timestamps.txt").write_text("\n".join(lines) + "\n")
    summary = import_sources([d], tmp_path / "out.mcap", progress=False)
    assert summary["written"] == {"camera/image_raw": 3}
    imgs = _recorded(tmp_path / "out.mcap")["camera/image_raw"]
    assert [m.header.stamp for m in imgs] == [1372687208617629000, 1372687208717629000, 1372687208817629000]
    assert int(np.asarray(imgs[2].data)[0, 0, 0]) == 80


def test_empty_folder_and_missing_inputs(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputFormatError, match=r"empty.*empty folder"):
        import_sources([empty], tmp_path / "out.mcap", progress=False)
    with pytest.raises(InputFormatError, match=r"nothere\.bag: no such"):
        import_sources([tmp_path / "nothere.bag"], tmp_path / "out.mcap", progress=False)
    d = tmp_path / "frames"
    d.mkdir()
    from PIL import Image as PILImage

    PILImage.fromarray(np.zeros((4, 4, 3), np.uint8)).save(d / "a.png")
    with pytest.raises(InputFormatError, match=r"missing\.txt: no such timestamps file"):
        import_sources([d], tmp_path / "out.mcap", frames_timestamps=tmp_path / "missing.txt", progress=False)
    with pytest.raises(InputFormatError, match=r"--frame-rate must be > 0"):
        import_sources([d], tmp_path / "out.mcap", frame_rate=0.0, progress=False)


def test_a_folder_of_frames_without_timestamps_in_file_name_order_at_the_frame_rate(tmp_path: Path) -> None:
    from PIL import Image as PILImage

    from common.mcap_io import read_metadata
    d = tmp_path / "lab"
    d.mkdir()
    for i, name in enumerate(["b.jpg", "a.png", "c.jpeg"]):
        PILImage.fromarray(np.full((6, 8, 3), 50 * i, np.uint8)).save(d / name)
    (d / "notes.txt").write_text("not a frame")
    out = tmp_path / "lab.mcap"
    assert main([str(d), "--out", str(out), "--frame-rate", "4", "--no-progress"]) == 0
    imgs = _recorded(out)["camera/image_raw"]
    assert [m.header.stamp for m in imgs] == [0, 250_000_000, 500_000_000]
    assert [m.header.seq for m in imgs] == [0, 1, 2]
    assert [int(np.asarray(m.data)[0, 0, 0]) for m in imgs] == [50, 0, 100]    # a.png, b.jpg, c.jpeg
    assert json.loads(read_metadata(out)["poseidon"]["frames"]) == ["a.png", "b.jpg", "c.jpeg"]


def test_csv_missing_column_via_import(tmp_path: Path) -> None:
    p = tmp_path / "dvl.csv"
    shutil.copyfile(DATA / "girona_caves" / "dvl_linkquest.csv", p) if (DATA / "girona_caves").is_dir() else None
    if not p.exists():
        pytest.skip("Girona DVL log not present")
    lines = p.read_text().splitlines()[:5]
    header = lines[0].split(",")
    drop = header.index("field.velocityInst1")
    cut = [",".join(c for i, c in enumerate(line.split(",")) if i != drop) for line in lines]
    p.write_text("\n".join(cut) + "\n")
    with pytest.raises(InputFormatError, match=r"dvl\.csv: missing column 'field\.velocityinst1'"):
        import_sources([p], tmp_path / "out.mcap", progress=False)


def test_girona_csvs_and_frames_list_via_import(tmp_path: Path) -> None:
    g = DATA / "girona_caves"
    if not g.is_dir():
        pytest.skip(f"Girona logs not present at {g}")
    summary = import_sources([g / "dvl_linkquest.csv", g / "depth_sensor.csv"], tmp_path / "out.mcap", progress=False)
    assert summary["written"] == {"depth_sensor": 19553, "dvl_linkquest": 5564}
    stamps = [r.stamp for r in read_messages(tmp_path / "out.mcap")]
    assert stamps == sorted(stamps) and len(stamps) == 19553 + 5564


_CAMEL_DVL = """std_msgs/Header header
int32[4] dataGood
float64[4] altitudeBeam
float64[4] bottomVelocityBeam
float64[4] waterVelocityBeam
float64[4] waterVelocityCredit
float64[3] velocityInst
int32 velocityInstFlag
float64[3] velocityEarth
int32 velocityEarthFlag
float64[3] waterVelocityInst
int32 waterVelocityInstFlag
float64[3] waterVelocityEarth
int32 waterVelocityEarthFlag
float64 roll
float64 pitch
float64 heading
float64 altitude
float64 temperature
float64 pressure
float64 salinity
float64 soundSpeed
"""


def test_ros1_camelcase_definitions_as_the_original_bags(tmp_path: Path) -> None:
    """The 2013 bags spell the DVL fields in camelCase (as the rostopic CSV columns show) and
    have no errCode/rawData; a definition lacking a required field is carried raw with a reason."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    st = get_typestore(Stores.ROS1_NOETIC)
    st.register(get_types_from_msg(_CAMEL_DVL, "cirs_girona_cala_viuda/msg/LinkquestDvl"))
    st.register(get_types_from_msg("std_msgs/Header header\nfloat64 pressure\n", "cirs_girona_cala_viuda/msg/Depth"))
    T = st.types
    vals: dict[str, Any] = dict(dataGood=np.array([0, 1, 1, 1], np.int32), altitudeBeam=np.array([0.0, 2.0, 2.0, 2.1]),
                bottomVelocityBeam=np.array([0.0, -0.0489, 0.0848, 0.0369]), waterVelocityBeam=np.zeros(4),
                waterVelocityCredit=np.zeros(4), velocityInst=np.array([-0.2424, -0.1145, -0.0065]),
                velocityInstFlag=1, velocityEarth=np.zeros(3), velocityEarthFlag=1, waterVelocityInst=np.zeros(3),
                waterVelocityInstFlag=0, waterVelocityEarth=np.zeros(3), waterVelocityEarthFlag=0, roll=0.0,
                pitch=0.0, heading=0.0, altitude=2.0, temperature=15.0, pressure=2853823.582, salinity=0.0,
                soundSpeed=1500.0)
    hdr = T["std_msgs/msg/Header"](seq=1245, stamp=T["builtin_interfaces/msg/Time"](sec=1372687208, nanosec=633787539),
                                   frame_id="dvl")
    with Writer(tmp_path / "orig.bag") as w:
        c = w.add_connection("/dvl_linkquest", "cirs_girona_cala_viuda/msg/LinkquestDvl", typestore=st)
        d = w.add_connection("/depth_sensor", "cirs_girona_cala_viuda/msg/Depth", typestore=st)
        w.write(c, 1372687208632644971, st.serialize_ros1(T["cirs_girona_cala_viuda/msg/LinkquestDvl"](
            header=hdr, **vals), "cirs_girona_cala_viuda/msg/LinkquestDvl"))
        w.write(d, 1372687208632644972, st.serialize_ros1(T["cirs_girona_cala_viuda/msg/Depth"](
            header=hdr, pressure=1.0), "cirs_girona_cala_viuda/msg/Depth"))
    summary = import_sources([tmp_path / "orig.bag"], tmp_path / "out.mcap", progress=False)
    assert summary["written"] == {"dvl_linkquest": 1, "raw/depth_sensor": 1}  # kept, unchanged, with the reason
    (reason, n), = summary["topics"]["/depth_sensor"]["raw_reasons"].items()
    assert n == 1 and "no lossless conversion" in reason and "'depth'" in reason
    m = _recorded(tmp_path / "out.mcap")["dvl_linkquest"][0]
    assert (m.header.seq, m.header.stamp) == (1245, 1372687208633787539)
    assert m.datagood == [0, 1, 1, 1] and m.velocityinst == [-0.2424, -0.1145, -0.0065] and m.soundspeed == 1500.0
    assert m.errcode == "" and m.rawdata == ""


def test_image_encodings() -> None:
    from types import SimpleNamespace

    from common.messages import Header
    from missions.importers.rosbags_io import CONVERTERS, ConversionError

    conv = CONVERTERS["sensor_msgs/Image"]
    h = Header(seq=0, stamp=1)
    # padded rows (step > width * channels) are cropped
    raw = np.arange(2 * 10, dtype=np.uint8)
    m = conv(SimpleNamespace(encoding="8UC3", height=2, width=3, step=10, is_bigendian=0, data=raw), h)
    assert isinstance(m, Image)
    assert m.encoding == "bgr8"
    np.testing.assert_array_equal(np.asarray(m.data), np.stack([raw[:9], raw[10:19]]).reshape(2, 3, 3))
    m = conv(SimpleNamespace(encoding="mono16", height=1, width=2, step=4, is_bigendian=1,
                             data=np.array([1, 2, 3, 4], np.uint8)), h)
    assert isinstance(m, Image)
    np.testing.assert_array_equal(np.asarray(m.data), [[258, 772]])
    with pytest.raises(ConversionError, match="yuv422"):
        conv(SimpleNamespace(encoding="yuv422", height=1, width=2, step=4, is_bigendian=0,
                             data=np.zeros(4, np.uint8)), h)
    with pytest.raises(ConversionError, match="expected step"):
        conv(SimpleNamespace(encoding="rgb8", height=2, width=2, step=6, is_bigendian=0,
                             data=np.zeros(7, np.uint8)), h)


def test_topic_option_maps_a_topic_onto_our_key_when_its_type_converts(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    from common.mcap_io import read_metadata
    from missions.importers.cli import parse_topic_args
    _write_bag(tmp_path / "cv.bag", ros2=False)
    out = tmp_path / "out.mcap"
    assert main([str(tmp_path / "cv.bag"), "--topic", "/imu_adis=imu_adis_ros", "--out", str(out), "--no-progress",
                 "--json"]) == 0
    written = json.loads(capsys.readouterr().out)["written"]
    assert "imu_adis_ros" in written and "imu_adis" not in written
    topics = json.loads(read_metadata(out)["poseidon"]["topics"])
    assert topics["/imu_adis"] == {"type": "cirs_girona_cala_viuda/Imu", "key": "imu_adis_ros"}
    # an IMU on the DVL's key would fail in the service: refused, naming both types, nothing written
    bad = tmp_path / "bad.mcap"
    assert main([str(tmp_path / "cv.bag"), "--topic", "/imu_adis=dvl_linkquest", "--out", str(bad),
                 "--no-progress"]) == 2
    assert "converts to Imu, but key 'dvl_linkquest' carries LinkquestDvl" in capsys.readouterr().err
    assert not list(tmp_path.glob("bad.mcap*"))
    assert parse_topic_args(["imu/data=imu_adis", "/x = y"]) == {"/imu/data": "imu_adis", "/x": "y"}
    for wrong in ("/imu/data", "/imu/data=", "=imu_adis", "/imu/data=/imu_adis"):
        with pytest.raises(InputFormatError, match="TOPIC=KEY"):
            parse_topic_args([wrong])
