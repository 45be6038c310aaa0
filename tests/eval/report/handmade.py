"""A small hand-made run recording whose content is known, for the report tests.

The vehicle flies a 20 m square twice at 1 m/s, its depth 5 m +- 1 m (one sine a lap; NED
truth at 5 Hz).
Dead reckoning (``Odometry``, published ENU as robot_state does by default) drifts by a
heading error growing 0.002 rad/s and a 2 % scale error.  Camera frames at 2 Hz: the
perimeter is cut into 40 places of 2 m; the first lap creates one LVC id per place, the
second lap recognises them, except place 30 which is mistaken for place 5 (one aliasing).
Fused SDRs: 40 bits per place prototype out of 2048, 32 kept per frame plus 8 random.
``truth/revisits``: second-lap frames within 1.5 m of a first-lap frame.  Events every
``event_every_m`` of travel; the map's nodes sit 30 % of the way from truth to dead
reckoning, linked in order, with loop-closure links from lap 2 back to lap 1
(``false_closure`` adds one between places 10 m apart).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from common.mcap_io import RecordingWriter
from common.messages import (
    ExperienceEvent,
    ExperienceImage,
    ExperienceLink,
    ExperienceMap,
    ExperienceNode,
    Header,
    LocalViewCell,
    LocalViewCells,
    MapSessions,
    NeocortexSdr,
    Odometry,
    RevisitTruth,
    Sdr,
    SessionLinkInfo,
)
from system.config import PoseidonConfig

SIDE_M = 20.0
PLACE_M = 2.0
PLACES = int(4 * SIDE_M / PLACE_M)
LAPS = 2
T0 = 1_700_000_000_000_000_000
SDR_SIZE = 2048


def square_ned(s: np.ndarray) -> np.ndarray:
    """NED position after travelling ``s`` metres on the square (north, then east, south, west)."""
    u = np.mod(s, 4 * SIDE_M)
    side = (u // SIDE_M).astype(int)
    f = u - side * SIDE_M
    n = np.select([side == 0, side == 1, side == 2, side == 3], [f, SIDE_M, SIDE_M - f, 0.0 * f])
    e = np.select([side == 0, side == 1, side == 2, side == 3], [0.0 * f, f, SIDE_M, SIDE_M - f])
    return np.stack([n, e, 5.0 + np.sin(2 * np.pi * u / (4 * SIDE_M))], axis=1)


def dead_reckoning_ned(t_s: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Truth seen through a heading error of 0.002 rad/s and a 2 % scale error, from the start."""
    start = square_ned(np.zeros(1))[0]
    th = 0.002 * t_s
    c, s = np.cos(th), np.sin(th)
    d = (truth - start) * 1.02
    return np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1) + start


def enu(ned: np.ndarray) -> list[float]:
    return [float(ned[1]), float(ned[0]), float(-ned[2])]


class _Headers:
    """Header factory: one seq counter per key."""

    def __init__(self) -> None:
        self.seqs: dict[str, int] = {}

    def __call__(self, key: str, stamp: int) -> Header:
        self.seqs[key] = self.seqs.get(key, 0) + 1
        return Header(seq=self.seqs[key] - 1, stamp=stamp, frame_id=key)


Out = list[tuple[int, str, object]]


def _poses(out: Out, hdr: _Headers, duration: float) -> None:
    """``truth/pose`` (NED) and ``Odometry`` (ENU, drifting) at 5 Hz."""
    t_pose = np.arange(0.0, duration, 0.2)
    truth = square_ned(t_pose)
    dr = dead_reckoning_ned(t_pose, truth)
    for t, p, q in zip(t_pose, truth, dr):
        st = T0 + int(round(t * 1e9))
        out.append((st, "truth/pose", Odometry(header=hdr("truth/pose", st), position=p.tolist(),
                                               orientation=[0.0, 0.0, 0.0, 1.0])))
        out.append((st + 1, "Odometry", Odometry(header=hdr("Odometry", st + 1), position=enu(q),
                                                 orientation=[0.0, 0.0, 0.0, 1.0])))


