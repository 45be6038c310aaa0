"""Generate a synthetic cave mission into an MCAP recording.

(Over 500 lines because every stream's generator shares the mission's one timeline and random
stream; splitting them would change the order of the random draws, and so the missions.)

Streams (keys as a real import of the Cala Viuda bags produces them) and their rates:

================== ================ ======= =============================================
key                type             rate    content
================== ================ ======= =============================================
camera/image_raw   Image rgb8       5 Hz    384x288 downward camera (see render.py)
sonar_micron       RangeImageBeam   23.3 Hz horizontal MSIS, 1.8 deg steps, 20 m, 397 bins
sonar_micron_ros   LaserScan        23.3 Hz same beam: angle_min = angle_max = head angle,
                                            ranges = bin-centre ranges, intensities = echo
sonar_seaking      RangeImageBeam   50 Hz   vertical profiler (across-track plane), 10 m,
                                            200 bins
sonar_seaking_ros  LaserScan        50 Hz   same beam as LaserScan
dvl_linkquest      LinkquestDvl     2.85 Hz instrument-frame bottom velocity with noise, bias,
                                            beam dropouts and dropout bursts (flag 0)
imu_adis           Imu              10 Hz   attitude with yaw drift, quaternion, gyro,
                                            accelerometer (specific force), magnetometer
imu_adis_ros       Imu              10 Hz   same samples, sensor_msgs/Imu content (no mag)
depth_sensor       Depth            10 Hz   depth with bias and noise
odometry           Odometry         11.2 Hz reference navigation (drifting, mildly noisy)
truth/pose         Odometry         10 Hz   exact pose and body velocities
truth/revisits     RevisitTruth     5 Hz    per camera frame: earlier frames of the same place
================== ================ ======= =============================================

Conventions: world NED (x north, y east, z down = depth, m); body x forward, y right,
z down; quaternions x y z w of body-to-world; angles rad except the DVL attitude (deg);
sonar head angles: Micron from body +x towards +y (clockwise seen from above), SeaKing
from body +y towards +z in the body y-z plane; ``angle_grad`` in gradians (400 per turn).
DVL instrument frame = body frame (mounting aligned).  Camera: optical axis body +z,
image right = body +y, image up = body +x, lever arm (0.4, 0, 0.2) m in body.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from common.geometry import wrap_angle
from common.mcap_io import RecordingWriter
from common.messages import Depth, Header, Image, Imu, LaserScan, LinkquestDvl, Odometry, RangeImageBeam, RevisitTruth
from missions.sim import render
from missions.sim.trajectory import (
    LOOPS_PER_AREA,
    START_AREAS,
    VehicleMotion,
    _smooth_noise,
    footprint_centres,
    make_trajectory,
    revisits,
    rot_wb,
)
from missions.sim.world import World, build_world

__all__ = ["GENERATOR_VERSION", "SimParams", "CameraModel", "generate", "T0_NS", "KEY_ORDER", "quat_from_rpy"]

#: mission start stamp (ns): 2013-07-01 14:00:00 UTC, the day of the real Cala Viuda mission
T0_NS = 1_372_687_200_000_000_000

#: bumped whenever the recording produced for a given seed and parameters changes
GENERATOR_VERSION = "poseidon-sim/4"

#: write order of messages with equal stamps
KEY_ORDER = ["truth/pose", "truth/revisits", "imu_adis", "imu_adis_ros", "depth_sensor", "dvl_linkquest",
             "odometry", "sonar_micron", "sonar_micron_ros", "sonar_seaking", "sonar_seaking_ros",
             "camera/image_raw"]

G = 9.81


@dataclass
class CameraModel:
    """Pinhole intrinsics of the real camera (camera_calibration.yaml, MEI with xi = 0)."""

    width: int = 384
    height: int = 288
    fx: float = 405.64
    fy: float = 405.59
    u0: float = 189.91
    v0: float = 139.91
    lever: tuple[float, float, float] = (0.4, 0.0, 0.2)
    rate_hz: float = 5.0
    lamp_tilt_deg: float = 12.0
    lamp_sigma_deg: float = 20.0
    attenuation_per_m: tuple[float, float, float] = (0.55, 0.10, 0.14)
    backscatter: tuple[float, float, float] = (0.004, 0.030, 0.034)
    blur_k: float = 0.25
    noise_sigma_dn: float = 4.0
    snow_per_frame: float = 45.0


@dataclass
class SimParams:
    """Every parameter of a mission; stored in the recording's ``poseidon`` metadata."""

    minutes: float = 10.0
    seed: int = 0                   # route, motion and sensor-noise seed
    world_seed: int | None = None   # the cave's seed (None: ``seed``, the cave of the route's seed)
    start: str = "area1"            # where the route starts: "area1" (the default) or "area2" (see trajectory.py)
    first_loops: int | None = None  # loops of the start area before the first transition (None: 3, every cycle's)
    speed_m_s: float = 0.3
    camera: CameraModel = field(default_factory=CameraModel)
    micron_rate_hz: float = 23.3
    micron_step_deg: float = 1.8
    micron_nbins: int = 397
    micron_range_m: int = 20
    seaking_rate_hz: float = 50.0
    seaking_step_deg: float = 1.8
    seaking_nbins: int = 200
    seaking_range_m: int = 10
    imu_rate_hz: float = 10.0
    imu_att_noise_deg: float = 0.1
    imu_yaw_drift_deg_per_min: float = 0.5
    imu_yaw_rw_deg_per_sqrt_s: float = 0.02
    imu_gyro_noise_deg_s: float = 0.05
    imu_gyro_bias_deg_s: float = 0.02
    imu_accel_noise_m_s2: float = 0.02
    depth_rate_hz: float = 10.0
    depth_noise_m: float = 0.02
    depth_bias_m: float = 0.05
    dvl_rate_hz: float = 2.85
    dvl_noise_m_s: float = 0.01
    dvl_bias_m_s: tuple[float, float, float] = (0.004, -0.003, 0.002)
    dvl_scale: float = 1.003
    dvl_beam_dropout_p: float = 0.04
    dvl_burst_start_p: float = 0.015
    dvl_burst_mean_samples: float = 6.0
    dvl_beam_inclination_deg: float = 30.0
    dvl_heading_noise_deg: float = 2.0
    odom_rate_hz: float = 11.2
    odom_vel_walk_m_s: float = 0.008
    truth_rate_hz: float = 10.0
    revisit_radius_m: float = 1.5
    revisit_max_vehicle_m: float = 2.0
    revisit_max_heading_deg: float | None = None  # None: heading ignored (downward camera)
    revisit_min_gap_m: float = 10.0
    chunk_s: float = 30.0


