"""Sonar sweeps and their registration (services/expmap/scans.py) and the loop edges they give."""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from services.expmap.config import ExpMapConfig
from services.expmap.graph import EventResult, ExperienceMap
from services.expmap.scans import MAX_EXTRAPOLATION_S, SweepBuffer, echo_range, register_sweeps
from tests.expmap.helpers import SEC, pc_of, small_cfg

# A cave chamber: polygon walls (x, y in m), irregular so a sweep fixes both axes.
CHAMBER = np.array([[0, 0], [9, -1], [12, 3], [10, 8], [5, 7.5], [3, 10], [-2, 6], [-1, 2]], float)
# A straight tunnel along x: two parallel walls (only the across-track offset is observable).
TUNNEL = [np.array([[-100, -2.0], [100, -2.0]]), np.array([[100, 2.5], [-100, 2.5]])]


def _ray(p: np.ndarray, d: np.ndarray, walls: Sequence[np.ndarray]) -> float:
    """Range from p along unit d to the nearest wall segment (inf if none)."""
    best = math.inf
    for poly in walls:
        for a, b in zip(poly, np.roll(poly, -1, axis=0)[: len(poly)] if len(poly) > 2 else poly[1:]):
            e = b - a
            den = d[0] * e[1] - d[1] * e[0]
            if abs(den) < 1e-12:
                continue
            w = a - p
            t = (w[0] * e[1] - w[1] * e[0]) / den
            u = (w[0] * d[1] - w[1] * d[0]) / den
            if t > 1e-6 and 0.0 <= u <= 1.0:
                best = min(best, t)
    return best


def _sweep(p: np.ndarray, walls: Sequence[np.ndarray], yaw_ned: float = 0.0, enu: bool = True, heading_error_deg: float = 0.0) -> np.ndarray:
    """A full 1.8-degree sweep from a vehicle standing at NED position p, through SweepBuffer.

    The simulated beam is the physical one; the dead-reckoning pose handed to the buffer may
    carry a heading error.  ENU: the published frame of robot_state's defaults."""
    sb = SweepBuffer(head_sign=-1.0 if enu else 1.0)
    psi = yaw_ned + math.radians(heading_error_deg)
    if enu:  # published ENU/FLU: position (y, x, -z), yaw pi/2 - psi, body y to port
        pos = [p[1], p[0], 0.0]
        a = math.pi / 2 - psi
        rot = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    else:
        pos = [p[0], p[1], 0.0]
        rot = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]])
    sb.add_pose(pos, rot)
    for k in range(201):
        h = math.radians((k * 1.8) % 360.0)
        th = yaw_ned + h                       # physical beam direction in NED (clockwise from north)
        r = _ray(np.asarray(p, float), np.array([math.cos(th), math.sin(th)]), walls)
        sb.add_beam(h, r if r < 20.0 else math.nan)
    return sb.sweep(pos[:2])


def _to_ned(xy: np.ndarray) -> np.ndarray:
    return xy[:, ::-1]


def test_echo_range_takes_the_wall_not_the_ring_down_or_the_noise() -> None:
    nb, rmax = 400, 20.0
    r = (np.arange(nb) + 0.5) * rmax / nb
    beam = (55 * np.exp(-r / 0.35) + 120 * np.exp(-0.5 * ((r - 6.3) / 0.18) ** 2) + 3).astype(np.int32)
    assert echo_range(beam, rmax, 1.0, 80.0) == pytest.approx(6.3, abs=0.05)
    assert math.isnan(echo_range((beam * 0.5).astype(np.int32), rmax, 1.0, 80.0))   # too weak: no wall
    ring = (55 * np.exp(-r / 0.35) * 3).astype(np.int32)                              # ring-down only
    assert math.isnan(echo_range(ring, rmax, 1.0, 80.0))
    assert echo_range(ring, rmax, 0.0, 80.0) < 1.0


