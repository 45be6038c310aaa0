"""Sessions in the experience map: a continued map begins a new session in its own
odometry frame, linked to the old one only by a verified sonar registration; the same link
recovers a kidnapped vehicle (an odometry jump within one mission)."""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from services.expmap.config import ExpMapConfig
from services.expmap.graph import EventResult, ExperienceMap
from services.expmap.session_link import SESSION_BREAK_WEIGHT
from tests.expmap.helpers import SEC, pc_of, small_cfg
from tests.expmap.test_scans import CHAMBER, _sweep

#: a hexagonal chamber: another place whose camera view (LVC) we pretend is the same
OTHER = np.c_[2 + 5 * np.cos(np.linspace(0, 2 * np.pi, 7)[:-1] + 0.3),
              4 + 4 * np.sin(np.linspace(0, 2 * np.pi, 7)[:-1] + 0.3)]
FRAME_B = np.array([31.0, -12.0, 0.0])     # where session B's odometry frame puts the chamber (ENU m)
OFF_TRUE = np.array([0.3, -0.2])           # session B flies 0.3 m N, 0.2 m W of session A's line (NED m)


def cfg(changes: Mapping[str, Any] | None = None) -> ExpMapConfig:
    """The sessions' map configuration with ``changes`` (dotted field -> value) applied."""
    base = {"min_experience_age": 20, "corrections.min_route_len": 20, "corrections.min_interval_sec": 0.0,
            "loops.edge_weight": 1000.0}
    return small_cfg({**base, **(changes or {})})


def true_ned(k: int, offset: Sequence[float] = (0.0, 0.0)) -> np.ndarray:
    a = 2 * math.pi * k / 40
    return np.array([1.0, 3.0]) + np.array([2.5 * math.sin(a), 1.5 * (1 - math.cos(a))]) + np.asarray(offset)


def enu(p_ned: np.ndarray) -> list[float]:
    return [float(p_ned[1]), float(p_ned[0]), 0.0]


def lap(em: ExperienceMap, t0: int, ks: range, odom_frame: np.ndarray, offset: Sequence[float] = (0.0, 0.0),
        walls: Sequence[np.ndarray] = (CHAMBER,), sweeps: bool = True) -> list[EventResult]:
    """Events k of a pass round the chamber; the odometry is exact in its own frame (its origin
    at ``odom_frame`` ENU), the true pass offset by ``offset`` (NED) from session A's."""
    out = []
    for k in ks:
        p = true_ned(k, offset)
        odom = list(np.asarray(enu(p)) + odom_frame)
        sw = _sweep(p, list(walls)) if sweeps else None
        out.append(em.add_event((t0 + k) * SEC, k, pc_of(odom), odom, 0.0, sweep=sw))
    return out


def session_a(c: ExpMapConfig) -> ExperienceMap:
    em = ExperienceMap(c)
    lap(em, 0, range(40), np.zeros(3))
    em.settle()
    return em


def test_a_new_session_starts_unlinked_in_its_own_frame_and_links_after_verification() -> None:
    em = session_a(cfg())
    em.begin_session()
    res = lap(em, 100, range(40), FRAME_B, OFF_TRUE)
    em.settle()
    assert res[0].session_started and em.n_sessions == 2
    assert em.edge_weights[40] == SESSION_BREAK_WEIGHT
    linked = [i for i, r in enumerate(res) if r.linked]
    assert len(linked) == 1 and len(em.session_links) == 1
    # not from a single match: the events before the link matched but were not yet confirmed
    first = linked[0]
    assert res[first].confirmations >= em.cfg.loops.confirmations and any(r.match >= 0 for r in res[:first])
    # before the link session B sat in its own frame
    assert em.session_links[0].stamp == (100 + first) * SEC
    link = em.session_links[0]
    np.testing.assert_allclose(link.shift[:2], -FRAME_B[:2], atol=0.1)
    np.testing.assert_allclose(link.delta[:2], OFF_TRUE[::-1], atol=0.08)   # the measured displacement
    # after it, every node of B is where it truly is, in session A's frame
    truth_b = np.array([enu(true_ned(k, OFF_TRUE)) for k in range(40)])
    assert np.abs(em.positions[40:, :2] - truth_b[:, :2]).max() < 0.1
    np.testing.assert_allclose(em.positions[:40, :2], [enu(true_ned(k))[:2] for k in range(40)], atol=0.1)
    assert em.session_root(1) == 0 and (em.sessions == np.r_[np.zeros(40), np.ones(40)]).all()


