"""The driver API (common/driver.py): records of a non-ROS sensor reach the bus with their stamps,
silent announced keys get wall-clock watermarks, close ends every stream; the folder example."""
import importlib.util
import queue
import threading
import time

import numpy as np
import pytest
from PIL import Image as PILImage

from common.codec import decode_frame
from common.driver import Pacer, SensorDriver
from common.mcap_io import read_messages
from common.messages import Image, Imu, LinkquestDvl, RangeImageBeam
from services.recorder.recorder import Recorder
from tests.conftest import REPO

KEYS = ["camera/image_raw", "sonar_micron", "dvl_linkquest", "imu_adis_ros"]


def _record(bus, path, expect):
    rec = Recorder(bus, path, expect=expect)
    result = {}
    t = threading.Thread(target=lambda: result.setdefault("stats", rec.run()), daemon=True)
    t.start()
    bus.wait_alive(["recorder"], 10)
    return t, result


def test_each_kind_of_record_is_published_with_its_stamp_and_the_streams_end_at_close(bus, tmp_path):
    out = tmp_path / "drv.mcap"
    t, result = _record(bus, out, KEYS + ["depth_sensor"])
    watch: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe("depth_sensor", watch)
    with SensorDriver(bus, announce=["depth_sensor"], watermark_interval_ms=20) as drv:
        drv.camera_frame(np.zeros((4, 6, 3), np.uint8), stamp_ns=1_000)
        drv.camera_frame(np.full((4, 6), 7, np.uint8), stamp_ns=2_000)
        drv.sonar_beam(0.5, [1, 2, 3], 20, stamp_ns=1_500)
        drv.dvl([0.3, 0.0, 0.01], 2.5, stamp_ns=1_600, heading=90.0)
        drv.dvl([0.0, 0.0, 0.0], 0.0, stamp_ns=1_700, valid=False)
        drv.imu(0.0, 0.0, np.pi / 2, gyro=(0, 0, 0.1), stamp_ns=1_800)
        time.sleep(2.5)   # > lateness + the 2 s grace of a key that never spoke (common.live)
        assert drv.published == {"camera/image_raw": 2, "sonar_micron": 1, "dvl_linkquest": 2, "imu_adis_ros": 1}
        with pytest.raises(ValueError, match="camera frame on camera/image_raw"):
            drv.camera_frame(np.zeros((2, 2, 2), np.uint8))
    t.join(10)
    assert not t.is_alive(), "the recorder did not see end-of-stream on every key"
    kinds: list[str] = []
    while "eos" not in kinds:
        kinds.append(decode_frame(watch.get(timeout=5)[1]).kind)
    assert "watermark" in kinds and kinds[-1] == "eos"  # the silent announced key was kept alive, then ended
    msgs = {k: [(m.stamp, m.message()) for m in read_messages(out, keys=[k])] for k in KEYS}
    (s0, im0), (s1, im1) = msgs["camera/image_raw"]
    assert (s0, s1) == (1_000, 2_000) and isinstance(im0, Image) and im0.encoding == "rgb8"
    assert im1.encoding == "mono8" and int(im1.data[0, 0]) == 7 and im1.header.seq == 1
    beam = msgs["sonar_micron"][0][1]
    assert isinstance(beam, RangeImageBeam) and list(beam.beam_data) == [1, 2, 3] and beam.max_range == 20
    d_ok, d_bad = (m for _s, m in msgs["dvl_linkquest"])
    assert isinstance(d_ok, LinkquestDvl) and d_ok.velocityinst == [0.3, 0.0, 0.01] and d_ok.heading == 90.0
    assert d_ok.velocityinstflag == 1 and d_bad.velocityinstflag == 0 and d_bad.datagood == [0, 0, 0, 0]
    imu = msgs["imu_adis_ros"][0][1]
    assert isinstance(imu, Imu) and imu.gz == 0.1 and imu.qz == pytest.approx(np.sqrt(0.5))


class FakeClock:
    """A pacing clock that only moves when slept on or when work is simulated (``spend``)."""

    def __init__(self, start_ns: int = 5_000_000_000):
        self.now = start_ns
        self.sleeps: list[float] = []

    def clock_ns(self) -> int:
        return self.now

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += int(round(s * 1e9))

    def spend(self, ms: float) -> None:
        self.now += int(round(ms * 1e6))


def _pacer(clock: FakeClock, rate_hz: float) -> Pacer:
    return Pacer(rate_hz, clock_ns=clock.clock_ns, sleep=clock.sleep, wall_ns=lambda: 1_000_000_000_000)