def quat_from_rpy(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) x y z w of ZYX Euler angles."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                     cr * cp * cy + sr * sp * sy], axis=-1)


# camera axes in the body frame (columns): x_c = body y, y_c = -body x, z_c = body z
R_BC = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


class _CameraRenderer:
    def __init__(self, world: World, cam: CameraModel):
        self.world = world
        self.cam = cam
        self.lin = np.empty((cam.height, cam.width, 3), np.float32)
        t = math.radians(cam.lamp_tilt_deg)
        self.lamp_c = np.array([0.0, -math.sin(t), math.cos(t)])
        self.att = np.asarray(cam.attenuation_per_m, np.float64)
        self.back = np.asarray(cam.backscatter, np.float64)
        r = np.arange(20001) / 1000.0  # 1 mm steps to 20 m
        self.lut_direct = np.exp(-2.0 * r[:, None] * self.att[None, :])
        self.lut_scatter = 1.0 - np.exp(-r[:, None] * self.att[None, :])
        self.gamma_lut = (255.0 * (np.arange(4097) / 4096.0) ** (1 / 2.2)).astype(np.float64)
        u = np.array([0.0, cam.width, 0.0, cam.width])
        v = np.array([0.0, 0.0, cam.height, cam.height])
        self.corners = np.stack([(u - cam.u0) / cam.fx, (v - cam.v0) / cam.fy, np.ones(4)])

    def render(self, pos: np.ndarray, rpy: np.ndarray, altitude: float, turbidity: float,
               rng: np.random.Generator, noise_seed: int) -> np.ndarray:
        cam, w = self.cam, self.world
        r_wb = rot_wb(rpy[0], rpy[1], rpy[2])
        r_wc = r_wb @ R_BC
        cpos = pos + r_wb @ np.asarray(cam.lever)
        lamp = r_wc @ self.lamp_c
        alt = max(altitude - cam.lever[2], 0.3)
        # texture tiles under the footprint (image corners on a floor up to 1 m deeper, +0.5 m)
        dirs = r_wc @ self.corners
        z_far = float(w.floor_at(cpos[0], cpos[1])[0]) + 1.0
        tt = (z_far - cpos[2]) / np.maximum(dirs[2], 0.15)
        xs = np.r_[cpos[0] + tt * dirs[0], cpos[0]]
        ys = np.r_[cpos[1] + tt * dirs[1], cpos[1]]
        w.ensure_tiles(xs.min() - 0.5, xs.max() + 0.5, ys.min() - 0.5, ys.max() + 0.5)
        # automatic exposure: bring the centre of a mid-grey floor to ~0.3 linear
        e_c = 0.55 / alt ** 2 * math.exp(-2 * self.att[1] * alt) + self.back[1] * (1 - math.exp(-self.att[1] * alt)) * turbidity
        gain = 0.30 / e_c
        render.render_linear(self.lin, r_wc, cpos, cam.fx, cam.fy, cam.u0, cam.v0, w.tiles0, w.tiles1, w.tile_index,
                             w.tex_x0, w.tex_y0, w.floor, w.grid_x0, w.grid_y0, w.grid_res, lamp,
                             math.radians(cam.lamp_sigma_deg), self.lut_direct, self.lut_scatter, self.back,
                             turbidity, cam.blur_k, gain)
        n = int(rng.poisson(cam.snow_per_frame * turbidity))
        if n:
            z = rng.uniform(0.25, 1.8, n)
            u = rng.uniform(-10, cam.width + 10, n)
            v = rng.uniform(-10, cam.height + 10, n)
            size = rng.uniform(0.0015, 0.005, n)
            rad = np.maximum(0.6, size * cam.fx / z / 2)
            # brightness: lamp spot in the particle's direction, 1/z^2 fall-off, scaled by exposure
            dirs = np.stack([(u - cam.u0) / cam.fx, (v - cam.v0) / cam.fy, np.ones(n)], axis=1)
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            ang = np.arccos(np.clip(dirs @ self.lamp_c, -1, 1))
            spot = np.exp(-0.5 * (ang / math.radians(cam.lamp_sigma_deg)) ** 2)
            bright = gain * 0.02 * spot / z ** 2 * rng.uniform(0.3, 1.0, n) / np.maximum(rad, 1.0) ** 2 * 2.0
            col = np.array([0.75, 1.0, 0.95])
            parts = np.column_stack([u, v, rad, bright[:, None] * col[None, :]])
            render.splat_particles(self.lin, parts)
        out = np.empty((cam.height, cam.width, 3), np.uint8)
        render.finish_image(self.lin, out, cam.noise_sigma_dn, noise_seed, self.gamma_lut)
        return out


