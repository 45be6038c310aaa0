"""Numba kernels: the downward camera image and the two scanning sonars.

Camera (pinhole, intrinsics of the real Cala Viuda camera): for every pixel the ray is
intersected with the floor (two fixed-point iterations on the floor relief), the albedo is
sampled bilinearly from the texture tiles (blended towards the 4 cm level with range x
turbidity: forward-scatter blur), lit by the vehicle's lamp (a Gaussian spot cone around
an axis tilted forward, inverse-square fall-off, Lambert incidence) and attenuated by
water over the two-way path with per-channel coefficients (red dies first: blue-green
cast), plus backscatter (veiling light) inside the lamp cone.  Marine snow particles are
splatted as Gaussian blobs, then gamma, sensor noise and 8-bit quantisation.

Sonars: one beam per call-row.  The Micron-like MSIS scans the horizontal plane (vertical
beam width 35 deg: the floor shows as a diffuse return beyond altitude / sin 17.5 deg);
the SeaKing-like profiler scans the vertical across-track plane (narrow beam: floor,
ceiling and walls).  The echo is a near-field ring-down, a Gaussian return at the first
surface with an incidence factor, an acoustic shadow behind it, multiplicative speckle
(exponential intensity, i.e. Rayleigh amplitude) and additive noise.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from missions.sim.world import L1_FACTOR, TEX_RES, TILE

__all__ = ["render_linear", "splat_particles", "finish_image", "micron_beams", "seaking_beams"]

_RES1 = TEX_RES * L1_FACTOR
_T1 = TILE // L1_FACTOR


@nb.njit(cache=True, inline="always")
def _grid(g: np.ndarray, x0: float, y0: float, res: float, x: float, y: float) -> float:
    ny, nx = g.shape
    fi = min(max((x - x0) / res, 0.0), ny - 1.001)
    fj = min(max((y - y0) / res, 0.0), nx - 1.001)
    i = int(fi)
    j = int(fj)
    ti = fi - i
    tj = fj - j
    out: float = (g[i, j] * (1 - ti) * (1 - tj) + g[i + 1, j] * ti * (1 - tj) + g[i, j + 1] * (1 - ti) * tj
                  + g[i + 1, j + 1] * ti * tj)
    return out


@nb.njit(cache=True, inline="always")
def _free(free: np.ndarray, x0: float, y0: float, res: float, x: float, y: float) -> bool:
    ny, nx = free.shape
    i = int((x - x0) / res + 0.5)
    j = int((y - y0) / res + 0.5)
    if i < 0 or j < 0 or i >= ny or j >= nx:
        return False
    out: bool = free[i, j]
    return out


@nb.njit(cache=True, inline="always")
def _tex3(tiles: np.ndarray, index: np.ndarray, tile: int, fi: float, fj: float) -> tuple[float, float, float]:
    """Bilinear RGB texel lookup at continuous texel coordinates (fi, fj), 0..1."""
    gi = int(np.floor(fi))
    gj = int(np.floor(fj))
    ti = fi - gi
    tj = fj - gj
    a = gi // tile
    b = gj // tile
    ny, nx = index.shape
    if a < 0 or b < 0 or a >= ny or b >= nx:
        return 0.3, 0.3, 0.3
    k = index[a, b]
    if k < 0:
        return 0.3, 0.3, 0.3
    li = gi - a * tile + 1
    lj = gj - b * tile + 1
    w00 = (1 - ti) * (1 - tj) * (1.0 / 255.0)
    w10 = ti * (1 - tj) * (1.0 / 255.0)
    w01 = (1 - ti) * tj * (1.0 / 255.0)
    w11 = ti * tj * (1.0 / 255.0)
    r = tiles[k, li, lj, 0] * w00 + tiles[k, li + 1, lj, 0] * w10 + tiles[k, li, lj + 1, 0] * w01 + tiles[k, li + 1, lj + 1, 0] * w11
    g = tiles[k, li, lj, 1] * w00 + tiles[k, li + 1, lj, 1] * w10 + tiles[k, li, lj + 1, 1] * w01 + tiles[k, li + 1, lj + 1, 1] * w11
    bl = tiles[k, li, lj, 2] * w00 + tiles[k, li + 1, lj, 2] * w10 + tiles[k, li, lj + 1, 2] * w01 + tiles[k, li + 1, lj + 1, 2] * w11
    return r, g, bl


STEP = 4  # pixels between the nodes where the ray geometry is evaluated exactly


@nb.njit(cache=True, nogil=True)
def render_linear(out: np.ndarray, r_wc: np.ndarray, cam: np.ndarray, fx: float, fy: float, u0: float, v0: float,
                  tiles0: np.ndarray, tiles1: np.ndarray, index: np.ndarray, tex_x0: float, tex_y0: float,
                  floor: np.ndarray, gx0: float, gy0: float, gres: float, lamp_axis: np.ndarray,
                  lamp_sigma: float, lut_direct: np.ndarray, lut_scatter: np.ndarray, back: np.ndarray,
                  turbidity: float, blur_k: float, gain: float) -> None:
    """Linear radiance image (H, W, 3) float32 of the floor seen from camera pose (r_wc, cam).

    ``lut_direct[k, c] = exp(-2 att_c r_k)`` and ``lut_scatter[k, c] = 1 - exp(-att_c r_k)``
    tabulate the water terms at r_k = k mm.  The ray geometry (floor point, blur weight,
    lamp/attenuation factor, backscatter) is exact on nodes every :data:`STEP` pixels and
    bilinear in between (it varies smoothly: ~2 cm of floor per node cell); the texture
    is sampled at every pixel."""
    h, w, _ = out.shape
    z0 = _grid(floor, gx0, gy0, gres, cam[0], cam[1])
    inv_s2 = 1.0 / (lamp_sigma * lamp_sigma)
    nlut = lut_direct.shape[0]
    nv = (h - 1) // STEP + 2
    nu = (w - 1) // STEP + 2
    node = np.empty((nv, nu, 9))
    for a in range(nv):
        for b in range(nu):
            xc = (b * STEP - u0) / fx
            yc = (a * STEP - v0) / fy
            dx = r_wc[0, 0] * xc + r_wc[0, 1] * yc + r_wc[0, 2]
            dy = r_wc[1, 0] * xc + r_wc[1, 1] * yc + r_wc[1, 2]
            dz = r_wc[2, 0] * xc + r_wc[2, 1] * yc + r_wc[2, 2]
            norm = np.sqrt(dx * dx + dy * dy + dz * dz)
            cl = min(max((dx * lamp_axis[0] + dy * lamp_axis[1] + dz * lamp_axis[2]) / norm, -1.0), 1.0)
            spot = np.exp(-(1.0 - cl) * inv_s2)  # Gaussian in the angle: 1 - cos(a) ~ a^2 / 2
            if dz < 0.05:  # looking (nearly) horizontally: backscatter only
                node[a, b, 0] = cam[0]
                node[a, b, 1] = cam[1]
                node[a, b, 2] = 0.0
                for c in range(3):
                    node[a, b, 3 + c] = 0.0
                    node[a, b, 6 + c] = gain * back[c] * spot * lut_scatter[nlut - 1, c] * turbidity
                continue
            t = (z0 - cam[2]) / dz
            for _ in range(2):
                zf = _grid(floor, gx0, gy0, gres, cam[0] + t * dx, cam[1] + t * dy)
                t = max((zf - cam[2]) / dz, 0.05)
            r = t * norm
            irr = spot * (dz / norm) / (r * r)
            kr = min(int(r * 1000.0), nlut - 1)
            node[a, b, 0] = cam[0] + t * dx
            node[a, b, 1] = cam[1] + t * dy
            node[a, b, 2] = min(max(blur_k * turbidity * (r - 0.5), 0.0), 1.0)
            for c in range(3):
                node[a, b, 3 + c] = gain * irr * lut_direct[kr, c]
                node[a, b, 6 + c] = gain * back[c] * spot * lut_scatter[kr, c] * turbidity
    inv = 1.0 / STEP
    for v in range(h):
        a = v // STEP
        fa = (v - a * STEP) * inv
        for u in range(w):
            b = u // STEP
            fb = (u - b * STEP) * inv
            w00 = (1 - fa) * (1 - fb)
            w01 = (1 - fa) * fb
            w10 = fa * (1 - fb)
            w11 = fa * fb
            px = node[a, b, 0] * w00 + node[a, b + 1, 0] * w01 + node[a + 1, b, 0] * w10 + node[a + 1, b + 1, 0] * w11
            py = node[a, b, 1] * w00 + node[a, b + 1, 1] * w01 + node[a + 1, b, 1] * w10 + node[a + 1, b + 1, 1] * w11
            wb = node[a, b, 2] * w00 + node[a, b + 1, 2] * w01 + node[a + 1, b, 2] * w10 + node[a + 1, b + 1, 2] * w11
            r0, g0, b0 = _tex3(tiles0, index, TILE, (px - tex_x0) / TEX_RES, (py - tex_y0) / TEX_RES)
            r1, g1, b1 = _tex3(tiles1, index, _T1, (px - tex_x0 - 1.5 * TEX_RES) / _RES1,
                               (py - tex_y0 - 1.5 * TEX_RES) / _RES1)
            alb0 = r0 + (r1 - r0) * wb
            alb1 = g0 + (g1 - g0) * wb
            alb2 = b0 + (b1 - b0) * wb
            for c in range(3):
                fac = (node[a, b, 3 + c] * w00 + node[a, b + 1, 3 + c] * w01 + node[a + 1, b, 3 + c] * w10
                       + node[a + 1, b + 1, 3 + c] * w11)
                add = (node[a, b, 6 + c] * w00 + node[a, b + 1, 6 + c] * w01 + node[a + 1, b, 6 + c] * w10
                       + node[a + 1, b + 1, 6 + c] * w11)
                alb = alb0 if c == 0 else (alb1 if c == 1 else alb2)
                out[v, u, c] = alb * fac + add


@nb.njit(cache=True)
def splat_particles(img: np.ndarray, parts: np.ndarray) -> None:
    """Add marine-snow blobs: rows (u, v, radius px, brightness r, g, b) in linear units."""
    h, w, _ = img.shape
    for k in range(parts.shape[0]):
        pu = parts[k, 0]
        pv = parts[k, 1]
        rad = parts[k, 2]
        ext = int(3.0 * rad) + 1
        u_lo = max(int(pu) - ext, 0)
        u_hi = min(int(pu) + ext, w - 1)
        v_lo = max(int(pv) - ext, 0)
        v_hi = min(int(pv) + ext, h - 1)
        inv = 1.0 / (2.0 * rad * rad)
        for v in range(v_lo, v_hi + 1):
            for u in range(u_lo, u_hi + 1):
                g = np.exp(-((u - pu) ** 2 + (v - pv) ** 2) * inv)
                for c in range(3):
                    img[v, u, c] += parts[k, 3 + c] * g


@nb.njit(cache=True, nogil=True)
def finish_image(img: np.ndarray, out: np.ndarray, noise_sigma: float, seed: int, gamma_lut: np.ndarray) -> None:
    """Gamma 1/2.2 (``gamma_lut[k] = 255 (k / (n - 1)) ** (1 / 2.2)``), additive sensor noise
    (sigma in 8-bit units, deterministic from ``seed``), quantisation to uint8."""
    h, w, _ = img.shape
    nl = gamma_lut.shape[0] - 1
    for v in nb.prange(h):
        for u in range(w):
            for c in range(3):
                x = gamma_lut[min(max(int(img[v, u, c] * nl + 0.5), 0), nl)]
                # triangular noise from two hashed uniforms (variance matches sigma)
                hsh = (((v * 384 + u) * 3 + c) * 2654435761 + seed * 40503) & 0xFFFFFFFF
                hsh = ((hsh ^ (hsh >> 15)) * 2246822519) & 0xFFFFFFFF
                hsh = hsh ^ (hsh >> 13)
                a = (hsh & 0xFFFF) / 65536.0
                b = ((hsh >> 16) & 0xFFFF) / 65536.0
                x += (a + b - 1.0) * noise_sigma * 2.449
                out[v, u, c] = np.uint8(min(max(x + 0.5, 0.0), 255.0))


@nb.njit(cache=True, inline="always")
def _wall_normal_cos(free: np.ndarray, gx0: float, gy0: float, gres: float, x: float, y: float,
                     bx: float, by: float) -> float:
    h = 0.25
    nx = (1.0 if _free(free, gx0, gy0, gres, x + h, y) else 0.0) - (1.0 if _free(free, gx0, gy0, gres, x - h, y) else 0.0)
    ny = (1.0 if _free(free, gx0, gy0, gres, x, y + h) else 0.0) - (1.0 if _free(free, gx0, gy0, gres, x, y - h) else 0.0)
    n = np.sqrt(nx * nx + ny * ny)
    if n == 0.0:
        return 0.7
    out: float = abs(bx * nx + by * ny) / n
    return out


@nb.njit(cache=True)
def _echo(out: np.ndarray, row: int, dr: float, r_hit: float, amp: float, speckle: np.ndarray, noise: np.ndarray,
          floor_r: float, floor_amp: float) -> None:
    nb_ = out.shape[1]
    for b in range(nb_):
        r = (b + 0.5) * dr
        val = 55.0 * np.exp(-r / 0.35)  # transducer ring-down
        if floor_r > 0.0 and r > floor_r:
            val += floor_amp * (1.0 - np.exp(-(r - floor_r) / 0.6)) * np.exp(-(r - floor_r) / 5.0)
        if r_hit > 0.0:
            if r < r_hit + 0.6:
                val += amp * np.exp(-0.5 * ((r - r_hit) / 0.18) ** 2)
            else:
                val = val * 0.15 + 0.35 * amp * np.exp(-(r - r_hit) / 0.7)
        val = val * speckle[row, b] + 3.0 + noise[row, b]
        out[row, b] = np.int32(min(max(val, 0.0), 191.0))


@nb.njit(cache=True, nogil=True)
def micron_beams(out: np.ndarray, pos: np.ndarray, beam_yaw: np.ndarray, altitude: np.ndarray, max_range: float,
                 free: np.ndarray, gx0: float, gy0: float, gres: float, speckle: np.ndarray,
                 noise: np.ndarray) -> None:
    """Horizontal MSIS beams: out[k, :] echo of beam k from pos[k] along world yaw beam_yaw[k]."""
    n, nbins = out.shape
    dr = max_range / nbins
    for k in nb.prange(n):
        bx = np.cos(beam_yaw[k])
        by = np.sin(beam_yaw[k])
        r_hit = -1.0
        step = dr * 0.5
        r = step
        while r < max_range:
            if not _free(free, gx0, gy0, gres, pos[k, 0] + r * bx, pos[k, 1] + r * by):
                r_hit = r
                break
            r += step
        amp = 0.0
        if r_hit > 0:
            amp = 150.0 * (0.35 + 0.65 * _wall_normal_cos(free, gx0, gy0, gres, pos[k, 0] + r_hit * bx,
                                                          pos[k, 1] + r_hit * by, bx, by))
        floor_r = altitude[k] / np.sin(np.deg2rad(17.5))
        _echo(out, k, dr, r_hit, amp, speckle, noise, floor_r, 22.0)


@nb.njit(cache=True, nogil=True)
def seaking_beams(out: np.ndarray, pos: np.ndarray, dirs: np.ndarray, max_range: float, free: np.ndarray,
                  floor: np.ndarray, ceiling: np.ndarray, gx0: float, gy0: float, gres: float,
                  speckle: np.ndarray, noise: np.ndarray) -> None:
    """Vertical profiler beams: out[k, :] echo from pos[k] along the world unit vector dirs[k]."""
    n, nbins = out.shape
    dr = max_range / nbins
    for k in nb.prange(n):
        dx = dirs[k, 0]
        dy = dirs[k, 1]
        dz = dirs[k, 2]
        r_hit = -1.0
        cosinc = 0.7
        step = dr * 0.5
        r = step
        while r < max_range:
            x = pos[k, 0] + r * dx
            y = pos[k, 1] + r * dy
            z = pos[k, 2] + r * dz
            if not _free(free, gx0, gy0, gres, x, y):
                r_hit = r
                hn = np.sqrt(dx * dx + dy * dy)
                cosinc = _wall_normal_cos(free, gx0, gy0, gres, x, y, dx / max(hn, 1e-6), dy / max(hn, 1e-6)) * hn
                break
            if z >= _grid(floor, gx0, gy0, gres, x, y) or z <= _grid(ceiling, gx0, gy0, gres, x, y):
                r_hit = r
                cosinc = abs(dz)
                break
            r += step
        amp = 170.0 * (0.35 + 0.65 * cosinc) if r_hit > 0 else 0.0
        _echo(out, k, dr, r_hit, amp, speckle, noise, -1.0, 0.0)
