"""The 3D experience map: nodes, edges, loop closure and relaxation (Section 4.2.4).

Every accepted ``experience_event`` creates a node; its position is the previous node's
position plus the dead-reckoning displacement since the previous event (Eq. 4.15), and an
odometry edge (delta, duration, weight 1) joins it to the previous node (Eq. 3.6).  The
first node sits at the odometry position of its event and is the map's anchor: the map
frame is the dead-reckoning frame (ENU) at the first experience and node 0 never moves.

Loop closure (Table 4.1), decided for the new node n of every event:

- candidates: nodes m with ``n - m >= min_experience_age`` (age in events).  Their score
  is ``lv_factor * [lvc_m == lvc_n] + pc_factor * proximity``.  Proximity is
  ``exp(-d^2 / (2 s^2))`` of the wrap-aware distance d between the two pose-cell centroids
  measured in lattice cells (x, y, z in units of ``distance_between_neurons``, each axis
  wrapping at ``number_of_neurons`` cells; yaw in bins of 2 pi / n_yaw, wrapping at 2 pi),
  s = ``pc_proximity_sigma_cells`` (3.5: with the Table 4.1 weights and threshold, a
  same-LVC node matches iff its centroid is within one cell; the default 100 makes the
  proximity > 0.99 anywhere on the default lattice, whose x/y/z wrap every 1.5 m and so
  cannot tell places apart beyond that: a same-LVC node matches, and the sonar registration
  below is the geometric check).  When
  ``pc_factor < match_threshold`` a node of another LVC can never reach the threshold, so
  only the nodes of the same LVC are scored, through an index lvc -> nodes (cost
  O(candidates)); otherwise every old node is scored.
- a match is a candidate with score >= ``match_threshold``.  Consecutive events confirm a
  loop when both match and their matched nodes are at most ``loop_confirmation_gap``
  experiences apart on the old route (either direction, so a route driven backwards
  confirms too); the event chooses, among its matches, the one closest to the previous
  match, else the best score (ties: the oldest).  A loop is closed between n and its match
  m when ``loop_confirmations`` consecutive events confirmed it, at least
  ``min_correction_interval_sec`` of event time passed since the last correction, and the
  route between m and n is at least ``min_correction_route_len`` experiences long.
  Route length is counted in experiences (edges) along the shortest route of the current
  graph, loop edges included: the same unit as ``min_experience_age`` and independent of
  drift; after an earlier closure it is shorter than the age, which is what keeps a
  second closure from re-closing a loop that is already closed.  A closure resets the
  confirmation count.
- the loop edge goes from m to n with zero displacement (an LVC match says "same place";
  measured by sonar instead when available, see below;
  the pose-cell offset is not used because the lattice wraps every 1.5 m and its centroid
  is itself pulled toward the stored pose) and weight ``loop_edge_weight``, duration 0 s.

Relaxation: the target is the exact weighted least-squares optimum of Eq. 4.20 with node 0
fixed, not OpenRatSLAM's half-error sweep.  Because every node but the first has an
odometry edge from its predecessor, the graph is one chain plus the loop edges: only the
loop endpoints (and the two chain ends) are junctions.  A chain segment between junctions
a, b is equivalent to one edge with the summed delta and resistance sum(1/w) (series
reduction), so the optimum is found by solving the small reduced system over the
junctions (sparse LU, minimum-degree ordering) and then placing every segment's
interior node by distributing the segment residual in proportion to 1/w (O(nodes), numba).
The map then moves toward that target: the correction of a node is capped at
``max_correction_norm`` (if any node would move farther, the whole correction is scaled
down uniformly, keeping its shape, and counted as clamped); each iteration moves every
pending node by the same fraction of its remaining correction such that no node moves more
than ``max_correction_step`` (so the map is always a blend of the old map and the target);
``relax_iterations_per_event`` iterations run per accepted event, and
:meth:`ExperienceMap.settle` finishes a pending correction.  Because every node moves by
the same fraction, the pending state is ``position = pos + phi * rem`` and an event's
iterations only advance phi (O(1)); positions are materialised when read.  Nodes created
while a correction is pending inherit their predecessor's correction.

Loop-edge displacement: with ``loop_scan_matching`` each node keeps the sonar sweep around
its odometry position and a closure's edge asks for the displacement measured by registering
the two sweeps (:mod:`services.expmap.scans`; a departure from the zero displacement above,
which stays the fallback when a sweep is missing or the registration is not trusted).

Save/load (:meth:`save`, :meth:`load`, npz) keeps everything needed to continue: nodes,
odometry increments, loop edges, sonar sweeps, the confirmation chain, the pending correction
and the last event's odometry (a continued mission must use the same odometry frame).
"""
from __future__ import annotations