def _stamps(duration_s: float, rate_hz: float, rng: np.random.Generator, jitter_s: float, offset_s: float) -> np.ndarray:
    n = max(int(math.floor((duration_s - offset_s) * rate_hz)), 0)
    t = offset_s + np.arange(n) / rate_hz
    if jitter_s > 0 and n:
        t = t + rng.uniform(-jitter_s, jitter_s, n)
    return t


def _ns(t: np.ndarray) -> np.ndarray:
    return T0_NS + np.round(np.asarray(t) * 1e9).astype(np.int64)


class _Out:
    """Collects (stamp, order, key, payload type, payload) for one chunk; writes them sorted."""

    def __init__(self, writer: RecordingWriter):
        self.writer = writer
        self.seq: dict[str, int] = {}
        self.items: list[tuple[int, int, int, str, Any]] = []
        self.order = {k: i for i, k in enumerate(KEY_ORDER)}

    def add(self, key: str, stamp: int, make: Callable[..., Any]) -> None:
        """``make(header)`` builds the message (lambdas bind their loop values as defaults)."""
        self.items.append((stamp, self.order[key], len(self.items), key, make))

    def flush(self) -> None:
        self.items.sort(key=lambda it: (it[0], it[1], it[2]))
        for stamp, _, _, key, make in self.items:
            s = self.seq.get(key, 0)
            self.seq[key] = s + 1
            msg = make(Header(seq=s, stamp=int(stamp), frame_id=_FRAME[key]))
            self.writer.write(key, msg)
        self.items.clear()


_FRAME = {
    "camera/image_raw": "camera", "sonar_micron": "sonar_micron", "sonar_micron_ros": "sonar_micron",
    "sonar_seaking": "sonar_seaking", "sonar_seaking_ros": "sonar_seaking", "dvl_linkquest": "dvl_linkquest",
    "imu_adis": "imu_adis", "imu_adis_ros": "imu_adis", "depth_sensor": "depth_sensor", "odometry": "world_ned",
    "truth/pose": "world_ned", "truth/revisits": "camera",
}


@dataclass
class _Streams:
    """Stamps (s from start) of every stream and the slow processes (biases, drifts)."""

    cam: np.ndarray
    micron: np.ndarray
    seaking: np.ndarray
    imu: np.ndarray
    depth: np.ndarray
    dvl: np.ndarray
    odom: np.ndarray
    truth: np.ndarray


