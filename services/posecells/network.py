"""4D pose-cell continuous attractor over (x, y, z, yaw) (dissertation Section 4.2.4).

:class:`PoseCellNetwork` holds the activity ``P`` on a ``(nx, ny, nz, n_yaw)`` lattice
(Table 4.1: ``(15, 15, 15, 8)``, translational spacing 0.1 m, yaw spacing 2 pi / n_yaw), with
wrap-around on every axis.  One :meth:`PoseCellNetwork.step` is, in this order:

0. maturation of the associations of LVCs that have been absent long enough (below);
1. path integration of the motion accumulated since the previous step (Eq. 4.15);
2. LVC injection ``P += delta * sum_l beta_l V_l`` of the mature associations (Eq. 4.19, right);
3. separable Gaussian excitation, wrapped on every axis (Eq. 4.16; sigmas in cells);
4. global inhibition ``phi``, ``max(0, .)`` and normalisation to a total of 1 (Eq. 4.17);
5. Hebbian learning ``beta_l <- max(beta_l, lambda V_l P)`` for the active LVCs (Eq. 4.19, left).

Global inhibition: the activity sums to 1 over 27 000 cells, so ``phi`` must be read against
a uniform level of 3.7e-5 (the chosen value and its measurements: docs/DECISIONS.md, "Pose
cells").

Path integration (our formulation).  The motion is given in the vehicle's heading frame:
``forward``/``left`` (horizontal, metres), ``up`` (metres) and the yaw change ``dyaw`` (radians,
counter-clockwise).  Yaw layer ``q`` stands for the heading ``theta_q = 2 pi q / n_yaw`` in the
world frame of the published ``Odometry`` (ENU: counter-clockwise from east).  The whole
packet moves by ``R(theta_bar) (forward, left)`` horizontally and ``up`` vertically, where
``theta_bar`` is the packet's own heading (its yaw centroid, below); then the yaw
axis shifts by ``dyaw / (2 pi / n_yaw)`` cells.  The node places the packet at the odometry
yaw, so without injection ``theta_bar`` equals the odometry yaw and the packet moves by the
odometry's world increment ``dp``; once an injection has turned the packet, translation
follows the packet's heading belief, as in RatSLAM.  We do not move each yaw layer along its
own ``theta_q`` (OpenRatSLAM's scheme): with 8 yaw bins of 45 deg the packet covers 3-5
layers, the layers fan out and the attractor then re-centres on the peak layer (docs/DECISIONS.md,
"Pose cells").
Sub-cell motion: the activity only ever moves by whole cells (exact rolls); the fraction is
kept as a continuous offset ``offset`` (cells, per axis, in ``[-0.5, 0.5)``) that is carried to
the next move and added to the read-out.  So two moves of 0.5 cell equal one of 1 cell
exactly, activity included, and any motion, however slow, is integrated without loss.  We
first shifted by linear interpolation of the fraction (OpenRatSLAM's scheme): the
interpolation blurs the packet and the thresholded attractor then pulls it back toward a
lattice-aligned shape, so slow motion was lost (docs/DECISIONS.md, "Pose cells").  Excitation commutes with whole-cell rolls, so the offset is
exact for the attractor; an LVC injection acts on whole cells (its sub-cell part, at most
half a cell, is not restored).

LVC -> pose-cell association (sparse).  Per LVC id, ``beta`` is stored only on the cells whose
activity is at least ``beta_min_fraction`` of the packet's peak when the LVC is active, at
most ``beta_max_cells`` of them (the strongest), as a sorted array of flat cell indices and
float32 values: a few hundred bytes per LVC instead of a dense 27k-cell vector.

Maturity (DolphinSLAM's ``L_mat``, Section 4.2.4): what an LVC learns during an episode of
activity (consecutive frames, gaps of at most ``lvc_maturity_steps`` frames) is injected only
after the episode has ended.  The front-end keeps one id for several frames while the vehicle
moves; injecting the association learned a few frames earlier dragged the packet back along
the path (docs/DECISIONS.md, "Pose cells").  A revisit
(the id seen again after a gap) injects the earlier episodes' pose.  ``lvc_maturity_steps: 0``
is the literal Eq. 4.19 (inject everything learned up to the previous frame).

Centroid: per axis, the marginal's mean of the wrapped offsets from the marginal's peak
(offsets in ``[-n/2, n/2]``, the antipodal cell of an even axis split between both ends), so
a packet straddling the wrap boundary is located correctly; plus the sub-cell offset.
Reported as metres (``[0, n * spacing)``) and radians (``[-pi, pi)``).

Hot loops (excitation, rolls) are numba kernels that skip zero cells: after inhibition the
packet covers a few hundred of the 27k cells.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from services.posecells.config import PoseCellsConfig

__all__ = ["PoseCellNetwork", "gaussian_kernel", "wrapped_centroid_cells"]

_STATE_VERSION = 1


def gaussian_kernel(sigma_cells: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and weights (sum 1) of a Gaussian of ``sigma_cells`` on a wrapped axis of ``n``.

    Radius ``ceil(3 sigma)``, capped at ``(n - 1) // 2`` so no cell is reached twice by the wrap.
    """
    radius = min(int(math.ceil(3.0 * sigma_cells)), (n - 1) // 2)
    offsets = np.arange(-radius, radius + 1, dtype=np.int64)
    weights = np.exp(-offsets.astype(np.float64) ** 2 / (2.0 * sigma_cells ** 2))
    return offsets, weights / weights.sum()


# --------------------------------------------------------------------------- numba kernels


@numba.njit(cache=True)
def _excite_list(src: np.ndarray, dst: np.ndarray, idx_src: np.ndarray, n_src: int, idx_dst: np.ndarray,
                 stride: int, n: int, offsets: np.ndarray, weights: np.ndarray) -> int:
    """Scatter the listed non-zero cells of ``src`` into ``dst`` along one wrapped axis (flat
    C-order arrays); lists the touched cells of ``dst`` in ``idx_dst`` and returns their number.
    ``dst`` must be zero on entry; ``src`` is left zero on exit.  The activity is never negative
    and the weights are positive, so a cell of ``dst`` still at 0 has not been touched yet.
    ``offsets`` ascend from ``-r`` to ``r``; a source at least ``r`` cells from both ends of the
    axis takes the straight path (no wrap), with the same additions in the same order."""
    m = offsets.shape[0]
    r = -offsets[0]
    n_dst = 0
    for t in range(n_src):
        i = idx_src[t]
        v = src[i]
        src[i] = 0.0
        c = (i // stride) % n
        if c >= r and c + r < n:
            j = i - r * stride
            for u in range(m):
                if dst[j] == 0.0:
                    idx_dst[n_dst] = j
                    n_dst += 1
                dst[j] += v * weights[u]
                j += stride
        else:
            base = i - c * stride
            for u in range(m):
                cc = c + offsets[u]
                if cc < 0:
                    cc += n
                elif cc >= n:
                    cc -= n
                j = base + cc * stride
                if dst[j] == 0.0:
                    idx_dst[n_dst] = j
                    n_dst += 1
                dst[j] += v * weights[u]
    return n_dst


@numba.njit(cache=True)
def _attractor_update(p: np.ndarray, tmp: np.ndarray, idx_a: np.ndarray, idx_b: np.ndarray,
                      strides: np.ndarray, dims: np.ndarray, off0: np.ndarray, w0: np.ndarray, off1: np.ndarray,
                      w1: np.ndarray, off2: np.ndarray, w2: np.ndarray, off3: np.ndarray, w3: np.ndarray,
                      phi: float) -> float:
    """Eqs. 4.16-4.17 in place on the flat activity ``p``: separable wrapped excitation over
    the non-zero cells only, then ``N(max(0, E - phi))``.  ``tmp`` is zero scratch (left
    zero).  Returns the total before normalisation."""
    n_a = 0
    for i in range(p.shape[0]):
        if p[i] != 0.0:
            idx_a[n_a] = i
            n_a += 1
    # yaw first: the packet already spans most of the yaw axis, so the support grows least
    n_b = _excite_list(p, tmp, idx_a, n_a, idx_b, strides[3], dims[3], off3, w3)
    n_a = _excite_list(tmp, p, idx_b, n_b, idx_a, strides[0], dims[0], off0, w0)
    n_b = _excite_list(p, tmp, idx_a, n_a, idx_b, strides[1], dims[1], off1, w1)
    n_a = _excite_list(tmp, p, idx_b, n_b, idx_a, strides[2], dims[2], off2, w2)
    total = 0.0
    for t in range(n_a):
        i = idx_a[t]
        v = p[i] - phi
        if v > 0.0:
            p[i] = v
            total += v
        else:
            p[i] = 0.0
    if total > 0.0:
        inv = 1.0 / total
        for t in range(n_a):
            p[idx_a[t]] *= inv
    return total


@numba.njit(cache=True)
def _marginals(p: np.ndarray, d0: int, d1: int, d2: int, d3: int) -> np.ndarray:
    """The four axis marginals of the flat (d0, d1, d2, d3) activity, concatenated."""
    out = np.zeros(d0 + d1 + d2 + d3)
    i = 0
    for a in range(d0):
        for b in range(d1):
            for c in range(d2):
                for q in range(d3):
                    v = p[i]
                    i += 1
                    if v != 0.0:
                        out[a] += v
                        out[d0 + b] += v
                        out[d0 + d1 + c] += v
                        out[d0 + d1 + d2 + q] += v
    return out


@numba.njit(cache=True)
def _roll_axis(src: np.ndarray, dst: np.ndarray, stride: int, n: int, k: int) -> None:
    """dst = src rolled by ``k`` whole cells along one wrapped axis (flat C-order arrays seen
    as (outer, n, stride)); zero cells skipped."""
    dst[:] = 0.0
    outer = src.shape[0] // (n * stride)
    for o in range(outer):
        base = o * n * stride
        for c in range(n):
            row = base + c * stride
            out = base + ((c + k) % n) * stride
            for j in range(stride):
                v = src[row + j]
                if v != 0.0:
                    dst[out + j] = v


# --------------------------------------------------------------------------- helpers


def wrapped_centroid_cells(marginal: np.ndarray) -> float:
    """Centroid (in cells, ``[0, n)``) of a wrapped 1D marginal: the peak plus the mean of the
    offsets from the peak wrapped to ``[-n/2, n/2]``; on an even axis the antipodal cell counts
    half at ``-n/2`` and half at ``+n/2`` (so a packet that reaches all the way round stays
    symmetric)."""
    n = marginal.shape[0]
    total = float(marginal.sum())
    if not total > 0.0:
        raise ValueError("centroid of an empty marginal (no activity)")
    peak = int(np.argmax(marginal))
    offsets = ((np.arange(n) - peak) % n).astype(np.float64)
    offsets = np.where(offsets > n / 2.0, offsets - n, offsets)
    if n % 2 == 0:
        offsets[(peak + n // 2) % n] = 0.0  # (+n/2 - n/2) / 2
    return float((peak + float(marginal @ offsets) / total) % n)


@dataclass
class _Beta:
    cells: np.ndarray  # int32 sorted flat indices
    values: np.ndarray  # float32


class PoseCellNetwork:
    """The 4D pose-cell attractor with sparse Hebbian LVC associations (Eqs. 4.15-4.19)."""

    def __init__(self, config: PoseCellsConfig | None = None):
        self.cfg = config or PoseCellsConfig()
        self.dims = tuple(int(v) for v in self.cfg.number_of_neurons)
        if min(self.dims) < 2:
            raise ValueError(f"posecells.number_of_neurons must be >= 2 on every axis, got {list(self.dims)}")
        self.spacing = np.asarray(self.cfg.distance_between_neurons, dtype=np.float64)
        self.yaw_step = 2.0 * math.pi / self.dims[3]
        self.size = int(np.prod(self.dims))
        self._strides = np.array([self.dims[1] * self.dims[2] * self.dims[3], self.dims[2] * self.dims[3],
                                  self.dims[3], 1], dtype=np.int64)
        self._dims = np.array(self.dims, dtype=np.int64)
        sig = (self.cfg.excitation_sigma_cells,) * 3 + (self.cfg.excitation_sigma_yaw_cells,)
        self._kernels = [gaussian_kernel(s, n) for s, n in zip(sig, self.dims)]
        self._layer_headings = np.arange(self.dims[3]) * self.yaw_step
        self.activity = np.zeros(self.size, dtype=np.float64)
        self._tmp = np.zeros(self.size, dtype=np.float64)  # zero between updates (see _attractor_update)
        self._roll_tmp = np.zeros(self.size, dtype=np.float64)
        self._idx_a = np.zeros(self.size, dtype=np.int64)
        self._idx_b = np.zeros(self.size, dtype=np.int64)
        self.beta: dict[int, _Beta] = {}  # mature associations (injected)
        self.episode_beta: dict[int, _Beta] = {}  # learned in the LVC's current episode (not injected yet)
        self.last_active: dict[int, int] = {}  # step an LVC with an open episode was last active
        self.offset = np.zeros(4)  # sub-cell position (cells) carried between moves
        self.steps = 0
        self.reset((self.dims[0] // 2, self.dims[1] // 2, self.dims[2] // 2, 0.0))

    # ---- state ------------------------------------------------------------------------------
    @property
    def P(self) -> np.ndarray:
        """Activity as a ``(nx, ny, nz, n_yaw)`` view."""
        return self.activity.reshape(self.dims)

    def reset(self, cell: tuple[float, float, float, float]) -> None:
        """A lone unit packet at a (possibly fractional) cell position (x, y, z, yaw cells)."""
        self.activity[:] = 0.0
        whole = [int(math.floor(float(c) + 0.5)) for c in cell]
        self.offset = np.array([float(c) - w for c, w in zip(cell, whole)])
        self.activity[int(np.dot([w % n for w, n in zip(whole, self.dims)], self._strides))] = 1.0

    def reset_at_pose(self, x: float, y: float, z: float, yaw: float) -> None:
        """A lone packet at a pose (metres, radians; positions wrap modulo the lattice)."""
        self.reset((x / self.spacing[0], y / self.spacing[1], z / self.spacing[2], yaw / self.yaw_step))

    # ---- dynamics -----------------------------------------------------------------------------
    def update(self) -> None:
        """Excitation, global inhibition, rectification and normalisation (Eqs. 4.16-4.17)."""
        (o0, w0), (o1, w1), (o2, w2), (o3, w3) = self._kernels
        total = _attractor_update(self.activity, self._tmp, self._idx_a, self._idx_b, self._strides,
                                  self._dims, o0, w0, o1, w1, o2, w2, o3, w3, float(self.cfg.global_inhibition))
        if not total > 0.0:
            raise RuntimeError("pose cells: global inhibition removed all activity "
                               f"(posecells.global_inhibition={self.cfg.global_inhibition} is too large)")

    def heading_concentration(self) -> tuple[float, float]:
        """Diagnostic (rho, mean): mean resultant length and circular mean (rad, sub-cell offset
        included) of the yaw marginal, ``rho e^{i mean} = sum_q w_q e^{i theta_q}``."""
        w = self.marginals()[3]
        z = complex(np.dot(w, np.cos(self._layer_headings)), np.dot(w, np.sin(self._layer_headings)))
        total = float(w.sum())
        return abs(z) / total, math.atan2(z.imag, z.real) + float(self.offset[3]) * self.yaw_step

    def path_integrate(self, forward: float, left: float, up: float, dyaw: float) -> None:
        """Move the packet by a motion in the heading frame (m, m, m, rad), Eq. 4.15:
        ``R(theta_bar) (forward, left)`` horizontally, ``up`` vertically, then ``dyaw`` along
        the yaw axis (module docstring)."""
        if forward or left:
            heading = (wrapped_centroid_cells(self.marginals()[3]) + float(self.offset[3])) * self.yaw_step
            c, s = math.cos(heading), math.sin(heading)
            dx, dy = c * forward - s * left, s * forward + c * left
        else:
            dx = dy = 0.0
        self._shift(np.array([dx / self.spacing[0], dy / self.spacing[1], up / self.spacing[2]]), dyaw / self.yaw_step)

    def _shift(self, cells: np.ndarray, yaw_cells: float) -> None:
        """Add (x, y, z, yaw) cells of motion: whole cells roll the activity, the rest stays in
        :attr:`offset` (module docstring)."""
        self.offset += np.array([cells[0], cells[1], cells[2], yaw_cells], dtype=np.float64)
        whole = np.floor(self.offset + 0.5)
        self.offset -= whole
        src, dst = self.activity, self._roll_tmp
        for axis in range(4):
            k = int(whole[axis]) % self.dims[axis]
            if k == 0:
                continue
            _roll_axis(src, dst, self._strides[axis], self._dims[axis], k)
            src, dst = dst, src
        if src is not self.activity:
            self.activity[:] = src

    # ---- LVC association (Eq. 4.19) ---------------------------------------------------------------
    def inject(self, lvc_ids: list[int] | tuple[int, ...]) -> int:
        """``P += delta * sum_l beta_l`` over the active LVCs with a mature association;
        returns how many injected."""
        gain = float(self.cfg.lvc_injection_gain)
        n = 0
        for lvc in lvc_ids:
            b = self.beta.get(int(lvc))
            if b is None:
                continue
            self.activity[b.cells] += gain * b.values
            n += 1
        return n

    def learn(self, lvc_ids: list[int] | tuple[int, ...]) -> None:
        """``beta_l <- max(beta_l, lambda P)`` on the cells near the packet, kept sparse, into
        the LVC's current episode (it matures once the LVC has been absent long enough)."""
        lam = float(self.cfg.lvc_learning_rate)
        peak = float(self.activity.max())
        if lam == 0.0 or not peak > 0.0:
            return
        cells = np.flatnonzero(self.activity >= self.cfg.beta_min_fraction * peak).astype(np.int32)
        values = (lam * self.activity[cells]).astype(np.float32)
        for lvc in lvc_ids:
            lvc = int(lvc)
            self.episode_beta[lvc] = self._merge(self.episode_beta.get(lvc), cells, values)
            self.last_active[lvc] = self.steps

    def _merge(self, old: _Beta | None, cells: np.ndarray, values: np.ndarray) -> _Beta:
        """Element-wise max of two sparse associations, capped at ``beta_max_cells`` (strongest)."""
        if old is None:
            c, v = cells, values
        else:
            c = np.concatenate([old.cells, cells])
            v = np.concatenate([old.values, values])
            order = np.argsort(c, kind="stable")
            c, v = c[order], v[order]
            starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
            c, v = c[starts], np.maximum.reduceat(v, starts)
        cap = int(self.cfg.beta_max_cells)
        if c.size > cap:
            keep = np.sort(np.argsort(-v, kind="stable")[:cap])
            c, v = c[keep], v[keep]
        return _Beta(np.ascontiguousarray(c, dtype=np.int32), np.ascontiguousarray(v, dtype=np.float32))

    def mature(self) -> int:
        """Move the episodes of LVCs absent for more than ``lvc_maturity_steps`` steps into the
        injected associations; returns how many matured."""
        limit = int(self.cfg.lvc_maturity_steps)
        done = [lvc for lvc, last in self.last_active.items() if self.steps - last > limit]
        for lvc in done:
            ep = self.episode_beta.pop(lvc)
            del self.last_active[lvc]
            self.beta[lvc] = self._merge(self.beta.get(lvc), ep.cells, ep.values)
        return len(done)

    def step(self, forward: float = 0.0, left: float = 0.0, up: float = 0.0, dyaw: float = 0.0,
             active_lvcs: list[int] | tuple[int, ...] = ()) -> None:
        """One frame: maturation, path integration, injection, attractor update, learning
        (module docstring)."""
        self.mature()
        if forward or left or up or dyaw:
            self.path_integrate(forward, left, up, dyaw)
        self.inject(active_lvcs)
        self.update()
        self.learn(active_lvcs)
        self.steps += 1

    # ---- read-out --------------------------------------------------------------------------------
    def marginals(self) -> list[np.ndarray]:
        """Activity summed over all axes but one, for x, y, z and yaw."""
        flat = _marginals(self.activity, *self.dims)
        ends = np.cumsum(self.dims)
        return [flat[e - n:e] for e, n in zip(ends, self.dims)]

    def centroid_cells(self) -> np.ndarray:
        """Wrap-safe centroid (x, y, z, yaw) in cells ``[0, n)``, sub-cell offset included."""
        c = np.array([wrapped_centroid_cells(m) for m in self.marginals()]) + self.offset
        return c % np.array(self.dims, dtype=np.float64)

    def centroid(self) -> list[float]:
        """Centroid as ``[x, y, z]`` metres in ``[0, n * spacing)`` and yaw radians in ``[-pi, pi)``."""
        c = self.centroid_cells()
        yaw = (c[3] * self.yaw_step + math.pi) % (2.0 * math.pi) - math.pi
        return [float(c[0] * self.spacing[0]), float(c[1] * self.spacing[1]), float(c[2] * self.spacing[2]),
                float(yaw)]

    def beta_cells(self) -> int:
        """Total stored associations (cells over every LVC, mature and open episodes)."""
        return sum(b.cells.size for b in self.beta.values()) + sum(b.cells.size for b in self.episode_beta.values())

    # ---- persistence -----------------------------------------------------------------------------
    @staticmethod
    def _pack(table: dict[int, _Beta], prefix: str) -> dict[str, np.ndarray]:
        ids = np.array(sorted(table), dtype=np.int64)
        return {f"{prefix}_ids": ids,
                f"{prefix}_counts": np.array([table[i].cells.size for i in ids], dtype=np.int64),
                f"{prefix}_cells": np.concatenate([table[i].cells for i in ids]) if ids.size else np.zeros(0, np.int32),
                f"{prefix}_values": np.concatenate([table[i].values for i in ids]) if ids.size else
                np.zeros(0, np.float32)}

    @staticmethod
    def _unpack(arrays: dict[str, np.ndarray] | np.lib.npyio.NpzFile, prefix: str) -> dict[int, _Beta]:
        counts = np.asarray(arrays[f"{prefix}_counts"])
        ends = np.cumsum(counts)
        cells, values = arrays[f"{prefix}_cells"], arrays[f"{prefix}_values"]
        return {int(lvc): _Beta(np.array(cells[e - n:e], dtype=np.int32), np.array(values[e - n:e], dtype=np.float32))
                for lvc, n, e in zip(arrays[f"{prefix}_ids"], counts, ends)}

    def state_arrays(self) -> dict[str, np.ndarray]:
        """Everything needed to continue, as numpy arrays (for ``np.savez``)."""
        last_ids = np.array(sorted(self.last_active), dtype=np.int64)
        return {"pc_version": np.array(_STATE_VERSION), "pc_dims": np.array(self.dims, dtype=np.int64),
                "pc_activity": self.activity.copy(), "pc_offset": self.offset.copy(),
                "pc_steps": np.array(self.steps, dtype=np.int64),
                **self._pack(self.beta, "pc_beta"), **self._pack(self.episode_beta, "pc_episode"),
                "pc_last_ids": last_ids,
                "pc_last_steps": np.array([self.last_active[i] for i in last_ids], dtype=np.int64)}

    def load_arrays(self, arrays: dict[str, np.ndarray] | np.lib.npyio.NpzFile, source: str = "state") -> None:
        """Restore what :meth:`state_arrays` wrote; ``source`` names the file in errors."""
        needed = ["pc_version", "pc_dims", "pc_activity", "pc_offset", "pc_steps", "pc_last_ids", "pc_last_steps"] + \
            [f"{p}_{k}" for p in ("pc_beta", "pc_episode") for k in ("ids", "counts", "cells", "values")]
        missing = [k for k in needed if k not in arrays]
        if missing:
            raise ValueError(f"{source}: not a pose-cell state (missing {missing})")
        if int(arrays["pc_version"]) != _STATE_VERSION:
            raise ValueError(f"{source}: pose-cell state version {int(arrays['pc_version'])}, expected {_STATE_VERSION}")
        dims = tuple(int(v) for v in arrays["pc_dims"])
        if dims != self.dims:
            raise ValueError(f"{source}: pose-cell lattice {list(dims)} differs from posecells.number_of_neurons "
                             f"{list(self.dims)}")
        self.activity[:] = np.asarray(arrays["pc_activity"], dtype=np.float64)
        self.offset = np.asarray(arrays["pc_offset"], dtype=np.float64).copy()
        self.steps = int(arrays["pc_steps"])
        self.beta = self._unpack(arrays, "pc_beta")
        self.episode_beta = self._unpack(arrays, "pc_episode")
        self.last_active = {int(i): int(s) for i, s in zip(arrays["pc_last_ids"], arrays["pc_last_steps"])}

    def save(self, path: str | Path) -> None:
        # numpy's savez stub types **kwds against its allow_pickle: bool keyword
        np.savez(Path(path), **self.state_arrays())  # type: ignore[arg-type]

    @classmethod
    def load(cls, path: str | Path, config: PoseCellsConfig | None = None) -> PoseCellNetwork:
        net = cls(config)
        with np.load(Path(path)) as f:
            net.load_arrays(f, source=str(path))
        return net
