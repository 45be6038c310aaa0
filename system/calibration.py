"""What a run takes from its input recording where the configuration leaves it open.

:func:`calibrate_from_input` resolves, before any service is built, the fields whose value
null means "measure it from the input":

- ``expmap.scan_graph.sensor_offset`` (laser map): the offset of ``expmap.scan.topic``'s
  sensor on the robot that the import measured (``poseidon`` metadata ``laser_offsets``: dx,
  dy m, dtheta rad), else 0 0 0;
- ``robot_state.wheel_time_offset_s`` (source ``wheel_odometry``): the scan clock's offset
  from the odometry's, measured on the input's first ``CLOCK_SPAN_S`` seconds by
  :func:`services.expmap.scan_clock.estimate_scan_time_offset` (scan pairs during turns
  registered against each other); 0 when the input has no scans, too few clear turns, or
  the estimate lies on the search bound.

Each resolved value is logged at INFO with what it was measured from, and it is what the
run's recorded configuration holds, so a replay of the run's configuration repeats it.
"""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from common.geometry import yaws_of_quaternions
from common.mcap_io import RecordingError, read_messages, read_metadata, recording_keys
from common.messages import LaserScan, Odometry
from services.expmap.laser_match import scan_points, transform_points
from services.expmap.scan_clock import ScanClockEstimate, estimate_scan_time_offset
from system.config import PoseidonConfig

__all__ = ["calibrate_from_input", "measure_scan_clock", "CLOCK_SPAN_S"]

log = logging.getLogger(__name__)

#: seconds of the input (from its first scan) that the scan clock is measured on
CLOCK_SPAN_S = 900.0


def calibrate_from_input(config: PoseidonConfig, input_path: str | Path) -> None:
    """Resolve the null "measure it" fields of ``config`` from ``input_path`` (module doc)."""
    _sensor_offset(config, input_path)
    _wheel_time_offset(config, input_path)


def _sensor_offset(config: PoseidonConfig, input_path: str | Path) -> None:
    sg = config.expmap.scan_graph
    if config.expmap.graph != "scan_graph" or sg.sensor_offset is not None:
        return
    offset = [0.0, 0.0, 0.0]
    raw = read_metadata(input_path).get("poseidon", {}).get("laser_offsets")
    if raw:
        try:
            entry = json.loads(raw).get(config.expmap.scan.topic)
        except (json.JSONDecodeError, AttributeError) as exc:
            raise RecordingError(f"{input_path}: metadata poseidon.laser_offsets is not a JSON object ({exc})") from None
        if entry:
            offset = [float(entry["dx"]), float(entry["dy"]), math.degrees(float(entry["dtheta"]))]
            log.info("expmap.scan_graph.sensor_offset from %s: %.3f m, %.3f m, %.2f deg", input_path, *offset)
    sg.sensor_offset = offset


def measure_scan_clock(input_path: str | Path, scan_key: str, odometry_key: str = "wheel_odometry",
                       sensor_offset: list[float] | None = None, max_range_m: float = 20.0,
                       span_s: float = CLOCK_SPAN_S) -> ScanClockEstimate:
    """The scan clock's offset from the odometry's on the first ``span_s`` s of a recording."""
    stamps: list[int] = []
    poses: list[tuple[float, float]] = []
    yaw_q: list[list[float]] = []
    scan_stamps: list[int] = []
    scans: list[np.ndarray] = []
    off = sensor_offset or [0.0, 0.0, 0.0]
    end: int | None = None
    for rec in read_messages(input_path, [odometry_key, scan_key]):
        if end is None:
            end = rec.stamp + int(span_s * 1e9)
        if rec.stamp >= end:
            break
        msg = rec.message()
        if rec.key == odometry_key and isinstance(msg, Odometry):
            stamps.append(msg.header.stamp)
            poses.append((msg.position[0], msg.position[1]))
            yaw_q.append(list(msg.orientation))
        elif rec.key == scan_key and isinstance(msg, LaserScan):
            far = min(max_range_m, msg.range_max * 0.999) if msg.range_max > 0 else max_range_m
            pts = scan_points(msg.ranges, msg.angle_min, msg.angle_increment, msg.range_min, far)
            scan_stamps.append(msg.header.stamp)
            scans.append(transform_points(pts, (off[0], off[1], math.radians(off[2]))) if any(off) else pts)
    if len(stamps) < 2:
        return ScanClockEstimate(None, 0, math.nan, math.nan)
    odom = np.column_stack([np.asarray(poses), yaws_of_quaternions(np.asarray(yaw_q))])
    return estimate_scan_time_offset(np.asarray(stamps, np.int64), odom, scan_stamps, scans)


def _wheel_time_offset(config: PoseidonConfig, input_path: str | Path) -> None:
    rs = config.robot_state
    if rs.wheel_time_offset_s is not None:
        return
    key = config.expmap.scan.topic
    if rs.source != "wheel_odometry" or key not in recording_keys(input_path):
        rs.wheel_time_offset_s = 0.0
        return
    est = measure_scan_clock(input_path, key, sensor_offset=config.expmap.scan_graph.sensor_offset,
                             max_range_m=config.expmap.scan_graph.max_range_m)
    bound = 0.3 - 1e-9
    if est.offset_s is None or abs(est.offset_s) >= bound:
        log.warning("robot_state.wheel_time_offset_s: not measured from %s (%d clear scan pairs, estimate %s): "
                    "0 s", input_path, est.pairs, est.offset_s)
        rs.wheel_time_offset_s = 0.0
        return
    log.info("robot_state.wheel_time_offset_s from %s: %.3f s (%d scan pairs in turns; median turn disagreement "
             "%.2f deg, %.2f deg with no offset)", input_path, est.offset_s, est.pairs, est.residual_deg,
             est.residual_at_zero_deg)
    rs.wheel_time_offset_s = est.offset_s
