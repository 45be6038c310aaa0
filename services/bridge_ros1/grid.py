"""The ROS 1 bridge's live occupancy grid (``/map``, nav_msgs/OccupancyGrid, latched).

What it is made of, as ``poseidon export --grid`` makes its grid (:mod:`common.occupancy`, one
implementation): the horizontal returns -- laser ``scan`` beams, else the ``sonar_micron``
wall echoes (:func:`services.expmap.scans.echo_range`) -- each a ray from the sensor to its end
point, placed at the map-corrected pose interpolated at its stamp: the dead reckoning
(``Odometry``) corrected by the latest experience map (``map``) as
:func:`eval.corrected.map_corrected` defines it (:func:`common.map_correction.blend_corrections`).
Before the first map the poses are the dead reckoning's.  Returns are kept in the sensor's own
frame with their stamps, so every rebuild places them at the poses the latest map gives: a loop
closure that moves experiences moves their walls.  Returns not yet covered by ``Odometry`` wait
for it; returns older than the first ``Odometry`` are never placed.

Rate.  Rebuilt from everything kept and published at most once per ``period_s`` of event time
(the newest stamp of a scan, beam, ``Odometry`` or ``map`` received), and only when something
changed; :meth:`LiveGrid.build` with ``force`` at the end.  The bridge also waits
``bridge_ros1.grid_wall_period_s`` of wall time between builds (a bag played fast).

Memory (bounded).  At most ``max_returns`` returns are kept: beyond that the placeable ones are
thinned to one per experience and cell of their dead-reckoning end point (cell =
``resolution``, doubled until the count is at most 3/4 of the bound), the one kept standing for
the others (its ray counts as many hits and misses as returns it replaced); still over the bound
(returns waiting for ``Odometry``), the oldest are dropped (counted).  At most
``max_poses`` ``Odometry`` samples are kept (and a quarter of that not yet merged): beyond that
every other sample of the older half goes where its neighbours interpolate it within half a cell
and ``resolution / 20 m`` of heading (all of them when none does), again until they fit.  A grid of more than ``max_cells`` cells is not built (logged, counted).
"""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

import numpy as np

from common.geometry import normalise_quaternions, wrap_angle, yaws_of_quaternions
from common.map_correction import blend_corrections, interpolate_poses
from common.messages import ExperienceMap, LaserScan, Odometry, RangeImageBeam
from common.occupancy import (
    GridFrame,
    accumulate,
    frame_of,
    laser_points,
    probability,
    rotate,
    scan_endpoints,
    sonar_body,
    trinary,
)
from services.expmap.scans import echo_range

__all__ = ["LiveGrid", "GridUpdate", "SonarModel", "LASER_KEY", "SONAR_KEY"]

log = logging.getLogger(__name__)

LASER_KEY, SONAR_KEY = "scan", "sonar_micron"
#: thinned poses keep the heading within resolution / this: a wall this far away moves by half a cell at most (m)
POSE_TOL_RANGE_M = 20.0
#: ROS OccupancyGrid cell values
ROS_OCCUPIED, ROS_FREE, ROS_UNKNOWN = 100, 0, -1


@dataclass(frozen=True)
class SonarModel:
    """How a ``sonar_micron`` beam becomes an echo: ``expmap.scan.min_range_m`` (m),
    ``expmap.scan.echo_threshold`` and ``robot_state.axis_sign_z`` (the published body's y sign)."""

    min_range_m: float
    echo_threshold: float
    head_sign: float


@dataclass
class GridUpdate:
    """One grid to publish: ``data`` int8 row-major from the bottom row (100 occupied, 0 free, -1 unknown)."""

    stamp: int
    frame_id: str
    frame: GridFrame
    data: np.ndarray
    returns: int


