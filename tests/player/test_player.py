"""The player: a source on the shared worker base (common.worker.Source).

Pacing, stopping on an abort, aborting the run when stopped early, waiting for its
consumers, flow control against the slowest one."""
import math
import threading
import time

import pytest

from common.codec import decode_frame, decode_header, split_frames
from common.mcap_io import RecordingWriter
from common.messages import Depth, Header
from services.player.player import Player

pytestmark = pytest.mark.timeout(120)

T0 = 10**18
STEP_NS = 100_000_000  # 0.1 s of event time between messages


def _depth_recording(path, n=16, indices=None):
    """Depth messages at ``indices`` (default 0..n-1) times ``STEP_NS`` after ``T0``."""
    with RecordingWriter(path) as w:
        for i in range(n) if indices is None else indices:
            w.write("depth_sensor", Depth(header=Header(seq=i, stamp=T0 + i * STEP_NS), depth=float(i)))
    return path


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_player_paces_at_real_time_or_faster(tmp_path, bus, rate):
    """1.5 s of recording: real time takes >= 1.5 s of wall time, 4x takes >= 0.375 s."""
    src = _depth_recording(tmp_path / "span.mcap")
    t0 = time.monotonic()
    stats = Player(bus, src, rate=rate, progress=False).run()
    wall = time.monotonic() - t0
    assert stats.published == {"depth_sensor": 16}
    assert stats.event_s == pytest.approx(1.5)
    assert wall >= 1.5 / rate * 0.95
    assert stats.aborted == ""


def test_an_abort_on_the_bus_stops_the_player_and_says_why(tmp_path, bus):
    src = _depth_recording(tmp_path / "span.mcap", n=40)  # 4 s at real time
    player = Player(bus, src, rate=1.0, progress=False)
    threading.Timer(0.5, bus.abort, args=("service x died",)).start()
    t0 = time.monotonic()
    stats = player.run()
    assert time.monotonic() - t0 < 3.0
    assert stats.aborted == "service x died"
    assert 0 < stats.published["depth_sensor"] < 40


def test_a_player_stopped_early_aborts_the_run_and_sends_no_end_of_stream(tmp_path, bus):
    import queue
    src = _depth_recording(tmp_path / "span.mcap", n=40)
    frames: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe("depth_sensor", frames)
    aborts: list[str] = []
    bus.on_abort(aborts.append)
    player = Player(bus, src, rate=1.0, progress=False, announce_absent=())
    threading.Timer(0.5, player.stop).start()
    stats = player.run()
    assert stats.aborted == "player stopped before the end of the recording"
    deadline = time.monotonic() + 5
    while not aborts and time.monotonic() < deadline:
        time.sleep(0.02)
    assert aborts == ["player stopped before the end of the recording"]
    kinds = []
    while not frames.empty():
        kinds.append(decode_frame(frames.get()[1]).kind)
    assert "eos" not in kinds and 0 < kinds.count("data") < 40


def test_source_keys_missing_from_the_recording_end_at_once(tmp_path, bus):
    """A service waiting on a sensor the recording lacks (e.g. the IMU) is not blocked."""
    import queue
    src = _depth_recording(tmp_path / "span.mcap", n=3)
    frames: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe("imu_adis", frames)
    bus.subscribe("depth_sensor", frames)
    time.sleep(0.2)
    Player(bus, src, progress=False).run()
    got: dict[str, list[str]] = {}
    deadline = time.monotonic() + 5
    while not all("eos" in got.get(k, []) for k in ("imu_adis", "depth_sensor")) and time.monotonic() < deadline:
        try:
            key, data = frames.get(timeout=0.2)
        except queue.Empty:
            continue
        got.setdefault(key, []).append(decode_frame(data).kind)
    assert got["imu_adis"][0] == "eos" and "data" not in got["imu_adis"]
    assert got["depth_sensor"][-1] == "eos" and got["depth_sensor"].count("data") == 3


def test_the_player_waits_for_its_consumers_and_names_the_missing_one(tmp_path, bus):
    src = _depth_recording(tmp_path / "span.mcap", n=3)
    with pytest.raises(TimeoutError, match="ghost"):
        Player(bus, src, wait_for=["ghost"], progress=False, startup_timeout_s=0.5).run()


def test_flow_control_holds_the_player_within_the_window_of_the_slowest_consumer(tmp_path, bus):
    """A consumer that reports progress only up to the 5th message: with a 0.2-s window the
    player sends what is within 0.2 s of it and waits; the rest goes once it reports more."""
    import queue
    src = _depth_recording(tmp_path / "span.mcap", n=20)
    frames: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe("depth_sensor", frames)
    bus.declare_alive("slow")
    progress = bus.progress_publisher("slow")
    player = Player(bus, src, wait_for=["slow"], progress=False, flow_window_ms=200, announce_absent=())
    result: dict = {}
    t = threading.Thread(target=lambda: result.setdefault("stats", player.run()))
    t.start()
    time.sleep(0.5)
    assert player.stats.published.get("depth_sensor", 0) == 3  # nothing reported: the window from the first stamp
    progress.report(T0 + 4 * STEP_NS, force=True)
    time.sleep(0.5)
    assert player.stats.published.get("depth_sensor", 0) == 7  # stamps up to 4 + 2 steps (the 0.2-s window)
    progress.report(T0 + 100 * STEP_NS, force=True)
    t.join(timeout=10)
    assert result["stats"].published == {"depth_sensor": 20}


