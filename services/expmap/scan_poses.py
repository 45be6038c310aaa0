"""The pose of every range scan in the frame of the newest experience (``scan_pose``).

The laser preset makes an experience every 0.25 m or 15 degrees; between two experiences the
map-corrected trajectory (:mod:`eval.corrected`) would otherwise turn as the wheel odometry
turns, and the odometry's heading errs by about as much in a second as the scans' registration
does (docs/LASER.md, "The heading error").  So every scan is registered too:

- the reference is the newest experience's local map (:meth:`ScanGraph.local_map`: the scans of
  it and its ``local_map_experiences - 1`` predecessors as the map places them, in its frame);
  its likelihood fields are built once per experience and map correction, so a scan costs one
  search (:func:`services.expmap.laser_match.match_in_fields`);
- the prior is the odometry's motion from the experience to the scan, the search window
  ``scan_pose_window_m`` / ``scan_pose_window_deg`` around it at the chain's coarse steps, the
  score multiplied by a Gaussian of the offset from the prior (``scan_pose_prior_sigma_m`` /
  ``_deg``), then refined at the fine steps (Olson 2009, as the chain edges);
- a registration scoring less than ``chain_min_score``, or a scan or local map of fewer than
  ``min_points`` points, gives no pose (``scan_pose_weak``, ``scan_pose_unplaced``).  Along a
  corridor, whose walls fix the heading but not the slide, the prior keeps the odometry's
  translation (the window is too small for the chain's spread test to tell a corridor).

The poses change nothing in the map (no node, no edge): they are a measurement of where each
scan was taken relative to an experience, which a relaxation moves with the experience.
Deterministic: the same scans, odometry and experiences in the same order give the same poses.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.expmap.config import ScanGraphConfig
from services.expmap.laser_match import LikelihoodField, match_in_fields, voxel_filter
from services.expmap.pose_graph import relative_pose
from services.expmap.scan_graph import ScanGraph

__all__ = ["ScanPose", "ScanPoses"]


@dataclass(frozen=True)
class ScanPose:
    """One scan's registered pose: ``pose`` (x m, y m, yaw rad) in the frame of ``experience``."""

    experience: int
    pose: np.ndarray
    score: float


class ScanPoses:
    """Registers scans against the newest experience's local map (module doc)."""

    def __init__(self, cfg: ScanGraphConfig):
        self.cfg = cfg
        self._key: tuple[int, int] | None = None     # (experience, map corrections) of the fields
        self._fields: tuple[LikelihoodField, LikelihoodField] | None = None
        self.counters = {"scan_pose": 0, "scan_pose_weak": 0, "scan_pose_unplaced": 0}

    def _fields_of(self, graph: ScanGraph, e: int) -> tuple[LikelihoodField, LikelihoodField] | None:
        key = (e, graph.corrections)
        if key != self._key:
            c = self.cfg
            ref = graph.local_map(e)
            self._key = key
            self._fields = None
            if ref is not None and len(ref) >= c.min_points:
                self._fields = (LikelihoodField(ref, c.chain_coarse_cell_m, c.chain_coarse_cell_m * 2,
                                                margin_m=6 * c.chain_coarse_cell_m),
                                LikelihoodField(ref, c.fine_cell_m, c.fine_sigma_m, margin_m=3 * c.fine_sigma_m))
        return self._fields

    def place(self, graph: ScanGraph, points: np.ndarray, odom_pose: np.ndarray) -> ScanPose | None:
        """The pose of a scan (``points`` k x 2 in the robot frame, m; taken at the odometry pose
        ``odom_pose`` x, y, yaw) in the frame of the newest experience, or None (module doc)."""
        c = self.cfg
        if graph.n_nodes == 0:
            return None
        e = graph.n_nodes - 1
        q = voxel_filter(np.asarray(points, np.float64), c.voxel_m)
        fields = self._fields_of(graph, e)
        if fields is None or len(q) < c.min_points:
            self.counters["scan_pose_unplaced"] += 1
            return None
        prior = relative_pose(graph.odometry_pose(e), np.asarray(odom_pose, np.float64))
        m = match_in_fields(fields[0], fields[1], q, prior, window_xy_m=c.scan_pose_window_m,
                            window_yaw_deg=c.scan_pose_window_deg, coarse_yaw_step_deg=c.chain_coarse_yaw_step_deg,
                            fine_yaw_step_deg=c.fine_yaw_step_deg, refine_peaks=1,
                            prior_sigma_xy_m=c.scan_pose_prior_sigma_m, prior_sigma_yaw_deg=c.scan_pose_prior_sigma_deg)
        if m.score < c.chain_min_score:
            self.counters["scan_pose_weak"] += 1
            return None
        self.counters["scan_pose"] += 1
        return ScanPose(e, m.pose.copy(), m.score)   # yaw already wrapped to [-pi, pi)
