"""When the encoder produces an output, and when the sonar raster is re-encoded (no transport).

:class:`SonarClock` keeps the sonar side of the encoder's clock (the rules are stated in
:mod:`services.encoder.node`): the :class:`~services.encoder.sonar.SonarRaster` the beams
accumulate in, the bearing swept since the last output (the sonar sweep clock: one
sonar-only output per further 360 deg while the camera is silent) and since the last sonar
encoding (the re-encoding rule: at least ``encoder.sonar_encode_sweep_deg``), the last
sonar SDR, and the freshness test of the sonar for a camera frame (newest beam at most
``sync.sync_stale_sec`` older).  Stamps are integer nanoseconds, bearings radians.

:class:`EncoderCore` drives a :class:`~services.encoder.encoder.MultimodalEncoder` with
that clock: one call per camera frame or sonar message, returning the per-modality SDRs of
an output (or None).  Both are plain classes: a notebook or a test feeds them messages
directly.  What happened is tallied in order in :attr:`EncoderCore.events` (counter name,
increment), which the node drains into its counters.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from common.messages import Image, LaserScan, RangeImageBeam

from .encoder import image_to_rgb
from .fusion import FUSION_MODES
from .sonar import SonarRaster

__all__ = ["SonarClock", "SonarUpdate", "EncoderCore"]

TWO_PI = 2.0 * math.pi


@dataclass
class SonarUpdate:
    """What one sonar message did to the clock."""

    reset: bool       # the gap since the previous beam exceeded the stale time: the ring restarted
    beams: int        # beams added
    clocked: bool     # the sonar sweep clock fires: a sonar-only output is due now


class SonarClock:
    """The sonar raster plus the sweep clock and the re-encoding rule.

    ``mode``: ``encoder.fusion_mode``; ``stale_ns``: ``sync.sync_stale_sec`` in ns;
    ``reencode_rad``: ``encoder.sonar_encode_sweep_deg`` in radians.
    """

    def __init__(self, raster: SonarRaster, mode: str, stale_ns: int, reencode_rad: float):
        if mode not in FUSION_MODES:
            raise ValueError(f"fusion mode must be one of {FUSION_MODES}, got {mode!r}")
        self.raster = raster
        self.mode = mode
        self.stale_ns = int(stale_ns)
        self.reencode_rad = float(reencode_rad)
        self.last_camera: int | None = None   # stamp of the newest camera frame (ns)
        self.sweep_rad = 0.0                  # bearing swept since the last output
        self.since_sonar_rad = 0.0            # bearing swept since the raster was last encoded
        self.sonar_sdr: np.ndarray | None = None   # the last sonar SDR

    def add(self, msg: RangeImageBeam | LaserScan) -> SonarUpdate:
        """Add one beam (or scan) to the raster; a gap > stale time first resets the ring.
        The swept bearing is the sum of the wrapped steps between consecutive beams."""
        stamp = msg.header.stamp
        reset = self.raster.last_stamp is not None and stamp - self.raster.last_stamp > self.stale_ns
        if reset:
            self.raster.reset()
            self.sweep_rad = 0.0
            self.sonar_sdr = None
        prev = self.raster.last_angle
        if isinstance(msg, RangeImageBeam):
            self.raster.add_beam(msg)
            angles = [msg.angle_rad]
        elif isinstance(msg, LaserScan):
            angles = self.raster.add_scan(msg)
        else:
            raise TypeError(f"encoder: the sonar key carries {type(msg).__name__}, "
                            "expected RangeImageBeam or LaserScan")
        for a in angles:
            if prev is not None:
                step = abs((a - prev + math.pi) % TWO_PI - math.pi)
                self.sweep_rad += step
                self.since_sonar_rad += step
            prev = a
        camera_silent = self.last_camera is None or stamp - self.last_camera > self.stale_ns
        sonar_clock = self.mode == "sonar" or (self.mode in ("union", "and") and camera_silent)
        return SonarUpdate(reset=reset, beams=len(angles), clocked=sonar_clock and self.sweep_rad >= TWO_PI)

    def camera_seen(self, stamp: int) -> None:
        """A camera frame at ``stamp`` (ns): the camera holds the clock while it is not stale."""
        self.last_camera = stamp

    def fresh(self, stamp: int) -> bool:
        """The sonar joins an output at ``stamp``: not ``camera`` mode, the ring holds beams and
        the newest is at most the stale time older."""
        r = self.raster
        return (self.mode != "camera" and r.has_data and r.last_stamp is not None
                and stamp - r.last_stamp <= self.stale_ns)

    @property
    def due(self) -> bool:
        """The re-encoding rule: no sonar SDR yet, or swept at least ``reencode_rad`` since the last."""
        return self.sonar_sdr is None or self.since_sonar_rad >= self.reencode_rad

    def encoded(self, sdr: np.ndarray) -> None:
        """The raster was just encoded to ``sdr``."""
        self.sonar_sdr = sdr
        self.since_sonar_rad = 0.0

    def emitted(self) -> None:
        """An output was produced: the sweep clock counts from here."""
        self.sweep_rad = 0.0


class SdrEncoder(Protocol):
    """What :class:`EncoderCore` uses of its encoder (a :class:`MultimodalEncoder`, or a stand-in)."""

    def embed(self, images: Sequence[np.ndarray]) -> list[np.ndarray]: ...

    def sdr(self, modality: str, embedding: np.ndarray) -> np.ndarray: ...

    def fuse(self, sdrs: Mapping[str, np.ndarray | None], mode: str | None = None) -> np.ndarray: ...


class EncoderCore:
    """Camera frames and sonar messages -> per-modality SDRs of the encoder's outputs.

    :meth:`on_camera` and :meth:`on_sonar` return ``{modality: sorted active bits}`` when an
    output is due (fuse them with :meth:`fuse`), else None.  A fresh sonar that is due is
    embedded in one batch with the frame (camera first).
    """

    def __init__(self, encoder: SdrEncoder, clock: SonarClock):
        self.encoder = encoder
        self.clock = clock
        self.events: list[tuple[str, int]] = []

    @property
    def mode(self) -> str:
        return self.clock.mode

    def _count(self, what: str, n: int = 1) -> None:
        self.events.append((what, n))

    def take_events(self) -> list[tuple[str, int]]:
        """The (counter, increment) pairs since the last call, in order."""
        out, self.events = self.events, []
        return out

    def on_sonar(self, msg: RangeImageBeam | LaserScan) -> dict[str, np.ndarray] | None:
        """Add the message; the sonar-only SDRs when the sweep clock fires."""
        up = self.clock.add(msg)
        if up.reset:
            self._count("sonar_ring_reset")
        self._count("sonar_beams", up.beams)
        if not up.clocked:
            return None
        sdrs = {"sonar": self._sonar_sdr()}
        self.clock.emitted()
        return sdrs

    def on_camera(self, msg: Image) -> dict[str, np.ndarray] | None:
        """The frame's SDRs (camera, and sonar when fresh); None in ``sonar`` mode."""
        stamp = msg.header.stamp
        self.clock.camera_seen(stamp)
        if self.mode == "sonar":
            self._count("camera_frames_unused")
            return None
        rgb = image_to_rgb(msg)
        sonar_fresh = self.clock.fresh(stamp)
        sdrs: dict[str, np.ndarray] = {}
        if sonar_fresh and self.clock.due:
            y_cam, y_son = self.encoder.embed([rgb, self.clock.raster.image3()])
            self._encoded(y_son)
        else:
            (y_cam,) = self.encoder.embed([rgb])
            if sonar_fresh:
                self._count("sonar_sdr_reused")
        sdrs["camera"] = self.encoder.sdr("camera", y_cam)
        if sonar_fresh:
            assert self.clock.sonar_sdr is not None
            sdrs["sonar"] = self.clock.sonar_sdr
        else:
            self._count("frames_without_sonar")
        self.clock.emitted()
        return sdrs

    def _encoded(self, y: np.ndarray) -> None:
        self.clock.encoded(self.encoder.sdr("sonar", y))
        self._count("sonar_encodings")

    def _sonar_sdr(self) -> np.ndarray:
        if self.clock.due:
            (y,) = self.encoder.embed([self.clock.raster.image3()])
            self._encoded(y)
        assert self.clock.sonar_sdr is not None
        return self.clock.sonar_sdr

    def fuse(self, sdrs: dict[str, np.ndarray]) -> np.ndarray:
        """Fused active bits of the output (Eq. 4.3, the clock's fusion mode)."""
        return self.encoder.fuse(sdrs, self.mode)
