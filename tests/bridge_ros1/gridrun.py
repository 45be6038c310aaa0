"""A run for the bridge's ``/map`` grid: the corridor of :mod:`tests.products.test_map_exports`
with a drifting dead reckoning as ``Odometry`` (so the map's correction matters), the exact
experience map, and laser scans or sonar beams; what the export makes of it; where the walls are."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from common.mcap_io import RecordingWriter, read_messages
from common.messages import ExperienceMap, Header, LaserScan, Odometry, RangeImageBeam
from common.occupancy import GridFrame, trinary
from products.grid import grid_of
from products.mapsource import load_map_source
from services.bridge_ros1.grid import LiveGrid, SonarModel
from system.config import PoseidonConfig
from tests.products.test_map_exports import WALL_Y, X_END, make_run

RES = 0.05
_ROS_FLOAT32 = ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time", "range_min", "range_max")


def drift_run(tmp: Path, sensor: str = "laser", trigger_s: float = 0.0, with_map: bool = True) -> Path:
    """The corridor run with ``Odometry`` = the drifting odometry, the laser's angles and limits as
    float32 (as ROS carries them); ``trigger_s`` > 0: one more
    ``Odometry`` sample that long after the last, at its pose (moves event time on)."""
    src = make_run(tmp / f"src-{sensor}.mcap", sensor, with_map=with_map)
    out = tmp / f"drift-{sensor}.mcap"
    last: Odometry | None = None
    with RecordingWriter(out) as w:
        for rec in read_messages(src):
            if rec.key == "Odometry":
                continue
            msg = rec.message()
            if isinstance(msg, LaserScan):  # as a ROS LaserScan carries them (float32): what the bridge sees
                msg = msg.model_copy(update={k: float(np.float32(getattr(msg, k))) for k in _ROS_FLOAT32})
            if rec.key == "wheel_odometry" and isinstance(msg, Odometry):
                w.write("Odometry", msg)
                last = msg
            else:
                w.write(rec.key, msg)
        if trigger_s > 0 and last is not None:
            h = last.header
            w.write("Odometry", Odometry(header=Header(seq=h.seq + 1, stamp=h.stamp + int(trigger_s * 1e9),
                                                       frame_id=h.frame_id), position=last.position,
                                         orientation=last.orientation))
    return out


def sonar_model() -> SonarModel:
    cfg = PoseidonConfig()
    return SonarModel(cfg.expmap.scan.min_range_m, cfg.expmap.scan.echo_threshold, float(cfg.robot_state.axis_sign_z))


def feed(grid: LiveGrid, path: Path, skip: tuple[str, ...] = (), on_each: object = None) -> None:
    """Every message of ``path`` into ``grid`` in event-time order; ``on_each()`` after each."""
    for rec in read_messages(path):
        if rec.key in skip:
            continue
        m = rec.message()
        if isinstance(m, LaserScan):
            grid.add_scan(m)
        elif isinstance(m, RangeImageBeam) and rec.key == "sonar_micron":
            grid.add_sonar(m)
        elif isinstance(m, Odometry) and rec.key == "Odometry":
            grid.add_odometry(m)
        elif isinstance(m, ExperienceMap):
            grid.set_map(m)
        if callable(on_each):
            on_each()


def exported(path: Path) -> tuple[GridFrame, np.ndarray]:
    """The map-corrected grid ``poseidon export --grid`` makes of ``path``: its frame and cells as
    OccupancyGrid values (int8, row-major from the bottom row)."""
    g = grid_of(load_map_source(path), "map_corrected", RES)
    frame = GridFrame(g.resolution, g.origin, g.shape[1], g.shape[0])
    return frame, trinary(g.probability(), 100, 0, -1, np.int8).reshape(-1)


def wall_offsets(origin: tuple[float, float], resolution: float, width: int, height: int,
                 data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, distance to the nearest corridor wall) of every occupied cell's centre (m)."""
    occ = np.asarray(data).reshape(height, width) == 100
    j, i = np.nonzero(occ)
    x = origin[0] + (i + 0.5) * resolution
    y = origin[1] + (j + 0.5) * resolution
    off = np.minimum(np.abs(np.abs(y) - WALL_Y), np.minimum(np.abs(x - X_END[0]), np.abs(x - X_END[1])))
    return x, y, off
