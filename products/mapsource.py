"""What the map exports (:mod:`products.grid`, :mod:`products.cloud`, :mod:`products.survex`) read
from a run: poses, the final experience map and the range returns placed at those poses.

Poses.  ``map_corrected``: the trajectory of :func:`eval.corrected.map_corrected` (the one
``poseidon export --tum`` writes); ``odometry``: the raw odometry, ``wheel_odometry`` when the
recording has it (a CARMEN import), else ``Odometry`` (the dead reckoning) -- the same choice
as the report's laser point maps (:mod:`eval.report.benchmark`).  Both are in the frame the run
publishes (``robot_state``'s, ENU by default), metres.

Returns (one per beam at most), each placed at the pose interpolated at its own stamp;
returns outside the trajectory's time span are left out:

- laser (key ``scan``, :class:`~common.messages.LaserScan`): the beam end points of
  :func:`common.occupancy.scan_endpoints` (no return at or beyond ``range_max``, nothing
  beyond 30 m), the laser at the offset the import measured, turned by the pose's yaw
  (:func:`common.occupancy.laser_points`, as the report's point map); z = the pose's z;
  intensity = the scan's ``intensities`` value of the beam (0 when the scan has none);
- sonar (``sonar_micron`` horizontal, ``sonar_seaking`` vertical profiler,
  :class:`~common.messages.RangeImageBeam`): the beam's wall echo, :func:`services.expmap.scans.echo_range`
  with the run's ``expmap.scan.min_range_m`` and ``expmap.scan.echo_threshold`` (the strongest
  bin beyond the ring-down if it is strong enough), intensity = that bin's echo.  Head angles as
  the simulator and the Cala Viuda data define them (Micron: from body +x towards +y, SeaKing: from
  body +y towards +z, FRD body); the published body's y and z are FRD's times
  ``robot_state.axis_sign_z`` (:func:`common.occupancy.sonar_body`); the point is turned by the
  pose's full orientation; the sonar at the body origin (lever arm neglected).  The ``*_ros``
  copies of the beams are not read.

The horizontal returns (laser, or ``sonar_micron``) make the grid; every return makes the cloud.
"""
from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.geometry import published_to_ned
from common.mcap_io import read_messages, recording_keys
from common.messages import ExperienceMap, LaserScan, RangeImageBeam, ScanPose
from common.occupancy import rotate, scan_endpoints, sonar_body
from eval.corrected import map_corrected
from eval.report.benchmark import _laser_offset, _world_points
from eval.rundata import load_run
from eval.trajectory import PoseSeries
from products.rosbag import ExportError
from services.expmap.scans import echo_range
from system.config import PoseidonConfig

__all__ = ["Returns", "MapSource", "load_map_source", "write_outputs", "SONAR_KEYS", "TRAJECTORIES"]

#: sonar keys read, and whether the beam is horizontal (makes the grid)
SONAR_KEYS = {"sonar_micron": True, "sonar_seaking": False}
#: the trajectories a product can be placed at
TRAJECTORIES = ("map_corrected", "odometry")


@dataclass
class Returns:
    """Range returns placed at poses: per return its stamp (ns), sensor origin and end point
    (m, the published frame), echo intensity, the index of its scan/beam and its sensor key."""

    stamps: np.ndarray
    origins: np.ndarray
    points: np.ndarray
    intensity: np.ndarray
    scan: np.ndarray
    sensor: np.ndarray

    def __len__(self) -> int:
        return len(self.stamps)

    def select(self, mask: np.ndarray) -> Returns:
        """The returns where ``mask`` is true."""
        return Returns(self.stamps[mask], self.origins[mask], self.points[mask], self.intensity[mask],
                       self.scan[mask], self.sensor[mask])


@dataclass
class _Beams:
    """Sonar beams of one key: stamp (ns), head angle (rad), echo range (m, nan: none), echo intensity."""

    stamps: np.ndarray
    angles: np.ndarray
    ranges: np.ndarray
    intensity: np.ndarray


