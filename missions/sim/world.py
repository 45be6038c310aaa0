"""The synthetic cave world: tunnel network, floor/ceiling relief, walls and floor texture.

Frames: world NED (x north, y east, z down, metres; z is depth below the surface).

Geometry is defined by a *route*: the tunnel centre lines of two loop areas, "Ellipse"
(area 1, an elliptical ring tunnel) and "Cave 2" (area 2, a rounded-rectangle ring with a
chamber), joined by a long transition tunnel.  A 2D grid (``grid_res`` = 5 cm) holds for
every cell whether it is free water (inside a tunnel, irregular walls), the floor depth
and the ceiling depth (arched); depth, height and width are smooth functions of position.
The floor albedo is a sparse set of 2.56 m texture tiles at 1 cm/texel (only tiles near
free space exist, generated lazily where the camera looks: :meth:`World.ensure_tiles`)
plus a 4 cm/texel level used for turbidity blur; procedural multi-scale texture (sand grain, ripples, rock patches with
cracks) is modulated by a "richness" field so long stretches are near-uniform sand, and
distinctive features (rocks, traffic cones, a diver guideline) are painted in.
Everything is a deterministic function of the seed.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numba as nb
import numpy as np

__all__ = ["World", "build_world", "TILE", "TEX_RES"]

TILE = 256          # texels per tile side (level 0)
TEX_RES = 0.01      # metres per texel (level 0)
L1_FACTOR = 4       # level 1 = 4x coarser
GRID_RES = 0.05     # metres per geometry cell


# --------------------------------------------------------------------------- noise


@nb.njit(cache=True, inline="always")
def _hash2(ix: int, iy: int, seed: int) -> float:
    """Deterministic pseudo-random value in [0, 1) of an integer lattice point."""
    h = (ix * 374761393 + iy * 668265263 + seed * 2147483647) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF) / 16777216.0


@nb.njit(cache=True, inline="always")
def _value_noise(x: float, y: float, seed: int) -> float:
    """Smooth value noise in [0, 1) with unit lattice spacing."""
    fx = np.floor(x)
    fy = np.floor(y)
    ix = int(fx)
    iy = int(fy)
    tx = x - fx
    ty = y - fy
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    a = _hash2(ix, iy, seed)
    b = _hash2(ix + 1, iy, seed)
    c = _hash2(ix, iy + 1, seed)
    d = _hash2(ix + 1, iy + 1, seed)
    out: float = (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * ty
    return out


@nb.njit(cache=True)
def _fbm(x: float, y: float, base_freq: float, octaves: int, seed: int) -> float:
    """Fractal sum of value noise, roughly in [0, 1)."""
    s = 0.0
    amp = 0.5
    norm = 0.0
    f = base_freq
    for o in range(octaves):
        s += amp * _value_noise(x * f, y * f, seed + 17 * o)
        norm += amp
        amp *= 0.5
        f *= 2.0
    return s / norm


@nb.njit(cache=True)
def _albedo(x: float, y: float, seed: int, fine: bool) -> tuple[float, float, float]:
    """Procedural floor albedo (linear RGB, 0..1) at world (x, y).

    ``fine=False`` drops the octaves finer than ~4 cm (the pre-filtered blur level)."""
    rich = _fbm(x, y, 0.05, 3, seed + 1)              # 20 m scale: texture richness
    rich = min(max((rich - 0.42) * 3.0, 0.0), 1.0)    # long stretches with rich ~ 0
    rockiness = _fbm(x, y, 0.35, 4, seed + 2)          # ~3 m patches
    rock = min(max((rockiness - 0.5) * 5.0, 0.0), 1.0) * (0.3 + 0.7 * rich)
    # sand: grain + ripples (only in ripple fields) whose direction wanders slowly
    ang = 6.0 * _fbm(x, y, 0.03, 2, seed + 3)
    u = x * np.cos(ang) + y * np.sin(ang)
    ripple = 0.5 + 0.5 * np.sin(u * 2.0 * np.pi / 0.14 + 4.0 * _value_noise(x * 0.8, y * 0.8, seed + 4))
    rfield = min(max((_fbm(x, y, 0.12, 2, seed + 10) - 0.45) * 4.0, 0.0), 1.0)
    medium = _fbm(x, y, 1.5, 3, seed + 5)
    if fine:
        grain = _fbm(x, y, 25.0, 3, seed + 6)
        peb = _value_noise(x * 14.0, y * 14.0, seed + 11)
    else:
        grain = 0.5
        peb = 0.5
    pebble = min(max((peb - 0.78) * 8.0, 0.0), 1.0) * rich
    sand = (0.60 + (0.14 + 0.14 * rich) * (medium - 0.5) + (0.03 + 0.09 * rich) * rfield * (ripple - 0.5)
            + 0.16 * (grain - 0.5) - 0.30 * pebble)
    # rock: darker, blotchy, with cracks (ridged noise)
    n = _fbm(x, y, 4.0, 3, seed + 7)
    crack = 1.0 - abs(2.0 * _fbm(x, y, 2.5, 4 if fine else 2, seed + 8) - 1.0)
    crack = crack ** 12
    rockv = 0.42 + 0.40 * (n - 0.5) + (0.12 * (grain - 0.5) if fine else 0.0) - 0.25 * crack
    v = sand * (1.0 - rock) + rockv * rock
    # slight hue variation: sand yellowish, rock grey-brown, organic dark spots
    hue = _fbm(x, y, 0.2, 2, seed + 9) - 0.5
    r = v * (1.05 + 0.15 * hue - 0.05 * rock)
    g = v * (1.0 + 0.05 * hue)
    b = v * (0.80 - 0.10 * hue + 0.10 * rock)
    return min(max(r, 0.0), 1.0), min(max(g, 0.0), 1.0), min(max(b, 0.0), 1.0)


@nb.njit(cache=True, parallel=True)
def _fill_tiles(tiles: np.ndarray, origins: np.ndarray, which: np.ndarray, res: float, seed: int, fine: bool) -> None:
    """tiles[k, i, j, c] for k in ``which``: albedo at origin_k + ((i - 1) * res, (j - 1) * res)
    (1-texel apron)."""
    n, h, w, _ = tiles.shape
    for q in nb.prange(which.shape[0]):
        k = which[q]
        ox = origins[k, 0]
        oy = origins[k, 1]
        for i in range(h):
            for j in range(w):
                r, g, b = _albedo(ox + (i - 1) * res, oy + (j - 1) * res, seed, fine)
                tiles[k, i, j, 0] = np.uint8(r * 255.0 + 0.5)
                tiles[k, i, j, 1] = np.uint8(g * 255.0 + 0.5)
                tiles[k, i, j, 2] = np.uint8(b * 255.0 + 0.5)


# --------------------------------------------------------------------------- painting


@nb.njit(cache=True)
def _paint_disc(tiles: np.ndarray, index: np.ndarray, only: np.ndarray, x0: float, y0: float, res: float,
                tile: int, cx: float, cy: float, radius: float, col: np.ndarray, kind: int, seed: int) -> None:
    """Blend a feature into the tiles flagged in ``only``.  kind 0: rock (shaded dome), 1: cone
    (orange with a white band, seen from above), 2: guideline dot (flat colour)."""
    n_ty, n_tx = index.shape
    h = tiles.shape[1]
    i0 = int(np.floor((cx - radius - x0) / res)) - 1
    i1 = int(np.floor((cx + radius - x0) / res)) + 1
    j0 = int(np.floor((cy - radius - y0) / res)) - 1
    j1 = int(np.floor((cy + radius - y0) / res)) + 1
    for gi in range(i0, i1 + 1):
        for gj in range(j0, j1 + 1):
            px = x0 + gi * res
            py = y0 + gj * res
            dx = px - cx
            dy = py - cy
            rr = np.sqrt(dx * dx + dy * dy) / radius
            if rr > 1.0:
                continue
            # every tile (with apron) that holds texel (gi, gj)
            ty = gi // tile
            tx = gj // tile
            for dty in range(-1, 2):
                for dtx in range(-1, 2):
                    a = ty + dty
                    b = tx + dtx
                    if a < 0 or b < 0 or a >= n_ty or b >= n_tx:
                        continue
                    k = index[a, b]
                    if k < 0 or not only[k]:
                        continue
                    li = gi - a * tile + 1
                    lj = gj - b * tile + 1
                    if li < 0 or lj < 0 or li >= h or lj >= h:
                        continue
                    if kind == 0:
                        shade = 0.55 + 0.45 * (-(dx + dy) / (radius * 1.4142)) * np.sqrt(max(1.0 - rr * rr, 0.0))
                        shade *= 0.85 + 0.3 * _value_noise(px * 30.0, py * 30.0, seed)
                        alpha = min(1.0, (1.0 - rr) * 6.0)
                        for c in range(3):
                            v = col[c] * shade
                            tiles[k, li, lj, c] = np.uint8(min(max(tiles[k, li, lj, c] * (1 - alpha) + 255.0 * v * alpha, 0.0), 255.0))
                    elif kind == 1:
                        band = 0.45 < rr < 0.65
                        for c in range(3):
                            v = 0.95 if band else col[c] * (0.75 + 0.25 * (1.0 - rr))
                            if rr < 0.12:
                                v = 0.08  # the cone's hollow tip
                            tiles[k, li, lj, c] = np.uint8(min(max(255.0 * v, 0.0), 255.0))
                    else:
                        alpha = min(1.0, (1.0 - rr) * 3.0)
                        for c in range(3):
                            tiles[k, li, lj, c] = np.uint8(tiles[k, li, lj, c] * (1 - alpha) + 255.0 * col[c] * alpha)


@nb.njit(cache=True)
def _paint_walls(dist: np.ndarray, seg: np.ndarray, cx: np.ndarray, cy: np.ndarray,
                 width: np.ndarray, gx0: float, gy0: float, res: float) -> None:
    """Rasterise the tunnels: for every centre-line point, a disc of its half-width; keep the
    nearest centre-line index per cell."""
    ny, nx = dist.shape
    for k in range(cx.shape[0]):
        w = width[k]
        i0 = max(int((cx[k] - w - gx0) / res), 0)
        i1 = min(int((cx[k] + w - gx0) / res) + 1, ny - 1)
        j0 = max(int((cy[k] - w - gy0) / res), 0)
        j1 = min(int((cy[k] + w - gy0) / res) + 1, nx - 1)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                dx = gx0 + i * res - cx[k]
                dy = gy0 + j * res - cy[k]
                d = np.sqrt(dx * dx + dy * dy)
                if d < dist[i, j]:
                    dist[i, j] = d
                    seg[i, j] = k


@nb.njit(cache=True, parallel=True)
def _relief(free: np.ndarray, floor: np.ndarray, ceil: np.ndarray, dist: np.ndarray, seg: np.ndarray,
            width: np.ndarray, base_depth: np.ndarray, height: np.ndarray, gx0: float, gy0: float,
            res: float, seed: int) -> None:
    ny, nx = dist.shape
    for i in nb.prange(ny):
        for j in range(nx):
            x = gx0 + i * res
            y = gy0 + j * res
            k = seg[i, j]
            if k < 0:
                free[i, j] = False
                floor[i, j] = 30.0
                ceil[i, j] = 0.0
                continue
            w = width[k] * (0.85 + 0.3 * _fbm(x, y, 0.6, 3, seed + 31))
            q = dist[i, j] / w
            free[i, j] = q < 1.0
            qq = min(q, 1.0)
            floor[i, j] = base_depth[i, j] + 0.35 * (1.0 - qq * qq) + 0.5 * (_fbm(x, y, 0.25, 3, seed + 32) - 0.5)
            ceil[i, j] = floor[i, j] - height[i, j] * np.sqrt(max(1.0 - qq * qq, 0.0)) - 0.05


@nb.njit(cache=True)
def _paint_line(tiles: np.ndarray, index: np.ndarray, only: np.ndarray, x0: float, y0: float, res: float, tile: int,
                pts: np.ndarray, radius: float, col: np.ndarray, seed: int) -> None:
    for k in range(pts.shape[0]):
        _paint_disc(tiles, index, only, x0, y0, res, tile, pts[k, 0], pts[k, 1], radius, col, 2, seed)


_ROCK = np.array([0.42, 0.38, 0.33])
_CONE = np.array([0.95, 0.35, 0.05])
_LINE = np.array([0.95, 0.9, 0.3])


# --------------------------------------------------------------------------- world


@dataclass
class World:
    """Cave geometry and texture (see module docstring)."""

    seed: int
    grid_x0: float
    grid_y0: float
    grid_res: float
    free: np.ndarray          # (ny, nx) bool: water inside the cave
    floor: np.ndarray         # (ny, nx) float32: floor depth (m, down +)
    ceiling: np.ndarray       # (ny, nx) float32: ceiling depth (m)
    tex_x0: float
    tex_y0: float
    tile_index: np.ndarray    # (nty, ntx) int32: tile number or -1
    tiles0: np.ndarray        # (n, TILE+2, TILE+2, 3) uint8, 1 cm texels with apron
    tiles1: np.ndarray        # (n, TILE/4+2, TILE/4+2, 3) uint8, 4 cm texels with apron
    route: list[np.ndarray]   # centre lines: [area 1 loop, transition, area 2 loop, transition back]
    route_names: list[str]
    features: list[dict[str, Any]] = field(default_factory=list)
    tile_origins: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (n, 2) world x, y of texel (0, 0)
    tile_ready: np.ndarray = field(default_factory=lambda: np.zeros(0, np.bool_))  # tiles generated so far
    guideline: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (m, 2) guideline points, 5 mm apart

    def ensure_tiles(self, x0: float, x1: float, y0: float, y1: float) -> int:
        """Generate the texture tiles overlapping [x0, x1] x [y0, y1] (m) that do not exist yet.

        A tile's content depends only on its position and the seed (procedural texture, then
        rocks and cones, then the guideline, then the 4 cm level), so the order in which
        tiles are generated never changes the result.  Returns the number generated."""
        tile_m = TILE * TEX_RES
        nty, ntx = self.tile_index.shape
        a0 = max(int(np.floor((x0 - self.tex_x0) / tile_m)), 0)
        a1 = min(int(np.floor((x1 - self.tex_x0) / tile_m)), nty - 1)
        b0 = max(int(np.floor((y0 - self.tex_y0) / tile_m)), 0)
        b1 = min(int(np.floor((y1 - self.tex_y0) / tile_m)), ntx - 1)
        if a1 < a0 or b1 < b0:
            return 0
        ids = self.tile_index[a0:a1 + 1, b0:b1 + 1].ravel()
        ids = np.unique(ids[ids >= 0])
        ids = ids[~self.tile_ready[ids]].astype(np.int64)
        if not len(ids):
            return 0
        _fill_tiles(self.tiles0, self.tile_origins, ids, TEX_RES, self.seed, True)
        only = np.zeros(len(self.tile_ready), np.bool_)
        only[ids] = True
        lo = self.tile_origins[ids].min(axis=0) - 0.5
        hi = self.tile_origins[ids].max(axis=0) + tile_m + 0.5
        for f in self.features:
            if lo[0] <= f["x"] <= hi[0] and lo[1] <= f["y"] <= hi[1]:
                _paint_disc(self.tiles0, self.tile_index, only, self.tex_x0, self.tex_y0, TEX_RES, TILE, f["x"],
                            f["y"], f["r"], _ROCK if f["kind"] == "rock" else _CONE, 0 if f["kind"] == "rock" else 1,
                            self.seed)
        g = self.guideline
        sel = (g[:, 0] >= lo[0]) & (g[:, 0] <= hi[0]) & (g[:, 1] >= lo[1]) & (g[:, 1] <= hi[1])
        _paint_line(self.tiles0, self.tile_index, only, self.tex_x0, self.tex_y0, TEX_RES, TILE, g[sel], 0.006,
                    _LINE, self.seed)
        _downsample_tiles(self.tiles0, self.tiles1, ids, L1_FACTOR)
        self.tile_ready[ids] = True
        return len(ids)

    def ensure_all_tiles(self) -> int:
        """Generate every tile (e.g. before timing the renderer)."""
        tile_m = TILE * TEX_RES
        nty, ntx = self.tile_index.shape
        return self.ensure_tiles(self.tex_x0, self.tex_x0 + nty * tile_m, self.tex_y0, self.tex_y0 + ntx * tile_m)

    def floor_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return _bilinear_grid(self.floor, self.grid_x0, self.grid_y0, self.grid_res,
                              np.atleast_1d(np.asarray(x, np.float64)), np.atleast_1d(np.asarray(y, np.float64)))


@nb.njit(cache=True)
def _bilinear_grid(g: np.ndarray, x0: float, y0: float, res: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    out = np.empty(x.shape[0])
    ny, nx = g.shape
    for k in range(x.shape[0]):
        fi = min(max((x[k] - x0) / res, 0.0), ny - 1.001)
        fj = min(max((y[k] - y0) / res, 0.0), nx - 1.001)
        i = int(fi)
        j = int(fj)
        ti = fi - i
        tj = fj - j
        out[k] = (g[i, j] * (1 - ti) * (1 - tj) + g[i + 1, j] * ti * (1 - tj) + g[i, j + 1] * (1 - ti) * tj
                  + g[i + 1, j + 1] * ti * tj)
    return out


def _resample(points: np.ndarray, step: float) -> np.ndarray:
    d = np.r_[0.0, np.cumsum(np.hypot(*np.diff(points, axis=0).T))]
    s = np.arange(0.0, d[-1], step)
    out: np.ndarray = np.c_[np.interp(s, d, points[:, 0]), np.interp(s, d, points[:, 1])]
    return out


def _route(rng: np.random.Generator) -> tuple[list[np.ndarray], list[str]]:
    """Centre lines (x north, y east) sampled every 0.1 m."""
    # area 1 "Ellipse": ring tunnel, start/end at its east-most point, counter-clockwise
    th = np.linspace(0.0, 2 * np.pi, 2000)
    a1 = np.c_[7.0 * np.sin(th), 14.0 * np.cos(th)]
    a1 = a1 + rng.normal(0, 0.15, 2)  # small seed-dependent offset
    # transition: wiggly corridor from (0, 14) east to area 2's west point
    t = np.linspace(0.0, 1.0, 800)
    tr = np.c_[3.0 * np.sin(2.5 * np.pi * t) + 6.0 * t, 14.0 + 40.0 * t]
    # area 2 "Cave 2": rounded rectangle (superellipse, n=4) centred at (6, 70)
    ph = np.linspace(np.pi, 3 * np.pi, 3000)
    c, s = np.cos(ph), np.sin(ph)
    sx = np.sign(s) * np.abs(s) ** 0.5
    sy = np.sign(c) * np.abs(c) ** 0.5
    a2 = np.c_[6.0 + 9.0 * sx, 70.0 + 16.0 * sy]
    a2 = np.r_[a2[:, :] - a2[0] + tr[-1]]
    back = tr[::-1].copy()
    pieces = [_resample(p, 0.1) for p in (a1, tr, a2, back)]
    return pieces, ["area1_ellipse", "transition_1_2", "area2_cave2", "transition_2_1"]


def _features(route: list[np.ndarray], names: list[str], rng: np.random.Generator) -> list[dict[str, Any]]:
    """Rocks (drawn from ``rng``, ~one every 12 m) and traffic cones along the centre lines."""
    features: list[dict[str, Any]] = []
    for piece, name in zip(route[:3], names[:3]):
        m = len(piece)
        for _ in range(int(m * 0.1 / 12)):  # ~one rock every 12 m
            k = int(rng.integers(0, m))
            tang = piece[min(k + 1, m - 1)] - piece[max(k - 1, 0)]
            nrm = np.array([-tang[1], tang[0]]) / (np.hypot(*tang) + 1e-9)
            p = piece[k] + nrm * rng.uniform(-1.2, 1.2)
            features.append({"kind": "rock", "x": float(p[0]), "y": float(p[1]), "r": float(rng.uniform(0.15, 0.45)),
                             "area": name})
    for name, piece, fr in (("area1_ellipse", route[0], (0.2, 0.7)), ("transition_1_2", route[1], (0.5,)),
                            ("area2_cave2", route[2], (0.15, 0.6, 0.85))):
        for f in fr:
            k = int(f * len(piece))
            tang = piece[min(k + 1, len(piece) - 1)] - piece[max(k - 1, 0)]
            nrm = np.array([-tang[1], tang[0]]) / (np.hypot(*tang) + 1e-9)
            p = piece[k] + nrm * 0.6
            features.append({"kind": "cone", "x": float(p[0]), "y": float(p[1]), "r": 0.2, "area": name})
    return features


def _guideline(route: list[np.ndarray]) -> np.ndarray:
    """A thin yellow line 0.4 m left of the centre line, through every tunnel."""
    gl = []
    for piece in route[:3]:
        tang = np.gradient(piece, axis=0)
        nrm = np.c_[-tang[:, 1], tang[:, 0]] / (np.hypot(tang[:, 0], tang[:, 1])[:, None] + 1e-9)
        gl.append(_resample(piece + 0.4 * nrm, 0.005))
    return np.concatenate(gl)


@lru_cache(maxsize=2)
def build_world(seed: int) -> World:
    """The cave for ``seed`` (deterministic; cached per process, treat as read-only); takes
    ~2-8 s depending on the load (the texture tiles dominate)."""
    rng = np.random.default_rng([seed, 101])
    route, names = _route(rng)
    pts = np.concatenate(route[:3])
    # per centre-line point: half-width, floor base depth, height (m)
    # half-width, floor base depth and height are smooth functions of *position* (not of the
    # arc length), so they are continuous where route pieces meet (junctions, loop closures)
    px, py = pts[:, 0], pts[:, 1]
    ph = rng.uniform(0, 2 * np.pi, 4)
    w = 2.0 + 0.5 * np.sin(px / 5.1 + py / 7.3 + ph[0]) + 0.25 * np.sin(px / 2.3 - py / 1.9 + ph[1])
    # a chamber in area 2 (its north side) and a wide spot in area 1
    c2 = route[2][int(0.25 * len(route[2]))]
    c1 = route[0][int(0.6 * len(route[0]))]
    ch = np.exp(-(np.hypot(px - c2[0], py - c2[1]) / 6.0) ** 2)
    w += 3.0 * ch + 1.2 * np.exp(-(np.hypot(px - c1[0], py - c1[1]) / 4.0) ** 2)
    margin = 7.0
    gx0 = float(np.floor(pts[:, 0].min() - margin))
    gy0 = float(np.floor(pts[:, 1].min() - margin))
    ny = int(np.ceil((pts[:, 0].max() + margin - gx0) / GRID_RES))
    nx = int(np.ceil((pts[:, 1].max() + margin - gy0) / GRID_RES))
    dist = np.full((ny, nx), np.inf)
    seg = np.full((ny, nx), -1, np.int64)
    _paint_walls(dist, seg, pts[:, 0].copy(), pts[:, 1].copy(), w * 1.2 + 0.5, gx0, gy0,
                 GRID_RES)
    free = np.zeros((ny, nx), np.bool_)
    floor = np.zeros((ny, nx), np.float32)
    ceil = np.zeros((ny, nx), np.float32)
    # floor base depth and tunnel height: smooth functions of the cell position
    gx = (gx0 + np.arange(ny) * GRID_RES)[:, None]
    gy = (gy0 + np.arange(nx) * GRID_RES)[None, :]
    base = 14.3 + 1.2 * np.sin(gx / 23.0 + ph[2]) * np.cos(gy / 31.0) + 0.4 * np.sin(gy / 11.0 + ph[3])
    chamber = np.exp(-(np.hypot(gx - c2[0], gy - c2[1]) / 6.0) ** 2)
    height = 3.0 + 1.5 * np.sin(gx / 9.0 + gy / 13.0 + 2.0) ** 2 + 2.0 * chamber
    _relief(free, floor, ceil, dist, seg, w, np.ascontiguousarray(base), np.ascontiguousarray(height), gx0, gy0,
            GRID_RES, seed)

    # texture tiles wherever the floor can be seen (free cells + a 1.5 m margin)
    tile_m = TILE * TEX_RES
    cells = int(round(tile_m / GRID_RES))
    nty = -(-ny // cells)
    ntx = -(-nx // cells)
    pad = np.zeros((nty * cells, ntx * cells), np.bool_)
    near = (seg >= 0) & (dist < np.where(seg >= 0, w[np.maximum(seg, 0)] * 1.3 + 1.0, 0.0))
    pad[:ny, :nx] = near
    need = pad.reshape(nty, cells, ntx, cells).any(axis=(1, 3))
    index = np.full((nty, ntx), -1, np.int32)
    index[need] = np.arange(int(need.sum()), dtype=np.int32)
    ty, tx = np.nonzero(need)
    origins = np.c_[gx0 + ty * tile_m, gy0 + tx * tile_m].astype(np.float64)
    tiles0 = np.zeros((len(origins), TILE + 2, TILE + 2, 3), np.uint8)
    t1 = TILE // L1_FACTOR
    tiles1 = np.zeros((len(origins), t1 + 2, t1 + 2, 3), np.uint8)

    # distinctive features along the centre line: rocks and traffic cones, plus a guideline
    features = _features(route, names, rng)
    guideline = _guideline(route)
    return World(seed=seed, grid_x0=gx0, grid_y0=gy0, grid_res=GRID_RES, free=free, floor=floor, ceiling=ceil,
                 tex_x0=gx0, tex_y0=gy0, tile_index=index, tiles0=tiles0, tiles1=tiles1, route=route,
                 route_names=names, features=features, tile_origins=origins,
                 tile_ready=np.zeros(len(origins), np.bool_), guideline=guideline)


@nb.njit(cache=True, parallel=True)
def _downsample_tiles(t0: np.ndarray, t1: np.ndarray, which: np.ndarray, f: int) -> None:
    """Level 1 = box mean of f x f level-0 texels (apron by clamping), tiles in ``which``."""
    n, h1, w1, _ = t1.shape
    h0 = t0.shape[1]
    for q in nb.prange(which.shape[0]):
        k = which[q]
        for i in range(h1):
            for j in range(w1):
                for c in range(3):
                    acc = 0.0
                    for a in range(f):
                        for b in range(f):
                            ii = min(max((i - 1) * f + a + 1, 0), h0 - 1)
                            jj = min(max((j - 1) * f + b + 1, 0), h0 - 1)
                            acc += t0[k, ii, jj, c]
                    t1[k, i, j, c] = np.uint8(acc / (f * f) + 0.5)
