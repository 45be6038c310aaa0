"""What the report needs from one run's MCAP recording (:class:`RunData`, :func:`load_run`).

Frames and units:

- Every position is taken to the NED world frame of ``robot_state`` (metres; x north,
  y east, z down): ``truth/pose`` is NED already; ``Odometry``, ``dead_reckoning``, the
  ``map`` nodes and the events are in the published frame of ``robot_state``
  (``axis_remap``/``axis_sign_z`` of the run's configuration, metadata record
  ``poseidon``; the defaults when the recording has none) and are taken back to NED.
- The estimates start wherever their producer put their origin.  To compare shapes with
  ground truth, dead reckoning is translated so that its first sample coincides with the
  truth at that stamp, and the map so that its first node (by id) coincides with the
  translated dead reckoning at that node's stamp (the map is built from odometry deltas).
- Times are event times in ns; figures show seconds since the first message of the run.
"""
from __future__ import annotations

import base64
import io
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.mcap_io import RecordingError, read_messages, read_metadata
from common.messages import ExperienceImage

__all__ = ["RunData", "Track", "load_run", "run_label"]

log = logging.getLogger(__name__)

#: keys the report reads (everything else in the recording is only counted)
REPORT_KEYS = ["truth/pose", "Odometry", "dead_reckoning", "experience_event", "map", "experience_image",
               "local_view_cells", "truth/revisits", "neocortex/sdr"]


@dataclass
class Track:
    """A time-stamped 3D trajectory in NED (``stamps`` int64 ns, ``ned`` (n, 3) metres)."""

    stamps: np.ndarray
    ned: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return len(self.stamps)

    def at(self, stamps: np.ndarray) -> np.ndarray:
        """Positions linearly interpolated at ``stamps``; NaN outside the covered span."""
        t = np.asarray(stamps, dtype=np.int64)
        out = np.full((len(t), 3), np.nan)
        if len(self.stamps) == 0:
            return out
        inside = (t >= self.stamps[0]) & (t <= self.stamps[-1])
        ref = (self.stamps - self.stamps[0]).astype(np.float64)
        q = (t[inside] - self.stamps[0]).astype(np.float64)
        for k in range(3):
            out[inside, k] = np.interp(q, ref, self.ned[:, k])
        return out

    def translated(self, offset: np.ndarray) -> "Track":
        return Track(self.stamps, self.ned + offset, self.source)

    def travelled(self) -> np.ndarray:
        """Cumulative distance travelled (m) at each sample."""
        if len(self.ned) == 0:
            return np.zeros(0)
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.ned, axis=0), axis=1))])


@dataclass
class RunData:
    """Everything the figures of one run are drawn from."""

    path: Path
    label: str
    metadata: dict[str, Any]
    counts: dict[str, int]
    start_ns: int
    end_ns: int
    truth: Track
    dead_reckoning: Track
    #: ``experience_event``: stamps, LVC id, gate
    event_stamps: np.ndarray
    event_lvc: np.ndarray
    event_gate: list[str]
    #: final ``map``: node id, LVC id, stamp, NED position; links (source, target, loop_closure)
    node_ids: np.ndarray
    node_lvc: np.ndarray
    node_stamps: np.ndarray
    node_ned: np.ndarray
    links: np.ndarray
    link_loop: np.ndarray
    maps_received: int
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
    #: a few ``experience_image`` frames as JPEG data URIs: (stamp, lvc id or -1, uri, size)
    images: list[tuple[int, int, str, str]] = field(default_factory=list)
    image_count: int = 0

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def seconds(self, stamps: np.ndarray) -> np.ndarray:
        """Seconds since the run's first message."""
        return (np.asarray(stamps, dtype=np.int64) - self.start_ns) / 1e9

    @property
    def map_track(self) -> Track:
        """The final map's nodes in id order (the experience path)."""
        return Track(self.node_stamps, self.node_ned, "map")


def _parse_metadata(path: Path) -> dict[str, Any]:
    raw = read_metadata(path).get("poseidon", {})
    out: dict[str, Any] = {}
    for k, v in raw.items():
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v  # plain strings are stored as they are (see RecordingWriter.add_metadata)
    return out


def _output_frame(metadata: dict[str, Any]) -> Any:
    from common.config import PoseidonConfig
    from services.robot_state.frames import OutputFrame
    cfg = metadata.get("config")
    rs = (cfg or {}).get("robot_state", {}) if isinstance(cfg, dict) else {}
    default = PoseidonConfig().robot_state
    return OutputFrame(rs.get("axis_remap", default.axis_remap), float(rs.get("axis_sign_z", default.axis_sign_z)))


def run_label(metadata: dict[str, Any], path: Path, has_events: bool = True) -> str:
    """``<file stem> (VPR Guard ON|OFF)`` when the run has events and its configuration says, else the stem."""
    cfg = metadata.get("config")
    guard = cfg.get("vpr_guard", {}).get("require_vpr_for_event") if isinstance(cfg, dict) else None
    if guard is None or not has_events:
        return path.stem
    return f"{path.stem} (VPR Guard {'ON' if guard else 'OFF'})"


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


def _anchor(track: Track, reference: Track) -> Track:
    """Translate ``track`` so its first sample lies on ``reference`` at the same stamp."""
    if len(track) == 0 or len(reference) == 0:
        return track
    ref = reference.at(track.stamps[:1])[0]
    if np.isnan(ref).any():
        log.warning("%s starts outside the span of %s: not anchored", track.source, reference.source)
        return track
    return track.translated(ref - track.ned[0])


