"""HTM Temporal Memory (BAMI pseudocode; dissertation Table 3.3, Table 5.1, Table 4.1).

Per step, with the active columns of the Spatial Pooler:

1. every active column that contains cells with *active* segments (computed at the end of
   the previous step) activates exactly those cells, which are also winners; learning
   reinforces those segments (``+permanenceIncrement`` on synapses from previously active
   cells, ``-permanenceDecrement`` on the others) and grows up to
   ``maxNewSynapseCount - numActivePotential`` synapses to previous winner cells;
2. every other active column *bursts*: all its cells become active; the winner is the
   cell of the best *matching* segment (most active potential synapses, ties to the lowest
   cell/segment) which learns as above, or else the least-used cell (fewest segments,
   random tie) on which a new segment grows ``min(maxNewSynapseCount, |prevWinners|)``
   synapses with ``initialPermanence``;
3. matching segments in inactive columns are punished by ``predictedSegmentDecrement``;
4. segment activity for the next step: a segment is *active* with
   ``>= activationThreshold`` connected (``>= connectedPermanence``) synapses from the
   active cells, *matching* with ``>= minThreshold`` potential synapses. Cells with an
   active segment are the predictive cells.

With a synapse budget (``max_synapses`` > 0; ours: the dissertation's TM has only
the per-cell and per-segment caps), a learning step that leaves more synapses than the budget
destroys approximately least recently used segments of any cell until it holds no more (the
oldest last-learnt of 32 segments drawn at random, O(1) each; never one the step may still
touch), before step 4.  Step 4 walks the presynaptic lists of the active cells, whose length
grows with the synapses the memory holds, so the budget keeps a step's cost flat over hours.

Anomaly = fraction of active columns that had no predictive cell.

Data layout (all flat numpy arrays, numba kernels, no Python objects per synapse):

- segments ``g``: owner cell, live synapse count, slot high-water mark, last-used step and
  up to ``ceil(maxSynapsesPerSegment / 32)`` blocks of 32 synapse slots; a synapse is
  addressed by a global slot id ``block * 32 + offset`` (stable while the synapse lives);
- synapses: presynaptic cell (``-1`` = free slot) and float32 permanence per slot;
- presynaptic index: every cell owns a chain of 16-entry blocks listing the slot ids of
  the synapses it feeds, so step 4 costs O(synapses of the active cells), never
  O(all segments).

Capacities grow by doubling between steps (the bound of what one step can allocate is
checked before the kernel runs).  Randomness comes from a xorshift64* generator whose
state is part of the saved state, so a saved and reloaded memory continues identically.
"""
from __future__ import annotations

import numpy as np

from services.htm.tm_kernels import _tm_step
from services.htm.tm_storage import (
    M_BLK_TOP,
    M_EVICTED,
    M_LEN,
    M_NACT,
    M_NMATCH,
    M_NPRED,
    M_NPREV_ACTIVE,
    M_NPREV_WINNER,
    M_NSYN,
    M_PB_TOP,
    M_SEG_FREE,
    M_SEG_TOP,
    PBLK,
    SBLK,
)

__all__ = ["TemporalMemory"]


def _grown(a: np.ndarray, n: int, fill: float) -> np.ndarray:
    out = np.full((n,) + a.shape[1:], fill, dtype=a.dtype)
    out[: a.shape[0]] = a
    return out