@dataclass
class MapSource:
    """One run read for the map exports (module docstring)."""

    path: Path
    metadata: dict[str, Any]
    odometry: PoseSeries | None
    raw: PoseSeries | None
    raw_name: str
    final_map: ExperienceMap | None
    node_session: np.ndarray
    head_sign: float
    axis: tuple[str, float]
    start_ns: int | None
    config: PoseidonConfig
    laser: tuple[np.ndarray, list[np.ndarray], list[np.ndarray], tuple[float, float, float]] | None = None
    sonar: dict[str, _Beams] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    cache: dict[Any, Any] = field(default_factory=dict)
    scan_poses: list[ScanPose] = field(default_factory=list)

    @property
    def sensor_name(self) -> str:
        """``scan`` (laser) or ``sonar_micron``: what the grid is made from."""
        return "scan" if self.laser is not None else "sonar_micron"

    def require_map(self, what: str) -> ExperienceMap:
        """The final map, or :class:`ExportError` naming what ``what`` needs."""
        if self.final_map is None or not self.final_map.nodes:
            raise ExportError(f"{self.path}: no 'map' message (or an empty map): {what} needs the experience map")
        return self.final_map

    def poses(self, trajectory: str) -> PoseSeries:
        """The poses of ``trajectory`` (``map_corrected`` needs the map, ``odometry`` the raw odometry)."""
        if trajectory not in TRAJECTORIES:
            raise ValueError(f"trajectory must be one of {TRAJECTORIES}, got {trajectory!r}")
        if trajectory == "odometry":
            if self.raw is None:
                raise ExportError(f"{self.path}: no 'wheel_odometry' nor 'Odometry' messages: nothing to place the "
                                  "scans at")
            return self.raw
        nodes = self.require_map("a map-corrected product").nodes
        if self.odometry is None:
            raise ExportError(f"{self.path}: no 'Odometry' messages: the map correction needs the dead reckoning")
        return map_corrected(self.odometry, nodes, self.scan_poses)

    def experience_of(self, stamps: np.ndarray) -> np.ndarray:
        """Per stamp the experience id its pose belongs to (the latest node with stamp <= t, the first
        node before it; :mod:`eval.corrected`); -1 everywhere without a map."""
        if self.final_map is None or not self.final_map.nodes:
            return np.full(len(stamps), -1, dtype=np.int32)
        ns = sorted(self.final_map.nodes, key=lambda n: (n.stamp, n.id))
        nt = np.array([n.stamp for n in ns], dtype=np.int64)
        ids = np.array([n.id for n in ns], dtype=np.int32)
        return ids[np.clip(np.searchsorted(nt, stamps, side="right") - 1, 0, len(ns) - 1)]

    def to_enu(self, p: np.ndarray) -> np.ndarray:
        """Positions (n, 3) of the published frame -> east, north, up (m)."""
        ned = published_to_ned(p, self.axis[0], self.axis[1])
        return np.column_stack([ned[:, 1], ned[:, 0], -ned[:, 2]])

    def returns_at(self, trajectory: str, horizontal_only: bool) -> Returns:
        """:meth:`returns` at the poses of ``trajectory`` (computed once per source)."""
        key = ("returns", trajectory, horizontal_only)
        if key not in self.cache:
            self.cache[key] = self.returns(self.poses(trajectory), horizontal_only)
        r: Returns = self.cache[key]
        return r

    def returns(self, poses: PoseSeries, horizontal_only: bool) -> Returns:
        """The returns (module docstring) placed at ``poses``; only the grid's sensor when
        ``horizontal_only``.

        :raises ExportError: the run has no scans / sonar beams, or none inside the poses' span."""
        parts: list[Returns] = []
        if self.laser is not None:
            parts.append(self._laser_returns(poses))
        for key, beams in self.sonar.items():
            if SONAR_KEYS[key] or not horizontal_only:
                parts.append(self._sonar_returns(key, beams, poses))
        if not parts:
            want = "'sonar_micron'" if horizontal_only else "'sonar_micron' or 'sonar_seaking'"
            raise ExportError(f"{self.path}: no 'scan' (laser) nor {want} (sonar) messages: no returns to map")
        out = Returns(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                        ("stamps", "origins", "points", "intensity", "scan", "sensor")))
        if not len(out):
            raise ExportError(f"{self.path}: no {self.sensor_name} return inside the trajectory's time span")
        order = np.argsort(out.stamps, kind="stable")
        return out.select(order)

    def _laser_returns(self, poses: PoseSeries) -> Returns:
        assert self.laser is not None
        stamps, local, inten, offset = self.laser
        inside = np.flatnonzero((stamps >= poses.stamps[0]) & (stamps <= poses.stamps[-1]))
        n = np.array([len(local[i]) for i in inside], dtype=np.int64)
        pts = _world_points(stamps, local, poses, offset)
        orig = _world_points(stamps, [np.zeros((1, 2))] * len(local), poses, offset)
        z = poses.interpolate(stamps[inside]).positions[:, 2]
        scan = np.repeat(inside, n)
        return Returns(stamps[scan], np.column_stack([np.repeat(orig, n, axis=0), np.repeat(z, n)]),
                       np.column_stack([pts, np.repeat(z, n)]),
                       np.concatenate([inten[i] for i in inside] or [np.zeros(0)]).astype(np.float32),
                       scan, np.full(len(scan), "scan"))

    def _sonar_returns(self, key: str, b: _Beams, poses: PoseSeries) -> Returns:
        ok = np.flatnonzero(np.isfinite(b.ranges) & (b.stamps >= poses.stamps[0]) & (b.stamps <= poses.stamps[-1]))
        at = poses.interpolate(b.stamps[ok])
        body = sonar_body(b.ranges[ok], b.angles[ok], self.head_sign, SONAR_KEYS[key])
        pts = at.positions + rotate(at.quaternions, body)
        return Returns(b.stamps[ok], at.positions, pts, b.intensity[ok].astype(np.float32), ok,
                       np.full(len(ok), key))