def segments_of(traj: VehicleMotion, duration_s: float) -> list[dict[str, Any]]:
    """Time ranges of the route pieces flown (area loops and transitions), in flight order."""
    t = traj.t
    m = t <= duration_s
    key = traj.segment[m] * 100 + traj.loop[m]
    change = np.r_[0, np.nonzero(np.diff(key))[0] + 1]
    out = []
    for i, a in enumerate(change):
        b = change[i + 1] if i + 1 < len(change) else int(m.sum())
        seg = int(traj.segment[a])
        end = float(t[b]) if b < int(m.sum()) else float(duration_s)
        out.append({"name": traj.segment_names[seg], "segment": seg, "loop": int(traj.loop[a]),
                    "start_s": round(float(t[a]), 3), "end_s": round(end, 3),
                    "complete": bool(b < int(m.sum()))})
    return out


def _all_stamps(p: SimParams, duration: float, rng: np.random.Generator) -> _Streams:
    """Sample times (s) of every stream, drawn from ``rng`` in this fixed order."""
    return _Streams(
        cam=_stamps(duration, p.camera.rate_hz, rng, 0.004, 0.05),
        micron=_stamps(duration, p.micron_rate_hz, rng, 0.0, 0.013),
        seaking=_stamps(duration, p.seaking_rate_hz, rng, 0.0, 0.007),
        imu=_stamps(duration, p.imu_rate_hz, rng, 0.002, 0.021),
        depth=_stamps(duration, p.depth_rate_hz, rng, 0.002, 0.037),
        dvl=_stamps(duration, p.dvl_rate_hz, rng, 0.01, 0.11),
        odom=_stamps(duration, p.odom_rate_hz, rng, 0.0, 0.03),
        truth=_stamps(duration, p.truth_rate_hz, rng, 0.0, 0.0),
    )


def _metadata(p: SimParams, duration: float, world: World, segs: list[dict[str, Any]], dvl_heading_off: float,
              gyro_bias: np.ndarray) -> dict[str, Any]:
    """The recording's ``poseidon`` metadata record (``world_seed``, ``start``, ``first_loops`` only when they
    differ from the defaults, so a default mission's bytes are those of generator version 4)."""
    params = asdict(p)
    extra: dict[str, Any] = {}
    for k, default in (("world_seed", None), ("start", "area1"), ("first_loops", None)):
        if params[k] == default:
            del params[k]
        else:
            extra[k] = params[k]
    if "world_seed" in extra:
        extra["world_seed"] = world.seed
    return {
        # no wall clock and no git revision (a dirty tree would change the bytes): the generator
        # version is bumped whenever the output for a given seed changes
        "tool": "poseidon sim", "generator_version": GENERATOR_VERSION, "seed": p.seed, "minutes": p.minutes,
        **extra, "params": params, "t0_ns": T0_NS, "duration_s": duration,
        "frames": "world NED (x north, y east, z down); body x forward, y right, z down; quaternion xyzw body->world",
        "revisit_definition": (f"camera footprint centres (optical axis meets floor) within {p.revisit_radius_m} m, "
                               f"vehicle positions within {p.revisit_max_vehicle_m} m, and >= {p.revisit_min_gap_m} m "
                               f"travelled between the frames; heading "
                               + ("ignored" if p.revisit_max_heading_deg is None
                                  else f"within {p.revisit_max_heading_deg} deg")),
        "route": world.route_names, "segments": segs, "features": world.features,
        "dvl_heading_offset_deg": dvl_heading_off, "gyro_bias_rad_s": gyro_bias.tolist(),
    }


@dataclass
class _SlowErrors:
    """The mission's slow processes on the 50 Hz grid of the trajectory."""

    turbidity: np.ndarray       # (n,) water turbidity factor of the camera
    yaw_err: np.ndarray         # (n,) rad: IMU yaw error (drift + random walk)
    gyro_bias: np.ndarray       # (3,) rad/s
    odom_err: np.ndarray        # (n, 3) m: reference odometry drift
    dvl_heading_off: float      # deg: DVL heading offset


def _slow_errors(p: SimParams, tt: np.ndarray, rng: np.random.Generator) -> _SlowErrors:
    """Turbidity, IMU yaw error, gyro bias, odometry drift and the DVL heading offset (the
    random draws in that order, after the sensor stamps)."""
    turb = np.clip(1.0 + _smooth_noise(rng, tt, 40.0, 0.3), 0.55, 1.6)
    yaw_err = np.deg2rad(p.imu_yaw_drift_deg_per_min / 60.0 * tt
                         + np.cumsum(rng.normal(0, p.imu_yaw_rw_deg_per_sqrt_s * math.sqrt(tt[1] - tt[0]), len(tt))))
    gyro_bias = np.deg2rad(rng.normal(0, p.imu_gyro_bias_deg_s, 3))
    vel_err = np.stack([_smooth_noise(rng, tt, 30.0, p.odom_vel_walk_m_s) for _ in range(3)], axis=1)
    vel_err[:, 2] *= 0.2
    odom_err = np.cumsum(vel_err, axis=0) * (tt[1] - tt[0])
    dvl_heading_off = rng.normal(0, 3.0)
    return _SlowErrors(turb, yaw_err, gyro_bias, odom_err, dvl_heading_off)


