"""Vehicle trajectory of a simulated mission and the revisit ground truth.

The vehicle (a hovering AUV) enters area 1 through the last 15 m of the tunnel from
area 2, then follows the route of :mod:`missions.sim.world` in cycles: three loops of area 1 ("Ellipse"), the transition, three loops of area 2 ("Cave 2"), the
transition back, and again.  Speed, lateral offset in the tunnel, altitude over the floor,
roll, pitch and a small crab angle vary smoothly, so passes of the same place differ a
little.  The state is sampled at 50 Hz and interpolated linearly for every sensor stamp.

Frames: world NED (x north, y east, z down = depth), body x forward, y right, z down;
attitude as ZYX Euler angles (yaw, pitch, roll), ``R_wb = Rz(yaw) Ry(pitch) Rx(roll)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from missions.sim.world import World

__all__ = ["START_AREAS", "VehicleMotion", "make_trajectory", "rot_wb", "footprint_centres", "revisits", "LOOPS_PER_AREA"]

BASE_HZ = 50.0
LOOPS_PER_AREA = 3
#: where a mission may start: "area1" enters area 1 from the tunnel of area 2 and flies the
#: cycle from there (the default); "area2" enters area 2 through the last 15 m
#: of the transition from area 1 and flies the same cycle from area 2 (its loops, the transition
#: back, area 1, the transition): the same cave, the same world frame
START_AREAS = ("area1", "area2")


def rot_wb(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body-to-world rotation matrices (..., 3, 3) of ZYX Euler angles (rad)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    r = np.empty(np.shape(roll) + (3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


def _smooth_noise(rng: np.random.Generator, t: np.ndarray, knot_s: float, sigma: float) -> np.ndarray:
    """A smooth random signal: Gaussian knots every ``knot_s`` seconds, cosine-interpolated."""
    n = int(np.ceil(t[-1] / knot_s)) + 2
    knots = rng.normal(0.0, sigma, n)
    u = t / knot_s
    i = np.floor(u).astype(int)
    f = u - i
    f = (1 - np.cos(np.pi * f)) / 2
    out: np.ndarray = knots[i] * (1 - f) + knots[i + 1] * f
    return out


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    pad = np.concatenate([np.repeat(x[:1], n // 2, axis=0), x, np.repeat(x[-1:], n - n // 2 - 1, axis=0)])
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), pad]), axis=0)
    out: np.ndarray = (c[n:] - c[:-n]) / n
    return out


@dataclass
class VehicleMotion:
    """50 Hz ground-truth state; times in seconds from the mission start."""

    t: np.ndarray          # (n,)
    pos: np.ndarray        # (n, 3) world NED, m
    rpy: np.ndarray        # (n, 3) roll, pitch, yaw (yaw unwrapped), rad
    vel_w: np.ndarray      # (n, 3) world velocity, m/s
    acc_w: np.ndarray      # (n, 3) world acceleration, m/s^2
    omega_b: np.ndarray    # (n, 3) body angular rate p, q, r, rad/s
    dist: np.ndarray       # (n,) distance travelled, m
    altitude: np.ndarray   # (n,) height over the floor below the vehicle, m
    segment: np.ndarray    # (n,) int: index into ``segment_names`` of the route piece being flown
    loop: np.ndarray       # (n,) int: loop number (0-based) within the current area visit
    segment_names: list[str]

    def at(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """Linear interpolation of the state at ``times`` (s)."""
        times = np.asarray(times, np.float64)
        out = {}
        for name in ("pos", "rpy", "vel_w", "acc_w", "omega_b"):
            a = getattr(self, name)
            out[name] = np.stack([np.interp(times, self.t, a[:, k]) for k in range(3)], axis=-1)
        out["dist"] = np.interp(times, self.t, self.dist)
        out["altitude"] = np.interp(times, self.t, self.altitude)
        idx = np.clip(np.searchsorted(self.t, times), 0, len(self.t) - 1)
        out["segment"] = self.segment[idx]
        out["loop"] = self.loop[idx]
        return out


def _speed_profile(rng: np.random.Generator, t: np.ndarray, speed: float) -> np.ndarray:
    """Distance along the route (m) at every 50 Hz sample: a smoothly varying speed around
    ``speed``, never below 30 % of it (the first of the trajectory's random draws)."""
    v = speed * (1.0 + _smooth_noise(rng, t, 20.0, 0.12))
    v = np.clip(v, 0.3 * speed, None)
    s: np.ndarray = np.concatenate([[0.0], np.cumsum(v[1:] * np.diff(t))])
    return s


def _piece_length(points: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(points, axis=0).T)))


