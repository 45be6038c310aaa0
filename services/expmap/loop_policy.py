"""Loop policy of the experience map (Section 4.2.4): the loop edges, the route rule and the
displacement a closure asks for (with the sonar sweep verification).

:class:`LoopEdges` keeps the loop edges (m, n, weight, stamp) and the displacement
``p_n - p_m`` (m) each asks for, and answers route lengths: edges on the shortest route
between two experiences over the odometry chain plus the loop edges (a loop edge counts 1),
the unit of ``corrections.min_route_len``.  :func:`loop_displacement` is the Delta p of a new
loop edge (Eq. 4.20), or None when the two sonar sweeps contradict the recognition.
"""
from __future__ import annotations

import bisect
import heapq
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit

from services.expmap.config import ExpMapConfig
from services.expmap.scans import Registration, register_sweeps

__all__ = ["EventResult", "LoopEdges", "loop_displacement", "link_displacement"]


@dataclass
class EventResult:
    """What one event did to the map."""

    node: int
    match: int = -1                 # matched old node (-1: none)
    score: float = 0.0
    confirmations: int = 0
    loop_closed: bool = False
    rejected: str = ""              # "interval" | "route" | "scan" when a confirmed loop was not closed
    correction_clamped: bool = False
    correction_norm: float = 0.0    # largest node displacement planned by this closure (m)
    step_max: float = 0.0           # largest node move in one relaxation iteration of this event (m)
    iterations: int = 0             # relaxation iterations run during this event
    step_capped: bool = False       # corrections.max_step limited an iteration
    settled: bool = False           # a pending correction finished during this event
    session_started: bool = False   # this event's node is the first of a new session
    linked: bool = False            # this event linked its session to an older one


@njit(cache=True)
def _route_dijkstra(a: int, b: int, limit: int, n_nodes: int, ends: np.ndarray, ptr: np.ndarray,
                    idx: np.ndarray) -> int:
    """Shortest route a -> b in edges over the chain 0..n_nodes-1 plus loop edges (CSR over
    the sorted endpoints ``ends``); returns a value >= limit as soon as the answer is."""
    big = 1 << 62
    dist = {a: 0}
    heap = [(0, a)]
    while len(heap) > 0:
        d, u = heapq.heappop(heap)
        if u == b or d >= limit:
            return d
        if d > dist[u]:
            continue
        i = np.searchsorted(ends, u)                 # ends[i-1] < u <= ends[i]
        lo = ends[i - 1] if i > 0 else (0 if u > 0 else -1)
        j = i + 1 if i < ends.size and ends[i] == u else i
        hi = ends[j] if j < ends.size else (n_nodes - 1 if u < n_nodes - 1 else -1)
        for x in (a, b):
            if x < u and (lo < 0 or x > lo):
                lo = x
            if x > u and (hi < 0 or x < hi):
                hi = x
        for k in range(3):
            if k == 0:
                v, w = lo, u - lo
            elif k == 1:
                v, w = hi, hi - u
            else:
                break
            if v >= 0:
                nd = d + w
                if nd < dist.get(v, big):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
        if i < ends.size and ends[i] == u:
            for e in range(ptr[i], ptr[i + 1]):
                v = idx[e]
                nd = d + 1
                if nd < dist.get(v, big):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
    return big