def _mission_world(p: SimParams, duration: float, world: World | None) -> World:
    """The cave of the mission (``world`` when given, checked against the mission's world seed)."""
    if duration <= 0:
        raise ValueError(f"minutes must be > 0, got {p.minutes}")
    if p.start not in START_AREAS:
        raise ValueError(f"start must be one of {', '.join(START_AREAS)}, got {p.start!r}")
    if p.first_loops is not None and not 1 <= p.first_loops <= LOOPS_PER_AREA:
        raise ValueError(f"first_loops must be in [1, {LOOPS_PER_AREA}], got {p.first_loops}")
    world_seed = p.seed if p.world_seed is None else int(p.world_seed)
    world = world if world is not None else build_world(world_seed)
    if world.seed != world_seed:
        raise ValueError(f"the world given was built for seed {world.seed}, the mission asks for world_seed {world_seed}")
    return world


def _camera_frames(p: SimParams, world: World, traj: VehicleMotion,
                   cam_times: np.ndarray) -> tuple[dict[str, np.ndarray], list[np.ndarray]]:
    """The camera frames' vehicle states and their revisit ground truth (per frame: the earlier
    frames of the same place)."""
    cs = traj.at(cam_times)
    centres = footprint_centres(world, cs["pos"], cs["rpy"], np.asarray(p.camera.lever))
    same = revisits(centres, cs["pos"], cs["dist"], cs["rpy"][:, 2], p.revisit_radius_m, p.revisit_max_vehicle_m,
                    p.revisit_min_gap_m,
                    None if p.revisit_max_heading_deg is None else math.radians(p.revisit_max_heading_deg))
    return cs, same


def _write_chunk(out: _Out, p: SimParams, traj: VehicleMotion, world: World, st: _Streams, slow: _SlowErrors,
                 cam: tuple[_CameraRenderer, dict[str, np.ndarray], list[np.ndarray]], ci: int,
                 t0: float, t1: float, bar: Any) -> None:
    """Every stream's messages stamped in [t0, t1) s: chunk ``ci``, with its own random stream."""
    cam_r, cs, same = cam
    crng = np.random.default_rng([p.seed, 404, ci])

    def sel(a: np.ndarray) -> np.ndarray:
        return np.nonzero((a >= t0) & (a < t1))[0]

    _truth(out, traj, st.truth[sel(st.truth)])
    _imu(out, p, traj, st.imu[sel(st.imu)], slow.yaw_err, slow.gyro_bias, crng)
    _depth(out, p, traj, st.depth[sel(st.depth)], crng)
    _dvl(out, p, traj, world, st.dvl, sel(st.dvl), slow.dvl_heading_off, np.random.default_rng([p.seed, 505]), crng)
    _odom(out, p, traj, st.odom[sel(st.odom)], slow.odom_err, slow.yaw_err, crng)
    _micron(out, p, traj, world, st.micron, sel(st.micron), crng)
    _seaking(out, p, traj, world, st.seaking, sel(st.seaking), crng)
    for k in sel(st.cam):
        img = cam_r.render(cs["pos"][k], cs["rpy"][k], float(cs["altitude"][k]),
                           float(np.interp(st.cam[k], traj.t, slow.turbidity)), crng, p.seed * 1_000_003 + int(k))
        stamp = int(_ns(st.cam[k]))
        out.add("camera/image_raw", stamp, lambda h, img=img: Image(header=h, height=img.shape[0],
                                                                     width=img.shape[1], encoding="rgb8",
                                                                     data=img))
        out.add("truth/revisits", stamp, lambda h, k=k: RevisitTruth(header=h, frame_index=int(k),
                                                                     same_place=same[k].astype(np.int32)))
        bar.update(1)
    out.flush()


def _loops_flown(segs: list[dict[str, Any]]) -> dict[str, int]:
    """Complete loops flown per area."""
    loops: dict[str, int] = {}
    for s in segs:
        if s["complete"] and s["name"].startswith("area"):
            loops[s["name"]] = loops.get(s["name"], 0) + 1
    return loops


