"""The HTM benchmark still runs against the current pipeline (it drives SP/TM/descriptor directly)."""
import subprocess
import sys

from tests.conftest import REPO


def test_bench_htm_runs_on_a_short_stream():
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_htm.py"), "--steps", "40", "--places", "5",
                           "--pipeline-frames", "60", "--pipeline-places", "10"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "ratio SP+TM / htm.core" in proc.stdout
    assert "chain sdr_seqmem " in proc.stdout and "chain sp_tm " in proc.stdout
