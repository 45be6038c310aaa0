"""Numba kernels of the dead-reckoning EKF (:mod:`services.robot_state.filter`): the prediction
step and the restricted-gain Kalman update on the 15-state filter, in place.

Why kernels: at 50 Hz of IMU, DVL and depth input the filter's arithmetic is a few
15 x 15 products per record, and numpy's per-call overhead on such small matrices was most of
robot_state's CPU (cProfile over a 3-min sim mission: the prediction 0.61 s, the update 0.31 s
of 1.66 s).  The kernels compute what that numpy code did (the filter's module notes give the
model): the process Jacobian F and the noise diagonal Q built per step, ``P = F P F' + Q``, the
Joseph-form update with the gain zeroed outside the updated states, each covariance
symmetrised as ``(P + P') / 2``; only the order of the sums differs (on a 3-min sim mission the
positions agree to 5e-15 m).  They are written in scalar loops: numba's slice arithmetic and
BLAS products took ~28 s to compile on a cold cache, the loops ~8 s.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.geometry import wrap_angle

__all__ = ["rotation", "euler_rate_matrix", "euler_rate_jacobian", "rotation_jacobian_times", "predict",
           "restricted_update"]

N_STATE = 15
_wrap = njit(cache=True)(wrap_angle)
# (3 x 3 results are filled entry by entry: numba compiles np.array of nested lists slowly, ~20 s)


@njit(cache=True)
def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body->world rotation Rz(yaw) Ry(pitch) Rx(roll) (Eq. 3.10; common.geometry.euler_to_matrix)."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    sy, cy = math.sin(yaw), math.cos(yaw)
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    r[1, 0], r[1, 1], r[1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    r[2, 0], r[2, 1], r[2, 2] = -sp, cp * sr, cp * cr
    return r


@njit(cache=True)
def euler_rate_matrix(roll: float, pitch: float) -> np.ndarray:
    """E(phi, theta): body rates -> ZYX Euler angle rates (Eq. 3.11)."""
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    cp = math.copysign(max(abs(cp), 1e-3), cp)
    tp = math.sin(pitch) / cp
    e = np.empty((3, 3))
    e[0, 0], e[0, 1], e[0, 2] = 1.0, sr * tp, cr * tp
    e[1, 0], e[1, 1], e[1, 2] = 0.0, cr, -sr
    e[2, 0], e[2, 1], e[2, 2] = 0.0, sr / cp, cr / cp
    return e


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
    j = np.empty((3, 3))
    j[0, 0], j[0, 1], j[0, 2] = cy * x0 - sy * y0, cy * x1, -sy * b0 - cy * a1
    j[1, 0], j[1, 1], j[1, 2] = sy * x0 + cy * y0, sy * x1, cy * b0 - sy * a1
    j[2, 0], j[2, 1], j[2, 2] = z0, z1, 0.0
    return j


@njit(cache=True)
def _symmetrise_into(src: np.ndarray, dst: np.ndarray) -> None:
    """dst = (src + src') / 2, entry by entry as (src[i, j] + src[j, i]) * 0.5."""
    n = src.shape[0]
    for i in range(n):
        for j in range(n):
            dst[i, j] = (src[i, j] + src[j, i]) * 0.5


@njit(cache=True)
def _ff_t(F: np.ndarray, P: np.ndarray) -> np.ndarray:
    """F P F' (n x n) by loops: numba's BLAS matmul costs seconds of compilation per signature."""
    n = P.shape[0]
    fp = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            f = F[i, k]
            if f != 0.0:
                for j in range(n):
                    fp[i, j] += f * P[k, j]
    return _mul_bt(fp, F)


@njit(cache=True)
def _mul_bt(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A B' by loops (each entry summed from 0 in index order; see _ff_t)."""
    out = np.empty((A.shape[0], B.shape[0]))
    for i in range(A.shape[0]):
        for j in range(B.shape[0]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[j, k]
            out[i, j] = acc
    return out


@njit(cache=True)
def _mv(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """m v (3 x 3 by 3)."""
    out = np.zeros(3)
    for i in range(3):
        out[i] = m[i, 0] * v[0] + m[i, 1] * v[1] + m[i, 2] * v[2]
    return out


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
    # (scalar loops throughout: numba compiles slice arithmetic on arrays several times slower)
    e = np.empty(3)
    v = np.empty(3)
    w = np.zeros(3)
    for i in range(3):
        e[i] = x[6 + i]
        v[i] = x[3 + i]
        if gyro_on:
            w[i] = gyro[i] - x[11 + i]
    F = np.eye(N_STATE)
    dp = np.zeros(3)
    if integrate:
        r = rotation(e[0], e[1], e[2])
        dp = _mv(r, v)
        jr = rotation_jacobian_times(e, v)
        for i in range(3):
            dp[i] *= g
            for j in range(3):
                F[i, 3 + j] = r[i, j] * g
                F[i, 6 + j] = jr[i, j] * g
        if not z_moves:
            dp[2] = 0.0
            for j in range(3, 9):
                F[2, j] = 0.0
    if a != 1.0:
        for i in range(3, 6):
            for j in range(3, 6):
                F[i, j] *= a
    rate = np.zeros((3, 3))
    if gyro_on:
        rate = euler_rate_matrix(e[0], e[1])
        je = euler_rate_jacobian(e[0], e[1], w)
        for i in range(3):
            for j in range(3):
                F[6 + i, 6 + j] += je[i, j] * dt
                F[6 + i, 11 + j] = -rate[i, j] * dt
    F[9, 14] = dt
    out = _ff_t(F, P)
    for k in range(3, 6):
        out[k, k] += qv
    for k in range(6, 9):
        out[k, k] += q_att
    out[2, 2] += q_z
    out[9, 9] += q_bimu
    out[14, 14] += q_dimu
    for k in range(11, 14):
        out[k, k] += q_bg
    for i in range(3):
        x[i] += dp[i]
        if a != 1.0:
            x[3 + i] = v[i] * a
    x[9] += x[14] * dt
    if gyro_on:
        de = _mv(rate, w)
        for i in range(3):
            x[6 + i] = e[i] + de[i] * dt
        x[8] = _wrap(x[8])
    _symmetrise_into(out, P)


@njit(cache=True)
def restricted_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, y: np.ndarray, R: np.ndarray,
                      keep: np.ndarray) -> None:
    """Kalman update with innovation ``y`` of the measurement ``H x`` (noise ``R``), the gain
    zeroed outside the states ``keep`` (bool, N_STATE), the Joseph form
    ``P = (I - K H) P (I - K H)' + K R K'`` (consistent for any gain); in place."""
    n, m = P.shape[0], H.shape[0]
    pht = _mul_bt(P, H)                    # P H' (loops: see _ff_t)
    S = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            acc = R[i, j]
            for k in range(n):
                acc += H[i, k] * pht[k, j]
            S[i, j] = acc
    s_inv = np.linalg.inv(S)
    K = np.zeros((n, m))
    for i in range(n):
        if keep[i]:
            for j in range(m):
                acc = 0.0
                for k in range(m):
                    acc += pht[i, k] * s_inv[k, j]
                K[i, j] = acc
    ikh = np.eye(n)
    for i in range(n):
        acc = 0.0
        for j in range(m):
            acc += K[i, j] * y[j]
        x[i] += acc
        for j in range(n):
            kh = 0.0
            for k in range(m):
                kh += K[i, k] * H[k, j]
            ikh[i, j] -= kh
    out = _ff_t(ikh, P)
    kr = _mul_bt(K, R.T.copy())            # K R, once (not per entry of K R K')
    out += _mul_bt(kr, K)
    _symmetrise_into(out, P)