def generate(out_path: str | Path, params: SimParams, progress: bool = True,
             world: World | None = None, compression: str = "zstd") -> dict[str, Any]:
    """Write the mission to ``out_path`` (MCAP chunks in ``compression``: zstd, lz4, none);
    returns the summary (see :mod:`missions.sim.cli`)."""
    p = params
    duration = p.minutes * 60.0
    world = _mission_world(p, duration, world)
    traj = make_trajectory(world, duration, p.seed, p.speed_m_s, start=p.start, first_loops=p.first_loops)
    rng = np.random.default_rng([p.seed, 303])
    st = _all_stamps(p, duration, rng)
    slow = _slow_errors(p, traj.t, rng)
    cs, same = _camera_frames(p, world, traj, st.cam)
    segs = segments_of(traj, duration)

    cam = (_CameraRenderer(world, p.camera), cs, same)
    writer = RecordingWriter(out_path, compression=compression)
    out = _Out(writer)
    writer.add_metadata("poseidon", _metadata(p, duration, world, segs, slow.dvl_heading_off, slow.gyro_bias))

    nchunks = int(math.ceil(duration / p.chunk_s))
    bar = tqdm(total=len(st.cam), desc="sim frames", unit="frame", disable=not progress, file=None)
    try:
        for ci in range(nchunks):
            _write_chunk(out, p, traj, world, st, slow, cam, ci, ci * p.chunk_s, min((ci + 1) * p.chunk_s, duration),
                         bar)
    finally:
        bar.close()
        writer.close()
    return {
        "out": str(out_path), "seed": p.seed, "world_seed": world.seed, "start": p.start, "first_loops": p.first_loops or LOOPS_PER_AREA, "minutes": p.minutes, "duration_s": duration,
        "distance_m": round(float(np.interp(duration, traj.t, traj.dist)), 3),
        "counts": dict(sorted(writer.counts.items())), "frames": len(st.cam),
        "frames_with_revisits": int(sum(len(s) > 0 for s in same)), "loops": _loops_flown(segs), "segments": segs,
    }


# --------------------------------------------------------------------------- sensor streams


def _odometry_msg(h: Header, pos: np.ndarray, q: np.ndarray, vb: np.ndarray, wb: np.ndarray,
                  cov: list[float] | None = None) -> Odometry:
    return Odometry(header=h, child_frame_id="base_link", position=[float(x) for x in pos],
                    orientation=[float(x) for x in q], linear_velocity=[float(x) for x in vb],
                    angular_velocity=[float(x) for x in wb], **({"pose_covariance": cov} if cov else {}))


def _body_vel(s: dict[str, np.ndarray]) -> np.ndarray:
    r = rot_wb(s["rpy"][:, 0], s["rpy"][:, 1], s["rpy"][:, 2])
    out: np.ndarray = np.einsum("nji,nj->ni", r, s["vel_w"])
    return out


def _truth(out: _Out, traj: VehicleMotion, times: np.ndarray) -> None:
    if not len(times):
        return
    s = traj.at(times)
    q = quat_from_rpy(s["rpy"][:, 0], s["rpy"][:, 1], s["rpy"][:, 2])
    vb = _body_vel(s)
    for k, stamp in enumerate(_ns(times)):
        out.add("truth/pose", int(stamp), lambda h, k=k: _odometry_msg(h, s["pos"][k], q[k], vb[k], s["omega_b"][k]))


def _imu(out: _Out, p: SimParams, traj: VehicleMotion, times: np.ndarray, yaw_err: np.ndarray, gyro_bias: np.ndarray,
         rng: np.random.Generator) -> None:
    n = len(times)
    if not n:
        return
    s = traj.at(times)
    an = np.deg2rad(p.imu_att_noise_deg)
    roll = s["rpy"][:, 0] + rng.normal(0, an, n)
    pitch = s["rpy"][:, 1] + rng.normal(0, an, n)
    yaw = wrap_angle(s["rpy"][:, 2] + np.interp(times, traj.t, yaw_err) + rng.normal(0, an, n))
    q = quat_from_rpy(roll, pitch, yaw)
    gyro = s["omega_b"] + gyro_bias + rng.normal(0, np.deg2rad(p.imu_gyro_noise_deg_s), (n, 3))
    r = rot_wb(s["rpy"][:, 0], s["rpy"][:, 1], s["rpy"][:, 2])
    f_w = s["acc_w"] - np.array([0.0, 0.0, G])
    acc = np.einsum("nji,nj->ni", r, f_w) + rng.normal(0, p.imu_accel_noise_m_s2, (n, 3))
    mag = np.einsum("nji,nj->ni", r, np.tile([0.27, 0.0, 0.35], (n, 1))) + rng.normal(0, 0.002, (n, 3))
    for k, stamp in enumerate(_ns(times)):
        base = dict(roll=float(roll[k]), pitch=float(pitch[k]), yaw=float(yaw[k]), qx=float(q[k, 0]),
                    qy=float(q[k, 1]), qz=float(q[k, 2]), qw=float(q[k, 3]), ax=float(acc[k, 0]), ay=float(acc[k, 1]),
                    az=float(acc[k, 2]), gx=float(gyro[k, 0]), gy=float(gyro[k, 1]), gz=float(gyro[k, 2]))
        out.add("imu_adis", int(stamp), lambda h, base=base, k=k: Imu(
            header=h, temp=22.0, mx=float(mag[k, 0]), my=float(mag[k, 1]), mz=float(mag[k, 2]),
            bx=float(gyro_bias[0]), by=float(gyro_bias[1]), bz=float(gyro_bias[2]), **base))
        out.add("imu_adis_ros", int(stamp), lambda h, base=base: Imu(header=h, **base))


