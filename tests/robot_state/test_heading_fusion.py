"""Heading fusion and dropout behaviour that decide dead reckoning across missions."""
from __future__ import annotations

import math

import numpy as np
import pytest
from synth import NS, T0, depth, dvl, imu, mission, odometry_positions

from common.node import run_offline
from services.robot_state.filter import B_DVL, D_IMU
from system.config import load_config
from system.services import build_node

# the filter on a 10 Hz grid of outputs (these tests count and time its outputs on it)
NED = ["robot_state.axis_remap=xyz", "robot_state.axis_sign_z=1", "robot_state.publish_rate_hz=10"]


def _drifting_imu_with_compass(minutes: float, drift_deg_min: float, offset_deg: float, heading_noise_deg: float,
                               seed: int = 3, spin_at: float | None = None,
                               compass_spike_at: float | None = None):
    """Cruising at 0.3 m/s, true yaw 0.  IMU yaw drifts linearly; the DVL compass sits at a
    constant offset with white noise.  Optionally the vehicle spins 10 turns in 3 s from
    ``spin_at`` (rate up to 2400 deg/s and back, gyro included: far beyond what 10 Hz samples
    can integrate), or one compass record is 90 deg off."""
    rng = np.random.default_rng(seed)
    dur = minutes * 60
    peak = math.radians(2400.0)

    def true_yaw(t: float) -> tuple[float, float]:
        if spin_at is None or not spin_at <= t < spin_at + 3.0:
            return 0.0, 0.0
        u = t - spin_at  # triangular rate profile: up for 1.5 s, down for 1.5 s
        if u < 1.5:
            return math.remainder(peak * u * u / 3.0, 2 * math.pi), peak * u / 1.5
        w = 3.0 - u
        return math.remainder(-peak * w * w / 3.0, 2 * math.pi), peak * w / 1.5

    msgs = []
    for k in range(int(dur * 10) + 1):
        t = k / 10
        yaw, rate = true_yaw(t)
        yaw += math.radians(drift_deg_min * t / 60.0)
        msgs.append(("imu_adis_ros", imu(T0 + k * NS // 10, k, (0.0, 0.0, yaw), (0, 0, rate))))
    for k in range(int(dur * 2) + 1):
        t = k / 2
        h = math.degrees(true_yaw(t)[0]) + offset_deg + rng.normal(0.0, heading_noise_deg)
        if compass_spike_at is not None and abs(t - compass_spike_at) < 0.25:
            h += 90.0
        msgs.append(("dvl_linkquest", dvl(T0 + k * NS // 2, k, [0.3, 0.0, 0.0], rpy_deg=(0.0, 0.0, h % 360.0))))
    for k in range(int(dur) + 1):
        msgs.append(("depth_sensor", depth(T0 + k * NS, k, 5.0)))
    return msgs


def _run(msgs, *overrides):
    node = build_node("robot_state", load_config(overrides=NED + list(overrides)))
    out = run_offline(node, msgs)
    return node, out


def test_imu_yaw_drift_rate_keeps_the_compass_offset_unbiased():
    """A 0.5 deg/min AHRS ramp and a 2 deg compass offset (2 deg noise): with the drift-rate state
    the learned offset and the heading stay within 0.3 deg; without it (rate prior 0, the old
    random-walk-only model) the early ramp is taken for compass offset."""
    msgs = _drifting_imu_with_compass(10, 0.5, 2.0, 2.0)
    node, out = _run(msgs)
    offset = math.degrees(node.filter.x[B_DVL])
    yaw_err = math.degrees(node.filter.x[8])
    assert abs(offset - 2.0) < 0.3
    assert abs(yaw_err) < 0.3
    assert math.degrees(node.filter.x[D_IMU]) * 60 == pytest.approx(0.5, abs=0.1)  # deg/min
    # the cross-track error of a 180 m straight run stays below 1 m (0.3 deg)
    _t, p = odometry_positions(out)
    assert abs(p[-1, 1]) < 1.0
    old, _ = _run(msgs, "robot_state.imu.yaw_drift_rate_sigma_deg_min=0")
    assert abs(math.degrees(old.filter.x[B_DVL]) - 2.0) > abs(offset - 2.0) + 0.1


def test_spin_resets_the_yaw_without_corrupting_the_compass_offset():
    """A spin at up to 2400 deg/s (what a heading flip at a route junction of the
    simulator looked like, ``missions/sim/trajectory.py::_tunnel_normals``), ending 4 s before the last record: the yaw is reset to the IMU at every
    sample the gyro cannot predict (counted), so the heading is right at once and the compass
    offset learned before survives; without the gate the heading is still ~10 deg off."""
    spin = [(k, m) for k, m in _drifting_imu_with_compass(4, 0.0, 2.0, 0.5, spin_at=225.0)
            if m.header.stamp <= T0 + 232 * NS]
    node, _ = _run(spin)
    assert node.counters.get("imu_yaw_reset", 0) >= 2
    assert abs(math.degrees(node.filter.x[B_DVL]) - 2.0) < 0.3
    assert abs(math.degrees(node.filter.x[8])) < 0.3
    ungated, _ = _run(spin, "robot_state.heading_gate_chi2=0")
    assert "imu_yaw_reset" not in ungated.counters
    assert abs(math.degrees(ungated.filter.x[8])) > 3.0  # what the gate prevents


def test_compass_spike_is_rejected_and_counted():
    msgs = _drifting_imu_with_compass(3, 0.0, 2.0, 0.5, compass_spike_at=100.0)
    node, _ = _run(msgs)
    assert node.counters["dvl_heading_outlier"] == 1
    assert "imu_yaw_reset" not in node.counters
    assert abs(math.degrees(node.filter.x[B_DVL]) - 2.0) < 0.3


def test_short_dvl_dropout_keeps_the_cruise_speed():
    """A 6 s DVL dropout while cruising at 0.5 m/s: the velocity is held, then decays with
    dvl_dropout_decay_s (30 s): 0.5 (4 - 30 (1 - exp(-4/30))) = 0.13 m lost; with 5 s it was 0.62 m."""
    msgs = mission(40, lambda t: (0.5, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 5.0, dvl_hz=2.0)
    msgs = [(k, m) for k, m in msgs
            if not (k == "dvl_linkquest" and 20 * NS < m.header.stamp - T0 < 26 * NS)]
    node, out = _run(msgs)
    t, p = odometry_positions(out)
    assert node.counters.get("dvl_reacquired") == 1
    i = int(np.searchsorted(t, 26.0))
    assert 0.5 * t[i] - p[i, 0] < 0.15
    fast, out5 = _run(msgs, "robot_state.dvl.dropout_decay_s=5")
    t5, p5 = odometry_positions(out5)
    assert 0.5 * t5[i] - p5[i, 0] > 0.5
