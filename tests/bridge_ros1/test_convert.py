"""The bridge's conversions, without ROS: the importer's mapping for ROS bytes in, ROS 1 bytes out."""
import json

import numpy as np
import pytest

from common.messages import (
    ExperienceEvent,
    ExperienceLink,
    ExperienceMap,
    ExperienceNode,
    Header,
    Imu,
    LocalViewCell,
    LocalViewCells,
    Odometry,
    RawMessage,
)
from common.ros_convert import make_typestore
from services.bridge_ros1.config import BridgeRos1Config, TopicRoute
from services.bridge_ros1.convert import Incoming, Outgoing

STORE = make_typestore()
T = STORE.types


def _imu_bytes(sec=47, nsec=580_000_000, seq=9):
    q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    v = T["geometry_msgs/msg/Vector3"](x=0.1, y=0.2, z=9.8)
    h = T["std_msgs/msg/Header"](seq=seq, stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                 frame_id="base_link")
    m = T["sensor_msgs/msg/Imu"](header=h, orientation=q, orientation_covariance=np.zeros(9), angular_velocity=v,
                                 angular_velocity_covariance=np.zeros(9), linear_acceleration=v,
                                 linear_acceleration_covariance=np.zeros(9))
    return bytes(STORE.serialize_ros1(m, "sensor_msgs/msg/Imu"))


def _definition(t):
    text, md5 = STORE.generate_msgdef(t, ros_version=1)
    return md5, text


def test_a_mapped_type_converts_like_the_importer_with_the_header_stamp():
    inc = Incoming(BridgeRos1Config().topics, discover=True)
    key, msg, why = inc.convert("/imu/data", "sensor_msgs/Imu", *_definition("sensor_msgs/msg/Imu"), _imu_bytes(),
                                arrival_ns=123)
    assert (key, why) == ("imu/data", "")
    assert isinstance(msg, Imu) and msg.header.stamp == 47_580_000_000 and msg.header.seq == 9
    assert msg.header.frame_id == "base_link" and msg.az == pytest.approx(9.8)


def test_the_configured_route_names_the_key_and_a_wrong_type_is_carried_raw():
    routes = {"/imu/data": TopicRoute(key="imu_adis_ros", type="sensor_msgs/Imu"),
              "/odom": TopicRoute(key="odometry", type="nav_msgs/Odometry")}
    inc = Incoming(routes, discover=False)
    key, msg, _ = inc.convert("/imu/data", "sensor_msgs/Imu", *_definition("sensor_msgs/msg/Imu"), _imu_bytes(), 1)
    assert key == "imu_adis_ros" and isinstance(msg, Imu)
    key, msg, why = inc.convert("/odom", "sensor_msgs/Imu", *_definition("sensor_msgs/msg/Imu"), _imu_bytes(), 1)
    assert key == "raw/odometry" and isinstance(msg, RawMessage) and why.startswith("type_mismatch")
    assert inc.convert("/other", "sensor_msgs/Imu", "", "", b"", 1) is None  # not configured, no discovery


def test_an_unknown_type_is_carried_raw_with_its_bytes_definition_and_header_stamp():
    definition = "Header header\nfloat32 level\n================================================================================\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    data = (b"\x05\x00\x00\x00" + (3).to_bytes(4, "little") + (7).to_bytes(4, "little") + b"\x02\x00\x00\x00ab"
            + np.float32(0.5).tobytes())
    inc = Incoming({}, discover=True)
    key, msg, why = inc.convert("/vendor/status", "vendor_msgs/Status", "abc123", definition, data, 99)
    assert key == "raw/vendor/status" and why == "no model for vendor_msgs/Status"
    assert isinstance(msg, RawMessage) and msg.data == data and msg.definition == definition
    assert msg.header.stamp == 3_000_000_007 and msg.header.frame_id == "ab" and msg.digest == "abc123"
    assert msg.ros_type == "vendor_msgs/msg/Status" and msg.serialization == "ros1"


def test_a_payload_that_does_not_decode_is_carried_raw_stamped_at_arrival():
    inc = Incoming({}, discover=True)
    key, msg, why = inc.convert("/imu/data", "sensor_msgs/Imu", *_definition("sensor_msgs/msg/Imu"), b"\x01\x02", 77)
    assert key == "raw/imu/data" and why.startswith("payload does not decode")
    assert msg.header.stamp == 77


def _h(stamp, frame=""):
    return Header(seq=3, stamp=stamp, frame_id=frame)


def test_our_outputs_become_ros_messages_that_read_back():
    out = Outgoing()
    odom = Odometry(header=_h(5_000_000_001, "odom"), child_frame_id="base_link", position=[1.0, 2.0, -3.0],
                    orientation=[0.0, 0.0, 0.0, 1.0])
    rtype, data = out.standard(odom)
    back = STORE.deserialize_ros1(data, "nav_msgs/msg/Odometry")
    assert rtype == "nav_msgs/Odometry" and back.pose.pose.position.z == -3.0
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (5, 1) and back.child_frame_id == "base_link"
    assert out.definition("nav_msgs/Odometry")[0] == "cd5e73d190d741a2f92e81eda573aca7"  # ROS's own md5

    nodes = [ExperienceNode(id=i, lvc_id=i, position=[float(i), 0.0, 0.0], yaw=0.0, stamp=100 + i) for i in range(3)]
    links = [ExperienceLink(source=0, target=1, delta=[1.0, 0.0, 0.0], duration_s=1.0, weight=1.0),
             ExperienceLink(source=2, target=0, delta=[-2.0, 0.0, 0.0], duration_s=1.0, weight=1.0, loop_closure=True)]
    m = ExperienceMap(header=_h(102), nodes=nodes, links=links, current=2)
    path = STORE.deserialize_ros1(out.path(m), "nav_msgs/msg/Path")
    assert [p.pose.position.x for p in path.poses] == [0.0, 1.0, 2.0] and path.header.frame_id == "odom"
    assert path.poses[2].header.stamp.nanosec == 102
    ma = STORE.deserialize_ros1(out.markers(m), "visualization_msgs/msg/MarkerArray")
    by_ns = {mk.ns: mk for mk in ma.markers}
    assert ma.markers[0].action == 3  # DELETEALL first
    assert len(by_ns["experiences"].points) == 3 and len(by_ns["links"].points) == 2
    assert [(p.x, p.y) for p in by_ns["loop_closures"].points] == [(2.0, 0.0), (0.0, 0.0)]
    assert by_ns["current"].pose.position.x == 2.0

    lvc = LocalViewCells(header=_h(7), most_active_cell=42, active_cells=[LocalViewCell(id=42, rate=0.5)],
                         is_new=False, intersection=3)
    assert STORE.deserialize_ros1(out.lvc_id(lvc), "std_msgs/msg/Int32").data == 42
    ev = ExperienceEvent(header=_h(8), lvc_id=42, pc_centroid=[0.0, 1.0, 2.0, 0.5], odom_position=[1.0, 2.0, 3.0],
                         odom_yaw=0.1, gate="vpr", vpr_count=4)
    doc = json.loads(STORE.deserialize_ros1(out.event(ev), "std_msgs/msg/String").data)
    assert doc == {"stamp": 8, "lvc_id": 42, "gate": "vpr", "vpr_count": 4, "odom_position": [1.0, 2.0, 3.0],
                   "odom_yaw": 0.1, "pc_centroid": [0.0, 1.0, 2.0, 0.5]}
