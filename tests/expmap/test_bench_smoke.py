"""The experience-map benchmark runs on a small map and its two searches agree."""
import subprocess
import sys

from tests.conftest import REPO


def test_bench_expmap_runs_on_a_small_map() -> None:
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_expmap.py"), "--sizes", "1000",
                           "--measure", "300"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    row = proc.stdout.strip().splitlines()[-1]
    assert row.split()[0] == "1000" and "(build" in row and " 0 search disagreements" in row
