"""Frame conventions, rotations and angle helpers shared by the services and ``eval``.

Conventions:

- World frame **NED** (x north, y east, z down, metres; origin = horizontal start position,
  z = depth below the surface).  Body frame **FRD** (x forward, y starboard, z down).
- Attitude = ZYX Euler angles (roll phi, pitch theta, yaw psi) in radians,
  ``R = Rz(psi) Ry(theta) Rx(phi)`` maps body vectors to world vectors (Eq. 3.10 of the
  dissertation, DolphinSLAM's ``R(phi, theta, psi)``).
- Quaternions are ``[x, y, z, w]``, body -> world (as in ``Odometry``).
- Sensor extrinsics ``*_rotation_rpy_deg`` are the ZYX Euler angles (degrees) of the sensor
  frame in the body frame: ``v_body = R_bs v_sensor``.
- Angles are wrapped to **[-pi, pi)** by :func:`wrap_angle` (``-pi`` is kept, ``+pi`` maps
  to ``-pi``).

Published frame (:class:`OutputFrame`): Table 4.1's ``axis_remap`` / ``axis_sign_z``
("dead-reckoning frame alignment", default ``yxz``, ``-1``) is applied to what
``robot_state`` publishes, never inside its filter: ``out[i] = ned[axis_remap[i]]`` and then
``out[2] *= axis_sign_z``.  With the defaults this is NED -> **ENU** (x east, y north,
z up), the ROS world convention the back-end consumes (Eq. 4.15 differences the published
positions).  The published orientation is that of a body frame whose y and z axes are
scaled by ``axis_sign_z`` (FRD -> FLU when z flips), so roll, pitch and yaw extracted from
the quaternion keep their usual meaning in the published frame (ENU yaw = pi/2 - NED yaw,
counter-clockwise from east).  ``axis_remap=xyz``, ``axis_sign_z=1`` publishes NED/FRD
unchanged.  The remap must be a proper rotation (det +1).  Everything built on the
published ``Odometry`` (the experience map, ``experience_event.odom_position``) is in the
same published frame; :func:`published_to_ned` takes it back to NED.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from common.config import ConfigError

__all__ = ["TWO_PI", "wrap_angle", "wrap_angles", "yaw_of_quaternion", "yaws_of_quaternions", "quaternion_of_yaw",
           "normalise_quaternions", "slerp", "quat_multiply", "quaternion_to_matrix", "matrix_to_quaternion",
           "rot_x", "rot_y", "rot_z", "euler_to_matrix", "euler_to_world_rate", "matrix_to_euler",
           "enu_to_ned", "ned_to_enu", "yaw_enu_to_ned", "published_to_ned", "OutputFrame"]

TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------- angles


def wrap_angle(a: Any) -> Any:
    """Angle(s) (rad) wrapped to [-pi, pi): a float for a float, an array for an array."""
    return (a + math.pi) % TWO_PI - math.pi


def wrap_angles(a: Any) -> np.ndarray:
    """Angles (rad, any array-like) wrapped to [-pi, pi), as a float array."""
    return np.asarray(wrap_angle(np.asarray(a, dtype=float)))


def yaw_of_quaternion(q: list[float] | np.ndarray) -> float:
    """Yaw (rad, about z, the ZYX yaw, in [-pi, pi]) of a unit quaternion ``[x, y, z, w]``."""
    x, y, z, w = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def yaws_of_quaternions(q: np.ndarray) -> np.ndarray:
    """Yaw (rad, in [-pi, pi]) of unit quaternions (..., 4) ``[x, y, z, w]`` (the ZYX yaw)."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.asarray(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def quaternion_of_yaw(yaw: float) -> list[float]:
    """Quaternion ``[x, y, z, w]`` of a rotation by ``yaw`` (rad) about z (w >= 0 for |yaw| <= pi)."""
    return [0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)]


# --------------------------------------------------------------------------- quaternions and rotations


