"""A small hand-made run recording whose every evaluation figure is known by construction.

Geometry (NED, metres, 1 m/s): out along north for 40 s, back along the same line for
40 s; depth z = 5 + x/10.  ``truth(t) = (x(t), 0, 5 + x(t)/10)``, x = t then 80 - t.

- ``truth/pose`` 10 Hz, t = 0..80 s (801 samples); header seq jumps by 3 after sample 99
  (one gap, 3 missing);
- ``Odometry`` 10 Hz in the published ENU frame: truth + (0, +D, 0) for t <= 40 and
  (0, -D, 0) after (D = 1 m): rigid ATE D, anchored final error 2D;
- map nodes 0..19 at t = 2 + 4k s (ENU): truth + (0, +E, 0) on the way out (t < 40) and
  (0, -E, 0) back (E = 0.3 m): every node pairs with a mirror node at the same x of
  opposite offset, so the rigid alignment is the identity and ATE = E;
  chain links k -> k+1 (19) plus loop closures 19->0 (d_gt 0, TP), 12->7 (d_gt 0, TP),
  15->2 (x 18 vs 10: d_gt 8, FP).  min_experience_age 5: opportunities = nodes 12..19;
- ``experience_event`` one per node (seq k, the node's stamp); ``experience_image`` for
  every event except k = 5, source stamp 0.1 s earlier except k = 7 (1.0 s: late), plus
  one orphan image (seq 99);
- camera frames 1 Hz t = 0..80 (frame i at t = i); ``truth/revisits``: frame i >= 45 shows
  the place of frame 80 - i; LVC ids: 0..40 new (id i), 41..44 new (141..144), 45..62 the
  right id 80 - i, 63..70 id 0 (wrong, >= 10 m away), 71..80 new (271..280);
- configuration in the ``poseidon`` metadata: ``expmap.min_experience_age`` 5,
  ``vpr_guard.vpr_window`` 3, ``vpr_min_rep`` 2.
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
    Image,
    LocalViewCells,
    Odometry,
    RevisitTruth,
)
from system.config import PoseidonConfig

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
D = 1.0
E = 0.3
NODE_T = [2 + 4 * k for k in range(20)]
LOOPS = [(19, 0), (12, 7), (15, 2)]
Q = [0.0, 0.0, 0.0, 1.0]


def x_of(t: float) -> float:
    return t if t <= 40 else 80 - t


def truth(t: float) -> np.ndarray:
    x = x_of(t)
    return np.array([x, 0.0, 5.0 + x / 10.0])


def enu(p_ned: np.ndarray) -> list[float]:
    return [float(p_ned[1]), float(p_ned[0]), float(-p_ned[2])]


def lvc_id(i: int) -> tuple[int, bool]:
    if i <= 40:
        return i, True
    if i <= 44:
        return 100 + i, True
    if i <= 62:
        return 80 - i, False
    if i <= 70:
        return 0, False
    return 200 + i, True


def config() -> PoseidonConfig:
    c = PoseidonConfig()
    c.expmap.min_experience_age = 5
    c.vpr_guard.vpr_window = 3
    c.vpr_guard.vpr_min_rep = 2
    return c


def _tiny(h: Header) -> dict:
    return {"header": h, "height": 2, "width": 2, "encoding": "rgb8", "data": np.zeros((2, 2, 3), np.uint8)}


def write_run(path: Path, with_metadata: bool = True) -> Path:
    msgs: list[tuple[str, object]] = []
    for k in range(801):
        t = k / 10
        stamp = T0 + k * NS // 10
        seq = k if k < 100 else k + 3
        msgs.append(("truth/pose", Odometry(header=Header(seq=seq, stamp=stamp), position=truth(t).tolist(),
                                            orientation=Q)))
        off = np.array([0.0, D if t <= 40 else -D, 0.0])
        msgs.append(("Odometry", Odometry(header=Header(seq=k, stamp=stamp), position=enu(truth(t) + off),
                                          orientation=Q)))
    for i in range(81):
        h = Header(seq=i, stamp=T0 + i * NS)
        msgs.append(("camera/image_raw", Image(**_tiny(h))))
        same = np.array([80 - i] if i >= 45 else [], dtype=np.int32)
        msgs.append(("truth/revisits", RevisitTruth(header=h, frame_index=i, same_place=same)))
        lid, new = lvc_id(i)
        msgs.append(("local_view_cells", LocalViewCells(header=h, most_active_cell=lid,
                                                        active_cells=[{"id": lid, "rate": 1.0}], is_new=new,
                                                        intersection=0)))
    nodes, links = [], []
    for k, t in enumerate(NODE_T):
        stamp = T0 + t * NS
        off = np.array([0.0, E if t < 40 else -E, 0.0])
        p = enu(truth(t) + off)
        nodes.append(ExperienceNode(id=k, lvc_id=k, position=p, yaw=0.0, stamp=stamp))
        h = Header(seq=k, stamp=stamp)
        msgs.append(("experience_event", ExperienceEvent(header=h, lvc_id=k, pc_centroid=[0.0, 0.0, 0.0, 0.0],
                                                         odom_position=p, odom_yaw=0.0, gate="vpr", vpr_count=3)))
        if k != 5:
            lag = NS if k == 7 else NS // 10
            msgs.append(("experience_image", ExperienceImage(**_tiny(h), source_stamp=stamp - lag)))
        if k:
            links.append(ExperienceLink(source=k - 1, target=k, delta=[0.0, 4.0, 0.0], duration_s=4.0, weight=1.0))
        for cur, mat in LOOPS:
            if cur == k:
                links.append(ExperienceLink(source=cur, target=mat, delta=[0.0, 0.0, 0.0], duration_s=0.0,
                                            weight=1.0, loop_closure=True))
        msgs.append(("map", ExperienceMap(header=Header(seq=k, stamp=stamp), nodes=list(nodes), links=list(links),
                                          current=k)))
    orphan = Header(seq=99, stamp=T0 + 50 * NS + 1)
    msgs.append(("experience_image", ExperienceImage(**_tiny(orphan), source_stamp=orphan.stamp)))
    msgs.sort(key=lambda km: km[1].header.stamp)  # type: ignore[attr-defined]
    with RecordingWriter(path) as w:
        if with_metadata:
            w.add_metadata("poseidon", {"tool": "tests/eval/handmade", "config": config().model_dump(mode="json")})
        for key, m in msgs:
            w.write(key, m)  # type: ignore[arg-type]
    return path
