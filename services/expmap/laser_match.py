"""Registration of 2D range scans: the measured pose between two experiences.

A planar range scan (a laser's ``LaserScan``, or one horizontal sweep of an imaging sonar
turned into points) is registered against a *reference*: the points of one or more
experiences, expressed in one experience's frame.  The method is correlative scan matching
(Olson, ICRA 2009): the reference becomes a likelihood field ``L(c) = exp(-d(c)^2 / 2 s^2)``
over a grid (d = distance from the cell centre to the nearest reference point), and a pose hypothesis (x, y, yaw) of the query is scored by the mean of
L over the query's transformed points (points off the grid score 0).  The search is
exhaustive over a window around a prior, coarse to fine:

1. coarse: a field with cell ``coarse_cell_m`` and sigma ``coarse_sigma_m`` over the whole
   window, yaw step ``coarse_yaw_step_deg``, the query thinned to one point per
   ``coarse_query_voxel_m`` square (0: all points);
2. fine: around each of the best ``refine_peaks`` coarse peaks (non-maximum suppressed), a
   field with cell ``fine_cell_m`` and sigma ``fine_sigma_m``, +- one coarse step in x, y and
   yaw at the fine steps;
3. the answer is the best fine pose, with its fine score (the fraction-like mean of L) and
   the *spread*: the std (m) along the principal axis of the coarse hypotheses whose score is
   within ``ambiguity_ratio`` of the best.  A corridor's walls constrain only across it: the
   spread along it is large, and the registration says nothing about that axis.  And the
   *second-peak ratio*: the best coarse score at translations more than ``second_peak_m``
   from the best one, over the best (repeated structure, e.g. doors every few metres, gives
   separate peaks of nearly equal score).

``prior_sigma_xy_m`` / ``prior_sigma_yaw_deg`` (> 0) multiply each score by a Gaussian of
the offset from the prior (the motion model of Olson's matcher): between consecutive
experiences, a flat score along a corridor then keeps the odometry's answer.

Everything is deterministic (fixed search order; ties go to the first hypothesis).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit

__all__ = ["LikelihoodField", "ScanMatch", "match_scan", "match_in_fields", "scan_points", "voxel_filter", "transform_points",
           "free_space_fraction"]


def scan_points(ranges: np.ndarray, angle_min: float, angle_increment: float, range_min: float,
                range_max: float) -> np.ndarray:
    """Points (k x 2, m, sensor frame: x forward, y left) of the returns in (range_min, range_max)."""
    r = np.asarray(ranges, np.float64)
    a = angle_min + angle_increment * np.arange(r.size)
    ok = np.isfinite(r) & (r > range_min) & (r < range_max)
    return np.stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])], axis=1)


def transform_points(pts: np.ndarray, pose: npt.ArrayLike) -> np.ndarray:
    """Points given in the frame of ``pose`` (x, y, yaw) expressed in its parent frame."""
    x, y, yaw = (float(v) for v in np.asarray(pose, np.float64)[:3])
    c, s = math.cos(yaw), math.sin(yaw)
    p = np.asarray(pts, np.float64).reshape(-1, 2)
    out = np.empty_like(p)
    out[:, 0] = x + c * p[:, 0] - s * p[:, 1]
    out[:, 1] = y + s * p[:, 0] + c * p[:, 1]
    return out


def voxel_filter(pts: np.ndarray, cell: float) -> np.ndarray:
    """One point per occupied ``cell`` x ``cell`` square (the first in input order)."""
    p = np.asarray(pts, np.float64).reshape(-1, 2)
    if p.shape[0] == 0 or cell <= 0:
        return p
    keys = np.floor(p / cell).astype(np.int64)
    _, first = np.unique(keys[:, 0] * 1_000_003 + keys[:, 1], return_index=True)
    out: np.ndarray = p[np.sort(first)]
    return out


class LikelihoodField:
    """Likelihood grid of a reference point set (see the module doc).

    ``L(c) = exp(-d^2 / 2 sigma^2)`` for cells within 3 sigma of a reference point (0 beyond),
    written point by point (numba), so the cost follows the points, not the grid's area."""

    def __init__(self, ref: np.ndarray, cell_m: float, sigma_m: float, margin_m: float):
        ref = np.asarray(ref, np.float64).reshape(-1, 2)
        if ref.shape[0] == 0:
            raise ValueError("likelihood field of an empty reference")
        self.cell = float(cell_m)
        lo = ref.min(axis=0) - margin_m
        hi = ref.max(axis=0) + margin_m
        self.origin = lo
        shape = np.maximum(np.ceil((hi - lo) / self.cell).astype(np.int64) + 1, 1)
        self.grid = np.zeros((int(shape[0]), int(shape[1])), np.float32)
        _splat(self.grid, lo[0], lo[1], self.cell, float(sigma_m), ref)

    def score(self, pts: np.ndarray, pose: npt.ArrayLike) -> float:
        """Mean likelihood of ``pts`` (query frame) placed at ``pose`` in the reference frame."""
        q = transform_points(pts, pose)
        return float(_mean_lookup(self.grid, self.origin[0], self.origin[1], self.cell, q))


