"""Numba kernels of the dead-reckoning EKF (:mod:`services.robot_state.filter`): the prediction
step and the restricted-gain Kalman update on the 15-state filter, in place.

Why kernels (issue 21): at 50 Hz of IMU, DVL and depth input the filter's arithmetic is a few
15 x 15 products per record, and numpy's per-call overhead on such small matrices was most of
robot_state's CPU (cProfile over a 3-min sim mission: the prediction 0.61 s, the update 0.31 s
of 1.66 s).  The kernels do the same operations in the same order as the numpy code they
replace (the filter's module notes give the model): the process Jacobian F and the noise
diagonal Q built per step, ``P = F P F' + Q``, the Joseph-form update with the gain zeroed
outside the updated states, each covariance symmetrised as ``(P + P') / 2``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.geometry import euler_to_matrix, wrap_angle

__all__ = ["euler_rate_matrix", "euler_rate_jacobian", "rotation_jacobian_times", "predict", "restricted_update"]

N_STATE = 15
_rotation = njit(cache=True)(euler_to_matrix)     # Eq. 3.10, the same closed form as common.geometry's
_wrap = njit(cache=True)(wrap_angle)


@njit(cache=True)
def euler_rate_matrix(roll: float, pitch: float) -> np.ndarray:
    """E(phi, theta): body rates -> ZYX Euler angle rates (Eq. 3.11)."""
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    cp = math.copysign(max(abs(cp), 1e-3), cp)
    tp = math.sin(pitch) / cp
    return np.array([[1.0, sr * tp, cr * tp], [0.0, cr, -sr], [0.0, sr / cp, cr / cp]])


@njit(cache=True)
def euler_rate_jacobian(roll: float, pitch: float, w: np.ndarray) -> np.ndarray:
    """d(E(e) w)/de (3x3; the yaw column is zero)."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    cp = math.copysign(max(abs(cp), 1e-3), cp)
    tp = sp / cp
    q, r = float(w[1]), float(w[2])
    j = np.zeros((3, 3))
    j[0, 0] = cr * tp * q - sr * tp * r
    j[1, 0] = -sr * q - cr * r
    j[2, 0] = (cr * q - sr * r) / cp
    j[0, 1] = (sr * q + cr * r) / (cp * cp)
    j[2, 1] = (sr * q + cr * r) * sp / (cp * cp)
    return j


@njit(cache=True)
def rotation_jacobian_times(e: np.ndarray, v: np.ndarray) -> np.ndarray:
    """d(R(e) v)/de (3x3), closed form of dR/droll v, dR/dpitch v, dR/dyaw v (R = Rz Ry Rx)."""
    sr, cr = math.sin(e[0]), math.cos(e[0])
    sp, cp = math.sin(e[1]), math.cos(e[1])
    sy, cy = math.sin(e[2]), math.cos(e[2])
    vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
    a1, a2 = cr * vy - sr * vz, sr * vy + cr * vz      # Rx v (y, z)
    dr1, dr2 = -sr * vy - cr * vz, cr * vy - sr * vz   # dRx/droll v (y, z)
    b0 = cp * vx + sp * a2                              # (Ry Rx v).x; y = a1
    x0, y0, z0 = sp * dr2, dr1, cp * dr2                # d/droll: Rz Ry (0, dr1, dr2)
    x1, z1 = -sp * vx + cp * a2, -cp * vx - sp * a2     # d/dpitch: Rz dRy (vx, a1, a2)
    return np.array([[cy * x0 - sy * y0, cy * x1, -sy * b0 - cy * a1],
                     [sy * x0 + cy * y0, sy * x1, cy * b0 - sy * a1],
                     [z0, z1, 0.0]])


@njit(cache=True)
def _symmetrise_into(src: np.ndarray, dst: np.ndarray) -> None:
    """dst = (src + src') / 2, entry by entry as (src[i, j] + src[j, i]) * 0.5."""
    n = src.shape[0]
    for i in range(n):
        for j in range(n):
            dst[i, j] = (src[i, j] + src[j, i]) * 0.5


@njit(cache=True)
def predict(x: np.ndarray, P: np.ndarray, gyro: np.ndarray, dt: float, a: float, g: float, qv: float,
            gyro_on: bool, integrate: bool, z_moves: bool, q_att: float, q_z: float, q_bimu: float, q_dimu: float,
            q_bg: float) -> None:
    """One prediction step of ``dt`` s, in place on the state ``x`` and covariance ``P``.

    ``p += R(e) v g`` (Eqs. 3.10-3.11; g = dt, or the dropout decay's integral), ``v *= a``,
    ``e += E(e) (w - b_g) dt`` while the gyro is fresh (``gyro_on``), ``b_imu += d_imu dt``;
    ``P = F P F' + diag(Q)`` with the analytic Jacobian F.  ``integrate``: the filter is
    initialised (the position moves); ``z_moves``: depth is fresh (else z is held).  The
    process noise: ``qv`` on v, ``q_att`` on e, ``q_z`` on a held z, ``q_bimu``/``q_dimu`` on the
    IMU yaw error and its rate, ``q_bg`` on each gyro bias (variances over this step)."""
    e = x[6:9].copy()
    v = x[3:6].copy()
    w = gyro - x[11:14] if gyro_on else np.zeros(3)
    F = np.eye(N_STATE)
    dp = np.zeros(3)
    if integrate:
        r = _rotation(e[0], e[1], e[2])
        dp = r @ v * g
        F[0:3, 3:6] = r * g
        F[0:3, 6:9] = rotation_jacobian_times(e, v) * g
        if not z_moves:
            dp[2] = 0.0
            F[2, 3:9] = 0.0
    if a != 1.0:
        F[3:6, 3:6] *= a
    rate = np.zeros((3, 3))
    if gyro_on:
        rate = euler_rate_matrix(e[0], e[1])
        F[6:9, 6:9] += euler_rate_jacobian(e[0], e[1], w) * dt
        F[6:9, 11:14] = -rate * dt
    F[9, 14] = dt
    out = F @ P @ F.T
    for k in range(3, 6):
        out[k, k] += qv
    for k in range(6, 9):
        out[k, k] += q_att
    out[2, 2] += q_z
    out[9, 9] += q_bimu
    out[14, 14] += q_dimu
    for k in range(11, 14):
        out[k, k] += q_bg
    x[0:3] += dp
    if a != 1.0:
        x[3:6] = v * a
    x[9] += x[14] * dt
    if gyro_on:
        x[6:9] = e + rate @ w * dt
        x[8] = _wrap(x[8])
    _symmetrise_into(out, P)


@njit(cache=True)
def restricted_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, y: np.ndarray, R: np.ndarray,
                      keep: np.ndarray) -> None:
    """Kalman update with innovation ``y`` of the measurement ``H x`` (noise ``R``), the gain
    zeroed outside the states ``keep`` (bool, N_STATE), the Joseph form
    ``P = (I - K H) P (I - K H)' + K R K'`` (consistent for any gain); in place."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    for i in range(N_STATE):
        if not keep[i]:
            K[i, :] = 0.0
    x += K @ y
    ikh = np.eye(N_STATE) - K @ H
    _symmetrise_into(ikh @ P @ ikh.T + K @ R @ K.T, P)
