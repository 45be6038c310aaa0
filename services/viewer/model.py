"""What the page shows, built from the run's messages: :class:`ViewModel`.

The same model serves a live run (fed by :mod:`services.viewer.live` with sampled messages)
and a finished recording (fed by :mod:`services.viewer.recording` up to the slider's time).
Everything it keeps is bounded: a trajectory or the LVC timeline drops every other point when
full (:class:`Trail`), the sonar sweep keeps one beam per angle bin, the camera only its latest
frame; the map and the pose-cell activity (``posecells/activity``: x-y and z-yaw projections,
uint8, with the centroid) are the latest published ones.  :meth:`ViewModel.snapshot` answers
with deltas: the page says which map version, which sonar sweep and how much of each trail it
already holds, and gets only what changed (a trail that was thinned is sent whole again; the
activity when its version moved; of the sweep, the angle bins written since the page's version).
"""
from __future__ import annotations

import base64
import io
import itertools
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image as PilImage

from common.messages import (
    ExperienceEvent,
    ExperienceMap,
    Image,
    LaserScan,
    LatencyReport,
    LocalViewCells,
    Message,
    Odometry,
    PoseCellActivity,
    PoseStamped,
    RangeImageBeam,
)
from services.posecells.activity import ACTIVITY_KEY
from services.viewer.config import ViewConfig

__all__ = ["ViewModel", "Trail", "MapArrays", "map_arrays", "jpeg_of", "MAP_KEY", "LVC_KEY", "EVENT_KEY",
           "DR_KEY", "ODOM_KEY", "LATENCY_KEY", "ACTIVITY_KEY", "TRAILS", "SONAR_ANGLE_BINS", "view_keys",
           "activity_json"]

MAP_KEY, LVC_KEY, EVENT_KEY, DR_KEY, ODOM_KEY = "map", "local_view_cells", "experience_event", "dead_reckoning", "Odometry"
LATENCY_KEY = "live/latency"  # common.live.LATENCY_KEY (the live run's latency report)
#: the trails the page draws
TRAILS = ("dead_reckoning", "odometry", "truth", "posecells")
#: angle bins of the sonar sweep (one beam kept per bin)
SONAR_ANGLE_BINS = 200
#: a model's identity in the sonar version the page holds ("ident.version"): a page that held the sweep
#: of another model (a recording scrubbed back and rebuilt, a view restarted) gets the whole sweep
_MODEL_IDS = itertools.count(int(time.time()) % 100_000 * 1000)


def view_keys(cfg: ViewConfig) -> list[str]:
    """Every data key the view reads under ``cfg``."""
    return sorted({MAP_KEY, LVC_KEY, EVENT_KEY, DR_KEY, ODOM_KEY, LATENCY_KEY, ACTIVITY_KEY, cfg.camera_key,
                   cfg.sonar_key, cfg.scan_key, *cfg.truth_keys})


class Trail:
    """A bounded list of points: when full, every other point is dropped and ``epoch`` grows
    (a client holding an older epoch gets the whole trail again)."""

    def __init__(self, max_points: int, keep: int = 0):
        self.max_points = max_points
        self.points: list[list[float]] = []
        self.epoch = 0
        self._keep = keep  # index of a column whose truthy points survive thinning (LVC revisits)

    def add(self, point: list[float]) -> None:
        self.points.append(point)
        if len(self.points) > self.max_points:
            if self._keep:
                k = self._keep
                self.points = [p for i, p in enumerate(self.points) if i % 2 == 0 or p[k]]
            else:
                self.points = self.points[::2] + ([self.points[-1]] if len(self.points) % 2 == 0 else [])
            self.epoch += 1

    def since(self, have: str | None) -> dict[str, Any]:
        """The points a client holding ``have`` (``"epoch.count"``) lacks."""
        start = 0
        if have:
            epoch, _, count = have.partition(".")
            if epoch.isdigit() and count.isdigit() and int(epoch) == self.epoch and int(count) <= len(self.points):
                start = int(count)
        return {"epoch": self.epoch, "start": start, "points": self.points[start:]}


@dataclass
class MapArrays:
    """A published experience map, compact: node ids and positions, links (node indices) and
    which links close a loop."""

    stamp: int
    ids: np.ndarray        # (n,) int64
    xyz: np.ndarray        # (n, 3) float32
    links: np.ndarray      # (m, 2) int32 indices into ids
    loop: np.ndarray       # (m,) bool
    current: int           # index of the current node, -1 if none
    corrections: int

    @property
    def loop_closures(self) -> int:
        return int(self.loop.sum())


