"""The console script leaves with the command's exit code, its output flushed, without finalisation."""
from __future__ import annotations

import json
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


def test_installed_console_script_runs_the_launcher():
    from importlib.metadata import entry_points
    (ep,) = entry_points(group="console_scripts", name="poseidon")
    assert ep.value == "launcher.cli:entry"
    script = Path(sys.executable).parent / "poseidon"
    out = subprocess.run([str(script), "run", "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "--input" in out.stdout


def test_one_blas_thread_per_process_unless_the_user_says_otherwise():
    code = "import launcher.cli, os; print(os.environ['OPENBLAS_NUM_THREADS'])"
    env = {k: v for k, v in __import__("os").environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env, timeout=60)
    assert out.stdout.strip() == "1"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         env={**env, "OPENBLAS_NUM_THREADS": "2"}, timeout=60)
    assert out.stdout.strip() == "2"


def test_native_writes_to_descriptor_1_do_not_reach_stdout():
    """Zenoh's Rust logging writes to file descriptor 1; stdout must carry only the command's
    own output (a ``--json`` document), the rest goes to stderr -- in the launcher and in
    every service it starts."""
    code = ("import json, os, subprocess, sys\n"
            "import launcher.cli as cli\n"
            "def fake_main():\n"
            "    os.write(1, b'NATIVE LOG LINE\\n')\n"
            "    subprocess.run([sys.executable, '-c', 'import os; os.write(1, b\"CHILD LINE\\\\n\")'], stdout=2, check=True)\n"
            "    print(json.dumps({'ok': True}))\n"
            "    return 0\n"
            "cli.main = fake_main\n"
            "cli.entry()\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == {"ok": True}
    assert "NATIVE LOG LINE" in out.stderr and "CHILD LINE" in out.stderr


def test_distributed_services_do_not_inherit_the_launchers_stdout(tmp_path):
    """A service process that writes to file descriptor 1 does not spoil ``run --json``."""
    from tests.common.recordings import six_stream_recording
    rec, cfg = tmp_path / "in.mcap", tmp_path / "cfg.yaml"
    six_stream_recording(rec, 200)
    cfg.write_text('{"service_classes": {"chatty": "tests.common.nodes:Chatty"}}')
    out = subprocess.run([sys.executable, "-m", "launcher.cli", "run", "--input", str(rec), "--out",
                          str(tmp_path / "run.mcap"), "--config", str(cfg), "--services", "chatty", "--json"],
                         cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout)["services"]["chatty"]["received"]
    assert "CHATTY SERVICE ON FD 1" in out.stderr
