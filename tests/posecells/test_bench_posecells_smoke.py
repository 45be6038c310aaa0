"""The pose-cell benchmark runs and checks itself against its numpy baseline."""
import subprocess
import sys

from tests.conftest import REPO


def test_bench_posecells_runs_and_matches_numpy() -> None:
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_posecells.py"), "--updates", "20"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "ratio numpy / ours" in proc.stdout and "max |numba - numpy|" in proc.stdout
