"""Relaxation of the experience map (Section 4.2.4, Eq. 4.20): the exact weighted
least-squares optimum and the capped blend toward it.

Target: the optimum of Eq. 4.20 with node 0 fixed.  Every node but the first has an odometry
edge from its predecessor, so the graph is one chain plus the loop edges: only the loop
endpoints (and the two chain ends) are junctions.  A chain segment between junctions a, b
is equivalent to one edge with the summed delta and resistance sum(1/w) (series
reduction); :func:`solve_optimum` solves the small reduced system over the junctions
(sparse LU, minimum-degree ordering) and places every segment's interior node by
distributing the segment residual in proportion to 1/w (O(nodes), numba).

Blend: :func:`plan_correction` caps the correction at ``corrections.max_norm`` (scaled down
uniformly, keeping its shape); :func:`relax_fraction` advances the applied fraction phi of
the pending correction so that no node moves more than ``corrections.max_step`` per
iteration (positions = pos + phi * rem).  Positions in m.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.sparse.linalg import splu

__all__ = ["solve_optimum", "plan_correction", "relax_fraction", "rescale_edges"]


@njit(cache=True)
def _interpolate(term: np.ndarray, term_pos: np.ndarray, cum: np.ndarray, cumres: np.ndarray,
                 n: int) -> np.ndarray:
    """Positions of all n nodes: junctions from ``term_pos``; the interior of each chain
    segment follows its odometry with the segment residual spread in proportion to 1/w."""
    out = np.empty((n, 3))
    for t in range(term.size - 1):
        a, b = term[t], term[t + 1]
        res_ab = cumres[b] - cumres[a]
        for k in range(3):
            resid = term_pos[t + 1, k] - term_pos[t, k] - (cum[b, k] - cum[a, k])
            for i in range(a, b + 1):
                frac = (cumres[i] - cumres[a]) / res_ab if res_ab > 0 else 0.0
                out[i, k] = term_pos[t, k] + (cum[i, k] - cum[a, k]) + frac * resid
    if term.size == 1:
        for k in range(3):
            out[0, k] = term_pos[0, k]
    return out


def solve_optimum(cum: np.ndarray, cumres: np.ndarray, loops: Sequence[tuple[int, int, float, int]],
                  loop_deltas: Sequence[np.ndarray], fixed: np.ndarray) -> tuple[np.ndarray, bool]:
    """(Node positions minimising Eq. 4.20 with node 0 at ``fixed``, whether a system was solved).

    ``cum``: the summed odometry increments up to each node (N x 3, m); ``cumres``: the summed
    1/w of the odometry edges up to each node; ``loops``: (m, n, weight, stamp) per loop edge,
    ``loop_deltas`` the p_n - p_m each asks for."""
    n = cum.shape[0]
    if n == 0:
        return np.zeros((0, 3)), False
    term = np.array(sorted({0, n - 1} | {m for m, _n, _w, _s in loops} | {k for _m, k, _w, _s in loops}),
                    np.int64)
    J = term.size
    # unknowns: junctions 1..J-1 -> 0..J-2; junction 0 (node 0) is fixed -> index J-1
    unk = np.arange(J, dtype=np.int64) - 1
    unk[0] = J - 1
    n_free = J - 1
    if n_free == 0:
        return _interpolate(term, fixed[None, :].copy(), cum, cumres, n), False
    # reduced edges: chain segments between consecutive junctions (series reduction), loop edges
    lp = np.array([(m, k, w) for m, k, w, _s in loops], np.float64).reshape(-1, 3)
    ea_a = np.concatenate([unk[:-1], unk[np.searchsorted(term, lp[:, 0].astype(np.int64))]])
    eb_a = np.concatenate([unk[1:], unk[np.searchsorted(term, lp[:, 1].astype(np.int64))]])
    eg_a = np.concatenate([1.0 / np.diff(cumres[term]), lp[:, 2]])
    ed_a = np.concatenate([np.diff(cum[term], axis=0), np.asarray(loop_deltas, np.float64).reshape(-1, 3)])
    fixed = fixed.copy()
    # normal equations of sum g ||x_b - x_a - D||^2; the fixed node's terms go to the right side
    rhs = np.zeros((J, 3))
    np.add.at(rhs, eb_a, eg_a[:, None] * (ed_a + np.where((ea_a == n_free)[:, None], fixed, 0.0)))
    np.add.at(rhs, ea_a, eg_a[:, None] * (-ed_a + np.where((eb_a == n_free)[:, None], fixed, 0.0)))
    fa, fb = ea_a < n_free, eb_a < n_free
    both = fa & fb
    lap = sp.csc_matrix((np.concatenate([eg_a[fa], eg_a[fb], -eg_a[both], -eg_a[both]]),
                         (np.concatenate([ea_a[fa], eb_a[fb], ea_a[both], eb_a[both]]),
                          np.concatenate([ea_a[fa], eb_a[fb], eb_a[both], ea_a[both]]))), shape=(n_free, n_free))
    # sparse LU with a minimum-degree ordering of the symmetric pattern (SuperLU, sequential:
    # deterministic)
    x = splu(lap, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True}).solve(rhs[:n_free])
    term_pos = np.vstack([fixed[None, :], x])
    return _interpolate(term, term_pos, cum, cumres, n), True


def plan_correction(target: np.ndarray, pos: np.ndarray, max_norm: float) -> tuple[np.ndarray, bool, float, float]:
    """(Correction per node (N x 3, m), clamped, planned largest displacement (m), peak (m)).

    The correction is ``target - pos``, scaled down uniformly when a node would move farther
    than ``max_norm`` (clamped); peak is the largest norm of the correction kept (0: nothing
    to apply)."""
    disp = target - pos
    norms = np.sqrt(np.sum(disp * disp, axis=1))
    peak = float(norms.max()) if norms.size else 0.0
    clamped = False
    if peak > max_norm:
        disp *= max_norm / peak
        clamped = True
    kept = float(np.sqrt(np.max(np.sum(disp * disp, axis=1)))) if disp.size else 0.0
    return disp, clamped, min(peak, max_norm), kept


def relax_fraction(phi: float, peak: float, step: float, iterations: int) -> tuple[float, int, float, bool]:
    """Run up to ``iterations`` iterations of a pending correction of largest norm ``peak`` (m),
    of which the fraction ``phi`` is applied: (new phi, iterations run, largest node move of
    one iteration (m), limited by ``step``).  Phi 1.0: the correction is complete.

    Each iteration moves every node by the same fraction of its correction, the node with the
    largest correction by ``step`` (or what is left of it), so the map stays a blend of the
    old map and the target: the iterations of one event add up to one update of phi."""
    left = (1.0 - phi) * peak
    if left <= iterations * step:
        return 1.0, max(1, math.ceil(left / step - 1e-9)), min(left, step), False
    return phi + iterations * step / peak, iterations, step, True


def rescale_edges(arrays: dict[str, np.ndarray], first: int, n: int, factor: float) -> None:
    """Multiply the horizontal delta of the weight-1 odometry edges into nodes first..n-1 by
    ``factor`` and rebuild ``cum`` (the chain's summed deltas) from there; a session's break
    edge (weight != 1) carries no measurement and keeps its delta."""
    if n <= 0 or factor == 1.0:
        return
    lo = max(int(first), 1)
    d, w, cum = arrays["delta"], arrays["weight"], arrays["cum"]
    odo = np.nonzero(w[lo:n] == 1.0)[0] + lo
    d[odo, :2] *= factor
    if lo < n:
        cum[lo:n] = cum[lo - 1] + np.cumsum(d[lo:n], axis=0)
