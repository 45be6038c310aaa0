"""``poseidon run --live ros1`` against a private ROS master: a bag played with ``rosbag play``
goes through robot_state into a complete recording that ends on SIGINT, carries the latency
summary, and replays through ``poseidon run --input`` to the same outputs; a service slowed on
purpose (``debug.slow_service``) drops its oldest queued inputs, counted, while the recording
stays complete.  Skips without ROS 1 or the bag."""
import json
import signal
import subprocess
import sys

import pytest

from common.mcap_io import read_messages
from eval.run_eval import evaluate_run
from tests.bridge_ros1.ros1 import Roscore, require_bag, require_ros1, wait_subscribed
from tests.conftest import REPO

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]
#: -d 5: rosbag waits after advertising, so the subscribed bridge has connected before the first message;
#: --queue: rosbag keeps 100 messages per subscriber by default and drops older ones when a loaded bridge lags
PLAY = ["rosbag", "play", "-q", "-d", "5", "--queue", "100000", "-r", "8"]
CLI = [sys.executable, "-m", "launcher.cli"]
TOPICS = ["/imu/data", "/jackal_velocity_controller/odom"]
#: lateness 1 s: at -r 8 on a loaded machine a rospy thread can stall longer than the 200 ms default,
#: and a message then late for robot_state would make the live outputs differ from the replay's
CONFIG = """robot_state:
  source: wheel_odometry
bridge_ros1:
  lateness_ms: 1000
  discover: false
  topics:
    /imu/data: {key: imu_adis_ros, type: sensor_msgs/Imu}
    /jackal_velocity_controller/odom: {key: wheel_odometry, type: nav_msgs/Odometry}
"""


def _live_run(tmp_path, core, bag, *extra, diagnostics=False, topics=TOPICS):
    """The live run of ``bag`` (once the bridge subscribed to ``topics``); with ``diagnostics``,
    what ``rostopic echo -n 1 /diagnostics`` printed while the bag played (else '')."""
    cfg = tmp_path / "live.yaml"
    cfg.write_text(CONFIG)
    out = tmp_path / "live.mcap"
    run = subprocess.Popen(CLI + ["run", "--live", "ros1", "--out", str(out), "--services", "robot_state",
                                  "--config", str(cfg), "--json", *extra], cwd=REPO, env=core.env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    echoed = ""
    try:
        wait_subscribed(core.uri, topics)
        play = subprocess.Popen(PLAY + [str(bag)], env=core.env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if diagnostics:
            echo = subprocess.run(["rostopic", "echo", "-n", "1", "/diagnostics"], env=core.env,
                                  stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
            assert echo.returncode == 0, echo.stderr
            echoed = echo.stdout
        _o, play_err = play.communicate(timeout=120)
        assert play.returncode == 0, play_err
        run.send_signal(signal.SIGINT)  # Ctrl-C: the source ends its streams, the rest finishes
        stdout, stderr = run.communicate(timeout=120)
    finally:
        for proc in (run, locals().get("play")):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert run.returncode == 0, stderr[-3000:]
    return out, cfg, json.loads(stdout), echoed


def test_a_live_run_ends_on_sigint_with_a_complete_recording_that_replays_to_the_same_outputs(tmp_path):
    require_ros1()
    bag = require_bag()
    core = Roscore(tmp_path / "roshome")
    try:
        # robot_state on wheel odometry reads no IMU: /imu/data is not bridged (bridge_ros1.bridge_unread off)
        out, cfg, result, echoed = _live_run(tmp_path, core, bag, diagnostics=True, topics=TOPICS[1:])
    finally:
        core.stop()
    assert result["mode"] == "live"
    # the run's health, as rqt_robot_monitor reads it: one status per process
    for name in ("hub", "recorder", "robot_state", "bridge_ros1"):
        assert f"name: \"poseidon/{name}\"" in echoed, echoed[:2000]
    rs = result["services"]["robot_state"]
    counts = dict(result["recording"]["counts"])
    assert counts.pop("live/health") >= 1  # one sample a second (supervise.health_interval_s)
    assert counts == {"wheel_odometry": 3060, "Odometry": 3060, "live/latency": 1}, (
        result["services"]["bridge_ros1"]["received"], result["services"]["bridge_ros1"]["late"], rs["rejected"],
        rs["dropped"])
    bridge = result["services"]["bridge_ros1"]
    assert bridge["late"] == {} and bridge["to_ros"]["/poseidon/odom"] == 3060
    assert bridge["unread"] == ["/imu/data"] and "/imu/data" not in bridge["received"]
    lat = bridge["latency"]["odometry"]
    print(f"live robot_state at -r 8: latency arrival -> Odometry {lat}")
    # < 5 s: the silent "odometry" input (announced, never published) did not stall robot_state; without
    # wall-clock watermarks nothing would come out before the end of the ~8 s bag
    assert lat["n"] == 3060 and 0 < lat["p50_ms"] <= lat["p95_ms"] <= lat["p99_ms"] <= lat["max_ms"] < 5000
    recorded = evaluate_run(out)["latency"]  # in the recording, for poseidon eval long after the run
    assert recorded["source"] == "bridge_ros1" and recorded["stages"]["odometry"] == lat
    assert result["services"]["robot_state"]["dropped"] == {}
    assert 0 < rs["cpu_s"] and 50 < rs["peak_rss_mb"] < 4000   # the process's own figures (MB)

    replay = tmp_path / "replay.mcap"
    proc = subprocess.run(CLI + ["run", "--input", str(out), "--out", str(replay), "--services", "robot_state",
                                 "--config", str(cfg), "--json"], cwd=REPO, capture_output=True, text=True,
                          timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    live = [m.payload for m in read_messages(out, keys=["Odometry"])]
    again = [m.payload for m in read_messages(replay, keys=["Odometry"])]
    assert len(live) == 3060 and live == again  # byte for byte: live event time is replay event time
    assert "live/latency" not in json.loads(proc.stdout)["recording"]["counts"]  # a replay has no live latency


def test_a_service_slowed_on_purpose_drops_its_oldest_inputs_counted_and_the_recording_stays_complete(tmp_path):
    require_ros1()
    bag = require_bag()
    core = Roscore(tmp_path / "roshome")
    try:
        _out, _cfg, result, _e = _live_run(tmp_path, core, bag, "--set", "debug.slow_service=robot_state",
                                       "--set", "debug.slow_ms=20", "--set", "live.queue_frames=20",
                                       "--set", "bridge_ros1.bridge_unread=true")
    finally:
        core.stop()
    counts = result["recording"]["counts"]
    published = result["services"]["bridge_ros1"]["published"]
    assert {k: counts[k] for k in published} == published  # the recorder keeps everything the source sent
    assert published["imu_adis_ros"] == 3061  # bridged though no service reads it (bridge_unread)
    assert result["services"]["bridge_ros1"]["unread"] == []
    dropped = result["services"]["robot_state"]["dropped"]
    print(f"slowed robot_state (20 ms/input, queue 20): dropped {dropped}, Odometry {counts['Odometry']}")
    assert dropped.get("wheel_odometry", 0) > 1000  # 400 msg/s offered, ~50/s taken
    assert counts["Odometry"] == published["wheel_odometry"] - dropped["wheel_odometry"]  # the rest was processed