def map_arrays(msg: ExperienceMap) -> MapArrays:
    ids = np.array([n.id for n in msg.nodes], dtype=np.int64)
    xyz = np.array([n.position for n in msg.nodes], dtype=np.float32).reshape(-1, 3)
    index = {int(i): k for k, i in enumerate(ids)}
    pairs = [(index[lk.source], index[lk.target], lk.loop_closure) for lk in msg.links
             if lk.source in index and lk.target in index]
    links = np.array([(a, b) for a, b, _ in pairs], dtype=np.int32).reshape(-1, 2)
    loop = np.array([c for _, _, c in pairs], dtype=bool)
    return MapArrays(msg.header.stamp, ids, xyz, links, loop, index.get(msg.current, -1), msg.corrections)


def _rgb(msg: Image) -> np.ndarray:
    """An image's pixels as uint8 RGB or grey."""
    data = np.asarray(msg.data)
    enc = msg.encoding
    if enc == "mono16":
        return (data.reshape(msg.height, msg.width).astype(np.uint16) >> 8).astype(np.uint8)
    if enc == "mono8":
        return data.reshape(msg.height, msg.width).astype(np.uint8)
    channels = 4 if enc in ("rgba8", "bgra8") else 3
    px = data.reshape(msg.height, msg.width, channels)[:, :, :3]
    return px[:, :, ::-1] if enc.startswith("bgr") else px


def jpeg_of(msg: Image, width: int, quality: int) -> bytes:
    """A small JPEG of a camera frame (at most ``width`` pixels wide)."""
    img = PilImage.fromarray(np.ascontiguousarray(_rgb(msg)))
    if img.width > width:
        img = img.resize((width, max(1, round(img.height * width / img.width))), PilImage.Resampling.BILINEAR)
    out = io.BytesIO()
    img.save(out, format="JPEG", quality=quality)
    return out.getvalue()


def _r(v: float, nd: int = 2) -> float:
    return round(float(v), nd)


def _image_json(img: np.ndarray, scale: float) -> dict[str, Any]:
    return {"shape": list(img.shape), "scale": float(scale),
            "data": base64.b64encode(np.ascontiguousarray(img, np.uint8).tobytes()).decode()}


def activity_json(msg: PoseCellActivity) -> dict[str, Any]:
    """The page's form of a pose-cell activity message: both images (uint8, base64, row-major)
    with their scales, the centroid (m, rad) and the centroid in cells of each image's axes."""
    n_yaw = int(msg.zyaw.shape[1])
    x, y, z, yaw = (float(v) for v in msg.centroid)
    cells = [x / msg.spacing[0], y / msg.spacing[1], z / msg.spacing[2], (yaw % (2 * math.pi)) / (2 * math.pi / n_yaw)]
    return {"stamp": msg.header.stamp, "xy": _image_json(msg.xy, msg.xy_scale),
            "zyaw": _image_json(msg.zyaw, msg.zyaw_scale), "centroid": [_r(v, 3) for v in msg.centroid],
            "centroid_cells": [_r(v, 2) for v in cells], "steps": msg.steps}