def _depth(out: _Out, p: SimParams, traj: VehicleMotion, times: np.ndarray, rng: np.random.Generator) -> None:
    if not len(times):
        return
    z = traj.at(times)["pos"][:, 2] + p.depth_bias_m + rng.normal(0, p.depth_noise_m, len(times))
    for k, stamp in enumerate(_ns(times)):
        out.add("depth_sensor", int(stamp), lambda h, d=float(z[k]): Depth(header=h, depth=d))


def _dvl_beams(incl_deg: float) -> np.ndarray:
    inc = math.radians(incl_deg)
    az = np.deg2rad([45.0, 135.0, 225.0, 315.0])
    return np.stack([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), np.full(4, np.cos(inc))], axis=1)


def _dvl(out: _Out, p: SimParams, traj: VehicleMotion, world: World, all_times: np.ndarray, idx: np.ndarray,
         heading_off: float, burst_rng: np.random.Generator, rng: np.random.Generator) -> None:
    """DVL samples ``idx`` of ``all_times``; dropout bursts are a Markov chain over all samples
    (drawn from ``burst_rng`` identically for every chunk, so the chain is continuous)."""
    if not len(idx):
        return
    n_all = len(all_times)
    start = burst_rng.random(n_all) < p.dvl_burst_start_p
    length = burst_rng.geometric(1.0 / p.dvl_burst_mean_samples, n_all)
    burst = np.zeros(n_all, bool)
    for i in np.nonzero(start)[0]:
        burst[i:i + length[i]] = True
    times = all_times[idx]
    n = len(times)
    s = traj.at(times)
    vb = _body_vel(s)
    beams = _dvl_beams(p.dvl_beam_inclination_deg)
    r = rot_wb(s["rpy"][:, 0], s["rpy"][:, 1], s["rpy"][:, 2])
    bw = np.einsum("nij,bj->nbi", r, beams)  # (n, 4, 3) beam directions in world
    alt_beam = np.empty((n, 4))
    for b in range(4):
        t_hit = s["altitude"] / np.maximum(bw[:, b, 2], 0.2)
        for _ in range(2):
            x = s["pos"][:, 0] + bw[:, b, 0] * t_hit
            y = s["pos"][:, 1] + bw[:, b, 1] * t_hit
            t_hit = (world.floor_at(x, y) - s["pos"][:, 2]) / np.maximum(bw[:, b, 2], 0.2)
        alt_beam[:, b] = t_hit
    good = rng.random((n, 4)) >= p.dvl_beam_dropout_p
    good &= ~burst[idx][:, None]
    vinst = vb * p.dvl_scale + np.asarray(p.dvl_bias_m_s) + rng.normal(0, p.dvl_noise_m_s, (n, 3))
    flag = good.sum(axis=1) >= 3
    vbeam = vb @ beams.T + rng.normal(0, p.dvl_noise_m_s, (n, 4))
    head = np.rad2deg(wrap_angle(s["rpy"][:, 2] + math.radians(heading_off))) + rng.normal(0, p.dvl_heading_noise_deg, n)
    hr = np.deg2rad(head)
    rr = rot_wb(s["rpy"][:, 0], s["rpy"][:, 1], hr)
    vearth = np.einsum("nij,nj->ni", rr, vinst)
    alt = s["altitude"] + rng.normal(0, 0.02, n)
    for k, stamp in enumerate(_ns(times)):
        ok = bool(flag[k])
        msg_kw = dict(
            errcode="", datagood=[int(g) for g in good[k]],
            altitudebeam=[round(float(a), 2) if g else 0.0 for a, g in zip(alt_beam[k], good[k])],
            bottomvelocitybeam=[float(v) if g else 0.0 for v, g in zip(vbeam[k], good[k])],
            watervelocitybeam=[0.0] * 4, watervelocitycredit=[0.0] * 4,
            velocityinst=[float(v) for v in vinst[k]] if ok else [0.0] * 3, velocityinstflag=int(ok),
            velocityearth=[float(v) for v in vearth[k]] if ok else [0.0] * 3, velocityearthflag=int(ok),
            watervelocityinst=[0.0] * 3, watervelocityinstflag=0, watervelocityearth=[0.0] * 3,
            watervelocityearthflag=0, roll=float(np.rad2deg(s["rpy"][k, 0])), pitch=float(np.rad2deg(s["rpy"][k, 1])),
            heading=float(head[k] % 360.0), altitude=float(alt[k]) if good[k].any() else 0.0, temperature=15.0,
            pressure=float(101325.0 + 1025.0 * G * s["pos"][k, 2]), salinity=35.0, soundspeed=1500.0, rawdata="")
        out.add("dvl_linkquest", int(stamp), lambda h, kw=msg_kw: LinkquestDvl(header=h, **kw))


