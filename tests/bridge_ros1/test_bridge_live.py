"""The bridge against a real ROS master: a bag played with ``rosbag play`` is recorded message
for message with its header stamps, and our outputs are seen by ROS tools (``rostopic echo``).

Needs ROS 1 (``deploy/setup.sh`` installs it when run as root) and
../shared/data/ros1_bags/robot_localization_test2.bag; skips with the reason otherwise.
The bridge runs in this process (rospy allows one node per process: one test here)."""
import subprocess
import threading
import time

import pytest

from common.mcap_io import read_messages
from common.messages import ExperienceMap, ExperienceNode, Header, Odometry
from services.bridge_ros1.bridge import Ros1Bridge
from services.bridge_ros1.config import BridgeRos1Config, TopicRoute
from services.recorder.recorder import Recorder
from tests.bridge_ros1.ros1 import Roscore, require_bag, require_ros1

pytestmark = [pytest.mark.timeout(240), pytest.mark.slow]
#: -d 5: rosbag waits after advertising, so the subscribed bridge has connected before the first message;
#: --queue: rosbag keeps 100 messages per subscriber by default and drops older ones when a loaded bridge lags
PLAY = ["rosbag", "play", "-q", "-d", "5", "--queue", "100000", "-r", "8"]

IMU, ODOM = "imu/data", "jackal_velocity_controller/odom"


def _bag_truth(bag):
    """Per topic: the header stamps of the bag's messages (read with rosbags, not ROS)."""
    from rosbags.highlevel import AnyReader
    out: dict[str, list[int]] = {}
    with AnyReader([bag]) as r:
        for conn, _t, raw in r.messages():
            h = r.deserialize(raw, conn.msgtype).header
            out.setdefault(conn.topic, []).append(h.stamp.sec * 1_000_000_000 + h.stamp.nanosec)
    return out


def _echo_while(env, topic, publish, timeout_s=40.0):
    """``rostopic echo -n 1 topic`` while ``publish()`` runs every 0.1 s; its output."""
    proc = subprocess.Popen(["rostopic", "echo", "-n", "1", topic], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + timeout_s
    while proc.poll() is None and time.monotonic() < deadline:
        publish()
        time.sleep(0.1)
    if proc.poll() is None:
        proc.kill()
    out = proc.communicate()[0]
    assert proc.returncode == 0, f"rostopic echo {topic} saw nothing in {timeout_s} s: {out}"
    return out


def test_a_played_bag_is_recorded_message_for_message_and_ros_sees_our_odometry(tmp_path, bus, monkeypatch):
    require_ros1()
    bag = require_bag()
    truth = _bag_truth(bag)
    core = Roscore(tmp_path / "roshome")
    try:
        for k in ("ROS_MASTER_URI", "ROS_HOSTNAME", "ROS_HOME"):
            monkeypatch.setenv(k, core.env[k])
        config = BridgeRos1Config(master_uri=core.uri, discover=False, topics={
            "/imu/data": TopicRoute(key=IMU, type="sensor_msgs/Imu"),
            "/jackal_velocity_controller/odom": TopicRoute(key=ODOM, type="nav_msgs/Odometry")},
            map_period_s=0.0)
        out = tmp_path / "live.mcap"
        recorder = Recorder(bus, out, expect=[IMU, ODOM])
        bridge = Ros1Bridge(bus, config)
        results = {}
        threads = [threading.Thread(target=lambda w=w, n=n: results.__setitem__(n, w.run()), daemon=True)
                   for n, w in (("recorder", recorder), ("bridge", bridge))]
        for t in threads:
            t.start()
        bus.wait_alive(["recorder", "bridge_ros1"], 30)  # the bridge has subscribed: play the bag now
        play = subprocess.run(PLAY + [str(bag)], env=core.env, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, timeout=120)
        assert play.returncode == 0, play.stderr

        odom_pub = bus.publisher("Odometry")
        seq = iter(range(10**6))

        def publish_odometry():
            odom_pub.send(Odometry(header=Header(seq=next(seq), stamp=60_000_000_000, frame_id="odom"),
                                   child_frame_id="base_link", position=[1.5, -2.25, -7.0],
                                   orientation=[0.0, 0.0, 0.0, 1.0]))
        echoed = _echo_while(core.env, "/poseidon/odom", publish_odometry)
        assert "x: 1.5" in echoed and "y: -2.25" in echoed and "z: -7.0" in echoed and "secs: 60" in echoed

        map_pub = bus.publisher("map")
        nodes = [ExperienceNode(id=i, lvc_id=i, position=[float(i), 0.5, 0.0], yaw=0.0, stamp=i) for i in range(3)]
        map_pub.send(ExperienceMap(header=Header(seq=0, stamp=2, frame_id="odom"), nodes=nodes, links=[]))
        path = _echo_while(core.env, "/poseidon/path", lambda: None)  # latched: no need to republish
        assert path.count("position:") == 3 and "x: 2.0" in path

        time.sleep(0.5)
        bridge.stop()
        for t in threads:
            t.join(60)
        assert not any(t.is_alive() for t in threads)
    finally:
        core.stop()
    stats = results["bridge"].as_dict()
    counts = {IMU: len(truth["/imu/data"]), ODOM: len(truth["/jackal_velocity_controller/odom"])}
    assert counts == {IMU: 3061, ODOM: 3060}
    recorded_counts = results["recorder"].recorded
    assert {k: recorded_counts.get(k) for k in counts} == counts, stats  # (also our stand-in Odometry and map)
    assert stats["published"] == counts and stats["raw"] == {} and stats["errors"] == {}
    assert stats["to_ros"]["/poseidon/odom"] >= 1 and stats["to_ros"]["/poseidon/path"] == 1
    assert stats["watermarks"] > 0
    recorded = {k: [m.stamp for m in read_messages(out, keys=[k])] for k in counts}
    assert recorded[IMU] == sorted(truth["/imu/data"])  # the ROS header stamps, every one
    assert recorded[ODOM] == sorted(truth["/jackal_velocity_controller/odom"])