def test_the_pacer_stamps_each_record_with_its_scheduled_instant_whatever_the_work_before_it():
    clock = FakeClock()
    pacer = _pacer(clock, 20.0)
    stamps = []
    for i, work_ms in enumerate([12.0, 1.0, 30.0, 0.0]):  # reading the first frame is the slowest
        clock.spend(work_ms)
        stamps.append(pacer.wait(i))
    assert [s - 1_000_000_000_000 for s in stamps] == [0, 50_000_000, 100_000_000, 150_000_000]
    assert clock.sleeps == pytest.approx([0.049, 0.020, 0.050])  # to the absolute schedule, not after the last send


def test_the_pacer_stamps_an_overdue_record_when_it_is_taken_and_keeps_the_schedule_after_it():
    clock = FakeClock()
    pacer = _pacer(clock, 10.0)
    assert pacer.wait(0) == 1_000_000_000_000
    clock.spend(250.0)  # a stall: records 1 and 2 are overdue
    assert pacer.wait(1) - 1_000_000_000_000 == 250_000_000
    assert pacer.wait(2) - 1_000_000_000_000 == 250_000_000
    assert pacer.wait(3) - 1_000_000_000_000 == 300_000_000  # back on the schedule, not shifted by the stall
    with pytest.raises(ValueError, match="rate"):
        Pacer(0.0)


def test_the_example_streams_a_folder_of_images_on_its_schedule(bus, tmp_path):
    spec = importlib.util.spec_from_file_location("stream_images", REPO / "deploy" / "examples" / "stream_images.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(5):
        PILImage.fromarray(np.full((8, 10, 3), 40 * i, np.uint8)).save(folder / f"f{i:03d}.png")
    (folder / "notes.txt").write_text("not an image")
    out = tmp_path / "frames.mcap"
    t, _result = _record(bus, out, ["camera/image_raw"])
    clock = FakeClock()
    with SensorDriver(bus, lateness_ms=60_000) as drv:  # stamps from the fake clock's epoch: never late
        assert mod.stream_folder(drv, folder, rate_hz=20.0, pacer=Pacer(20.0, clock.clock_ns, clock.sleep)) == 5
    t.join(10)
    rec = list(read_messages(out, keys=["camera/image_raw"]))
    assert [int(m.message().data[0, 0, 0]) for m in rec] == [0, 40, 80, 120, 160]  # name order
    assert [m.stamp - rec[0].stamp for m in rec] == [i * 50_000_000 for i in range(5)]  # 20 frames/s
    with pytest.raises(ValueError, match="rate"):
        mod.stream_folder(drv, folder, rate_hz=0)


def test_a_supervised_driver_replays_what_a_restarted_consumer_missed_and_forgets_what_all_checkpointed(bus):
    import json

    from common.messages import Depth, Header
    got: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe_callback("depth_sensor", lambda _k, data: got.put(decode_frame(data)))
    driver = SensorDriver(bus, consumers={"depth_sensor": ["robot_state", "recorder"]}, retain_s=60.0)
    try:
        time.sleep(0.2)
        for i in range(6):
            driver.publish("depth_sensor", Depth(header=Header(seq=i, stamp=1_000_000_000 + i), depth=float(i)))
        bus.session.put(bus.full_key("@replay/depth_sensor"), json.dumps({"from": 2, "by": "robot_state"}).encode())
        deadline = time.monotonic() + 10
        frames = []
        while time.monotonic() < deadline and not any(f.kind == "replay" for f in frames):
            driver.source.send_watermarks()  # the ticker answers too; this makes it now
            try:
                frames.append(got.get(timeout=0.2))
            except queue.Empty:
                pass
        until = time.monotonic() + 1.0  # the replay's frames follow its R frame (watermarks keep coming)
        while time.monotonic() < until:
            try:
                frames.append(got.get(timeout=0.2))
            except queue.Empty:
                pass
        start = next(i for i, f in enumerate(frames) if f.kind == "replay")
        assert (frames[start].index, frames[start].type_name) == (2, "robot_state")
        assert [f.index for f in frames[start + 1:] if f.kind == "data"] == [2, 3, 4, 5]
        for who in ("robot_state", "recorder"):  # both checkpointed past 4: frames 0..3 are forgotten
            bus.session.put(bus.full_key(f"@ckpt/{who}"), json.dumps({"depth_sensor": 4}).encode())
        deadline = time.monotonic() + 10
        pub = driver.source.publishers()[0]
        while time.monotonic() < deadline and pub.retained[0][0] != 4:
            time.sleep(0.05)
        assert [i for i, _f in pub.retained] == [4, 5]
    finally:
        driver.close()
