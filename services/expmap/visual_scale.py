"""The odometry's scale, measured by the downward camera: what loop closures cannot see.

Why: a loop closure ties two visits of one place, and around a closed route a scale error of
the dead reckoning adds up to nothing, so neither relaxation (Eq. 4.20) nor a session link
can see it.  On the simulated missions the DVL reads 1-2 % long (its scale and its forward
bias), which is most of the map's error (``docs/DECISIONS.md``, "What limits the map").  The
sonar sweeps did not measure it without a bias of their own (same section).  A downward
camera over the floor does:

- between two consecutive frames the floor's texture shifts by ``d_px = f d / h`` pixels
  (pinhole over a locally flat floor; f = ``focal_px``, h = the camera's height over the
  floor = the DVL's altitude minus ``camera_height_m``, the camera's offset below the DVL);
- the shift comes from phase correlation of the two frames, each reduced to the means of
  ``downsample`` x ``downsample`` pixel blocks (1: full resolution), high-passed (a 13-px
  box mean removed), contrast-normalised (divided by the 25-px box mean of its magnitude, so
  the lamp's bright spot does not dominate; both boxes in full-resolution pixels, the nearest
  odd size at the reduced one) and Hann-windowed, refined to a tenth of a pixel by a parabola
  through the peak, and scaled back to full-resolution pixels;
- the pair's metric displacement ``|d_px| h / f`` is compared with the odometry's
  horizontal displacement between the same two stamps (interpolated):
  ``s = sum(d_camera) / sum(d_odometry)`` over the pairs whose ratio lies within
  ``inlier_band`` of the median ratio of every pair measured so far (re-estimated every 16
  pairs).  A frame pair that failed (turbidity, snow, a bare floor) gives a wild ratio and is
  left out; the rest average the per-pair noise away (+-8 % interquartile on the sim's
  floors: the floor under the camera is not where the DVL measured its altitude).
- :attr:`VisualScale.scale` is None until ``min_pairs`` inliers were seen.

The map multiplies its odometry edges' horizontal displacements by ``s``
(:meth:`services.expmap.graph.ExperienceMap.set_odometry_scale`); the depth channel is
absolute and keeps its own scale.  Only every ``pair_every``-th frame pair is measured
(the estimate needs hundreds, not every one), by default on 2 x 2 block means: ~1 ms per
measured frame instead of ~3 ms at full resolution (``docs/DECISIONS.md``, "The odometry's
scale from the camera").  Everything is deterministic: the inputs' stamps decide every choice.
"""
from __future__ import annotations

import math
from collections import deque
from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from scipy.ndimage import uniform_filter

from services.expmap.config import VisualScaleConfig

_REESTIMATE_EVERY = 16      # pairs between two estimates (each costs a median over every pair)
_HIGHPASS_PX = 13           # box of the high-pass (full-resolution pixels)
_CONTRAST_PX = 25           # box of the contrast normalisation (full-resolution pixels)

__all__ = ["VisualScale", "image_shift"]


@lru_cache(maxsize=4)
def _window(h: int, w: int) -> np.ndarray:
    """The 2-D Hann window of an h x w frame (float32, read-only: shared between calls)."""
    win = np.outer(np.hanning(h), np.hanning(w)).astype(np.float32)
    win.setflags(write=False)
    return win


def _odd(px: float) -> int:
    """The odd box size nearest ``px`` (at least 1)."""
    n = max(int(round(px)), 1)
    return n if n % 2 else n + 1


def _reduce(image: np.ndarray, factor: int) -> np.ndarray:
    """The frame as float32, reduced to the means of ``factor`` x ``factor`` pixel blocks (rows
    and columns beyond the last whole block dropped)."""
    a = np.asarray(image)
    if factor == 1:
        return np.asarray(a, np.float32)
    h, w = a.shape[0] // factor * factor, a.shape[1] // factor * factor
    full = a[:h, :w].astype(np.float32)
    out: np.ndarray = full[::factor, ::factor].copy()   # strided sums: ~10x faster than a reshaped sum
    for i in range(factor):
        for j in range(factor):
            if i or j:
                out += full[i::factor, j::factor]
    out *= np.float32(1.0 / factor ** 2)
    return out


def _prepare(image: np.ndarray, factor: int = 1) -> np.ndarray:
    """Spectrum of the reduced, high-passed, contrast-normalised, Hann-windowed frame."""
    img = _reduce(image, factor)
    hp = img - uniform_filter(img, _odd(_HIGHPASS_PX / factor))
    hp /= uniform_filter(np.abs(hp), _odd(_CONTRAST_PX / factor)) + 1e-3
    hp *= _window(*img.shape)
    out: np.ndarray = sfft.rfft2(hp)
    return out


def _parabola(a: float, b: float, c: float) -> float:
    d = a - 2.0 * b + c
    return 0.0 if d == 0.0 else 0.5 * (a - c) / d


def _shift(spec_a: np.ndarray, spec_b: np.ndarray, shape: tuple[int, int]) -> tuple[float, float]:
    """(rows, columns) the content of frame b moved to reach frame a (phase correlation)."""
    r = spec_a * np.conj(spec_b)
    r /= np.abs(r) + 1e-9
    c = sfft.irfft2(r, s=shape)
    h, w = shape
    i, j = np.unravel_index(int(np.argmax(c)), c.shape)
    y = i + _parabola(c[(i - 1) % h, j], c[i, j], c[(i + 1) % h, j])
    x = j + _parabola(c[i, (j - 1) % w], c[i, j], c[i, (j + 1) % w])
    return (y - h if y > h / 2 else y), (x - w if x > w / 2 else x)


