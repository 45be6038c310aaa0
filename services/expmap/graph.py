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
  loop when both match and their matched nodes are at most ``loops.confirmation_gap``
  experiences apart on the old route (either direction, so a route driven backwards
  confirms too); the event chooses, among its matches, the one closest to the previous
  match, else the best score (ties: the oldest).  A loop is closed between n and its match
  m when ``loops.confirmations`` consecutive events confirmed it, at least
  ``corrections.min_interval_sec`` of event time passed since the last correction, and the
  route between m and n is at least ``corrections.min_route_len`` experiences long.
  Route length is counted in experiences (edges) along the shortest route of the current
  graph, loop edges included: the same unit as ``min_experience_age`` and independent of
  drift; after an earlier closure it is shorter than the age, which is what keeps a
  second closure from re-closing a loop that is already closed.  A closure resets the
  confirmation count.
- the loop edge goes from m to n with zero displacement (an LVC match says "same place";
  measured by sonar instead when available, see below;
  the pose-cell offset is not used because the lattice wraps every 1.5 m and its centroid
  is itself pulled toward the stored pose) and weight ``loops.edge_weight``, duration 0 s.

Relaxation: the target is the exact weighted least-squares optimum of Eq. 4.20 with node 0
fixed (not OpenRatSLAM's half-error sweep), found by series reduction of the chain between
loop endpoints; the map moves toward it by capped iterations (``corrections.max_norm``,
``corrections.max_step``, ``corrections.iterations_per_event``; :meth:`ExperienceMap.settle`
finishes a pending correction).  Every rule and its cost: :mod:`services.expmap.relaxation`.

Odometry scale: :meth:`ExperienceMap.set_odometry_scale` multiplies the horizontal
displacement of this run's odometry edges by the camera's measure of the odometry's scale
(:mod:`services.expmap.visual_scale`), retroactively, and relaxes toward the new optimum.

Loop-edge displacement: with ``loops.scan_matching`` each node keeps the sonar sweep around
its odometry position and a closure's edge asks for the displacement measured by registering
the two sweeps (:mod:`services.expmap.scans`; a departure from the zero displacement above,
which stays the fallback when a sweep is missing or the registration is not trusted).

State and save/load: :meth:`ExperienceMap.state` gives everything needed to continue the map
as an :class:`~services.expmap.state.ExperienceMapState` (nodes, odometry increments, loop
edges, sonar sweeps, the confirmation chain, the pending correction, the last event's odometry,
the sessions), :meth:`ExperienceMap.load_state` takes one; :meth:`save` and :meth:`load` write
and read it as a file (npz, :mod:`services.expmap.storage`).

Sessions: a map continued by another mission (``poseidon run --map-dir``) or a
vehicle whose odometry jumps by more than ``sessions.jump_m`` (kidnapped) begins a new session
(:meth:`ExperienceMap.begin_session`), unlinked to the earlier ones until a link verified by
the sonar joins them; the rules are in :mod:`services.expmap.session_link`.

Code by concern: candidates and scores in :mod:`services.expmap.candidates`; loop edges,
the route rule and the sweep verification in :mod:`services.expmap.loop_policy`; the
Eq. 4.20 solver and the capped blend in :mod:`services.expmap.relaxation`; the node columns
and the map file in :mod:`services.expmap.storage`; quickest paths in
:mod:`services.expmap.routes`; session links in :mod:`services.expmap.session_link`.  :class:`ExperienceMap` holds the state and applies the rules
in order for each event.

(Over 500 lines because the class holds the map's state and applies every rule to it in order:
the rules' arithmetic lives in the modules above, and what remains (the event, the loop and link
policy, the relaxation's bookkeeping, the public state) shares that one state.)
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from services.expmap.candidates import candidate_nodes, choose_match, lattice_geometry, match_scores, pc_distance_cells
from services.expmap.config import ExpMapConfig
from services.expmap.gtsam_graph import relaxation_optimum
from services.expmap.loop_policy import EventResult, LoopEdges, link_displacement, loop_displacement
from services.expmap.relaxation import plan_correction, relax_fraction, rescale_edges
from services.expmap.routes import quickest_path, quickest_path_links
from services.expmap.scans import Registration
from services.expmap.session_link import SESSION_BREAK_WEIGHT, SessionLink, backfill, move_component, rot2
from services.expmap.state import NODE_COLUMNS, ExperienceMapState
from services.expmap.storage import FORMAT_VERSION, ColumnStore, SweepStore, load_map, read_map_file, save_map

__all__ = ["ExperienceMap", "ExperienceMapState", "EventResult", "quickest_path", "quickest_path_links", "pc_distance_cells",
           "read_map_file", "FORMAT_VERSION"]


class ExperienceMap:
    """The experience graph of Section 4.2.4 (see the module docstring for every rule)."""

    def __init__(self, cfg: ExpMapConfig, lattice_shape: Any = (15, 15, 15, 8),
                 lattice_spacing: Any = (0.1, 0.1, 0.1)):
        self.cfg = cfg
        self.lattice_shape = tuple(int(v) for v in lattice_shape)
        self.lattice_spacing = tuple(float(v) for v in lattice_spacing)
        if len(self.lattice_shape) != 4 or len(self.lattice_spacing) != 3:
            raise ValueError("posecells.number_of_neurons needs 4 values and distance_between_neurons 3")
        self._period, self._cell = lattice_geometry(self.lattice_shape, self.lattice_spacing)
        g = ColumnStore()
        for name, (shape, dtype) in NODE_COLUMNS.items():   # the node columns (their meaning: NODE_COLUMNS)
            g.add(name, shape, dtype)
        self._g = g
        self._loop_edges = LoopEdges()
        self._lvc_index: dict[int, list[int]] = {}
        self._phi = 0.0                      # fraction of the pending correction applied
        self._peak = 0.0                     # largest node displacement of the pending correction (m)
        self.last_odom: np.ndarray | None = None
        self.last_match = -1
        self.confirmations = 0
        self.last_correction_stamp = -1
        self.corrections = 0
        self.solves = 0
        self._scans = SweepStore()                    # per node: sonar sweep around its odometry position
        self.scan_registrations = {"trusted": 0, "partial": 0, "untrusted": 0, "no_sweep": 0}
        self.last_registration: Registration | None = None
        self.session = 0                      # the session of the newest node
        self._session_pending = False
        self._session_first = 0               # first node of the newest session
        self._session_root: dict[int, int] = {0: 0}
        self.frame_yaw = 0.0                  # rad: the newest session's odometry frame turned into the map's
        self.session_links: list[SessionLink] = []
        self.link_rejections = {"no_sweep": 0, "untrusted": 0, "ambiguous": 0, "inliers": 0}
        self.odometry_scale = 1.0             # horizontal scale applied to this run's odometry edges
        self.run_first = 0                    # first node of this run (edges from here are this run's odometry)

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

    def _position(self, i: int) -> np.ndarray:
        A = self._g.arrays
        out: np.ndarray = A["pos"][i] + self._phi * A["rem"][i] if self._peak > 0.0 else A["pos"][i]
        return out

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
    def loops(self) -> list[tuple[int, int, float, int]]:
        """Loop edges (m, n, weight, stamp ns), in the order they were closed."""
        return self._loop_edges.loops

    @property
    def loop_deltas(self) -> list[np.ndarray]:
        """Per loop edge: the displacement p_n - p_m it asks for (m); zero by default."""
        return self._loop_edges.deltas

    @property
    def sessions(self) -> np.ndarray:
        """Session id per node."""
        return self._a("session")

    @property
    def n_sessions(self) -> int:
        return int(self._a("session").max()) + 1 if self.n_nodes else 0

    def session_root(self, session: int) -> int:
        """The oldest session of the component ``session`` is linked into (itself if unlinked)."""
        return self._session_root[int(session)]

    def begin_session(self) -> None:
        """The next event's node begins a new session (a map continued by another mission)."""
        if self.n_nodes:
            self._session_pending = True

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
    def add_event(self, stamp: int, lvc_id: int, pc_centroid: Any, odom_position: Any, odom_yaw: float,
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
        res = EventResult(node=n)
        jump = (n > 0 and cfg.sessions.jump_m > 0 and self.last_odom is not None
                and float(np.linalg.norm(odom - self.last_odom)) > cfg.sessions.jump_m)
        if n > 0 and (self._session_pending or jump):
            self.session = int(self._a("session").max()) + 1
            self._session_root[self.session] = self.session
            self._session_pending = False
            self._session_first = n
            self.frame_yaw = 0.0              # its own frame
            delta = odom - self._position(n - 1)
            A["pos"][n] = odom                # its own odometry frame
            A["delta"][n] = delta
            A["cum"][n] = A["cum"][n - 1] + delta
            A["weight"][n] = SESSION_BREAK_WEIGHT
            A["cumres"][n] = A["cumres"][n - 1] + 1.0 / SESSION_BREAK_WEIGHT
            A["rem"][n] = 0.0
            self.last_match, self.confirmations = -1, 0
            res.session_started = True
        elif n == 0:
            A["pos"][0] = odom
            A["delta"][0] = 0.0
            A["cum"][0] = 0.0
            A["cumres"][0] = 0.0
            A["weight"][0] = 0.0
        else:
            if self.last_odom is None:
                raise RuntimeError("experience map holds nodes but no last odometry position")
            delta = odom - self.last_odom
            delta[:2] *= self.odometry_scale
            if self.frame_yaw != 0.0:         # a session turned by a link: its odometry turns with it
                delta[:2] = rot2(self.frame_yaw) @ delta[:2]
            A["delta"][n] = delta
            A["pos"][n] = A["pos"][n - 1] + delta
            A["cum"][n] = A["cum"][n - 1] + delta
            A["weight"][n] = 1.0
            A["cumres"][n] = A["cumres"][n - 1] + 1.0
            A["rem"][n] = A["rem"][n - 1]    # a new node follows its predecessor's correction
        A["yaw"][n] = float(odom_yaw) + self.frame_yaw
        A["lvc"][n] = int(lvc_id)
        A["pc"][n] = pc
        A["stamp"][n] = int(stamp)
        A["session"][n] = self.session
        A["odom"][n] = odom
        g.n = n + 1
        self.last_odom = odom.copy()
        self._lvc_index.setdefault(int(lvc_id), []).append(n)
        sw = None if sweep is None or len(sweep) == 0 else np.asarray(sweep, np.float32).reshape(-1, 2)
        if sw is not None and self.frame_yaw != 0.0:
            sw = (sw.astype(np.float64) @ rot2(self.frame_yaw).T).astype(np.float32)
        self._scans.append(sw)

        self._loop_search(n, res)
        if res.confirmations >= cfg.loops.confirmations:
            self._try_close(n, res)
        self._relax(res, cfg.corrections.iterations_per_event)
        return res

    def _loop_search(self, n: int, res: EventResult) -> None:
        """Score the candidates of node n and update the confirmation chain (:mod:`.candidates`)."""
        cfg = self.cfg
        lvc_n = int(self._a("lvc")[n])
        cand = candidate_nodes(n, cfg, self._lvc_index, lvc_n, self._session_first)
        if cand.size == 0:
            self.last_match, self.confirmations = -1, 0
            return
        scores = match_scores(cand, self._g.arrays["pc"], self._g.arrays["lvc"], self._a("pc")[n], lvc_n,
                              self._period, self._cell, cfg)
        ok = scores >= cfg.match_threshold
        if not np.any(ok):
            self.last_match, self.confirmations = -1, 0
            return
        matches, mscores = cand[ok], scores[ok]
        chosen, self.confirmations = choose_match(matches, mscores, self.last_match, self.confirmations,
                                                  cfg.loops.confirmation_gap)
        self.last_match = int(matches[chosen])
        res.match, res.score, res.confirmations = self.last_match, float(mscores[chosen]), self.confirmations

    # ---- loop policy ----------------------------------------------------------------
    def route_length(self, a: int, b: int, limit: int | None = None) -> int:
        """Edges on the shortest route between nodes a and b (a loop edge counts 1); ``limit``:
        stop once the answer is known to be >= limit (:meth:`LoopEdges.route_length`)."""
        return self._loop_edges.route_length(a, b, self.n_nodes, limit)

    def add_loop_edge(self, m: int, n: int, weight: float, stamp: int, delta: Any = None) -> None:
        """Record a loop edge m -> n asking p_n - p_m = ``delta`` (default zero: the same place).
        No rules, no relaxation: the loop-closure path calls it, and tools can join known
        places before :meth:`optimum`."""
        if not (0 <= m < self.n_nodes and 0 <= n < self.n_nodes) or m == n:
            raise ValueError(f"loop edge {m} -> {n}: nodes must be distinct ids in 0..{self.n_nodes - 1}")
        self._loop_edges.add(m, n, weight, stamp, delta)

    def _try_close(self, n: int, res: EventResult) -> None:
        """The closure rules for a confirmed match (interval, route, sweeps), then the closure."""
        cfg = self.cfg
        m = res.match
        stamp = int(self._a("stamp")[n])
        sess = self._a("session")
        if self.session_root(int(sess[m])) != self.session_root(int(sess[n])):
            self._try_link(m, n, stamp, res)
            return
        if self.last_correction_stamp >= 0 and (stamp - self.last_correction_stamp) < cfg.corrections.min_interval_sec * 1e9:
            res.rejected = "interval"
            return
        if self._loop_edges.route_bound(m, n, self.n_nodes, cfg.corrections.min_route_len) < cfg.corrections.min_route_len:
            res.rejected = "route"
            return
        delta = self.loop_delta(m, n)
        if delta is None:
            res.rejected = "scan"
            return
        self._close(m, n, stamp, delta, res)

    def _try_link(self, m: int, n: int, stamp: int, res: EventResult) -> None:
        """A confirmed match between unlinked sessions: a link if the sweeps verify it
        (:mod:`services.expmap.session_link`), else rejected (``rejected = "link"``)."""
        odom = self._a("odom")
        delta, reg, reason = link_displacement(self.cfg, self._scans[m], self._scans[n],
                                               float(odom[n, 2] - odom[m, 2]))
        self.last_registration = reg
        if delta is None or reg is None:
            self.link_rejections[reason] += 1
            res.rejected = "link"
            return
        self._apply_pending()
        A, N = self._g.arrays, self.n_nodes
        old_root, new_root = self.session_root(int(A["session"][n])), self.session_root(int(A["session"][m]))
        moving = np.array([s for s, r in self._session_root.items() if r == old_root], np.int64)
        mask = np.isin(A["session"][:N], moving)
        # the rigid transform of the newer component about n, with the registration's rotation
        # (zero with sessions.link_rotate off)
        theta = math.radians(float(reg.rotation_deg)) if self.cfg.sessions.link_rotate else 0.0
        shift = A["pos"][m] + delta - A["pos"][n]
        move_component(A, N, mask, n, A["pos"][m] + delta, theta, self._loop_edges, self._scans)
        if theta != 0.0:
            self.frame_yaw += theta
        for s in moving.tolist():
            self._session_root[s] = new_root
        older = np.isin(A["session"][:N], [s for s, r in self._session_root.items() if r == new_root]) & ~mask
        n_backfill = self._backfill(mask & (np.arange(N) != n), older, stamp)
        self.session_links.append(SessionLink(
            session=int(A["session"][n]), to_session=int(A["session"][m]), m=m, n=n, stamp=stamp,
            delta=delta.copy(), shift=shift.copy(), rotation_deg=float(reg.rotation_deg), applied_deg=math.degrees(theta),
            inlier_fraction=float(reg.inlier_fraction), backfill_edges=n_backfill))
        res.linked = True
        self._close(m, n, stamp, delta, res)

    def _backfill(self, newer: np.ndarray, older: np.ndarray, stamp: int) -> int:
        """Loop edges between the just-linked component's nodes ``newer`` and the older one's
        ``older`` where their sweeps verify it (:func:`~services.expmap.session_link.backfill`)."""
        N = self.n_nodes
        found = backfill(self.cfg, self._g.arrays["pos"][:N], self._a("odom"), self._scans[:N], newer, older)
        for j, i, delta in found:
            self.add_loop_edge(j, i, float(self.cfg.loops.edge_weight), stamp, delta)
        return len(found)

    def _close(self, m: int, n: int, stamp: int, delta: np.ndarray, res: EventResult) -> None:
        """Add the loop edge m -> n asking ``delta`` and plan the relaxation toward the optimum."""
        cfg = self.cfg
        self.add_loop_edge(m, n, float(cfg.loops.edge_weight), stamp, delta)
        self.corrections += 1
        self.last_correction_stamp = stamp
        self.confirmations = 0
        res.loop_closed = True
        self._plan(res)

    def set_odometry_scale(self, scale: float) -> EventResult:
        """Scale the horizontal displacement of this run's odometry edges (from :attr:`run_first`)
        by ``scale`` (replacing the scale applied so far) and plan the relaxation toward Eq. 4.20's
        new optimum."""
        res = EventResult(node=self.n_nodes - 1)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"odometry scale must be finite and > 0, got {scale}")
        rescale_edges(self._g.arrays, self.run_first, self.n_nodes, scale / self.odometry_scale)
        self.odometry_scale = float(scale)
        if self.n_nodes:
            self._plan(res)
        return res

    def _plan(self, res: EventResult) -> None:
        """Plan the capped relaxation toward the optimum (the pending blend made the base first)."""
        cfg = self.cfg
        target = self.optimum()
        self._apply_pending()
        disp, res.correction_clamped, res.correction_norm, self._peak = plan_correction(
            target, self._a("pos"), cfg.corrections.max_norm)
        self._g.arrays["rem"][: self.n_nodes] = disp
        self._phi = 0.0
        if self._peak <= 0.0:
            self._g.arrays["rem"][: self.n_nodes] = 0.0

    def loop_delta(self, m: int, n: int) -> np.ndarray | None:
        """Displacement p_n - p_m a loop closure of m and n asks for (Eq. 4.20's Delta p of the
        loop edge), or None when the sonar contradicts the recognition (rules:
        :func:`services.expmap.loop_policy.loop_displacement`; counted in
        :attr:`scan_registrations`, the registration kept in :attr:`last_registration`)."""
        d = self._position(n) - self._position(m)
        cum = self._a("cum")
        delta, self.last_registration = loop_displacement(self.cfg, d, self._scans[m], self._scans[n],
                                                          cum[n, 2] - cum[m, 2], self.scan_registrations)
        return delta

    # ---- relaxation -----------------------------------------------------------------
    def _apply_pending(self) -> None:
        """Make the blend of a pending correction the base positions (O(nodes))."""
        if self._peak > 0.0:
            A, n = self._g.arrays, self.n_nodes
            A["pos"][:n] += self._phi * A["rem"][:n]
            A["rem"][:n] = 0.0
            self._phi, self._peak = 0.0, 0.0

    def optimum(self) -> np.ndarray:
        """Node positions minimising Eq. 4.20 with node 0 fixed (exact; ``expmap.corrections.optimizer``)."""
        if self.n_nodes == 0:
            return np.zeros((0, 3))
        target, solved = relaxation_optimum(self.cfg.corrections.optimizer, self._a("cum"), self._a("cumres"),
                                            self.loops, self.loop_deltas, self._position(0))
        self.solves += int(solved)
        return target

    def _relax(self, res: EventResult, iterations: int) -> None:
        """Run up to ``iterations`` relaxation iterations of the pending correction
        (:func:`services.expmap.relaxation.relax_fraction`; O(1) until the map is read)."""
        if self._peak <= 0.0:
            return
        self._phi, ran, step_max, capped = relax_fraction(self._phi, self._peak, self.cfg.corrections.max_step,
                                                          iterations)
        res.iterations += ran
        res.step_max = max(res.step_max, step_max)
        if capped:
            res.step_capped = True
        else:
            self._apply_pending()
            res.settled = True

    def settle(self) -> int:
        """Finish a pending correction (every iteration still capped); returns iterations run."""
        res = EventResult(node=self.n_nodes - 1)
        if self._peak > 0.0:
            self._relax(res, math.ceil((1.0 - self._phi) * self._peak / self.cfg.corrections.max_step) + 1)
        return res.iterations

    # ---- state and persistence ------------------------------------------------------
    def state(self) -> ExperienceMapState:
        """Everything needed to continue the map, as data (copies of the arrays); what
        :meth:`save` writes and :meth:`load_state` takes."""
        return ExperienceMapState(
            lattice_shape=self.lattice_shape, lattice_spacing=self.lattice_spacing,
            columns={k: self._a(k).copy() for k in self._g.arrays},
            loops=list(self.loops), loop_deltas=[d.copy() for d in self.loop_deltas], sweeps=list(self._scans),
            phi=self._phi, peak=self._peak, last_odom=None if self.last_odom is None else self.last_odom.copy(),
            last_match=self.last_match, confirmations=self.confirmations,
            last_correction_stamp=self.last_correction_stamp, corrections=self.corrections, solves=self.solves,
            session=self.session, session_pending=self._session_pending, session_root=dict(self._session_root),
            session_links=list(self.session_links), link_rejections=dict(self.link_rejections),
            frame_yaw=self.frame_yaw)

    def load_state(self, state: ExperienceMapState) -> None:
        """Fill this empty map from ``state`` (:meth:`state` of a map on the same lattice).

        :raises ValueError: the map already holds nodes, or ``state`` does not fit it
            (:meth:`ExperienceMapState.check_fits`)
        """
        if self.n_nodes:
            raise ValueError(f"load_state needs an empty map, this one holds {self.n_nodes} nodes")
        state.check_fits(self.lattice_shape, self.lattice_spacing)
        n = state.n_nodes
        self._g.reserve(max(n, 1))
        for name, col in self._g.arrays.items():
            col[:n] = state.columns[name]
        self._g.n = n
        for (m, k, w, stamp), dl in zip(state.loops, state.loop_deltas):
            self.add_loop_edge(int(m), int(k), float(w), int(stamp), dl)
        self._phi, self._peak = float(state.phi), float(state.peak)
        self.last_odom = None if state.last_odom is None else np.asarray(state.last_odom, np.float64).copy()
        self.last_match, self.confirmations = int(state.last_match), int(state.confirmations)
        self.last_correction_stamp = int(state.last_correction_stamp)
        self.corrections, self.solves = int(state.corrections), int(state.solves)
        self.session, self._session_pending = int(state.session), bool(state.session_pending)
        self._session_first = int(np.argmax(self.sessions == self.session)) if n else 0
        self._session_root = {int(k): int(v) for k, v in state.session_root.items()}
        self.session_links = list(state.session_links)
        self.frame_yaw = float(state.frame_yaw)
        self.link_rejections.update(state.link_rejections)
        for i, lvc in enumerate(self.lvc_ids.tolist()):
            self._lvc_index.setdefault(int(lvc), []).append(i)
        self._scans = SweepStore(state.sweeps)

    def save(self, path: str | Path) -> None:
        """Write everything needed to continue the map (npz, :func:`services.expmap.storage.save_map`)."""
        save_map(self.state(), path)

    @classmethod
    def load(cls, path: str | Path, cfg: ExpMapConfig, lattice_shape: Any = (15, 15, 15, 8),
             lattice_spacing: Any = (0.1, 0.1, 0.1)) -> ExperienceMap:
        """Read a map written by :meth:`save`; the lattice must match the saved one."""
        em = cls(cfg, lattice_shape, lattice_spacing)
        em.load_state(load_map(path, em.lattice_shape, em.lattice_spacing))
        em.run_first = em.n_nodes
        return em
