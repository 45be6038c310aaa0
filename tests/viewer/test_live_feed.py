"""The live feed on an in-process bus: it follows what is published, keeps only bounded buffers
(a flood drops view updates, counted), samples heavy keys, leaves each key at its end-of-stream
(a finished publisher's drain does not wait for the view), and publishes nothing."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from common.bus import Bus
from common.mcap_io import read_messages
from common.messages import Header, Image
from services.viewer.config import ViewConfig
from services.viewer.live import LatencyWindow, LiveFeed
from tests.viewer.runs import write_run


def _wait(cond, timeout_s: float = 10.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


@pytest.mark.parametrize("bundle", [0, 4])
def test_the_feed_follows_the_bus_and_leaves_each_key_at_its_end(bus: Bus, tmp_path: Path, bundle: int) -> None:
    """``bundle`` 4: the frames come in a replay's bundles of up to 4 (the feed splits them)."""
    run = tmp_path / "run.mcap"
    write_run(run, seconds=6.0)
    feed = LiveFeed(bus, ViewConfig(), io={"expmap": (("experience_event",), ("map", "dead_reckoning"))})
    feed.start()
    try:
        pubs = {}
        for rec in read_messages(run):
            pub = pubs.get(rec.key) or pubs.setdefault(rec.key, bus.publisher(rec.key))
            pub.bundle_max = bundle
            pub.send_data(rec.type_name, rec.payload, rec.stamp)
        for pub in pubs.values():
            pub.flush()
        expected = {k: p.sent - 1 for k, p in pubs.items()}
        _wait(lambda: {k: feed.figures.newest_index(k) for k in pubs} == expected)
        # the latest-only keys (camera, map, activity) keep their newest frame; every other is taken
        assert all(feed.figures.frames[k] == n + 1 for k, n in expected.items() if k not in feed.figures.partial)
        feed.update()
        snap = feed.snapshot({})
        counts = snap["counts"]
        assert counts["nodes"] == 3 and counts["events"] == 3 and counts["lvc"] == 8
        # the pose-cell activity is latest-only, like the camera and the map: at most one decoded per update
        activity = [r.stamp for r in read_messages(run, keys=["posecells/activity"])]
        assert 1 <= snap["activity_version"] <= min(feed.updates, len(activity))
        assert snap["activity"]["stamp"] == activity[-1]
        assert counts["pose"] is not None and feed.dropped == 0
        # what the hub delivered, per key (the view's cost on the hub, in its state for the benchmark)
        by_key = snap["view"]["received_by_key"]
        assert set(by_key) == set(pubs) and sum(by_key.values()) == snap["view"]["received_bytes"]
        assert all(p.has_subscribers() for p in pubs.values())
        for p in pubs.values():
            p.send_eos()
        _wait(lambda: feed.ended == set(pubs))
        feed.update()  # undeclares the ended keys
        _wait(lambda: not any(p.has_subscribers() for p in pubs.values()))
        table = feed.snapshot({})["services"]
        assert table["expmap"]["gaps"] == 0 and table["expmap"]["restarts"] == 0
    finally:
        feed.stop()


def test_a_flood_drops_view_updates_never_blocks(bus: Bus) -> None:
    cfg = ViewConfig()
    feed = LiveFeed(bus, cfg, io={"robot_state": ((), ("dead_reckoning",))}, queue_frames=50)
    feed.start()
    try:
        pub = bus.publisher("dead_reckoning")
        cam = bus.publisher(cfg.camera_key)
        from common.messages import PoseStamped
        pub.send(PoseStamped(header=Header(seq=0, stamp=1), position=[0.0, 0.0, 0.0]))
        _wait(lambda: (feed.update(), feed.figures.newest_index("dead_reckoning") == 0)[1])
        updates = feed.updates
        t0 = time.monotonic()
        for i in range(1, 2000):
            pub.send(PoseStamped(header=Header(seq=i, stamp=1 + i), position=[float(i), 0.0, 0.0]))
        for i in range(20):
            cam.send(Image(header=Header(seq=i, stamp=1 + i), height=8, width=8,
                           data=np.full((8, 8, 3), i, dtype=np.uint8)))
        assert time.monotonic() - t0 < 10.0
        newest = feed.figures.newest_index
        _wait(lambda: (feed.update(), newest(cfg.camera_key) == 19 and newest("dead_reckoning") == 1999)[1])
        # at most the newest 50 are kept between two updates (the pump may have run during the flood)
        assert 1999 - 50 * (feed.updates - updates) <= feed.dropped <= 1999 - 50
        assert feed.figures.frames["dead_reckoning"] + feed.dropped == 2000
        assert 1 <= feed.model.camera_version <= min(20, feed.updates)  # latest-only: at most one frame per update
        assert feed.model.camera is not None and int(np.asarray(feed.model.camera.data)[0, 0, 0]) == 19
    finally:
        feed.stop()