def normalise_quaternions(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) scaled to unit norm (ValueError for a zero one)."""
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(~(n > 0)):
        raise ValueError("quaternion of zero norm")
    return np.asarray(q / n)


def slerp(q0: np.ndarray, q1: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (n, 4) at fractions f (n,), shortest arc."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float).copy()
    f = np.asarray(f, dtype=float)[:, None]
    d = np.sum(q0 * q1, axis=1)
    q1[d < 0] *= -1.0
    d = np.abs(d)[:, None]
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s[:, 0] < 1e-9
    w0 = np.where(small[:, None], 1.0 - f, np.sin((1.0 - f) * theta) / np.where(small[:, None], 1.0, s))
    w1 = np.where(small[:, None], f, np.sin(f * theta) / np.where(small[:, None], 1.0, s))
    return normalise_quaternions(w0 * q0 + w1 * q1)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of quaternions (..., 4) ``[x, y, z, w]``."""
    ax, ay, az, aw = (a[..., k] for k in range(4))
    bx, by, bz, bw = (b[..., k] for k in range(4))
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def quaternion_to_matrix(q: list[float] | np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion ``[x, y, z, w]`` (normalised first; ValueError if zero)."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0.0:
        raise ValueError(f"quaternion {list(q)} has zero norm")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


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


def rot_x(a: float) -> np.ndarray:
    """Rotation by ``a`` (rad) about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` (rad) about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` (rad) about z."""
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


# --------------------------------------------------------------------------- frames


def enu_to_ned(p: np.ndarray) -> np.ndarray:
    """ENU (x east, y north, z up) positions (..., 3) -> NED (x north, y east, z down)."""
    p = np.asarray(p, dtype=float)
    return np.stack([p[..., 1], p[..., 0], -p[..., 2]], axis=-1)


def ned_to_enu(p: np.ndarray) -> np.ndarray:
    """NED positions (..., 3) -> ENU (the same swap; the map is its own inverse)."""
    return enu_to_ned(p)


def yaw_enu_to_ned(yaw: float | np.ndarray) -> float | np.ndarray:
    """ENU yaw (counter-clockwise from east) -> NED yaw (clockwise from north), rad; self-inverse."""
    return np.pi / 2 - yaw


class OutputFrame:
    """The published frame: NED/FRD remapped by ``axis_remap`` and ``axis_sign_z`` (module docstring).

    :raises ConfigError: ``axis_remap`` not a permutation of ``xyz``, ``axis_sign_z`` not +-1,
        or the pair a reflection.
    """

    def __init__(self, axis_remap: str = "yxz", axis_sign_z: float = -1.0) -> None:
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
        """True when the published frame is NED/FRD itself."""
        return self.name == "ned"

    def position(self, p_ned: np.ndarray) -> np.ndarray:
        """Published position of an NED one (m)."""
        return np.asarray(self.m @ p_ned)

    def position_to_ned(self, p_out: np.ndarray) -> np.ndarray:
        """NED position of a published one (m)."""
        return np.asarray(self.m.T @ p_out)

    def rotation(self, r_ned_frd: np.ndarray) -> np.ndarray:
        """Published body->world rotation of an NED/FRD one."""
        return np.asarray(self.m @ r_ned_frd @ self.b)

    def rotation_to_ned(self, r_out: np.ndarray) -> np.ndarray:
        """NED/FRD body->world rotation of a published one."""
        return np.asarray(self.m.T @ r_out @ self.b)

    def euler_jacobian(self, roll: float, pitch: float, yaw: float) -> np.ndarray:
        """d(published Euler)/d(NED Euler) at an attitude.

        A small change de turns the NED attitude by the world rotation vector T(e) de; the
        published attitude turns by M T(e) de (M proper), i.e. de_out = T(e_out)^-1 M T(e) de.
        """
        if self.identity:
            return np.eye(3)
        e_out = matrix_to_euler(self.rotation(euler_to_matrix(roll, pitch, yaw)))
        return np.linalg.solve(euler_to_world_rate(*e_out), self.m @ euler_to_world_rate(roll, pitch, yaw))


def published_to_ned(p: np.ndarray, axis_remap: str = "yxz", axis_sign_z: float = -1.0) -> np.ndarray:
    """Positions (..., 3) in ``robot_state``'s published frame -> NED (m): the inverse of
    :class:`OutputFrame`'s position remap."""
    m = OutputFrame(axis_remap, axis_sign_z).m  # NED -> published, orthogonal
    return np.asarray(p, dtype=float) @ m
