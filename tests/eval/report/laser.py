"""A small hand-made laser run without ground truth, for the report tests.

A robot circles a square room (walls at |x|, |y| = 5 m) on a 2 m circle, one lap a minute,
``laps`` times; a 181-beam laser scan and a pose every second.  Its ``wheel_odometry``
drifts in yaw (0.2 deg/s); ``Odometry`` and the map are exact.  The map has a node every
2 s (an ``experience_event`` each) and, from the second lap on, a loop closure from every
node to the node of the same place a lap earlier.  No ``truth/pose``, no camera.

The run's ``poseidon`` metadata names an imported recording (``write_imported``) as its
input and carries the configuration of the ``laser2d`` preset, as ``poseidon run --config
deploy/presets/laser2d.yaml`` on a CARMEN import would.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from common.mcap_io import RecordingWriter
from common.messages import (
    ExperienceEvent,
    ExperienceLink,
    ExperienceMap,
    ExperienceNode,
    Header,
    LaserScan,
    Odometry,
)
from eval.report.naming import PRESETS_DIR
from system.config import load_config

NS = 1_000_000_000
T0 = 1_000 * NS
ROOM = 5.0  # half-width of the square room centred on the origin (m)
LAP_S = 60
NODE_EVERY_S = 2


def _q(yaw: float) -> list[float]:
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def room_ranges(x: float, y: float, yaw: float, angles: np.ndarray) -> np.ndarray:
    """Ranges from (x, y, yaw) to the walls of the square room |x|, |y| <= ROOM."""
    a = yaw + angles
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (ROOM - x) / c, np.where(c < 0, (-ROOM - x) / c, np.inf))
        ty = np.where(s > 0, (ROOM - y) / s, np.where(s < 0, (-ROOM - y) / s, np.inf))
    return np.minimum(tx, ty)


def write_imported(path: Path, source: str = "/data/radish/aces.clf.bz2") -> None:
    """The recording a CARMEN import writes, reduced to its metadata and one message."""
    with RecordingWriter(path) as w:
        w.write("wheel_odometry", Odometry(header=Header(seq=0, stamp=T0), position=[0.0, 0.0, 0.0],
                                           orientation=_q(0.0)))
        w.add_metadata("poseidon", {"tool": "poseidon import", "sources": [source], "source_format": "CARMEN log",
                                    "laser_offsets": {"scan": {"dx": 0.0, "dy": 0.0, "dtheta": 0.0}}})


def loop_closures(laps: int) -> int:
    """Loop closures of the map :func:`write_laser_run` writes."""
    return (laps - 1) * (LAP_S // NODE_EVERY_S)


def write_laser_run(path: Path, imported: Path | None = None, laps: int = 2, preset: str | None = "laser2d") -> None:
    """Write the run (module docstring); ``imported`` the input it names (None: no input), ``preset`` the
    one its configuration comes from (None: the defaults)."""
    angles = -math.pi / 2 + np.arange(181) * math.pi / 180
    per_lap = LAP_S // NODE_EVERY_S
    nodes: list[ExperienceNode] = []
    links: list[ExperienceLink] = []
    with RecordingWriter(path) as w:
        for k in range(laps * LAP_S + 1):
            t = T0 + k * NS
            th = 2 * math.pi * k / LAP_S
            x, y, yaw = 2 * math.cos(th), 2 * math.sin(th), th + math.pi / 2
            drift = math.radians(0.2) * k
            w.write("wheel_odometry", Odometry(header=Header(seq=k, stamp=t), position=[x, y, 0.0],
                                               orientation=_q(yaw + drift)))
            w.write("Odometry", Odometry(header=Header(seq=k, stamp=t), position=[x, y, 0.0], orientation=_q(yaw)))
            r = room_ranges(x, y, yaw, angles).astype(np.float32)
            w.write("scan", LaserScan(header=Header(seq=k, stamp=t), angle_min=-math.pi / 2, angle_max=math.pi / 2,
                                      angle_increment=math.pi / 180, range_min=0.0, range_max=81.9, ranges=r,
                                      intensities=np.zeros(0, np.float32)))
            if k % NODE_EVERY_S or k == laps * LAP_S:
                continue
            i = len(nodes)
            w.write("experience_event", ExperienceEvent(
                header=Header(seq=i, stamp=t), lvc_id=i % per_lap, pc_centroid=[0.0, 0.0, 0.0, 0.0],
                odom_position=[x, y, 0.0], odom_yaw=yaw, gate="off", vpr_count=0))
            nodes.append(ExperienceNode(id=i, lvc_id=i % per_lap, position=[x, y, 0.0], yaw=yaw, stamp=t))
            if i:
                links.append(ExperienceLink(source=i - 1, target=i, delta=[0, 0, 0], duration_s=NODE_EVERY_S,
                                            weight=1))
            if i >= per_lap:
                links.append(ExperienceLink(source=i, target=i - per_lap, delta=[0, 0, 0], duration_s=0, weight=1,
                                            loop_closure=True))
        w.write("map", ExperienceMap(header=Header(seq=0, stamp=T0 + laps * LAP_S * NS), nodes=nodes, links=links,
                                     current=len(nodes) - 1))
        config = load_config(PRESETS_DIR / f"{preset}.yaml" if preset else None).model_dump(mode="json")
        meta = {"tool": "poseidon run", "mode": "embedded", "code_revision": "0123456789abcdef-test",
                "config": config}
        if imported is not None:
            meta["input"] = str(imported)
        w.add_metadata("poseidon", meta)