def image_shift(first: np.ndarray, second: np.ndarray, downsample: int = 1) -> tuple[float, float]:
    """Pixels (rows, columns) the floor's texture moved from ``first`` to ``second`` (2-D arrays),
    measured on ``downsample`` x ``downsample`` block means."""
    a, b = np.asarray(first), np.asarray(second)
    if a.ndim != 2 or a.shape != b.shape:
        raise ValueError(f"image_shift needs two 2-D frames of one shape, got {a.shape} and {b.shape}")
    f = int(downsample)
    if f < 1 or a.shape[0] < 2 * f or a.shape[1] < 2 * f:
        raise ValueError(f"image_shift: downsample {downsample} does not fit frames of {a.shape}")
    dy, dx = _shift(_prepare(b, f), _prepare(a, f), (a.shape[0] // f, a.shape[1] // f))
    return dy * f, dx * f


class VisualScale:
    """Running estimate of the odometry's horizontal scale from camera frame pairs (module doc)."""

    def __init__(self, cfg: VisualScaleConfig):
        self.cfg = cfg
        self._frames = 0
        self._prev: tuple[int, np.ndarray] | None = None      # (stamp, spectrum) of the last prepared frame
        self._altitude: tuple[int, float] | None = None
        self._odom: deque[tuple[int, float, float]] = deque(maxlen=256)
        self._pending: deque[tuple[int, int, float]] = deque()  # (t0, t1, camera metres) awaiting odometry
        self._camera: list[float] = []                          # every measured pair: camera metres
        self._odometry: list[float] = []                        # ... and the odometry's metres
        self._estimated_at = 0
        self.sum_camera = 0.0
        self.sum_odometry = 0.0
        self.counts = {"pairs": 0, "inliers": 0, "outliers": 0, "no_altitude": 0, "slow": 0, "no_odometry": 0,
                       "resized": 0}

    @property
    def scale(self) -> float | None:
        """Camera over odometry, or None before ``min_pairs`` inliers."""
        if self.counts["inliers"] < self.cfg.min_pairs or self.sum_odometry <= 0.0:
            return None
        return self.sum_camera / self.sum_odometry

    def add_altitude(self, stamp: int, altitude_m: float) -> None:
        """The DVL's altitude over the floor (m) at ``stamp`` (ns); non-finite or <= 0: none."""
        self._altitude = (int(stamp), float(altitude_m)) if math.isfinite(altitude_m) and altitude_m > 0 else None

    def add_odometry(self, stamp: int, x: float, y: float) -> None:
        """The odometry's horizontal position (m) at ``stamp`` (ns); settles the pairs it covers."""
        self._odom.append((int(stamp), float(x), float(y)))
        while self._pending and self._pending[0][1] <= stamp:
            self._settle(*self._pending.popleft())

    def add_frame(self, stamp: int, image: np.ndarray) -> None:
        """A camera frame (2-D, any numeric type); measures the pair it closes when its turn comes."""
        cfg = self.cfg
        k = self._frames
        self._frames += 1
        every = cfg.pair_every
        if every > 1 and k % every not in (0, every - 1):
            self._prev = None
            return
        f = cfg.downsample
        spec = _prepare(image, f)
        prev, self._prev = self._prev, (int(stamp), spec)
        if prev is not None and prev[1].shape != spec.shape:     # the camera's resolution changed
            self.counts["resized"] += 1
            return
        if prev is None or (every > 1 and k % every != 0):
            return
        alt = self._altitude
        if alt is None or stamp - alt[0] > cfg.altitude_max_age_s * 1e9 or alt[1] - cfg.camera_height_m < cfg.min_clearance_m:
            self.counts["no_altitude"] += 1
            return
        dy, dx = _shift(spec, prev[1], (int(image.shape[0]) // f, int(image.shape[1]) // f))
        metres = math.hypot(dy, dx) * f * (alt[1] - cfg.camera_height_m) / cfg.focal_px
        self._pending.append((prev[0], int(stamp), metres))

    def _odom_at(self, t: int) -> np.ndarray | None:
        od = self._odom
        if not od or t < od[0][0] or t > od[-1][0]:
            return None
        ts = np.fromiter((o[0] for o in od), np.int64, len(od))
        k = int(np.searchsorted(ts, t))
        if ts[k] == t:
            return np.array(od[k][1:])
        (t0, x0, y0), (t1, x1, y1) = od[k - 1], od[k]
        f = (t - t0) / (t1 - t0)
        return np.array([x0 + f * (x1 - x0), y0 + f * (y1 - y0)])

    def _settle(self, t0: int, t1: int, camera_m: float) -> None:
        a, b = self._odom_at(t0), self._odom_at(t1)
        if a is None or b is None:
            self.counts["no_odometry"] += 1
            return
        odo = float(np.linalg.norm(b - a))
        if odo < self.cfg.min_step_m:
            self.counts["slow"] += 1
            return
        self.counts["pairs"] += 1
        self._camera.append(camera_m)
        self._odometry.append(odo)
        if len(self._camera) - self._estimated_at >= _REESTIMATE_EVERY:
            self._estimate()

    def _estimate(self) -> None:
        """Sum ratio over the pairs within ``inlier_band`` of the median pair ratio."""
        cam, odo = np.asarray(self._camera), np.asarray(self._odometry)
        ratio = cam / odo
        sel = np.abs(ratio / float(np.median(ratio)) - 1.0) <= self.cfg.inlier_band
        self.sum_camera, self.sum_odometry = float(cam[sel].sum()), float(odo[sel].sum())
        self.counts["inliers"] = int(sel.sum())
        self.counts["outliers"] = int(sel.size - sel.sum())
        self._estimated_at = len(cam)
