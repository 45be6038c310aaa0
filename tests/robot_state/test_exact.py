"""Noise-free synthetic streams: the published trajectory equals the analytic one (Eqs. 3.10-3.11)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from synth import mission, odometry_positions

from common.geometry import OutputFrame, matrix_to_euler, quaternion_to_matrix
from common.node import run_offline
from system.config import load_config
from system.services import build_node

# the filter on a 10 Hz grid of outputs (these tests count and time its outputs on it)
NED = ["robot_state.axis_remap=xyz", "robot_state.axis_sign_z=1", "robot_state.publish_rate_hz=10"]


def _yaws(outputs, frame: OutputFrame) -> np.ndarray:
    return np.array([matrix_to_euler(frame.rotation_to_ned(quaternion_to_matrix(m.orientation)))[2]
                     for k, m in outputs if k == "Odometry"])


@pytest.mark.parametrize("heading_deg", [0.0, 30.0, -135.0])
def test_straight_run_constant_heading(heading_deg):
    psi = math.radians(heading_deg)
    u, v = 0.5, 0.1
    msgs = mission(60, lambda t: (u, v, 0.0), lambda t: (0.0, 0.0, psi), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 5.0)
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    t, p = odometry_positions(out)
    assert len(t) == 601 and t[0] == 0.0 and t[-1] == pytest.approx(60.0)
    c, s = math.cos(psi), math.sin(psi)
    expected = np.column_stack([(c * u - s * v) * t, (s * u + c * v) * t, np.full_like(t, 5.0)])
    assert np.abs(p - expected).max() < 1e-9
    assert np.abs(np.array([math.remainder(a - psi, 2 * math.pi) for a in _yaws(out, OutputFrame("xyz", 1.0))])).max() < 1e-12
    last = [m for k, m in out if k == "Odometry"][-1]
    assert last.status == ["attitude_imu"]
    cov = np.array(last.pose_covariance).reshape(6, 6)
    assert np.all(np.diag(cov) >= 0) and np.allclose(cov, cov.T)
    assert cov[0, 0] + cov[1, 1] > 0  # horizontal uncertainty grows with distance
    assert cov[2, 2] <= 0.05 ** 2 + 1e-12  # depth-bounded


def test_pure_rotation_with_lever_arm():
    """Spinning in place: the DVL (0.4, 0.1, 0.2) m off the centre sees w x r, the filter removes it."""
    w = 0.3
    r = np.array([0.4, 0.1, 0.2])
    msgs = mission(40, lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, math.remainder(w * t, 2 * math.pi)),
                   lambda t: (0.0, 0.0, w), lambda t: 5.0,
                   dvl_velocity=lambda t: tuple(np.cross([0.0, 0.0, w], r)))
    node = build_node("robot_state", load_config(overrides=NED + ["robot_state.dvl.translation_m=[0.4,0.1,0.2]"]))
    out = run_offline(node, msgs)
    t, p = odometry_positions(out)
    assert np.abs(p - [0.0, 0.0, 5.0]).max() < 1e-9
    err = [math.remainder(a - w * tt, 2 * math.pi) for a, tt in zip(_yaws(out, OutputFrame("xyz", 1.0)), t)]
    assert np.abs(err).max() < 1e-9


def test_dive_default_enu_output():
    """Level descent at 0.2 m/s while moving north-east; default output frame is ENU (z up)."""
    psi = math.radians(45)
    u, w = 0.3, 0.2
    msgs = mission(30, lambda t: (u, 0.0, w), lambda t: (0.0, 0.0, psi), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 2.0 + w * t)
    node = build_node("robot_state", load_config())
    out = run_offline(node, msgs)
    t, p = odometry_positions(out)
    north = east = u * t * math.sqrt(0.5)
    expected = np.column_stack([east, north, -(2.0 + w * t)])
    assert np.abs(p - expected).max() < 1e-9
    assert out[0][1].header.frame_id == "odom_enu"
    # ENU yaw = pi/2 - NED yaw, counter-clockwise from east
    yaw_enu = [matrix_to_euler(quaternion_to_matrix(m.orientation))[2] for k, m in out if k == "Odometry"]
    assert np.allclose(yaw_enu, math.pi / 2 - psi, atol=1e-12)


def test_pitched_dive_uses_full_rotation():
    """Nose 20 deg down at 0.5 m/s forward: depth rate u sin(20 deg), horizontal u cos(20 deg)."""
    th = math.radians(-20.0)  # NED pitch: nose down is negative
    u = 0.5
    msgs = mission(30, lambda t: (u, 0.0, 0.0), lambda t: (0.0, th, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 3.0 - u * math.sin(th) * t)
    node = build_node("robot_state", load_config(overrides=NED))
    t, p = odometry_positions(run_offline(node, msgs))
    expected = np.column_stack([u * math.cos(th) * t, np.zeros_like(t), 3.0 - u * math.sin(th) * t])
    assert np.abs(p - expected).max() < 1e-9


def test_dvl_attitude_fallback_without_imu():
    """No IMU stream: the DVL's heading (deg) rotates its velocity (heading 90 deg -> east)."""
    msgs = mission(20, lambda t: (0.4, 0.0, 0.0), lambda t: (0.0, 0.0, math.pi / 2), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 4.0, with_imu=False, dvl_attitude=True)
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    t, p = odometry_positions(out)
    assert np.abs(p - np.column_stack([np.zeros_like(t), 0.4 * t, np.full_like(t, 4.0)])).max() < 1e-9
    statuses = [m.status for k, m in out if k == "Odometry"]
    assert all("imu_absent" in s and "attitude_dvl" in s for s in statuses)