@njit(cache=True)
def _splat(grid: np.ndarray, ox: float, oy: float, cell: float, sigma: float, ref: np.ndarray) -> None:
    nx, ny = grid.shape
    k = int(math.ceil(3.0 * sigma / cell))
    inv = 0.5 / (sigma * sigma)
    gx = np.empty(2 * k + 1)
    gy = np.empty(2 * k + 1)
    for p in range(ref.shape[0]):
        fi = (ref[p, 0] - ox) / cell
        fj = (ref[p, 1] - oy) / cell
        ci = int(math.floor(fi))
        cj = int(math.floor(fj))
        for a in range(2 * k + 1):      # the Gaussian is separable: exp(-dx^2 c) * exp(-dy^2 c)
            dx = (ci - k + a + 0.5 - fi) * cell
            dy = (cj - k + a + 0.5 - fj) * cell
            gx[a] = math.exp(-dx * dx * inv)
            gy[a] = math.exp(-dy * dy * inv)
        for i in range(max(0, ci - k), min(nx, ci + k + 1)):
            vx = gx[i - ci + k]
            for j in range(max(0, cj - k), min(ny, cj + k + 1)):
                v = vx * gy[j - cj + k]
                if v > grid[i, j]:
                    grid[i, j] = v


@njit(cache=True)
def _mean_lookup(grid: np.ndarray, ox: float, oy: float, cell: float, q: np.ndarray) -> float:
    nx, ny = grid.shape
    acc: float = 0.0
    for k in range(q.shape[0]):
        i = int(math.floor((q[k, 0] - ox) / cell))
        j = int(math.floor((q[k, 1] - oy) / cell))
        if 0 <= i < nx and 0 <= j < ny:
            acc += grid[i, j]
    n_q: int = max(q.shape[0], 1)
    return acc / n_q


