"""Bad input: each case is rejected, bridged or flagged, counted, visible in the output status,
never a crash and never a jump of the estimate."""
from __future__ import annotations

import math

import numpy as np
from synth import NS, T0, depth, dvl, imu, mission, odometry_positions

from common.node import run_offline
from system.config import load_config
from system.services import build_node

# the filter on a 10 Hz grid of outputs (these tests count and time its outputs on it)
NED = ["robot_state.axis_remap=xyz", "robot_state.axis_sign_z=1", "robot_state.publish_rate_hz=10"]
U = 0.5  # m/s forward, heading 0 -> north


def _straight(duration=30.0, **kw):
    return mission(duration, lambda t: (U, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 5.0, **kw)


def _replace(msgs, key, seq, new):
    return [(k, new if (k == key and m.header.seq == seq) else m) for k, m in msgs]


def _odometry(out):
    return [m for k, m in out if k == "Odometry"]


def _max_step(out) -> float:
    t, p = odometry_positions(out)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).max())


def _statuses(out) -> set[str]:
    return {s for m in _odometry(out) for s in m.status}


def test_nan_and_inf_are_rejected_and_counted():
    msgs = _straight()
    msgs = _replace(msgs, "dvl_linkquest", 20, dvl(T0 + 4 * NS, 20, [math.nan, 0.0, 0.0]))
    msgs = _replace(msgs, "dvl_linkquest", 21, dvl(T0 + int(4.2 * NS), 21, [math.inf, 0.0, 0.0]))
    msgs = _replace(msgs, "depth_sensor", 50, depth(T0 + 5 * NS, 50, math.nan))
    msgs = _replace(msgs, "depth_sensor", 51, depth(T0 + int(5.1 * NS), 51, -math.inf))
    msgs = _replace(msgs, "imu_adis_ros", 120, imu(T0 + 6 * NS, 120, (0.0, 0.0, math.nan), (0.0, 0.0, 0.0)))
    msgs = _replace(msgs, "imu_adis_ros", 121, imu(T0 + int(6.05 * NS), 121, (0.0, 0.0, 0.0), (math.inf, 0.0, 0.0)))
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    assert node.counters["dvl_nonfinite"] == 2
    assert node.counters["depth_nonfinite"] == 2
    assert node.counters["imu_nonfinite"] == 2
    assert {"dvl_nonfinite", "depth_nonfinite", "imu_nonfinite"} <= _statuses(out)
    t, p = odometry_positions(out)
    # nothing was lost: constant motion is still reproduced exactly
    assert np.abs(p - np.column_stack([U * t, 0 * t, 0 * t + 5.0])).max() < 1e-9
    for m in _odometry(out):
        assert all(math.isfinite(v) for v in m.position + m.orientation + m.pose_covariance)


def test_invalid_flag_few_beams_and_too_fast_are_rejected():
    msgs = _straight()
    msgs = _replace(msgs, "dvl_linkquest", 30, dvl(T0 + 6 * NS, 30, [9.0, 9.0, 0.0], flag=0))
    msgs = _replace(msgs, "dvl_linkquest", 31, dvl(T0 + int(6.2 * NS), 31, [9.0, 0.0, 0.0], good=(1, 1, 0, 0)))
    msgs = _replace(msgs, "dvl_linkquest", 32, dvl(T0 + int(6.4 * NS), 32, [3.5, 0.0, 0.0]))
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    assert node.counters["dvl_invalid_flag"] == 1
    assert node.counters["dvl_few_beams"] == 1
    assert node.counters["dvl_too_fast"] == 1
    assert {"dvl_invalid_flag", "dvl_few_beams", "dvl_too_fast"} <= _statuses(out)
    t, p = odometry_positions(out)
    assert np.abs(p[:, 0] - U * t).max() < 1e-9


def test_three_good_beams_are_enough_by_default():
    msgs = _replace(_straight(10), "dvl_linkquest", 10, dvl(T0 + 2 * NS, 10, [U, 0.0, 0.0], good=(0, 1, 1, 1)))
    node = build_node("robot_state", load_config(overrides=NED))
    run_offline(node, msgs)
    assert "dvl_few_beams" not in node.counters


def test_timestamp_backwards_offline_is_rejected():
    """A DVL record stamped 1.5 s too early: the event-time merge moves it, the seq betrays it."""
    msgs = _straight()
    msgs = _replace(msgs, "dvl_linkquest", 50, dvl(T0 + int(8.5 * NS), 50, [U, 0.0, 0.0]))
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    assert node.counters["timestamp_backwards"] >= 1
    assert node.counters["dvl_timestamp_backwards"] == node.counters["timestamp_backwards"]
    assert "timestamp_backwards" in _statuses(out)
    t, p = odometry_positions(out)
    assert np.abs(p[:, 0] - U * t).max() < 1e-9


