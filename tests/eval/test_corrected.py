"""The map-corrected trajectory (eval/corrected.py) and ``poseidon export --tum``."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common.geometry import quaternion_to_matrix, slerp
from common.mcap_io import RecordingWriter
from common.messages import ExperienceMap, ExperienceNode, Header, Odometry, ScanPose
from common.stamps import ns_to_text
from eval.corrected import map_corrected, read_tum, write_tum
from eval.trajectory import PoseSeries, pose_series
from products.cli import main as export_main

NS = 1_000_000_000
T0 = 1_700_000_000_123_456_789  # an odd epoch: the TUM time column must keep every nanosecond


def _q_yaw(yaw: float) -> list[float]:
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def _q_roll_yaw(roll: float, yaw: float) -> list[float]:
    """q = Rz(yaw) * Rx(roll)."""
    cr, sr, cy, sy = math.cos(roll / 2), math.sin(roll / 2), math.cos(yaw / 2), math.sin(yaw / 2)
    return [cy * sr, sy * sr, sy * cr, cy * cr]


def _odometry(roll: float = 0.0) -> list[Odometry]:
    """Straight along x at 1 m/s, yaw 0, z = -2, t = T0 + 0..10 s."""
    return [Odometry(header=Header(seq=k, stamp=T0 + k * NS, frame_id="odom"), position=[float(k), 0.0, -2.0],
                     orientation=_q_roll_yaw(roll, 0.0)) for k in range(11)]


def _node(i: int, stamp: int, pos: list[float], yaw: float) -> ExperienceNode:
    return ExperienceNode(id=i, lvc_id=i, position=pos, yaw=yaw, stamp=stamp)


#: node 0 at t = 2 s moved by +1 m in y; node 1 between samples (t = 5.5 s) at (10, 5, 1) facing +y
NODES = [_node(0, T0 + 2 * NS, [2.0, 1.0, -2.0], 0.0), _node(1, T0 + 5_500_000_000, [10.0, 5.0, 1.0], math.pi / 2)]


def _expected(k: int) -> tuple[list[float], float]:
    """Hand-computed corrected position and yaw at t = k s: before node 0 (t = 2 s) its
    correction, a translation by (0, 1, 0); after node 1 (t = 5.5 s) its correction, odom at
    5.5 s = (5.5, 0, -2) rotated by Rz(pi/2) onto (10, 5, 1); between them the two blended by
    f = (k - 2) / 3.5."""
    c0 = np.array([float(k), 1.0, -2.0])
    d = k - 5.5
    c1 = np.array([10.0, 5.0 + d, 1.0])
    f = min(max((k - 2.0) / 3.5, 0.0), 1.0)
    if k >= 5.5:
        return list(c1), math.pi / 2
    return list((1 - f) * c0 + f * c1), f * math.pi / 2


def test_map_correction_by_hand():
    got = map_corrected(pose_series(_odometry()), NODES)
    assert list(got.stamps) == [T0 + k * NS for k in range(11)]
    for k in range(11):
        pos, yaw = _expected(k)
        assert got.positions[k] == pytest.approx(pos, abs=1e-12), k
        assert got.yaws[k] == pytest.approx(yaw, abs=1e-12), k


def test_correction_keeps_roll_and_pitch_of_3d_odometry():
    roll = 0.3
    got = map_corrected(pose_series(_odometry(roll)), NODES)
    for k in (1, 8):
        _, yaw = _expected(k)
        r = quaternion_to_matrix(got.quaternions[k])
        expected = quaternion_to_matrix(_q_roll_yaw(roll, yaw))  # Rz(dpsi) * Rx(roll)
        assert r == pytest.approx(expected, abs=1e-12)
    assert got.positions[8] == pytest.approx([10.0, 7.5, 1.0], abs=1e-12)


def test_nodes_order_and_no_map():
    odo = pose_series(_odometry())
    assert map_corrected(odo, None) is odo and map_corrected(odo, []) is odo
    same = map_corrected(odo, list(reversed(NODES)))  # nodes are taken by stamp, not list order
    assert same.positions == pytest.approx(map_corrected(odo, NODES).positions)


def test_slerp_takes_the_short_way_and_interpolation_clamps():
    q0 = np.array([_q_yaw(3.0)])
    q1 = np.array([_q_yaw(-3.0)])
    mid = slerp(q0, q1, np.array([0.5]))
    assert abs(abs(math.atan2(2 * mid[0, 2] * mid[0, 3], 1 - 2 * mid[0, 2] ** 2)) - math.pi) < 1e-9
    s = PoseSeries(np.array([0, 10], dtype=np.int64), np.array([[0.0, 0, 0], [10.0, 0, 0]]),
                   np.array([_q_yaw(0.0), _q_yaw(1.0)]))
    at = s.interpolate(np.array([-5, 5, 15], dtype=np.int64))
    assert at.positions[:, 0] == pytest.approx([0.0, 5.0, 10.0])
    assert at.yaws == pytest.approx([0.0, 0.5, 1.0])


def _write_run(path: Path, with_map: bool) -> None:
    with RecordingWriter(path) as w:
        for m in _odometry():
            w.write("Odometry", m)
        if with_map:  # two map messages: only the last counts
            w.write("map", ExperienceMap(header=Header(seq=0, stamp=T0 + 3 * NS),
                                         nodes=[_node(0, T0, [50.0, 50.0, 0.0], 1.0)], links=[]))
            w.write("map", ExperienceMap(header=Header(seq=1, stamp=T0 + 10 * NS), nodes=NODES, links=[]))


def test_tum_export_read_back(tmp_path, capsys):
    run = tmp_path / "run.mcap"
    _write_run(run, with_map=True)
    out = tmp_path / "traj.txt"
    assert export_main([str(run), "--tum", str(out)]) == 0
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("#")]
    assert len(lines) == 11
    assert lines[3].split()[0] == ns_to_text(T0 + 3 * NS) == "1700000003.123456789"
    back = read_tum(out)
    assert list(back.stamps) == [T0 + k * NS for k in range(11)]
    for k in range(11):
        pos, yaw = _expected(k)
        assert back.positions[k] == pytest.approx(pos, abs=1e-8)
        assert back.quaternions[k] == pytest.approx(_q_yaw(yaw), abs=1e-8)
    assert export_main([str(run), "--tum", str(out)]) == 2  # exists
    assert "exists" in capsys.readouterr().err
    assert export_main([str(run), "--tum", str(out), "--overwrite"]) == 0


def test_tum_export_without_map_is_the_dead_reckoning(tmp_path, capsys):
    run = tmp_path / "run.mcap"
    _write_run(run, with_map=False)
    out = tmp_path / "traj.txt"
    assert export_main([str(run), "--tum", str(out)]) == 0
    assert "no map message" in capsys.readouterr().err
    back = read_tum(out)
    assert back.positions[:, 0] == pytest.approx(np.arange(11.0)) and np.all(back.positions[:, 1] == 0)
    empty = tmp_path / "empty.mcap"
    with RecordingWriter(empty) as w:
        w.write("map", ExperienceMap(header=Header(seq=0, stamp=T0), nodes=NODES, links=[]))
    assert export_main([str(empty), "--tum", str(tmp_path / "e.txt")]) == 2
    assert "no 'Odometry' messages" in capsys.readouterr().err


def test_tum_reader_names_bad_lines(tmp_path):
    f = tmp_path / "t.txt"
    write_tum(f, pose_series(_odometry()))
    f.write_text(f.read_text() + "1.0 2 3\n")
    with pytest.raises(ValueError, match=r"t.txt:13: 3 fields, expected 8"):
        read_tum(f)


def _scan_pose(stamp: int, experience: int, yaw: float) -> ScanPose:
    return ScanPose(header=Header(seq=0, stamp=stamp), experience_id=experience, pose=[0.3, 0.0, yaw], score=0.8)


def test_scan_poses_give_the_heading_between_experiences_and_keep_the_position():
    """Step 5: a scan pose at t = 4 s says the robot faced node 0's yaw + 0.2 rad; there the
    heading is that, the position the experiences' blend; poses at a node's stamp or of an
    experience not in the map are not used."""
    odo = pose_series(_odometry())
    plain = map_corrected(odo, NODES)
    poses = [_scan_pose(T0 + 4 * NS, 0, 0.2), _scan_pose(T0 + 2 * NS, 0, 1.0), _scan_pose(T0 + 3 * NS, 7, 1.0)]
    got = map_corrected(odo, NODES, poses)
    assert got.yaws[4] == pytest.approx(0.2, abs=1e-12) and got.positions[4] == pytest.approx(plain.positions[4], abs=1e-12)
    # between node 0 (t = 2 s) and the scan pose (t = 4 s) the heading blends from 0 to 0.2
    assert got.yaws[3] == pytest.approx(0.1, abs=1e-12) and got.yaws[2] == pytest.approx(0.0, abs=1e-12)
    # between the scan pose and node 1 (t = 5.5 s): from 0.2 to pi/2 over 1.5 s
    assert got.yaws[5] == pytest.approx(0.2 + (math.pi / 2 - 0.2) / 1.5, abs=1e-12)
    assert got.positions[6:] == pytest.approx(plain.positions[6:], abs=1e-12)
    assert map_corrected(odo, NODES, [_scan_pose(T0 + 3 * NS, 7, 1.0)]).positions == pytest.approx(plain.positions)


def test_tum_export_takes_the_recorded_scan_poses(tmp_path):
    with RecordingWriter(tmp_path / "with_poses.mcap") as w:
        for m in _odometry():
            w.write("Odometry", m)
        w.write("scan_pose", _scan_pose(T0 + 4 * NS, 0, 0.2))
        w.write("map", ExperienceMap(header=Header(seq=1, stamp=T0 + 10 * NS), nodes=NODES, links=[]))
    out = tmp_path / "traj.txt"
    assert export_main([str(tmp_path / "with_poses.mcap"), "--tum", str(out)]) == 0
    assert read_tum(out).yaws[4] == pytest.approx(0.2, abs=1e-8)
