"""The bridge's connection to the hub is reset (every TCP connection of the relay between them
dropped, new ones refused for 3 s) while a bag plays: the bridge keeps running, its Zenoh
client reconnects by itself and the run still ends with every stream's end-of-stream.  Two
outcomes, both seen: the client reconnects at once to the hub's own address, which it learnt
from the hub (around the relay: only the frames in flight are lost), or through the relay once
it is back (a 3 s outage: what the bridge published meanwhile, ~200 IMU/s at -r 4, was lost
before the outage rule of :mod:`common.live`; now the bridge holds it and sends it again when
the recorder matches again -- measured: 3061 of 3061 recorded).  The bounds below allow the
loss of the frames in flight.  Skips without ROS 1 or the bag."""
import json
import signal
import subprocess
import sys
import threading
import time

import pytest

from common.bus import Bus, open_hub
from common.mcap_io import read_messages
from services.recorder.recorder import Recorder
from tests.bridge_ros1.ros1 import Roscore, free_port, require_bag, require_ros1, wait_subscribed
from tests.bridge_ros1.tcp_cut import CuttableLink
from tests.conftest import REPO

pytestmark = [pytest.mark.timeout(240), pytest.mark.slow]
IMU, ODOM = "imu/data", "jackal_velocity_controller/odom"
CONFIG = """bridge_ros1:
  discover: false
  topics:
    /imu/data: {key: imu/data}
    /jackal_velocity_controller/odom: {key: jackal_velocity_controller/odom}
"""


def test_the_bridge_rides_out_a_reset_link_to_the_hub(tmp_path):
    require_ros1()
    bag = require_bag()
    core = Roscore(tmp_path / "roshome")
    hub_port = free_port()
    hub = open_hub(f"tcp/127.0.0.1:{hub_port}")
    link = CuttableLink(hub_port)
    bus = Bus("poseidon", connect=[f"tcp/127.0.0.1:{hub_port}"])
    cfg = tmp_path / "bridge.yaml"
    cfg.write_text(CONFIG)
    bridge = None
    try:
        out = tmp_path / "cut.mcap"
        recorder = Recorder(bus, out, expect=[IMU, ODOM])
        rec_thread = threading.Thread(target=recorder.run, daemon=True)
        rec_thread.start()
        arrivals: list[float] = []
        bus.subscribe_callback(IMU, lambda _k, _d: arrivals.append(time.monotonic()))
        bridge = subprocess.Popen([sys.executable, "-m", "launcher.cli", "bridge", "ros1", "--connect",
                                   f"tcp/127.0.0.1:{link.port}", "--config", str(cfg)], cwd=REPO, env=core.env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        wait_subscribed(core.uri, ["/imu/data", "/jackal_velocity_controller/odom"])
        bus.wait_alive(["bridge_ros1"], 60)
        play = subprocess.Popen(["rosbag", "play", "-q", "-d", "2", "-r", "4", str(bag)], env=core.env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(6)  # 2 s advertise delay, then ~16 s of bag at 4x
        link.cut()  # every connection dropped
        cut_at = time.monotonic()
        time.sleep(3)
        link.restore()
        assert play.wait(120) == 0
        time.sleep(3)  # the client has reconnected (retries every second or so)
        bridge.send_signal(signal.SIGINT)
        stdout, stderr = bridge.communicate(timeout=60)
        assert bridge.returncode == 0, stderr[-3000:]
        rec_thread.join(60)
        assert not rec_thread.is_alive(), "the recorder never saw the end-of-stream sent after the cut"
    finally:
        if bridge is not None and bridge.poll() is None:
            bridge.kill()
        link.close()
        bus.close()
        hub.close()
        core.stop()
    stats = json.loads(stdout)
    assert stats["received"] == {"/imu/data": 3061, "/jackal_velocity_controller/odom": 3060}  # ROS side intact
    stamps = [m.stamp for m in read_messages(out, keys=[IMU])]
    lost = 3061 - len(stamps)
    gaps = [b - a for a, b in zip(stamps, stamps[1:])]
    silent = max(b - a for a, b in zip(arrivals, arrivals[1:]))
    print(f"link reset: {len(stamps)} of 3061 IMU recorded ({lost} lost), longest gap {max(gaps) / 1e9:.3f} s "
          f"of bag time; longest wall-clock silence at the hub side {silent:.2f} s")
    assert any(a > cut_at + 1.0 for a in arrivals)  # data came after the reset
    assert silent < 3.0 + 3.0  # back within 3 s of the link
    assert lost <= 20 + 200 * silent and max(gaps) <= 4 * (silent + 0.5) * 1e9  # lost: what was sent while cut off