def _read_sensors(src: MapSource) -> None:
    """Fill ``src.laser`` / ``src.sonar`` from the recording."""
    cfg = src.config
    keys = recording_keys(src.path)
    if "scan" in keys:
        scans = [m for m in (r.message() for r in read_messages(src.path, keys=["scan"])) if isinstance(m, LaserScan)]
        src.counts["scan"] = len(scans)
        if scans:
            stamps, local = scan_endpoints(scans)
            inten = [_laser_intensities(s) for s in scans]
            offset, note = _laser_offset(src.path)
            if note:
                src.notes.append(note)
            src.laser = (stamps, local, inten, offset)
    for key in SONAR_KEYS:
        if key not in keys:
            continue
        st, ang, rng, val = [], [], [], []
        for rec in read_messages(src.path, keys=[key]):
            m = rec.message()
            if not isinstance(m, RangeImageBeam):
                raise ExportError(f"{src.path}: key {key!r} carries {m.type_name}, not RangeImageBeam")
            data = np.asarray(m.beam_data)
            e = echo_range(data, float(m.max_range), cfg.expmap.scan.min_range_m, cfg.expmap.scan.echo_threshold)
            st.append(m.header.stamp)
            ang.append(m.angle_rad)
            rng.append(e)
            val.append(float(data[min(int(e / m.max_range * m.nbins), m.nbins - 1)]) if math.isfinite(e) else 0.0)
        src.counts[key] = len(st)
        if st:
            src.sonar[key] = _Beams(np.array(st, dtype=np.int64), np.array(ang), np.array(rng), np.array(val))


def _laser_intensities(s: LaserScan) -> np.ndarray:
    """The intensities of the beams :func:`scan_endpoints` keeps (0 without intensities)."""
    r = np.asarray(s.ranges, dtype=np.float64)
    a = np.asarray(s.intensities, dtype=np.float64)
    ok = np.isfinite(r) & (r > s.range_min) & (r < s.range_max) & (r <= 30.0)
    return (a[ok] if len(a) == len(r) else np.zeros(int(ok.sum()))).astype(np.float32)


def load_map_source(path: str | Path) -> MapSource:
    """Read ``path`` for the map exports: poses, final map, sessions and the range returns.

    :raises RecordingError: unreadable recording.
    """
    run = load_run(path, keys=("Odometry", "wheel_odometry", "map", "map_sessions", "scan_pose"))
    raw, raw_name = ((run.wheel_odometry, "wheel_odometry") if run.wheel_odometry is not None
                     else (run.odometry_poses, "Odometry"))
    m = run.final_map
    n_nodes = len(m.nodes) if m is not None else 0
    node_session = np.zeros(n_nodes, dtype=np.int64)
    notes: list[str] = []
    if run.final_sessions is not None:
        if len(run.final_sessions.node_session) == n_nodes:
            node_session = np.asarray(run.final_sessions.node_session, dtype=np.int64)
        else:
            notes.append(f"the last map_sessions names {len(run.final_sessions.node_session)} nodes, the last map "
                         f"has {n_nodes}: the map is treated as one session")
    rs = run.config.robot_state
    src = MapSource(path=Path(path), metadata=run.metadata, odometry=run.odometry_poses,
                    raw=raw, raw_name=raw_name, final_map=m, node_session=node_session, head_sign=float(rs.axis_sign_z),
                    axis=(rs.axis_remap, float(rs.axis_sign_z)), start_ns=run.start_ns, config=run.config, notes=notes,
                    counts=dict(run.counts), scan_poses=run.scan_poses)
    _read_sensors(src)
    return src


def write_outputs(files: dict[Path, bytes], overwrite: bool) -> None:
    """Write every file whole or none: each to a temporary file beside it, then all moved into place.

    :raises ExportError: an output exists and ``overwrite`` is false.
    """
    for p in files:
        if p.exists() and not overwrite:
            raise ExportError(f"{p} exists (--overwrite replaces it)")
    tmps: dict[Path, str] = {}
    try:
        for p, data in files.items():
            p.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".partial", dir=p.parent)
            tmps[p] = tmp
            with os.fdopen(fd, "wb") as f:
                f.write(data)
        for p, tmp in tmps.items():
            os.replace(tmp, p)
    finally:
        for tmp in tmps.values():
            if os.path.exists(tmp):
                os.unlink(tmp)
