"""The Freiburg relation error (eval/relations.py) and ``poseidon eval --relations``."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from common.geometry import wrap_angles as wrap
from common.mcap_io import RecordingWriter
from common.messages import ExperienceMap, ExperienceNode, Header, Odometry
from eval.cli.run_eval import main as eval_main
from eval.relations import Relations, interpolate_planar, read_relations, relation_errors, relation_summary
from eval.results import RunEvaluation
from eval.run_eval import evaluate_run
from tests.eval.shapes import assert_shape

NS = 1_000_000_000
DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "radish"
needs_radish = pytest.mark.skipif(not (DATA / "aces.clf.bz2").is_file(),
                                  reason=f"the Freiburg CARMEN logs are not present at {DATA}")


def _rel(rows: list[tuple[float, float, float, float, float]]) -> Relations:
    a = np.array(rows, dtype=float).reshape(-1, 5)
    return Relations(np.round(a[:, 0] * NS).astype(np.int64), np.round(a[:, 1] * NS).astype(np.int64),
                     a[:, 2], a[:, 3], a[:, 4])


def _square(turn: float, side: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """1 m per second along a side of ``side`` m, then a turn of ``turn`` rad in place (1 s);
    four times.  Returns stamps (ns), x, y, yaw and the stamps (s) at which each turn starts."""
    t, x, y, a = [0], [0.0], [0.0], [0.0]
    corners = []
    for _ in range(4):
        for _ in range(side):
            t.append(t[-1] + 1)
            x.append(x[-1] + math.cos(a[-1]))
            y.append(y[-1] + math.sin(a[-1]))
            a.append(a[-1])
        corners.append(t[-1])
        t.append(t[-1] + 1)
        x.append(x[-1])
        y.append(y[-1])
        a.append(float(wrap(a[-1] + turn)))
    return np.array(t, dtype=np.int64) * NS, np.array(x), np.array(y), np.array(a), corners


def test_square_with_a_known_yaw_error_per_turn():
    delta = math.radians(5.0)
    L = 4.0
    ref = _square(math.pi / 2)
    est = _square(math.pi / 2 + delta)
    corners = ref[4]
    # reference relations measured on the true square: along a side (no turn), and across each corner
    # (from the pose at the corner to L m along the next side)
    rows = []
    for c in corners[:3]:
        rows.append((c - 6, c - 1, 5.0, 0.0, 0.0))      # straight: the estimate agrees exactly
        rows.append((c, c + 1 + L, 0.0, L, math.pi / 2))  # across the turn
    s = relation_summary(est[0], est[1], est[2], est[3], _rel(rows))
    ex, ey, ea, inside = relation_errors(est[0], est[1], est[2], est[3], _rel(rows))
    assert inside.all()
    # across a turn of 90 + delta: ex = -L sin(delta), ey = L cos(delta) - L, eyaw = delta
    assert ex[1::2] == pytest.approx([-L * math.sin(delta)] * 3)
    assert ey[1::2] == pytest.approx([L * (math.cos(delta) - 1)] * 3)
    assert ea[1::2] == pytest.approx([delta] * 3)
    assert np.abs(np.r_[ex[0::2], ey[0::2], ea[0::2]]).max() < 1e-12
    chord = 2 * L * math.sin(delta / 2)
    assert s["count"] == 6 and s["outside"] == 0
    assert s["trans_abs_m"]["mean"] == pytest.approx(chord / 2, abs=1e-6)
    assert s["trans_abs_m"]["std"] == pytest.approx(chord / 2, abs=1e-6)  # population std of {0, c, 0, c, 0, c}
    assert s["rot_abs_deg"]["mean"] == pytest.approx(2.5, abs=1e-6)
    assert s["trans_sq_m2"]["mean"] == pytest.approx(chord ** 2 / 2, abs=1e-6)
    # the true square scores zero on its own relations
    z = relation_summary(ref[0], ref[1], ref[2], ref[3], _rel(rows))
    assert z["trans_abs_m"] == {"mean": 0.0, "std": 0.0} and z["rot_abs_deg"] == {"mean": 0.0, "std": 0.0}


def test_yaw_wraps_across_pi():
    t = np.array([0, 1, 2], dtype=np.int64) * NS
    x = np.zeros(3)
    y = np.zeros(3)
    yaw = np.array([3.1, -3.1, -3.0])  # turning counter-clockwise through +-pi
    step = 2 * math.pi - 6.2
    # interpolation half-way between 3.1 and -3.1 is at pi, not 0
    _, _, a = interpolate_planar(t, x, y, yaw, np.array([NS // 2]))
    assert abs(wrap(a[0] - math.pi)) < 1e-12
    for ref_dyaw in (step, step - 2 * math.pi, step + 2 * math.pi):  # the reference may be given unwrapped
        _, _, ea, _ = relation_errors(t, x, y, yaw, _rel([(0, 1, 0.0, 0.0, ref_dyaw)]))
        assert abs(ea[0]) < 1e-12
    _, _, ea, _ = relation_errors(t, x, y, yaw, _rel([(0, 2, 0.0, 0.0, -0.2)]))
    assert ea[0] == pytest.approx(step + 0.1 + 0.2)
    s = relation_summary(t, x, y, yaw, _rel([(0, 1, 0.0, 0.0, step + math.radians(179.0) * 2)]))
    assert s["rot_abs_deg"]["mean"] == pytest.approx(2.0)  # 358 deg of error is 2 deg


def test_poses_are_interpolated_between_samples():
    t = np.array([0, 10], dtype=np.int64) * NS
    x = np.array([0.0, 10.0])
    y = np.array([0.0, 5.0])
    yaw = np.array([0.0, 1.0])
    xi, yi, ai = interpolate_planar(t, x, y, yaw, np.array([2 * NS, 7_500_000_000]))
    assert xi == pytest.approx([2.0, 7.5]) and yi == pytest.approx([1.0, 3.75]) and ai == pytest.approx([0.2, 0.75])
    # relation between the interpolated poses at 2 s and 7.5 s, in the frame of the first
    dx, dy = 5.5, 2.75
    c, s = math.cos(0.2), math.sin(0.2)
    ref = (c * dx + s * dy, -s * dx + c * dy, 0.55)
    ex, ey, ea, _ = relation_errors(t, x, y, yaw, _rel([(2.0, 7.5, *ref)]))
    assert max(abs(ex[0]), abs(ey[0]), abs(ea[0])) < 1e-12
    # repeated stamps: the last sample of equal stamps counts
    t2 = np.array([0, 5, 5, 10], dtype=np.int64) * NS
    x2 = np.array([0.0, 5.0, 6.0, 11.0])
    xq, _, _ = interpolate_planar(t2, x2, np.zeros(4), np.zeros(4), np.array([5 * NS, 7 * NS]))
    assert xq == pytest.approx([6.0, 8.0])


def test_relations_outside_the_span_are_counted_and_excluded():
    t = np.array([10, 20], dtype=np.int64) * NS
    x = np.array([0.0, 10.0])
    z = np.zeros(2)
    rel = _rel([(10, 20, 10.0, 0.0, 0.0), (9.5, 15, 5.5, 0.0, 0.0), (15, 20.5, 5.0, 0.0, 0.0), (12, 18, 5.0, 0, 0)])
    s = relation_summary(t, x, z, z, rel)
    assert (s["count"], s["outside"]) == (2, 2)
    assert s["trans_abs_m"] == {"mean": 0.5, "std": 0.5}  # errors 0 and 1 m
    none = relation_summary(t, x, z, z, _rel([(0, 1, 1.0, 0.0, 0.0)]))
    assert none["count"] == 0 and none["trans_abs_m"] == {"mean": None, "std": None}


def test_relations_file_parsing_and_errors(tmp_path):
    f = tmp_path / "r.relations"
    f.write_text("# comment\n90.239599 90.719599 0.422330 -0.000750 0.000000 0.000000 0.000000 0.017260\n\n"
                 "1216.630413 1217.490267 0.407950 -0.016330 0 0 0 -0.069620\n")
    r = read_relations(f)
    assert list(r.t_i) == [90_239_599_000, 1_216_630_413_000] and list(r.t_j) == [90_719_599_000, 1_217_490_267_000]
    assert r.dx == pytest.approx([0.42233, 0.40795]) and r.dyaw == pytest.approx([0.01726, -0.06962])
    f.write_text("1 2 0.1 0.2 0 0 0 0.3\n1 2 0.1 0.2 0 0 0\n")
    with pytest.raises(ValueError, match=r"r.relations:2: 7 fields, expected 8"):
        read_relations(f)
    f.write_text("1 2 0.1 zz 0 0 0 0.3\n")
    with pytest.raises(ValueError, match=r"r.relations:1: field dy: 'zz' is not a number"):
        read_relations(f)
    f.write_text("1 x 0.1 0.2 0 0 0 0.3\n")
    with pytest.raises(ValueError, match=r"r.relations:1: field t_j"):
        read_relations(f)
    with pytest.raises(ValueError, match="cannot read"):
        read_relations(tmp_path / "missing.relations")


# --------------------------------------------------------------------------- poseidon eval --relations


def _odo(key_stamp: int, seq: int, x: float, y: float, yaw: float) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=key_stamp, frame_id="odom"), position=[x, y, 0.0],
                    orientation=[0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def _write_run(path: Path, with_map: bool, with_dead_reckoning: bool = True) -> None:
    """wheel_odometry: straight along x at 1 m/s with a yaw drift of 0.01 rad/s (t = 100..110 s);
    Odometry: exact straight line along x; map (if any): one node at t = 100 s, identity."""
    with RecordingWriter(path) as w:
        for k in range(11):
            st = (100 + k) * NS
            w.write("wheel_odometry", _odo(st, k, float(k), 0.0, 0.01 * k))
            if with_dead_reckoning:
                w.write("Odometry", _odo(st, k, float(k), 0.0, 0.0))
        if with_map:
            node = ExperienceNode(id=0, lvc_id=0, position=[0.0, 0.0, 0.0], yaw=0.0, stamp=100 * NS)
            w.write("map", ExperienceMap(header=Header(seq=0, stamp=110 * NS), nodes=[node], links=[]))


def test_eval_scores_the_map_and_the_raw_odometry(tmp_path, capsys):
    run = tmp_path / "run.mcap"
    _write_run(run, with_map=True)
    rel = tmp_path / "r.relations"
    rel.write_text("100.0 110.0 10.0 0.0 0 0 0 0.0\n100.0 120.0 20.0 0.0 0 0 0 0.0\n")
    r = evaluate_run(run, relations=rel)
    assert_shape(r, RunEvaluation)
    assert r["relations_in_file"] == 2
    m, o = r["relations"], r["relations_odometry"]
    assert m["source"] == "map_corrected" and o["source"] == "wheel_odometry"
    assert (m["count"], m["outside"]) == (1, 1)
    assert m["trans_abs_m"]["mean"] == pytest.approx(0.0, abs=1e-9)
    assert o["rot_abs_deg"]["mean"] == pytest.approx(math.degrees(0.1), abs=1e-6)
    assert eval_main([str(run), "--relations", str(rel)]) == 0
    text = capsys.readouterr().out
    assert "relations          2 in" in text and "wheel_odometry)" in text
    assert eval_main([str(run), "--relations", str(tmp_path / "missing")]) == 2
    assert "cannot read the relations file" in capsys.readouterr().err


def test_eval_on_an_imported_log_without_map_truth_or_camera(tmp_path, capsys):
    run = tmp_path / "imported.mcap"
    _write_run(run, with_map=False, with_dead_reckoning=False)
    rel = tmp_path / "r.relations"
    rel.write_text("100.0 110.0 10.0 0.0 0 0 0 0.0\n")
    assert eval_main([str(run), "--relations", str(rel), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["relations"] is None and r["relations_odometry"]["source"] == "wheel_odometry"
    assert r["ground_truth"] is False and r["nodes"] == 0
    # without a map, the dead reckoning is the raw odometry when there is no wheel_odometry
    run2 = tmp_path / "dr.mcap"
    with RecordingWriter(run2) as w:
        for k in range(11):
            w.write("Odometry", _odo((100 + k) * NS, k, float(k), 0.0, 0.0))
    r2 = evaluate_run(run2, relations=rel)
    assert r2["relations"] is None and r2["relations_odometry"]["source"] == "Odometry"


@needs_radish
@pytest.mark.parametrize("name,trans,rot", [("aces", (0.549, 2.681), (2.2, 6.2)),
                                            ("fr079", (6.504, 13.664), (30.2, 45.5))])
def test_raw_odometry_of_the_real_logs_scores_the_published_figures(tmp_path, name, trans, rot):
    from missions.importers.carmen import import_carmen

    out = tmp_path / f"{name}.mcap"
    import_carmen(DATA / f"{name}.clf.bz2", out)
    r = evaluate_run(out, relations=DATA / f"{name}.relations")
    o = r["relations_odometry"]
    assert o["outside"] == 0
    assert (round(o["trans_abs_m"]["mean"], 3), round(o["trans_abs_m"]["std"], 3)) == trans
    assert (round(o["rot_abs_deg"]["mean"], 1), round(o["rot_abs_deg"]["std"], 1)) == rot
