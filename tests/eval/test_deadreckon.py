"""``poseidon deadreckon`` on a small recording written in the test (out-and-back run)."""
from __future__ import annotations

import json
import math

import numpy as np

from common.geometry import euler_to_matrix, matrix_to_quaternion
from common.mcap_io import RecordingWriter
from common.messages import Header, Odometry
from eval.deadreckon import main
from services.robot_state.config import RobotStateConfig
from tests.robot_state.synth import NS, T0, mission

U, W = 0.5, math.pi / 10  # forward speed m/s, turn rate rad/s


def _vel(t):
    return (U, 0.0, 0.0) if (t < 20 or t >= 30) else (0.0, 0.0, 0.0)


def _yaw(t):
    return 0.0 if t < 20 else (W * (t - 20) if t < 30 else math.pi)


def _pos(t):
    if t <= 20:
        return (U * t, 0.0, 6.0)
    if t <= 30:
        return (U * 20, 0.0, 6.0)
    return (U * 20 - U * (t - 30), 0.0, 6.0)


def _write(path):
    msgs = mission(50, _vel, lambda t: (0.0, 0.0, math.remainder(_yaw(t), 2 * math.pi)),
                   lambda t: (0.0, 0.0, W if 20 <= t < 30 else 0.0), lambda t: 6.0, dvl_attitude=True)
    for k in range(501):
        t = k / 10
        q = matrix_to_quaternion(euler_to_matrix(0.0, 0.0, _yaw(t)))
        msgs.append(("truth/pose", Odometry(header=Header(seq=k, stamp=T0 + k * NS // 10, frame_id="world_ned"),
                                            position=list(_pos(t)), orientation=q)))
    msgs.sort(key=lambda km: km[1].header.stamp)
    with RecordingWriter(path) as w:
        for key, m in msgs:
            w.write(key, m)


def test_deadreckon_json_with_cones_and_truth(tmp_path, capsys):
    rec = tmp_path / "run.mcap"
    _write(rec)
    cones = tmp_path / "cones.csv"
    # the same cone seen at 2.5 m north on the way out (heading 0) and back (heading 180 deg)
    cones.write_text("pass,stamp,cone,offset_x,offset_y\n"
                     f"0,{(T0 + 5 * NS) // NS}.000000000,7,1.0,1.0\n"
                     f"1,{(T0 + 45 * NS) // NS}.000000000,7,-1.0,-1.0\n"
                     f"2,{(T0 + 99 * NS) // NS}.000000000,8,0.0,0.0\n")
    # the speed steps (stop, turn, go) are not constant-velocity motion: a large process noise
    # makes the velocity follow the DVL at once, so the estimate is exact here
    assert main([str(rec), "--json", "--cones", str(cones), "--set", "robot_state.process_accel_sigma=1e4"]) == 0
    s = json.loads(capsys.readouterr().out)
    n_out = int(50 * RobotStateConfig().publish_rate_hz) + 1   # the 50 s on the default grid, both ends
    assert s["frame"] == "enu" and s["odometry_count"] == n_out
    assert s["duration_s"] == 50.0
    assert abs(s["distance_travelled_m"] - 20.0) < 1e-6
    assert np.allclose(s["start_position_m"], [0.0, 0.0, 6.0], atol=1e-9)
    assert np.allclose(s["end_position_m"], [0.0, 0.0, 6.0], atol=1e-9)
    assert s["counters"]["initialised"] == 1
    assert s["status_flags"]["attitude_imu"] == n_out
    c = s["cones"]
    assert c["passes_used"] == 2 and c["passes_outside"] == 1
    for est in ("filter", "plain"):
        assert c[est]["no_offset"]["per_cone_m"]["7"] < 1e-9
        assert c[est]["offset"]["per_cone_m"]["7"] < 1e-9
    t = s["truth"]
    assert t["filter"]["final_drift_pct"] < 1e-6 and t["filter"]["ate_rmse_m"] < 1e-9
    assert abs(t["filter"]["truth_distance_m"] - 20.0) < 1e-9
    assert s["plain"]["dvl_used"] == 251


def test_deadreckon_text_and_overrides(tmp_path, capsys):
    rec = tmp_path / "run.mcap"
    _write(rec)
    assert main([str(rec), "--set", "robot_state.axis_remap=xyz", "--set", "robot_state.axis_sign_z=1",
                 "--set", "robot_state.process_accel_sigma=1e4"]) == 0
    out = capsys.readouterr().out
    assert "frame ned" in out and "truth filter" in out and "distance travelled 20.00 m" in out


def test_deadreckon_bad_inputs_exit_2(tmp_path, capsys):
    assert main([str(tmp_path / "missing.mcap")]) == 2
    assert "missing.mcap" in capsys.readouterr().err
    rec = tmp_path / "run.mcap"
    _write(rec)
    assert main([str(rec), "--cones", str(tmp_path / "nope.csv")]) == 2
    assert "nope.csv" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    assert main([str(rec), "--cones", str(bad)]) == 2
    assert "bad.csv" in capsys.readouterr().err
    assert main([str(rec), "--set", "robot_state.dvl.max_speed=-1"]) == 2
    assert "robot_state.dvl.max_speed" in capsys.readouterr().err