def _flight_plan(world: World, start: str, length_m: float,
                 first_loops: int | None = None) -> list[tuple[np.ndarray, int, int]]:
    """Route pieces (points, segment id, loop) in flight order until ``length_m`` is covered;
    ``first_loops``: loops of the start area before the first transition (default
    :data:`LOOPS_PER_AREA`; afterwards the cycle as always)."""
    a1, tr, a2, back = world.route
    plan: list[tuple[np.ndarray, int, int]] = []
    cycle = [(a1, 0, k) for k in range(LOOPS_PER_AREA)] + [(tr, 1, 0)] + \
            [(a2, 2, k) for k in range(LOOPS_PER_AREA)] + [(back, 3, 0)]
    # the mission starts with an approach: the last 15 m of the tunnel from area 2 into area 1
    # (from area 1 into area 2 when starting in area 2, and the cycle begins with area 2)
    entry = back[-150:]
    entry_seg = 3
    if start == "area2":
        entry, entry_seg = tr[-150:], 1
        cycle = cycle[LOOPS_PER_AREA + 1:] + cycle[:LOOPS_PER_AREA + 1]
    plan.append((entry, entry_seg, 0))
    total = 0.0 + _piece_length(entry)
    if first_loops is not None and first_loops != LOOPS_PER_AREA:
        for item in cycle[LOOPS_PER_AREA - first_loops:]:   # the first pass: fewer loops of the start area
            plan.append(item)
            total += _piece_length(item[0])
    while total < length_m:
        for item in cycle:
            plan.append(item)
            total += _piece_length(item[0])
    return plan


def _centreline(plan: list[tuple[np.ndarray, int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The plan as one polyline with its corners smoothed (2 m moving average of the 0.1 m
    polyline): (points, distance along it, segment id, loop) per point, repeated points dropped."""
    pts = np.concatenate([p for p, _, _ in plan])
    seg_id = np.concatenate([np.full(len(p), g) for p, g, _ in plan])
    loop_id = np.concatenate([np.full(len(p), k) for p, _, k in plan])
    pts = _moving_average(pts, 21)
    d = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    keep = np.r_[True, np.diff(d) > 1e-9]
    return pts[keep], d[keep], seg_id[keep], loop_id[keep]


def _tunnel_normals(cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
    """Unit normals (n, 2) of the centreline, from its direction smoothed over 1 s.

    The raw tangent of the 0.1 m polyline is piecewise constant, and offsetting the path by up
    to 0.5 m along a normal that jumps at every vertex made the vehicle step backwards there on
    the inside of bends -- the velocity direction (the heading, until generator_version 3) then
    flipped by 180 deg, np.unwrap chose a side at random and the 1-s heading average turned the
    flips into yaw spins of up to ~2000 deg/s."""
    tang = np.stack([np.gradient(cx), np.gradient(cy)], axis=1)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True) + 1e-12
    tang = _moving_average(tang, int(BASE_HZ))
    tang /= np.linalg.norm(tang, axis=1, keepdims=True) + 1e-12
    return np.stack([-tang[:, 1], tang[:, 0]], axis=1)


def _attitude(rng: np.random.Generator, t: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(roll, pitch, yaw) rad: yaw = the heading plus a small crab angle, then roll and pitch
    wobble (random draws in that order).

    The heading follows the velocity averaged over 1 s as a vector (not the angle of each
    sample: where the path nearly stalls, at a hairpin where route pieces join, single samples
    point anywhere and their unwrapped angles spun the same way)."""
    vbar = _moving_average(vel[:, :2], int(1.0 * BASE_HZ))
    heading = np.unwrap(np.arctan2(vbar[:, 1], vbar[:, 0]))
    heading = _moving_average(heading, int(1.0 * BASE_HZ))
    yaw = heading + np.deg2rad(_smooth_noise(rng, t, 8.0, 3.0))
    roll = np.deg2rad(_smooth_noise(rng, t, 4.0, 1.5))
    pitch = np.deg2rad(_smooth_noise(rng, t, 5.0, 2.0))
    return roll, pitch, yaw


def _body_rates(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, dt: float) -> np.ndarray:
    """Body angular rates (n, 3) p, q, r (rad/s) of the ZYX Euler angles' time derivatives."""
    dr, dp, dyw = (np.gradient(a, dt) for a in (roll, pitch, yaw))
    p = dr - dyw * np.sin(pitch)
    q = dp * np.cos(roll) + dyw * np.cos(pitch) * np.sin(roll)
    r = -dp * np.sin(roll) + dyw * np.cos(pitch) * np.cos(roll)
    return np.stack([p, q, r], axis=1)


def make_trajectory(world: World, duration_s: float, seed: int, speed: float = 0.3,
                    start: str = "area1", first_loops: int | None = None) -> VehicleMotion:
    """The vehicle's path for ``duration_s`` seconds at a mean ``speed`` (m/s), starting in
    ``start`` (one of :data:`START_AREAS`) and flying ``first_loops`` loops there before the
    first transition (default :data:`LOOPS_PER_AREA`)."""
    if start not in START_AREAS:
        raise ValueError(f"start must be one of {', '.join(START_AREAS)}, got {start!r}")
    if first_loops is not None and not 1 <= first_loops <= LOOPS_PER_AREA:
        raise ValueError(f"first_loops must be in [1, {LOOPS_PER_AREA}], got {first_loops}")
    rng = np.random.default_rng([seed, 202])
    t = np.arange(0.0, duration_s + 1.0 / BASE_HZ + 2.0, 1.0 / BASE_HZ)
    s = _speed_profile(rng, t, speed)
    pts, d, seg_id, loop_id = _centreline(_flight_plan(world, start, s[-1] + 10.0, first_loops))
    cx = np.interp(s, d, pts[:, 0])
    cy = np.interp(s, d, pts[:, 1])
    k = np.clip(np.searchsorted(d, s), 0, len(d) - 1)
    nrm = _tunnel_normals(cx, cy)
    lateral = np.clip(_smooth_noise(rng, t, 15.0, 0.25), -0.5, 0.5)
    x = cx + nrm[:, 0] * lateral
    y = cy + nrm[:, 1] * lateral
    floor = world.floor_at(x, y)
    alt_target = 2.1 + _smooth_noise(rng, t, 12.0, 0.25)
    alt_target = np.clip(alt_target, 1.4, 2.8)
    z = _moving_average(floor - alt_target, int(3 * BASE_HZ))
    pos = np.stack([x, y, z], axis=1)
    dt = 1.0 / BASE_HZ
    vel = np.gradient(pos, dt, axis=0)
    roll, pitch, yaw = _attitude(rng, t, vel)
    acc = np.gradient(vel, dt, axis=0)
    dist = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))]
    altitude = world.floor_at(x, y) - z
    return VehicleMotion(t=t, pos=pos, rpy=np.stack([roll, pitch, yaw], axis=1), vel_w=vel, acc_w=acc,
                      omega_b=_body_rates(roll, pitch, yaw, dt), dist=dist, altitude=altitude, segment=seg_id[k],
                      loop=loop_id[k], segment_names=list(world.route_names))


