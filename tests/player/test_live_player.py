"""The live player (services/player/live.py): a recording published by the wall clock as a live
source -- its pace, end-of-stream on absent sensors, latency matched by stamp and published on
``live/latency``, a stop before the end."""
import queue
import threading
import time

import pytest

from common.codec import decode, decode_frame, encode
from common.live import LATENCY_KEY
from common.mcap_io import RecordingWriter
from common.messages import Depth, Header, LatencyReport, LatencyStage, Odometry
from services.player.live import LivePlayer

pytestmark = pytest.mark.timeout(120)

T0 = 10**18
STEP_NS = 100_000_000  # 0.1 s of event time between messages
STAGES = {"Odometry": "odometry"}


def _depth_recording(path, n=16):
    with RecordingWriter(path) as w:
        for i in range(n):
            w.write("depth_sensor", Depth(header=Header(seq=i, stamp=T0 + i * STEP_NS), depth=float(i)))
    return path


def _echo_service(bus, delay_s):
    """A stand-in service: each depth_sensor frame becomes, ``delay_s`` later, an Odometry of its stamp."""
    pub = bus.publisher("Odometry")

    def on_frame(_key, data):
        f = decode_frame(data)
        if f.kind == "eos":
            pub.send_eos()
        elif f.kind == "data":
            time.sleep(delay_s)
            stamp = f.message().header.stamp
            pub.send(Odometry(header=Header(seq=0, stamp=stamp), position=[0.0, 0.0, 0.0],
                              orientation=[0.0, 0.0, 0.0, 1.0]))
    bus.subscribe_callback("depth_sensor", on_frame)


def _frames(bus, key):
    q: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe(key, q)
    return q


def _drain(q):
    out = []
    while not q.empty():
        out.append(decode_frame(q.get()[1]))
    return out


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_the_live_player_keeps_the_wall_clock_pace_and_reports_latency_matched_by_stamp(tmp_path, bus, rate):
    """1.5 s of recording takes 1.5 s / rate of wall time; every output is timed against the
    publication of the input of its stamp (the echo adds 30 ms), and the report goes out on
    ``live/latency`` followed by its end-of-stream."""
    src = _depth_recording(tmp_path / "span.mcap")
    _echo_service(bus, 0.03)
    reports = _frames(bus, LATENCY_KEY)
    player = LivePlayer(bus, src, STAGES, rate=rate, report_wait_s=0.2)
    t0 = time.monotonic()
    stats = player.run()
    wall = time.monotonic() - t0
    assert stats.published == {"depth_sensor": 16} and stats.complete and stats.late == {}
    assert 1.5 / rate * 0.95 <= wall < 1.5 / rate + 5.0
    assert stats.behind_ms["p99"] < 200  # it kept its schedule (ms)
    lat = stats.latency["odometry"]
    assert lat["n"] == 16 and lat["unmatched"] == 0
    assert 30.0 <= lat["p50_ms"] <= lat["p99_ms"] <= lat["max_ms"] < 2000.0
    time.sleep(0.2)
    frames = _drain(reports)
    assert [f.kind for f in frames] == ["data", "eos"]
    report = frames[0].message()
    assert isinstance(report, LatencyReport) and report.source == "live_player" and report.rate == rate
    assert report.header.stamp == T0 + 15 * STEP_NS  # the newest input's stamp
    assert report.stages["odometry"].n == 16 and report.stages["odometry"].p50_ms == lat["p50_ms"]


@pytest.mark.parametrize("stall_hold_ms", [0, 300, 2000])
def test_sensors_the_recording_lacks_end_at_once_and_watermarks_keep_a_silent_gap_moving(tmp_path, bus, stall_hold_ms):
    """An absent source key gets end-of-stream before the first message (nobody waits for it);
    while the recording has a 1.1 s gap, wall-clock watermarks still advance its key, once the
    silence has held them back for ``stall_hold_ms`` (common/live.py: Stalls)."""
    with RecordingWriter(tmp_path / "gap.mcap") as w:
        for i, t in enumerate([0, 1, 12]):  # 0, 0.1 s, then 1.2 s
            w.write("depth_sensor", Depth(header=Header(seq=i, stamp=T0 + t * STEP_NS), depth=0.0))
    imu = _frames(bus, "imu_adis")
    depth = _frames(bus, "depth_sensor")
    stats = LivePlayer(bus, tmp_path / "gap.mcap", STAGES, rate=1.0, report_wait_s=0.1,
                       stall_hold_ms=stall_hold_ms).run()
    time.sleep(0.2)
    assert [f.kind for f in _drain(imu)] == ["eos"]
    kinds = [f.kind for f in _drain(depth)]
    assert kinds.count("data") == 3 and kinds[-1] == "eos"
    between = kinds[kinds.index("data") + 2:kinds.index("data", kinds.index("data") + 2)]
    # 1.1 s of silence after two messages 0.1 s apart: a watermark every 100 ms once past the
    # lateness; held from 4 gaps (0.4 s) of silence on, for at most stall_hold_ms
    held = min(stall_hold_ms / 1000, 0.7)
    if held < 0.7:
        assert between.count("watermark") >= 3 and stats.watermarks >= 3
    assert stats.stalls == ({"depth_sensor": 1} if stall_hold_ms else {}) and stats.late == {}
    assert stats.stalled_s.get("depth_sensor", 0.0) == pytest.approx(held, abs=0.15)


def test_a_stopped_live_player_ends_its_streams_and_still_reports(tmp_path, bus):
    src = _depth_recording(tmp_path / "long.mcap", n=40)  # 4 s at real time
    depth = _frames(bus, "depth_sensor")
    reports = _frames(bus, LATENCY_KEY)
    player = LivePlayer(bus, src, STAGES, rate=1.0, report_wait_s=0.1)
    threading.Timer(0.5, player.stop).start()
    t0 = time.monotonic()
    stats = player.run()
    assert time.monotonic() - t0 < 3.5  # the 2 s wait for outputs that never come, then the report
    assert not stats.complete and 0 < stats.published["depth_sensor"] < 40
    time.sleep(0.2)
    assert _drain(depth)[-1].kind == "eos"
    assert [f.kind for f in _drain(reports)] == ["data", "eos"]


def test_a_live_player_needs_a_positive_rate(tmp_path, bus):
    with pytest.raises(ValueError, match="rate must be > 0"):
        LivePlayer(bus, _depth_recording(tmp_path / "r.mcap"), STAGES, rate=0.0)


def test_a_recorded_latency_report_is_not_played_again(tmp_path, bus):
    """A live run's recording holds its ``live/latency``; playing it live again publishes only its inputs."""
    path = tmp_path / "run.mcap"
    with RecordingWriter(path) as w:
        w.write("depth_sensor", Depth(header=Header(seq=0, stamp=T0), depth=0.0))
        w.write(LATENCY_KEY, LatencyReport(header=Header(seq=0, stamp=T0), source="live_player", rate=1.0, stages={}))
    player = LivePlayer(bus, path, STAGES, rate=8.0, report_wait_s=0.1)
    assert player.keys == ["depth_sensor"]


def test_a_latency_report_survives_the_wire():
    r = LatencyReport(header=Header(seq=0, stamp=T0), source="bridge_ros1", rate=0.0,
                      stages={"lvc": LatencyStage(n=3, unmatched=1, p50_ms=1.5, p95_ms=2.0, p99_ms=2.5, max_ms=3.0),
                              "map": LatencyStage(n=0, unmatched=2)})
    assert decode(encode(r), LatencyReport) == r
