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