@dataclass
class _Returns:
    """Kept returns of one sensor: stamp (ns), two sensor-frame numbers (laser: x, y in the laser
    frame; sonar: range, head angle), weight (returns it stands for)."""

    stamps: list[np.ndarray] = field(default_factory=list)
    a: list[np.ndarray] = field(default_factory=list)
    b: list[np.ndarray] = field(default_factory=list)
    w: list[np.ndarray] = field(default_factory=list)
    n: int = 0

    def add(self, stamps: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
        self.stamps.append(stamps)
        self.a.append(a)
        self.b.append(b)
        self.w.append(np.ones(len(stamps), dtype=np.int32))
        self.n += len(stamps)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Everything kept, sorted by stamp (stable), as one array each."""
        if len(self.stamps) != 1:
            t = np.concatenate(self.stamps) if self.stamps else np.zeros(0, dtype=np.int64)
            order = np.argsort(t, kind="stable")
            self.stamps = [t[order]]
            a = np.concatenate(self.a)[order] if self.a else np.zeros(0)
            b = np.concatenate(self.b)[order] if self.b else np.zeros(0)
            w = np.concatenate(self.w)[order] if self.w else np.zeros(0, dtype=np.int32)
            self.a, self.b, self.w = [a], [b], [w.astype(np.int32)]
        return self.stamps[0], self.a[0], self.b[0], self.w[0]

    def keep(self, mask: np.ndarray, w: np.ndarray | None = None) -> None:
        t, a, b, old = self.arrays()
        self.stamps, self.a, self.b = [t[mask]], [a[mask]], [b[mask]]
        self.w = [(old if w is None else w)[mask].astype(np.int32)]
        self.n = int(mask.sum())


def _thin_poses(t: np.ndarray, p: np.ndarray, q: np.ndarray, tol_m: float, tol_rad: float) -> np.ndarray:
    """Indices to keep of poses sorted by stamp: every other sample of the older half goes where
    its neighbours interpolate it within ``tol_m`` and ``tol_rad`` (yaw); all of them when none does."""
    n = len(t)
    cand = np.arange(1, max(1, n // 2) - 1, 2)
    cand = cand[cand + 1 < n]
    span = (t[cand + 1] - t[cand - 1]).astype(np.float64)
    f = np.where(span > 0, (t[cand] - t[cand - 1]) / np.where(span > 0, span, 1.0), 0.0)
    lin = p[cand - 1] + f[:, None] * (p[cand + 1] - p[cand - 1])
    yaw = yaws_of_quaternions(q)
    yaw_lin = yaw[cand - 1] + f * wrap_angle(yaw[cand + 1] - yaw[cand - 1])
    ok = (np.linalg.norm(lin - p[cand], axis=1) <= tol_m) & (np.abs(wrap_angle(yaw[cand] - yaw_lin)) <= tol_rad)
    drop = cand[ok] if ok.any() else cand
    keep = np.ones(n, dtype=bool)
    keep[drop] = False
    return np.flatnonzero(keep)


class LiveGrid:
    """Keeps returns, poses and the latest map; :meth:`build` makes the grid (module docstring).
    Thread-safe: the ``add_*`` methods may be called from any thread."""

    def __init__(self, period_s: float, resolution: float, max_returns: int, max_poses: int, max_cells: int,
                 sonar: SonarModel | None = None, laser_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        self.period_ns = int(round(period_s * 1e9))
        self.resolution = float(resolution)
        self.max_returns, self.max_poses, self.max_cells = int(max_returns), int(max_poses), int(max_cells)
        self.sonar, self.laser_offset = sonar, laser_offset
        self._lock = threading.Lock()
        self._laser, self._sonar = _Returns(), _Returns()
        self._odom: list[tuple[int, list[float], list[float]]] = []
        self._poses = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
        self._nodes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._frame_id = ""
        self._map_frame = ""
        self.clock: int | None = None
        self._last_try: int | None = None
        self._changed = False
        self.dropped = 0      #: returns dropped waiting for Odometry beyond the bound
        self.thinned = 0      #: returns merged into others by thinning
        self.too_large = 0    #: builds refused: over max_cells
        self.bad_odometry = 0  #: Odometry samples left out (no usable pose)

    @property
    def enabled(self) -> bool:
        return self.period_ns > 0

    def warm_up(self) -> None:
        """Load the compiled ray tracer now (seconds on a busy computer) rather than at the first build."""
        if self.enabled:
            xy = np.zeros((1, 2))
            accumulate(frame_of(xy, self.resolution), xy, xy)

    def _tick(self, stamp: int) -> None:
        self.clock = stamp if self.clock is None else max(self.clock, stamp)
        self._changed = True

    def add_scan(self, msg: LaserScan) -> None:
        """A laser scan (key ``scan``)."""
        stamps, local = scan_endpoints([msg])
        pts = local[0]
        with self._lock:
            self._laser.add(np.full(len(pts), stamps[0], dtype=np.int64), pts[:, 0], pts[:, 1])
            self._tick(int(stamps[0]))
            self._bound(self._laser)

    def add_sonar(self, msg: RangeImageBeam) -> None:
        """A horizontal sonar beam (key ``sonar_micron``); nothing without a :class:`SonarModel` or an echo,
        nor once a laser scan came (the grid is the laser's then)."""
        if self.sonar is None or self._laser.n:
            return
        r = echo_range(np.asarray(msg.beam_data), float(msg.max_range), self.sonar.min_range_m,
                       self.sonar.echo_threshold)
        with self._lock:
            self._tick(msg.header.stamp)
            if np.isfinite(r):
                self._sonar.add(np.array([msg.header.stamp], dtype=np.int64), np.array([r]),
                                np.array([float(msg.angle_rad)]))
                self._bound(self._sonar)

    def add_odometry(self, msg: Odometry) -> None:
        """One dead-reckoning sample (key ``Odometry``); one without a usable orientation is logged and skipped."""
        if not (np.all(np.isfinite(msg.position)) and np.linalg.norm(msg.orientation) > 0):
            self.bad_odometry += 1
            log.error("bridge_ros1: Odometry at stamp %d left out of the /map grid: position %s, orientation %s",
                      msg.header.stamp, msg.position, msg.orientation)
            return
        with self._lock:
            self._odom.append((msg.header.stamp, list(msg.position), list(msg.orientation)))
            self._frame_id = self._frame_id or msg.header.frame_id
            self._tick(msg.header.stamp)
            if len(self._odom) >= max(1, self.max_poses // 4):
                self._pose_arrays()

    def set_map(self, m: ExperienceMap) -> None:
        """The latest experience map (key ``map``): its nodes correct the poses from now on."""
        ns = sorted(m.nodes, key=lambda n: (n.stamp, n.id))
        with self._lock:
            self._nodes = (np.array([n.stamp for n in ns], dtype=np.int64),
                           np.array([n.position for n in ns], dtype=float).reshape(-1, 3),
                           np.array([n.yaw for n in ns], dtype=float)) if ns else None
            self._map_frame = m.header.frame_id
            self._tick(m.header.stamp)

    def due(self) -> bool:
        """Something changed and ``period_s`` of event time passed since the last build (or none yet)."""
        with self._lock:
            return self._due()

    def _due(self) -> bool:
        if not self.enabled or not self._changed or self.clock is None:
            return False
        return self._last_try is None or self.clock - self._last_try >= self.period_ns

    # ---- building (the caller's thread) -------------------------------------------------------
    def _pose_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kept Odometry samples sorted by stamp (thinned beyond ``max_poses``)."""
        if self._odom:
            t0, p0, q0 = self._poses
            t = np.concatenate([t0, np.array([o[0] for o in self._odom], dtype=np.int64)])
            p = np.vstack([p0, np.array([o[1] for o in self._odom], dtype=float).reshape(-1, 3)])
            q = np.vstack([q0, normalise_quaternions(np.array([o[2] for o in self._odom], dtype=float).reshape(-1, 4))])
            self._odom = []
            order = np.argsort(t, kind="stable")
            t, p, q = t[order], p[order], q[order]
            while len(t) > self.max_poses:
                keep = _thin_poses(t, p, q, self.resolution / 2, self.resolution / POSE_TOL_RANGE_M)
                t, p, q = t[keep], p[keep], q[keep]
            self._poses = (t, p, q)
        return self._poses

    def _place(self, rs: _Returns, laser: bool, t: np.ndarray, p: np.ndarray,
               q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(inside mask, origins (n, 2), end points (n, 2), weights) of ``rs``' returns inside the poses' span."""
        st, a, b, w = rs.arrays()
        inside = (st >= t[0]) & (st <= t[-1]) if len(t) else np.zeros(len(st), dtype=bool)
        s_in, a_in, b_in = st[inside], a[inside], b[inside]
        if not len(s_in):
            return inside, np.zeros((0, 2)), np.zeros((0, 2)), w[inside]
        if laser:  # one pose per scan (stamp), as the export places a scan
            u, counts = np.unique(s_in, return_counts=True)
            at_p, at_q = interpolate_poses(t, p, q, u)
            yaw = yaws_of_quaternions(at_q)
            local = np.split(np.column_stack([a_in, b_in]), np.cumsum(counts)[:-1])
            pts = laser_points(at_p, yaw, local, self.laser_offset)
            orig = np.repeat(laser_points(at_p, yaw, [np.zeros((1, 2))] * len(u), self.laser_offset), counts, axis=0)
        else:
            assert self.sonar is not None
            at_p, at_q = interpolate_poses(t, p, q, s_in)
            body = sonar_body(a_in, b_in, self.sonar.head_sign, True)
            pts, orig = (at_p + rotate(at_q, body))[:, :2], at_p[:, :2]
        return inside, orig.reshape(-1, 2), pts.reshape(-1, 2), w[inside]

    def _bound(self, rs: _Returns) -> None:
        """Keep ``rs`` within ``max_returns`` (module docstring); under the lock."""
        if rs.n <= self.max_returns:
            return
        t, p, q = self._pose_arrays()
        target = self.max_returns * 3 // 4
        voxel = self.resolution
        while rs.n > target and voxel < 1e4:
            inside, _o, pts, w = self._place(rs, rs is self._laser, t, p, q)
            if not inside.any():
                break
            st = rs.arrays()[0][inside]
            exp = (np.searchsorted(self._nodes[0], st, side="right") - 1 if self._nodes is not None
                   else np.zeros(len(st), dtype=np.int64))
            cell = np.floor(pts / voxel).astype(np.int64)
            _u, first, inv = np.unique(np.column_stack([exp, cell]), axis=0, return_index=True, return_inverse=True)
            merged = np.bincount(inv.reshape(-1), weights=w, minlength=len(first))
            keep = np.zeros(rs.n, dtype=bool)
            idx = np.flatnonzero(inside)
            keep[~inside] = True
            keep[idx[first]] = True
            new_w = rs.arrays()[3].copy()
            new_w[idx[first]] = merged.astype(np.int32)
            self.thinned += int(inside.sum()) - len(first)
            rs.keep(keep, new_w)
            voxel *= 2
        if rs.n > self.max_returns:  # still over (returns nobody can place yet): the oldest go
            over = rs.n - self.max_returns
            keep = np.ones(rs.n, dtype=bool)
            keep[:over] = False
            self.dropped += over
            rs.keep(keep)

    def build(self, force: bool = False) -> GridUpdate | None:
        """The grid of everything kept if :meth:`due` (or ``force`` and something changed); None
        when not due, nothing is placeable yet, or the grid is over ``max_cells`` (counted)."""
        with self._lock:
            if not (self._due() or (force and self._changed and self.enabled)) or self.clock is None:
                return None
            self._last_try, self._changed = self.clock, False
            t, p, q = self._pose_arrays()
            if not len(t):
                return None
            if self._nodes is not None:
                p, q = blend_corrections(t, p, q, *self._nodes)
            laser = self._laser.n > 0
            _in, orig, pts, w = self._place(self._laser if laser else self._sonar, laser, t, p, q)
            stamp, frame_id = self.clock, self._map_frame or self._frame_id or "odom"
        if not len(pts):
            return None
        try:
            frame = frame_of(np.vstack([orig, pts]), self.resolution, self.max_cells)
        except ValueError as exc:  # logged and counted: the bridge goes on without a new grid
            self.too_large += 1
            log.error("bridge_ros1: no /map grid: %s (bridge_ros1.grid_max_cells, grid_resolution_m)", exc)
            return None
        hits, misses = accumulate(frame, orig, pts, w)
        data = trinary(probability(hits, misses), ROS_OCCUPIED, ROS_FREE, ROS_UNKNOWN, np.int8).reshape(-1)
        return GridUpdate(stamp, frame_id, frame, data, int(w.sum()))
