"""A private ROS 1 master for the bridge's tests: ``roscore`` on a free port, ``ROS_HOME`` in
the test's folder; skips (with the reason) when ROS 1, rosbag or the test bag is absent."""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import SHARED_DATA

ROS_PY = "/usr/lib/python3/dist-packages"
BAG = SHARED_DATA / "ros1_bags" / "robot_localization_test2.bag"


def require_ros1() -> None:
    """Skip unless rospy imports (system path appended) and roscore/rosbag/rostopic are on PATH."""
    if ROS_PY not in sys.path:
        sys.path.append(ROS_PY)
    try:
        import rosgraph  # noqa: F401
        import rospy  # noqa: F401
    except ImportError as exc:
        pytest.skip(f"ROS 1 (rospy) is not installed: {exc} (deploy/setup.sh installs it as root)")
    for tool in ("roscore", "rosbag", "rostopic"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not on PATH (Debian ros-core)")


def require_bag() -> Path:
    if not BAG.is_file():
        pytest.skip(f"test bag {BAG} is absent (../shared/data/ros1_bags)")
    return BAG


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Roscore:
    """``roscore`` in its own session; :meth:`stop` ends it (SIGINT to its own group)."""

    def __init__(self, home: Path):
        self.port = free_port()
        self.uri = f"http://127.0.0.1:{self.port}"
        home.mkdir(parents=True, exist_ok=True)
        self.env = {**os.environ, "ROS_MASTER_URI": self.uri, "ROS_HOSTNAME": "127.0.0.1", "ROS_HOME": str(home)}
        self.env.pop("ROS_IP", None)
        self.log = open(home / "roscore.log", "wb")
        self.proc = subprocess.Popen(["roscore", "-p", str(self.port)], env=self.env, stdout=self.log,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        import rosgraph
        deadline = time.monotonic() + 30
        while not rosgraph.is_master_online(master_uri=self.uri):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"roscore on port {self.port} did not start (see {home / 'roscore.log'})")
            time.sleep(0.1)

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)
        self.log.close()


def wait_subscribed(uri: str, topics: list[str], node: str = "/poseidon_bridge", timeout_s: float = 90.0) -> None:
    """Wait until ``node`` subscribes to every one of ``topics`` on the master at ``uri``."""
    import rosgraph
    master = rosgraph.Master("/poseidon_test", master_uri=uri)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        _pubs, subs, _srvs = master.getSystemState()
        have = {t for t, nodes in subs if node in nodes}
        if set(topics) <= have:
            return
        time.sleep(0.2)
    raise TimeoutError(f"{node} did not subscribe to {topics} within {timeout_s:.0f} s")
