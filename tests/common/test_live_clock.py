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


def test_a_whole_source_stall_holds_the_watermarks_so_what_comes_after_it_is_not_late():
    # imu and dvl arrive 4 s after their stamps; then nothing at all from 5.0 s to 5.5 s of wall
    # time (rosbag play starved): the imu message due at 5.1 s arrives at 5.5 s
    for hold_ns, late in ((0, True), (2_000 * MS, False)):
        c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=hold_ns)
        c.observe("dvl", 990 * MS, 4_990 * MS)
        c.observe("imu", 1_000 * MS, 5_000 * MS)
        # the plain rule promises 1.2 s at 5.4 s; held since 5.1 s of wall time, 0.9 s: not past the last stamp
        assert c.watermark("imu", 5_400 * MS) == (1_200 * MS if hold_ns == 0 else None)
        assert c.observe("imu", 1_100 * MS, 5_500 * MS) is late
        c.observe("imu", 1_500 * MS, 5_520 * MS)  # the backlog comes through, then the flow as before
        c.observe("dvl", 1_690 * MS, 5_700 * MS)
        assert c.watermark("imu", 5_750 * MS) == 1_530 * MS  # the stall is over: the plain rule again
    assert (c.stalls, c.stalled_ns) == (1, 300 * MS)  # the hold's largest, at 5.4 s: 5.4 - 5.0 - 0.1


def test_the_hold_is_bounded_so_a_source_that_stopped_does_not_stall_the_services():
    c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=2_000 * MS)
    c.observe("imu", 1_000 * MS, 5_000 * MS)
    assert c.watermark("imu", 5_200 * MS) is None       # held since 5.1 s
    assert c.watermark("imu", 7_100 * MS) is None       # 2 s of silence beyond 5.1 s: the hold's bound
    assert c.watermark("imu", 7_600 * MS) == 1_400 * MS  # then the watermark advances again, 2 s behind
    assert c.stalls == 1 and c.stalled_ns == 2_000 * MS


def test_one_silent_stream_among_others_that_arrive_is_not_a_stall():
    c = LiveClock(lateness_ns=200 * MS, stall_hold_ns=2_000 * MS)
    c.observe("dvl", 1_000 * MS, 5_000 * MS)
    for t in range(5_000, 6_000, 50):
        c.observe("imu", (t - 4_000) * MS, t * MS)
    assert c.watermark("dvl", 5_960 * MS) == 1_760 * MS  # a dead sensor's promise follows the wall clock
    assert c.stalls == 0


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
