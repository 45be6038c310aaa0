"""What the figures draw of one run (:class:`RunView`), derived from the one run model
:class:`eval.rundata.RunData` (:func:`run_view`); nothing here reads messages but the few
evidence images shown.

Frames and units:

- Every position is in the NED world frame of ``robot_state`` (metres; x north, y east,
  z down), as :func:`eval.rundata.load_run` delivers it: ``truth/pose`` is NED already;
  ``Odometry``, ``dead_reckoning`` and the ``map`` nodes are taken back from the published
  frame (``axis_remap``/``axis_sign_z`` of the run's configuration).
- The estimates start wherever their producer put their origin.  To compare shapes with
  ground truth, dead reckoning (``Odometry``, else ``dead_reckoning``) is translated so that
  its first sample coincides with the truth at that stamp, and the map so that its first
  node (by id) coincides with the translated dead reckoning at that node's stamp (the map is
  built from odometry deltas).
- Times are event times in ns; figures show seconds since the first message of the run.

Sessions: the run's last ``map_sessions`` (:attr:`eval.rundata.RunData.final_sessions`,
published by a map of several sessions) gives the session of each node and the session links
(:attr:`RunView.node_session`, :attr:`RunView.session_links`); a run without ``map_sessions``
is one session.  How sessions are coloured is :func:`eval.report.style.session_groups`.
"""
from __future__ import annotations

import base64
import io
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.mcap_io import read_messages
from common.messages import ExperienceImage
from eval.report.naming import run_label
from eval.rundata import RunData
from eval.trajectory import Trajectory

__all__ = ["RunView", "run_view"]

log = logging.getLogger(__name__)


@dataclass
class RunView:
    """Everything the figures of one run are drawn from (arrays in the order stated)."""

    run: RunData
    label: str
    truth: Trajectory
    dead_reckoning: Trajectory  # anchored to the truth
    #: ``experience_event``: stamps, LVC id, gate
    event_stamps: np.ndarray
    event_lvc: np.ndarray
    event_gate: list[str]
    #: final ``map`` in id order: node id, LVC id, stamp, anchored NED position; links (source, target, loop_closure)
    node_ids: np.ndarray
    node_lvc: np.ndarray
    node_stamps: np.ndarray
    node_ned: np.ndarray
    links: np.ndarray
    link_loop: np.ndarray
    #: ``local_view_cells`` per frame
    lvc_stamps: np.ndarray
    lvc_id: np.ndarray
    lvc_new: np.ndarray
    #: fused SDR per frame (``neocortex/sdr``): stamps and sorted active bits
    sdr_stamps: np.ndarray
    sdr_active: list[np.ndarray]
    sdr_size: int
    #: ``truth/revisits``: stamp of each camera frame index and its earlier same-place frames
    revisit_stamps: np.ndarray
    revisit_same: list[np.ndarray]
    #: session of each node (node order; zeros without ``map_sessions``) and the session links
    #: (k x 2 node ids: older experience, newer experience)
    node_session: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    session_links: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    #: a few ``experience_image`` frames as JPEG data URIs: (stamp, lvc id or -1, uri, size)
    images: list[tuple[int, int, str, str]] = field(default_factory=list)

    @property
    def path(self) -> Path:
        return self.run.path

    @property
    def metadata(self) -> dict[str, Any]:
        return self.run.metadata

    @property
    def counts(self) -> dict[str, int]:
        return self.run.counts

    @property
    def start_ns(self) -> int:
        return int(self.run.start_ns or 0)

    @property
    def duration_s(self) -> float:
        return self.run.duration_s

    @property
    def maps_received(self) -> int:
        return self.run.map_messages

    @property
    def image_count(self) -> int:
        return len(self.run.images)

    def seconds(self, stamps: np.ndarray) -> np.ndarray:
        """Seconds since the run's first message."""
        return (np.asarray(stamps, dtype=np.int64) - self.start_ns) / 1e9


def _image_uri(msg: ExperienceImage, max_width: int = 256) -> tuple[str, str]:
    from PIL import Image as PilImage
    a = np.asarray(msg.data)
    enc = msg.encoding
    if enc == "mono16":
        a = (a.astype(np.float64) / max(float(a.max()), 1.0) * 255).astype(np.uint8)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if enc.startswith("bgr"):
        a = a[:, :, [2, 1, 0]]
    elif a.ndim == 3 and a.shape[2] == 4:
        a = a[:, :, :3]
    img = PilImage.fromarray(np.ascontiguousarray(a.astype(np.uint8)))
    if img.width > max_width:
        img = img.resize((max_width, max(1, round(img.height * max_width / img.width))))
    buf = io.BytesIO()
    img.convert("RGB").save(buf, format="JPEG", quality=80)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode(), f"{msg.width}x{msg.height}"


def _anchor(track: Trajectory, reference: Trajectory) -> Trajectory:
    """Translate ``track`` so its first sample lies on ``reference`` at the same stamp."""
    if len(track) == 0 or len(reference) == 0:
        return track
    ref = reference.positions_within(track.t[:1])[0]
    if np.isnan(ref).any():
        log.warning("%s starts outside the span of %s: not anchored", track.source, reference.source)
        return track
    return track.translated(ref - track.p[0])