class _Consumer:
    """A consumer of ``depth_sensor`` that reports as progress the newest event time its key
    promised (a data frame's stamp or a watermark), as a service's merger does, after ``work_s``
    of work per data frame; it counts the watermarks it received."""

    def __init__(self, bus, work_s: float):
        self.progress = bus.progress_publisher("consumer")
        self.work_s = work_s
        self.watermarks: list[int] = []
        self.data = 0
        bus.subscribe("depth_sensor", self)
        bus.declare_alive("consumer")

    def put_nowait(self, item) -> None:  # the bus's callback: frames arrive here in order
        frame = decode_frame(item[1])
        if frame.kind == "watermark":
            self.watermarks.append(frame.stamp)
            stamp = frame.stamp
        elif frame.kind == "data":
            self.data += 1
            time.sleep(self.work_s)
            stamp = int(decode_header(frame.payload)["stamp"])
        else:
            return
        self.progress.report(stamp, force=True)


def test_a_held_player_promises_nothing_while_its_consumer_progresses(tmp_path, bus, monkeypatch):
    """Flow control holds the player often (a 0.2-s window, 0.1 s per message), but the consumer
    takes every frame within ms: no watermark is needed, none is sent but the first heartbeat's
    (heartbeats are otherwise off)."""
    import services.player.player as player_module
    monkeypatch.setattr(player_module, "PROMISE_AFTER_S", 2.0)  # far above any wait for a frame's work
    consumer = _Consumer(bus, work_s=0.005)
    src = _depth_recording(tmp_path / "span.mcap", n=30)
    stats = Player(bus, src, wait_for=["consumer"], progress=False, flow_window_ms=200, heartbeat_ms=10**6,
                   announce_absent=()).run()
    assert stats.published == {"depth_sensor": 30}
    deadline = time.monotonic() + 5
    while consumer.data < 30 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert consumer.data == 30 and consumer.watermarks == [T0]


def test_a_gap_longer_than_the_window_is_promised_once_the_consumer_stands_still(tmp_path, bus):
    """Five messages, a 5-s gap (the window is 0.2 s), five more: the consumer's progress stops at
    the gap, so the held player promises the next stamp, and the replay goes on to the end."""
    consumer = _Consumer(bus, work_s=0.0)
    src = _depth_recording(tmp_path / "gap.mcap", indices=[*range(5), *range(55, 60)])
    t0 = time.monotonic()
    stats = Player(bus, src, wait_for=["consumer"], progress=False, flow_window_ms=200,
                   heartbeat_ms=10**6, announce_absent=()).run()
    assert time.monotonic() - t0 < 5.0
    assert stats.published == {"depth_sensor": 10}
    assert consumer.watermarks == [T0, T0 + 55 * STEP_NS]


def _bundled_replay(tmp_path, bus, flow_window_ms, bundle_frames, bundle_ms, n=200):
    """Replay ``n`` depth messages at rate 0 with bundles, check that every frame arrived in
    order and that the player counted the data samples; the number of frames in each data
    sample the bus carried (heartbeats and watermarks left out)."""
    samples: list[bytes] = []
    raw = bus.session.declare_subscriber(bus.full_key("depth_sensor"), lambda s: samples.append(s.payload.to_bytes()))
    consumer = _Consumer(bus, work_s=0.0)
    src = _depth_recording(tmp_path / "many.mcap", n=n)
    stats = Player(bus, src, wait_for=["consumer"], progress=False, flow_window_ms=flow_window_ms,
                   heartbeat_ms=10**6, announce_absent=(), bundle_frames=bundle_frames, bundle_ms=bundle_ms).run()
    deadline = time.monotonic() + 5
    while consumer.data < n and time.monotonic() < deadline:
        time.sleep(0.02)
    raw.undeclare()
    assert stats.published == {"depth_sensor": n} and consumer.data == n
    bundles = [[decode_frame(f) for f in split_frames(s)] for s in samples]
    bundles = [b for b in bundles if b[0].kind == "data"]
    data = [f for b in bundles for f in b]
    assert [f.index for f in data] == list(range(n))
    assert [decode_header(f.payload)["stamp"] for f in data] == [T0 + i * STEP_NS for i in range(n)]
    assert stats.samples == {"depth_sensor": len(bundles)}
    return [len(b) for b in bundles]


@pytest.mark.parametrize(("bundle_frames", "bundle_ms", "sizes"), [
    (4, 1000, [4] * 50),        # full at 4 frames, long before the first is 1 s old
    (8, 300, [3] * 66 + [2]),   # the first frame 0.3 s old (checked every 75 ms of event time)
])
def test_a_bundling_player_that_is_never_held_sends_full_or_aged_bundles(tmp_path, bus, bundle_frames,
                                                                         bundle_ms, sizes):
    """At rate 0 with a window wider than the recording: no hold, so the bundles are set by the
    two rules alone, whatever the machine's speed: full, or its first frame ``bundle_ms`` old
    (the last goes out at the end of the stream)."""
    assert _bundled_replay(tmp_path, bus, 100_000, bundle_frames, bundle_ms) == sizes


def test_a_bundling_player_held_by_its_window_still_delivers_everything_in_bundles(tmp_path, bus):
    """A 1-s window (10 messages), bundles of up to 8 or 0.5 s: the player is held often, and
    what it holds for a bundle goes out before it waits (or the consumer could never catch up).
    Each hold lets a burst of at least 0.5 s go (6 messages), and the age rule cuts R messages
    sent between two holds into at most ceil(R / 5) samples: at most 2 samples per 6 messages,
    however the holds fall on a loaded machine (a sample per message without bundles)."""
    sizes = _bundled_replay(tmp_path, bus, 1000, 8, 500)
    assert max(sizes) <= 8 and len(sizes) <= 2 * math.ceil(200 / 6)