class LoopEdges:
    """The loop edges of the map and route lengths over the chain 0..n-1 plus those edges."""

    def __init__(self) -> None:
        self.loops: list[tuple[int, int, float, int]] = []   # (m, n, weight, stamp)
        self.deltas: list[np.ndarray] = []   # per loop edge: p_n - p_m it asks for (m); zero by default
        self._ends: list[int] = []              # sorted distinct loop-edge endpoints
        self._adj: dict[int, list[int]] = {}    # loop-edge endpoint -> other ends
        self._csr: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._route_cache: tuple[int, int, int] | None = None   # (m, n, upper bound of their route)

    def add(self, m: int, n: int, weight: float, stamp: int, delta: npt.ArrayLike | None = None) -> None:
        """Record a loop edge m -> n asking p_n - p_m = ``delta`` (default zero: the same place)."""
        self.loops.append((m, n, weight, stamp))
        self.deltas.append(np.zeros(3) if delta is None else np.asarray(delta, np.float64).reshape(3).copy())
        self._csr = None
        self._route_cache = None
        for x, y in ((m, n), (n, m)):
            if x not in self._adj:
                bisect.insort(self._ends, x)
            self._adj.setdefault(x, []).append(y)

    def route_length(self, a: int, b: int, n_nodes: int, limit: int | None = None) -> int:
        """Edges on the shortest route between nodes a and b of a map of ``n_nodes``.

        Dijkstra over junctions only (numba): from a node the chain leads to the nearest
        loop endpoint (or a, b) on either side, weighing the number of odometry edges
        between; a loop edge leads to its other end.  ``limit``: stop once the answer is
        known to be >= limit, so a query explores only the junctions within ``limit`` edges.
        """
        if a == b:
            return 0
        if self._csr is None:
            ends = np.asarray(self._ends, np.int64)
            ptr = np.zeros(ends.size + 1, np.int64)
            for i, e in enumerate(self._ends):
                ptr[i + 1] = ptr[i] + len(self._adj[e])
            idx = np.array([v for e in self._ends for v in self._adj[e]], np.int64)
            self._csr = (ends, ptr, idx)
        ends, ptr, idx = self._csr
        lim = (1 << 62) if limit is None else int(limit)
        return int(_route_dijkstra(int(a), int(b), lim, n_nodes, ends, ptr, idx))

    def route_bound(self, m: int, n: int, n_nodes: int, min_len: float) -> int:
        """The route length between m and n where it is below ``min_len``, else a value >= it.

        Consecutive events of a confirmed chain ask about (m+1, n+1) after (m, n): the
        previous answer plus the chain steps bounds the route from above, so most rejections
        need no search."""
        bound = 1 << 62
        if self._route_cache is not None:
            a0, b0, d0 = self._route_cache
            bound = d0 + abs(m - a0) + abs(n - b0)
        if bound >= min_len:
            bound = self.route_length(m, n, n_nodes, limit=math.ceil(min_len))
        self._route_cache = (m, n, bound)
        return bound


def loop_displacement(cfg: ExpMapConfig, d: np.ndarray, sweep_m: np.ndarray | None, sweep_n: np.ndarray | None,
                      dz_odom: float, tallies: dict[str, int]) -> tuple[np.ndarray | None, Registration | None]:
    """(Displacement p_n - p_m a loop closure of m and n asks for, the registration made), the
    displacement None when the sonar contradicts the recognition.

    ``d``: the current map separation p_n - p_m (m); ``sweep_m``, ``sweep_n``: the sonar
    sweeps kept with the two experiences (k x 2, m; None: none); ``dz_odom``: their odometry
    height difference (m); ``tallies``: registration outcomes counted here (``trusted``,
    ``partial``, ``untrusted``, ``no_sweep``).

    With ``loops.scan_matching`` and both sweeps, they are registered
    (:func:`services.expmap.scans.register_sweeps`): a trusted registration gives the
    horizontal displacement (along an ambiguous axis, e.g. along a straight tunnel, the map's
    current separation is kept) and the odometry gives the vertical one (pressure depth is
    absolute).  Otherwise the dissertation's rule: a recognised place is the same place, zero
    displacement; with ``loops.place_radius_m`` r > 0 the edge keeps the current separation d
    when |d| <= r and asks for d r / |d| beyond (pulls the two to r apart).  Geometric
    verification (``scan.reject_inconsistent``): when both sweeps have enough echoes but fewer
    than ``scan.min_inlier_fraction`` of them fit after the best alignment, the two
    experiences do not see the same walls: None.  Sweeps without walls in range or ambiguous
    in every direction prove nothing and fall back to the rule above.
    """
    reg = None
    if cfg.loops.scan_matching:
        if sweep_m is None or sweep_n is None:
            tallies["no_sweep"] += 1
        else:
            reg = register_sweeps(sweep_m, sweep_n, d[:2], cell_m=cfg.scan.cell_m,
                                  search_radius_m=cfg.scan.search_radius_m,
                                  max_rotation_deg=cfg.scan.max_rotation_deg,
                                  rotation_step_deg=cfg.scan.rotation_step_deg, min_points=cfg.scan.min_points,
                                  min_inlier_fraction=cfg.scan.min_inlier_fraction,
                                  ambiguity_margin_m=cfg.scan.ambiguity_margin_m,
                                  max_ambiguity_m=cfg.scan.max_ambiguity_m)
            if reg.trusted:
                t = reg.translation.copy()
                if reg.ambiguous_axis is not None:
                    u = reg.ambiguous_axis
                    t = t + u * float(u @ (d[:2] - t))
                    tallies["partial"] += 1
                else:
                    tallies["trusted"] += 1
                return np.array([t[0], t[1], dz_odom]), reg
            tallies["untrusted"] += 1
            if reg.inconsistent and cfg.scan.reject_inconsistent:
                return None, reg
    r = float(cfg.loops.place_radius_m)
    if r <= 0.0:
        return np.zeros(3), reg
    norm = float(np.sqrt(np.sum(d * d)))
    return (d if norm <= r else d * (r / norm)), reg


