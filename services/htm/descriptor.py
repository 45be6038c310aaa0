"""The matching descriptor D_t of the neocortical front-end (Section 4.2.2, Eqs. 4.4-4.5).

Bit spaces (``n_bits``):

- ``tm`` (default): with ``descriptor.tm_bits: cells`` TM *cell* indices, ``column * cellsPerColumn
  + cell`` (81 920 bits at the dissertation's 2048 x 40), so the descriptor keeps the
  sequence context the TM encodes in which cell of a column wins (Fig. 4.3); with
  ``descriptor.tm_bits: columns`` (default: measured better on revisits, whose context differs lap to
  lap) the winners' columns (2048 bits): the same pooling, without the context.
- ``sp``: SP active column indices (``sp.columns`` bits).
- ``sdr``: the raw fused SDR indices (``input_size`` = L bits).

Pipeline of ``tm`` mode:

1. temporal pooling: the winner cells of the last ``descriptor.tm_window`` steps are counted and the
   ``descriptor.tm_topk`` most frequent kept -> A_t (Eq. 4.4). Ties in frequency are broken by a
   seeded random rank of the bit (a min-hash order), so equal windows give equal A_t and
   similar windows give similar A_t, without favouring low indices;
2. interval union (Eq. 4.5) when ``descriptor.interval_mode``: the run continues (K_t = min(K_{t-1} + 1,
   theta_rho)) while |A_t & A_{t-1}| / |A_t| >= theta_alpha, else restarts (K_t = 1);
   D_t = A_t | ... | A_{t-K_t+1};
3. cap: D_t keeps its ``descriptor.max_bits`` (``descriptor.tm_topk`` when 0) best bits, ranked by how many of the
   run's A sets hold the bit, then its window frequency, then the seeded rank.

``sp`` / ``sdr`` modes skip step 1 (A_t is the SP output or the fused SDR) and cap only when
``descriptor.max_bits`` > 0.
"""
from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["DescriptorBuilder"]


class DescriptorBuilder:
    """Stateful builder of D_t from per-step source bits (winner cells, columns or SDR bits)."""

    def __init__(self, mode: str, n_bits: int, window: int, topk: int, interval_mode: bool,
                 theta_alpha: float, theta_rho: int, max_bits: int, seed: int):
        if mode not in ("tm", "sp", "sdr"):
            raise ValueError(f"htm.descriptor.source must be tm, sp or sdr, got {mode!r}")
        self.mode = mode
        self.n_bits = int(n_bits)
        self.window = int(window) if mode == "tm" else 1
        self.topk = int(topk)
        self.interval_mode = bool(interval_mode)
        self.theta_alpha = float(theta_alpha)
        self.theta_rho = int(theta_rho)
        if max_bits > 0:
            self.cap = int(max_bits)
        else:
            self.cap = self.topk if mode == "tm" else 0
        rng = np.random.Generator(np.random.PCG64([seed, 0x5D]))
        # rank[bit]: the seeded tie-break order (smaller first)
        self.rank = rng.permutation(self.n_bits).astype(np.int64)
        self._hist: deque[np.ndarray] = deque(maxlen=self.window)
        self._runs: deque[np.ndarray] = deque(maxlen=self.theta_rho)
        self.run_length = 0

    def _ranked(self, bits: np.ndarray, primary: np.ndarray, secondary: np.ndarray, k: int) -> np.ndarray:
        """The k best of ``bits`` by (primary desc, secondary desc, rank asc), returned sorted."""
        if k <= 0 or bits.size <= k:
            return np.sort(bits).astype(np.int64)
        order = np.lexsort((self.rank[bits], -secondary, -primary))
        return np.sort(bits[order[:k]]).astype(np.int64)

    def update(self, source: np.ndarray) -> np.ndarray:
        """Push this step's source bits; returns D_t (sorted int64 bit indices)."""
        src = np.asarray(source, dtype=np.int64)
        if src.size > 1 and not bool(np.all(src[1:] > src[:-1])):    # sorted unique already: as is
            src = np.unique(src)
        if src.size and (src[0] < 0 or src[-1] >= self.n_bits):
            raise ValueError(f"descriptor source bit out of range [0, {self.n_bits})")
        self._hist.append(src)
        if self.mode != "tm" and not self.interval_mode and not self.cap:
            # window 1, no interval union, no cap: D_t is the source itself (what the general
            # path below computes, without its three unique() passes)
            self._runs.clear()
            self._runs.append(src)
            self.run_length = 1
            return src
        pooled = np.concatenate(list(self._hist))
        bits, counts = np.unique(pooled, return_counts=True)
        if self.mode == "tm":
            a_t = self._ranked(bits, counts, counts, self.topk)
        else:
            a_t = src
        # Eq. 4.5: interval union over the current run
        if self.interval_mode and self._runs:
            prev = self._runs[-1]
            overlap = np.intersect1d(a_t, prev, assume_unique=True).size
            cont = a_t.size > 0 and overlap / a_t.size >= self.theta_alpha
        else:
            cont = False
        self.run_length = min(self.run_length + 1, self.theta_rho) if cont else 1
        if not cont:
            self._runs.clear()
        self._runs.append(a_t)
        run = list(self._runs)[-self.run_length:]
        ubits, in_runs = np.unique(np.concatenate(run), return_counts=True)
        if not self.cap or ubits.size <= self.cap:
            return ubits
        # window frequency of each candidate bit (0 for bits that left the pooling window)
        freq = np.zeros(ubits.size, np.int64)
        pos = np.minimum(np.searchsorted(bits, ubits), bits.size - 1)
        hit = bits[pos] == ubits
        freq[hit] = counts[pos[hit]]
        return self._ranked(ubits, in_runs, freq, self.cap)

    def reset(self) -> None:
        self._hist.clear()
        self._runs.clear()
        self.run_length = 0

    # ---- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        hist = list(self._hist)
        runs = list(self._runs)
        return {
            "hist_bits": np.concatenate(hist) if hist else np.zeros(0, np.int64),
            "hist_len": np.array([h.size for h in hist], np.int64),
            "runs_bits": np.concatenate(runs) if runs else np.zeros(0, np.int64),
            "runs_len": np.array([r.size for r in runs], np.int64),
            "run_length": np.array([self.run_length], np.int64),
        }

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        self._hist.clear()
        self._runs.clear()
        for key_bits, key_len, dq in (("hist_bits", "hist_len", self._hist), ("runs_bits", "runs_len", self._runs)):
            bounds = np.concatenate([[0], np.cumsum(st[key_len])]).astype(np.int64)
            for a, b in zip(bounds[:-1], bounds[1:]):
                dq.append(np.asarray(st[key_bits][a:b], np.int64))
        self.run_length = int(st["run_length"][0])
