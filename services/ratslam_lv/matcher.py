"""RatSLAM local view: low-resolution templates matched by shifted mean absolute difference.

The canonical RatSLAM front-end (dissertation Section 3.1, Table 3.1; OpenRatSLAM's
``LocalViewMatch``), written from the description, used as the baseline the dissertation
compares NeoSLAM with (Section 5.4.2):

1. **Template** (:meth:`LocalViewMatcher.make_template`): the frame is made grey (mean of the
   colour channels, scaled to [0, 1]), cropped to ``[image_crop_x_min, image_crop_x_max) x
   [image_crop_y_min, image_crop_y_max)`` (pixels from the top-left corner) and reduced to
   ``template_x_size x template_y_size`` by area averaging (every source pixel counts once).
2. **Patch normalisation** (``vt_patch_normalise`` = radius r > 0, local contrast): every
   template pixel becomes its z-score within the (2r+1)^2 window around it (clipped at the
   borders); the z-score is mapped to [0, 1] as ``0.5 + z / 6`` (+-3 sigma; ours: the
   dissertation leaves the range open) so thresholds keep the meaning of intensity differences.
3. **Global normalisation** (``vt_normalisation`` = N > 0, illumination): the template is
   scaled so that its mean is N, values clipped to [0, 1].
4. **Matching** (:meth:`LocalViewMatcher.match`): the template is compared with every stored
   one at every shift ``dx in [-vt_shift_match, vt_shift_match]``, ``dy in
   [-vt_shift_match_y, vt_shift_match_y]`` (step ``vt_step_match``) as the mean absolute
   difference over the overlapping pixels (shifts overlapping less than ``vt_min_overlap`` of
   the template are skipped).  The smallest difference over shifts and templates wins; below
   ``vt_match_threshold`` it is a match (the template's view-cell id), otherwise the template
   is stored as a new view cell with the next id (0, 1, 2, ...).

The comparison kernel is numba (``cache=True``) with OpenRatSLAM's early exit: a shift stops
summing as soon as its partial sum cannot beat the best difference found so far.

``rate`` (published as the ``LocalViewCell`` rate, in [0, 1]): ``1 - d / vt_match_threshold``
for a match with difference d (1: identical, -> 0 at the threshold); 1 for a new template
(it is compared with itself).  Deterministic: no randomness, no clock.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from services.ratslam_lv.config import RatSlamLvConfig

__all__ = ["LocalViewMatcher", "ViewMatch", "grey", "area_downsample", "patch_normalise"]


@dataclass(frozen=True)
class ViewMatch:
    """Result of one frame: the view-cell id, whether it was created now, the mean absolute
    difference to the best stored template (inf when none existed), the winning shift
    ``(dx, dy)`` in template pixels (current pixel (x, y) compared with stored pixel
    (x + dx, y + dy)) and the rate documented in the module docstring."""

    view_id: int
    is_new: bool
    difference: float
    shift: tuple[int, int]
    rate: float


def grey(image: np.ndarray, encoding: str = "rgb8") -> np.ndarray:
    """(H, W[, C]) image -> float32 grey in [0, 1] (channel mean; alpha ignored)."""
    a = np.asarray(image)
    scale = 65535.0 if encoding == "mono16" or a.dtype == np.uint16 else 255.0
    if a.ndim == 3:
        chans = a[..., :3] if a.shape[2] >= 3 else a
        g = chans.astype(np.float32).mean(axis=2)
    elif a.ndim == 2:
        g = a.astype(np.float32)
    else:
        raise ValueError(f"image must be (H, W) or (H, W, C), got shape {a.shape}")
    out: np.ndarray = g / np.float32(scale)
    return out


@nb.njit(cache=True)
def _area_downsample(src: np.ndarray, ty: int, tx: int) -> np.ndarray:
    h, w = src.shape
    out = np.zeros((ty, tx), np.float32)
    for i in range(ty):
        y0 = (i * h) // ty
        y1 = max(((i + 1) * h) // ty, y0 + 1)
        for j in range(tx):
            x0 = (j * w) // tx
            x1 = max(((j + 1) * w) // tx, x0 + 1)
            s = 0.0
            for y in range(y0, y1):
                for x in range(x0, x1):
                    s += src[y, x]
            out[i, j] = s / ((y1 - y0) * (x1 - x0))
    return out


def area_downsample(src: np.ndarray, ty: int, tx: int) -> np.ndarray:
    """Average of the source pixels falling in each of the ``ty x tx`` cells."""
    h, w = src.shape
    if ty > h or tx > w:
        raise ValueError(f"template {tx}x{ty} is larger than the cropped image {w}x{h}")
    return _area_downsample(np.ascontiguousarray(src, np.float32), ty, tx)


@nb.njit(cache=True)
def _patch_normalise(t: np.ndarray, r: int) -> np.ndarray:
    ty, tx = t.shape
    out = np.empty_like(t)
    for i in range(ty):
        for j in range(tx):
            s = 0.0
            s2 = 0.0
            n = 0
            for y in range(max(0, i - r), min(ty, i + r + 1)):
                for x in range(max(0, j - r), min(tx, j + r + 1)):
                    v = t[y, x]
                    s += v
                    s2 += v * v
                    n += 1
            mean = s / n
            var = s2 / n - mean * mean
            sd = np.sqrt(var) if var > 1e-12 else 0.0
            z = (t[i, j] - mean) / sd if sd > 0.0 else 0.0
            out[i, j] = min(max(0.5 + z / 6.0, 0.0), 1.0)
    return out


def patch_normalise(t: np.ndarray, radius: int) -> np.ndarray:
    """Local-contrast normalisation of a template (module docstring, step 2)."""
    return _patch_normalise(np.ascontiguousarray(t, np.float32), int(radius))


@nb.njit(cache=True)
def _best_match(cur: np.ndarray, store: np.ndarray, n: int, sx: int, sy: int, step: int,
                min_overlap: int) -> tuple[int, float, int, int]:
    """Smallest mean absolute difference between ``cur`` and ``store[:n]`` over the shifts."""
    ty, tx = cur.shape
    best_k, best_d, best_dx, best_dy = -1, np.inf, 0, 0
    for k in range(n):
        t = store[k]
        for dy in range(-sy, sy + 1, step):
            ys0 = max(0, -dy)
            ys1 = min(ty, ty - dy)
            if ys1 <= ys0:
                continue
            for dx in range(-sx, sx + 1, step):
                xs0 = max(0, -dx)
                xs1 = min(tx, tx - dx)
                if xs1 <= xs0:
                    continue
                cnt = (ys1 - ys0) * (xs1 - xs0)
                if cnt < min_overlap:
                    continue
                limit = best_d * cnt  # early exit: this shift cannot win any more
                s = 0.0
                for y in range(ys0, ys1):
                    for x in range(xs0, xs1):
                        s += abs(cur[y, x] - t[y + dy, x + dx])
                    if s >= limit:
                        break
                if s < limit:
                    d = s / cnt
                    if d < best_d:
                        best_k, best_d, best_dx, best_dy = k, d, dx, dy
    return best_k, best_d, best_dx, best_dy


class LocalViewMatcher:
    """Template store and matcher; one :meth:`step` per camera frame (see the module docstring)."""

    def __init__(self, cfg: RatSlamLvConfig):
        self.cfg = cfg
        self.shape = (cfg.template_y_size, cfg.template_x_size)
        self._store = np.zeros((64,) + self.shape, np.float32)
        self.count = 0
        overlap = cfg.vt_min_overlap * cfg.template_x_size * cfg.template_y_size
        self._min_overlap = int(np.ceil(overlap))

    def __len__(self) -> int:
        return self.count

    @property
    def templates(self) -> np.ndarray:
        """The stored templates, (n, template_y_size, template_x_size), read-only view."""
        v = self._store[:self.count]
        v.flags.writeable = False
        return v

    def make_template(self, image: np.ndarray, encoding: str = "rgb8") -> np.ndarray:
        """Grey, crop, downsample, patch- and global-normalise one frame (steps 1-3)."""
        cfg = self.cfg
        g = grey(image, encoding)
        h, w = g.shape
        x1 = w if cfg.image_crop_x_max is None else cfg.image_crop_x_max
        y1 = h if cfg.image_crop_y_max is None else cfg.image_crop_y_max
        if not (0 <= cfg.image_crop_x_min < x1 <= w and 0 <= cfg.image_crop_y_min < y1 <= h):
            raise ValueError(f"ratslam_lv crop x [{cfg.image_crop_x_min}, {x1}) y [{cfg.image_crop_y_min}, {y1}) "
                             f"does not fit the {w}x{h} image")
        t = area_downsample(g[cfg.image_crop_y_min:y1, cfg.image_crop_x_min:x1], *self.shape)
        if cfg.vt_patch_normalise > 0:
            t = patch_normalise(t, cfg.vt_patch_normalise)
        if cfg.vt_normalisation > 0:
            m = float(t.mean())
            if m > 0:
                t = np.clip(t * np.float32(cfg.vt_normalisation / m), 0.0, 1.0).astype(np.float32)
        return t

    def compare(self, template: np.ndarray) -> tuple[int, float, tuple[int, int]]:
        """Best stored template for ``template``: (index or -1, mean absolute difference, (dx, dy))."""
        cfg = self.cfg
        if template.shape != self.shape:
            raise ValueError(f"template shape {template.shape} differs from {self.shape}")
        k, d, dx, dy = _best_match(np.ascontiguousarray(template, np.float32), self._store, self.count,
                                   cfg.vt_shift_match, cfg.vt_shift_match_y, cfg.vt_step_match, self._min_overlap)
        return int(k), float(d), (int(dx), int(dy))

    def add(self, template: np.ndarray) -> int:
        """Store ``template`` as a new view cell; returns its id."""
        if self.count == len(self._store):
            grown = np.zeros((2 * len(self._store),) + self.shape, np.float32)
            grown[:self.count] = self._store[:self.count]
            self._store = grown
        self._store[self.count] = template
        self.count += 1
        return self.count - 1

    def match(self, template: np.ndarray) -> ViewMatch:
        """Match a template against the store, adding it when nothing is below the threshold."""
        k, d, shift = self.compare(template)
        thr = self.cfg.vt_match_threshold
        if k >= 0 and d < thr:
            return ViewMatch(k, False, d, shift, float(min(max(1.0 - d / thr, 0.0), 1.0)))
        return ViewMatch(self.add(template), True, d, (0, 0), 1.0)

    def step(self, image: np.ndarray, encoding: str = "rgb8") -> ViewMatch:
        """One camera frame -> view-cell id."""
        return self.match(self.make_template(image, encoding))