def _frames(out: Out, hdr: _Headers, duration: float, rng: np.random.Generator) -> None:
    """Per camera frame (2 Hz): the fused SDR, the LVC id and the revisit truth."""
    prototypes = [np.sort(rng.choice(SDR_SIZE, 40, replace=False)) for _ in range(PLACES)]
    t_cam = np.arange(0.1, duration, 0.5)
    cam_pos = square_ned(t_cam)
    seen: set[int] = set()
    for k, t in enumerate(t_cam):
        st = T0 + int(round(t * 1e9))
        place = int(t // PLACE_M) % PLACES
        lap = int(t // (4 * SIDE_M))
        lvc = 5 if (lap == 1 and place == 30) else place
        is_new = lvc not in seen
        seen.add(lvc)
        bits = np.unique(np.concatenate([rng.choice(prototypes[lvc], 32, replace=False),
                                         rng.choice(SDR_SIZE, 8, replace=False)])).astype(np.uint32)
        fused = Sdr(header=hdr("sdr", st), modality="fused", size=SDR_SIZE, active=bits)
        out.append((st, "neocortex/sdr", NeocortexSdr(header=hdr("neocortex/sdr", st), modalities=[fused],
                                                       fused=fused, fusion_mode="union")))
        out.append((st, "local_view_cells", LocalViewCells(
            header=hdr("local_view_cells", st), most_active_cell=lvc, active_cells=[LocalViewCell(id=lvc, rate=0.8)],
            is_new=is_new, intersection=0 if is_new else 30)))
        earlier = np.flatnonzero((np.linalg.norm(cam_pos[:k] - cam_pos[k], axis=1) < 1.5)
                                 & (t - t_cam[:k] >= 10.0)).astype(np.int32)
        out.append((st, "truth/revisits", RevisitTruth(header=hdr("truth/revisits", st), frame_index=k,
                                                       same_place=earlier)))


def _events(out: Out, hdr: _Headers, duration: float, guard_on: bool, event_every_m: float,
            false_closure: bool, second_session: bool = False) -> None:
    """Events, evidence images and the growing map (loop closures a lap apart).  ``second_session``:
    the second lap is session 1 (a ``map_sessions`` with every map from then on), linked to session
    0 by its first loop closure."""
    t_ev = np.arange(event_every_m / 2, duration, event_every_m)
    truth_ev = square_ned(t_ev)
    dr_ev = dead_reckoning_ned(t_ev, truth_ev)
    map_ned = truth_ev + 0.3 * (dr_ev - truth_ev)
    nodes: list[ExperienceNode] = []
    links: list[ExperienceLink] = []
    per_lap = len(t_ev) // LAPS
    for i, t in enumerate(t_ev):
        st = T0 + int(round(t * 1e9)) + 2
        place = int(t // PLACE_M) % PLACES
        out.append((st, "experience_event", ExperienceEvent(
            header=hdr("experience_event", st), lvc_id=place, pc_centroid=[0.0, 0.0, 0.0, 0.0],
            odom_position=enu(dr_ev[i]), odom_yaw=0.0, gate="vpr" if guard_on else "off", vpr_count=3)))
        img = np.zeros((24, 32, 3), dtype=np.uint8)
        img[:, :, 0] = 40 + 5 * place
        img[:, :, 2] = 200 - 4 * place
        img[6:18, 8:24, 1] = 255
        out.append((st, "experience_image", ExperienceImage(
            header=hdr("experience_image", st), height=24, width=32, encoding="rgb8", data=img, source_stamp=st - 2)))
        nodes.append(ExperienceNode(id=i, lvc_id=place, position=enu(map_ned[i]), yaw=0.0, stamp=st))
        if i:
            links.append(ExperienceLink(source=i - 1, target=i, delta=[0.0, 0.0, 0.0], duration_s=event_every_m,
                                        weight=1.0))
        if i >= per_lap and (i - per_lap) % (per_lap // 4) == 0:
            links.append(ExperienceLink(source=i, target=i - per_lap, delta=[0.0, 0.0, 0.0], duration_s=0.0,
                                        weight=1.0, loop_closure=True))
        if false_closure and i == per_lap + per_lap // 8:
            links.append(ExperienceLink(source=i, target=i - per_lap + per_lap // 8 + 5, delta=[0.0, 0.0, 0.0],
                                        duration_s=0.0, weight=1.0, loop_closure=True))
        if i % 10 == 9 or i == len(t_ev) - 1:
            out.append((st, "map", ExperienceMap(header=hdr("map", st), nodes=list(nodes), links=list(links),
                                                 current=i)))
            if second_session and i >= per_lap:
                link = SessionLinkInfo(session=1, to_session=0, source=0, target=per_lap, stamp=nodes[per_lap].stamp,
                                       delta=[0.0, 0.0, 0.0], shift=[0.0, 0.0, 0.0], rotation_deg=0.0,
                                       inlier_fraction=0.9)
                out.append((st, "map_sessions", MapSessions(
                    header=hdr("map_sessions", st), node_session=[int(k >= per_lap) for k in range(i + 1)],
                    loaded_nodes=0, links=[link])))


def write_handmade_run(path: Path, guard_on: bool = True, event_every_m: float = 2.0, false_closure: bool = False,
                       seed: int = 0, revision: str = "0123456789abcdef-test",
                       second_session: bool = False) -> dict[str, int]:
    """Write the run; returns message counts per key."""
    rng = np.random.default_rng(seed)
    hdr = _Headers()
    out: Out = []
    duration = LAPS * 4 * SIDE_M  # s at 1 m/s
    _poses(out, hdr, duration)
    _frames(out, hdr, duration, rng)
    _events(out, hdr, duration, guard_on, event_every_m, false_closure, second_session)
    out.sort(key=lambda x: x[0])
    config = PoseidonConfig().model_dump(mode="json")
    config["vpr_guard"]["require_vpr_for_event"] = guard_on
    with RecordingWriter(path) as w:
        w.add_metadata("poseidon", {"tool": "tests/eval/report/handmade.py", "mode": "embedded",
                                    "code_revision": revision, "config": config})
        for _st, key, msg in out:
            w.write(key, msg)  # type: ignore[arg-type]
        return dict(w.counts)
