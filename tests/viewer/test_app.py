"""``poseidon view`` of a running deployment: it runs, Zenoh's threads included, at the niceness
of ``view.nice`` (validated), takes the services' keys from ``--io`` instead of importing the
services' modules (numba and the like), and says it is ready (subscribed, page served) through ``--ready-file``."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.bus import open_hub
from common.config import ConfigError
from services.viewer.app import ViewError, read_io
from system.config import load_config
from tests.conftest import REPO
from tests.viewer.runs import free_port, view_state, write_run

pytestmark = pytest.mark.timeout(120)


def test_lower_niceness_raises_the_thread_and_the_threads_it_starts_never_lowers_it() -> None:
    code = ("import os, threading; from services.viewer.app import lower_niceness\n"
            "a = lower_niceness(10); b = lower_niceness(5); seen = []\n"
            "t = threading.Thread(target=lambda: seen.append(os.nice(0))); t.start(); t.join()\n"
            "print(a, b, seen[0])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.split() == ["10", "10", "10"], out.stderr


@pytest.mark.parametrize("level", [-1, 20])
def test_lower_niceness_refuses_a_level_outside_0_to_19(level: int) -> None:
    from services.viewer.app import lower_niceness
    with pytest.raises(ValueError, match="view.nice"):
        lower_niceness(level)


@pytest.mark.parametrize("value", ["20", "-5"])
def test_the_configuration_refuses_a_view_nice_outside_0_to_19(value: str) -> None:
    with pytest.raises(ConfigError, match=r"view\.nice"):
        load_config(None, [f"view.nice={value}"])


def test_read_io_takes_the_services_keys_and_names_a_bad_file(tmp_path: Path) -> None:
    good = tmp_path / "io.json"
    good.write_text(json.dumps({"robot_state": [["dvl", "imu"], ["odometry"]]}))
    assert read_io(good) == {"robot_state": (("dvl", "imu"), ("odometry",))}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"robot_state": ["dvl"]}))
    with pytest.raises(ViewError, match=str(bad)):
        read_io(bad)
    with pytest.raises(ViewError, match="missing.json"):
        read_io(tmp_path / "missing.json")


def _threads_nice(pid: int) -> set[int]:
    """The niceness of every thread of ``pid`` (``/proc/PID/task/TID/stat`` field 19)."""
    out = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out.add(int((task / "stat").read_text().rsplit(")", 1)[1].split()[16]))
        except FileNotFoundError:  # a thread that ended since the listing has no niceness to check
            continue
    return out


def test_a_live_view_says_when_it_is_ready_and_runs_niced_with_every_thread(tmp_path: Path) -> None:
    hub_port, page_port = free_port(), free_port()
    hub = open_hub(f"tcp/127.0.0.1:{hub_port}")
    io = tmp_path / "io.json"
    io.write_text(json.dumps({"robot_state": [["dvl"], ["odometry"]]}))
    ready = tmp_path / "ready"
    cmd = [sys.executable, "-X", "importtime", "-m", "launcher.cli", "view", "--connect", f"tcp/127.0.0.1:{hub_port}",
           "--listen", str(page_port), "--io", str(io), "--ready-file", str(ready), "--set", "view.nice=7"]
    log = tmp_path / "stderr.txt"
    with log.open("wb") as err:
        proc = subprocess.Popen(cmd, cwd=REPO, stderr=err)
    try:
        deadline = time.monotonic() + 60
        while not ready.exists():
            assert proc.poll() is None, log.read_text()[-3000:]
            assert time.monotonic() < deadline, "the view never wrote its ready file"
            time.sleep(0.05)
        url = ready.read_text().strip()
        assert url == f"http://127.0.0.1:{page_port}/"
        state = view_state(url)  # served as soon as it is ready
        assert state is not None and state["mode"] == "live"
        assert set(state["services"]) == {"robot_state"}  # the table from --io
        assert {"dvl", "odometry"} <= set(state["view"]["keys"])
        assert _threads_nice(proc.pid) == {7}  # Zenoh's threads too
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        hub.close()
    assert proc.returncode == 0
    imported = {line.rsplit("|", 1)[-1].strip() for line in log.read_text().splitlines() if line.startswith("import")}
    assert "services.viewer.live" in imported
    assert not imported & {"numba", "services.posecells.core", "services.encoder.core"}  # no service's module


def test_a_recording_s_view_says_when_it_is_ready_and_refuses_io(tmp_path: Path) -> None:
    run = tmp_path / "run.mcap"
    write_run(run)
    page_port = free_port()
    ready = tmp_path / "ready"
    cli = [sys.executable, "-m", "launcher.cli", "view", str(run)]
    proc = subprocess.Popen([*cli, "--listen", str(page_port), "--ready-file", str(ready)], cwd=REPO,
                            stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not ready.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the view never wrote its ready file"
            time.sleep(0.05)
        state = view_state(ready.read_text().strip())
        assert state is not None and state["mode"] == "recording"
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    refused = subprocess.run([*cli, "--io", str(tmp_path / "io.json")], cwd=REPO, capture_output=True, text=True,
                             timeout=60)
    assert refused.returncode == 2 and "--io and --final-recording are for a live deployment" in refused.stderr
