"""The laser preset end to end on a hand-made CARMEN log: import, every service (embedded),
relation error of the map against the raw odometry's, TUM export."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from eval.corrected import read_tum
from eval.run_eval import evaluate_run
from launcher.run import run_embedded
from missions.importers.cli import main as import_main
from products.cli import main as export_main
from services.expmap.pose_graph import relative_pose
from system.config import load_config
from tests.expmap.laser_world import drifting_odometry, raycast, ring_route, ring_world

ROOT = Path(__file__).resolve().parents[2]
PRESET = ROOT / "deploy" / "presets" / "laser2d.yaml"


def write_carmen(path: Path, truth: np.ndarray, odo: np.ndarray, dt: float = 0.5) -> list[float]:
    """ODOM + FLASER (180 beams, -90..89 deg) lines at 2 Hz; returns the laser stamps (s)."""
    rng = np.random.default_rng(4)
    lines = ["# hand-made CARMEN log: a corridor ring driven one and a half times",
             "PARAM robot_front_laser_max 30.0 nohost 0"]
    stamps = []
    for k, (t, o) in enumerate(zip(truth, odo)):
        ts = 100.0 + k * dt
        lines.append(f"ODOM {o[0]:.6f} {o[1]:.6f} {o[2]:.6f} 0.5 0.0 0.0 {ts:.6f} nohost {ts:.6f}")
        pose = (t[0], t[1], t[2])
        r = raycast(ring_world(), pose, n_beams=181, max_range=30.0, noise=0.01, rng=rng)[:180]
        ranges = " ".join(f"{v:.3f}" for v in r)
        ls = ts + 0.01
        lines.append(f"FLASER 180 {ranges} {o[0]:.6f} {o[1]:.6f} {o[2]:.6f} {o[0]:.6f} {o[1]:.6f} {o[2]:.6f} "
                     f"{ls:.6f} nohost {ls:.6f}")
        stamps.append(ls)
    path.write_text("\n".join(lines) + "\n")
    return stamps


def write_relations(path: Path, truth: np.ndarray, stamps: list[float]) -> None:
    rows = []
    for i in range(0, len(truth) - 60, 7):
        for j in (i + 3, i + 60):            # short ones and ones across the loop
            d = relative_pose(truth[i], truth[j])
            rows.append(f"{stamps[i]:.6f} {stamps[j]:.6f} {d[0]:.6f} {d[1]:.6f} 0 0 0 {d[2]:.6f}")
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.slow
def test_laser_preset_maps_a_hand_made_log(tmp_path):
    truth = ring_route(laps=2, step=0.5)[:170]
    # the scan of step k is taken at the pose of step k: 180 beams from -90 deg at 1 deg
    odo = drifting_odometry(truth, yaw_drift_deg_per_m=0.4, scale=1.01)
    log, rel = tmp_path / "ring.clf", tmp_path / "ring.relations"
    stamps = write_carmen(log, truth, odo)
    write_relations(rel, truth, stamps)
    imported = tmp_path / "ring.mcap"
    assert import_main([str(log), "--out", str(imported)]) == 0
    cfg = load_config(PRESET, overrides=[f"encoder.lsbh.matrix_path={tmp_path}/lsbh_{{backbone}}_{{modality}}.npy"])
    res = run_embedded(cfg, imported, tmp_path / "run.mcap", progress=False, timeout_s=400)
    counters = res.services["expmap"]["counters"]
    assert counters["loop_closures"] >= 1 and counters["chain_scan"] >= 0.9 * counters["events"] > 60
    ev = evaluate_run(tmp_path / "run.mcap", relations=rel)
    mp, od = ev["relations"], ev["relations_odometry"]
    assert mp["count"] == od["count"] > 30
    assert od["trans_abs_m"]["mean"] > 1.0
    assert mp["trans_abs_m"]["mean"] < od["trans_abs_m"]["mean"] / 5
    assert mp["rot_abs_deg"]["mean"] < 1.5
    out = tmp_path / "traj.txt"
    assert export_main([str(tmp_path / "run.mcap"), "--tum", str(out)]) == 0
    back = read_tum(out)
    assert len(back) == res.recording["counts"]["Odometry"] == len(truth)
    assert math.isclose(back.stamps[0] / 1e9, 100.0)


def _recording_with_offsets(path: Path, offsets: dict | None) -> Path:
    from common.mcap_io import RecordingWriter
    from common.messages import Header, Odometry
    with RecordingWriter(path) as w:
        w.write("wheel_odometry", Odometry(header=Header(seq=0, stamp=1), position=[0.0, 0.0, 0.0],
                                           orientation=[0.0, 0.0, 0.0, 1.0]))
        if offsets is not None:
            w.add_metadata("poseidon", {"tool": "test", "laser_offsets": offsets})
    return path


def test_sensor_offset_comes_from_the_input_unless_configured(tmp_path):
    from launcher.run import calibrate_from_input
    rec = _recording_with_offsets(tmp_path / "a.mcap", {"scan": {"dx": -0.04, "dy": 0.0, "dtheta": math.pi / 2,
                                                                "max_deviation_m": 0.0}})
    cfg = load_config(PRESET)
    assert cfg.expmap.scan_graph.sensor_offset is None
    calibrate_from_input(cfg, rec)
    assert cfg.expmap.scan_graph.sensor_offset == pytest.approx([-0.04, 0.0, 90.0])
    mine = load_config(PRESET, overrides=["expmap.scan_graph.sensor_offset=[0.1,0,0]"])
    calibrate_from_input(mine, rec)
    assert mine.expmap.scan_graph.sensor_offset == [0.1, 0.0, 0.0]
    bare = load_config(PRESET)
    calibrate_from_input(bare, _recording_with_offsets(tmp_path / "b.mcap", None))
    assert bare.expmap.scan_graph.sensor_offset == [0.0, 0.0, 0.0]
    sonar = load_config()                     # the underwater map is left alone
    calibrate_from_input(sonar, rec)
    assert sonar.expmap.scan_graph.sensor_offset is None


def test_the_wheel_time_offset_is_measured_from_the_input_only_when_left_null(tmp_path):
    from launcher.run import calibrate_from_input
    rec = _recording_with_offsets(tmp_path / "a.mcap", None)     # odometry, no scans: nothing to measure
    cfg = load_config(PRESET)
    assert cfg.robot_state.wheel_time_offset_s is None
    calibrate_from_input(cfg, rec)
    assert cfg.robot_state.wheel_time_offset_s == 0.0
    mine = load_config(PRESET, overrides=["robot_state.wheel_time_offset_s=0.1"])
    calibrate_from_input(mine, rec)
    assert mine.robot_state.wheel_time_offset_s == 0.1
    sonar = load_config()                     # the underwater robot_state keeps its default
    calibrate_from_input(sonar, rec)
    assert sonar.robot_state.wheel_time_offset_s == 0.0
