"""Sonar observation o_t^(son) of Eq. 4.1: MSIS beams rasterised into a polar image.

A mechanically scanned imaging sonar (MSIS: Tritech Micron / SeaKing) delivers one beam
at a time; a full 360 deg sweep takes seconds.  :class:`SonarRaster` keeps the most recent
sweep as a ring of ``W`` angle bins (``sonar.polar_width``): each incoming beam overwrites
the bins it covers, so the image always shows the latest echo profile at every bearing.

Polar image (default, the dissertation's "polar tensor"), shape (H, W) =
(``sonar.polar_height``, ``sonar.polar_width``):

* column j covers bearings [j, j+1) * 2 pi / W (beam angle taken modulo 2 pi);
* row i covers ranges [i, i+1) * ``sonar.max_range_m`` / H metres (row 0 nearest the sonar);
  echoes beyond ``sonar.max_range_m`` are dropped;
* value: with ``sonar.use_intensities`` the echo intensity / ``intensity_scale`` clipped to
  [0, 1] (several range bins falling in one row: their maximum); without, 1 at the range
  of the strongest echo of the beam (``RangeImageBeam``) or at the measured range
  (``LaserScan``) and 0 elsewhere.

A beam fills the bins from the previous beam's bearing (exclusive) to its own (inclusive)
when the step is at most ``max_fill_rad`` (so a 1.8 deg step leaves no empty columns in a
1.6 deg-per-column ring); a larger jump only writes its own column.

``cartesian=True`` renders the same ring as a top-down fan instead: the sonar at the image
centre, x to the right = bearing 0, bearing increasing counter-clockwise, ``sonar.max_range_m`` at
the half-width (pixels outside the disc are 0).

:meth:`SonarRaster.image3` gives the 3-channel float tensor for the CNN (the grey image
replicated), so both modalities share the backbone and its ImageNet normalisation.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from common.messages import LaserScan, RangeImageBeam

__all__ = ["SonarRaster", "warm_up_kernels"]

TWO_PI = 2.0 * math.pi


@numba.njit(cache=True)
def _intensity_profile(data: np.ndarray, max_range: float, rmax: float, scale: np.float32,
                       prof: np.ndarray) -> None:  # pragma: no cover - compiled
    """Row maxima of one beam's intensities (``prof``, float32, zeroed by the caller): bin ``i``
    of ``n`` centred at ``(i + 0.5) * max_range / n`` m, value ``clip(data[i] / scale, 0, 1)``
    in float32; bins outside ``[0, rmax)`` dropped.  The same float32 / float64 operations, in
    the same order, as the array expression it replaces, so the raster is bit for bit the same."""
    n = data.size
    height = prof.size
    step = max_range / n
    for i in range(n):
        centre = (i + 0.5) * step
        if centre < 0.0 or centre >= rmax:
            continue
        row = min(int(centre / rmax * height), height - 1)
        v = np.float32(data[i]) / scale
        v = min(max(v, np.float32(0.0)), np.float32(1.0))
        if v > prof[row]:
            prof[row] = v


@numba.njit(cache=True)
def _column(angle: float, width: int) -> int:  # pragma: no cover - compiled
    a = angle % TWO_PI
    return min(int(a / TWO_PI * width), width - 1)


@numba.njit(cache=True)
def _scan_into_ring(ranges: np.ndarray, inten: np.ndarray, angle_min: float, angle_increment: float,
                    range_min: float, range_max: float, rmax: float, scale: float, use_intensities: bool,
                    max_fill_rad: float, last_angle: float, polar: np.ndarray, filled: np.ndarray,
                    angles: np.ndarray) -> None:  # pragma: no cover - compiled
    """A multi-bearing scan written bearing by bearing into the ring, as :meth:`SonarRaster._write`
    does one profile at a time (``last_angle`` NaN: none yet): each bearing's columns (those
    since the previous bearing, within ``max_fill_rad``) get its profile -- zero but at the
    row of its range, which holds its intensity / ``scale`` clipped to [0, 1] (1 without
    intensities).  ``angles`` receives the bearings.  The same float64 operations as the
    per-bearing code, so the ring is bit for bit the same."""
    height, width = polar.shape
    with_values = use_intensities and inten.size > 0
    for i in range(ranges.size):
        angle = angle_min + i * angle_increment
        angles[i] = angle
        r = ranges[i]
        row = -1
        if np.isfinite(r) and range_min <= r <= range_max and 0.0 <= r < rmax:
            row = min(int(r / rmax * height), height - 1)
        value = 1.0
        if with_values:  # clipped as np.clip does (a NaN stays NaN)
            value = inten[i] / scale
            if value < 0.0:
                value = 0.0
            elif value > 1.0:
                value = 1.0
        col = _column(angle, width)
        first, count, sign = col, 1, 1
        if not np.isnan(last_angle):
            step = (angle - last_angle + math.pi) % TWO_PI - math.pi
            if abs(step) <= max_fill_rad:
                prev = _column(last_angle, width)
                n = (col - prev) % width if step >= 0 else (prev - col) % width
                if n > 0:
                    sign = 1 if step >= 0 else -1
                    first, count = (prev + sign) % width, n
        for k in range(count):
            c = (first + sign * k) % width
            polar[:, c] = 0.0
            if row >= 0:
                polar[row, c] = value
            filled[c] = True
        last_angle = angle


def warm_up_kernels() -> None:
    """Compile (or load from numba's cache) the beam kernel for the int32 beams of the bus."""
    _intensity_profile(np.zeros(2, np.int32), 1.0, 1.0, np.float32(1.0), np.zeros(2, np.float32))
    one = np.ones(1)
    _scan_into_ring(one, one, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, True, 1.0, math.nan, np.zeros((2, 2), np.float32),
                    np.zeros(2, np.bool_), np.zeros(1))


class SonarRaster:
    """Ring of the latest beam per bearing bin, rendered as a polar (or Cartesian) image."""

    def __init__(self, width: int = 224, height: int = 224, rmax: float = 30.0,
                 use_intensities: bool = True, intensity_scale: float = 255.0,
                 max_fill_rad: float = math.radians(10.0), cartesian: bool = False):
        if width < 1 or height < 1:
            raise ValueError(f"sonar raster size must be positive, got {width}x{height}")
        if rmax <= 0:
            raise ValueError(f"encoder.sonar.max_range_m must be > 0 m, got {rmax}")
        if intensity_scale <= 0:
            raise ValueError(f"intensity_scale must be > 0, got {intensity_scale}")
        self.width = int(width)
        self.height = int(height)
        self.rmax = float(rmax)
        self.use_intensities = bool(use_intensities)
        self.intensity_scale = float(intensity_scale)
        self.max_fill_rad = float(max_fill_rad)
        self.cartesian = bool(cartesian)
        self.polar = np.zeros((self.height, self.width), dtype=np.float32)
        self.filled = np.zeros(self.width, dtype=bool)
        self.last_angle: float | None = None
        self.last_stamp: int | None = None
        self.beams = 0
        self._cart_lut: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget every beam (e.g. after a sonar dropout)."""
        self.polar[:] = 0.0
        self.filled[:] = False
        self.last_angle = None
        self.beams = 0

    @property
    def has_data(self) -> bool:
        return bool(self.filled.any())

    # ------------------------------------------------------------------ geometry
    def column(self, angle_rad: float) -> int:
        """Column of bearing ``angle_rad`` (radians, any turn)."""
        a = float(angle_rad) % TWO_PI
        return min(int(a / TWO_PI * self.width), self.width - 1)

    def row(self, range_m: float) -> int:
        """Row of range ``range_m`` (metres); -1 when outside [0, rmax)."""
        if not (0.0 <= range_m < self.rmax):
            return -1
        return min(int(range_m / self.rmax * self.height), self.height - 1)

    def _columns_for(self, angle: float) -> np.ndarray:
        col = self.column(angle)
        if self.last_angle is None:
            return np.array([col])
        step = (angle - self.last_angle + math.pi) % TWO_PI - math.pi  # signed, in [-pi, pi)
        if abs(step) > self.max_fill_rad:
            return np.array([col])
        prev = self.column(self.last_angle)
        n = (col - prev) % self.width if step >= 0 else (prev - col) % self.width
        if n == 0:
            return np.array([col])
        sign = 1 if step >= 0 else -1
        return (prev + sign * np.arange(1, n + 1)) % self.width

    def _profile_from_bins(self, values: np.ndarray, bin_range: np.ndarray) -> np.ndarray:
        prof = np.zeros(self.height, dtype=np.float32)
        ok = (bin_range >= 0) & (bin_range < self.rmax)
        if not ok.any():
            return prof
        rows = np.minimum((bin_range[ok] / self.rmax * self.height).astype(np.int64), self.height - 1)
        np.maximum.at(prof, rows, values[ok].astype(np.float32))
        return prof

    # ------------------------------------------------------------------ input
    def add_beam(self, msg: RangeImageBeam) -> None:
        """Write one MSIS beam (``beam_data``: ``nbins`` intensities over ``max_range`` m)."""
        data = np.asarray(msg.beam_data).reshape(-1)
        if msg.nbins != data.size:
            raise ValueError(f"RangeImageBeam seq {msg.header.seq}: nbins={msg.nbins} but beam_data has "
                             f"{data.size} values")
        if not math.isfinite(msg.angle_rad):
            raise ValueError(f"RangeImageBeam seq {msg.header.seq}: angle_rad is {msg.angle_rad}")
        prof = np.zeros(self.height, dtype=np.float32)
        if data.size and msg.max_range > 0:
            if self.use_intensities:
                _intensity_profile(data, float(msg.max_range), self.rmax, np.float32(self.intensity_scale), prof)
            elif data.max() > 0:
                centres = (np.arange(data.size) + 0.5) * (float(msg.max_range) / data.size)
                strongest = int(np.argmax(data))
                r = self.row(float(centres[strongest]))
                if r >= 0:
                    prof[r] = 1.0
        self._write(msg.angle_rad, prof, msg.header.stamp)

    def add_scan(self, msg: LaserScan) -> list[float]:
        """Write a LaserScan; returns the bearings (rad) written.

        Two forms: a *beam profile* (``angle_min == angle_max``, one bearing: ``ranges[i]`` are
        the range bins and ``intensities[i]`` their echoes -- the ``sonar_*_ros`` topics of the
        Girona dataset and the simulator), or a standard scan (one return per bearing
        ``angle_min + i * angle_increment``).
        """
        ranges = np.asarray(msg.ranges, dtype=np.float64).reshape(-1)
        inten = np.asarray(msg.intensities, dtype=np.float64).reshape(-1)
        if inten.size not in (0, ranges.size):
            raise ValueError(f"LaserScan seq {msg.header.seq}: {ranges.size} ranges but {inten.size} intensities")
        single_bearing = msg.angle_max == msg.angle_min or msg.angle_increment == 0.0
        if single_bearing:
            prof = np.zeros(self.height, dtype=np.float32)
            valid = np.isfinite(ranges) & (ranges >= msg.range_min) & (ranges <= msg.range_max)
            if self.use_intensities and inten.size:
                vals = np.clip(np.where(valid, inten, 0.0) / self.intensity_scale, 0.0, 1.0)
                prof = self._profile_from_bins(vals, np.where(valid, ranges, -1.0))
            elif inten.size and valid.any() and np.max(np.where(valid, inten, 0.0)) > 0:
                r = self.row(float(ranges[int(np.argmax(np.where(valid, inten, -np.inf)))]))
                if r >= 0:
                    prof[r] = 1.0
            elif not inten.size and valid.any():
                r = self.row(float(ranges[valid][0]))
                if r >= 0:
                    prof[r] = 1.0
            self._write(msg.angle_min, prof, msg.header.stamp)
            return [float(msg.angle_min)]
        if not ranges.size:
            return []
        angles = np.empty(ranges.size)
        _scan_into_ring(ranges, inten, float(msg.angle_min), float(msg.angle_increment), float(msg.range_min),
                        float(msg.range_max), self.rmax, self.intensity_scale, self.use_intensities,
                        self.max_fill_rad, math.nan if self.last_angle is None else self.last_angle,
                        self.polar, self.filled, angles)
        self.last_angle = float(angles[-1])
        self.last_stamp = int(msg.header.stamp)
        self.beams += ranges.size
        return angles.tolist()

    def _write(self, angle: float, profile: np.ndarray, stamp: int) -> None:
        cols = self._columns_for(angle)
        self.polar[:, cols] = profile[:, None]
        self.filled[cols] = True
        self.last_angle = float(angle)
        self.last_stamp = int(stamp)
        self.beams += 1

    # ------------------------------------------------------------------ output
    def _lut(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._cart_lut is None:
            h, w = self.height, self.width
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
            dx = (xx + 0.5 - w / 2.0) / (w / 2.0) * self.rmax
            dy = (h / 2.0 - (yy + 0.5)) / (h / 2.0) * self.rmax  # up = +y
            rng = np.hypot(dx, dy)
            ang = np.arctan2(dy, dx) % TWO_PI
            inside = rng < self.rmax
            rows = np.minimum((rng / self.rmax * self.height).astype(np.int64), self.height - 1)
            cols = np.minimum((ang / TWO_PI * self.width).astype(np.int64), self.width - 1)
            self._cart_lut = (rows, cols, inside)
        return self._cart_lut

    def image(self) -> np.ndarray:
        """The current raster, float32 (H, W) in [0, 1]."""
        if not self.cartesian:
            return self.polar.copy()
        rows, cols, inside = self._lut()
        return np.where(inside, self.polar[np.clip(rows, 0, self.height - 1), cols], 0.0).astype(np.float32)

    def image3(self) -> np.ndarray:
        """The raster as an (H, W, 3) float32 image in [0, 1] for the CNN."""
        img = self.image()
        return np.repeat(img[:, :, None], 3, axis=2)