def test_use_imu_false_drops_the_imu_input():
    node = build_node("robot_state", load_config(overrides=["robot_state.imu.enabled=false"]))
    assert node.inputs == ("dvl_linkquest", "depth_sensor", "odometry")
    node = build_node("robot_state", load_config(overrides=["robot_state.imu.topic=imu_adis"]))
    assert node.inputs[0] == "imu_adis"


def test_ground_truth_relay_keeps_everything_but_seq():
    from synth import T0, odom
    msgs = mission(2, lambda t: (0.1, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 1.0)
    refs = [odom(T0 + k * 250_000_000, 100 + 7 * k, [float(k), 2.0, 3.0]) for k in range(8)]
    out = run_offline(build_node("robot_state", load_config()), msgs + [("odometry", m) for m in refs])
    gt = [m for k, m in out if k == "ground_truth"]
    assert [m.header.seq for m in gt] == list(range(8))
    for a, b in zip(gt, refs):
        assert a.header.stamp == b.header.stamp and a.header.frame_id == b.header.frame_id
        assert a.model_dump(exclude={"header"}) == b.model_dump(exclude={"header"})


def test_deterministic_outputs():
    msgs = mission(10, lambda t: (0.3, 0.05, 0.01), lambda t: (0.01, 0.02, 0.1 * t), lambda t: (0.0, 0.0, 0.1),
                   lambda t: 3.0 + 0.01 * t)
    a = run_offline(build_node("robot_state", load_config()), msgs)
    b = run_offline(build_node("robot_state", load_config()), list(reversed(msgs)))
    assert [(k, m.model_dump()) for k, m in a] == [(k, m.model_dump()) for k, m in b]


def test_reflection_remap_is_rejected():
    from common.config import ConfigError
    with pytest.raises(ConfigError, match="axis_remap"):
        build_node("robot_state", load_config(overrides=["robot_state.axis_remap=yxz", "robot_state.axis_sign_z=1"]))


@pytest.mark.parametrize("fusion", [True, False])
def test_dvl_compass_bounds_imu_yaw_drift(fusion):
    """IMU yaw drifting 1 deg/min, DVL compass with a constant 2 deg mounting offset: fusing the
    compass (offset learned while the IMU is still good) bounds the heading error."""
    from synth import NS, T0, depth, dvl, imu

    msgs = []
    for k in range(600 * 10 + 1):  # IMU 10 Hz: true yaw 0, reported yaw drifts
        t = k / 10
        msgs.append(("imu_adis_ros", imu(T0 + k * NS // 10, k, (0.0, 0.0, math.radians(t / 60.0)), (0, 0, 0))))
    for k in range(600 * 2 + 1):  # DVL 2 Hz with compass heading 2 deg (offset)
        msgs.append(("dvl_linkquest", dvl(T0 + k * NS // 2, k, [0.3, 0.0, 0.0], rpy_deg=(0.0, 0.0, 2.0))))
    for k in range(600 + 1):
        msgs.append(("depth_sensor", depth(T0 + k * NS, k, 5.0)))
    node = build_node("robot_state", load_config(overrides=NED + [f"robot_state.dvl.heading_fusion={str(fusion).lower()}"]))
    out = run_offline(node, msgs)
    yaw_end = math.degrees(_yaws(out, OutputFrame("xyz", 1.0))[-1])
    if fusion:
        assert abs(yaw_end) < 2.0
        assert abs(math.degrees(node.filter.x[10]) - 2.0) < 1.5  # the learned compass offset
    else:
        assert abs(yaw_end - 10.0) < 0.5  # follows the IMU (slightly behind: the gyro says 0)


def test_gyro_bias_is_estimated():
    """A 0.05 deg/s gyro bias against a correct IMU attitude: the bias state absorbs it and the
    yaw does not lag (without the state it would lag by bias x the filter's time constant)."""
    bias = math.radians(0.05)
    msgs = mission(300, lambda t: (0.3, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, bias),
                   lambda t: 5.0, dvl_hz=2.0, depth_hz=2.0)
    node = build_node("robot_state", load_config(overrides=NED + ["robot_state.dvl.heading_fusion=false"]))
    out = run_offline(node, msgs)
    assert abs(node.filter.x[13] - bias) < 0.05 * bias
    assert abs(math.degrees(_yaws(out, OutputFrame("xyz", 1.0))[-1])) < 0.01
