"""The console script leaves with the command's exit code, its output flushed, without finalisation."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _entry(*args: str) -> subprocess.CompletedProcess:
    code = "from launcher.cli import entry; entry()"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_exit_codes_and_output_survive_os_exit(tmp_path):
    ok = _entry("run", "--help")
    assert ok.returncode == 0 and "usage" in ok.stdout.lower()
    bad = _entry("no-such-command")
    assert bad.returncode == 2 and "invalid choice" in bad.stderr
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    info = _entry("info", str(empty))
    assert info.returncode == 2 and str(empty) in info.stderr


def test_console_script_points_at_entry():
    text = (ROOT / "pyproject.toml").read_text()
    assert 'poseidon = "launcher.cli:entry"' in text


def test_one_blas_thread_per_process_unless_the_user_says_otherwise():
    code = "import launcher.cli, os; print(os.environ['OPENBLAS_NUM_THREADS'])"
    env = {k: v for k, v in __import__("os").environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env, timeout=60)
    assert out.stdout.strip() == "1"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         env={**env, "OPENBLAS_NUM_THREADS": "2"}, timeout=60)
    assert out.stdout.strip() == "2"
