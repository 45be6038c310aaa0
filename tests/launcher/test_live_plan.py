"""``poseidon run --live``'s plan and argument checks (no ROS needed)."""
import subprocess
import sys

import pytest

from launcher.live import plan_live, run_live
from system.config import load_config
from tests.conftest import REPO


def test_the_bridge_announces_every_sensor_key_the_services_read_and_the_recorder_awaits_the_outputs_too():
    config = load_config(None, ["robot_state.source=wheel_odometry",
                                "bridge_ros1.topics={/odom: {key: wheel_odometry}}"])
    plan = plan_live(config, ["robot_state"])
    assert plan.player_keys == ["odometry", "wheel_odometry"]  # routed + read (silent ones kept alive)
    assert plan.expect == ["Odometry", "ground_truth", "live/latency", "odometry", "wheel_odometry"]


def test_the_bridge_reads_only_the_keys_the_services_read_unless_told_to_bridge_every_topic():
    plan = plan_live(load_config(), None)
    read = ["camera/image_raw", "depth_sensor", "dvl_linkquest", "imu_adis_ros", "odometry", "sonar_micron"]
    assert plan.read == read and plan.player_keys == read  # not sonar_seaking, imu_adis, sonar_*_ros
    every = plan_live(load_config(None, ["bridge_ros1.bridge_unread=true"]), None)
    assert every.read is None
    assert {"sonar_seaking", "sonar_micron_ros", "imu_adis"} <= set(every.player_keys)


def test_a_service_input_nobody_provides_is_named():
    config = load_config(None, ["robot_state.source=wheel_odometry", "bridge_ros1.topics={}"])
    with pytest.raises(ValueError, match="wheel_odometry"):
        plan_live(config, ["robot_state"])


def test_unknown_live_source_and_bad_output_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown live source"):
        run_live(load_config(), "ros2", tmp_path / "x.mcap")
    with pytest.raises(ValueError, match=".mcap"):
        run_live(load_config(), "ros1", tmp_path / "x.bag")


@pytest.mark.parametrize("args", [["--out", "x.mcap"], ["--live", "ros1", "--input", "a.mcap", "--out", "x.mcap"],
                                  ["--live", "ros1", "--embedded", "--out", "x.mcap"]])
def test_run_wants_exactly_one_source(args, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "launcher.cli", "run", *args], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 2 and "poseidon run:" in proc.stderr, proc.stderr
