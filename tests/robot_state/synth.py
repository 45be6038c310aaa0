"""Synthetic, noise-free sensor streams for the robot_state tests (built in the tests)."""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from common.messages import Depth, Header, Imu, LinkquestDvl, Message, Odometry

NS = 1_000_000_000
T0 = 1_700_000_000 * NS  # an epoch stamp on the 10 Hz grid


def dvl(stamp: int, seq: int, v_inst, flag: int = 1, good=(1, 1, 1, 1), rpy_deg=(0.0, 0.0, 0.0)) -> LinkquestDvl:
    z4 = [0.0] * 4
    return LinkquestDvl(
        header=Header(seq=seq, stamp=stamp), datagood=list(good), altitudebeam=[3.0] * 4,
        bottomvelocitybeam=z4, watervelocitybeam=z4, watervelocitycredit=z4,
        velocityinst=[float(v) for v in v_inst], velocityinstflag=flag, velocityearth=[0.0] * 3,
        velocityearthflag=0, watervelocityinst=[0.0] * 3, watervelocityinstflag=0,
        watervelocityearth=[0.0] * 3, watervelocityearthflag=0,
        roll=float(rpy_deg[0]), pitch=float(rpy_deg[1]), heading=float(rpy_deg[2]),
        altitude=3.0, temperature=15.0, pressure=0.0, salinity=0.0, soundspeed=1500.0)


def imu(stamp: int, seq: int, rpy, gyro) -> Imu:
    return Imu(header=Header(seq=seq, stamp=stamp), roll=float(rpy[0]), pitch=float(rpy[1]), yaw=float(rpy[2]),
               qx=0.0, qy=0.0, qz=0.0, qw=1.0, gx=float(gyro[0]), gy=float(gyro[1]), gz=float(gyro[2]))


def depth(stamp: int, seq: int, d: float) -> Depth:
    return Depth(header=Header(seq=seq, stamp=stamp), depth=float(d))


def odom(stamp: int, seq: int, p) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=stamp, frame_id="world"), position=list(p),
                    orientation=[0.0, 0.0, 0.0, 1.0])


def mission(duration_s: float,
            body_velocity: Callable[[float], tuple[float, float, float]],
            attitude: Callable[[float], tuple[float, float, float]],
            rates: Callable[[float], tuple[float, float, float]],
            depth_of: Callable[[float], float],
            dvl_hz: float = 5.0, imu_hz: float = 20.0, depth_hz: float = 10.0,
            with_imu: bool = True, dvl_attitude: bool = False,
            dvl_velocity: Callable[[float], tuple[float, float, float]] | None = None,
            imu_key: str = "imu_adis_ros") -> list[tuple[str, Message]]:
    """Streams sampled from analytic functions of time (s since T0), stamps in ns."""
    out: list[tuple[str, Message]] = []
    vel = dvl_velocity or body_velocity
    for k in range(int(duration_s * dvl_hz) + 1):
        t = k / dvl_hz
        rpy = tuple(math.degrees(a) for a in attitude(t)) if dvl_attitude else (0.0, 0.0, 0.0)
        out.append(("dvl_linkquest", dvl(T0 + int(round(t * NS)), k, vel(t), rpy_deg=rpy)))
    if with_imu:
        for k in range(int(duration_s * imu_hz) + 1):
            t = k / imu_hz
            out.append((imu_key, imu(T0 + int(round(t * NS)), k, attitude(t), rates(t))))
    for k in range(int(duration_s * depth_hz) + 1):
        t = k / depth_hz
        out.append(("depth_sensor", depth(T0 + int(round(t * NS)), k, depth_of(t))))
    return out


def odometry_positions(outputs, key: str = "Odometry") -> tuple[np.ndarray, np.ndarray]:
    """(stamps s since T0, positions Nx3) of the published key."""
    rows = [(m.header.stamp, m.position) for k, m in outputs if k == key]
    t = np.array([(s - T0) / NS for s, _ in rows])
    p = np.array([p for _, p in rows], dtype=float)
    return t, p
