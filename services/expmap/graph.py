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
  same-LVC node matches iff its centroid is within one cell).  When
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
  the pose-cell offset is not used because the lattice wraps every 1.5 m and its centroid
  is itself pulled toward the stored pose) and weight ``loop_edge_weight``, duration 0 s.

Relaxation: the target is the exact weighted least-squares optimum of Eq. 4.20 with node 0
fixed, not OpenRatSLAM's half-error sweep.  Because every node but the first has an
odometry edge from its predecessor, the graph is one chain plus the loop edges: only the
loop endpoints (and the two chain ends) are junctions.  A chain segment between junctions
a, b is equivalent to one edge with the summed delta and resistance sum(1/w) (series
reduction), so the optimum is found by solving the small reduced system over the
junctions (Jacobi-preconditioned conjugate gradients) and then placing every segment's
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

Save/load (:meth:`save`, :meth:`load`, npz) keeps everything needed to continue: nodes,
odometry increments, loop edges, the confirmation chain, the pending correction and the
last event's odometry (a continued mission must use the same odometry frame).
"""
from __future__ import annotations

import bisect
import heapq
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

from common.config import ExpMapConfig

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
def _reduced_cg(n_free: int, ea: np.ndarray, eb: np.ndarray, eg: np.ndarray, rhs: np.ndarray,
                x0: np.ndarray, tol: float, max_iter: int) -> tuple:
    """Solve L x = rhs (L: weighted Laplacian of edges (ea, eb, eg) among free unknowns
    0..n_free-1; an endpoint index >= n_free is a fixed node whose term is already in rhs)
    by Jacobi-preconditioned conjugate gradients, one column at a time."""
    diag = np.zeros(n_free)
    for e in range(ea.size):
        if ea[e] < n_free:
            diag[ea[e]] += eg[e]
        if eb[e] < n_free:
            diag[eb[e]] += eg[e]
    x = x0.copy()
    iters = 0
    for col in range(rhs.shape[1]):
        b = rhs[:, col]
        xc = x[:, col].copy()
        r = b.copy()
        for e in range(ea.size):  # r = b - L x
            a, c, g = ea[e], eb[e], eg[e]
            xa = xc[a] if a < n_free else 0.0
            xb = xc[c] if c < n_free else 0.0
            if a < n_free:
                r[a] -= g * (xa - xb)
            if c < n_free:
                r[c] -= g * (xb - xa)
        bnorm = math.sqrt(np.sum(b * b)) + 1e-300
        z = r / diag
        p = z.copy()
        rz = np.sum(r * z)
        for it in range(max_iter):
            if math.sqrt(np.sum(r * r)) <= tol * bnorm:
                break
            q = np.zeros(n_free)
            for e in range(ea.size):
                a, c, g = ea[e], eb[e], eg[e]
                pa = p[a] if a < n_free else 0.0
                pb = p[c] if c < n_free else 0.0
                if a < n_free:
                    q[a] += g * (pa - pb)
                if c < n_free:
                    q[c] += g * (pb - pa)
            alpha = rz / np.sum(p * q)
            xc += alpha * p
            r -= alpha * q
            z = r / diag
            rz_new = np.sum(r * z)
            p = z + (rz_new / rz) * p
            rz = rz_new
            iters += 1
        x[:, col] = xc
    return x, iters


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
    rejected: str = ""              # "interval" | "route" when a confirmed loop was not closed
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
        self._lvc_index: dict[int, list[int]] = {}
        self._phi = 0.0                      # fraction of the pending correction applied
        self._peak = 0.0                     # largest node displacement of the pending correction (m)
        self.last_odom: np.ndarray | None = None
        self.last_match = -1
        self.confirmations = 0
        self.last_correction_stamp = -1
        self.corrections = 0
        self.cg_iterations = 0

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
        for m, n, wl, _s in self.loops:
            out.append((m, n, np.zeros(3), 0.0, wl, True))
        return out

    # ---- the event ----------------------------------------------------------------
    def add_event(self, stamp: int, lvc_id: int, pc_centroid, odom_position, odom_yaw: float) -> EventResult:
        """Create the node of one accepted event, look for a loop, relax (one event's iterations)."""
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
        """Edges on the shortest route between nodes a and b (loop edges count 1 each).

        Dijkstra over the junction graph: the chain segments between consecutive loop
        endpoints weigh their number of edges.  ``limit``: stop once the answer is >= limit.
        """
        if a == b:
            return 0
        term = sorted({a, b} | {m for m, _n, _w, _s in self.loops} | {n for _m, n, _w, _s in self.loops})
        idx = {t: i for i, t in enumerate(term)}
        adj: list[list[tuple[int, int]]] = [[] for _ in term]
        for i in range(len(term) - 1):
            w = term[i + 1] - term[i]
            adj[i].append((i + 1, w))
            adj[i + 1].append((i, w))
        for m, n, _w, _s in self.loops:
            adj[idx[m]].append((idx[n], 1))
            adj[idx[n]].append((idx[m], 1))
        dist = {idx[a]: 0}
        heap = [(0, idx[a])]
        goal = idx[b]
        while heap:
            d, u = heapq.heappop(heap)
            if u == goal:
                return d
            if limit is not None and d >= limit:
                return d
            if d > dist.get(u, 1 << 62):
                continue
            for v, w in adj[u]:
                nd = d + w
                if nd < dist.get(v, 1 << 62):
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
        return 1 << 62  # not connected

    def _try_close(self, n: int, res: EventResult) -> None:
        cfg = self.cfg
        m = res.match
        stamp = int(self._a("stamp")[n])
        if self.last_correction_stamp >= 0 and (stamp - self.last_correction_stamp) < cfg.min_correction_interval_sec * 1e9:
            res.rejected = "interval"
            return
        limit = math.ceil(cfg.min_correction_route_len)
        if self.route_length(m, n, limit=limit) < cfg.min_correction_route_len:
            res.rejected = "route"
            return
        self.loops.append((m, n, float(cfg.loop_edge_weight), stamp))
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
        where = {int(t): i for i, t in enumerate(term)}
        ea, eb, eg, ed = [], [], [], []
        for i in range(J - 1):
            a, b = int(term[i]), int(term[i + 1])
            ea.append(unk[i]); eb.append(unk[i + 1])
            eg.append(1.0 / (cumres[b] - cumres[a])); ed.append(cum[b] - cum[a])
        for m, k, w, _s in self.loops:
            ea.append(unk[where[m]]); eb.append(unk[where[k]])
            eg.append(w); ed.append(np.zeros(3))
        ea_a, eb_a = np.array(ea, np.int64), np.array(eb, np.int64)
        eg_a, ed_a = np.array(eg, np.float64), np.array(ed, np.float64).reshape(-1, 3)
        fixed = self._position(0).copy()
        rhs = np.zeros((n_free, 3))
        # normal equations of sum g ||x_b - x_a - D||^2
        for e in range(ea_a.size):
            a, b, gg, D = ea_a[e], eb_a[e], eg_a[e], ed_a[e]
            if b < n_free:
                rhs[b] += gg * D
                if a >= n_free:
                    rhs[b] += gg * fixed
            if a < n_free:
                rhs[a] -= gg * D
                if b >= n_free:
                    rhs[a] += gg * fixed
        x0 = np.array([self._position(int(t)) for t in term[1:]]).reshape(-1, 3)
        x, iters = _reduced_cg(n_free, ea_a, eb_a, eg_a, rhs, x0, 1e-12, 20 * J + 200)
        self.cg_iterations += int(iters)
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
            "corrections": self.corrections, "cg_iterations": self.cg_iterations,
            "phi": self._phi, "peak": self._peak,
        }
        arrays = {k: self._a(k) for k in self._g.arrays}
        loops = np.array([(m, n, s) for m, n, _w, s in self.loops], np.int64).reshape(-1, 3)
        loop_w = np.array([w for _m, _n, w, _s in self.loops], np.float64)
        last_odom = self.last_odom if self.last_odom is not None else np.full(3, np.nan)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), loops=loops, loop_weight=loop_w,
                 last_odom=last_odom, **arrays)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, cfg: ExpMapConfig, lattice_shape=(15, 15, 15, 8),
             lattice_spacing=(0.1, 0.1, 0.1)) -> "ExperienceMap":
        """Read a map written by :meth:`save`; the lattice must match the saved one."""
        path = Path(path)
        try:
            z = np.load(path, allow_pickle=False)
            meta = json.loads(bytes(z["meta"]).decode())
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"{path}: not an experience map file ({exc})") from None
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
        em.loops = [(int(m), int(k), float(w), int(s)) for (m, k, s), w in zip(z["loops"], z["loop_weight"])]
        em._phi, em._peak = float(meta["phi"]), float(meta["peak"])
        lo = z["last_odom"]
        em.last_odom = None if np.any(np.isnan(lo)) else lo.astype(np.float64)
        em.last_match = int(meta["last_match"])
        em.confirmations = int(meta["confirmations"])
        em.last_correction_stamp = int(meta["last_correction_stamp"])
        em.corrections = int(meta["corrections"])
        em.cg_iterations = int(meta["cg_iterations"])
        for i, l in enumerate(em.lvc_ids.tolist()):
            em._lvc_index.setdefault(int(l), []).append(i)
        return em


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