def _odom(out: _Out, p: SimParams, traj: VehicleMotion, times: np.ndarray, odom_err: np.ndarray, yaw_err: np.ndarray,
          rng: np.random.Generator) -> None:
    n = len(times)
    if not n:
        return
    s = traj.at(times)
    err = np.stack([np.interp(times, traj.t, odom_err[:, k]) for k in range(3)], axis=1)
    pos = s["pos"] + err
    yaw = wrap_angle(s["rpy"][:, 2] + 0.5 * np.interp(times, traj.t, yaw_err))
    q = quat_from_rpy(s["rpy"][:, 0], s["rpy"][:, 1], yaw)
    vb = _body_vel(s) + rng.normal(0, 0.01, (n, 3))
    cov = [0.0] * 36
    for i, v in enumerate((0.05, 0.05, 0.01, 0.001, 0.001, 0.01)):
        cov[i * 7] = v
    for k, stamp in enumerate(_ns(times)):
        out.add("odometry", int(stamp), lambda h, k=k: _odometry_msg(h, pos[k], q[k], vb[k], s["omega_b"][k], cov))


def _micron(out: _Out, p: SimParams, traj: VehicleMotion, world: World, all_times: np.ndarray, idx: np.ndarray,
            rng: np.random.Generator) -> None:
    if not len(idx):
        return
    times = all_times[idx]
    n = len(times)
    s = traj.at(times)
    head = np.deg2rad((idx * p.micron_step_deg) % 360.0)
    beam = np.zeros((n, p.micron_nbins), np.int32)
    render.micron_beams(beam, s["pos"], s["rpy"][:, 2] + head, s["altitude"], float(p.micron_range_m), world.free,
                        world.grid_x0, world.grid_y0, world.grid_res,
                        rng.exponential(1.0, (n, p.micron_nbins)), rng.normal(0, 2.0, (n, p.micron_nbins)))
    _beam_msgs(out, "sonar_micron", times, head, beam, p.micron_range_m, p.micron_step_deg, p.micron_rate_hz)


def _seaking(out: _Out, p: SimParams, traj: VehicleMotion, world: World, all_times: np.ndarray, idx: np.ndarray,
             rng: np.random.Generator) -> None:
    if not len(idx):
        return
    times = all_times[idx]
    n = len(times)
    s = traj.at(times)
    head = np.deg2rad((idx * p.seaking_step_deg) % 360.0)
    d_b = np.stack([np.zeros(n), np.cos(head), np.sin(head)], axis=1)
    r = rot_wb(s["rpy"][:, 0], s["rpy"][:, 1], s["rpy"][:, 2])
    d_w = np.einsum("nij,nj->ni", r, d_b)
    beam = np.zeros((n, p.seaking_nbins), np.int32)
    render.seaking_beams(beam, s["pos"], d_w, float(p.seaking_range_m), world.free, world.floor, world.ceiling,
                         world.grid_x0, world.grid_y0, world.grid_res,
                         rng.exponential(1.0, (n, p.seaking_nbins)), rng.normal(0, 2.0, (n, p.seaking_nbins)))
    _beam_msgs(out, "sonar_seaking", times, head, beam, p.seaking_range_m, p.seaking_step_deg, p.seaking_rate_hz)


def _beam_msgs(out: _Out, key: str, times: np.ndarray, head: np.ndarray, beam: np.ndarray, max_range: int,
               step_deg: float, rate: float) -> None:
    nbins = beam.shape[1]
    ranges = ((np.arange(nbins) + 0.5) * max_range / nbins).astype(np.float32)
    inc = math.radians(step_deg)
    for k, stamp in enumerate(_ns(times)):
        a = float(head[k])
        out.add(key, int(stamp), lambda h, a=a, k=k: RangeImageBeam(
            header=h, angle_grad=a * 200.0 / math.pi, angle_rad=a, nbins=nbins, max_range=max_range,
            beam_data=beam[k]))
        out.add(key + "_ros", int(stamp), lambda h, a=a, k=k: LaserScan(
            header=h, angle_min=a, angle_max=a, angle_increment=inc, time_increment=0.0, scan_time=1.0 / rate,
            range_min=0.0, range_max=float(max_range), ranges=ranges, intensities=beam[k].astype(np.float32)))
