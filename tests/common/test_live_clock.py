"""Live watermarks from the wall clock and latency percentiles (the rules of common/live.py)."""
import pytest

from common.live import LatencyTracker, LiveClock

MS = 1_000_000


def test_watermark_follows_the_wall_clock_minus_the_streams_offset_and_the_lateness():
    c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=0)
    assert c.watermark("imu", 10_000 * MS) is None  # nothing seen: no promise
    assert not c.observe("imu", stamp_ns=1_000 * MS, arrival_ns=5_000 * MS)  # offset 4 s
    assert c.watermark("imu", 5_500 * MS) == 1_300 * MS  # 5.5 s - 4 s - 0.2 s
    assert c.watermark("imu", 5_500 * MS) is None  # no newer promise at the same time


def test_a_silent_stream_is_promised_with_the_latest_offset_of_any_stream_and_a_grace():
    c = LiveClock(lateness_ns=100 * MS, stall_hold_ns=0)
    c.observe("imu", 1_000 * MS, 3_000 * MS)
    # dvl never spoke: it does not stall the merge, but promises 2 s less (its first message may be slow)
    assert c.watermark("dvl", 4_000 * MS) is None            # 4 s - 2 s - 0.1 s - 2 s < 0: nothing yet
    assert c.watermark("dvl", 6_500 * MS) == 2_400 * MS
    assert not c.observe("dvl", 2_450 * MS, 6_600 * MS)   # its first message, 0.25 s behind the imu's offset
    assert c.watermark("dvl", 6_750 * MS) == 2_500 * MS   # from then on its own offset and the lateness
    assert LiveClock(100 * MS, unseen_grace_ns=0).watermark("x", 0) is None


def test_a_message_older_than_its_streams_promise_is_late():
    c = LiveClock(lateness_ns=100 * MS, stall_hold_ns=0)
    c.observe("imu", 1_000 * MS, 3_000 * MS)
    assert c.watermark("imu", 4_000 * MS) == 1_900 * MS
    assert c.observe("imu", 1_850 * MS, 4_100 * MS)  # delayed 150 ms more than its predecessor: late
    assert not c.observe("imu", 2_000 * MS, 4_050 * MS)


def test_the_watermark_never_passes_the_streams_last_stamp_backwards_and_tracks_a_faster_clock():
    c = LiveClock(lateness_ns=0, stall_hold_ns=0)
    c.observe("odom", 0, 1_000 * MS)
    c.observe("odom", 8_000 * MS, 2_000 * MS)  # stamps run 8x the wall (rosbag play -r 8): offset follows
    assert c.watermark("odom", 2_100 * MS) == 8_100 * MS


def test_negative_lateness_is_refused():
    with pytest.raises(ValueError, match="lateness"):
        LiveClock(-1)
    with pytest.raises(ValueError, match="stall hold"):
        LiveClock(100 * MS, stall_hold_ns=-1)


def _flow(c: LiveClock, key: str, t0_ms: int, t1_ms: int, every_ms: int, delay_ms: int = 4_000) -> None:
    """Messages of ``key`` arriving every ``every_ms`` from ``t0_ms`` up to ``t1_ms``, ``delay_ms`` after their stamps."""
    for t in range(t0_ms, t1_ms + 1, every_ms):
        c.observe(key, (t - delay_ms) * MS, t * MS)


def test_a_stalled_stream_holds_its_watermark_so_what_comes_after_the_stall_is_not_late():
    # sonar every 10 ms and imu every 20 ms, 4 s after their stamps; then no sonar from 5.0 s to
    # 5.5 s of wall time (its thread starved) while the imu goes on: the beam due at 5.01 s comes at 5.5 s
    for hold_ns, late in ((0, True), (2_000 * MS, False)):
        c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=hold_ns)
        _flow(c, "sonar", 4_000, 5_000, 10)
        _flow(c, "imu", 4_000, 5_480, 20)
        # the plain rule promises 1.2 s at 5.4 s; held since 5.1 s of wall time (4 gaps < half the bound)
        assert c.watermark("sonar", 5_400 * MS) == (1_200 * MS if hold_ns == 0 else None)
        assert c.hold("imu", 5_480 * MS) == 0  # the stream that flows is not held
        assert c.observe("sonar", 1_010 * MS, 5_500 * MS) is late
        _flow(c, "sonar", 5_510, 5_600, 10, delay_ms=4_500)  # the backlog, then the flow as before
        _flow(c, "sonar", 5_610, 5_700, 10)
        assert c.hold("sonar", 5_750 * MS) == 0  # the stall is over: the plain rule again
        assert c.watermark("sonar", 5_750 * MS) is None  # (which promises nothing past its last stamp yet)
    assert c.stalls == {"sonar": 1} and c.stalled_ns == {"sonar": 300 * MS}  # at 5.4 s: 5.4 - 5.0 - 0.1


def test_the_hold_is_bounded_so_a_stream_that_stopped_holds_the_services_back_once():
    c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=2_000 * MS)
    _flow(c, "dvl", 4_000, 5_000, 100)
    assert c.watermark("dvl", 5_300 * MS) == 1_100 * MS  # the plain rule until 4 mean gaps (0.4 s) of silence
    assert c.watermark("dvl", 5_500 * MS) == 1_200 * MS  # held since 5.4 s
    assert c.watermark("dvl", 6_000 * MS) is None
    assert c.watermark("dvl", 7_400 * MS) is None       # 2 s held: the hold's bound
    assert c.watermark("dvl", 7_500 * MS) == 3_300 * MS  # then the plain rule: a stopped sensor, not a stall
    assert c.watermark("dvl", 7_600 * MS) == 3_400 * MS  # and no lag after it
    assert c.stalls == {"dvl": 1} and c.stalled_ns == {"dvl": 2_000 * MS}


def test_a_slow_stream_is_not_held_between_its_messages_nor_a_stream_before_its_second():
    c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=2_000 * MS)
    c.observe("depth", 1_000 * MS, 5_000 * MS)
    assert c.watermark("depth", 5_500 * MS) == 1_300 * MS  # one message: its gaps are unknown, never held
    _flow(c, "dvl", 4_000, 5_000, 330)                     # a 3 Hz sensor: held only past 1.32 s of silence
    assert c.watermark("dvl", 5_250 * MS) == 1_050 * MS
    assert c.watermark("dvl", 6_300 * MS) == 2_100 * MS
    assert c.stalls == {}


def test_latency_matches_outputs_to_inputs_by_stamp_once_per_stage():
    t = LatencyTracker()
    for i in range(100):
        t.arrived(stamp_ns=i * 1000, wall_ns=i * 10 * MS)
    for i in range(100):
        assert t.output("lvc", i * 1000, i * 10 * MS + (i + 1) * MS) == pytest.approx(i + 1)
    assert t.output("lvc", 0, 999 * MS) is None  # already counted
    assert t.output("map", 12345, 0) is None  # no input of that stamp
    s = t.summary()
    assert s["lvc"]["n"] == 100 and s["lvc"]["p50_ms"] == pytest.approx(50.5) and s["lvc"]["max_ms"] == 100
    assert s["lvc"]["p99_ms"] == pytest.approx(99.01)
    assert s["map"] == {"n": 0, "unmatched": 1}