@pytest.mark.parametrize("enu", [True, False])
def test_sweep_points_lie_on_the_walls_in_either_published_frame(enu: bool) -> None:
    p, yaw = np.array([4.0, 3.0]), math.radians(35.0)
    pts = _sweep(p, [CHAMBER], yaw, enu=enu)
    assert len(pts) >= 150
    ned = (_to_ned(pts) if enu else pts.astype(float)) + p
    # every point is on a wall: its distance to the polygon boundary is ~0
    assert max(_wall_distance(q, CHAMBER) for q in ned) < 1e-6


def _wall_distance(q: np.ndarray, poly: np.ndarray) -> float:
    """Distance (m) from point q to the boundary of polygon ``poly``."""
    ds = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        e = b - a
        t = np.clip(np.dot(q - a, e) / np.dot(e, e), 0, 1)
        ds.append(np.linalg.norm(q - (a + t * e)))
    return float(min(ds))


def test_beams_are_placed_at_the_pose_carried_to_their_own_stamps() -> None:
    """Poses at 5 Hz, beams at 23 Hz, the vehicle crabbing at 0.32 m/s while it turns at 15 deg/s:
    each point lies where its beam met the wall; with the last pose as it was (no stamps) the
    points are off by decimetres."""
    v, w, p0, yaw0 = np.array([0.3, 0.1]), math.radians(15.0), np.array([4.0, 3.0]), 0.3

    def rz(a: float) -> np.ndarray:
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    moving, stale = SweepBuffer(head_sign=1.0), SweepBuffer(head_sign=1.0)
    next_pose = 0
    for k in range(230):
        t_ns = round(k * 1e9 / 23)
        while next_pose <= t_ns:                        # the odometry's 5 Hz grid
            ts = next_pose * 1e-9
            p, rot = p0 + v * ts, rz(yaw0 + w * ts)
            body_v = rot.T @ np.array([v[0], v[1], 0.0])
            moving.add_pose([p[0], p[1], 0.0], rot, next_pose, body_v, [0.0, 0.0, w])
            stale.add_pose([p[0], p[1], 0.0], rot)
            next_pose += 200_000_000
        h = math.radians((k * 1.8) % 360.0)
        ts = t_ns * 1e-9
        th = yaw0 + w * ts + h                          # the physical beam at the beam's own instant
        r = _ray(p0 + v * ts, np.array([math.cos(th), math.sin(th)]), [CHAMBER])
        for sb in (moving, stale):
            sb.add_beam(h, r if r < 20.0 else math.nan, t_ns if sb is moving else None)
    pts = moving.sweep([0.0, 0.0]).astype(float)
    assert len(pts) >= 150
    assert max(_wall_distance(q, CHAMBER) for q in pts) < 1e-4
    assert max(_wall_distance(q, CHAMBER) for q in stale.sweep([0.0, 0.0]).astype(float)) > 0.1