def footprint_centres(world: World, pos: np.ndarray, rpy: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """Where the camera's optical axis (body z) meets the floor, (n, 2) world x, y."""
    rot = rot_wb(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    cam = pos + rot @ lever
    axis = rot[:, :, 2]
    c = cam[:, :2].copy()
    for _ in range(3):
        zf = world.floor_at(c[:, 0], c[:, 1])
        tt = (zf - cam[:, 2]) / np.maximum(axis[:, 2], 1e-3)
        c = cam[:, :2] + axis[:, :2] * tt[:, None]
    out: np.ndarray = c
    return out


@nb.njit(cache=True)
def _revisit_pairs(c: np.ndarray, pos: np.ndarray, dist: np.ndarray, yaw: np.ndarray, radius: float,
                   max_vehicle: float, min_gap: float, max_dyaw: float) -> tuple[np.ndarray, np.ndarray]:
    n = c.shape[0]
    counts = np.zeros(n + 1, np.int64)
    cap = 1024
    idx = np.empty(cap, np.int32)
    m = 0
    r2 = radius * radius
    for i in range(n):
        for j in range(i):
            if dist[i] - dist[j] < min_gap:
                break  # dist is non-decreasing: every later j is closer along the path
            dx = c[i, 0] - c[j, 0]
            dy = c[i, 1] - c[j, 1]
            if dx * dx + dy * dy > r2:
                continue
            ex = pos[i, 0] - pos[j, 0]
            ey = pos[i, 1] - pos[j, 1]
            ez = pos[i, 2] - pos[j, 2]
            if ex * ex + ey * ey + ez * ez > max_vehicle * max_vehicle:
                continue
            if max_dyaw >= 0.0:
                d = (yaw[i] - yaw[j] + np.pi) % (2 * np.pi) - np.pi
                if abs(d) > max_dyaw:
                    continue
            if m == cap:
                cap *= 2
                new = np.empty(cap, np.int32)
                new[:m] = idx[:m]
                idx = new
            idx[m] = j
            m += 1
        counts[i + 1] = m
    return counts, idx[:m].copy()


def revisits(centres: np.ndarray, pos: np.ndarray, dist: np.ndarray, yaw: np.ndarray, radius: float = 1.5,
             max_vehicle_dist: float = 2.0, min_gap: float = 10.0,
             max_heading_diff: float | None = None) -> list[np.ndarray]:
    """For every camera frame, the indices of earlier frames of the same place.

    Same place: footprint centres within ``radius`` metres, vehicle positions (3D) within
    ``max_vehicle_dist`` metres, and at least ``min_gap`` metres travelled between the two
    frames (so neighbours of the same pass, which trivially
    overlap, are not counted as revisits).  ``max_heading_diff`` (rad) additionally bounds
    the heading difference; None (default) ignores heading, since a downward camera sees the
    same floor whatever the heading (only rotated).
    """
    indptr, idx = _revisit_pairs(np.ascontiguousarray(centres, np.float64), np.ascontiguousarray(pos, np.float64),
                                 np.asarray(dist, np.float64), np.asarray(yaw, np.float64), radius,
                                 float(max_vehicle_dist), min_gap,
                                 -1.0 if max_heading_diff is None else float(max_heading_diff))
    return [idx[indptr[i]:indptr[i + 1]] for i in range(len(centres))]