import bisect
import heapq
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.sparse.linalg import splu

from common.config import ExpMapConfig
from services.expmap.scans import Registration, register_sweeps

__all__ = ["ExperienceMap", "EventResult", "quickest_path", "quickest_path_links", "pc_distance_cells"]

FORMAT_VERSION = 1


# --------------------------------------------------------------------------- kernels


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


def pc_distance_cells(a: np.ndarray, b: np.ndarray, shape: tuple[int, int, int, int],
                      spacing: tuple[float, float, float]) -> float:
    """Wrap-aware distance (lattice cells) between two pose-cell centroids [x, y, z m, yaw rad]."""
    period, cell = _lattice(shape, spacing)
    d = np.abs(np.asarray(a, float) - np.asarray(b, float)) % period
    d = np.minimum(d, period - d) / cell
    return float(np.sqrt(np.sum(d * d)))


def _lattice(shape, spacing) -> tuple[np.ndarray, np.ndarray]:
    cell = np.array([spacing[0], spacing[1], spacing[2], 2.0 * math.pi / shape[3]], float)
    period = np.array([shape[0] * spacing[0], shape[1] * spacing[1], shape[2] * spacing[2], 2.0 * math.pi], float)
    return period, cell


# --------------------------------------------------------------------------- the map


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
    step_capped: bool = False       # max_correction_step limited an iteration
    settled: bool = False           # a pending correction finished during this event


@dataclass
class _Grow:
    """Append-only column store with amortised doubling."""

    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    n: int = 0

    def add(self, name: str, shape: tuple[int, ...], dtype) -> None:
        self.arrays[name] = np.zeros((64,) + shape, dtype)

    def reserve(self, n: int) -> None:
        cap = next(iter(self.arrays.values())).shape[0]
        if n <= cap:
            return
        while cap < n:
            cap *= 2
        for k, a in self.arrays.items():
            b = np.zeros((cap,) + a.shape[1:], a.dtype)
            b[: self.n] = a[: self.n]
            self.arrays[k] = b


