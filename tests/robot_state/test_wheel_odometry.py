"""robot_state with ``source: wheel_odometry`` (the laser preset): wheel odometry republished."""
from __future__ import annotations

import math

from common.messages import Header, Odometry
from common.node import run_offline
from services.robot_state.node import RobotStateNode
from system.config import PoseidonConfig
from system.services import build_node


def wheel(seq: int, stamp: int, x: float, y: float, yaw: float, q=None) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=stamp, frame_id="odom"), position=[x, y, 0.0],
                    orientation=q if q is not None else [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)],
                    linear_velocity=[0.4, 0.0, 0.0], angular_velocity=[0.0, 0.0, 0.1])


def config() -> PoseidonConfig:
    cfg = PoseidonConfig().model_copy(deep=True)
    cfg.robot_state.source = "wheel_odometry"
    return cfg


def test_inputs_are_the_wheel_odometry_only():
    ins, outs = RobotStateNode.io_keys(config().robot_state)
    assert ins == ("wheel_odometry", "odometry") and "Odometry" in outs


def test_each_wheel_pose_is_published_with_its_stamp():
    msgs = [("wheel_odometry", wheel(k, 1_000 + 200_000_000 * k, 0.1 * k, 0.02 * k, 0.05 * k)) for k in range(5)]
    out = run_offline(build_node("robot_state", config()), msgs)
    odo = [m for k, m in out if k == "Odometry"]
    assert [m.header.stamp for m in odo] == [m.header.stamp for _k, m in msgs]
    assert [m.header.seq for m in odo] == list(range(5))
    for (_k, src), m in zip(msgs, odo):
        assert m.position == src.position and m.orientation == src.orientation
        assert m.linear_velocity == src.linear_velocity and m.status == ["wheel_odometry"]
        assert m.header.frame_id == "odom_wheel"


def test_a_zero_quaternion_is_counted_and_skipped():
    node = build_node("robot_state", config())
    msgs = [("wheel_odometry", wheel(0, 10, 0.0, 0.0, 0.0)),
            ("wheel_odometry", wheel(1, 20, 0.1, 0.0, 0.0, q=[0.0, 0.0, 0.0, 0.0])),
            ("wheel_odometry", wheel(2, 30, 0.2, 0.0, 0.0))]
    out = run_offline(node, msgs)
    assert [m.header.stamp for k, m in out if k == "Odometry"] == [10, 30]
    assert node.counters["wheel_odometry_invalid"] == 1


def test_the_wheel_time_offset_moves_every_stamp_onto_the_scans_clock():
    msgs = [("wheel_odometry", wheel(k, 1_000_000_000 + 200_000_000 * k, 0.1 * k, 0.0, 0.0)) for k in range(4)]
    for offset in (0.085, -0.05):
        cfg = config()
        cfg.robot_state.wheel_time_offset_s = offset
        node = build_node("robot_state", cfg)
        out = run_offline(node, msgs)
        shift = round(offset * 1e9)
        assert [m.header.stamp for k, m in out if k == "Odometry"] == [m.header.stamp + shift for _k, m in msgs]
        # outputs stamped before their inputs lower the promise by as much; later ones keep it
        assert node.output_watermark(5_000_000_000) == 5_000_000_000 + min(0, shift)
