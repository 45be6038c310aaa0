"""The experience maps' relaxations solved by GTSAM (Dellaert and Kaess, factor graphs), beside ours.

Two problems, each the same objective as our own solver and a drop-in for its call site:

- **Planar pose graph** (the laser map, :mod:`services.expmap.scan_graph`): :func:`relax_se2_gtsam`
  minimises the SE(2) generalisation of Eq. 4.20 that :func:`services.expmap.pose_graph.relax_se2`
  minimises, ``sum_edges rho(||r_ij||_W)``: one ``Pose2`` per experience, one
  ``BetweenFactorPose2`` per edge whose noise model is the edge's diagonal information
  (sigmas ``1 / sqrt(w)``), wrapped in a Huber kernel of the same threshold (in sigma, on the
  whole residual's Mahalanobis norm, as ours) on *every* edge when ``huber`` > 0 (ours weighs
  every edge the same way; the objectives must match), node 0 held by a
  ``NonlinearEqualityPose2``.  GTSAM's residual is ``Log(z_ij^-1 (x_i^-1 x_j))``, ours the
  component difference ``(x_i^-1 x_j) - z_ij``; with the isotropic translation information of
  every edge here their Mahalanobis norms differ only by a factor 1 + O(dtheta^2), so the optima
  agree to well below a millimetre (``tests/expmap/test_gtsam_graph.py``).
- **Eq. 4.20 over positions** (the 3D experience map, :mod:`services.expmap.graph`):
  :func:`solve_optimum_gtsam` minimises ``sum_edges w ||p_j - p_i - Delta_ij||^2`` over every
  node's position, node 0 fixed: one ``Point3`` per experience, one ``BetweenFactorPoint3`` per
  odometry edge (the increment of ``cum``, sigma ``sqrt(1/w)`` from ``cumres``) and per loop
  edge (its ``loop_delta``, sigma ``1 / sqrt(w)``), node 0 held by a ``NonlinearEqualityPoint3``.
  The same optimum :func:`services.expmap.relaxation.solve_optimum` reaches by series reduction,
  here without the reduction: the whole chain is in the factor graph.

Optimiser: batch Levenberg-Marquardt (GTSAM's defaults: COLAMD ordering, multifrontal Cholesky;
single-threaded in the package index's build, so deterministic).  Batch, not iSAM2: our maps
relax the whole graph after a closure from the current poses and take a closure back when the
relaxed map cannot satisfy it; LM answers exactly that question (the full nonlinear optimum from
the given initial poses), where iSAM2 keeps a factorisation between calls, relinearises only
variables past a threshold (an approximate optimum) and would have to be told about every
closure taken back.  The stopping rule is ours: an accepted LM step that moves no pose coordinate
by more than ``tol`` ends it (or ``iterations`` accepted steps, or a step LM cannot accept).

:func:`relax_planar` and :func:`relaxation_optimum` choose by the configuration's name
(``expmap.scan_graph.optimizer``, ``expmap.corrections.optimizer``).  gtsam is imported on the first
GTSAM solve, so the default path does not pay its import.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from services.expmap.pose_graph import relax_se2, wrap_angle
from services.expmap.relaxation import solve_optimum

__all__ = ["PLANAR_OPTIMIZERS", "RELAXATION_OPTIMIZERS", "relax_se2_gtsam", "solve_optimum_gtsam", "relax_planar",
           "relaxation_optimum"]

#: values of ``expmap.scan_graph.optimizer``: ours (services/expmap/pose_graph.py) and GTSAM's LM
PLANAR_OPTIMIZERS = ("gauss_newton", "gtsam_lm")
#: values of ``expmap.corrections.optimizer``: ours (services/expmap/relaxation.py) and GTSAM's LM
RELAXATION_OPTIMIZERS = ("series_reduction", "gtsam_lm")

_MIN_SIGMA = 1e-9      # an edge of infinite information (zero resistance) is held this tightly


def _gtsam() -> Any:
    import gtsam  # the package index's wheel; imported on the first GTSAM solve

    return gtsam


def _iterate(gtsam: Any, graph: Any, initial: Any, extract: Any, iterations: int,
             tol: float) -> tuple[np.ndarray, int]:
    """Run LM steps on ``graph`` from ``initial`` until an accepted step moves no coordinate of
    ``extract(values)`` by more than ``tol``, ``iterations`` steps ran, or no step is accepted:
    (the last estimate's coordinates, accepted steps)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(iterations))
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    x = np.asarray(extract(initial), np.float64)
    steps = 0
    for _ in range(int(iterations)):
        err = opt.error()
        opt.iterate()
        x_new = np.asarray(extract(opt.values()), np.float64)
        moved = float(np.max(np.abs(x_new - x))) if x.size else 0.0
        x = x_new
        if opt.error() >= err and moved == 0.0:
            break                       # LM could not lower the cost: nothing was accepted
        steps += 1
        if moved < tol:
            break
    return x, steps


def relax_se2_gtsam(poses: np.ndarray, ei: np.ndarray, ej: np.ndarray, z: np.ndarray, w: np.ndarray, *,
                    huber: float = 0.0, iterations: int = 10, tol: float = 1e-6) -> tuple[np.ndarray, int]:
    """GTSAM's LM on the planar pose graph of :func:`~services.expmap.pose_graph.relax_se2`, node 0 fixed.

    The SE(2) form of Eq. 4.20, ``sum rho(||Log(z_ij^-1 (x_i^-1 x_j))||_W)`` with ``rho`` the
    Huber kernel of threshold ``huber`` (sigma; 0: plain least squares).  Arguments and return as
    ``relax_se2``: ``poses`` N x 3 (x m, y m, yaw rad), edge ends ``ei``, ``ej``, ``z`` E x 3 the
    pose of j measured in the frame of i, ``w`` E x 3 diagonal information (1/m^2, 1/m^2, 1/rad^2);
    returns the relaxed poses (headings in [-pi, pi)) and the LM steps run."""
    x0 = np.array(poses, np.float64, copy=True).reshape(-1, 3)
    ei = np.asarray(ei, np.int64)
    ej = np.asarray(ej, np.int64)
    z = np.asarray(z, np.float64).reshape(-1, 3)
    w = np.asarray(w, np.float64).reshape(-1, 3)
    n = x0.shape[0]
    if n < 2 or ei.size == 0:
        return x0, 0
    gtsam = _gtsam()
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for k in range(n):
        initial.insert(k, gtsam.Pose2(float(x0[k, 0]), float(x0[k, 1]), float(x0[k, 2])))
    graph.add(gtsam.NonlinearEqualityPose2(0, gtsam.Pose2(float(x0[0, 0]), float(x0[0, 1]), float(x0[0, 2]))))
    sigmas = 1.0 / np.sqrt(np.maximum(w, _MIN_SIGMA ** 2))
    kernel = gtsam.noiseModel.mEstimator.Huber.Create(float(huber)) if huber > 0.0 else None
    for k in range(ei.size):
        model = gtsam.noiseModel.Diagonal.Sigmas(sigmas[k])
        if kernel is not None:
            model = gtsam.noiseModel.Robust.Create(kernel, model)
        graph.add(gtsam.BetweenFactorPose2(int(ei[k]), int(ej[k]),
                                           gtsam.Pose2(float(z[k, 0]), float(z[k, 1]), float(z[k, 2])), model))
    x, steps = _iterate(gtsam, graph, initial, gtsam.utilities.extractPose2, iterations, tol)
    x[:, 2] = wrap_angle(x[:, 2])
    x[0] = x0[0]
    return x, steps


def solve_optimum_gtsam(cum: np.ndarray, cumres: np.ndarray, loops: Sequence[tuple[int, int, float, int]],
                        loop_deltas: Sequence[np.ndarray], fixed: np.ndarray, *,
                        iterations: int = 10, tol: float = 1e-9,
                        stats: dict[str, int] | None = None) -> tuple[np.ndarray, bool]:
    """GTSAM's LM on Eq. 4.20 over positions, node 0 at ``fixed``: drop-in for
    :func:`services.expmap.relaxation.solve_optimum` (same arguments and return).

    Minimises ``sum_i ||p_i - p_{i-1} - (cum_i - cum_{i-1})||^2 / (cumres_i - cumres_{i-1}) +
    sum_loops w ||p_n - p_m - Delta_mn||^2`` over every node's position (m); the start is the
    odometry chain ``fixed + cum - cum_0``.  Returns (N x 3 positions, whether a system was solved);
    ``stats``, when given, receives the LM steps run (``steps``)."""
    cum = np.asarray(cum, np.float64).reshape(-1, 3)
    n = cum.shape[0]
    fixed = np.asarray(fixed, np.float64).reshape(3)
    if n == 0:
        return np.zeros((0, 3)), False
    start = fixed + (cum - cum[0])
    if n == 1:
        return start, False
    gtsam = _gtsam()
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for k in range(n):
        initial.insert(k, start[k])
    graph.add(gtsam.NonlinearEqualityPoint3(0, fixed))
    delta = np.diff(cum, axis=0)
    res = np.diff(np.asarray(cumres, np.float64).reshape(-1)[:n])
    sig = np.sqrt(np.maximum(res, _MIN_SIGMA ** 2))
    for k in range(n - 1):
        graph.add(gtsam.BetweenFactorPoint3(k, k + 1, delta[k], gtsam.noiseModel.Isotropic.Sigma(3, float(sig[k]))))
    for (m, j, wl, _s), d in zip(loops, loop_deltas):
        s = 1.0 / np.sqrt(max(float(wl), _MIN_SIGMA ** 2))
        graph.add(gtsam.BetweenFactorPoint3(int(m), int(j), np.asarray(d, np.float64).reshape(3),
                                            gtsam.noiseModel.Isotropic.Sigma(3, float(s))))
    x, steps = _iterate(gtsam, graph, initial, gtsam.utilities.extractPoint3, iterations, tol)
    if stats is not None:
        stats["steps"] = steps
    x = x.reshape(-1, 3)
    x[0] = fixed
    return x, True


def relax_planar(optimizer: str, poses: np.ndarray, ei: np.ndarray, ej: np.ndarray, z: np.ndarray, w: np.ndarray,
                 *, huber: float = 0.0, iterations: int = 10) -> tuple[np.ndarray, int]:
    """The planar relaxation by ``optimizer`` (``expmap.scan_graph.optimizer``): ours (Gauss-Newton,
    :func:`~services.expmap.pose_graph.relax_se2`) or GTSAM's LM (:func:`relax_se2_gtsam`)."""
    if optimizer == "gauss_newton":
        return relax_se2(poses, ei, ej, z, w, huber=huber, iterations=iterations)
    if optimizer == "gtsam_lm":
        return relax_se2_gtsam(poses, ei, ej, z, w, huber=huber, iterations=iterations)
    raise ValueError(f"unknown planar optimizer {optimizer!r} (one of {', '.join(PLANAR_OPTIMIZERS)})")


def relaxation_optimum(optimizer: str, cum: np.ndarray, cumres: np.ndarray,
                       loops: Sequence[tuple[int, int, float, int]], loop_deltas: Sequence[np.ndarray],
                       fixed: np.ndarray) -> tuple[np.ndarray, bool]:
    """Eq. 4.20's optimum by ``optimizer`` (``expmap.corrections.optimizer``): ours (series
    reduction, :func:`~services.expmap.relaxation.solve_optimum`) or GTSAM's LM
    (:func:`solve_optimum_gtsam`)."""
    if optimizer == "series_reduction":
        return solve_optimum(cum, cumres, loops, loop_deltas, fixed)
    if optimizer == "gtsam_lm":
        return solve_optimum_gtsam(cum, cumres, loops, loop_deltas, fixed)
    raise ValueError(f"unknown relaxation optimizer {optimizer!r} (one of {', '.join(RELAXATION_OPTIMIZERS)})")