class ExperienceMap:
    """The experience graph of Section 4.2.4 (see the module docstring for every rule)."""

    def __init__(self, cfg: ExpMapConfig, lattice_shape=(15, 15, 15, 8), lattice_spacing=(0.1, 0.1, 0.1)):
        self.cfg = cfg
        self.lattice_shape = tuple(int(v) for v in lattice_shape)
        self.lattice_spacing = tuple(float(v) for v in lattice_spacing)
        if len(self.lattice_shape) != 4 or len(self.lattice_spacing) != 3:
            raise ValueError("posecells.number_of_neurons needs 4 values and distance_between_neurons 3")
        self._period, self._cell = _lattice(self.lattice_shape, self.lattice_spacing)
        g = _Grow()
        g.add("pos", (3,), np.float64)       # map position (m)
        g.add("delta", (3,), np.float64)     # odometry increment from the previous node (edge k-1 -> k)
        g.add("cum", (3,), np.float64)       # sum of the increments up to the node
        g.add("cumres", (), np.float64)      # sum of 1/w of the odometry edges up to the node
        g.add("weight", (), np.float64)      # w of edge k-1 -> k
        g.add("yaw", (), np.float64)
        g.add("lvc", (), np.int64)
        g.add("pc", (4,), np.float64)
        g.add("stamp", (), np.int64)
        g.add("rem", (3,), np.float64)       # correction being applied (m): position = pos + phi * rem
        self._g = g
        self.loops: list[tuple[int, int, float, int]] = []   # (m, n, weight, stamp)
        self.loop_deltas: list[np.ndarray] = []   # per loop edge: p_n - p_m it asks for (m); zero by default
        self._lvc_index: dict[int, list[int]] = {}
        self._loop_ends: list[int] = []              # sorted distinct loop-edge endpoints
        self._loop_adj: dict[int, list[int]] = {}    # loop-edge endpoint -> other ends
        self._loop_csr: tuple | None = None
        self._route_cache: tuple[int, int, int] | None = None   # (m, n, upper bound of their route)
        self._phi = 0.0                      # fraction of the pending correction applied
        self._peak = 0.0                     # largest node displacement of the pending correction (m)
        self.last_odom: np.ndarray | None = None
        self.last_match = -1
        self.confirmations = 0
        self.last_correction_stamp = -1
        self.corrections = 0
        self.solves = 0
        self._scans: list[np.ndarray | None] = []    # per node: sonar sweep around its odometry position
        self.scan_registrations = {"trusted": 0, "partial": 0, "untrusted": 0, "no_sweep": 0}
        self.last_registration: Registration | None = None

    # ---- read access --------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self._g.n

    def _a(self, name: str) -> np.ndarray:
        return self._g.arrays[name][: self._g.n]

    @property
    def positions(self) -> np.ndarray:
        """Map positions (m), N x 3 (a copy while a correction is being applied)."""
        if self._peak > 0.0:
            return self._a("pos") + self._phi * self._a("rem")
        return self._a("pos")

    def _position(self, i) -> np.ndarray:
        A = self._g.arrays
        return A["pos"][i] + self._phi * A["rem"][i] if self._peak > 0.0 else A["pos"][i]

    @property
    def stamps(self) -> np.ndarray:
        return self._a("stamp")

    @property
    def lvc_ids(self) -> np.ndarray:
        return self._a("lvc")

    @property
    def yaws(self) -> np.ndarray:
        return self._a("yaw")

    @property
    def deltas(self) -> np.ndarray:
        return self._a("delta")

    @property
    def edge_weights(self) -> np.ndarray:
        return self._a("weight")

    @property
    def pending(self) -> bool:
        """A correction is still being applied."""
        return self._peak > 0.0

    def edges(self) -> list[tuple[int, int, np.ndarray, float, float, bool]]:
        """Every edge as (source, target, delta m, duration s, weight, loop_closure)."""
        out = []
        st, d, w = self.stamps, self.deltas, self.edge_weights
        for k in range(1, self.n_nodes):
            out.append((k - 1, k, d[k].copy(), (int(st[k]) - int(st[k - 1])) * 1e-9, float(w[k]), False))
        for (m, n, wl, _s), dl in zip(self.loops, self.loop_deltas):
            out.append((m, n, dl.copy(), 0.0, wl, True))
        return out

    # ---- the event ----------------------------------------------------------------
    def add_event(self, stamp: int, lvc_id: int, pc_centroid, odom_position, odom_yaw: float,
                  sweep: np.ndarray | None = None) -> EventResult:
        """Create the node of one accepted event, look for a loop, relax (one event's iterations).

        ``sweep``: the sonar points (k x 2, m) around the event's odometry position
        (:meth:`services.expmap.scans.SweepBuffer.sweep`), kept to measure loop displacements."""
        cfg, g = self.cfg, self._g
        odom = np.asarray(odom_position, np.float64)
        pc = np.asarray(pc_centroid, np.float64)
        if odom.shape != (3,) or pc.shape != (4,) or not (np.all(np.isfinite(odom)) and np.all(np.isfinite(pc))):
            raise ValueError(f"experience event at stamp {stamp}: odom_position needs 3 and pc_centroid 4 finite "
                             f"values, got {odom_position} and {pc_centroid}")
        n = g.n
        g.reserve(n + 1)
        A = g.arrays
        if n == 0:
            A["pos"][0] = odom
            A["delta"][0] = 0.0
            A["cum"][0] = 0.0
            A["cumres"][0] = 0.0
            A["weight"][0] = 0.0
        else:
            delta = odom - self.last_odom
            A["delta"][n] = delta
            A["pos"][n] = A["pos"][n - 1] + delta
            A["cum"][n] = A["cum"][n - 1] + delta
            A["weight"][n] = 1.0
            A["cumres"][n] = A["cumres"][n - 1] + 1.0
            A["rem"][n] = A["rem"][n - 1]    # a new node follows its predecessor's correction
        A["yaw"][n] = float(odom_yaw)
        A["lvc"][n] = int(lvc_id)
        A["pc"][n] = pc
        A["stamp"][n] = int(stamp)
        g.n = n + 1
        self.last_odom = odom.copy()
        self._lvc_index.setdefault(int(lvc_id), []).append(n)
        self._scans.append(None if sweep is None or len(sweep) == 0 else np.asarray(sweep, np.float32).reshape(-1, 2))

        res = EventResult(node=n)
        self._loop_search(n, res)
        if res.confirmations >= cfg.loop_confirmations:
            self._try_close(n, res)
        self._relax(res, cfg.relax_iterations_per_event)
        return res

    def _loop_search(self, n: int, res: EventResult) -> None:
        cfg = self.cfg
        cutoff = n - cfg.min_experience_age
        if cutoff < 0:
            self.last_match, self.confirmations = -1, 0
            return
        if cfg.pc_factor < cfg.match_threshold:
            ids = self._lvc_index[int(self._a("lvc")[n])]
            cand = np.asarray(ids[: bisect.bisect_right(ids, cutoff)], np.int64)
        else:
            cand = np.arange(cutoff + 1, dtype=np.int64)
        if cand.size == 0:
            self.last_match, self.confirmations = -1, 0
            return
        scores = _pc_scores(cand, self._g.arrays["pc"], self._g.arrays["lvc"], self._a("pc")[n],
                            int(self._a("lvc")[n]), self._period, self._cell, cfg.lv_factor, cfg.pc_factor,
                            cfg.pc_proximity_sigma_cells)
        ok = scores >= cfg.match_threshold
        if not np.any(ok):
            self.last_match, self.confirmations = -1, 0
            return
        matches, mscores = cand[ok], scores[ok]
        chosen = -1
        if self.last_match >= 0 and self.confirmations > 0:
            gap = np.abs(matches - self.last_match)
            j = int(np.argmin(gap))          # first minimum: the oldest among equals
            if gap[j] <= cfg.loop_confirmation_gap:
                chosen = j
                self.confirmations += 1
        if chosen < 0:
            chosen = int(np.argmax(mscores))  # first maximum: the oldest among equals
            self.confirmations = 1
        self.last_match = int(matches[chosen])
        res.match, res.score, res.confirmations = self.last_match, float(mscores[chosen]), self.confirmations

    def route_length(self, a: int, b: int, limit: int | None = None) -> int:
        """Edges on the shortest route between nodes a and b (a loop edge counts 1).

        Dijkstra over junctions only (numba): from a node the chain leads to the nearest
        loop endpoint (or a, b) on either side, weighing the number of odometry edges
        between; a loop edge leads to its other end.  ``limit``: stop once the answer is
        known to be >= limit, so a query explores only the junctions within ``limit`` edges.
        """
        if a == b:
            return 0
        if self._loop_csr is None:
            ends = np.asarray(self._loop_ends, np.int64)
            ptr = np.zeros(ends.size + 1, np.int64)
            for i, e in enumerate(self._loop_ends):
                ptr[i + 1] = ptr[i] + len(self._loop_adj[e])
            idx = np.array([v for e in self._loop_ends for v in self._loop_adj[e]], np.int64)
            self._loop_csr = (ends, ptr, idx)
        ends, ptr, idx = self._loop_csr
        lim = (1 << 62) if limit is None else int(limit)
        return int(_route_dijkstra(int(a), int(b), lim, self.n_nodes, ends, ptr, idx))

    def add_loop_edge(self, m: int, n: int, weight: float, stamp: int, delta=None) -> None:
        """Record a loop edge m -> n asking p_n - p_m = ``delta`` (default zero: the same place).
        No rules, no relaxation: the loop-closure path calls it, and tools can join known
        places before :meth:`optimum`."""
        if not (0 <= m < self.n_nodes and 0 <= n < self.n_nodes) or m == n:
            raise ValueError(f"loop edge {m} -> {n}: nodes must be distinct ids in 0..{self.n_nodes - 1}")
        self.loops.append((m, n, weight, stamp))
        self.loop_deltas.append(np.zeros(3) if delta is None else np.asarray(delta, np.float64).reshape(3).copy())
        self._loop_csr = None
        self._route_cache = None
        for x, y in ((m, n), (n, m)):
            if x not in self._loop_adj:
                bisect.insort(self._loop_ends, x)
            self._loop_adj.setdefault(x, []).append(y)

    def _try_close(self, n: int, res: EventResult) -> None:
        cfg = self.cfg
        m = res.match
        stamp = int(self._a("stamp")[n])
        if self.last_correction_stamp >= 0 and (stamp - self.last_correction_stamp) < cfg.min_correction_interval_sec * 1e9:
            res.rejected = "interval"
            return
        # route rule; consecutive events of a confirmed chain ask about (m+1, n+1) after (m, n):
        # the previous answer plus the chain steps bounds the route from above, so most
        # rejections need no search
        bound = 1 << 62
        if self._route_cache is not None:
            a0, b0, d0 = self._route_cache
            bound = d0 + abs(m - a0) + abs(n - b0)
        if bound >= cfg.min_correction_route_len:
            bound = self.route_length(m, n, limit=math.ceil(cfg.min_correction_route_len))
        self._route_cache = (m, n, bound)
        if bound < cfg.min_correction_route_len:
            res.rejected = "route"
            return
        delta = self.loop_delta(m, n)
        if delta is None:
            res.rejected = "scan"
            return
        self.add_loop_edge(m, n, float(cfg.loop_edge_weight), stamp, delta)
        self.corrections += 1
        self.last_correction_stamp = stamp
        self.confirmations = 0
        res.loop_closed = True
        target = self.optimum()
        self._apply_pending()
        disp = target - self._a("pos")
        norms = np.sqrt(np.sum(disp * disp, axis=1))
        peak = float(norms.max()) if norms.size else 0.0
        if peak > cfg.max_correction_norm:
            disp *= cfg.max_correction_norm / peak
            res.correction_clamped = True
        res.correction_norm = min(peak, cfg.max_correction_norm)
        self._g.arrays["rem"][: self.n_nodes] = disp
        self._phi = 0.0
        self._peak = float(np.sqrt(np.max(np.sum(disp * disp, axis=1)))) if disp.size else 0.0
        if self._peak <= 0.0:
            self._g.arrays["rem"][: self.n_nodes] = 0.0

    def loop_delta(self, m: int, n: int) -> np.ndarray | None:
        """Displacement p_n - p_m a loop closure of m and n asks for (Eq. 4.20's Delta p of the
        loop edge), or None when the sonar contradicts the recognition.

        With ``loop_scan_matching`` and a sonar sweep kept with both experiences, the sweeps are
        registered (:func:`services.expmap.scans.register_sweeps`): a trusted registration gives
        the horizontal displacement (along an ambiguous axis, e.g. along a straight tunnel, the
        map's current separation is kept) and the odometry gives the vertical one (pressure
        depth is absolute).  Otherwise the dissertation's rule: a recognised place is the same
        place, zero displacement; with ``loop_place_radius_m`` r > 0 the edge keeps the current
        separation d when |d| <= r and asks for d r / |d| beyond (pulls the two to r apart).
        Geometric verification (``scan_reject_inconsistent``): when both sweeps have enough
        echoes but fewer than ``scan_min_inlier_fraction`` of them fit after the best
        alignment, the two experiences do not see the same walls: None (the closure is
        rejected, counted as ``loop_rejected_scan`` by the node).  Sweeps without walls in
        range or ambiguous in every direction prove nothing and fall back to the rule below.
        """
        cfg = self.cfg
        d = self._position(n) - self._position(m)
        self.last_registration = None
        if cfg.loop_scan_matching:
            a, b = self._scans[m], self._scans[n]
            if a is None or b is None:
                self.scan_registrations["no_sweep"] += 1
            else:
                reg = register_sweeps(a, b, d[:2], cell_m=cfg.scan_cell_m, search_radius_m=cfg.scan_search_radius_m,
                                      max_rotation_deg=cfg.scan_max_rotation_deg,
                                      rotation_step_deg=cfg.scan_rotation_step_deg, min_points=cfg.scan_min_points,
                                      min_inlier_fraction=cfg.scan_min_inlier_fraction,
                                      ambiguity_margin_m=cfg.scan_ambiguity_margin_m,
                                      max_ambiguity_m=cfg.scan_max_ambiguity_m)
                self.last_registration = reg
                if reg.trusted:
                    t = reg.translation.copy()
                    if reg.ambiguous_axis is not None:
                        u = reg.ambiguous_axis
                        t = t + u * float(u @ (d[:2] - t))
                        self.scan_registrations["partial"] += 1
                    else:
                        self.scan_registrations["trusted"] += 1
                    cum = self._a("cum")
                    return np.array([t[0], t[1], cum[n, 2] - cum[m, 2]])
                self.scan_registrations["untrusted"] += 1
                if reg.inconsistent and cfg.scan_reject_inconsistent:
                    return None
        r = float(cfg.loop_place_radius_m)
        if r <= 0.0:
            return np.zeros(3)
        norm = float(np.sqrt(np.sum(d * d)))
        return d if norm <= r else d * (r / norm)

    def _apply_pending(self) -> None:
        """Make the blend of a pending correction the base positions (O(nodes))."""
        if self._peak > 0.0:
            A, n = self._g.arrays, self.n_nodes
            A["pos"][:n] += self._phi * A["rem"][:n]
            A["rem"][:n] = 0.0
            self._phi, self._peak = 0.0, 0.0

    def optimum(self) -> np.ndarray:
        """Node positions minimising Eq. 4.20 with node 0 fixed (exact, by series reduction)."""
        n = self.n_nodes
        if n == 0:
            return np.zeros((0, 3))
        cum, cumres = self._a("cum"), self._a("cumres")
        term = np.array(sorted({0, n - 1} | {m for m, _n, _w, _s in self.loops} | {k for _m, k, _w, _s in self.loops}),
                        np.int64)
        J = term.size
        # unknowns: junctions 1..J-1 -> 0..J-2; junction 0 (node 0) is fixed -> index J-1
        unk = np.arange(J, dtype=np.int64) - 1
        unk[0] = J - 1
        n_free = J - 1
        if n_free == 0:
            return _interpolate(term, self._position(0)[None, :].copy(), cum, cumres, n)
        # reduced edges: chain segments between consecutive junctions (series reduction), loop edges
        lp = np.array([(m, k, w) for m, k, w, _s in self.loops], np.float64).reshape(-1, 3)
        ea_a = np.concatenate([unk[:-1], unk[np.searchsorted(term, lp[:, 0].astype(np.int64))]])
        eb_a = np.concatenate([unk[1:], unk[np.searchsorted(term, lp[:, 1].astype(np.int64))]])
        eg_a = np.concatenate([1.0 / np.diff(cumres[term]), lp[:, 2]])
        ed_a = np.concatenate([np.diff(cum[term], axis=0), np.asarray(self.loop_deltas, np.float64).reshape(-1, 3)])
        fixed = self._position(0).copy()
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
        # deterministic); ~5 ms for 1600 junctions, where Jacobi-CG needed ~1400 iterations
        x = splu(lap, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True}).solve(rhs[:n_free])
        self.solves += 1
        term_pos = np.vstack([fixed[None, :], x])
        return _interpolate(term, term_pos, cum, cumres, n)

    def _relax(self, res: EventResult, iterations: int) -> None:
        """Run up to ``iterations`` relaxation iterations of the pending correction.

        Each iteration moves every node by the same fraction of its correction, the node with
        the largest correction by ``max_correction_step`` (or what is left of it), so the map
        stays a blend ``pos + phi * rem`` of the old map and the target: the iterations of one
        event add up to one update of phi, O(1) until the map is read.
        """
        if self._peak <= 0.0:
            return
        step = self.cfg.max_correction_step
        left = (1.0 - self._phi) * self._peak
        if left <= iterations * step:
            res.iterations += max(1, math.ceil(left / step - 1e-9))
            res.step_max = max(res.step_max, min(left, step))
            self._phi = 1.0
            self._apply_pending()
            res.settled = True
        else:
            res.iterations += iterations
            res.step_max = max(res.step_max, step)
            res.step_capped = True
            self._phi += iterations * step / self._peak

    def settle(self) -> int:
        """Finish a pending correction (every iteration still capped); returns iterations run."""
        res = EventResult(node=self.n_nodes - 1)
        if self._peak > 0.0:
            self._relax(res, math.ceil((1.0 - self._phi) * self._peak / self.cfg.max_correction_step) + 1)
        return res.iterations

    # ---- persistence ----------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write everything needed to continue the map (npz)."""
        meta = {
            "format": FORMAT_VERSION, "lattice_shape": list(self.lattice_shape),
            "lattice_spacing": list(self.lattice_spacing), "last_match": self.last_match,
            "confirmations": self.confirmations, "last_correction_stamp": self.last_correction_stamp,
            "corrections": self.corrections, "solves": self.solves,
            "phi": self._phi, "peak": self._peak,
        }
        arrays = {k: self._a(k) for k in self._g.arrays}
        loops = np.array([(m, n, s) for m, n, _w, s in self.loops], np.int64).reshape(-1, 3)
        loop_w = np.array([w for _m, _n, w, _s in self.loops], np.float64)
        loop_d = np.asarray(self.loop_deltas, np.float64).reshape(-1, 3)
        last_odom = self.last_odom if self.last_odom is not None else np.full(3, np.nan)
        sweeps = [np.zeros((0, 2), np.float32) if a is None else a for a in self._scans]
        sweep_ptr = np.concatenate([[0], np.cumsum([len(a) for a in sweeps])]).astype(np.int64)
        sweep_pts = np.concatenate(sweeps).astype(np.float32) if sweeps else np.zeros((0, 2), np.float32)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), loops=loops, loop_weight=loop_w, loop_delta=loop_d,
                 last_odom=last_odom, sweep_ptr=sweep_ptr, sweep_pts=sweep_pts, **arrays)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, cfg: ExpMapConfig, lattice_shape=(15, 15, 15, 8),
             lattice_spacing=(0.1, 0.1, 0.1)) -> "ExperienceMap":
        """Read a map written by :meth:`save`; the lattice must match the saved one."""
        path = Path(path)
        z, meta = read_map_file(path, "an experience map")
        if meta.get("format") != FORMAT_VERSION:
            raise ValueError(f"{path}: map format {meta.get('format')} (this build reads {FORMAT_VERSION})")
        if list(meta["lattice_shape"]) != [int(v) for v in lattice_shape] or \
                not np.allclose(meta["lattice_spacing"], lattice_spacing):
            raise ValueError(f"{path}: saved with pose-cell lattice {meta['lattice_shape']} x "
                             f"{meta['lattice_spacing']} m, configured {list(lattice_shape)} x {list(lattice_spacing)}")
        em = cls(cfg, lattice_shape, lattice_spacing)
        n = int(z["pos"].shape[0])
        em._g.reserve(max(n, 1))
        for k in em._g.arrays:
            if k not in z:
                raise ValueError(f"{path}: missing array {k!r}")
            em._g.arrays[k][:n] = z[k]
        em._g.n = n
        deltas = z["loop_delta"] if "loop_delta" in z else np.zeros((len(z["loops"]), 3))
        for (m, k, s), w, dl in zip(z["loops"], z["loop_weight"], deltas):
            em.add_loop_edge(int(m), int(k), float(w), int(s), dl)
        em._phi, em._peak = float(meta["phi"]), float(meta["peak"])
        lo = z["last_odom"]
        em.last_odom = None if np.any(np.isnan(lo)) else lo.astype(np.float64)
        em.last_match = int(meta["last_match"])
        em.confirmations = int(meta["confirmations"])
        em.last_correction_stamp = int(meta["last_correction_stamp"])
        em.corrections = int(meta["corrections"])
        em.solves = int(meta["solves"])
        for i, l in enumerate(em.lvc_ids.tolist()):
            em._lvc_index.setdefault(int(l), []).append(i)
        if "sweep_ptr" in z:                      # maps saved before sonar sweeps existed have none
            ptr, pts = z["sweep_ptr"], z["sweep_pts"]
            if len(ptr) != n + 1:
                raise ValueError(f"{path}: {len(ptr) - 1} sonar sweeps for {n} experiences")
            em._scans = [pts[ptr[i]:ptr[i + 1]].copy() if ptr[i + 1] > ptr[i] else None for i in range(n)]
        else:
            em._scans = [None] * n
        return em