class TemporalMemory:
    """BAMI Temporal Memory over ``columns * cells_per_column`` cells (Table 3.3 / Table 5.1)."""

    _SEG_ARRAYS = ("seg_cell", "seg_nsyn", "seg_nslots", "seg_last", "seg_blk", "seg_free",
                   "seg_stamp", "seg_nconn", "seg_npot", "touched", "act_list", "match_list")
    _STATE = _SEG_ARRAYS + ("meta", "rs", "cell_nseg", "blk_seg", "blk_free", "syn_pre", "syn_perm",
                            "pl_head", "pl_tail", "pl_count", "pb_ref", "pb_next", "pb_free",
                            "prev_active", "prev_winner")

    def __init__(self, columns: int, cells_per_column: int, activation_threshold: int,
                 min_threshold: int, initial_permanence: float, connected_permanence: float,
                 permanence_increment: float, permanence_decrement: float,
                 predicted_segment_decrement: float, max_new_synapse_count: int,
                 max_segments_per_cell: int, max_synapses_per_segment: int, seed: int, max_synapses: int = 0):
        self.columns = int(columns)
        self.cpc = int(cells_per_column)
        self.num_cells = self.columns * self.cpc
        self.act_thr = int(activation_threshold)
        self.min_thr = int(min_threshold)
        self.perm0 = float(initial_permanence)
        self.connected = float(connected_permanence)
        self.inc = float(permanence_increment)
        self.dec = float(permanence_decrement)
        self.pred_dec = float(predicted_segment_decrement)
        self.max_new = int(max_new_synapse_count)
        self.max_seg_per_cell = int(max_segments_per_cell)
        self.max_syn = int(max_synapses_per_segment)
        self.max_synapses = int(max_synapses)
        if self.max_synapses < 0:
            raise ValueError(f"TM max_synapses must be >= 0 (0: no budget), got {max_synapses}")
        self.max_blocks = (self.max_syn + SBLK - 1) // SBLK
        n = self.num_cells
        g0, b0, p0 = 1024, 2048, 4096
        self.meta = np.zeros(M_LEN, np.int64)
        seed_rng = np.random.Generator(np.random.PCG64(seed))
        self.rs = np.array([seed_rng.integers(1, 2**63, dtype=np.int64)], np.int64).view(np.uint64)
        self.seg_cell = np.full(g0, -1, np.int32)
        self.seg_nsyn = np.zeros(g0, np.int32)
        self.seg_nslots = np.zeros(g0, np.int32)
        self.seg_last = np.zeros(g0, np.int64)
        self.seg_blk = np.full((g0, self.max_blocks), -1, np.int32)
        self.seg_free = np.zeros(g0, np.int32)
        self.seg_stamp = np.zeros(g0, np.int64)
        self.seg_nconn = np.zeros(g0, np.int32)
        self.seg_npot = np.zeros(g0, np.int32)
        self.touched = np.zeros(g0, np.int32)
        self.act_list = np.zeros(g0, np.int32)
        self.match_list = np.zeros(g0, np.int32)
        self.cell_nseg = np.zeros(n, np.int32)
        self.blk_seg = np.full(b0, -1, np.int32)
        self.blk_free = np.zeros(b0, np.int32)
        self.syn_pre = np.full(b0 * SBLK, -1, np.int32)
        self.syn_perm = np.zeros(b0 * SBLK, np.float32)
        self.pl_head = np.full(n, -1, np.int32)
        self.pl_tail = np.full(n, -1, np.int32)
        self.pl_count = np.zeros(n, np.int32)
        self.pb_ref = np.zeros(p0 * PBLK, np.int32)
        self.pb_next = np.full(p0, -1, np.int32)
        self.pb_free = np.zeros(p0, np.int32)
        self.prev_active = np.zeros(n, np.int32)
        self.prev_winner = np.zeros(n, np.int32)        # predicted columns can have several winners
        self._prev_flag = np.zeros(n, np.bool_)
        self._mark = np.zeros(n, np.bool_)
        self._out_active = np.zeros(n, np.int32)
        self._out_winner = np.zeros(n, np.int32)
        self._out_pred = np.zeros(n, np.int32)
        self.active_cells = np.zeros(0, np.int32)
        self.winner_cells = np.zeros(0, np.int32)
        self.anomaly = 0.0

    # ---- capacity -------------------------------------------------------------------
    def _ensure_capacity(self, n_active_cols: int) -> None:
        """Grow arrays so that one step cannot run out of segments, blocks or index blocks."""
        m = self.meta
        n_learn = int(m[M_NACT]) + n_active_cols          # segments that may learn this step
        new_syn = n_learn * self.max_new
        g_need = int(m[M_SEG_TOP]) + n_active_cols
        b_need = int(m[M_BLK_TOP]) + n_learn * (self.max_new // SBLK + 2)
        p_need = int(m[M_PB_TOP]) + new_syn
        gcap = self.seg_cell.shape[0]
        if g_need > gcap:
            new = max(2 * gcap, g_need)
            for name, fill in (("seg_cell", -1), ("seg_nsyn", 0), ("seg_nslots", 0), ("seg_last", 0),
                               ("seg_blk", -1), ("seg_free", 0), ("seg_stamp", 0), ("seg_nconn", 0),
                               ("seg_npot", 0), ("touched", 0), ("act_list", 0), ("match_list", 0)):
                setattr(self, name, _grown(getattr(self, name), new, fill))
        bcap = self.blk_seg.shape[0]
        if b_need > bcap:
            new = max(2 * bcap, b_need)
            self.blk_seg = _grown(self.blk_seg, new, -1)
            self.blk_free = _grown(self.blk_free, new, 0)
            self.syn_pre = _grown(self.syn_pre, new * SBLK, -1)
            self.syn_perm = _grown(self.syn_perm, new * SBLK, 0.0)
        pcap = self.pb_next.shape[0]
        if p_need > pcap:
            new = max(2 * pcap, p_need)
            self.pb_next = _grown(self.pb_next, new, -1)
            self.pb_free = _grown(self.pb_free, new, 0)
            self.pb_ref = _grown(self.pb_ref, new * PBLK, 0)

    # ---- step -----------------------------------------------------------------------
    def compute(self, active_columns: np.ndarray, learn: bool = True) -> np.ndarray:
        """Run one step on the sorted active columns; returns the winner cells (sorted int32)."""
        cols = np.ascontiguousarray(active_columns, dtype=np.int32)
        if cols.size and (cols[0] < 0 or cols[-1] >= self.columns or np.any(np.diff(cols) <= 0)):
            raise ValueError(f"TM active columns must be sorted, unique and in [0, {self.columns})")
        self._ensure_capacity(cols.size)
        par = (self.cpc, self.act_thr, self.min_thr, self.perm0, self.connected, self.inc, self.dec,
               self.pred_dec, self.max_new, self.max_seg_per_cell, self.max_syn, self.max_synapses)
        seg = (self.seg_cell, self.seg_nsyn, self.seg_nslots, self.seg_last, self.seg_blk, self.seg_free,
               self.seg_stamp, self.seg_nconn, self.seg_npot, self.cell_nseg)
        syn = (self.blk_seg, self.blk_free, self.syn_pre, self.syn_perm)
        pl = (self.pl_head, self.pl_tail, self.pl_count, self.pb_ref, self.pb_next, self.pb_free)
        prev = (self.prev_active, self.prev_winner, self._prev_flag, self._mark)
        na, nw, npc = _tm_step(cols, bool(learn), par, seg, syn, pl, prev, self.meta, self.rs, self.touched,
                               self.act_list, self.match_list, self._out_active, self._out_winner,
                               self._out_pred)
        self.active_cells = self._out_active[:na].copy()
        self.winner_cells = np.sort(self._out_winner[:nw])
        self.anomaly = 1.0 - npc / cols.size if cols.size else 0.0
        return self.winner_cells

    @property
    def predictive_cells(self) -> np.ndarray:
        """Cells predicted for the next step (sorted int32)."""
        return self._out_pred[: int(self.meta[M_NPRED])].copy()

    @property
    def num_segments(self) -> int:
        return int(self.meta[M_SEG_TOP] - self.meta[M_SEG_FREE])

    @property
    def evicted(self) -> int:
        """Segments the synapse budget (``max_synapses``) has evicted so far."""
        return int(self.meta[M_EVICTED])

    @property
    def num_synapses(self) -> int:
        return int(self.meta[M_NSYN])

    def reset(self) -> None:
        """Forget the sequence context (no previous active/winner cells, no predictions)."""
        self.meta[[M_NACT, M_NMATCH, M_NPREV_ACTIVE, M_NPREV_WINNER, M_NPRED]] = 0

    # ---- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self._STATE}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        if st["cell_nseg"].shape[0] != self.num_cells or st["seg_blk"].shape[1] != self.max_blocks:
            raise ValueError("TM state does not match the configuration (cells or maxSynapsesPerSegment)")
        for name in self._STATE:
            setattr(self, name, np.array(st[name], dtype=getattr(self, name).dtype))
        if self.meta.size < M_LEN:   # saved before the synapse budget's counters existed
            self.meta = np.concatenate([self.meta, np.zeros(M_LEN - self.meta.size, np.int64)])
            self.meta[M_NSYN] = self.pl_count.sum()
        self._out_pred[: int(self.meta[M_NPRED])] = 0
        self._recompute_predictive()

    def _recompute_predictive(self) -> None:
        n = int(self.meta[M_NACT])
        cells = np.unique(self.seg_cell[self.act_list[:n]])
        self._out_pred[: cells.size] = cells
        self.meta[M_NPRED] = cells.size
