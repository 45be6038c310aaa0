"""Rotations, Euler angles and the published-frame convention of ``robot_state``.

Conventions (used everywhere in :mod:`services.robot_state`):

- World frame **NED** (x north, y east, z down, metres; origin = horizontal start position,
  z = depth below the surface).  Body frame **FRD** (x forward, y starboard, z down).
- Attitude = ZYX Euler angles (roll phi, pitch theta, yaw psi) in radians,
  ``R = Rz(psi) Ry(theta) Rx(phi)`` maps body vectors to world vectors (Eq. 3.10 of the
  dissertation, DolphinSLAM's ``R(phi, theta, psi)``).
- Sensor extrinsics ``*_rotation_rpy_deg`` are the ZYX Euler angles (degrees) of the sensor
  frame in the body frame: ``v_body = R_bs v_sensor``.

Published frame (:class:`OutputFrame`): Table 4.1's ``axis_remap`` / ``axis_sign_z``
("dead-reckoning frame alignment", default ``yxz``, ``-1``) is applied to what the node
publishes, never inside the filter: ``out[i] = ned[axis_remap[i]]`` and then
``out[2] *= axis_sign_z``.  With the defaults this is NED -> **ENU** (x east, y north,
z up), the ROS world convention the dissertation's back-end consumes (Eq. 4.15 differences
the published positions).  The published orientation is that of a body frame whose y and z
axes are scaled by ``axis_sign_z`` (FRD -> FLU when z flips), so roll, pitch and yaw
extracted from the quaternion keep their usual meaning in the published frame (ENU yaw =
pi/2 - NED yaw, counter-clockwise from east).  ``axis_remap=xyz``, ``axis_sign_z=1``
publishes NED/FRD unchanged.  The remap must be a proper rotation (det +1).
"""
from __future__ import annotations

import math

import numpy as np

from common.config import ConfigError
from common.geometry import quaternion_to_matrix

__all__ = ["rot_x", "rot_y", "rot_z", "euler_to_matrix", "euler_to_world_rate", "matrix_to_euler", "matrix_to_quaternion",
           "quaternion_to_matrix", "wrap_angle", "OutputFrame"]


def wrap_angle(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body->world rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (Eq. 3.10), closed form."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    sy, cy = math.sin(yaw), math.cos(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def euler_to_world_rate(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """T(e): ZYX Euler angle rates -> world-frame angular velocity (columns: the axes of
    roll, pitch and yaw expressed in the world frame)."""
    sp, cp = math.sin(pitch), math.cos(pitch)
    sy, cy = math.sin(yaw), math.cos(yaw)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


def matrix_to_euler(r: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) of a rotation matrix; yaw in [-pi, pi]."""
    pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
    roll = math.atan2(float(r[2, 1]), float(r[2, 2]))
    yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
    return roll, pitch, yaw


def matrix_to_quaternion(r: np.ndarray) -> list[float]:
    """Unit quaternion ``[x, y, z, w]`` (w >= 0) of a rotation matrix."""
    m = r
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w], dtype=float)
    q /= np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    return [float(v) for v in q]




class OutputFrame:
    """The published frame: NED/FRD remapped by ``axis_remap`` and ``axis_sign_z``."""

    def __init__(self, axis_remap: str = "yxz", axis_sign_z: float = -1.0):
        if sorted(axis_remap) != ["x", "y", "z"]:
            raise ConfigError(f"robot_state.axis_remap must be a permutation of 'xyz', got {axis_remap!r}")
        if axis_sign_z not in (1.0, -1.0):
            raise ConfigError(f"robot_state.axis_sign_z must be 1 or -1, got {axis_sign_z!r}")
        m = np.zeros((3, 3))
        for i, c in enumerate(axis_remap):
            m[i, "xyz".index(c)] = 1.0
        m[2, :] *= axis_sign_z
        if np.linalg.det(m) < 0:
            raise ConfigError(f"robot_state.axis_remap={axis_remap!r} with axis_sign_z={axis_sign_z} is a "
                              "reflection (det -1); the published frame must be right-handed")
        self.axis_remap = axis_remap
        self.axis_sign_z = float(axis_sign_z)
        self.m = m  # world NED -> published world
        self.b = np.diag([1.0, axis_sign_z, axis_sign_z])  # published body -> FRD body (its own inverse)
        if axis_remap == "xyz" and axis_sign_z == 1.0:
            self.name = "ned"
        elif axis_remap == "yxz" and axis_sign_z == -1.0:
            self.name = "enu"
        else:
            self.name = f"remap_{axis_remap}_{'m' if axis_sign_z < 0 else 'p'}z"

    @property
    def identity(self) -> bool:
        return self.name == "ned"

    def position(self, p_ned: np.ndarray) -> np.ndarray:
        return self.m @ p_ned

    def position_to_ned(self, p_out: np.ndarray) -> np.ndarray:
        return self.m.T @ p_out

    def rotation(self, r_ned_frd: np.ndarray) -> np.ndarray:
        """Published body->world rotation of an NED/FRD one."""
        return self.m @ r_ned_frd @ self.b

    def rotation_to_ned(self, r_out: np.ndarray) -> np.ndarray:
        return self.m.T @ r_out @ self.b

    def euler_jacobian(self, roll: float, pitch: float, yaw: float) -> np.ndarray:
        """d(published Euler)/d(NED Euler) at an attitude.

        A small change de turns the NED attitude by the world rotation vector T(e) de; the
        published attitude turns by M T(e) de (M proper), i.e. de_out = T(e_out)^-1 M T(e) de.
        """
        if self.identity:
            return np.eye(3)
        e_out = matrix_to_euler(self.rotation(euler_to_matrix(roll, pitch, yaw)))
        return np.linalg.solve(euler_to_world_rate(*e_out), self.m @ euler_to_world_rate(roll, pitch, yaw))