def _i64(v: Any) -> np.ndarray:
    return np.asarray(v, dtype=np.int64)


def _empty(source: str) -> Trajectory:
    return Trajectory(_i64([]), np.zeros((0, 3)), source=source)


def _map_arrays(run: RunData, dr: Trajectory, truth: Trajectory) -> tuple[np.ndarray, ...]:
    """The final map's node ids, LVC ids, stamps, anchored NED positions (id order), links
    and their loop-closure flags (the :class:`RunView` fields, in that order)."""
    m = run.final_map
    if m is None or not m.nodes:
        return (_i64([]), _i64([]), _i64([]), np.zeros((0, 3)), _i64([]).reshape(0, 2), np.zeros(0, dtype=bool))
    nodes = sorted(m.nodes, key=lambda n: n.id)
    stamps = _i64([n.stamp for n in nodes])
    ned = run.to_ned(np.asarray([n.position for n in nodes], dtype=np.float64)).reshape(-1, 3)
    anchored = _anchor(Trajectory(stamps, ned, source="map"), dr if len(dr) else truth)
    return (_i64([n.id for n in nodes]), _i64([n.lvc_id for n in nodes]), stamps, anchored.p,
            _i64([[ln.source, ln.target] for ln in m.links]).reshape(-1, 2),
            np.asarray([ln.loop_closure for ln in m.links], dtype=bool))


def _session_arrays(run: RunData, node_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Session per node (``node_ids`` order) and the session links (node ids) of the final map."""
    none = np.zeros(len(node_ids), dtype=np.int64), np.zeros((0, 2), dtype=np.int64)
    ms = run.final_sessions
    if ms is None or not len(node_ids):
        return none
    sess = np.asarray(ms.node_session, dtype=np.int64)
    if node_ids.min() < 0 or node_ids.max() >= len(sess):
        log.warning("%s: map_sessions names %d nodes, the final map has node ids up to %d: drawn as one session",
                    run.path, len(sess), int(node_ids.max()))
        return none
    links = _i64([[lk.source, lk.target] for lk in ms.links]).reshape(-1, 2)
    return sess[node_ids], links


def _revisit_arrays(run: RunData) -> tuple[np.ndarray, list[np.ndarray]]:
    frames = sorted(run.revisits)
    if frames and frames != list(range(len(frames))):
        log.warning("%s: truth/revisits frame indices are not 0..%d; missing frames are left out",
                    run.path, len(frames) - 1)
    n_frames = (frames[-1] + 1) if frames else 0
    stamps = np.full(n_frames, -1, dtype=np.int64)
    same: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * n_frames
    for k in frames:
        r = run.revisits[k]
        stamps[k], same[k] = r.header.stamp, np.asarray(r.same_place, dtype=np.int64)
    return stamps, same


def _thumbnails(view: RunView, max_images: int) -> None:
    """Decode ``max_images`` evenly spaced ``experience_image`` frames into ``view.images``."""
    img_stamps = [r.stamp for r in view.run.images]
    if not img_stamps or max_images <= 0:
        return
    chosen = {img_stamps[i] for i in np.unique(np.linspace(0, len(img_stamps) - 1, max_images).round().astype(int))}
    ev_lvc = dict(zip(view.event_stamps.tolist(), view.event_lvc.tolist()))
    for r in read_messages(view.path, keys=["experience_image"]):
        if r.stamp in chosen:
            chosen.discard(r.stamp)
            img: Any = r.message()
            uri, size = _image_uri(img)
            view.images.append((r.stamp, int(ev_lvc.get(r.stamp, -1)), uri, size))


def run_view(run: RunData, label: str | None = None, max_images: int = 12, compare: bool = False) -> RunView:
    """The figures' view of ``run`` (module docstring); ``label`` defaults to :func:`eval.report.naming.run_label` (``compare``:
    the run is one of several compared)."""
    truth = run.truth if run.truth is not None else _empty("truth/pose")
    dr = run.odometry if run.odometry is not None else (run.dead_reckoning or _empty("dead_reckoning"))
    dr = _anchor(dr, truth)
    ev = run.events
    revisit_stamps, revisit_same = _revisit_arrays(run)
    node_ids, node_lvc, node_stamps, node_ned, links, link_loop = _map_arrays(run, dr, truth)
    view = RunView(
        run=run, label=label or run_label(run, compare), truth=truth, dead_reckoning=dr,
        event_stamps=_i64([e.header.stamp for e in ev]), event_lvc=_i64([e.lvc_id for e in ev]),
        event_gate=[e.gate for e in ev], node_ids=node_ids, node_lvc=node_lvc, node_stamps=node_stamps,
        node_ned=node_ned, links=links, link_loop=link_loop,
        lvc_stamps=_i64([m.header.stamp for m in run.lvcs]), lvc_id=_i64([m.most_active_cell for m in run.lvcs]),
        lvc_new=np.asarray([m.is_new for m in run.lvcs], dtype=bool),
        sdr_stamps=_i64([s.stamp for s in run.sdrs]), sdr_active=[s.active for s in run.sdrs],
        sdr_size=max([s.size for s in run.sdrs], default=0),
        revisit_stamps=revisit_stamps, revisit_same=revisit_same)
    view.node_session, view.session_links = _session_arrays(run, node_ids)
    _thumbnails(view, max_images)
    return view