def load_run(path: str | Path, label: str | None = None, max_images: int = 12) -> RunData:
    """Read what the report draws from one run recording (raises RecordingError)."""
    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such recording")
    metadata = _parse_metadata(p)
    frame = _output_frame(metadata)
    counts: dict[str, int] = {}
    first = last = None
    truth_t: list[int] = []
    truth_p: list[list[float]] = []
    odo_t: list[int] = []
    odo_p: list[np.ndarray] = []
    drk_t: list[int] = []
    drk_p: list[np.ndarray] = []
    ev_t: list[int] = []
    ev_l: list[int] = []
    ev_g: list[str] = []
    last_map: Any = None
    maps = 0
    lvc_t: list[int] = []
    lvc_i: list[int] = []
    lvc_n: list[bool] = []
    sdr_t: list[int] = []
    sdr_a: list[np.ndarray] = []
    sdr_size = 0
    rev: dict[int, tuple[int, np.ndarray]] = {}
    img_stamps: list[int] = []
    for r in read_messages(p):
        counts[r.key] = counts.get(r.key, 0) + 1
        first = r.stamp if first is None else min(first, r.stamp)
        last = r.stamp if last is None else max(last, r.stamp)
        if r.key not in REPORT_KEYS:
            continue
        if r.key == "experience_image":
            img_stamps.append(r.stamp)  # decoded below, only the few shown
            continue
        m: Any = r.message()
        st = m.header.stamp
        if r.key == "truth/pose":
            truth_t.append(st)
            truth_p.append(m.position)
        elif r.key == "Odometry":
            odo_t.append(st)
            odo_p.append(frame.position_to_ned(np.asarray(m.position, dtype=np.float64)))
        elif r.key == "dead_reckoning":
            drk_t.append(st)
            drk_p.append(frame.position_to_ned(np.asarray(m.position, dtype=np.float64)))
        elif r.key == "experience_event":
            ev_t.append(st)
            ev_l.append(m.lvc_id)
            ev_g.append(m.gate)
        elif r.key == "map":
            last_map = m
            maps += 1
        elif r.key == "local_view_cells":
            lvc_t.append(st)
            lvc_i.append(m.most_active_cell)
            lvc_n.append(m.is_new)
        elif r.key == "truth/revisits":
            rev[m.frame_index] = (st, np.asarray(m.same_place, dtype=np.int64))
        elif r.key == "neocortex/sdr":
            sdr_t.append(st)
            sdr_a.append(np.asarray(m.fused.active, dtype=np.int64))
            sdr_size = max(sdr_size, m.fused.size)
    if not counts:
        raise RecordingError(f"{p}: no readable message (not an MCAP recording, or an empty one)")
    i64 = lambda v: np.asarray(v, dtype=np.int64)  # noqa: E731
    xyz = lambda v: np.asarray(v, dtype=np.float64).reshape(-1, 3)  # noqa: E731
    truth = Track(i64(truth_t), xyz(truth_p), "truth/pose")
    dr = Track(i64(odo_t), xyz(odo_p), "Odometry") if odo_t else Track(i64(drk_t), xyz(drk_p), "dead_reckoning")
    dr = _anchor(dr, truth)
    if last_map is not None and last_map.nodes:
        nodes = sorted(last_map.nodes, key=lambda n: n.id)
        node_ids = i64([n.id for n in nodes])
        node_lvc = i64([n.lvc_id for n in nodes])
        node_stamps = i64([n.stamp for n in nodes])
        node_ned = xyz([frame.position_to_ned(np.asarray(n.position, dtype=np.float64)) for n in nodes])
        anchored = _anchor(Track(node_stamps, node_ned, "map"), dr if len(dr) else truth)
        node_ned = anchored.ned
        links = i64([[ln.source, ln.target] for ln in last_map.links]).reshape(-1, 2)
        link_loop = np.asarray([ln.loop_closure for ln in last_map.links], dtype=bool)
    else:
        node_ids = node_lvc = node_stamps = i64([])
        node_ned = xyz([])
        links = i64([]).reshape(0, 2)
        link_loop = np.zeros(0, dtype=bool)
    frames = sorted(rev)
    if frames and frames != list(range(len(frames))):
        log.warning("%s: truth/revisits frame indices are not 0..%d; missing frames are left out",
                    p, len(frames) - 1)
    n_frames = (frames[-1] + 1) if frames else 0
    revisit_stamps = np.full(n_frames, -1, dtype=np.int64)
    revisit_same: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * n_frames
    for k in frames:
        revisit_stamps[k], revisit_same[k] = rev[k]
    data = RunData(
        path=p, label=label or run_label(metadata, p, bool(ev_t)), metadata=metadata, counts=counts,
        start_ns=int(first or 0), end_ns=int(last or 0), truth=truth, dead_reckoning=dr,
        event_stamps=i64(ev_t), event_lvc=i64(ev_l), event_gate=ev_g,
        node_ids=node_ids, node_lvc=node_lvc, node_stamps=node_stamps, node_ned=node_ned,
        links=links, link_loop=link_loop, maps_received=maps,
        lvc_stamps=i64(lvc_t), lvc_id=i64(lvc_i), lvc_new=np.asarray(lvc_n, dtype=bool),
        sdr_stamps=i64(sdr_t), sdr_active=sdr_a, sdr_size=sdr_size,
        revisit_stamps=revisit_stamps, revisit_same=revisit_same, image_count=len(img_stamps))
    if img_stamps and max_images > 0:
        chosen = {img_stamps[i] for i in np.unique(np.linspace(0, len(img_stamps) - 1, max_images).round().astype(int))}
        ev_lvc = dict(zip(ev_t, ev_l))
        for r in read_messages(p, keys=["experience_image"]):
            if r.stamp in chosen:
                chosen.discard(r.stamp)
                img: Any = r.message()
                uri, size = _image_uri(img)
                data.images.append((r.stamp, int(ev_lvc.get(r.stamp, -1)), uri, size))
    return data
