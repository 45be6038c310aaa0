"""HTM Spatial Pooler (BAMI pseudocode; dissertation Table 3.2, Table 5.1, Table 4.1).

Global inhibition only: exactly ``num_active`` columns win every step, ties broken by the
lowest column index (deterministic).  Each column has a potential pool of
``round(potential_pct * (2 * potential_radius + 1))`` inputs drawn without replacement from
the inputs within ``potential_radius`` of its centre (wrap-around), permanences start
uniform in ``[connected, 1]`` (connected) or ``[0, connected)`` (not), half each.

Learning (BAMI "Phase 3"): active columns increase the permanence of synapses on active
inputs by ``syn_perm_active_inc`` and decrease the others by ``syn_perm_inactive_dec``;
duty cycles are moving averages over ``duty_cycle_period``; boosting uses
``boost = exp(-boost_strength * (activeDutyCycle - targetDensity))`` and columns whose
overlap duty cycle falls under ``min_pct_overlap_duty_cycle * max(overlapDutyCycle)`` get
all permanences raised by ``connected / 10`` (BAMI ``increasePermanences``).

Overlap standardisation (``overlap_norm_steps`` N > 0, ours): inhibition ranks
``(overlap - mean_c) / sqrt(var_c + 1)`` with each column's running mean and variance of its
overlap over the first N learning steps (then frozen), in place of boosting, and the
permanences do not learn.  A dense input (the camera OR sonar union has ~900 of 2048 bits on)
otherwise lets the columns wired to frequently-on bits win every frame: on the seed-1234
mission the descriptor-overlap AP of 4096 columns / 800 active is 0.639 standardised vs
0.502 (4096 / 400) with BAMI boosting (fused SDR itself 0.623).

Speed: the connected synapses are mirrored in a column-major bit matrix
``conn[column, input // 64]`` (uint64 words), so a column's overlap is a popcount of
``conn & input`` over ``L / 64`` words (32 for L = 2048), and learning only touches the
winners' potential pools.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from services.htm._bits import popcount64

__all__ = ["SpatialPooler"]


@njit(cache=True)
def _top_k(scores: np.ndarray, k: int, out: np.ndarray) -> int:
    """Indices of the k largest scores, ties to the lowest index; returned sorted by index.

    O(n): the k-th largest value v by partition, then one pass taking every score above v and
    the lowest-index scores equal to v until k are taken."""
    n = scores.shape[0]
    if k > n:
        k = n
    if k <= 0:
        return 0
    v = np.partition(scores, n - k)[n - k]
    need = k
    for c in range(n):
        if scores[c] > v:
            need -= 1
    m = 0
    for c in range(n):
        s = scores[c]
        if s > v or (s == v and need > 0):
            if s == v:
                need -= 1
            out[m] = c
            m += 1
    return m


@njit(cache=True)
def _set_conn(conn: np.ndarray, c: int, i: int, on: bool) -> None:
    w = i >> 6
    b = np.uint64(1) << np.uint64(i & 63)
    if on:
        conn[c, w] |= b
    else:
        conn[c, w] &= ~b


@njit(cache=True)
def _sp_step(active: np.ndarray, inp_bits: np.ndarray, conn: np.ndarray, pot: np.ndarray,
             perm: np.ndarray, boost: np.ndarray, overlap_duty: np.ndarray, active_duty: np.ndarray,
             overlaps: np.ndarray, out: np.ndarray, num_active: int, learn: bool, use_boost: bool,
             boost_strength: float, inc: float, dec: float, connected: float, period: float,
             min_overlap_duty: float, use_norm: bool, ov_mean: np.ndarray, ov_isd: np.ndarray) -> int:
    """One SP step: overlap (popcount of connected & input), global inhibition, BAMI learning."""
    ncols, nwords = conn.shape
    inp_bits[:] = 0
    for a in range(active.shape[0]):
        i = active[a]
        inp_bits[i >> 6] |= np.uint64(1) << np.uint64(i & 63)
    scores = np.empty(ncols, np.float64)
    for c in range(ncols):
        s = 0
        for w in range(nwords):
            s += popcount64(conn[c, w] & inp_bits[w])
        overlaps[c] = s
        if use_norm:
            scores[c] = (s - ov_mean[c]) * ov_isd[c]
        else:
            scores[c] = s * boost[c] if use_boost else s
    k = _top_k(scores, num_active, out)
    if not learn:
        return k
    npot = pot.shape[1]
    delta_tbl = np.array([-dec, inc], np.float32)
    fconn = np.float32(connected)
    for a in range(k):
        c = out[a]
        for j in range(npot):
            i = pot[c, j]
            bit = (inp_bits[i >> 6] >> np.uint64(i & 63)) & np.uint64(1)
            p = min(max(perm[c, j] + delta_tbl[bit], np.float32(0.0)), np.float32(1.0))
            perm[c, j] = p
            # branch-free update of bit i of the connected mask of column c
            w = i >> 6
            sh = np.uint64(i & 63)
            conn[c, w] = (conn[c, w] & ~(np.uint64(1) << sh)) | (np.uint64(p >= fconn) << sh)
    # duty cycles (moving averages over `period` learning steps)
    keep = (period - 1.0) / period
    for c in range(ncols):
        overlap_duty[c] = overlap_duty[c] * keep + (1.0 / period if overlaps[c] > 0 else 0.0)
        active_duty[c] *= keep
    for a in range(k):
        active_duty[out[a]] += 1.0 / period
    # BAMI increasePermanences for columns whose overlap duty cycle is too low
    delta = np.float32(0.1 * connected)
    for c in range(ncols):
        if overlap_duty[c] < min_overlap_duty:
            for j in range(npot):
                p = min(perm[c, j] + delta, np.float32(1.0))
                perm[c, j] = p
                _set_conn(conn, c, pot[c, j], p >= fconn)
    if use_boost:
        target = num_active / ncols
        for c in range(ncols):
            boost[c] = np.exp(-boost_strength * (active_duty[c] - target))
    return k


class SpatialPooler:
    """Spatial Pooler with global inhibition (BAMI; Table 3.2 / Table 5.1 parameters)."""

    UPDATE_PERIOD = 50  # learning steps between recomputations of the minimum duty cycle

    def __init__(self, input_size: int, columns: int, num_active: int, potential_radius: int,
                 potential_pct: float, syn_perm_active_inc: float, syn_perm_inactive_dec: float,
                 syn_perm_connected: float, boost_strength: float, duty_cycle_period: int,
                 min_pct_overlap_duty_cycle: float, seed: int, overlap_norm_steps: int = 0):
        if num_active > columns:
            raise ValueError(f"htm.sp.num_active_columns ({num_active}) exceeds htm.sp.columns ({columns})")
        self.input_size = int(input_size)
        self.columns = int(columns)
        self.num_active = int(num_active)
        self.inc = float(syn_perm_active_inc)
        self.dec = float(syn_perm_inactive_dec)
        self.connected = float(syn_perm_connected)
        self.boost_strength = float(boost_strength)
        self.duty_cycle_period = int(duty_cycle_period)
        self.min_pct_overlap = float(min_pct_overlap_duty_cycle)
        self.overlap_norm_steps = int(overlap_norm_steps)
        rng = np.random.Generator(np.random.PCG64(seed))

        radius = min(int(potential_radius), (self.input_size - 1) // 2)
        span = 2 * radius + 1
        npot = max(1, int(round(span * potential_pct)))
        self.pot = np.empty((self.columns, npot), np.int32)
        self.perm = np.empty((self.columns, npot), np.float32)
        offsets = np.arange(-radius, radius + 1)
        for c in range(self.columns):
            centre = int((c + 0.5) * self.input_size / self.columns)
            pool = (centre + offsets) % self.input_size
            self.pot[c] = np.sort(rng.choice(pool, size=npot, replace=False))
            is_conn = rng.random(npot) < 0.5
            r = rng.random(npot)
            self.perm[c] = np.where(is_conn, self.connected + (1.0 - self.connected) * r, self.connected * r)
        self.nwords = (self.input_size + 63) // 64
        self.conn = np.zeros((self.columns, self.nwords), np.uint64)
        self._rebuild_conn()
        self.overlap_duty = np.zeros(self.columns, np.float64)
        self.active_duty = np.zeros(self.columns, np.float64)
        self.boost = np.ones(self.columns, np.float64)
        self.min_overlap_duty = 0.0
        self.iteration = 0
        self.iteration_learn = 0
        self.overlaps = np.zeros(self.columns, np.int32)
        # overlap standardisation (overlap_norm_steps > 0): running mean / M2 of each column's overlap
        self.ov_n = 0
        self.ov_mean = np.zeros(self.columns, np.float64)
        self.ov_m2 = np.zeros(self.columns, np.float64)
        self.ov_isd = np.ones(self.columns, np.float64)
        self._out = np.empty(self.num_active, np.int32)
        self._inp_bits = np.zeros(self.nwords, np.uint64)

    def _rebuild_conn(self) -> None:
        """Mirror ``perm >= connected`` into the column-major bit matrix ``conn``."""
        self.conn[:] = 0
        on = self.perm >= self.connected
        cols = np.repeat(np.arange(self.columns), self.pot.shape[1])[on.ravel()]
        idx = self.pot.ravel()[on.ravel()].astype(np.uint64)
        np.bitwise_or.at(self.conn, (cols, (idx >> np.uint64(6)).astype(np.int64)),
                         np.left_shift(np.uint64(1), idx & np.uint64(63)))

    def compute(self, active_inputs: np.ndarray, learn: bool = True) -> np.ndarray:
        """Active columns (sorted int32, exactly ``num_active``) for the active input indices."""
        act = np.ascontiguousarray(active_inputs, dtype=np.int64)
        if act.size and (act.min() < 0 or act.max() >= self.input_size):
            raise ValueError(f"SP input index out of range [0, {self.input_size}): "
                             f"min {act.min()}, max {act.max()}")
        if learn:
            self.iteration_learn += 1
        self.iteration += 1
        period = float(min(self.duty_cycle_period, max(self.iteration_learn, 1)))
        norm = self.overlap_norm_steps > 0
        k = _sp_step(act, self._inp_bits, self.conn, self.pot, self.perm, self.boost,
                     self.overlap_duty, self.active_duty, self.overlaps, self._out, self.num_active,
                     bool(learn) and not norm, self.boost_strength > 0, self.boost_strength, self.inc, self.dec,
                     self.connected, period, self.min_overlap_duty, norm, self.ov_mean, self.ov_isd)
        if norm and learn and self.ov_n < self.overlap_norm_steps:
            self._update_norm()
        if learn and self.iteration_learn % self.UPDATE_PERIOD == 0:
            self.min_overlap_duty = self.min_pct_overlap * float(self.overlap_duty.max())
        return self._out[:k].copy()

    def _update_norm(self) -> None:
        """Welford update of the per-column overlap statistics with this step's overlaps."""
        x = self.overlaps.astype(np.float64)
        self.ov_n += 1
        d = x - self.ov_mean
        self.ov_mean += d / self.ov_n
        self.ov_m2 += d * (x - self.ov_mean)
        # 1 / sqrt(var + 1): a column whose overlap never varied ranks by its raw deviation
        self.ov_isd = 1.0 / np.sqrt(self.ov_m2 / self.ov_n + 1.0)

    # ---- persistence ---------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        return {
            "pot": self.pot, "perm": self.perm, "overlap_duty": self.overlap_duty,
            "active_duty": self.active_duty, "boost": self.boost,
            "scalars": np.array([self.iteration, self.iteration_learn], np.int64),
            "min_overlap_duty": np.array([self.min_overlap_duty], np.float64),
            "ov_n": np.array([self.ov_n], np.int64), "ov_mean": self.ov_mean, "ov_m2": self.ov_m2,
        }

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        if st["pot"].shape != self.pot.shape:
            raise ValueError(f"SP state has potential pools {st['pot'].shape}, configuration expects {self.pot.shape}")
        self.pot = np.array(st["pot"], np.int32)
        self.perm = np.array(st["perm"], np.float32)
        self.overlap_duty = np.array(st["overlap_duty"], np.float64)
        self.active_duty = np.array(st["active_duty"], np.float64)
        self.boost = np.array(st["boost"], np.float64)
        self.iteration, self.iteration_learn = (int(x) for x in st["scalars"])
        self.min_overlap_duty = float(st["min_overlap_duty"][0])
        if "ov_n" in st:
            self.ov_n = int(st["ov_n"][0])
            self.ov_mean = np.array(st["ov_mean"], np.float64)
            self.ov_m2 = np.array(st["ov_m2"], np.float64)
            self.ov_isd = 1.0 / np.sqrt(self.ov_m2 / max(self.ov_n, 1) + 1.0)
        self._rebuild_conn()