@njit(cache=True)
def _search(grid: np.ndarray, ox: float, oy: float, cell: float, pts: np.ndarray, yaws: np.ndarray, cx: float,
            cy: float, w: int, px: float, py: float, pyaw: float, sxy: float, syaw: float) -> np.ndarray:
    """Scores (n_yaw, 2w+1, 2w+1) of the query at yaw yaws[a] and translation
    (cx + i*cell, cy + j*cell), i, j in -w..w, times the prior's Gaussian when sxy > 0."""
    nx, ny = grid.shape
    na = yaws.shape[0]
    n = pts.shape[0]
    out = np.zeros((na, 2 * w + 1, 2 * w + 1))
    ii = np.empty(n, np.int64)
    jj = np.empty(n, np.int64)
    for a in range(na):
        c = math.cos(yaws[a])
        s = math.sin(yaws[a])
        for k in range(n):
            ii[k] = int(math.floor((c * pts[k, 0] - s * pts[k, 1] + cx - ox) / cell))
            jj[k] = int(math.floor((s * pts[k, 0] + c * pts[k, 1] + cy - oy) / cell))
        # point by point, each point's (2w+1)^2 block of the grid added to the block of sums:
        # every sum still adds its points in order k = 0..n-1 (the same bits as summing each
        # translation over the points), and the grid is read row by row
        acc = np.zeros((2 * w + 1, 2 * w + 1))
        for k in range(n):
            i0 = max(ii[k] - w, 0)
            i1 = min(ii[k] + w + 1, nx)
            j0 = max(jj[k] - w, 0)
            j1 = min(jj[k] + w + 1, ny)
            for i in range(i0, i1):
                r = i - ii[k] + w
                for j in range(j0, j1):
                    acc[r, j - jj[k] + w] += grid[i, j]
        for di in range(-w, w + 1):
            for dj in range(-w, w + 1):
                v = acc[di + w, dj + w] / max(n, 1)
                if sxy > 0.0:
                    ex = cx + di * cell - px
                    ey = cy + dj * cell - py
                    ea = yaws[a] - pyaw
                    v *= math.exp(-0.5 * (ex * ex + ey * ey) / (sxy * sxy) - 0.5 * ea * ea / (syaw * syaw))
                out[a, di + w, dj + w] = v
    return out


@dataclass
class ScanMatch:
    """Result of :func:`match_scan`: the pose of the query in the reference frame."""

    pose: np.ndarray          # x m, y m, yaw rad
    score: float              # mean likelihood at the fine resolution (0..1), prior not applied
    spread_m: float           # std of the near-best coarse translations along their principal axis
    spread_yaw_deg: float     # std of their yaws
    n_points: int
    second_ratio: float = 0.0  # best coarse score farther than ``second_peak_m`` from the best / best


def _peaks(scores: np.ndarray, k: int, sep: int) -> list[tuple[int, int, int]]:
    """Up to k best cells of a (yaw, x, y) score volume, at least ``sep`` cells apart in x/y."""
    flat_scores = -scores.reshape(-1)
    m = min(max(50 * k, 200), flat_scores.size)
    # the first m of a stable sort, without sorting the whole volume: every cell scoring at
    # least the m-th best, in index order, then stably sorted by score
    kth = np.partition(flat_scores, m - 1)[m - 1]
    head = np.flatnonzero(flat_scores <= kth)
    order = head[np.argsort(flat_scores[head], kind="stable")]
    out: list[tuple[int, int, int]] = []
    for flat in order[:m]:
        a, i, j = np.unravel_index(int(flat), scores.shape)
        if all(abs(i - i2) > sep or abs(j - j2) > sep for _a, i2, j2 in out):
            out.append((int(a), int(i), int(j)))
            if len(out) >= k:
                break
    return out


