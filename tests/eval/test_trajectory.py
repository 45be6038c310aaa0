"""eval.trajectory: interpolation, rigid alignment, ATE / RPE / drift on known answers."""
import math

import numpy as np
import pytest

from eval.trajectory import NS, Trajectory, align_rigid, align_trajectory, anchored_errors, ate, drift_pct, rpe


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_trajectory_interpolation_coverage_and_distance():
    # unsorted input is sorted; yaw crossing the seam interpolates the short way
    t = Trajectory([2 * NS, 0, NS], [[2, 0, 0], [0, 0, 0], [1, 0, 0]], [-3.1, 3.1, math.pi])
    assert t.t.tolist() == [0, NS, 2 * NS]
    p, yaw = t.at(NS // 2)
    assert p.tolist() == [0.5, 0.0, 0.0]
    assert math.remainder(yaw - (3.1 + (math.pi - 3.1) / 2), 2 * math.pi) == pytest.approx(0.0)
    assert t.covers(0) and t.covers(2 * NS) and not t.covers(2 * NS + 1)
    assert t.covered([-1, 0, 3 * NS]).tolist() == [False, True, False]
    assert t.distance(None) == pytest.approx(2.0)
    assert t.distance(0.5) == pytest.approx(2.0)
    assert t.travelled_at([NS, 2 * NS]).tolist() == [1.0, 2.0]
    # zig-zag noise at 10 Hz inflates the raw length, not the 1 s resampled one
    s = np.arange(0, 101) * NS // 10
    zig = Trajectory(s, [[k / 10, 0.05 * (-1) ** k, 0] for k in range(101)])
    assert zig.distance(None) > 10.4 and zig.distance(1.0) == pytest.approx(10.0, abs=1e-9)
    w = zig.window(NS, 2 * NS)
    assert len(w) == 11 and w.t[0] == NS
    with pytest.raises(ValueError, match="stamps but"):
        Trajectory([0, 1], [[0, 0, 0]])


def test_align_rigid_recovers_a_known_motion():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(20, 3)) * 10
    r_true = _rot_z(0.7) @ np.array([[1, 0, 0], [0, math.cos(0.2), -math.sin(0.2)], [0, math.sin(0.2), math.cos(0.2)]])
    t_true = np.array([5.0, -3.0, 2.0])
    r, t = align_rigid(a, a @ r_true.T + t_true)
    assert np.allclose(r, r_true) and np.allclose(t, t_true)
    # a mirrored target is not matched by a reflection: R stays a proper rotation
    r, _ = align_rigid(a, a * np.array([1, 1, -1]))
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_ate_zero_for_rigid_motion_and_known_for_balanced_offsets():
    stamps = np.arange(4) * NS
    corners = np.array([[1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0]], float)
    truth = Trajectory(stamps, corners)
    moved = Trajectory(stamps, corners @ _rot_z(1.0).T + [10, 20, 30])
    assert ate(moved, truth)["rmse_m"] == pytest.approx(0.0, abs=1e-12)
    assert ate(moved, truth, align=False)["rmse_m"] > 30
    # +e, -e, +e, -e along z: uncorrelated with the corners, so the best alignment is the identity
    e = 0.25
    bumped = Trajectory(stamps, corners + np.array([[0, 0, e], [0, 0, -e], [0, 0, e], [0, 0, -e]]))
    r = ate(bumped, truth)
    assert r["rmse_m"] == pytest.approx(e) and r["max_m"] == pytest.approx(e) and r["n"] == 4
    # time alignment: the estimate is interpolated at the reference stamps it covers
    half = Trajectory(stamps[:2] + NS // 2, corners[:2])
    assert ate(half, truth, align=False)["n"] == 1  # only the reference stamp 1 s lies in [0.5, 1.5] s
    with pytest.raises(ValueError, match="no time overlap"):
        ate(Trajectory([10 * NS, 11 * NS], corners[:2]), truth)


def test_rpe_constant_velocity_error():
    s = np.arange(0, 31) * NS
    truth = Trajectory(s, [[k, 0, 0] for k in range(31)])
    est = Trajectory(s, [[1.1 * k, 0, 0] for k in range(31)])  # 10% long: 1 m per 10 s
    r = rpe(est, truth, delta_s=10.0, align=False)
    assert r["rmse_m"] == pytest.approx(1.0) and r["n"] == 21
    assert rpe(est, truth, delta_s=100.0)["n"] == 0


def test_anchored_errors_and_drift():
    s = np.arange(0, 11) * NS
    truth = Trajectory(s, [[k, 0, 0] for k in range(11)])
    # starts 5 m off (anchoring removes it) and ends 1 m short
    est = Trajectory(s, [[5 + 0.9 * k, 0, 0] for k in range(11)])
    r = anchored_errors(est, truth)
    assert r["final_error_m"] == pytest.approx(1.0)
    assert r["truth_distance_m"] == pytest.approx(10.0)
    assert r["final_drift_pct"] == pytest.approx(10.0)
    assert r["max_error_m"] == pytest.approx(1.0)
    assert r["ate_rmse_m"] == pytest.approx(math.sqrt(np.mean((0.1 * np.arange(11)) ** 2)))
    assert drift_pct(1.0, 0.0) is None


def test_align_trajectory_moves_the_estimate_onto_the_reference():
    stamps = np.arange(5) * NS
    truth = Trajectory(stamps, [[k, k * k, 0.5 * k] for k in range(5)], [0.0] * 5)
    r = _rot_z(0.5)
    est = Trajectory(stamps, truth.p @ r.T + [3, 4, 5], [0.5] * 5)
    moved = align_trajectory(est, truth)
    assert np.allclose(moved.p, truth.p)
    assert np.allclose(moved.yaw, 0.0)  # the yaw turns with the rotation about z
    assert moved.t.tolist() == est.t.tolist()
