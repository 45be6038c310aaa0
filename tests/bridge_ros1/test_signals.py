"""``poseidon service bridge_ros1`` and signals: a bridge that cannot reach its hub honours
SIGTERM at once and gives up after ``bus.startup_timeout_s``; a bridge held up at its end (a
consumer that never leaves: it would wait ``bus.drain_timeout_s``) exits at once on a second
SIGTERM; one whose hub went away leaves on the first.  The first two need no ROS."""
import queue
import signal
import subprocess
import sys
import time

import pytest

from common.bus import Bus, open_hub
from tests.bridge_ros1.ros1 import Roscore, free_port, require_ros1
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(90)
CMD = [sys.executable, "-m", "launcher.cli", "service", "bridge_ros1"]


def _start(*args: str, env=None) -> subprocess.Popen:
    return subprocess.Popen([*CMD, *args], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _signal_and_wait(proc: subprocess.Popen, *gaps: float) -> tuple[float, str]:
    """Send SIGTERM after each of ``gaps`` (s); returns the time from the last one to the exit, and stderr."""
    for gap in gaps:
        time.sleep(gap)
        proc.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    _out, err = proc.communicate(timeout=30)
    return time.monotonic() - t0, err


def test_a_bridge_that_never_reached_its_hub_honours_sigterm():
    proc = _start("--connect", f"tcp/127.0.0.1:{free_port()}")
    took, err = _signal_and_wait(proc, 2.0)
    assert took < 3.0 and proc.returncode == 0, err
    assert "stopped by signal 15 before reaching the hub" in err


def test_a_bridge_that_never_reached_its_hub_gives_up():
    t0 = time.monotonic()
    proc = _start("--connect", f"tcp/127.0.0.1:{free_port()}", "--set", "bus.startup_timeout_s=2")
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and time.monotonic() - t0 < 15, err
    assert "not reached within 2 s (bus.startup_timeout_s); giving up" in err


@pytest.fixture
def ros_and_hub(tmp_path):
    require_ros1()
    core = Roscore(tmp_path / "roshome")
    port = free_port()
    hub = open_hub(f"tcp/127.0.0.1:{port}")
    try:
        yield core, hub, f"tcp/127.0.0.1:{port}"
    finally:
        hub.close()
        core.stop()


def test_a_second_sigterm_ends_a_bridge_held_up_by_its_consumer(ros_and_hub):
    core, _hub, endpoint = ros_and_hub
    bus = Bus("poseidon", connect=[endpoint])
    try:
        bus.subscribe("imu/data", queue.SimpleQueue())  # a consumer that never leaves
        proc = _start("--connect", endpoint, "--announce", "imu/data", env=core.env)
        bus.wait_alive(["bridge_ros1"], 60)
        proc.send_signal(signal.SIGTERM)
        time.sleep(4.0)  # end-of-stream sent, ROS node shut; now waiting for the consumer to leave
        assert proc.poll() is None, proc.communicate()[1]
        took, err = _signal_and_wait(proc, 0.0)
    finally:
        bus.close()
    assert took < 2.0 and proc.returncode == 4, err
    assert "second signal 15: exiting now" in err


def test_a_bridge_whose_hub_went_away_leaves_on_sigterm(ros_and_hub):
    core, hub, endpoint = ros_and_hub
    bus = Bus("poseidon", connect=[endpoint])
    try:
        bus.subscribe("imu/data", queue.SimpleQueue())
        proc = _start("--connect", endpoint, "--announce", "imu/data", env=core.env)
        bus.wait_alive(["bridge_ros1"], 60)
    finally:
        bus.close()
    hub.close()
    took, err = _signal_and_wait(proc, 1.0)
    assert took < 10.0 and proc.returncode == 0, err
