"""The soak benchmark's measuring parts (the soak itself runs for minutes, on demand)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import bench_soak  # noqa: E402


def test_peaks_are_binned_by_sixths_of_the_wall_time():
    s = bench_soak.RssSampler()
    s.samples = [(0.5, "encoder", 100.0), (1.5, "encoder", 150.0), (1.9, "encoder", 120.0), (5.9, "encoder", 160.0),
                 (3.2, "htm", 50.0)]
    peaks = s.peaks(wall_s=6.0)
    assert peaks["encoder"] == [100.0, 150.0, 0.0, 0.0, 0.0, 160.0]
    assert peaks["htm"] == [0.0, 0.0, 0.0, 50.0, 0.0, 0.0]


def test_service_children_are_found_and_sampled():
    busy = "import time; t = time.process_time()\nwhile time.process_time() - t < 0.3: pass\ntime.sleep(30)"
    child = subprocess.Popen([sys.executable, "-c", busy, "service", "fakesvc"])
    try:
        deadline = time.monotonic() + 10
        found = {}
        while time.monotonic() < deadline and "fakesvc" not in found:
            found = bench_soak._service_pids(bench_soak.os.getpid())
            time.sleep(0.05)
        assert found.get("fakesvc") == child.pid
        rss = bench_soak._rss_mib(child.pid)
        assert rss is not None and rss > 1.0
        cpu = 0.0
        while time.monotonic() < deadline and cpu < 0.3:   # the child burns 0.3 s of CPU, then sleeps
            cpu = bench_soak._cpu_s(child.pid) or 0.0
            time.sleep(0.05)
        assert 0.3 <= cpu < 5.0
    finally:
        child.kill()
        child.wait()
    assert bench_soak._rss_mib(child.pid) is None and bench_soak._cpu_s(child.pid) is None


def test_per_mission_part_follows_the_recorders_progress(tmp_path):
    from common.resume import save_checkpoint
    ckpt = tmp_path / "recorder.ckpt"
    save_checkpoint(ckpt, {"service": "recorder", "seen": 5_000_000_000})
    assert bench_soak._recorder_seen_ns(ckpt) == 5_000_000_000
    assert bench_soak._recorder_seen_ns(tmp_path / "none.ckpt") is None
    s = bench_soak.RssSampler()
    start = 1_000_000_000_000
    # mission 0-300 s: the first 100 s of mission took 10 s of wall, the last 100 s took 30 s
    s.mission_samples = [(5.0, start + 50_000_000_000), (10.0, start + 100_000_000_000),
                         (20.0, start + 200_000_000_000), (35.0, start + 250_000_000_000)]
    s.cpu_samples = [(10.0, "htm", 4.0), (20.0, "htm", 9.0), (50.0, "htm", 30.0)]
    parts = s.per_mission_part(3, start, 300.0, wall_s=50.0)
    assert [p["wall_s"] for p in parts] == [10.0, 10.0, 30.0]
    assert [p["real_time_factor"] for p in parts] == [10.0, 10.0, 3.33]
    assert [p["cpu_s"]["htm"] for p in parts] == [4.0, 5.0, 21.0]
    assert parts[2]["mission_s"] == [200.0, 300.0]
    s.samples = [(5.0, "htm", 100.0), (9.9, "htm", 110.0), (15.0, "htm", 120.0), (49.0, "htm", 180.0),
                 (50.5, "htm", 190.0), (12.0, "expmap", 70.0)]
    parts = s.per_mission_part(3, start, 300.0, wall_s=50.0)
    assert [p["peak_rss_mib"] for p in parts] == [{"htm": 110.0}, {"expmap": 70.0, "htm": 120.0}, {"htm": 190.0}]


def test_the_report_shows_first_part_against_last_per_service(capsys):
    first = {"mission_s": [0.0, 1200.0], "cpu_s": {"htm": 20.0, "encoder": 30.0},
             "peak_rss_mib": {"htm": 300.0, "encoder": 400.0}}
    last = {"mission_s": [2400.0, 3600.0], "cpu_s": {"htm": 25.0, "encoder": 30.0},
            "peak_rss_mib": {"htm": 350.5, "encoder": 400.0}}
    bench_soak.print_first_last(first, last, 3)
    lines = capsys.readouterr().out.splitlines()
    assert "0-1200 s" in lines[0] and "2400-3600 s" in lines[0]
    assert lines[2].split() == ["encoder", "30.0", "30.0", "1.00x", "400.0", "400.0", "+0.0"]
    assert lines[3].split() == ["htm", "20.0", "25.0", "1.25x", "300.0", "350.5", "+50.5"]


def test_a_restarted_service_keeps_the_cpu_of_its_first_process():
    s = bench_soak.RssSampler()
    assert s._carried("player", 100, 2.0) == 2.0
    assert s._carried("player", 100, 5.0) == 5.0
    assert s._carried("player", 200, 0.5) == 5.5     # restarted: a new pid counting from 0
    assert s._carried("player", 200, 1.0) == 6.0
    assert s._carried("htm", 300, 1.0) == 1.0


def test_cpu_split_is_the_process_cpu_parted_for_algorithm_services_only():
    services = {"htm": {"cpu_s": 8.2, "startup_cpu_s": 2.43, "node_cpu_s": 4.02, "frame_path_cpu_s": 1.03},
                "recorder": {"cpu_s": 7.0},
                "embedded": {"startup_cpu_s": 1.0, "node_cpu_s": 1.0, "frame_path_cpu_s": 0.1}}
    split = bench_soak.cpu_split(services)
    assert split == {"htm": {"cpu_s": 8.2, "startup_s": 2.4, "node_s": 4.0, "frame_path_s": 1.0, "rest_s": 0.7}}


def test_the_encoders_work_per_frame_is_its_node_cpu_over_the_camera_frames():
    split = {"encoder": {"cpu_s": 91.8, "startup_s": 2.6, "node_s": 75.1, "frame_path_s": 8.6, "rest_s": 5.5}}
    assert bench_soak.encoder_ms_per_frame(split, 17999) == 4.172
    assert bench_soak.encoder_ms_per_frame(split, 0) is None            # no camera frame recorded
    assert bench_soak.encoder_ms_per_frame({"htm": split["encoder"]}, 17999) is None   # no encoder started
