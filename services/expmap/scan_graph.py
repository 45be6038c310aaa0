"""Experience map of a planar range sensor: experiences joined by registered scans.

The laser preset (``deploy/presets/laser2d.yaml``, ``expmap.graph: scan_graph``) runs the
experience map on a robot whose odometry drifts in heading (wheel odometry: several degrees
per loop), where Eq. 4.20's position-only relaxation cannot undo the drift.  Each experience
keeps its range scan (points in its own frame: x forward, y left) and the map is a planar
pose graph (:mod:`services.expmap.pose_graph`), every edge a *measured* relative pose:

- **Chain edge** (experience n-1 -> n): the odometry increment is the prior; the scan of n
  is registered (:func:`services.expmap.laser_match.match_scan`) against the scans of the
  previous ``local_map_experiences`` experiences placed by the map (the local map, in the
  frame of n-1) within ``chain_window_m`` / ``chain_window_deg``, the score multiplied by the
  odometry prior (sigmas ``chain_prior_sigma_m`` / ``chain_prior_sigma_deg``).  A
  registration scoring at least ``chain_min_score`` becomes the edge (information
  ``1 / scan_sigma_m^2``, ``1 / scan_sigma_deg^2``); otherwise the odometry increment is
  (``1 / odom_sigma_m^2``, ``1 / odom_sigma_deg^2``), counted as ``chain_odometry``.  When
  the near-best translations spread more than ``chain_max_spread_m`` (a corridor, whose walls
  fix the heading but not the slide along it), the edge takes the registered heading and
  the odometry's translation (``chain_heading_only``).
- **Loop edge** (experience m -> n): candidates are older experiences whose route distance
  from n along the chain is at least ``loop_min_route_m`` and whose map position lies within
  the search radius ``r = min(loop_radius_max_m, loop_radius_m + loop_radius_growth *
  L)`` of n, L the distance travelled since the last accepted loop edge (the map's
  uncertainty grows with it) or along the route from m to n if shorter; the nearest one
  whose map heading is within ``loop_max_heading_diff_deg`` of n's is tried (a scan taken
  facing away shares little with n's), and, when the front-end's place
  identity (LVC id) of n names an older experience, that experience too (appearance
  proposes, geometry verifies).  The query is the scans of n and its ``loop_query_experiences``
  predecessors in n's frame; the reference the scans of the ``loop_reference_experiences``
  experiences either side of m in m's frame; the window is r and ``loop_window_deg`` (grown
  like r up to ``loop_window_max_deg``), no prior.  Verification: score >= ``loop_min_score``
  and spread (the near-best translations' principal std) <= ``loop_max_spread_m`` and
  second-peak ratio <= ``loop_max_second_ratio`` (repeated structure); at most
  ``loop_max_free_space`` of the query's points where a reference scan saw through (more than
  ``loop_free_space_margin_m`` in front of its return: a corridor of another width, a shifted
  room; :func:`services.expmap.laser_match.free_space_fraction`); and a
  *confirmation*: a verified match is kept pending until a later experience (within
  ``loop_confirm_within`` experiences) also verifies one whose implied pose of the map agrees
  (the relative pose of the two current experiences implied by the two loop measurements
  differs from the chain's by at most ``loop_confirm_m`` and ``loop_confirm_deg``).  Then
  both become loop edges (information as a scan chain edge).
- **Relaxation**: after new loop edges whose residual in the current map exceeds
  ``relax_threshold_m`` / ``relax_threshold_deg``, the whole graph is relaxed to its
  least-squares optimum (Gauss-Newton, Huber kernel ``huber``; node 0 fixed); the map's
  correction is applied at once (the clamps of the sonar map do not apply).  A closure whose
  loop edges the relaxed map still cannot satisfy (Mahalanobis residual above
  ``loop_max_residual``: the rest of the map disagrees) is taken back, edges and all
  (``loop_rejected_residual``).

The vertical coordinate of an experience is its odometry z (planar sensor).  Yaws are part
of the map: a node's ``yaw`` is its relaxed heading.  Deterministic: fixed search orders,
ties to the first hypothesis or the oldest experience.
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from services.expmap.config import ScanGraphConfig
from services.expmap.graph import EventResult, read_map_file
from services.expmap.gtsam_graph import relax_planar
from services.expmap.laser_match import ScanMatch, free_space_fraction, match_scan, transform_points, voxel_filter
from services.expmap.pose_graph import compose, relative_pose, wrap_angle

__all__ = ["ScanGraph", "local_points"]

FORMAT_VERSION = 1


def local_points(scans: Sequence[np.ndarray | None], poses: Sequence[np.ndarray], nodes: Iterable[int], frame: int,
                 voxel_m: float) -> np.ndarray | None:
    """The scans of ``nodes`` (points in their own frames) placed at their ``poses``, in the frame of
    experience ``frame``, one point per ``voxel_m`` square; None when none of them has a scan.

    Overlapping scans see the same walls, and one point per voxel keeps the likelihood field's cost
    flat; the point kept is the one of the experience nearest ``frame`` along the chain (the newer
    of two as near): the scans nearest the frame carry the least of the map's accumulated error, so
    they, not the oldest scan of the window, decide where a wall lies.
    """
    parts = []
    for k in sorted(nodes, key=lambda k: (abs(k - frame), -k)):
        s = scans[k]
        if s is not None:
            parts.append(transform_points(s, relative_pose(poses[frame], poses[k])))
    return voxel_filter(np.concatenate(parts), voxel_m) if parts else None


class ScanGraph:
    """Planar experience map with registered chain and loop edges (see the module doc)."""

    def __init__(self, cfg: ScanGraphConfig):
        self.cfg = cfg
        self._pose: list[np.ndarray] = []     # map (x, y, yaw) per experience
        self._z: list[float] = []             # odometry z per experience (m)
        self._odom: list[np.ndarray] = []     # odometry (x, y, yaw) per experience
        self._lvc: list[int] = []
        self._stamp: list[int] = []
        self._route: list[float] = []         # odometry path length up to the experience (m)
        self._scans: list[np.ndarray | None] = []
        self.ei: list[int] = []
        self.ej: list[int] = []
        self.z: list[np.ndarray] = []
        self.w: list[np.ndarray] = []
        self.is_loop: list[bool] = []
        self.loop_stamps: list[int] = []
        self._lvc_index: dict[int, list[int]] = {}
        self._pending: list[tuple[int, int, np.ndarray]] = []   # verified, unconfirmed (m, n, z)
        self.since_loop_m = 0.0
        self.corrections = 0
        self.solves = 0
        self.counters = {"chain_scan": 0, "chain_odometry": 0, "chain_heading_only": 0, "loop_tried": 0, "loop_verified": 0,
                         "loop_rejected_score": 0, "loop_rejected_ambiguous": 0, "loop_rejected_free_space": 0, "loop_rejected_residual": 0,
                         "loop_from_lvc": 0}
        self.last_registration: ScanMatch | None = None

    # ---- read access (the interface of services.expmap.graph.ExperienceMap) ----------
    @property
    def n_nodes(self) -> int:
        return len(self._pose)

    @property
    def positions(self) -> np.ndarray:
        if not self._pose:
            return np.zeros((0, 3))
        p = np.asarray(self._pose)
        return np.column_stack([p[:, 0], p[:, 1], np.asarray(self._z)])

    @property
    def yaws(self) -> np.ndarray:
        return np.asarray(self._pose)[:, 2].copy() if self._pose else np.zeros(0)

    @property
    def lvc_ids(self) -> np.ndarray:
        return np.asarray(self._lvc, np.int64)

    @property
    def stamps(self) -> np.ndarray:
        return np.asarray(self._stamp, np.int64)

    @property
    def loops(self) -> list[tuple[int, int, float, int]]:
        return [(self.ei[k], self.ej[k], float(self.w[k][0]), s)
                for k, s in zip([k for k, lp in enumerate(self.is_loop) if lp], self.loop_stamps)]

    @property
    def loop_deltas(self) -> list[np.ndarray]:
        return [self._delta3(k) for k, lp in enumerate(self.is_loop) if lp]

    @property
    def pending(self) -> bool:
        return False

    def settle(self) -> int:
        """Nothing is ever pending (corrections are applied at once)."""
        return 0

    def _delta3(self, k: int) -> np.ndarray:
        i, j = self.ei[k], self.ej[k]
        c, s = math.cos(self._pose[i][2]), math.sin(self._pose[i][2])
        zk = self.z[k]
        return np.array([c * zk[0] - s * zk[1], s * zk[0] + c * zk[1], self._z[j] - self._z[i]])

    def edges(self) -> list[tuple[int, int, np.ndarray, float, float, bool]]:
        """Every edge as (source, target, delta m in the map frame, duration s, weight, loop)."""
        return [(self.ei[k], self.ej[k], self._delta3(k),
                 0.0 if self.is_loop[k] else (self._stamp[self.ej[k]] - self._stamp[self.ei[k]]) * 1e-9,
                 float(self.w[k][0]), self.is_loop[k]) for k in range(len(self.ei))]

    def scan(self, i: int) -> np.ndarray | None:
        """The scan kept with experience i (k x 2, its own frame), or None."""
        return self._scans[i]

    def local_map(self, frame: int) -> np.ndarray | None:
        """The chain's local map of experience ``frame``: its scan and those of its
        ``local_map_experiences - 1`` predecessors, placed by the map, in its frame; None without scans."""
        return self._local_points(range(max(0, frame - self.cfg.local_map_experiences + 1), frame + 1), frame)

    def odometry_pose(self, i: int) -> np.ndarray:
        """Experience i's odometry pose (x m, y m, yaw rad)."""
        return self._odom[i].copy()

    # ---- the event ----------------------------------------------------------------
    def add_event(self, stamp: int, lvc_id: int, pc_centroid: np.ndarray | Sequence[float],
                  odom_position: np.ndarray | Sequence[float], odom_yaw: float,
                  sweep: np.ndarray | None = None) -> EventResult:
        """Add the experience of one accepted event; ``sweep``: its range scan (k x 2, m, own frame)."""
        odom = np.asarray(odom_position, np.float64)
        if odom.shape != (3,) or not (np.all(np.isfinite(odom)) and math.isfinite(odom_yaw)):
            raise ValueError(f"experience event at stamp {stamp}: odom_position needs 3 finite values and a "
                             f"finite yaw, got {odom_position}, {odom_yaw}")
        cfg = self.cfg
        o = np.array([odom[0], odom[1], wrap_angle(float(odom_yaw))])
        n = self.n_nodes
        scan = None if sweep is None or len(sweep) == 0 else voxel_filter(np.asarray(sweep, np.float64), cfg.voxel_m)
        res = EventResult(node=n)
        if n == 0:
            self._pose.append(o.copy())
            self._route.append(0.0)
        else:
            d = relative_pose(self._odom[-1], o)
            step = float(math.hypot(d[0], d[1]))
            self._route.append(self._route[-1] + step)
            self.since_loop_m += step
            z, w = self._chain_measurement(d, scan)
            self._pose.append(compose(self._pose[-1], z))
            self._add_edge(n - 1, n, z, w, loop=False, stamp=stamp)
        self._odom.append(o)
        self._z.append(float(odom[2]))
        self._lvc.append(int(lvc_id))
        self._stamp.append(int(stamp))
        self._scans.append(scan)
        if scan is not None and n > 0:
            self._loop_step(n, res)
        self._lvc_index.setdefault(int(lvc_id), []).append(n)
        return res

    def _add_edge(self, i: int, j: int, z: np.ndarray, w: np.ndarray, *, loop: bool, stamp: int) -> None:
        self.ei.append(i)
        self.ej.append(j)
        self.z.append(np.asarray(z, np.float64).copy())
        self.w.append(np.asarray(w, np.float64).copy())
        self.is_loop.append(loop)
        if loop:
            self.loop_stamps.append(int(stamp))

    def _scan_info(self) -> np.ndarray:
        c = self.cfg
        return np.array([c.scan_sigma_m ** -2, c.scan_sigma_m ** -2, math.radians(c.scan_sigma_deg) ** -2])

    def _chain_measurement(self, d: np.ndarray, scan: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        c = self.cfg
        odom_w = np.array([c.odom_sigma_m ** -2, c.odom_sigma_m ** -2, math.radians(c.odom_sigma_deg) ** -2])
        n = self.n_nodes
        ref = self._local_points(range(max(0, n - c.local_map_experiences), n), n - 1) if scan is not None else None
        if scan is None or ref is None or len(ref) < c.min_points or len(scan) < c.min_points:
            self.counters["chain_odometry"] += 1
            return d, odom_w
        m = match_scan(ref, scan, d, window_xy_m=c.chain_window_m, window_yaw_deg=c.chain_window_deg,
                       coarse_cell_m=c.chain_coarse_cell_m, coarse_sigma_m=c.chain_coarse_cell_m * 2,
                       coarse_yaw_step_deg=c.chain_coarse_yaw_step_deg, fine_cell_m=c.fine_cell_m,
                       fine_sigma_m=c.fine_sigma_m, fine_yaw_step_deg=c.fine_yaw_step_deg, refine_peaks=1,
                       prior_sigma_xy_m=c.chain_prior_sigma_m, prior_sigma_yaw_deg=c.chain_prior_sigma_deg)
        if m.score < c.chain_min_score:
            self.counters["chain_odometry"] += 1
            return d, odom_w
        if c.chain_max_spread_m > 0 and m.spread_m > c.chain_max_spread_m:
            # a corridor: the walls fix the heading, the odometry the slide along it
            self.counters["chain_heading_only"] += 1
            return np.array([d[0], d[1], m.pose[2]]), np.array([odom_w[0], odom_w[1], self._scan_info()[2]])
        self.counters["chain_scan"] += 1
        return m.pose, self._scan_info()

    def _local_points(self, nodes: Iterable[int], frame: int) -> np.ndarray | None:
        """Scans of ``nodes`` placed by the map, in the frame of experience ``frame``."""
        return local_points(self._scans, self._pose, nodes, frame, self.cfg.voxel_m)

    # ---- loops ------------------------------------------------------------------------
    def _loop_step(self, n: int, res: EventResult) -> None:
        c = self.cfg
        self._pending = [p for p in self._pending if n - p[1] <= c.loop_confirm_within]
        if n % c.loop_every != 0:
            return
        route = np.asarray(self._route)
        old = np.flatnonzero(route[:n] <= route[n] - c.loop_min_route_m)
        if old.size == 0:
            return
        # the uncertainty of n relative to m grows with the travel since the last closure, and
        # never exceeds what the route between them allows
        travel = np.minimum(self.since_loop_m, route[n] - route[old])
        radius = np.minimum(c.loop_radius_max_m, c.loop_radius_m + c.loop_radius_growth * travel)
        P = np.asarray(self._pose)
        dist = np.hypot(P[old, 0] - P[n, 0], P[old, 1] - P[n, 1])
        cands: list[tuple[int, str, float]] = []
        # a 180-degree scan overlaps little with one taken facing away: prefer candidates
        # facing the same way (within loop_max_heading_diff_deg), nearest first
        facing = np.abs(wrap_angle(P[old, 2] - P[n, 2])) <= math.radians(c.loop_max_heading_diff_deg)
        inside = np.flatnonzero((dist <= radius) & facing)
        if inside.size:
            k = int(inside[int(np.argmin(dist[inside]))])
            cands.append((int(old[k]), "geometry", float(radius[k])))
        same = [m for m in self._lvc_index.get(self._lvc[n], []) if route[m] <= route[n] - c.loop_min_route_m]
        if same:
            m_lvc = same[0]
            r_lvc = min(c.loop_radius_max_m, c.loop_radius_m + c.loop_radius_growth *
                        min(self.since_loop_m, route[n] - route[m_lvc]))
            if all(m_lvc != m for m, _k, _r in cands) and \
                    math.hypot(P[m_lvc, 0] - P[n, 0], P[m_lvc, 1] - P[n, 1]) <= max(r_lvc, c.loop_lvc_radius_m):
                cands.append((m_lvc, "lvc", max(r_lvc, c.loop_lvc_radius_m)))
        yaw_win = min(c.loop_window_max_deg, c.loop_window_deg + c.loop_window_growth_deg_per_m * self.since_loop_m)
        for m, kind, r in cands:
            if self._try_loop(m, n, r, yaw_win, res):
                if kind == "lvc":
                    self.counters["loop_from_lvc"] += 1
                break

    def _try_loop(self, m: int, n: int, r: float, yaw_win: float, res: EventResult) -> bool:
        c = self.cfg
        self.counters["loop_tried"] += 1
        ref = self._local_points(range(max(0, m - c.loop_reference_experiences),
                                       min(self.n_nodes, m + c.loop_reference_experiences + 1)), m)
        query = self._local_points(range(max(0, n - c.loop_query_experiences), n + 1), n)
        if ref is None or query is None or len(ref) < c.min_points or len(query) < c.min_points:
            return False
        query = voxel_filter(query, c.loop_query_voxel_m)
        prior = relative_pose(self._pose[m], self._pose[n])
        mt = match_scan(ref, query, prior, window_xy_m=r, window_yaw_deg=yaw_win,
                        coarse_cell_m=c.loop_coarse_cell_m, coarse_sigma_m=c.loop_coarse_cell_m * 1.5,
                        coarse_yaw_step_deg=c.loop_coarse_yaw_step_deg, fine_cell_m=c.fine_cell_m,
                        fine_sigma_m=c.fine_sigma_m, fine_yaw_step_deg=c.fine_yaw_step_deg, refine_peaks=3,
                        coarse_query_voxel_m=c.loop_coarse_voxel_m)
        self.last_registration = mt
        res.match, res.score = m, mt.score
        if mt.score < c.loop_min_score:
            self.counters["loop_rejected_score"] += 1
            return False
        if mt.spread_m > c.loop_max_spread_m or mt.second_ratio > c.loop_max_second_ratio:
            self.counters["loop_rejected_ambiguous"] += 1
            return False
        refs = range(max(0, m - c.loop_reference_experiences), min(self.n_nodes, m + c.loop_reference_experiences + 1))
        # both ways: the query's walls against the reference's free space, and back
        placed = transform_points(query, mt.pose)
        free = free_space_fraction([self._scans[k] for k in refs],
                                   [relative_pose(self._pose[m], self._pose[k]) for k in refs], placed,
                                   margin_m=c.loop_free_space_margin_m)
        qs = range(max(0, n - c.loop_query_experiences), n + 1)
        ref_in_query = transform_points(ref, relative_pose(mt.pose, np.zeros(3)))
        free = max(free, free_space_fraction([self._scans[k] for k in qs],
                                             [relative_pose(self._pose[n], self._pose[k]) for k in qs], ref_in_query,
                                             margin_m=c.loop_free_space_margin_m))
        if free > c.loop_max_free_space:
            self.counters["loop_rejected_free_space"] += 1
            return False
        self.counters["loop_verified"] += 1
        z_new = mt.pose
        for k, (m0, n0, z0) in enumerate(self._pending):
            # implied relative pose n0 -> n from the two loop measurements vs the map's chain
            a = compose(self._pose[m0], z0)
            b = compose(self._pose[m], z_new)
            implied = relative_pose(a, b)
            chain = relative_pose(self._pose[n0], self._pose[n])
            err = implied - chain
            if math.hypot(err[0], err[1]) <= c.loop_confirm_m and \
                    abs(float(wrap_angle(err[2]))) <= math.radians(c.loop_confirm_deg):
                del self._pending[k]
                self._close([(m0, n0, z0), (m, n, z_new)], res)
                return True
        self._pending.append((m, n, z_new))
        res.confirmations = 1
        return False

    def _close(self, loops: list[tuple[int, int, np.ndarray]], res: EventResult) -> None:
        c = self.cfg
        worst_m, worst_deg = 0.0, 0.0
        first = len(self.ei)
        for m, n, z in loops:
            self._add_edge(m, n, z, self._scan_info(), loop=True, stamp=self._stamp[n])
            pred = relative_pose(self._pose[m], self._pose[n])
            e = pred - z
            worst_m = max(worst_m, math.hypot(e[0], e[1]))
            worst_deg = max(worst_deg, abs(math.degrees(float(wrap_angle(e[2])))))
        if worst_m > c.relax_threshold_m or worst_deg > c.relax_threshold_deg:
            before = np.asarray(self._pose)
            after, it = relax_planar(c.optimizer, before, np.asarray(self.ei), np.asarray(self.ej), np.asarray(self.z),
                                     np.asarray(self.w), huber=c.huber, iterations=c.relax_iterations)
            self.solves += 1
            # the rest of the map must agree: loop edges the relaxed map still cannot satisfy
            # (Mahalanobis residual > loop_max_residual) were a wrong place; take them back
            ei, ej = np.asarray(self.ei[first:]), np.asarray(self.ej[first:])
            r = relative_pose(after[ei], after[ej]) - np.asarray(self.z[first:])
            r[:, 2] = wrap_angle(r[:, 2])
            maha = np.sqrt(np.sum(np.asarray(self.w[first:]) * r * r, axis=1))
            if c.loop_max_residual > 0 and float(maha.max()) > c.loop_max_residual:
                for lst in (self.ei, self.ej, self.z, self.w, self.is_loop):
                    del lst[first:]
                del self.loop_stamps[len(self.loop_stamps) - len(loops):]
                self.solves -= 1
                self.counters["loop_rejected_residual"] += 1
                res.rejected = "residual"
                return
            self._pose = [p for p in after]
            res.iterations = it
            res.correction_norm = float(np.max(np.hypot(after[:, 0] - before[:, 0], after[:, 1] - before[:, 1])))
            res.settled = True
        self.corrections += 1
        self.since_loop_m = 0.0
        res.loop_closed = True
        res.confirmations = 2

    # ---- persistence ----------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write everything needed to continue the map (npz)."""
        meta = {"format": FORMAT_VERSION, "kind": "scan_graph", "since_loop_m": self.since_loop_m,
                "corrections": self.corrections, "solves": self.solves, "counters": self.counters}
        scans = [np.zeros((0, 2)) if s is None else s for s in self._scans]
        ptr = np.concatenate([[0], np.cumsum([len(s) for s in scans])]).astype(np.int64)
        pend = np.array([[m, n, *z] for m, n, z in self._pending], np.float64).reshape(-1, 5)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8),
                 pose=np.asarray(self._pose).reshape(-1, 3), z_odom=np.asarray(self._z), odom=np.asarray(self._odom).reshape(-1, 3),
                 lvc=np.asarray(self._lvc, np.int64), stamp=np.asarray(self._stamp, np.int64),
                 route=np.asarray(self._route), scan_ptr=ptr,
                 scan_pts=np.concatenate(scans).reshape(-1, 2) if scans else np.zeros((0, 2)),
                 ei=np.asarray(self.ei, np.int64), ej=np.asarray(self.ej, np.int64),
                 ez=np.asarray(self.z).reshape(-1, 3), ew=np.asarray(self.w).reshape(-1, 3),
                 is_loop=np.asarray(self.is_loop, bool), loop_stamps=np.asarray(self.loop_stamps, np.int64),
                 pending=pend)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, cfg: ScanGraphConfig) -> ScanGraph:
        """Read a map written by :meth:`save`."""
        path = Path(path)
        zf, meta = read_map_file(path, "a scan-graph map")
        if meta.get("kind") != "scan_graph" or meta.get("format") != FORMAT_VERSION:
            raise ValueError(f"{path}: not a scan-graph map of format {FORMAT_VERSION} "
                             f"(kind {meta.get('kind')!r}, format {meta.get('format')})")
        g = cls(cfg)
        g._pose = [p for p in zf["pose"]]
        g._z = [float(v) for v in zf["z_odom"]]
        g._odom = [p for p in zf["odom"]]
        g._lvc = [int(v) for v in zf["lvc"]]
        g._stamp = [int(v) for v in zf["stamp"]]
        g._route = [float(v) for v in zf["route"]]
        ptr, pts = zf["scan_ptr"], zf["scan_pts"]
        g._scans = [pts[ptr[i]:ptr[i + 1]].copy() if ptr[i + 1] > ptr[i] else None for i in range(len(g._pose))]
        g.ei = [int(v) for v in zf["ei"]]
        g.ej = [int(v) for v in zf["ej"]]
        g.z = [v for v in zf["ez"]]
        g.w = [v for v in zf["ew"]]
        g.is_loop = [bool(v) for v in zf["is_loop"]]
        g.loop_stamps = [int(v) for v in zf["loop_stamps"]]
        g._pending = [(int(r[0]), int(r[1]), r[2:].copy()) for r in zf["pending"]]
        for i, lvc in enumerate(g._lvc):
            g._lvc_index.setdefault(lvc, []).append(i)
        g.since_loop_m = float(meta["since_loop_m"])
        g.corrections = int(meta["corrections"])
        g.solves = int(meta["solves"])
        g.counters.update(meta["counters"])
        return g