def match_scan(ref: np.ndarray, query: np.ndarray, prior: npt.ArrayLike, *, window_xy_m: float, window_yaw_deg: float,
               coarse_cell_m: float = 0.1, coarse_sigma_m: float = 0.2, coarse_yaw_step_deg: float = 1.0,
               fine_cell_m: float = 0.025, fine_sigma_m: float = 0.05, fine_yaw_step_deg: float = 0.25,
               refine_peaks: int = 3, ambiguity_ratio: float = 0.95, second_peak_m: float = 0.5,
               prior_sigma_xy_m: float = 0.0, prior_sigma_yaw_deg: float = 0.0,
               coarse_query_voxel_m: float = 0.0) -> ScanMatch:
    """Register ``query`` (k x 2, its own frame) against ``ref`` (reference frame) near ``prior``
    (the query frame's pose in the reference frame); see the module doc."""
    ref = np.asarray(ref, np.float64).reshape(-1, 2)
    q = np.ascontiguousarray(np.asarray(query, np.float64).reshape(-1, 2))
    prior = np.asarray(prior, np.float64)
    if q.shape[0] == 0 or ref.shape[0] == 0:
        raise ValueError(f"scan registration needs points on both sides (reference {ref.shape[0]}, "
                         f"query {q.shape[0]})")
    # only the reference near where the query can land matters
    placed = transform_points(q, prior)
    reach = window_xy_m + 3.0 * max(coarse_sigma_m, fine_sigma_m) + float(np.max(np.hypot(q[:, 0], q[:, 1]))) * \
        math.sin(min(math.radians(window_yaw_deg), math.pi / 2)) + coarse_cell_m
    lo, hi = placed.min(axis=0) - reach, placed.max(axis=0) + reach
    ref = ref[np.all((ref >= lo) & (ref <= hi), axis=1)]
    if ref.shape[0] == 0:
        return ScanMatch(pose=prior.copy(), score=0.0, spread_m=math.inf, spread_yaw_deg=math.inf,
                         n_points=int(q.shape[0]), second_ratio=1.0)
    coarse = LikelihoodField(ref, coarse_cell_m, coarse_sigma_m, margin_m=3 * coarse_sigma_m)
    fine = LikelihoodField(ref, fine_cell_m, fine_sigma_m, margin_m=3 * fine_sigma_m)
    return match_in_fields(coarse, fine, q, prior, window_xy_m=window_xy_m, window_yaw_deg=window_yaw_deg,
                           coarse_yaw_step_deg=coarse_yaw_step_deg, fine_yaw_step_deg=fine_yaw_step_deg,
                           refine_peaks=refine_peaks, ambiguity_ratio=ambiguity_ratio, second_peak_m=second_peak_m,
                           prior_sigma_xy_m=prior_sigma_xy_m, prior_sigma_yaw_deg=prior_sigma_yaw_deg,
                           coarse_query_voxel_m=coarse_query_voxel_m)


def match_in_fields(coarse: LikelihoodField, fine: LikelihoodField, query: np.ndarray, prior: npt.ArrayLike, *,
                    window_xy_m: float, window_yaw_deg: float, coarse_yaw_step_deg: float = 1.0,
                    fine_yaw_step_deg: float = 0.25, refine_peaks: int = 3, ambiguity_ratio: float = 0.95,
                    second_peak_m: float = 0.5, prior_sigma_xy_m: float = 0.0, prior_sigma_yaw_deg: float = 0.0,
                    coarse_query_voxel_m: float = 0.0) -> ScanMatch:
    """:func:`match_scan`'s search (steps 1-3 of the module doc) in likelihood fields built beforehand,
    so that several queries against one reference build its fields once."""
    q = np.ascontiguousarray(np.asarray(query, np.float64).reshape(-1, 2))
    prior = np.asarray(prior, np.float64)
    coarse_cell_m = coarse.cell
    fine_cell_m = fine.cell
    sxy = float(prior_sigma_xy_m)
    syaw = math.radians(prior_sigma_yaw_deg) if prior_sigma_yaw_deg > 0 else 1.0
    w = max(1, int(math.ceil(window_xy_m / coarse_cell_m)))
    na = max(0, int(math.ceil(window_yaw_deg / coarse_yaw_step_deg)))
    yaws = prior[2] + np.radians(coarse_yaw_step_deg) * np.arange(-na, na + 1)
    qc = np.ascontiguousarray(voxel_filter(q, coarse_query_voxel_m)) if coarse_query_voxel_m > 0 else q
    sc = _search(coarse.grid, coarse.origin[0], coarse.origin[1], coarse.cell, qc, yaws, prior[0], prior[1], w,
                 prior[0], prior[1], prior[2], sxy, syaw)
    best = float(sc.max())
    near = np.argwhere(sc >= ambiguity_ratio * best)
    txy = (near[:, 1:] - w) * coarse_cell_m
    spread = 0.0
    if near.shape[0] > 1:
        spread = float(math.sqrt(max(np.linalg.eigvalsh(np.cov(txy.T) + 1e-12 * np.eye(2)).max(), 0.0)))
    spread_yaw = float(np.degrees(np.std(yaws[near[:, 0]]))) if near.shape[0] > 1 else 0.0
    a0, i0, j0 = np.unravel_index(int(np.argmax(sc)), sc.shape)
    ii, jj = np.meshgrid(np.arange(sc.shape[1]), np.arange(sc.shape[2]), indexing="ij")
    far = np.hypot(ii - i0, jj - j0) * coarse_cell_m > second_peak_m
    second = float(sc.max(axis=0)[far].max()) / best if np.any(far) and best > 0 else 0.0
    wf = max(1, int(math.ceil(coarse_cell_m / fine_cell_m)))
    nf = max(1, int(math.ceil(coarse_yaw_step_deg / fine_yaw_step_deg)))
    best_pose, best_val, best_raw = prior.copy(), -1.0, 0.0
    for a, i, j in _peaks(sc, refine_peaks, sep=max(1, int(round(0.5 / coarse_cell_m)))):
        cx, cy = prior[0] + (i - w) * coarse_cell_m, prior[1] + (j - w) * coarse_cell_m
        fy = yaws[a] + np.radians(fine_yaw_step_deg) * np.arange(-nf, nf + 1)
        sf = _search(fine.grid, fine.origin[0], fine.origin[1], fine.cell, q, fy, cx, cy, wf,
                     prior[0], prior[1], prior[2], sxy, syaw)
        k = int(np.argmax(sf))
        fa, fi, fj = np.unravel_index(k, sf.shape)
        if float(sf.flat[k]) > best_val:
            best_val = float(sf.flat[k])
            best_pose = np.array([cx + (fi - wf) * fine_cell_m, cy + (fj - wf) * fine_cell_m, float(fy[fa])])
    best_raw = fine.score(q, best_pose)
    best_pose[2] = (best_pose[2] + math.pi) % (2 * math.pi) - math.pi
    return ScanMatch(pose=best_pose, score=best_raw, spread_m=spread, spread_yaw_deg=spread_yaw,
                     n_points=int(q.shape[0]), second_ratio=second)