def test_no_link_without_sweeps() -> None:
    em = session_a(cfg())
    em.begin_session()
    res = lap(em, 100, range(40), FRAME_B, OFF_TRUE, sweeps=False)
    assert not em.session_links and any(r.rejected == "link" for r in res)
    assert em.link_rejections["no_sweep"] >= 1
    # unlinked: B stays where its own odometry puts it
    odom_b = np.array([enu(true_ned(k, OFF_TRUE)) for k in range(40)]) + FRAME_B
    np.testing.assert_allclose(em.positions[40:], odom_b, atol=1e-9)
    assert em.session_root(1) == 1


def test_a_wrong_candidate_is_rejected() -> None:
    """The camera says "same place" (same LVC ids) but session B is in another chamber: the
    sweeps do not fit, no link; session B stays in its own frame."""
    em = session_a(cfg())
    em.begin_session()
    res = lap(em, 100, range(40), FRAME_B, walls=(OTHER,))
    assert sum(r.confirmations >= 2 for r in res) >= 5          # plenty of confirmed candidates...
    assert not em.session_links and not em.loops                 # ...none verified
    assert em.link_rejections["untrusted"] + em.link_rejections["inliers"] >= 5
    odom_b = np.array([enu(true_ned(k)) for k in range(40)]) + FRAME_B
    np.testing.assert_allclose(em.positions[40:], odom_b, atol=1e-9)


def test_saved_loaded_continued_equals_uninterrupted(tmp_path: Path) -> None:
    c = cfg()
    whole = session_a(c)
    whole.begin_session()
    lap(whole, 100, range(40), FRAME_B, OFF_TRUE)
    whole.settle()
    # the same, with the map saved after session A and after half of session B
    a = session_a(c)
    a.save(tmp_path / "a.npz")
    b = ExperienceMap.load(tmp_path / "a.npz", c)
    b.begin_session()
    lap(b, 100, range(20), FRAME_B, OFF_TRUE)
    b.save(tmp_path / "b.npz")
    b2 = ExperienceMap.load(tmp_path / "b.npz", c)
    lap(b2, 100, range(20, 40), FRAME_B, OFF_TRUE)
    b2.settle()
    np.testing.assert_array_equal(b2.positions, whole.positions)
    np.testing.assert_array_equal(b2.sessions, whole.sessions)
    assert b2.loops == whole.loops and len(b2.session_links) == len(whole.session_links) == 1
    np.testing.assert_array_equal(b2.session_links[0].delta, whole.session_links[0].delta)
    assert b2.session_root(1) == 0


def test_a_map_saved_before_sessions_loads_as_one_session(tmp_path: Path) -> None:
    em = session_a(cfg())
    em.save(tmp_path / "m.npz")
    z = dict(np.load(tmp_path / "m.npz"))
    for k in ("session", "odom"):
        z.pop(k)
    np.savez(tmp_path / "old.npz", **z)
    back = ExperienceMap.load(tmp_path / "old.npz", cfg())
    assert back.n_sessions == 1 and (back.sessions == 0).all()
    np.testing.assert_allclose(back.state().columns["odom"], em.state().columns["odom"], atol=1e-9)


@pytest.mark.parametrize("jump_m", [0.0, 5.0])
def test_kidnapped_vehicle_recovers_by_a_verified_link(jump_m: float) -> None:
    """One mission: after a lap the odometry jumps by 33 m (the vehicle was moved, or the
    navigation reset); with sessions.jump_m the jump begins a new session which the next
    verified recognition links back; without, the jump is taken as motion and the map keeps it."""
    em = ExperienceMap(cfg({"sessions.jump_m": jump_m}))
    lap(em, 0, range(40), np.zeros(3))
    res = lap(em, 100, range(40), FRAME_B, OFF_TRUE)
    em.settle()
    truth_b = np.array([enu(true_ned(k, OFF_TRUE)) for k in range(40)])
    err = np.abs(em.positions[40:, :2] - truth_b[:, :2]).max()
    if jump_m:
        assert res[0].session_started and len(em.session_links) == 1
        assert err < 0.1
    else:
        assert em.n_sessions == 1 and not em.session_links
        assert err > 5.0


def test_an_earlier_session_is_a_candidate_whatever_its_age() -> None:
    """A prior map smaller than min_experience_age events: its places are still candidates."""
    c = cfg({"min_experience_age": 200})
    em = session_a(c)
    em.begin_session()
    res = lap(em, 100, range(40), FRAME_B, OFF_TRUE)
    assert any(r.match >= 0 for r in res) and len(em.session_links) == 1
    # within one session the age rule holds: a second lap of the same session matches nothing
    one = ExperienceMap(c)
    lap(one, 0, range(40), np.zeros(3))
    assert all(r.match < 0 for r in lap(one, 100, range(40), np.zeros(3), OFF_TRUE))


