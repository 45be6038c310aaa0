"""Helpers of the view's tests (and its benchmark).  A small generated recording of a run, shaped like one ``poseidon run`` writes: camera frames,
sonar beams, local view cells with revisits, pose-cell activity, experience events, dead reckoning,
truth and a map published every few events (a loop closure among its links)."""
from __future__ import annotations

import json
import math
import socket
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np

from common.mcap_io import RecordingWriter
from common.messages import (
    ExperienceEvent,
    ExperienceLink,
    ExperienceMap,
    ExperienceNode,
    Header,
    Image,
    LocalViewCell,
    LocalViewCells,
    Odometry,
    PoseCellActivity,
    PoseStamped,
    RangeImageBeam,
)

T0 = 1_600_000_000_000_000_000


def _pos(t_s: float) -> list[float]:
    """A circle of 10 m radius, one lap per 40 s, at 5 m depth."""
    a = 2 * math.pi * t_s / 40.0
    return [10 * math.cos(a), 10 * math.sin(a), -5.0]


def activity(header: Header, t_s: float) -> PoseCellActivity:
    """A pose-cell activity message: a packet on the 15 x 15 x 15 x 8 lattice that drifts with ``t_s``."""
    cx, cy, cz, cq = (3 + t_s) % 15, (7 + 0.5 * t_s) % 15, 5.0, (2 + 0.2 * t_s) % 8
    d = [np.minimum(abs(np.arange(n) - c), n - abs(np.arange(n) - c)) for n, c in ((15, cx), (15, cy), (15, cz), (8, cq))]
    g = [np.exp(-v ** 2 / 2) for v in d]
    xy, zyaw = np.outer(g[0], g[1]), np.outer(g[2], g[3])
    xy, zyaw = xy / xy.sum(), zyaw / zyaw.sum()
    return PoseCellActivity(header=header, xy=np.rint(xy / xy.max() * 255).astype(np.uint8), xy_scale=xy.max() / 255,
                            zyaw=np.rint(zyaw / zyaw.max() * 255).astype(np.uint8), zyaw_scale=zyaw.max() / 255,
                            centroid=[cx * 0.1, cy * 0.1, cz * 0.1, (cq * math.pi / 4 + math.pi) % (2 * math.pi) - math.pi],
                            spacing=[0.1, 0.1, 0.1], steps=int(t_s * 2))


def write_run(path: Path, seconds: float = 20.0, with_map: bool = True, with_activity: bool = True) -> dict[str, int]:
    """Write the recording; returns the message count per key."""
    rng = np.random.default_rng(3)
    seq: dict[str, int] = {}

    def hdr(key: str, stamp: int) -> Header:
        seq[key] = seq.get(key, -1) + 1
        return Header(seq=seq[key], stamp=stamp)

    nodes: list[ExperienceNode] = []
    links: list[ExperienceLink] = []
    with RecordingWriter(path) as w:
        for i in range(int(seconds * 10)):
            t = i / 10
            stamp = T0 + i * 100_000_000
            p = _pos(t)
            w.write("dead_reckoning", PoseStamped(header=hdr("dead_reckoning", stamp), position=p, yaw=t / 10))
            w.write("truth/pose", Odometry(header=hdr("truth/pose", stamp), position=[p[0] + 0.5, p[1], p[2]],
                                           orientation=[0.0, 0.0, 0.0, 1.0]))
            w.write("sonar_micron", RangeImageBeam(header=hdr("sonar_micron", stamp + 1), angle_grad=float(i % 400),
                                                   angle_rad=(i % 63) / 10, nbins=100, max_range=20,
                                                   beam_data=rng.integers(0, 100, 100).astype(np.int32)))
            if i % 5 == 0:  # camera and LVC at 2 Hz; places 0..7 seen again after 4 s
                k = i // 5
                w.write("camera/image_raw", Image(header=hdr("camera/image_raw", stamp), height=48, width=64,
                                                  data=rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)))
                cell = k if k < 8 else k % 8
                w.write("local_view_cells", LocalViewCells(
                    header=hdr("local_view_cells", stamp), most_active_cell=cell,
                    active_cells=[LocalViewCell(id=cell, rate=0.5)], is_new=k < 8, intersection=3))
            if with_activity and i % 5 == 2:  # pose-cell activity at 2 Hz, from 0.2 s
                w.write("posecells/activity", activity(hdr("posecells/activity", stamp), t))
            if i % 20 == 10:  # an experience every 2 s
                n = len(nodes)
                nodes.append(ExperienceNode(id=n, lvc_id=n % 8, position=p, yaw=0.0, stamp=stamp))
                if n:
                    links.append(ExperienceLink(source=n - 1, target=n, delta=[0.0, 0.0, 0.0], duration_s=2.0,
                                                weight=1.0))
                if n == 7:
                    links.append(ExperienceLink(source=7, target=0, delta=[0.0, 0.0, 0.0], duration_s=2.0,
                                                weight=1.0, loop_closure=True))
                w.write("experience_event", ExperienceEvent(
                    header=hdr("experience_event", stamp), lvc_id=n % 8, pc_centroid=[p[0] / 10, p[1] / 10, 0.1, t],
                    odom_position=p, odom_yaw=0.0, gate="vpr", vpr_count=1))
                if with_map and n % 3 == 2:
                    w.write("map", ExperienceMap(header=hdr("map", stamp), nodes=list(nodes), links=list(links),
                                                 current=n))
    return {k: v + 1 for k, v in seq.items()}


def free_port() -> int:
    """A loopback port free now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def view_state(url: str) -> dict[str, Any] | None:
    """The view's ``state.json`` at ``url``, or None while nothing answers there."""
    try:
        return dict(json.loads(urllib.request.urlopen(url + "state.json", timeout=5).read()))
    except OSError:
        return None