def free_space_fraction(scans: Sequence[np.ndarray | None], poses: Sequence[np.ndarray], query: np.ndarray, *,
                        margin_m: float = 0.3, bin_deg: float = 1.0) -> float:
    """Fraction of ``query`` points (reference frame) that lie where a reference scan saw
    through: for a scan (points in its own frame, taken at ``pose`` in the reference frame),
    a point at bearing b and range r is in its free space when the scan's nearest return in
    b's bin (``bin_deg`` wide) and the two bins beside it is farther than r + ``margin_m``.  A true registration puts the query's walls on or
    behind the reference's walls; a false one (a corridor of another width, a shifted room)
    puts some of them in space the reference laser looked through.  Bearings without a
    return say nothing: the fraction is over the points on a bearing some scan has a return on."""
    q = np.asarray(query, np.float64).reshape(-1, 2)
    if q.shape[0] == 0:
        return 0.0
    nbins = int(round(360.0 / bin_deg))
    seen = np.zeros(q.shape[0], bool)
    covered = np.zeros(q.shape[0], bool)
    for pts, pose in zip(scans, poses):
        if pts is None or len(pts) == 0:
            continue
        far = np.full(nbins, np.inf)       # nearest return per bearing bin: where the rays stopped
        b = ((np.degrees(np.arctan2(pts[:, 1], pts[:, 0])) + 180.0) / bin_deg).astype(np.int64) % nbins
        np.minimum.at(far, b, np.hypot(pts[:, 0], pts[:, 1]))
        c, s_ = math.cos(pose[2]), math.sin(pose[2])
        dx, dy = q[:, 0] - pose[0], q[:, 1] - pose[1]
        lx, ly = c * dx + s_ * dy, -s_ * dx + c * dy
        qb = ((np.degrees(np.arctan2(ly, lx)) + 180.0) / bin_deg).astype(np.int64) % nbins
        # the nearest return over the bin and its two neighbours: a wall seen at a grazing
        # angle spans metres of range within one bin
        near = np.minimum(np.minimum(far[qb], far[(qb + 1) % nbins]), far[(qb - 1) % nbins])
        hit = np.isfinite(near)
        seen |= hit & (near > np.hypot(lx, ly) + margin_m)
        covered |= hit
    n = int(np.count_nonzero(covered))
    return float(np.count_nonzero(seen)) / n if n else 0.0