def test_the_live_view_drops_to_the_lowest_cpu_priority() -> None:
    """view.idle_priority: a view on a vehicle computer takes only the CPU time the SLAM leaves."""
    import subprocess
    import sys
    code = ("import os; from services.viewer.app import _lowest_priority; _lowest_priority(); "
            "print(os.sched_getscheduler(0) == os.SCHED_IDLE)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True", out.stderr


def test_a_heavy_key_is_sampled_not_followed(bus: Bus) -> None:
    """Frames over view.sample_bytes: the feed leaves the key's subscription and takes about
    view.sample_hz frames a second; the input rate still counts every frame (transport indices)."""
    cfg = ViewConfig(sample_bytes=2048, sample_hz=4.0)
    feed = LiveFeed(bus, cfg, io={"encoder": ((cfg.camera_key,), ("neocortex/sdr",))})
    feed.start()
    try:
        cam = bus.publisher(cfg.camera_key)
        t0 = time.monotonic()
        i = 0
        while time.monotonic() - t0 < 3.0:  # 50 frames a second of 48 kB
            cam.send(Image(header=Header(seq=i, stamp=1 + i), height=128, width=128,
                           data=np.full((128, 128, 3), i % 255, dtype=np.uint8)))
            i += 1
            time.sleep(0.02)
            if i % 25 == 0:  # the page polls
                feed.update()
                feed.snapshot({})
        _wait(lambda: feed.sampler.keys == [cfg.camera_key])
        seen = feed.figures.frames[cfg.camera_key]
        assert seen < i / 3, (seen, i)  # about 4 a second and the frames before the subscription was left
        assert feed.model.camera is not None and feed.model.camera_version >= 3
        rate = feed.snapshot({})["services"]["encoder"]["rate_hz"]
        assert 25 < rate < 60, rate
        assert feed.snapshot({})["view"]["sampled"] == [cfg.camera_key]
        cam.send_eos()
        deadline = time.monotonic() + 3.0  # the publisher finds the key without subscribers (the sampler's gap)
        while cam.has_subscribers():
            assert time.monotonic() < deadline, "the view never leaves the ended key"
            time.sleep(0.05)
    finally:
        feed.stop()


def test_latency_percentiles_follow_new_samples() -> None:
    """The per-service p50/p99 are computed again after a new sample (and only then)."""
    window = LatencyWindow()
    for stamp in range(10):
        window.arrived(stamp, 0)
        window.output("dead_reckoning", stamp, 10_000_000)  # 10 ms
    assert window.percentiles(["dead_reckoning"]) == (10.0, 10.0)
    for stamp in range(10, 40):
        window.arrived(stamp, 0)
        window.output("dead_reckoning", stamp, 50_000_000)  # 50 ms
    assert window.percentiles(["dead_reckoning"]) == (50.0, 50.0)
    assert window.percentiles(["map"]) == (None, None)


def test_the_lags_come_from_live_health_once_it_arrives_and_progress_is_left(bus: Bus) -> None:
    """@progress (one report per input a service finished) is the busiest stream the view reads;
    a supervised live run's launcher publishes every service's lag once a second on live/health."""
    import struct

    from common.bus import PROGRESS
    from common.live import HEALTH_KEY
    from common.messages import Odometry
    from launcher.health import ServiceHealth, diagnostics
    feed = LiveFeed(bus, ViewConfig(), io={"htm": (("Odometry",), ("local_view_cells",))})
    feed.start()
    try:
        def lag() -> float | None:
            feed.update()
            return feed.snapshot({})["services"]["htm"]["lag_s"]  # type: ignore[no-any-return]

        bus.publisher("Odometry").send(Odometry(header=Header(seq=0, stamp=10_000_000_000), position=[0.0, 0.0, 0.0],
                                                orientation=[0.0, 0.0, 0.0, 1.0]))
        bus.session.put(bus.full_key(f"{PROGRESS}/htm"), struct.pack("<q", 8_000_000_000))
        _wait(lambda: lag() == 2.0)
        assert feed.snapshot({})["view"]["lag_from"] == "@progress"
        health = {"htm": ServiceHealth(alive=True, restarts=0, lag_s=0.5, checkpoint_age_s=None)}
        bus.publisher(HEALTH_KEY).send(diagnostics(health, 10_000_000_000, 0, 2.0))
        _wait(lambda: lag() == 0.5)
        assert feed.snapshot({})["view"]["lag_from"] == HEALTH_KEY
        bus.session.put(bus.full_key(f"{PROGRESS}/htm"), struct.pack("<q", 9_000_000_000))
        time.sleep(0.5)
        assert lag() == 0.5 and feed.figures.progress["htm"] == 8_000_000_000  # @progress left
    finally:
        feed.stop()


def test_the_finished_run_s_recording_replaces_a_live_state_that_dropped_frames(bus: Bus, tmp_path: Path) -> None:
    """``poseidon run --view`` after the run: the page ends with the recording's counts even when
    the view dropped frames, and every panel is fetched whole again (versions and trail epochs
    move past the live ones); frames arriving later no longer change what is shown."""
    from services.viewer.app import show_final
    from services.viewer.recording import RecordingView
    run = tmp_path / "run.mcap"
    write_run(run, seconds=20.0)
    cfg = ViewConfig()
    feed = LiveFeed(bus, cfg, io={"vpr": (("camera/image_raw",), ("local_view_cells",))}, queue_frames=5)
    feed.start()
    try:
        pubs = {}
        recs = list(read_messages(run))
        for rec in recs[:20]:  # a view counts drops from the first frame it took of a key
            pub = pubs.get(rec.key) or pubs.setdefault(rec.key, bus.publisher(rec.key))
            pub.send_data(rec.type_name, rec.payload, rec.stamp)
        _wait(lambda: (feed.update(), feed.figures.newest_index("local_view_cells") >= 0)[1])
        for rec in recs[20: len(recs) * 3 // 4]:  # a burst; the last quarter never reaches the view
            pub = pubs.get(rec.key) or pubs.setdefault(rec.key, bus.publisher(rec.key))
            pub.send_data(rec.type_name, rec.payload, rec.stamp)
        _wait(lambda: (feed.update(), feed.figures.newest_index("local_view_cells") == pubs["local_view_cells"].sent - 1
                       and feed.model.map is not None)[1])
        live = feed.snapshot({})
        assert feed.dropped > 0  # the small rings overflowed during the burst
        expected = RecordingView(run, cfg)
        expected.seek(expected.duration_s)
        want = expected.model.counts()
        assert live["counts"] != want
        have = {"map": str(live["map_version"]), "activity": str(live["activity_version"]),
                **{name: f"{live[name]['epoch']}.{len(live[name]['points'])}" for name in (*feed.model.trails, "lvc")
                   if name in live}}
        camera = feed.model.camera

        assert show_final(feed, run)
        final = feed.snapshot(have)
        assert final["counts"] == want and final["view"]["final"] == "run.mcap"
        assert final["map_version"] > live["map_version"] and final["activity_version"] > live["activity_version"]
        assert "map" in final and "activity" in final  # sent again to a page that held the live ones
        assert final["lvc"]["start"] == 0 and final["lvc"]["epoch"] > live["lvc"]["epoch"]
        assert feed.model.camera is camera and final["camera_version"] == live["camera_version"]
        for rec in recs[len(recs) * 3 // 4:]:  # late frames: counted, not shown
            pub = pubs.get(rec.key) or pubs.setdefault(rec.key, bus.publisher(rec.key))
            pub.send_data(rec.type_name, rec.payload, rec.stamp)
        _wait(lambda: (feed.update(), feed.figures.newest_index("dead_reckoning") == len(
            [r for r in recs if r.key == "dead_reckoning"]) - 1)[1])
        assert feed.snapshot({})["counts"] == want
    finally:
        feed.stop()


def test_an_unreadable_recording_leaves_the_live_state_shown(bus: Bus, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    from services.viewer.app import show_final
    bad = tmp_path / "run.mcap"
    bad.write_bytes(b"not an mcap")
    feed = LiveFeed(bus, ViewConfig())
    before = feed.snapshot({})["counts"]
    assert not show_final(feed, bad)
    assert feed.final == "" and feed.snapshot({})["counts"] == before
    err = capsys.readouterr().err
    assert "the live state stays shown" in err and "run.mcap" in err