class ViewModel:
    """The view's state (see the module notes).  Not thread-safe: one thread applies messages
    and takes snapshots (the live feed's pump, or the recording's lock)."""

    def __init__(self, cfg: ViewConfig):
        self.cfg = cfg
        self.t0: int | None = None
        self.stamp = 0
        self.map: MapArrays | None = None
        self.map_version = 0
        self.maps = 0
        self.provisional: list[list[float]] = []  # experiences announced since the last published map
        self.events = 0
        self.trails = {name: Trail(cfg.trajectory_points) for name in TRAILS}
        self.lvc = Trail(cfg.timeline_points, keep=2)
        self.lvc_ids: set[int] = set()
        self.lvc_frames = 0
        self.last_lvc = -1
        self.revisits = 0
        self.pose: list[float] | None = None  # latest dead-reckoning pose x y z yaw
        self.posecell: list[float] | None = None  # latest pose-cell estimate x y z yaw
        self.truth_key: str | None = None
        self.camera: Image | None = None
        self.camera_version = 0
        self._jpeg: tuple[int, bytes] = (0, b"")
        self.sonar: dict[int, tuple[float, float, bytes]] = {}  # angle bin -> (angle rad, max range m, bins)
        self.sonar_version = 0
        self._sonar_at: dict[int, int] = {}  # angle bin -> sonar_version that wrote it
        self.ident = next(_MODEL_IDS)
        self._scan_msg: LaserScan | None = None  # latest laser scan, turned into points when asked for
        self._scan_points: tuple[int, list[list[float]]] = (-1, [])
        self.latency: dict[str, Any] | None = None
        self._activity: tuple[PoseCellActivity, float] | None = None  # latest activity and its time (s)
        self._activity_json: tuple[int, dict[str, Any]] = (-1, {})
        self.activity_version = 0

    def continue_from(self, old: ViewModel) -> None:
        """Take the place of ``old`` on a page that showed it: every version and trail epoch moves
        past ``old``'s (so each panel is fetched whole and drawn again), and ``old``'s camera frame
        is kept when this model has none (a recording's model reads no camera frames)."""
        self.map_version += old.map_version + 1
        self.activity_version += old.activity_version + 1
        self.sonar_version += old.sonar_version + 1
        for name, trail in self.trails.items():  # a page holding old's trails gets them whole
            trail.epoch += old.trails[name].epoch + 1
        self.lvc.epoch += old.lvc.epoch + 1
        if self.camera is None:
            self.camera, self.camera_version = old.camera, old.camera_version
        else:
            self.camera_version += old.camera_version + 1

    # ---- input ---------------------------------------------------------------------------
    def apply(self, key: str, msg: Message) -> None:
        """Take one message of ``key`` into the view."""
        stamp = msg.header.stamp
        if self.t0 is None:
            self.t0 = stamp
        self.stamp = max(self.stamp, stamp)
        cfg = self.cfg
        if key == MAP_KEY and isinstance(msg, ExperienceMap):
            self.map = map_arrays(msg)
            self.map_version += 1
            self.maps += 1
            self.provisional = []
        elif key == LVC_KEY and isinstance(msg, LocalViewCells):
            cell = msg.most_active_cell
            # a revisit: an older place recognised again (not the place of the frame before)
            revisit = not msg.is_new and cell in self.lvc_ids and cell != self.last_lvc
            self.lvc_ids.add(cell)
            self.lvc_frames += 1
            self.last_lvc = cell
            self.revisits += int(revisit)
            self.lvc.add([self._t(stamp), cell, int(revisit)])
        elif key == EVENT_KEY and isinstance(msg, ExperienceEvent):
            self.events += 1
            self.provisional.append([_r(v) for v in msg.odom_position])
            self.posecell = [_r(v, 3) for v in msg.pc_centroid]
            self.trails["posecells"].add(list(self.posecell))
        elif key == DR_KEY and isinstance(msg, PoseStamped):
            self.pose = [*(_r(v, 3) for v in msg.position), _r(msg.yaw, 3)]
            self.trails["dead_reckoning"].add([_r(v) for v in msg.position])
        elif key == ODOM_KEY and isinstance(msg, Odometry):
            self.trails["odometry"].add([_r(v) for v in msg.position])
        elif key in cfg.truth_keys and isinstance(msg, Odometry):
            if self.truth_key is None or cfg.truth_keys.index(key) < cfg.truth_keys.index(self.truth_key):
                if self.truth_key is not None:
                    self.trails["truth"] = Trail(cfg.trajectory_points)
                self.truth_key = key
            if key == self.truth_key:
                self.trails["truth"].add([_r(v) for v in msg.position])
        elif key == cfg.camera_key and isinstance(msg, Image):
            self.camera = msg
            self.camera_version += 1
        elif key in (cfg.sonar_key, cfg.scan_key) and isinstance(msg, RangeImageBeam):
            self._beam(msg)
        elif key in (cfg.sonar_key, cfg.scan_key) and isinstance(msg, LaserScan):
            self._scan(msg)
        elif key == ACTIVITY_KEY and isinstance(msg, PoseCellActivity):
            self._activity = (msg, self._t(stamp))
            self.activity_version += 1
        elif key == LATENCY_KEY and isinstance(msg, LatencyReport):
            self.latency = {k: v.model_dump() for k, v in msg.stages.items()}

    def _t(self, stamp: int) -> float:
        return _r((stamp - (self.t0 or stamp)) / 1e9, 2)

    def _beam(self, msg: RangeImageBeam) -> None:
        data = np.asarray(msg.beam_data, dtype=np.float32)
        if data.size == 0:
            return
        n = self.cfg.sonar_bins
        if data.size > n:  # the strongest echo of each group of bins
            data = data[: data.size // n * n].reshape(n, -1).max(axis=1)
        top = float(data.max())
        scaled = (np.clip(data / top, 0, 1) * 255).astype(np.uint8) if top > 0 else np.zeros(data.size, np.uint8)
        angle = float(msg.angle_rad)
        k = int(round((angle % (2 * math.pi)) / (2 * math.pi) * SONAR_ANGLE_BINS)) % SONAR_ANGLE_BINS
        self.sonar[k] = (angle, float(msg.max_range), scaled.tobytes())
        self.sonar_version += 1
        self._sonar_at[k] = self.sonar_version

    def _scan(self, msg: LaserScan) -> None:
        self._scan_msg = msg
        self.sonar_version += 1

    @property
    def scan(self) -> list[list[float]]:
        """The latest laser scan as at most about 360 points (x, y m, sensor frame; valid ranges
        only), computed once per scan and only when asked for (a recording seeks over thousands)."""
        msg = self._scan_msg
        if msg is None:
            return []
        if self._scan_points[0] != self.sonar_version:
            r = np.asarray(msg.ranges, dtype=np.float64)
            a = msg.angle_min + np.arange(r.size) * msg.angle_increment
            ok = np.isfinite(r) & (r >= msg.range_min) & (r <= msg.range_max)
            step = max(1, r.size // 360)
            r, a = r[ok][::step], a[ok][::step]
            points: list[list[float]] = np.round(np.column_stack([r * np.cos(a), r * np.sin(a)]), 2).tolist()
            self._scan_points = (self.sonar_version, points)
        return self._scan_points[1]

    @property
    def activity(self) -> dict[str, Any] | None:
        """The latest pose-cell activity in the page's form (:func:`activity_json` and ``t``, s),
        computed once per message and only when asked for."""
        if self._activity is None:
            return None
        if self._activity_json[0] != self.activity_version:
            msg, t = self._activity
            self._activity_json = (self.activity_version, {**activity_json(msg), "t": t})
        return self._activity_json[1]

    # ---- output --------------------------------------------------------------------------
    def counts(self) -> dict[str, Any]:
        """The figures shown at the top of the page (and checked by the tests)."""
        m = self.map
        return {"nodes": int(m.ids.size) if m is not None else 0,
                "loop_closures": m.loop_closures if m is not None else 0,
                "corrections": m.corrections if m is not None else 0,
                "maps": self.maps, "events": self.events, "lvc": len(self.lvc_ids), "last_lvc": self.last_lvc,
                "lvc_frames": self.lvc_frames, "revisits": self.revisits, "pose": self.pose,
                "posecell": self.posecell}

    def camera_jpeg(self) -> tuple[int, bytes]:
        """(version, JPEG) of the latest camera frame, encoded once per frame asked for."""
        if self.camera is not None and self._jpeg[0] != self.camera_version:
            self._jpeg = (self.camera_version, jpeg_of(self.camera, self.cfg.image_width, self.cfg.jpeg_quality))
        return self._jpeg

    def snapshot(self, have: Mapping[str, str]) -> dict[str, Any]:
        """The state for a client that holds ``have`` (``map``: map version, ``sonar``: the
        ``sonar_have`` it was given (:meth:`sonar_since`), ``activity``: activity version, each trail name and ``lvc``: ``"epoch.count"``):
        only what it lacks."""
        out: dict[str, Any] = {"stamp": self.stamp, "t": self._t(self.stamp) if self.t0 is not None else 0.0,
                               "counts": self.counts(), "map_version": self.map_version,
                               "camera_version": self.camera_version if self.camera is not None else 0,
                               "sonar_version": self.sonar_version, "truth_key": self.truth_key,
                               "provisional": self.provisional, "latency_report": self.latency,
                               "update_hz": self.cfg.update_hz, "activity_version": self.activity_version}
        if self.map is not None and have.get("map") != str(self.map_version):
            m = self.map
            out["map"] = {"ids": m.ids.tolist(), "xyz": np.round(m.xyz.astype(np.float64), 2).tolist(),
                          "links": m.links.tolist(), "loop": m.loop.astype(int).tolist(), "current": m.current}
        if self._activity is not None and have.get("activity") != str(self.activity_version):
            out["activity"] = self.activity
        out["trails"] = {name: t.since(have.get(name)) for name, t in self.trails.items()}
        out["lvc"] = self.lvc.since(have.get("lvc"))
        out["sonar_have"] = f"{self.ident}.{self.sonar_version}"
        if have.get("sonar") != out["sonar_have"]:
            out["sonar"] = self.sonar_since(have.get("sonar"))
        return out

    def sonar_since(self, have: str | None) -> dict[str, Any]:
        """The sweep for a page holding ``have`` (``"ident.version"`` of :meth:`snapshot`'s
        ``sonar_have``): ``beams`` ``[bin, angle rad, max range m, base64 uint8 bins]`` written
        since that version, all of them (``full``) when it is not this model's or is unknown;
        ``scan``: the latest laser scan's points."""
        since = -1
        ident, _, version = (have or "").partition(".")
        if ident == str(self.ident) and version.isdigit() and int(version) <= self.sonar_version:
            since = int(version)
        beams = [[k, _r(a, 4), _r(rng, 1), base64.b64encode(b).decode()] for k, (a, rng, b) in self.sonar.items()
                 if self._sonar_at[k] > since]
        return {"full": since < 0, "beams": beams, "scan": self.scan}