def link_displacement(cfg: ExpMapConfig, sweep_m: np.ndarray | None, sweep_n: np.ndarray | None,
                      dz_odom: float, separation: np.ndarray | None = None,
                      search_radius_m: float | None = None) -> tuple[np.ndarray | None, Registration | None, str]:
    """(Displacement p_n - p_m of a session link, the registration made, why not) for a
    confirmed match between two unlinked sessions; the displacement None unless verified.

    The frames of two unlinked sessions are unrelated, so the search is centred on "the same
    place" (zero separation, grown by ``scan.search_radius_m``).  Verified: both sweeps, a
    registration trusted along both axes (no ambiguous axis: a straight tunnel does not place
    a session) with at least ``sessions.link_min_inliers`` inliers.  The reason when not:
    ``no_sweep``, ``untrusted``, ``ambiguous`` or ``inliers``.  ``dz_odom``: the two
    experiences' odometry height difference (m; pressure depth is absolute in every session).
    The backfill of a made link (:mod:`services.expmap.session_link`) passes the two nodes'
    ``separation`` p_n - p_m in the linked frame and its ``search_radius_m``: the search then
    also covers the separation, and the same verification applies.
    """
    if sweep_m is None or sweep_n is None:
        return None, None, "no_sweep"
    around = np.zeros(2) if separation is None else np.asarray(separation, np.float64)[:2]
    radius = cfg.scan.search_radius_m if search_radius_m is None else search_radius_m
    reg = register_sweeps(sweep_m, sweep_n, around, cell_m=cfg.scan.cell_m,
                          search_radius_m=radius, max_rotation_deg=cfg.sessions.link_max_rotation_deg,
                          rotation_step_deg=cfg.sessions.link_rotation_step_deg, min_points=cfg.scan.min_points,
                          min_inlier_fraction=cfg.scan.min_inlier_fraction,
                          ambiguity_margin_m=cfg.scan.ambiguity_margin_m, max_ambiguity_m=cfg.scan.max_ambiguity_m)
    if not reg.trusted:
        return None, reg, "untrusted"
    if reg.ambiguous_axis is not None:
        return None, reg, "ambiguous"
    if reg.inlier_fraction < cfg.sessions.link_min_inliers:
        return None, reg, "inliers"
    t = reg.translation
    return np.array([float(t[0]), float(t[1]), dz_odom]), reg, ""