def test_a_beam_long_after_its_pose_is_carried_forward_by_the_bound_only() -> None:
    """After a silence of the odometry the pose is carried at most MAX_EXTRAPOLATION_S; a beam
    stamped before the pose is placed at the pose itself."""
    sb = SweepBuffer(head_sign=1.0)
    sb.add_pose([0.0, 0.0, 0.0], np.eye(3), 1_000_000_000, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    for k in range(201):
        t = 6_000_000_000 if k == 0 else 900_000_000    # the first 5 s after the pose, the rest before it
        sb.add_beam(math.radians(k * 1.8), 3.0, t)
    pts = sb.sweep([0.0, 0.0]).astype(float)
    assert pts[-1] == pytest.approx([MAX_EXTRAPOLATION_S + 3.0, 0.0])   # the first beam: sweep() lists newest first
    assert np.allclose(np.linalg.norm(pts[:-1], axis=1), 3.0, atol=1e-5)


def test_sweep_needs_a_full_turn_and_no_pose_means_no_points() -> None:
    sb = SweepBuffer()
    assert not sb.add_beam(0.0, 3.0)                  # no pose yet
    sb.add_pose([0, 0, 0], np.eye(3))
    for k in range(100):                              # half a turn
        sb.add_beam(math.radians(k * 1.8), 3.0)
    assert len(sb.sweep([0, 0])) == 0
    for k in range(100, 201):
        sb.add_beam(math.radians(k * 1.8), 3.0)
    out = sb.sweep([0.0, 0.0])
    assert 195 <= len(out) <= 201 and np.allclose(np.linalg.norm(out, axis=1), 3.0, atol=1e-5)


def test_registration_measures_the_displacement_between_two_visits() -> None:
    pm, pn = np.array([4.0, 3.0]), np.array([4.7, 2.6])
    ref = _sweep(pm, [CHAMBER], math.radians(10))
    cur = _sweep(pn, [CHAMBER], math.radians(190))          # seen the other way round
    true_pub = (pn - pm)[::-1]                             # ENU: (east, north)
    reg = register_sweeps(ref, cur, map_separation=[0.0, 0.0])
    assert reg.trusted and reg.ambiguous_axis is None, reg.reason
    assert np.linalg.norm(reg.translation - true_pub) < 0.06
    # a heading disagreement of 1.5 degrees between the two visits is absorbed by the rotation search
    cur_rot = _sweep(pn, [CHAMBER], math.radians(190), heading_error_deg=1.5)
    reg = register_sweeps(ref, cur_rot, map_separation=[0.0, 0.0])
    assert reg.trusted and np.linalg.norm(reg.translation - true_pub) < 0.12
    assert reg.rotation_deg != 0.0


def test_straight_tunnel_fixes_only_the_across_track_offset() -> None:
    pm, pn = np.array([0.0, 0.0]), np.array([1.5, 0.6])      # 1.5 m along, 0.6 m across
    ref = _sweep(pm, TUNNEL)
    cur = _sweep(pn, TUNNEL)
    reg = register_sweeps(ref, cur, map_separation=[0.0, 0.0], max_rotation_deg=0.0)
    assert reg.trusted, reg.reason
    u = reg.ambiguous_axis
    assert u is not None and abs(abs(u[1]) - 1.0) < 0.05          # ENU y = NED x: along the tunnel
    assert reg.translation[0] == pytest.approx(0.6, abs=0.06)       # ENU x = NED y: across
    assert reg.spread_m[1] > 0.3 >= reg.spread_m[0]


def test_sweeps_of_different_places_are_not_trusted() -> None:
    ref = _sweep(np.array([4.0, 3.0]), [CHAMBER])
    rng = np.random.default_rng(3)
    cur = rng.uniform(-8, 8, (200, 2)).astype(np.float32)
    reg = register_sweeps(ref, cur, map_separation=[0.0, 0.0])
    assert not reg.trusted and "inlier" in reg.reason
    few = register_sweeps(ref[:10], cur, map_separation=[0.0, 0.0])
    assert not few.trusted and "too few" in few.reason


def _chamber_loop(em: ExperienceMap, offset_true: np.ndarray, sweeps: bool) -> None:
    """Out and back along x twice; the second pass runs offset_true (NED m) beside the first,
    and the odometry does not know it (it thinks both passes are on the same line)."""
    base = np.array([1.0, 3.0])
    t = 0
    for lap in range(2):
        for k in range(40):
            a = 2 * math.pi * k / 40
            true = base + np.array([2.5 * math.sin(a), 2.5 * (1 - math.cos(a)) * 0.6])
            if lap == 1:
                true = true + offset_true
            odom_ned = base + np.array([2.5 * math.sin(a), 2.5 * (1 - math.cos(a)) * 0.6])
            pub = [odom_ned[1], odom_ned[0], 0.0]
            sw = _sweep(true, [CHAMBER]) if sweeps else None
            em.add_event(t * SEC, k, pc_of(pub), pub, 0.0, sweep=sw)
            t += 1
    em.settle()


def test_loop_edge_asks_for_the_measured_displacement_not_zero() -> None:
    off = np.array([0.5, -0.3])                                 # NED
    cfg = small_cfg({"min_experience_age": 20, "corrections.min_route_len": 20, "corrections.min_interval_sec": 0.0, "loops.edge_weight": 1000.0})
    em = ExperienceMap(cfg)
    _chamber_loop(em, off, sweeps=True)
    assert em.corrections >= 1 and em.scan_registrations["trusted"] >= 1
    m, n, _w, _s = em.loops[0]
    d = em.loop_deltas[0]
    # the two experiences were recognised as the same place (same LVC); the sonar says how far apart
    assert np.linalg.norm(d[:2] - off[::-1]) < 0.08
    sep = em.positions[n] - em.positions[m]
    assert np.linalg.norm(sep[:2] - off[::-1]) < 0.08            # stiff loop edge: the map follows it
    # without sweeps (or with the option off) the dissertation's zero displacement
    em0 = ExperienceMap(cfg)
    _chamber_loop(em0, off, sweeps=False)
    assert em0.scan_registrations["no_sweep"] >= 1 and np.allclose(em0.loop_deltas[0], 0.0)
    em1 = ExperienceMap(cfg.updated({"loops.scan_matching": False}))
    _chamber_loop(em1, off, sweeps=True)
    assert np.allclose(em1.loop_deltas[0], 0.0) and sum(em1.scan_registrations.values()) == 0


def test_sweeps_survive_save_and_load(tmp_path: Path) -> None:
    cfg = small_cfg({"min_experience_age": 20, "corrections.min_route_len": 20, "corrections.min_interval_sec": 0.0})
    em = ExperienceMap(cfg)
    _chamber_loop(em, np.array([0.4, 0.2]), sweeps=True)
    em.save(tmp_path / "m.npz")
    back = ExperienceMap.load(tmp_path / "m.npz", cfg)
    assert len(back.state().sweeps) == em.n_nodes
    for a, b in zip(em.state().sweeps, back.state().sweeps):
        assert (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def test_a_closure_whose_sweeps_do_not_fit_is_rejected() -> None:
    """Geometric verification: the LVCs say "same place" but the second pass is in another
    chamber; the closure is refused (or, with the check off, closed with zero displacement)."""
    ang = np.linspace(0, 2 * np.pi, 7)[:-1] + 0.3
    other = np.c_[2 + 5 * np.cos(ang), 4 + 4 * np.sin(ang)]               # a hexagonal chamber
    cfg = small_cfg({"min_experience_age": 20, "corrections.min_route_len": 20, "corrections.min_interval_sec": 0.0})

    def run(c: ExpMapConfig) -> tuple[ExperienceMap, list[EventResult]]:
        em = ExperienceMap(c)
        base = np.array([1.0, 3.0])
        results = []
        for lap in range(2):
            for k in range(40):
                a = 2 * math.pi * k / 40
                p = base + np.array([2.5 * math.sin(a), 1.5 * (1 - math.cos(a))])
                walls = [CHAMBER] if lap == 0 else [other]
                pub = [p[1], p[0], 0.0]
                results.append(em.add_event((lap * 40 + k) * SEC, k, pc_of(pub), pub, 0.0, sweep=_sweep(p, walls)))
        return em, results

    em, results = run(cfg)
    assert em.corrections == 0 and not em.loops
    assert any(r.rejected == "scan" for r in results) and em.scan_registrations["untrusted"] >= 1
    assert em.last_registration is not None and em.last_registration.inconsistent
    em_off, _ = run(cfg.updated({"scan.reject_inconsistent": False}))
    assert em_off.corrections >= 1 and np.allclose(em_off.loop_deltas[0], 0.0)
