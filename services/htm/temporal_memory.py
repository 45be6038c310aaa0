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
from numba import njit

__all__ = ["TemporalMemory"]

SBLK = 32   # synapse slots per segment block
PBLK = 16   # entries per presynaptic-index block

# indices into the int64 ``meta`` array
M_SEG_TOP, M_SEG_FREE, M_BLK_TOP, M_BLK_FREE, M_PB_TOP, M_PB_FREE = 0, 1, 2, 3, 4, 5
M_ITER, M_NACT, M_NMATCH, M_NPREV_ACTIVE, M_NPREV_WINNER, M_NPRED = 6, 7, 8, 9, 10, 11
M_LEN = 12


# --------------------------------------------------------------------------- random numbers
@njit(cache=True)
def _rand_u64(rs: np.ndarray) -> np.uint64:
    x = rs[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    rs[0] = x
    return x * np.uint64(2685821657736338717)


@njit(cache=True)
def _rand_below(rs: np.ndarray, n: int) -> int:
    return int((_rand_u64(rs) >> np.uint64(11)) % np.uint64(n))


# --------------------------------------------------------------------------- presynaptic index
@njit(cache=True)
def _pl_append(p, ref, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta):
    cnt = pl_count[p]
    if cnt % PBLK == 0:
        if meta[M_PB_FREE] > 0:
            meta[M_PB_FREE] -= 1
            b = pb_free[meta[M_PB_FREE]]
        else:
            b = meta[M_PB_TOP]
            meta[M_PB_TOP] += 1
        pb_next[b] = -1
        if pl_head[p] == -1:
            pl_head[p] = b
        else:
            pb_next[pl_tail[p]] = b
        pl_tail[p] = b
    pb_ref[pl_tail[p] * PBLK + cnt % PBLK] = ref
    pl_count[p] = cnt + 1


@njit(cache=True)
def _pl_remove(p, ref, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta):
    cnt = pl_count[p]
    b = pl_head[p]
    pos = -1
    k = 0
    while b != -1 and pos < 0:
        lim = min(PBLK, cnt - k)
        for j in range(lim):
            if pb_ref[b * PBLK + j] == ref:
                pos = b * PBLK + j
                break
        k += PBLK
        b = pb_next[b]
    if pos < 0:
        raise RuntimeError("temporal memory: presynaptic index lost a synapse")
    last = pl_tail[p] * PBLK + (cnt - 1) % PBLK
    pb_ref[pos] = pb_ref[last]
    cnt -= 1
    pl_count[p] = cnt
    if cnt % PBLK == 0:
        # the tail block is empty now: free it and find the new tail
        pb_free[meta[M_PB_FREE]] = pl_tail[p]
        meta[M_PB_FREE] += 1
        if cnt == 0:
            pl_head[p] = -1
            pl_tail[p] = -1
        else:
            b = pl_head[p]
            for _ in range(cnt // PBLK - 1):
                b = pb_next[b]
            pb_next[b] = -1
            pl_tail[p] = b


# --------------------------------------------------------------------------- synapses/segments
@njit(cache=True)
def _destroy_synapse(g, slot, seg_nsyn, syn_pre, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                     pb_free, meta):
    p = syn_pre[slot]
    _pl_remove(p, slot, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta)
    syn_pre[slot] = -1
    seg_nsyn[g] -= 1


@njit(cache=True)
def _slot_id(seg_blk, g, j):
    return seg_blk[g, j // SBLK] * SBLK + j % SBLK


@njit(cache=True)
def _add_synapse(g, pre, perm0, seg_nsyn, seg_nslots, seg_blk, blk_seg, blk_free, syn_pre, syn_perm,
                 pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta):
    n = seg_nslots[g]
    slot = -1
    if seg_nsyn[g] < n:
        for j in range(n):
            s = _slot_id(seg_blk, g, j)
            if syn_pre[s] == -1:
                slot = s
                break
    if slot == -1:
        if n % SBLK == 0:
            if meta[M_BLK_FREE] > 0:
                meta[M_BLK_FREE] -= 1
                b = blk_free[meta[M_BLK_FREE]]
            else:
                b = meta[M_BLK_TOP]
                meta[M_BLK_TOP] += 1
            blk_seg[b] = g
            syn_pre[b * SBLK:(b + 1) * SBLK] = -1
            seg_blk[g, n // SBLK] = b
        slot = _slot_id(seg_blk, g, n)
        seg_nslots[g] = n + 1
    syn_pre[slot] = pre
    syn_perm[slot] = perm0
    seg_nsyn[g] += 1
    _pl_append(pre, slot, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta)


@njit(cache=True)
def _destroy_segment(g, seg_cell, seg_nsyn, seg_nslots, seg_blk, blk_free, cell_nseg, seg_free,
                     syn_pre, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta):
    n = seg_nslots[g]
    for j in range(n):
        s = _slot_id(seg_blk, g, j)
        if syn_pre[s] != -1:
            _destroy_synapse(g, s, seg_nsyn, syn_pre, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                             pb_free, meta)
    for bi in range((n + SBLK - 1) // SBLK):
        blk_free[meta[M_BLK_FREE]] = seg_blk[g, bi]
        meta[M_BLK_FREE] += 1
        seg_blk[g, bi] = -1
    seg_nslots[g] = 0
    cell_nseg[seg_cell[g]] -= 1
    seg_cell[g] = -1
    seg_free[meta[M_SEG_FREE]] = g
    meta[M_SEG_FREE] += 1


@njit(cache=True)
def _adapt_segment(g, prev_flag, inc, dec, seg_nsyn, seg_nslots, seg_blk, syn_pre, syn_perm,
                   pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta):
    """BAMI adaptation: +inc on synapses from previously active cells, -dec on the others."""
    for j in range(seg_nslots[g]):
        s = _slot_id(seg_blk, g, j)
        p = syn_pre[s]
        if p == -1:
            continue
        v = syn_perm[s] + (inc if prev_flag[p] else -dec)
        if v > 1.0:
            v = 1.0
        if v < 1e-6:
            _destroy_synapse(g, s, seg_nsyn, syn_pre, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                             pb_free, meta)
        else:
            syn_perm[s] = v


@njit(cache=True)
def _grow_synapses(g, n_desired, prev_winners, n_prev_winners, max_syn, perm0, mark, rs,
                   seg_nsyn, seg_nslots, seg_blk, blk_seg, blk_free, syn_pre, syn_perm,
                   pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta):
    """Grow up to ``n_desired`` synapses from previous winners not yet on the segment."""
    if n_desired <= 0 or n_prev_winners == 0:
        return
    ns = seg_nslots[g]
    for j in range(ns):
        s = _slot_id(seg_blk, g, j)
        if syn_pre[s] != -1:
            mark[syn_pre[s]] = True
    cand = np.empty(n_prev_winners, np.int32)
    nc = 0
    for i in range(n_prev_winners):
        c = prev_winners[i]
        if not mark[c]:
            cand[nc] = c
            nc += 1
    for j in range(ns):
        s = _slot_id(seg_blk, g, j)
        if syn_pre[s] != -1:
            mark[syn_pre[s]] = False
    n = min(n_desired, nc)
    if n <= 0:
        return
    # make room: destroy the weakest synapses beyond maxSynapsesPerSegment
    overflow = seg_nsyn[g] + n - max_syn
    while overflow > 0:
        worst = -1
        wv = 2.0
        for j in range(seg_nslots[g]):
            s = _slot_id(seg_blk, g, j)
            if syn_pre[s] != -1 and syn_perm[s] < wv:
                wv = syn_perm[s]
                worst = s
        _destroy_synapse(g, worst, seg_nsyn, syn_pre, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                         pb_free, meta)
        overflow -= 1
    # sample n candidates without replacement (partial Fisher-Yates)
    for i in range(n):
        r = i + _rand_below(rs, nc - i)
        tmp = cand[i]
        cand[i] = cand[r]
        cand[r] = tmp
        _add_synapse(g, cand[i], perm0, seg_nsyn, seg_nslots, seg_blk, blk_seg, blk_free, syn_pre,
                     syn_perm, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta)


@njit(cache=True)
def _tm_step(active_cols, learn, cpc, act_thr, min_thr, perm0, connected, inc, dec, pred_dec,
             max_new, max_seg_per_cell, max_syn,
             meta, rs, seg_cell, seg_nsyn, seg_nslots, seg_last, seg_blk, seg_free,
             seg_stamp, seg_nconn, seg_npot, touched, act_list, match_list,
             cell_nseg, blk_seg, blk_free, syn_pre, syn_perm,
             pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free,
             prev_active, prev_winner, prev_flag, mark, out_active, out_winner, out_pred):
    """One Temporal Memory step; returns (n_active_cells, n_winner_cells, n_predicted_cols)."""
    it = meta[M_ITER] + 1
    meta[M_ITER] = it
    n_prev_active = meta[M_NPREV_ACTIVE]
    n_prev_winner = meta[M_NPREV_WINNER]
    nact = meta[M_NACT]
    nmatch = meta[M_NMATCH]
    for i in range(n_prev_active):
        prev_flag[prev_active[i]] = True

    ncols_act = active_cols.shape[0]
    # 3. punish matching segments of inactive columns (before any segment id is reused)
    if learn and pred_dec > 0.0:
        ai = 0
        for mi in range(nmatch):
            g = match_list[mi]
            col = seg_cell[g] // cpc
            while ai < ncols_act and active_cols[ai] < col:
                ai += 1
            if ai < ncols_act and active_cols[ai] == col:
                continue
            _adapt_segment(g, prev_flag, -pred_dec, 0.0, seg_nsyn, seg_nslots, seg_blk, syn_pre,
                           syn_perm, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta)
            if seg_nsyn[g] == 0:
                _destroy_segment(g, seg_cell, seg_nsyn, seg_nslots, seg_blk, blk_free, cell_nseg,
                                 seg_free, syn_pre, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                                 pb_free, meta)

    n_out_act = 0
    n_out_win = 0
    n_pred_cols = 0
    ia = 0   # cursor in act_list (sorted by cell)
    im = 0   # cursor in match_list (sorted by cell)
    for ci in range(ncols_act):
        col = active_cols[ci]
        lo = col * cpc
        hi = lo + cpc
        while ia < nact and seg_cell[act_list[ia]] < lo:
            ia += 1
        while im < nmatch and seg_cell[match_list[im]] < lo:
            im += 1
        a_end = ia
        while a_end < nact and seg_cell[act_list[a_end]] < hi:
            a_end += 1
        m_end = im
        while m_end < nmatch and seg_cell[match_list[m_end]] < hi:
            m_end += 1
        if a_end > ia:
            # 1. correctly predicted column
            n_pred_cols += 1
            last_cell = -1
            for k in range(ia, a_end):
                g = act_list[k]
                cell = seg_cell[g]
                if cell != last_cell:
                    out_active[n_out_act] = cell
                    n_out_act += 1
                    out_winner[n_out_win] = cell
                    n_out_win += 1
                    last_cell = cell
                if learn:
                    _adapt_segment(g, prev_flag, inc, dec, seg_nsyn, seg_nslots, seg_blk, syn_pre,
                                   syn_perm, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free,
                                   meta)
                    _grow_synapses(g, max_new - seg_npot[g], prev_winner, n_prev_winner, max_syn,
                                   perm0, mark, rs, seg_nsyn, seg_nslots, seg_blk, blk_seg, blk_free,
                                   syn_pre, syn_perm, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                                   pb_free, meta)
                    seg_last[g] = it
                    if seg_nsyn[g] == 0:
                        _destroy_segment(g, seg_cell, seg_nsyn, seg_nslots, seg_blk, blk_free,
                                         cell_nseg, seg_free, syn_pre, pl_head, pl_tail, pl_count,
                                         pb_ref, pb_next, pb_free, meta)
        else:
            # 2. bursting column
            for cell in range(lo, hi):
                out_active[n_out_act] = cell
                n_out_act += 1
            if m_end > im:
                best = match_list[im]
                for k in range(im + 1, m_end):
                    if seg_npot[match_list[k]] > seg_npot[best]:
                        best = match_list[k]
                winner = seg_cell[best]
                if learn:
                    _adapt_segment(best, prev_flag, inc, dec, seg_nsyn, seg_nslots, seg_blk,
                                   syn_pre, syn_perm, pl_head, pl_tail, pl_count, pb_ref, pb_next,
                                   pb_free, meta)
                    _grow_synapses(best, max_new - seg_npot[best], prev_winner, n_prev_winner,
                                   max_syn, perm0, mark, rs, seg_nsyn, seg_nslots, seg_blk, blk_seg,
                                   blk_free, syn_pre, syn_perm, pl_head, pl_tail, pl_count, pb_ref,
                                   pb_next, pb_free, meta)
                    seg_last[best] = it
                    if seg_nsyn[best] == 0:
                        _destroy_segment(best, seg_cell, seg_nsyn, seg_nslots, seg_blk, blk_free,
                                         cell_nseg, seg_free, syn_pre, pl_head, pl_tail, pl_count,
                                         pb_ref, pb_next, pb_free, meta)
            else:
                # least used cell, random tie
                fewest = cell_nseg[lo]
                for cell in range(lo + 1, hi):
                    if cell_nseg[cell] < fewest:
                        fewest = cell_nseg[cell]
                nties = 0
                for cell in range(lo, hi):
                    if cell_nseg[cell] == fewest:
                        nties += 1
                pick = _rand_below(rs, nties)
                winner = lo
                for cell in range(lo, hi):
                    if cell_nseg[cell] == fewest:
                        if pick == 0:
                            winner = cell
                            break
                        pick -= 1
                if learn and n_prev_winner > 0:
                    if cell_nseg[winner] >= max_seg_per_cell:
                        # evict the least recently used segment of this cell
                        lru = -1
                        for g in range(meta[M_SEG_TOP]):
                            if seg_cell[g] == winner and (lru == -1 or seg_last[g] < seg_last[lru]):
                                lru = g
                        _destroy_segment(lru, seg_cell, seg_nsyn, seg_nslots, seg_blk, blk_free,
                                         cell_nseg, seg_free, syn_pre, pl_head, pl_tail, pl_count,
                                         pb_ref, pb_next, pb_free, meta)
                    if meta[M_SEG_FREE] > 0:
                        meta[M_SEG_FREE] -= 1
                        g = seg_free[meta[M_SEG_FREE]]
                    else:
                        g = meta[M_SEG_TOP]
                        meta[M_SEG_TOP] += 1
                    seg_cell[g] = winner
                    seg_nsyn[g] = 0
                    seg_nslots[g] = 0
                    seg_last[g] = it
                    seg_stamp[g] = 0
                    cell_nseg[winner] += 1
                    _grow_synapses(g, max_new, prev_winner, n_prev_winner, max_syn, perm0, mark, rs,
                                   seg_nsyn, seg_nslots, seg_blk, blk_seg, blk_free, syn_pre,
                                   syn_perm, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free,
                                   meta)
            out_winner[n_out_win] = winner
            n_out_win += 1
        ia = a_end
        im = m_end

    for i in range(n_prev_active):
        prev_flag[prev_active[i]] = False

    # 4. segment activity from the new active cells (presynaptic index walk)
    nt = 0
    for i in range(n_out_act):
        p = out_active[i]
        b = pl_head[p]
        rem = pl_count[p]
        while b != -1:
            lim = min(PBLK, rem)
            for j in range(lim):
                s = pb_ref[b * PBLK + j]
                g = blk_seg[s // SBLK]
                if seg_stamp[g] != it:
                    seg_stamp[g] = it
                    seg_nconn[g] = 0
                    seg_npot[g] = 0
                    touched[nt] = g
                    nt += 1
                seg_npot[g] += 1
                if syn_perm[s] >= connected:
                    seg_nconn[g] += 1
            rem -= PBLK
            b = pb_next[b]
    na = 0
    nm = 0
    keys_a = np.empty(nt, np.int64)
    keys_m = np.empty(nt, np.int64)
    gcap = seg_cell.shape[0]
    for i in range(nt):
        g = touched[i]
        if seg_nconn[g] >= act_thr:
            keys_a[na] = seg_cell[g] * np.int64(gcap) + g
            na += 1
        if seg_npot[g] >= min_thr:
            keys_m[nm] = seg_cell[g] * np.int64(gcap) + g
            nm += 1
    keys_a = np.sort(keys_a[:na])
    keys_m = np.sort(keys_m[:nm])
    npred = 0
    last = -1
    for i in range(na):
        g = keys_a[i] % gcap
        act_list[i] = g
        cell = seg_cell[g]
        if cell != last:
            out_pred[npred] = cell
            npred += 1
            last = cell
    for i in range(nm):
        match_list[i] = keys_m[i] % gcap
    meta[M_NACT] = na
    meta[M_NMATCH] = nm
    meta[M_NPRED] = npred
    prev_active[:n_out_act] = out_active[:n_out_act]
    prev_winner[:n_out_win] = out_winner[:n_out_win]
    meta[M_NPREV_ACTIVE] = n_out_act
    meta[M_NPREV_WINNER] = n_out_win
    return n_out_act, n_out_win, n_pred_cols


def _grown(a: np.ndarray, n: int, fill) -> np.ndarray:
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
                 max_segments_per_cell: int, max_synapses_per_segment: int, seed: int):
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
        na, nw, npc = _tm_step(
            cols, bool(learn), self.cpc, self.act_thr, self.min_thr, self.perm0, self.connected,
            self.inc, self.dec, self.pred_dec, self.max_new, self.max_seg_per_cell, self.max_syn,
            self.meta, self.rs, self.seg_cell, self.seg_nsyn, self.seg_nslots, self.seg_last,
            self.seg_blk, self.seg_free, self.seg_stamp, self.seg_nconn, self.seg_npot, self.touched,
            self.act_list, self.match_list, self.cell_nseg, self.blk_seg, self.blk_free,
            self.syn_pre, self.syn_perm, self.pl_head, self.pl_tail, self.pl_count, self.pb_ref,
            self.pb_next, self.pb_free, self.prev_active, self.prev_winner, self._prev_flag,
            self._mark, self._out_active, self._out_winner, self._out_pred)
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
    def num_synapses(self) -> int:
        return int(self.pl_count.sum())

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
        self._out_pred[: int(self.meta[M_NPRED])] = 0
        self._recompute_predictive()

    def _recompute_predictive(self) -> None:
        n = int(self.meta[M_NACT])
        cells = np.unique(self.seg_cell[self.act_list[:n]])
        self._out_pred[: cells.size] = cells
        self.meta[M_NPRED] = cells.size
