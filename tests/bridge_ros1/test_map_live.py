"""The bridge's ``/map`` against a real ROS master: laser scans played with ``rosbag play`` come in
through the bridge, ``Odometry`` and the experience map arrive on the bus as the services would
publish them (the Odometry at the bag's pace, the map at the end: the grids until then are at
the dead reckoning's poses, the last at the map-corrected ones), and ``rostopic echo /map`` sees a latched nav_msgs/OccupancyGrid that is the grid
``poseidon export --grid`` makes of the same messages, its walls on the corridor's walls.

Needs ROS 1 (``deploy/setup.sh`` installs it when run as root); skips with the reason otherwise.
The bridge runs as ``poseidon bridge ros1`` connected to a hub in this process."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from common.bus import Bus, open_hub
from common.mcap_io import read_messages
from products.rosbag import export_rosbag
from tests.bridge_ros1.gridrun import RES, drift_run, exported, wall_offsets
from tests.bridge_ros1.ros1 import Roscore, free_port, require_ros1, wait_subscribed
from tests.conftest import REPO

pytestmark = [pytest.mark.timeout(240), pytest.mark.slow]
#: -d 3: rosbag waits after advertising, so the subscribed bridge has connected before the first message
RATE = 10
PLAY = ["rosbag", "play", "-q", "-d", "3", "--queue", "100000", "-r", str(RATE)]
CLI = [sys.executable, "-m", "launcher.cli"]
PERIOD_S = 5.0
CONFIG = f"""bridge_ros1:
  discover: false
  grid_period_s: {PERIOD_S}
  topics:
    /scan: {{key: scan, type: sensor_msgs/LaserScan}}
"""


def _echo_map(env: dict[str, str], stamp: int, timeout_s: float = 60.0) -> dict[str, Any]:
    """The latched ``/map`` as ``rostopic echo -n 1`` prints it, once its stamp is ``stamp``."""
    deadline = time.monotonic() + timeout_s
    seen = None
    while time.monotonic() < deadline:
        proc = subprocess.run(["rostopic", "echo", "-n", "1", "/map"], env=env, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        msg = yaml.safe_load(proc.stdout.split("\n---")[0])
        seen = msg["header"]["stamp"]
        if seen["secs"] * 1_000_000_000 + seen["nsecs"] == stamp:
            return dict(msg)
        time.sleep(0.5)
    raise AssertionError(f"/map never carried stamp {stamp} in {timeout_s} s (last {seen})")


def test_ros_sees_the_export_grid_of_the_live_messages_latched_on_map(tmp_path: Path) -> None:
    require_ros1()
    # the last Odometry sample moves event time on by more than a period: past the last build's clock
    # even when that build came at the last scan, whose stamp (ROS secs/nsecs) may be 1 ns past the
    # last Odometry's; a trigger of exactly one period then falls 1 ns short, and /map keeps that build
    run = drift_run(tmp_path, trigger_s=PERIOD_S + 1.0)
    bag = tmp_path / "scans.bag"
    export_rosbag(run, bag, ros2=False)
    odom = [r.message() for r in read_messages(run, keys=["Odometry"])]
    (experience_map,) = [r.message() for r in read_messages(run, keys=["map"])]
    n_scans = sum(1 for _ in read_messages(run, keys=["scan"]))
    cfg = tmp_path / "bridge.yaml"
    cfg.write_text(CONFIG)
    core = Roscore(tmp_path / "roshome")
    hub_port = free_port()
    hub = open_hub(f"tcp/127.0.0.1:{hub_port}")
    bus = Bus("poseidon", connect=[f"tcp/127.0.0.1:{hub_port}"])
    bridge = None
    try:
        bridge = subprocess.Popen(CLI + ["bridge", "ros1", "--connect", f"tcp/127.0.0.1:{hub_port}", "--config",
                                         str(cfg)], cwd=REPO, env=core.env, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        wait_subscribed(core.uri, ["/scan"])
        bus.wait_alive(["bridge_ros1"], 60)
        # the services' outputs: the dead reckoning at the bag's pace, then the map (a loop closure's result)
        play = subprocess.Popen(PLAY + [str(bag), "--topics", "/scan"], env=core.env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(3.0)                            # rosbag's -d
        pub = bus.publisher("Odometry")
        for m in odom[:-1]:
            pub.send(m)
            time.sleep(0.2 / RATE)
        _o, play_err = play.communicate(timeout=120)
        assert play.returncode == 0, play_err
        bus.publisher("map").send(experience_map)
        time.sleep(1.0)
        pub.send(odom[-1])                         # after every scan and the map: the grid of everything
        echoed = _echo_map(core.env, odom[-1].header.stamp)
        bridge.send_signal(signal.SIGINT)
        stdout, stderr = bridge.communicate(timeout=60)
        assert bridge.returncode == 0, stderr[-3000:]
    finally:
        if bridge is not None and bridge.poll() is None:
            bridge.kill()
            bridge.wait()
        bus.close()
        hub.close()
        core.stop()
    stats = json.loads(stdout)
    assert stats["errors"] == {} and stats["received"] == {"/scan": n_scans}
    info = echoed["info"]
    frame, cells = exported(run)          # what poseidon export --grid makes of the same messages
    assert info["resolution"] == pytest.approx(RES, abs=1e-7)
    assert (info["width"], info["height"]) == (frame.width, frame.height)
    assert (info["origin"]["position"]["x"], info["origin"]["position"]["y"]) == pytest.approx(frame.origin)
    assert echoed["header"]["frame_id"] == "odom"
    data = np.array(echoed["data"], dtype=np.int8)
    assert np.array_equal(data, cells)
    x, y, off = wall_offsets(frame.origin, RES, frame.width, frame.height, data)
    assert len(off) > 300 and np.max(off) <= 2.5 * RES, "an occupied cell off the corridor's walls"
    for wall in (1.5, -1.5):
        assert np.ptp(x[np.abs(y - wall) < 0.1]) > 19.0, f"the wall at y={wall} m is not drawn end to end"
    # rate: grids while the bag played, at most one per period of event time (~85 s of scans and Odometry)
    span_s = (odom[-1].header.stamp - odom[0].header.stamp) / 1e9
    n = stats["to_ros"]["/map"]
    print(f"/map: {n} grids over {span_s:.0f} s of event time; {stats['grid']}")
    assert 3 <= n <= span_s / PERIOD_S + 2
