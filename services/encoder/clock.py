"""The sonar side of the encoder's clock: when an output is due, when the sonar raster is re-encoded (no transport).

:class:`SonarClock` keeps the sonar side of the encoder's clock (the rules are stated in
:mod:`services.encoder.node`): the :class:`~services.encoder.sonar.SonarRaster` the beams
accumulate in, the bearing swept since the last output (the sonar sweep clock: one
sonar-only output per further 360 deg while the camera is silent) and since the last sonar
encoding (the re-encoding rule: at least ``encoder.sonar.encode_sweep_deg``), the last
sonar SDR, and the freshness test of the sonar for a camera frame (newest beam at most
``sync.sync_stale_sec`` older).  Stamps are integer nanoseconds, bearings radians.

The encoder core that drives this clock: :mod:`services.encoder.core`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.messages import LaserScan, RangeImageBeam

from .fusion import FUSION_MODES
from .sonar import SonarRaster

__all__ = ["SonarClock", "SonarUpdate"]

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
    ``reencode_rad``: ``encoder.sonar.encode_sweep_deg`` in radians.
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
