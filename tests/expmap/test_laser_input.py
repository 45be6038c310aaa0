"""The laser map's scans in the odometry frame (services/expmap/laser_input.py), without transport."""
from __future__ import annotations

import math

import numpy as np

from services.expmap.laser_input import LaserScans


def _one_return(r: float) -> np.ndarray:
    ranges = np.full(181, np.inf)
    ranges[90] = r            # straight ahead (angle 0)
    return ranges


def test_a_scan_before_any_pose_is_not_placed() -> None:
    scans = LaserScans(0.05, 20.0, None)
    assert not scans.add_scan(_one_return(2.0), -math.pi / 2, math.pi / 180, 0.0, 30.0)
    assert scans.sweep_for(0.0, 0.0, 0.0) is None


def test_returns_are_placed_through_sensor_offset_and_pose_and_back_into_the_experience_frame() -> None:
    scans = LaserScans(0.05, 20.0, (0.5, 0.0, 90.0))     # sensor 0.5 m ahead, looking left
    scans.set_pose(10.0, 5.0, math.pi / 2)                # robot at (10, 5) facing +y
    assert scans.add_scan(_one_return(2.0), -math.pi / 2, math.pi / 180, 0.0, 30.0)
    assert scans.scan_odom is not None
    # the return is 2 m to the robot's left of a point 0.5 m ahead: robot frame (0.5, 2), world (8, 5.5)
    np.testing.assert_allclose(scans.scan_odom, [[8.0, 5.5]], atol=1e-9)
    # an experience made later at (10, 6) facing +y sees it at (-0.5, 2) ... in its own frame: (x fwd, y left)
    sweep = scans.sweep_for(10.0, 6.0, math.pi / 2)
    assert sweep is not None
    np.testing.assert_allclose(sweep, [[-0.5, 2.0]], atol=1e-9)


def test_range_limits_of_the_map_and_of_the_scan_both_apply() -> None:
    scans = LaserScans(0.5, 5.0, None)
    scans.set_pose(0.0, 0.0, 0.0)
    ranges = np.array([0.3, 1.0, 4.0, 6.0])
    scans.add_scan(ranges, 0.0, 0.1, 0.0, 30.0)
    assert scans.scan_odom is not None and len(scans.scan_odom) == 2          # 0.3 too near, 6.0 beyond 5 m
    scans.add_scan(ranges, 0.0, 0.1, 0.0, 4.0)                              # the scan's own max: 4 m (exclusive)
    assert scans.scan_odom is not None and len(scans.scan_odom) == 1


def test_a_scan_is_placed_at_the_odometry_of_its_own_stamp() -> None:
    scans = LaserScans(0.05, 20.0, None)
    scans.set_pose(0.0, 0.0, 0.0, stamp=0)
    # the scan is stamped between two poses: it waits for the second and is placed between them
    assert scans.add_scan(_one_return(2.0), -math.pi / 2, math.pi / 180, 0.0, 30.0, stamp=25)
    assert scans.scan_odom is None
    scans.set_pose(1.0, 0.0, math.radians(40.0), stamp=100)
    assert scans.scan_odom is not None and scans.scan_stamp == 25
    # a quarter of the way: x 0.25 m, heading 10 degrees; the return is 2 m ahead of it
    a = math.radians(10.0)
    np.testing.assert_allclose(scans.scan_odom, [[0.25 + 2 * math.cos(a), 2 * math.sin(a)]], atol=1e-9)
    pose = scans.pose_at(50)
    assert pose is not None
    np.testing.assert_allclose(pose, [0.5, 0.0, math.radians(20.0)], atol=1e-12)
    assert scans.covers(100) and not scans.covers(101)


def test_headings_are_interpolated_the_short_way_across_pi() -> None:
    scans = LaserScans(0.05, 20.0, None)
    scans.set_pose(0.0, 0.0, math.radians(170.0), stamp=0)
    scans.set_pose(0.0, 0.0, math.radians(-170.0), stamp=10)
    pose = scans.pose_at(5)
    assert pose is not None and abs(abs(pose[2]) - math.pi) < 1e-9


def test_a_scan_still_waiting_at_the_end_is_placed_at_the_newest_pose() -> None:
    scans = LaserScans(0.05, 20.0, None)
    scans.set_pose(3.0, 0.0, 0.0, stamp=0)
    scans.add_scan(_one_return(2.0), -math.pi / 2, math.pi / 180, 0.0, 30.0, stamp=50)
    assert scans.scan_odom is None
    scans.flush()
    assert scans.scan_odom is not None
    np.testing.assert_allclose(scans.scan_odom, [[5.0, 0.0]], atol=1e-9)