def read_map_file(path: Path, what: str) -> tuple[Any, dict]:
    """The arrays and the ``meta`` JSON record of a map file written by a ``save`` (npz);
    ValueError naming the file when it is not one (``what``: the kind, for the message)."""
    try:
        z = np.load(path, allow_pickle=False)
        return z, json.loads(bytes(z["meta"]).decode())
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: not {what} file ({exc})") from None


# --------------------------------------------------------------------------- path planning


def quickest_path(em: ExperienceMap, source: int, target: int) -> tuple[list[int], float, float]:
    """Quickest path over the map's edges (see :func:`quickest_path_links`)."""
    return quickest_path_links(em.positions, [(s, t, d) for s, t, _dl, d, _w, _l in em.edges()], source, target)


def quickest_path_links(positions: np.ndarray, links, source: int, target: int) -> tuple[list[int], float, float]:
    """Dijkstra over edge durations, each edge usable both ways (a loop edge takes 0 s).

    ``links``: (source, target, duration s).  Returns (node ids from source to target, total
    duration s, length m along the map positions).  Raises ValueError for an unknown node or
    when no route exists.
    """
    n = len(positions)
    for name, v in (("from", source), ("to", target)):
        if not 0 <= v < n:
            raise ValueError(f"--{name} {v}: the map has nodes 0..{n - 1}")
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for s, t, d in links:
        d = max(float(d), 0.0)
        adj[int(s)].append((int(t), d))
        adj[int(t)].append((int(s), d))
    dist = [math.inf] * n
    prev = [-1] * n
    dist[source] = 0.0
    heap = [(0.0, source)]
    while heap:
        d, u = heapq.heappop(heap)
        if u == target:
            break
        if d > dist[u]:
            continue
        for v, w in adj[u]:
            nd = d + w
            if nd < dist[v]:
                dist[v] = nd
                prev[v] = u
                heapq.heappush(heap, (nd, v))
    if not math.isfinite(dist[target]):
        raise ValueError(f"no route from node {source} to node {target}")
    path = [target]
    while path[-1] != source:
        path.append(prev[path[-1]])
    path.reverse()
    p = np.asarray(positions, float)[path]
    length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(path) > 1 else 0.0
    return path, float(dist[target]), length
