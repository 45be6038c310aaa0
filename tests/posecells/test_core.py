"""OdometryIntegrator and PoseCellsCore driven directly (no node, no messages, no transport)."""
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from services.posecells.core import OdometryIntegrator, PoseCellsCore, wrap_angle
from system.config import PoseidonConfig


def test_wrap_angle() -> None:
    assert wrap_angle(math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-0.25) == pytest.approx(-0.25)


def test_straight_motion_along_a_heading_is_forward() -> None:
    odo = OdometryIntegrator(max_step=1.0)
    yaw = math.radians(30)
    assert odo.update([1.0, 2.0, -3.0], yaw) == "first"
    for k in range(1, 11):   # 10 increments of 5 cm along the heading, 1 cm down each
        assert odo.update([1.0 + 0.05 * k * math.cos(yaw), 2.0 + 0.05 * k * math.sin(yaw), -3.0 - 0.01 * k],
                          yaw) == "step"
    forward, left, up, dyaw = odo.take_step()
    assert (forward, left, up, dyaw) == pytest.approx((0.5, 0.0, -0.1, 0.0), abs=1e-12)
    assert odo.take_step() == (0.0, 0.0, 0.0, 0.0)


def test_increments_are_in_the_frame_of_the_yaw_at_the_last_step() -> None:
    odo = OdometryIntegrator(max_step=1.0)
    odo.update([0.0, 0.0, 0.0], 0.0)
    odo.update([0.0, 0.2, 0.0], math.pi / 2)        # the vehicle turns while moving north (ENU y)
    assert odo.take_step() == pytest.approx((0.0, 0.2, 0.0, math.pi / 2))   # left of the old heading
    odo.update([0.0, 0.5, 0.0], math.pi / 2)        # now heading north: north is forward
    assert odo.take_step() == pytest.approx((0.3, 0.0, 0.0, 0.0))


def test_yaw_increment_wraps_across_pi() -> None:
    odo = OdometryIntegrator(max_step=1.0)
    odo.update([0.0, 0.0, 0.0], math.pi - 0.05)
    odo.update([0.0, 0.0, 0.0], -math.pi + 0.05)
    assert odo.take_step()[3] == pytest.approx(0.1)


def test_discontinuity_and_non_finite_poses_add_no_motion() -> None:
    odo = OdometryIntegrator(max_step=1.0)
    odo.update([0.0, 0.0, 0.0], 0.0)
    odo.update([0.02, 0.0, 0.0], 0.0)
    assert odo.update([100.0, 50.0, 0.0], 0.0) == "discontinuity"
    assert odo.last_jump == pytest.approx(math.hypot(99.98, 50.0))
    assert odo.update([float("nan"), 0.0, 0.0], 0.0) == "non_finite"
    assert odo.update([100.03, 50.0, 0.0], 0.0) == "step"
    assert odo.take_step()[0] == pytest.approx(0.05)


def core() -> PoseCellsCore:
    cfg = PoseidonConfig()
    cfg.vpr_guard.require_vpr_for_event = False
    return PoseCellsCore(cfg.posecells, cfg.vpr_guard)


def cells(*id_rate: tuple[int, float]) -> list[SimpleNamespace]:
    return [SimpleNamespace(id=i, rate=r) for i, r in id_rate]


def test_first_odometry_places_the_packet_and_lvc_before_odometry_makes_no_step() -> None:
    c = core()
    assert c.on_lvc(3, cells((3, 0.6))).decision is None
    c.on_odometry([0.42, 0.31, 0.2], 0.5)
    x, y, z, yaw = c.net.centroid()
    assert (x, y, z, yaw) == pytest.approx((0.42, 0.31, 0.2, 0.5), abs=0.02)


def test_a_step_moves_the_packet_by_the_odometry_and_the_gate_decides() -> None:
    c = core()
    c.on_odometry([0.2, 0.2, 0.2], 0.0)
    c.on_odometry([0.5, 0.2, 0.2], 0.0)
    step = c.on_lvc(1, cells((1, 0.6)))
    assert step.decision is not None and step.decision.accepted and step.decision.gate == "off"
    assert step.position == [0.5, 0.2, 0.2] and step.yaw == 0.0
    assert step.centroid is not None and step.centroid[0] == pytest.approx(0.5, abs=0.02)


def test_save_load_round_trip_continues_identically(tmp_path: Path) -> None:
    a = core()
    rng = np.random.default_rng(1)
    p, yaw = np.zeros(3), 0.0
    for k in range(40):
        p = p + rng.normal(0, 0.03, 3)
        yaw = wrap_angle(yaw + rng.normal(0, 0.05))
        a.on_odometry(p.tolist(), yaw)
        if k % 3 == 0:
            a.on_lvc(k % 5, cells((k % 5, 0.6)))
    a.on_odometry((p + 0.01).tolist(), yaw)          # a pending motion is saved too
    path = tmp_path / "s" / "pc.npz"
    a.save(path)
    b = core()
    b.load(path)
    assert b.node_state() == a.node_state()
    assert np.array_equal(b.net.P, a.net.P)
    sa, sb = a.on_lvc(2, cells((2, 0.6))), b.on_lvc(2, cells((2, 0.6)))
    assert sa == sb and np.array_equal(b.net.P, a.net.P)


def test_load_rejects_a_file_that_is_not_a_posecells_state(tmp_path: Path) -> None:
    path = tmp_path / "x.npz"
    np.savez(path, a=np.zeros(2))
    with pytest.raises(ValueError, match="not a posecells state file"):
        core().load(path)
