"""The range scans of a laser map in the odometry frame (no transport).

:class:`LaserScans` keeps the latest ``Odometry`` pose (x, y, yaw) and the latest range scan's
returns placed in the dead-reckoning frame with that pose: ranges between ``min_range_m`` and
``max_range_m`` (and the scan's own limits) become points in the sensor frame, then in the
robot frame (``sensor_offset``: x m forward, y m left, yaw deg of the sensor on the robot),
then in the odometry frame.  :meth:`LaserScans.sweep_for` gives an experience the latest scan
in the experience's own frame, so the motion between the scan and the event is compensated
by the odometry.  A scan before the first pose is not placed (:meth:`add_scan` returns False).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from services.expmap.laser_match import scan_points, transform_points
from services.expmap.pose_graph import relative_pose

__all__ = ["LaserScans"]


class LaserScans:
    """Latest odometry pose and latest scan (points in the odometry frame)."""

    def __init__(self, min_range_m: float, max_range_m: float, sensor_offset: Sequence[float] | None):
        self.min_range_m = float(min_range_m)
        self.max_range_m = float(max_range_m)
        self.sensor_offset = tuple(float(v) for v in (sensor_offset or (0.0, 0.0, 0.0)))
        self.odom_pose: np.ndarray | None = None     # latest odometry (x, y, yaw)
        self.scan_odom: np.ndarray | None = None     # latest scan's points in the odometry frame

    def set_pose(self, x: float, y: float, yaw: float) -> None:
        """The latest odometry pose (m, m, rad)."""
        self.odom_pose = np.array([x, y, yaw])

    def add_scan(self, ranges: np.ndarray, angle_min: float, angle_increment: float, range_min: float,
                 range_max: float) -> bool:
        """Place one scan (ranges in m, angles in rad) with the latest pose; False before any pose."""
        if self.odom_pose is None:
            return False
        far = min(self.max_range_m, range_max * 0.999) if range_max > 0 else self.max_range_m
        pts = scan_points(ranges, angle_min, angle_increment, max(self.min_range_m, range_min), far)
        off = self.sensor_offset
        if any(off):   # sensor frame -> robot frame
            pts = transform_points(pts, (off[0], off[1], math.radians(off[2])))
        self.scan_odom = transform_points(pts, self.odom_pose)
        return True

    def sweep_for(self, x: float, y: float, yaw: float) -> np.ndarray | None:
        """The latest scan in the frame of the odometry pose (x, y, yaw) of an experience, or None."""
        if self.scan_odom is None:
            return None
        return transform_points(self.scan_odom, relative_pose(np.array([x, y, yaw]), np.zeros(3)))
