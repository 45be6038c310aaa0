"""Loop-closure candidates of the experience map (Section 4.2.4, Table 4.1): which old
experiences an event is compared with, their scores, and the match an event chooses.

Candidates of the new node n: nodes m with ``n - m >= min_experience_age`` (age in events);
when ``pc_factor < match_threshold`` only the nodes of the same LVC can reach the threshold,
so only those are scored (an index lvc -> nodes).  Score (Table 4.1):
``lv_factor * [lvc_m == lvc_n] + pc_factor * exp(-d^2 / (2 s^2))`` with d the wrap-aware
distance between the pose-cell centroids in lattice cells, s = ``pc_proximity_sigma_cells``.
A match scores >= ``match_threshold``; :func:`choose_match` picks the one that continues the
confirmation chain (closest to the previous match, within ``loops.confirmation_gap``), else
the best score (ties: the oldest).  The rules in full: :mod:`services.expmap.graph`.
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from numba import njit

from services.expmap.config import ExpMapConfig

__all__ = ["lattice_geometry", "pc_distance_cells", "candidate_nodes", "match_scores", "choose_match"]


@njit(cache=True)
def _pc_scores(cand: np.ndarray, pc: np.ndarray, lvc: np.ndarray, q_pc: np.ndarray, q_lvc: int,
               period: np.ndarray, cell: np.ndarray, lv_factor: float, pc_factor: float,
               sigma: float) -> np.ndarray:
    """Score of every candidate node: lv_factor*[same LVC] + pc_factor*proximity."""
    out = np.empty(cand.size)
    inv2s2 = 1.0 / (2.0 * sigma * sigma)
    for c in range(cand.size):
        i = cand[c]
        d2 = 0.0
        for a in range(4):
            d = abs(pc[i, a] - q_pc[a]) % period[a]
            if d > period[a] - d:
                d = period[a] - d
            d /= cell[a]
            d2 += d * d
        s = pc_factor * math.exp(-d2 * inv2s2)
        if lvc[i] == q_lvc:
            s += lv_factor
        out[c] = s
    return out



def pc_distance_cells(a: npt.ArrayLike, b: npt.ArrayLike, shape: tuple[int, int, int, int],
                      spacing: tuple[float, float, float]) -> float:
    """Wrap-aware distance (lattice cells) between two pose-cell centroids [x, y, z m, yaw rad]."""
    period, cell = lattice_geometry(shape, spacing)
    d = np.abs(np.asarray(a, float) - np.asarray(b, float)) % period
    d = np.minimum(d, period - d) / cell
    return float(np.sqrt(np.sum(d * d)))


def lattice_geometry(shape: Sequence[int], spacing: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    cell = np.array([spacing[0], spacing[1], spacing[2], 2.0 * math.pi / shape[3]], float)
    period = np.array([shape[0] * spacing[0], shape[1] * spacing[1], shape[2] * spacing[2], 2.0 * math.pi], float)
    return period, cell


def candidate_nodes(n: int, cfg: ExpMapConfig, lvc_index: dict[int, list[int]], lvc_n: int,
                    session_first: int = 0) -> np.ndarray:
    """Ids (int64, ascending) of the nodes the new node ``n`` of LVC ``lvc_n`` is compared with:
    those at least ``min_experience_age`` events older, and every node of an earlier session
    (ids below ``session_first``, the first node of n's session: another mission, or before
    an odometry jump, is never "the place just passed")."""
    cutoff = max(n - cfg.min_experience_age, session_first - 1)
    if cutoff < 0:
        return np.zeros(0, np.int64)
    if cfg.pc_factor < cfg.match_threshold:
        ids = lvc_index[lvc_n]
        return np.asarray(ids[: bisect.bisect_right(ids, cutoff)], np.int64)
    return np.arange(cutoff + 1, dtype=np.int64)


def match_scores(cand: np.ndarray, pc: np.ndarray, lvc: np.ndarray, q_pc: np.ndarray, q_lvc: int,
                 period: np.ndarray, cell: np.ndarray, cfg: ExpMapConfig) -> np.ndarray:
    """Table 4.1 score of each candidate (``pc``, ``lvc``: every node's centroid and LVC)."""
    return _pc_scores(cand, pc, lvc, q_pc, q_lvc, period, cell, cfg.lv_factor, cfg.pc_factor,
                      cfg.pc_proximity_sigma_cells)


def choose_match(matches: np.ndarray, mscores: np.ndarray, last_match: int, confirmations: int,
                 gap: int) -> tuple[int, int]:
    """(index into ``matches`` of the chosen match, the confirmation count after this event).

    Continues the chain when the previous event matched (``confirmations`` > 0) and a match
    lies within ``gap`` experiences of ``last_match`` (the closest; ties: the oldest), else
    starts a new chain at the best score (ties: the oldest)."""
    if last_match >= 0 and confirmations > 0:
        g = np.abs(matches - last_match)
        j = int(np.argmin(g))          # first minimum: the oldest among equals
        if g[j] <= gap:
            return j, confirmations + 1
    return int(np.argmax(mscores)), 1   # first maximum: the oldest among equals