def _turned_lap(em: ExperienceMap, t0: int, ks: range, phi_deg: float) -> list[EventResult]:
    """Session B's pass with its odometry frame turned by ``phi_deg`` (ENU, counter-clockwise)
    about its origin at FRAME_B: positions, heading and sweeps all seen in that frame."""
    a = math.radians(phi_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    out = []
    for k in ks:
        p = true_ned(k, OFF_TRUE)
        e = np.asarray(enu(p))
        odom = [*(rot @ e[:2] + FRAME_B[:2]), 0.0]
        sw = _sweep(p, [CHAMBER]) @ rot.T
        out.append(em.add_event((t0 + k) * SEC, k, pc_of(odom), odom, a, sweep=sw))
    return out


@pytest.mark.parametrize("rotate", [True, False])
def test_a_link_turns_the_new_session_by_the_registered_rotation(rotate: bool) -> None:
    """Session B's frame is turned 20 degrees from A's: the link applies the registration's
    rotation too, so B (before and after the link point) lines up with A's frame; translation
    only leaves it visibly turned."""
    em = session_a(cfg({"sessions.link_max_rotation_deg": 25.0, "sessions.link_rotation_step_deg": 1.0, "sessions.link_rotate": rotate}))
    em.begin_session()
    lap_b = _turned_lap(em, 100, range(40), -20.0)
    _turned_lap(em, 140, range(40), -20.0)     # a second pass: the odometry after the link turns too
    em.settle()
    assert sum(r.linked for r in lap_b) == 1 and len(em.session_links) == 1
    link = em.session_links[0]
    assert abs(link.rotation_deg - 20.0) <= 1.0
    truth_b = np.array([enu(true_ned(k, OFF_TRUE)) for k in range(40)] * 2)
    err = np.abs(em.positions[40:, :2] - truth_b[:, :2]).max()
    if rotate:
        assert link.applied_deg == pytest.approx(link.rotation_deg)
        assert err < 0.25
        np.testing.assert_allclose(em.yaws[40:], math.radians(link.rotation_deg - 20.0), atol=1e-9)
    else:
        assert link.applied_deg == 0.0
        assert err > 0.5


def _drifting_session_b(em: ExperienceMap, unknown: int, drift: np.ndarray) -> list[EventResult]:
    """Session B's pass: its first ``unknown`` events name places the camera never saw (no
    candidate, so no link yet), and its odometry drifts by ``drift`` (ENU m) per event."""
    out = []
    for k in range(40):
        p = true_ned(k, OFF_TRUE)
        odom = list(np.asarray(enu(p)) + FRAME_B + drift * k)
        lvc = 1000 + k if k < unknown else k
        out.append(em.add_event((100 + k) * SEC, lvc, pc_of(odom), odom, 0.0, sweep=_sweep(p, [CHAMBER])))
    return out


@pytest.mark.parametrize("radius_m", [2.0, 0.0])
def test_the_part_mapped_before_the_link_is_pinned_to_the_older_map(radius_m: float) -> None:
    """Session B maps 15 events before it is recognised, its odometry drifting 3 cm per event:
    that part hangs from the link node by odometry alone (0.45 m off at its start).  The backfill
    registers it against session A's sweeps where they overlap and pins it to the older map;
    with the backfill off (radius 0) the drift stays.  Measured against session A's nodes as the
    map holds them (B's event k truly sits OFF_TRUE from A's event k): Eq. 4.20 spreads B's
    drift over both chains, so the older map is not the truth any more either."""
    em = session_a(cfg({"sessions.backfill_radius_m": radius_m}))
    em.begin_session()
    res = _drifting_session_b(em, 15, np.array([0.03, 0.0, 0.0]))
    em.settle()
    linked = [k for k, r in enumerate(res) if r.linked]
    assert len(linked) == 1 and linked[0] >= 15
    link = em.session_links[0]
    off = np.asarray(enu(OFF_TRUE))[:2]
    err = np.linalg.norm(em.positions[40:55, :2] - em.positions[:15, :2] - off, axis=1)
    if radius_m:
        assert link.backfill_edges >= 4
        assert err.max() < 0.06, err
    else:
        assert link.backfill_edges == 0
        assert err.max() > 0.4, err


def test_backfill_rejects_a_part_that_does_not_fit() -> None:
    """Session B's unrecognised first events were flown in another chamber whose sweeps do not
    fit session A's walls nearby: no backfill edge, whatever the distance in the linked frame."""
    em = session_a(cfg())
    em.begin_session()
    for k in range(15):
        p = true_ned(k, OFF_TRUE)
        odom = list(np.asarray(enu(p)) + FRAME_B)
        em.add_event((100 + k) * SEC, 1000 + k, pc_of(odom), odom, 0.0, sweep=_sweep(p, [OTHER]))
    lap(em, 100, range(15, 40), FRAME_B, OFF_TRUE)
    em.settle()
    assert len(em.session_links) == 1 and em.session_links[0].backfill_edges == 0
