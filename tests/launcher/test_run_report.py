"""The readable lines of a run's summary (launcher/run_report.py)."""
from launcher.run_report import format_service


def test_a_service_with_nothing_to_say_is_ok():
    assert format_service("htm", {}) == ["  [htm] ok"]


def test_a_service_line_lists_its_counters_then_its_latency_per_stage():
    st = {"invalid": 2, "counters": {"b": 1, "a": 3}, "cpu_s": 1.234, "peak_rss_mb": 99.6,
          "latency": {"decoded": {"n": 4, "p50_ms": 1.0, "p95_ms": 2.0, "p99_ms": 3.0}, "idle": {"n": 0}}}
    lines = format_service("encoder", st)
    assert lines[0] == "  [encoder] invalid 2; a 3, b 1; process CPU 1.23 s; peak memory 100 MB"
    assert len(lines) == 2 and lines[1].startswith("    latency arrival -> decoded   p50      1.0 ms")


def test_an_algorithm_service_line_says_where_its_cpu_went():
    st = {"cpu_s": 8.2, "startup_cpu_s": 1.21, "node_cpu_s": 3.14, "frame_path_cpu_s": 1.33}
    assert format_service("posecells", st) == [
        "  [posecells] process CPU 8.20 s (start-up 1.21 s, node 3.14 s, frame path 1.33 s)"]
