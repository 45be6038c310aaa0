"""``poseidon service bridge_ros1`` and signals: a bridge that cannot reach its hub honours
SIGTERM at once and gives up after ``bus.startup_timeout_s``; a bridge held up at its end (a
service whose outputs keep coming: it would forward them for up to 60 s) exits at once on a
second SIGTERM; one whose hub went away leaves on the first.  The first two need no ROS."""
import queue
import signal
import subprocess
import sys
import threading
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
    try:
        _out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:  # show where it hangs: SIGUSR1 prints its threads' stacks
        proc.send_signal(signal.SIGUSR1)
        time.sleep(2.0)
        proc.kill()
        pytest.fail(f"the bridge did not exit within 30 s of the signal; its stderr:\n{proc.communicate()[1]}")
    return time.monotonic() - t0, err


def test_a_bridge_that_never_reached_its_hub_honours_sigterm():
    proc = _start("--connect", f"tcp/127.0.0.1:{free_port()}")
    first = proc.stderr.readline()  # its signal handlers are in place (a loaded machine imports slowly)
    assert "waiting for the hub" in first, first
    took, err = _signal_and_wait(proc, 0.5)
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


def test_a_second_sigterm_ends_a_bridge_held_up_by_a_service(ros_and_hub):
    core, _hub, endpoint = ros_and_hub
    bus = Bus("poseidon", connect=[endpoint])
    stop = threading.Event()

    def service_outputs():  # Odometry that never ends: the bridge forwards it until its 60 s limit
        pub, stamp = bus.publisher("Odometry"), 1
        while not stop.wait(0.3):
            pub.send_watermark(stamp)
            stamp += 1
    ticker = threading.Thread(target=service_outputs, daemon=True)
    try:
        proc = _start("--connect", endpoint, "--announce", "imu/data", env=core.env)
        bus.wait_alive(["bridge_ros1"], 60)
        ticker.start()
        proc.send_signal(signal.SIGTERM)
        time.sleep(4.0)  # end-of-stream sent; forwarding the service's last outputs
        assert proc.poll() is None, proc.communicate()[1]
        took, err = _signal_and_wait(proc, 0.0)
    finally:
        stop.set()
        ticker.join(5)
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


def test_a_stuck_master_does_not_hold_the_bridge_at_its_end(monkeypatch, caplog):
    """Unregistering at a master that does not answer (rospy's XML-RPC calls and thread joins
    have no bound of ours) is left behind after RosLink.CLOSE_TIMEOUT_S; a failure is raised."""
    from services.bridge_ros1 import ros_io

    class StuckRospy:
        def __init__(self):
            self.release = threading.Event()

        def signal_shutdown(self, reason):
            self.release.wait()

    stuck = StuckRospy()
    monkeypatch.setattr(ros_io, "import_rospy", lambda path: stuck)
    link = ros_io.RosLink("http://127.0.0.1:1", "probe", "", lambda *a: None)
    link.CLOSE_TIMEOUT_S = 0.5
    t0 = time.monotonic()
    assert link.close() is False and time.monotonic() - t0 < 2.0
    assert "did not finish within" in caplog.text
    stuck.release.set()

    class FailingRospy:
        def signal_shutdown(self, reason):
            raise RuntimeError("master refused")

    monkeypatch.setattr(ros_io, "import_rospy", lambda path: FailingRospy())
    with pytest.raises(RuntimeError, match="master refused"):
        ros_io.RosLink("http://127.0.0.1:1", "probe", "", lambda *a: None).close()
