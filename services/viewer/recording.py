"""A finished run's recording as the page sees it at any time of the slider: :class:`RecordingView`.

The displayed streams except the camera are read once and kept decoded (a run of hours holds
tens of thousands of small messages); the model is advanced message by message to the asked
time and rebuilt from the start only when the slider goes back.  Camera frames are read one
at a time from the file's chunk index when the page asks for the frame of the current time,
so the camera stream is never held in memory.  The snapshot's ``streams`` says which of the
page's sources the recording has at all (``camera``, ``sonar``, ``scan``, ``activity``,
``truth``), so the page can say why a panel is empty.
"""
from __future__ import annotations

import bisect
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from common.codec import DecodeError
from common.mcap_io import RecordingError, read_messages, recording_keys
from common.messages import Image, Message
from services.viewer.config import ViewConfig
from services.viewer.live import ViewError
from services.viewer.model import ACTIVITY_KEY, MAP_KEY, ViewModel, jpeg_of, view_keys

__all__ = ["RecordingView", "final_model"]


def final_model(path: str | Path, cfg: ViewConfig) -> ViewModel:
    """The view's model at the end of the recording at ``path``: its displayed streams but the
    camera applied in order, streamed (memory bounded like the live view's, whatever the run's
    length; a :class:`RecordingView` keeps every message for its slider).

    :raises ViewError: the file is not a readable recording (the message names it)"""
    path = Path(path)
    model = ViewModel(cfg)
    try:
        keys = _readable_keys(path)
        for rec in read_messages(path, keys=_model_keys(cfg, keys)):
            model.apply(rec.key, rec.message())
    except (RecordingError, DecodeError) as exc:
        raise ViewError(f"{path}: {exc}") from None
    return model


def _readable_keys(path: Path) -> dict[str, str]:
    """The recording's keys; :class:`ViewError` when it has none readable."""
    try:
        keys = recording_keys(path)
    except RecordingError as exc:
        raise ViewError(str(exc)) from None
    if not keys:
        raise ViewError(f"{path}: no readable messages (not an MCAP recording, or damaged from its start)")
    return keys


def _model_keys(cfg: ViewConfig, keys: dict[str, str]) -> list[str]:
    """The recorded keys the model is built from: the displayed ones but the camera (read a frame
    at a time when shown)."""
    return [k for k in view_keys(cfg) if k in keys and k != cfg.camera_key]


class RecordingView:
    """The view of the recording at ``path`` at a chosen time (see the module notes).

    :raises ViewError: the file is not a readable recording, or holds no experience map
        (a sensor recording that was never run through the services)."""

    def __init__(self, path: str | Path, cfg: ViewConfig):
        self.path = Path(path)
        self.cfg = cfg
        keys = _readable_keys(self.path)
        if MAP_KEY not in keys:
            raise ViewError(f"{self.path} holds no experience map (no '{MAP_KEY}' key): it is not the recording of a "
                            f"run; run it through the services first (poseidon run --input {self.path.name} "
                            f"--out RUN.mcap) and view RUN.mcap")
        self.streams = {"camera": cfg.camera_key in keys, "sonar": cfg.sonar_key in keys, "scan": cfg.scan_key in keys,
                        "activity": ACTIVITY_KEY in keys, "truth": any(k in keys for k in cfg.truth_keys)}
        wanted = _model_keys(cfg, keys)
        self.messages: list[tuple[int, str, Message]] = []
        try:
            for rec in read_messages(self.path, keys=wanted):
                self.messages.append((rec.stamp, rec.key, rec.message()))
            self.camera_stamps = [m.stamp for m in read_messages(self.path, keys=[cfg.camera_key])
                                  ] if cfg.camera_key in keys else []
        except (RecordingError, DecodeError) as exc:
            raise ViewError(f"{self.path}: {exc}") from None
        stamps = [s for s, _k, _m in self.messages] + self.camera_stamps
        self.start, self.end = min(stamps), max(stamps)
        self._stamps = [s for s, _k, _m in self.messages]
        self.model = ViewModel(cfg)
        self._applied = 0  # messages applied to the model
        self._camera_index = -1
        self._jpeg: tuple[int, bytes] = (-1, b"")
        self.lock = threading.Lock()

    @property
    def duration_s(self) -> float:
        return (self.end - self.start) / 1e9

    def seek(self, t_s: float) -> None:
        """Bring the model to ``t_s`` seconds after the recording's first message."""
        target = self.start + int(round(max(0.0, t_s) * 1e9))
        upto = bisect.bisect_right(self._stamps, target)
        if upto < self._applied:
            self.model = ViewModel(self.cfg)
            self._applied = 0
        self.model.t0 = self.start
        for _stamp, key, msg in self.messages[self._applied:upto]:
            self.model.apply(key, msg)
        self._applied = upto
        self.model.stamp = target
        self._camera_index = bisect.bisect_right(self.camera_stamps, target) - 1

    def snapshot(self, have: Mapping[str, str], t_s: float) -> dict[str, Any]:
        """The state at ``t_s`` for a client holding ``have`` (see :meth:`ViewModel.snapshot`)."""
        with self.lock:
            self.seek(t_s)
            snap = self.model.snapshot(have)
            snap["camera_version"] = self._camera_index + 1
        snap["mode"] = "recording"
        snap["duration_s"] = round(self.duration_s, 3)
        snap["recording"] = self.path.name
        snap["streams"] = self.streams
        return snap

    def camera(self) -> tuple[int, bytes]:
        """(version, JPEG) of the camera frame at the current time ((0, b"") before the first)."""
        with self.lock:
            index = self._camera_index
            if index < 0:
                return 0, b""
            if self._jpeg[0] != index:
                stamp = self.camera_stamps[index]
                frame = next(iter(read_messages(self.path, keys=[self.cfg.camera_key], start_ns=stamp,
                                                end_ns=stamp + 1)))
                msg = frame.message()
                if not isinstance(msg, Image):
                    raise ViewError(f"{self.path}: {self.cfg.camera_key} carries {frame.type_name}, not an image")
                self._jpeg = (index, jpeg_of(msg, self.cfg.image_width, self.cfg.jpeg_quality))
            return index + 1, self._jpeg[1]
