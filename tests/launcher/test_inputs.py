"""A run says what each service received on its inputs and, for a service that got nothing,
which keys of the recording no service read and the import option that maps them
(launcher/inputs.py); on the real ROS 1 bag, the mapping it names gives dead reckoning."""
import json

import pytest

from common.mcap_io import RecordingWriter, read_messages
from common.messages import Header, Imu, NavSatFix, Odometry
from launcher.inputs import format_inputs, input_report
from launcher.run import run_embedded
from missions.importers.cli import main as import_main
from system.config import load_config
from system.services import node_io

pytestmark = pytest.mark.timeout(600)

BAG_TOPICS = {"/imu/data": {"type": "sensor_msgs/Imu", "key": "imu/data"},
              "/husky_velocity_controller/odom": {"type": "nav_msgs/Odometry", "key": "husky_velocity_controller/odom"},
              "/fix": {"type": "sensor_msgs/NavSatFix", "key": "fix"}}


def _imported_like_the_husky_bag(path):
    """A recording with the keys and metadata ``poseidon import`` gives robot_localization_test1.bag."""
    with RecordingWriter(path) as w:
        for i in range(3):
            h = Header(seq=i, stamp=1_000_000_000 + i * 100_000_000, frame_id="x")
            w.write("imu/data", Imu(header=h, roll=0, pitch=0, yaw=0, qx=0, qy=0, qz=0, qw=1, gx=0, gy=0, gz=0,
                                    ax=0, ay=0, az=0))
            w.write("husky_velocity_controller/odom", Odometry(header=h, child_frame_id="base_link",
                                                               position=[0, 0, 0], orientation=[0, 0, 0, 1]))
            w.write("fix", NavSatFix(header=h, status=0, latitude=0, longitude=0, altitude=0))
        w.add_metadata("poseidon", {"tool": "poseidon import", "sources": ["in.bag"], "topics": BAG_TOPICS})


def test_a_service_without_input_is_named_with_the_exact_mapping_and_setting(tmp_path):
    rec = tmp_path / "t1.mcap"
    _imported_like_the_husky_bag(rec)
    cfg = load_config()
    io = {"robot_state": node_io("robot_state", cfg), "posecells": node_io("posecells", cfg)}
    report = input_report(cfg, io, {"robot_state": {"received": {}}, "posecells": {}}, rec)
    rs = report["robot_state"]
    assert rs["received"] == {"imu_adis_ros": 0, "dvl_linkquest": 0, "depth_sensor": 0, "odometry": 0}
    assert rs["missing"] == ["imu_adis_ros", "dvl_linkquest", "depth_sensor"]   # the reference is not needed
    assert rs["hint"] == (
        "robot_state: no input on imu_adis_ros, dvl_linkquest, depth_sensor; the recording has fix "
        "(sensor_msgs/NavSatFix), husky_velocity_controller/odom (nav_msgs/Odometry), imu/data (sensor_msgs/Imu), "
        "which no service reads: map them with 'poseidon import in.bag --topic "
        f"/husky_velocity_controller/odom=wheel_odometry --out {rec}' and run with "
        "'--set robot_state.source=wheel_odometry'")
    # posecells misses what robot_state (and htm, not in this run: a source key then) would publish
    assert report["posecells"]["hint"].startswith("posecells: no input on Odometry, local_view_cells")
    assert "(robot_state published nothing)" not in report["posecells"]["hint"]  # local_view_cells has no producer
    lines = format_inputs(report)
    assert lines[:2] == ["inputs received per service:",
                         "  [robot_state] imu_adis_ros 0, dvl_linkquest 0, depth_sensor 0, odometry 0"]
    assert lines[-2] == "  " + rs["hint"]


def test_a_service_missing_only_other_services_outputs_names_them():
    cfg = load_config()
    io = {n: node_io(n, cfg) for n in ("robot_state", "posecells", "htm", "encoder")}
    report = input_report(cfg, io, {"encoder": {"received": {"camera/image_raw": 5}},
                                    "htm": {"received": {"neocortex/sdr": 5, "Odometry": 5}},
                                    "robot_state": {"received": {"imu_adis_ros": 3, "dvl_linkquest": 3,
                                                                 "depth_sensor": 3}},
                                    "posecells": {"received": {"Odometry": 4}}}, None)
    assert report["posecells"]["hint"] == "posecells: no input on local_view_cells (htm published nothing)"
    assert report["robot_state"]["missing"] == [] and report["robot_state"]["hint"] == ""


def test_the_husky_bag_mapped_as_the_run_says_gives_dead_reckoning(shared_data, tmp_path):
    bag = shared_data / "ros1_bags" / "robot_localization_test1.bag"
    rec = tmp_path / "t1.mcap"
    assert import_main([str(bag), "--out", str(rec), "--no-progress"]) == 0
    cfg = load_config()
    before = run_embedded(cfg, rec, tmp_path / "r0.mcap", services=["robot_state"], progress=False, timeout_s=300)
    hint = before.as_dict()["inputs"]["robot_state"]["hint"]
    assert "--topic /husky_velocity_controller/odom=wheel_odometry" in hint, hint
    assert "--set robot_state.source=wheel_odometry" in hint and f"--out {rec}" in hint
    assert "imu/data (sensor_msgs/Imu)" in hint
    assert "Odometry" not in before.recording["counts"]
    # what the run said, word for word
    import_args = hint.split("'poseidon import ")[1].split("'")[0].split()
    assert import_main([*import_args, "--no-progress"]) == 0
    setting = hint.split("'--set ")[1].rstrip("'")
    after = run_embedded(load_config(overrides=[setting]), rec, tmp_path / "r1.mcap", services=["robot_state"],
                         progress=False, timeout_s=300)
    inputs = after.as_dict()["inputs"]["robot_state"]
    assert inputs["received"]["wheel_odometry"] == 3952 and inputs["missing"] == [] and inputs["hint"] == ""
    odometry = [m.message() for m in read_messages(tmp_path / "r1.mcap", keys=["Odometry"])]
    assert len(odometry) == 3952 and json.dumps(odometry[-1].position) != json.dumps(odometry[0].position)
