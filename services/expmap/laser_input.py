"""The range scans of a laser map in the odometry frame (no transport).

:class:`LaserScans` keeps the odometry poses (x, y, yaw) and the latest range scan's returns
placed in the dead-reckoning frame: ranges between ``min_range_m`` and ``max_range_m`` (and
the scan's own limits) become points in the sensor frame, then in the robot frame
(``sensor_offset``: x m forward, y m left, yaw deg of the sensor on the robot), then in the
odometry frame at the robot's pose *at the scan's stamp*: the odometry interpolated between
the two poses that bracket it (position linear, heading by the shorter way).  A scan newer
than the newest pose waits for the next pose (:meth:`set_pose` places it); a scan given
without a stamp takes the newest pose.  During a turn of 30 deg/s, the newest pose before a
scan 0.1 s older than the scan would rotate it by 3 degrees: every experience's scan, and
so every registered edge, would carry that error (docs/LASER.md, "Time").

:meth:`LaserScans.pose_at` gives an experience the odometry pose at its own stamp the same
way, and :meth:`LaserScans.sweep_for` the latest placed scan in the experience's frame, so
the motion between the scan and the event is compensated by the odometry.  A scan before
the first pose is not placed (:meth:`add_scan` returns False).

With ``keep_placed``, every placed scan is also kept, as (stamp, odometry pose, points in the
robot frame), until :meth:`take_placed` hands them on (the scan poses of
:mod:`services.expmap.scan_poses`); a scan replaced before an experience took it is still there.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from services.expmap.laser_match import scan_points, transform_points
from services.expmap.pose_graph import relative_pose, wrap_angle

__all__ = ["LaserScans"]


class LaserScans:
    """Odometry poses and the latest scan (points in the odometry frame)."""

    def __init__(self, min_range_m: float, max_range_m: float, sensor_offset: Sequence[float] | None,
                 keep_placed: bool = False):
        self.min_range_m = float(min_range_m)
        self.max_range_m = float(max_range_m)
        self.sensor_offset = tuple(float(v) for v in (sensor_offset or (0.0, 0.0, 0.0)))
        self.odom_pose: np.ndarray | None = None     # newest odometry (x, y, yaw)
        self.odom_stamp: int | None = None           # its stamp (ns; None: given without one)
        self._prev: tuple[int, np.ndarray] | None = None   # the pose before it, with its stamp
        self.scan_odom: np.ndarray | None = None     # latest placed scan's points in the odometry frame
        self.scan_stamp: int | None = None
        self._waiting: list[tuple[int, np.ndarray]] = []   # scans newer than the newest pose (robot frame)
        self.keep_placed = keep_placed
        self._placed: list[tuple[int | None, np.ndarray, np.ndarray]] = []

    @property
    def oldest_waiting(self) -> int | None:
        """Stamp (ns) of the oldest scan waiting for a pose after it, or None."""
        return min((t for t, _ in self._waiting), default=None)

    def take_placed(self) -> list[tuple[int | None, np.ndarray, np.ndarray]]:
        """The scans placed since the last call (``keep_placed``): (stamp, odometry pose x y yaw,
        points k x 2 in the robot frame), in the order they were placed."""
        out, self._placed = self._placed, []
        return out

    def _keep(self, stamp: int | None, pose: np.ndarray, pts: np.ndarray) -> None:
        if self.keep_placed:
            self._placed.append((stamp, pose.copy(), pts))

    def set_pose(self, x: float, y: float, yaw: float, stamp: int | None = None) -> None:
        """The newest odometry pose (m, m, rad) and its stamp (ns); places the scans waiting for it."""
        if stamp is not None and self.odom_pose is not None and self.odom_stamp is not None:
            self._prev = (self.odom_stamp, self.odom_pose)
        self.odom_pose = np.array([x, y, yaw])
        self.odom_stamp = stamp
        if stamp is not None:
            ready = [w for w in self._waiting if w[0] <= stamp]
            self._waiting = [w for w in self._waiting if w[0] > stamp]
            for t, pts in ready:
                self._place(pts, t)

    def pose_at(self, stamp: int) -> np.ndarray | None:
        """The odometry pose at ``stamp`` (interpolated; the oldest kept pose before it, the
        newest after it), or None before any pose."""
        if self.odom_pose is None:
            return None
        if self.odom_stamp is None or stamp >= self.odom_stamp or self._prev is None:
            return self.odom_pose.copy()
        t0, p0 = self._prev
        if stamp <= t0:
            return p0.copy()
        f = (stamp - t0) / (self.odom_stamp - t0)
        p1 = self.odom_pose
        return np.array([p0[0] + f * (p1[0] - p0[0]), p0[1] + f * (p1[1] - p0[1]),
                         float(wrap_angle(p0[2] + f * float(wrap_angle(p1[2] - p0[2]))))])

    def covers(self, stamp: int) -> bool:
        """Whether the newest pose is at or after ``stamp`` (a pose there needs no later input)."""
        return self.odom_stamp is not None and self.odom_stamp >= stamp

    def add_scan(self, ranges: np.ndarray, angle_min: float, angle_increment: float, range_min: float,
                 range_max: float, stamp: int | None = None) -> bool:
        """Place one scan (ranges in m, angles in rad; ``stamp`` ns) at the pose of its stamp, or
        keep it until a pose at or after its stamp arrives; False before any pose."""
        if self.odom_pose is None:
            return False
        far = min(self.max_range_m, range_max * 0.999) if range_max > 0 else self.max_range_m
        pts = scan_points(ranges, angle_min, angle_increment, max(self.min_range_m, range_min), far)
        off = self.sensor_offset
        if any(off):   # sensor frame -> robot frame
            pts = transform_points(pts, (off[0], off[1], math.radians(off[2])))
        if stamp is None or self.odom_stamp is None:
            self.scan_odom, self.scan_stamp = transform_points(pts, self.odom_pose), stamp
            self._keep(stamp, self.odom_pose, pts)
        elif self.covers(stamp):
            self._place(pts, stamp)
        else:
            self._waiting.append((stamp, pts))
        return True

    def flush(self) -> None:
        """Place the waiting scans at the newest pose (no pose after them will come)."""
        if self.odom_pose is not None:
            for t, pts in self._waiting:
                self.scan_odom, self.scan_stamp = transform_points(pts, self.odom_pose), t
                self._keep(t, self.odom_pose, pts)
        self._waiting = []

    def _place(self, pts: np.ndarray, stamp: int) -> None:
        pose = self.pose_at(stamp)
        assert pose is not None
        if self.scan_stamp is None or stamp >= self.scan_stamp:
            self.scan_odom, self.scan_stamp = transform_points(pts, pose), stamp
            self._keep(stamp, pose, pts)

    def sweep_for(self, x: float, y: float, yaw: float) -> np.ndarray | None:
        """The latest placed scan in the frame of the odometry pose (x, y, yaw) of an experience, or None."""
        if self.scan_odom is None:
            return None
        return transform_points(self.scan_odom, relative_pose(np.array([x, y, yaw]), np.zeros(3)))
