"""Planar pose-graph relaxation: the SE(2) generalisation of Eq. 4.20.

Eq. 4.20 asks every edge (i, j) for a displacement and relaxes positions only; with a
range sensor that measures relative *poses* (x, y and heading), the heading must be
relaxed too, or the map keeps the odometry's yaw drift.  :func:`relax_se2` minimises

    sum_edges  r_ij^T W_ij r_ij,   r_ij = z_ij (-) (x_i^-1 (+) x_j)

(the measured pose of j in the frame of i against the current estimate, heading wrapped)
over the poses x_k = (x, y, yaw) with node 0 fixed, by Gauss-Newton on the sparse normal
equations (SuperLU, a deterministic ordering).  ``W_ij = diag(w_xy, w_xy, w_yaw)``.  A
Huber kernel on the Mahalanobis norm of each residual (``huber`` > 0) lets a loop edge that
disagrees with the rest pull with bounded force.  The heights are not part of it: planar
maps keep the odometry's z.
"""
from __future__ import annotations

import math
from typing import overload

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

__all__ = ["relax_se2", "relative_pose", "compose", "wrap_angle"]


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: np.ndarray) -> np.ndarray: ...
def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + math.pi) % (2.0 * math.pi) - math.pi


def relative_pose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose b in the frame of pose a: a^-1 (+) b, for (x, y, yaw) rows (N x 3 or 3)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def compose(a: np.ndarray, d: np.ndarray) -> np.ndarray:
    """a (+) d: the pose d given in the frame of a, in a's parent frame."""
    a = np.asarray(a, np.float64)
    d = np.asarray(d, np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * d[..., 0] - s * d[..., 1], a[..., 1] + s * d[..., 0] + c * d[..., 1],
                     wrap_angle(a[..., 2] + d[..., 2])], axis=-1)


def relax_se2(poses: np.ndarray, ei: np.ndarray, ej: np.ndarray, z: np.ndarray, w: np.ndarray, *,
              huber: float = 0.0, iterations: int = 10, tol: float = 1e-6) -> tuple[np.ndarray, int]:
    """Gauss-Newton relaxation of a planar pose graph, node 0 fixed.

    :param poses: N x 3 initial (x m, y m, yaw rad)
    :param ei, ej: edge ends (int arrays, length E)
    :param z: E x 3 measured pose of j in the frame of i
    :param w: E x 3 information (diagonal: x, y in 1/m^2, yaw in 1/rad^2)
    :param huber: Huber threshold on sqrt(r^T W r) (0: plain least squares)
    :returns: the relaxed poses and the iterations run
    """
    x = np.array(poses, np.float64, copy=True)
    n = x.shape[0]
    ei = np.asarray(ei, np.int64)
    ej = np.asarray(ej, np.int64)
    z = np.asarray(z, np.float64).reshape(-1, 3)
    w = np.asarray(w, np.float64).reshape(-1, 3)
    if n < 2 or ei.size == 0:
        return x, 0
    it = 0
    for step in range(1, iterations + 1):
        it = step
        xi, xj = x[ei], x[ej]
        c, s = np.cos(xi[:, 2]), np.sin(xi[:, 2])
        dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
        pred = np.stack([c * dx + s * dy, -s * dx + c * dy, xj[:, 2] - xi[:, 2]], axis=1)
        r = pred - z
        r[:, 2] = wrap_angle(r[:, 2])
        wk = w.copy()
        if huber > 0.0:
            m = np.sqrt(np.sum(w * r * r, axis=1))
            scale = np.where(m > huber, huber / np.maximum(m, 1e-12), 1.0)
            wk *= scale[:, None]
        # Jacobians of pred w.r.t. x_i (A) and x_j (B), E x 3 x 3
        A = np.zeros((ei.size, 3, 3))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2] = -c, -s, -s * dx + c * dy
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2] = s, -c, -c * dx - s * dy
        A[:, 2, 2] = -1.0
        B = np.zeros((ei.size, 3, 3))
        B[:, 0, 0], B[:, 0, 1] = c, s
        B[:, 1, 0], B[:, 1, 1] = -s, c
        B[:, 2, 2] = 1.0
        WA = A * wk[:, :, None]
        WB = B * wk[:, :, None]
        Hii = np.einsum("eki,ekj->eij", A, WA)
        Hjj = np.einsum("eki,ekj->eij", B, WB)
        Hij = np.einsum("eki,ekj->eij", A, WB)
        gi = np.einsum("eki,ek->ei", WA, r)
        gj = np.einsum("eki,ek->ei", WB, r)
        rows, cols, vals = [], [], []
        ar = np.arange(3)
        for (p, q, blk) in ((ei, ei, Hii), (ej, ej, Hjj), (ei, ej, Hij), (ej, ei, np.transpose(Hij, (0, 2, 1)))):
            rows.append((3 * p[:, None, None] + ar[None, :, None]).repeat(3, axis=2).ravel())
            cols.append((3 * q[:, None, None] + ar[None, None, :]).repeat(3, axis=1).ravel())
            vals.append(blk.ravel())
        g = np.zeros(3 * n)
        np.add.at(g, (3 * ei[:, None] + ar).ravel(), gi.ravel())
        np.add.at(g, (3 * ej[:, None] + ar).ravel(), gj.ravel())
        H = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))
        Hf = H[3:, 3:].tocsc()
        Hf = Hf + sp.identity(Hf.shape[0], format="csc") * 1e-9
        dxv = -splu(Hf, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True}).solve(g[3:])
        x[1:] += dxv.reshape(-1, 3)
        x[:, 2] = wrap_angle(x[:, 2])
        if float(np.max(np.abs(dxv))) < tol:
            break
    return x, it