def test_timestamp_backwards_and_late_live():
    """Records delivered out of order by a live transport: backwards on its own stream is rejected,
    older than the state but in order on its stream is applied now and counted as late."""
    node = build_node("robot_state", load_config(overrides=NED))
    node.process("imu_adis_ros", imu(T0, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    node.process("dvl_linkquest", dvl(T0, 0, [U, 0.0, 0.0]))
    node.process("depth_sensor", depth(T0, 0, 5.0))
    node.process("imu_adis_ros", imu(T0 + 2 * NS, 1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    node.process("dvl_linkquest", dvl(T0 + 2 * NS, 1, [U, 0.0, 0.0]))
    node.process("dvl_linkquest", dvl(T0 + 1 * NS, 2, [U, 0.0, 0.0]))  # backwards on its stream
    node.process("depth_sensor", depth(T0 + 1 * NS, 1, 5.0))  # late (state is at T0 + 2 s)
    node.process("imu_adis_ros", imu(T0 + 3 * NS, 2, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    node.finish()
    out = node.take_outbox()
    assert node.counters["timestamp_backwards"] == 1
    assert node.counters["late"] == 1
    assert {"timestamp_backwards", "late"} <= _statuses(out)
    t, p = odometry_positions(out)
    assert np.all(np.diff(t) > 0)
    assert np.abs(p[:, 0] - U * t).max() < 1e-9


def _with_gap(msgs, start_s, end_s):
    return [(k, m) for k, m in msgs if not (T0 + start_s * NS < m.header.stamp < T0 + end_s * NS)]


def test_gap_of_30s_is_bridged_flagged_and_bounded():
    cfg = load_config(overrides=NED)
    rs = cfg.robot_state
    msgs = _with_gap(_straight(90.0), 30.0, 60.0)  # every sensor silent for 30 s
    node = build_node("robot_state", cfg)
    out = run_offline(node, msgs)
    assert node.counters["gap"] == 1
    odo = _odometry(out)
    t, p = odometry_positions(out)
    bridged = [m for m in odo if "gap_bridged" in m.status]
    assert len(bridged) == 299  # the grid strictly inside the gap
    assert all("dvl_dropout" in m.status for m in bridged[-10:])
    # velocity held for dvl.timeout_s then decaying: the bridge moves at most |v| (timeout + tau)
    i30, i60 = np.searchsorted(t, 30.0), np.searchsorted(t, 60.0)
    bridge = p[i60 - 1, 0] - p[i30, 0]
    assert 0 < bridge <= U * (rs.dvl.timeout_s + rs.dvl.dropout_decay_s) + 1e-9
    assert _max_step(out) <= U / rs.publish_rate_hz + 1e-9  # never a jump
    # covariance grows through the gap and shrinks back (velocity) after it
    var = np.array([m.pose_covariance[0] + m.pose_covariance[7] for m in odo])
    assert var[i60 - 1] > var[i30] * 1.5
    assert all(np.diff(var[i30:i60]) >= -1e-12)
    # after the gap the motion resumes at the DVL velocity
    assert abs((p[-1, 0] - p[i60 + 10, 0]) - U * (t[-1] - t[i60 + 10])) < 1e-9


def test_long_silence_does_not_flood_the_output():
    msgs = _with_gap(_straight(40.0), 5.0, 3605.0)
    msgs += [(k, m.model_copy(update={"header": m.header.model_copy(update={"stamp": m.header.stamp + 3600 * NS})}))
             for k, m in _straight(40.0) if m.header.stamp > T0 + 3605 * NS - 3600 * NS]
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    assert node.counters["gap"] == 1
    assert len(_odometry(out)) < 50 + 300 + 400 + 10


def test_dvl_dropout_is_flagged_and_velocity_decays():
    cfg = load_config(overrides=NED)
    msgs = [(k, m) for k, m in _straight(60.0)
            if not (k == "dvl_linkquest" and T0 + 20 * NS < m.header.stamp < T0 + 40 * NS)]
    node = build_node("robot_state", cfg)
    out = run_offline(node, msgs)
    odo = _odometry(out)
    t, p = odometry_positions(out)
    flagged = [tt for tt, m in zip(t, odo) if "dvl_dropout" in m.status]
    assert flagged and min(flagged) > 20.0 + cfg.robot_state.dvl.timeout_s - 0.1 and max(flagged) < 40.0
    assert node.counters["dvl_reacquired"] == 1
    speed = np.diff(p[:, 0]) / np.diff(t)
    i38 = np.searchsorted(t, 38.0)
    assert speed[i38] < U * math.exp(-(38 - 22.1) / cfg.robot_state.dvl.dropout_decay_s) * 1.01
    assert _max_step(out) <= U / cfg.robot_state.publish_rate_hz + 1e-9


def test_imu_dropout_falls_back_to_dvl_attitude():
    msgs = mission(30, lambda t: (U, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 5.0, dvl_attitude=True)
    msgs = [(k, m) for k, m in msgs if not (k == "imu_adis_ros" and m.header.stamp > T0 + 10 * NS)]
    node = build_node("robot_state", load_config(overrides=NED))
    out = run_offline(node, msgs)
    first = [m.status for m in _odometry(out)]
    assert "attitude_imu" in first[50] and "imu_absent" not in first[50]
    assert "attitude_dvl" in first[200] and "imu_absent" in first[200]
    t, p = odometry_positions(out)
    assert np.abs(p[:, 0] - U * t).max() < 1e-9


def test_innovation_gate_rejects_spikes_and_reinitialises_on_a_real_step():
    cfg = load_config(overrides=NED + ["robot_state.dvl.gate_chi2=16.27"])
    msgs = _straight(30.0)
    msgs = _replace(msgs, "dvl_linkquest", 40, dvl(T0 + 8 * NS, 40, [1.9, 0.0, 0.0]))  # one spike
    node = build_node("robot_state", cfg)
    out = run_offline(node, msgs)
    assert node.counters["dvl_outlier"] == 1 and "dvl_reinit" not in node.counters
    assert "dvl_outlier" in _statuses(out)
    t, p = odometry_positions(out)
    assert np.abs(p[:, 0] - U * t).max() < 1e-9
    # a genuine, lasting change of speed: two rejections, then the third re-initialises
    step = mission(30, lambda t: (U if t < 10 else 1.5, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: (0.0, 0.0, 0.0), lambda t: 5.0)
    node = build_node("robot_state", cfg)
    out = run_offline(node, step)
    assert node.counters["dvl_outlier"] == 2 and node.counters["dvl_reinit"] == 1
    t, p = odometry_positions(out)
    speed = np.diff(p[:, 0]) / np.diff(t)
    assert abs(speed[-1] - 1.5) < 1e-9


def test_enu_covariance_is_the_ned_one_remapped():
    msgs = mission(20, lambda t: (0.5, 0.0, 0.0), lambda t: (0.0, 0.0, math.radians(60)),
                   lambda t: (0.0, 0.0, 0.0), lambda t: 5.0)
    ned = _odometry(run_offline(build_node("robot_state", load_config(overrides=NED)), msgs))[-1]
    enu = _odometry(run_offline(build_node("robot_state", load_config()), msgs))[-1]
    a = np.array(ned.pose_covariance).reshape(6, 6)
    b = np.array(enu.pose_covariance).reshape(6, 6)
    perm = [1, 0, 2]
    assert np.allclose(b[:3, :3], a[np.ix_(perm, perm)] * np.outer([1, 1, -1], [1, 1, -1]), rtol=1e-12, atol=1e-15)
    assert np.allclose(np.diag(b)[3:], np.diag(a)[3:], rtol=1e-9)
    assert b[0, 0] != b[1, 1]  # heading 60 deg: along-/cross-track uncertainty differ per axis


def test_output_watermark_is_a_promise():
    """Live use: after output_watermark(W) returned w, no later output is stamped below w."""
    from synth import odom

    from common.ordering import EventTimeMerger

    msgs = _straight(10.0) + [("odometry", odom(T0 + k * NS // 4, k, [0.0, 0.0, 0.0])) for k in range(40)]
    node = build_node("robot_state", load_config())
    merger = EventTimeMerger(list(node.inputs))
    promised = -1
    for key, m in sorted(msgs, key=lambda km: km[1].header.stamp):
        merger.push(key, m.header.stamp, m.header.seq, m)
        for k, _stamp, item in merger.pop_ready():
            node.process(k, item)
            for _key, out in node.take_outbox():
                assert out.header.stamp >= promised
            promised = max(promised, node.output_watermark(merger.watermark))
    for key in node.inputs:
        merger.end(key)
    for k, _stamp, item in merger.pop_ready():
        node.process(k, item)
    node.finish()
    assert all(out.header.stamp >= promised for _k, out in node.take_outbox())
