"""Live watermarks from the wall clock and latency percentiles (the rules of common/live.py)."""
import pytest

from common.live import LatencyTracker, LiveClock

MS = 1_000_000


def test_watermark_follows_the_wall_clock_minus_the_streams_offset_and_the_lateness():
    c = LiveClock(lateness_ns=200 * MS)
    assert c.watermark("imu", 10_000 * MS) is None  # nothing seen: no promise
    assert not c.observe("imu", stamp_ns=1_000 * MS, arrival_ns=5_000 * MS)  # offset 4 s
    assert c.watermark("imu", 5_500 * MS) == 1_300 * MS  # 5.5 s - 4 s - 0.2 s
    assert c.watermark("imu", 5_500 * MS) is None  # no newer promise at the same time


def test_a_silent_stream_is_promised_with_the_latest_offset_of_any_stream_and_a_grace():
    c = LiveClock(lateness_ns=100 * MS)
    c.observe("imu", 1_000 * MS, 3_000 * MS)
    # dvl never spoke: it does not stall the merge, but promises 2 s less (its first message may be slow)
    assert c.watermark("dvl", 4_000 * MS) is None            # 4 s - 2 s - 0.1 s - 2 s < 0: nothing yet
    assert c.watermark("dvl", 6_500 * MS) == 2_400 * MS
    assert not c.observe("dvl", 2_450 * MS, 6_600 * MS)   # its first message, 0.25 s behind the imu's offset
    assert c.watermark("dvl", 6_750 * MS) == 2_500 * MS   # from then on its own offset and the lateness
    assert LiveClock(100 * MS, unseen_grace_ns=0).watermark("x", 0) is None


def test_a_message_older_than_its_streams_promise_is_late():
    c = LiveClock(lateness_ns=100 * MS)
    c.observe("imu", 1_000 * MS, 3_000 * MS)
    assert c.watermark("imu", 4_000 * MS) == 1_900 * MS
    assert c.observe("imu", 1_850 * MS, 4_100 * MS)  # delayed 150 ms more than its predecessor: late
    assert not c.observe("imu", 2_000 * MS, 4_050 * MS)


def test_the_watermark_never_passes_the_streams_last_stamp_backwards_and_tracks_a_faster_clock():
    c = LiveClock(lateness_ns=0)
    c.observe("odom", 0, 1_000 * MS)
    c.observe("odom", 8_000 * MS, 2_000 * MS)  # stamps run 8x the wall (rosbag play -r 8): offset follows
    assert c.watermark("odom", 2_100 * MS) == 8_100 * MS


def test_negative_lateness_is_refused():
    with pytest.raises(ValueError, match="lateness"):
        LiveClock(-1)


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
