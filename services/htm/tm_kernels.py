"""Step kernels of the Temporal Memory (:mod:`services.htm.temporal_memory` states the
algorithm and the data layout): one step in the phases of the BAMI pseudocode --
``punishPredictedColumn``, ``activatePredictedColumn``, ``burstColumn``,
``activateDendrites`` -- over the storage kernels of :mod:`services.htm.tm_storage`.  Plain
functions over flat arrays; the class in :mod:`services.htm.temporal_memory` owns the arrays."""
from __future__ import annotations

import numpy as np
from numba import njit

from services.htm.tm_storage import (
    EVICT_SAMPLES,
    I32,
    I64,
    M_EVICTED,
    M_ITER,
    M_NACT,
    M_NMATCH,
    M_NPRED,
    M_NPREV_ACTIVE,
    M_NPREV_WINNER,
    M_NSYN,
    M_SEG_FREE,
    M_SEG_TOP,
    PBLK,
    SBLK,
    Params,
    PlArrays,
    PrevArrays,
    RngState,
    SegArrays,
    SynArrays,
    _adapt_segment,
    _destroy_segment,
    _grow_synapses,
    _rand_below,
)


# Bundles passed to the phases (numba tuples of arrays; every phase reads what it needs):
#   seg   = (seg_cell, seg_nsyn, seg_nslots, seg_last, seg_blk, seg_free, seg_stamp, seg_nconn,
#            seg_npot, cell_nseg)                          -- per segment / per cell
#   syn   = (blk_seg, blk_free, syn_pre, syn_perm)        -- synapse blocks and slots
#   pl    = (pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free)   -- presynaptic index
#   par   = (cpc, act_thr, min_thr, perm0, connected, inc, dec, pred_dec, max_new,
#            max_seg_per_cell, max_syn, max_synapses)     -- the configuration (max_synapses 0: no budget)
#   prev  = (prev_active, prev_winner, prev_flag, mark)   -- the previous step's cells
@njit(cache=True)
def _destroy(g: int, seg: SegArrays, syn: SynArrays, pl: PlArrays, meta: I64) -> None:
    _destroy_segment(g, seg[0], seg[1], seg[2], seg[4], syn[1], seg[9], seg[5], syn[2],
                     pl[0], pl[1], pl[2], pl[3], pl[4], pl[5], meta)


@njit(cache=True)
def _learn_on_segment(g: int, n_new: int, it: int, seg: SegArrays, syn: SynArrays, pl: PlArrays, par: Params,
                      prev: PrevArrays, n_prev_winner: int, rs: RngState, meta: I64) -> None:
    """Reinforce segment g on the previous active cells, grow up to ``n_new`` synapses to the
    previous winners, mark it used at step ``it``; destroy it if it lost every synapse."""
    _adapt_segment(g, prev[2], par[5], par[6], seg[1], seg[2], seg[4], syn[2], syn[3],
                   pl[0], pl[1], pl[2], pl[3], pl[4], pl[5], meta)
    _grow_synapses(g, n_new, prev[1], n_prev_winner, par[10], par[3], prev[3], rs, seg[1], seg[2],
                   seg[4], syn[0], syn[1], syn[2], syn[3], pl[0], pl[1], pl[2], pl[3], pl[4], pl[5],
                   meta)
    seg[3][g] = it
    if seg[1][g] == 0:
        _destroy(g, seg, syn, pl, meta)


@njit(cache=True)
def _punish_inactive_columns(active_cols: I32, match_list: I32, nmatch: int, seg: SegArrays, syn: SynArrays,
                             pl: PlArrays, par: Params, prev: PrevArrays, meta: I64) -> None:
    """Phase 3 (BAMI ``punishPredictedColumn``): matching segments of inactive columns lose
    ``predictedSegmentDecrement`` on their synapses from the previous active cells."""
    ncols_act = active_cols.shape[0]
    ai = 0
    for mi in range(nmatch):
        g = match_list[mi]
        col = seg[0][g] // par[0]
        while ai < ncols_act and active_cols[ai] < col:
            ai += 1
        if ai < ncols_act and active_cols[ai] == col:
            continue
        _adapt_segment(g, prev[2], -par[7], 0.0, seg[1], seg[2], seg[4], syn[2], syn[3],
                       pl[0], pl[1], pl[2], pl[3], pl[4], pl[5], meta)
        if seg[1][g] == 0:
            _destroy(g, seg, syn, pl, meta)


@njit(cache=True)
def _activate_predicted_column(act_list: I32, a_lo: int, a_hi: int, learn: bool, it: int, seg: SegArrays,
                               syn: SynArrays, pl: PlArrays, par: Params, prev: PrevArrays, n_prev_winner: int,
                               rs: RngState, meta: I64, out_active: I32, out_winner: I32, n_act: int,
                               n_win: int) -> tuple[int, int]:
    """Phase 1 (BAMI ``activatePredictedColumn``): the cells of the column's active segments
    become active and winners; learning reinforces those segments.  Returns the new counts."""
    last_cell = -1
    for k in range(a_lo, a_hi):
        g = act_list[k]
        cell = seg[0][g]
        if cell != last_cell:
            out_active[n_act] = cell
            n_act += 1
            out_winner[n_win] = cell
            n_win += 1
            last_cell = cell
        if learn:
            _learn_on_segment(g, par[8] - seg[8][g], it, seg, syn, pl, par, prev, n_prev_winner, rs, meta)
    return n_act, n_win


@njit(cache=True)
def _least_used_cell(lo: int, hi: int, cell_nseg: I32, rs: RngState) -> int:
    """The cell of [lo, hi) with the fewest segments, a random one among ties."""
    fewest = cell_nseg[lo]
    for cell in range(lo + 1, hi):
        if cell_nseg[cell] < fewest:
            fewest = cell_nseg[cell]
    nties = 0
    for cell in range(lo, hi):
        if cell_nseg[cell] == fewest:
            nties += 1
    pick = _rand_below(rs, nties)
    for cell in range(lo, hi):
        if cell_nseg[cell] == fewest:
            if pick == 0:
                return cell
            pick -= 1
    return lo


@njit(cache=True)
def _sampled_lru_segment(it: int, seg: SegArrays, meta: I64, rs: RngState) -> int:
    """An approximately least recently used segment: the oldest ``seg_last`` among
    ``EVICT_SAMPLES`` segments drawn at random (O(1), the sampled LRU of cache eviction), never
    one the step uses -- learnt or grown in it, or reached by the previous step's active cells
    (``seg_stamp``: the active and matching lists of this step).  -1 when the draws found none."""
    seg_cell, seg_last, seg_stamp = seg[0], seg[3], seg[6]
    top = meta[M_SEG_TOP]
    best = np.int64(-1)
    for _ in range(EVICT_SAMPLES):
        g = np.int64(_rand_below(rs, top))
        if seg_cell[g] == -1 or seg_last[g] >= it or seg_stamp[g] >= it - 1:
            continue
        if best == -1 or seg_last[g] < seg_last[best]:
            best = g
    return int(best)


@njit(cache=True)
def _enforce_synapse_budget(it: int, seg: SegArrays, syn: SynArrays, pl: PlArrays, meta: I64, rs: RngState,
                            budget: int) -> None:
    """While the memory holds more than ``budget`` synapses, destroy an approximately least
    recently used segment (:func:`_sampled_lru_segment`); stops early when the draws find none
    that may go (the next step tries again)."""
    if budget <= 0:
        return
    while meta[M_NSYN] > budget and meta[M_SEG_TOP] - meta[M_SEG_FREE] > 0:
        victim = _sampled_lru_segment(it, seg, meta, rs)
        if victim < 0:
            return
        _destroy(victim, seg, syn, pl, meta)
        meta[M_EVICTED] += 1


@njit(cache=True)
def _grow_new_segment(winner: int, it: int, seg: SegArrays, syn: SynArrays, pl: PlArrays, par: Params,
                      prev: PrevArrays, n_prev_winner: int, rs: RngState, meta: I64) -> None:
    """A new segment on ``winner`` (evicting its least recently used one when the cell is full)
    with up to ``maxNewSynapseCount`` synapses to the previous winners."""
    seg_cell, seg_last, cell_nseg = seg[0], seg[3], seg[9]
    if cell_nseg[winner] >= par[9]:
        lru = -1
        for g in range(meta[M_SEG_TOP]):
            if seg_cell[g] == winner and (lru == -1 or seg_last[g] < seg_last[lru]):
                lru = g
        _destroy(lru, seg, syn, pl, meta)
    if meta[M_SEG_FREE] > 0:
        meta[M_SEG_FREE] -= 1
        g = seg[5][meta[M_SEG_FREE]]
    else:
        g = meta[M_SEG_TOP]
        meta[M_SEG_TOP] += 1
    seg_cell[g] = winner
    seg[1][g] = 0
    seg[2][g] = 0
    seg_last[g] = it
    seg[6][g] = 0
    cell_nseg[winner] += 1
    _grow_synapses(g, par[8], prev[1], n_prev_winner, par[10], par[3], prev[3], rs, seg[1], seg[2],
                   seg[4], syn[0], syn[1], syn[2], syn[3], pl[0], pl[1], pl[2], pl[3], pl[4], pl[5],
                   meta)


@njit(cache=True)
def _burst_column(lo: int, hi: int, match_list: I32, m_lo: int, m_hi: int, learn: bool, it: int, seg: SegArrays,
                  syn: SynArrays, pl: PlArrays, par: Params, prev: PrevArrays, n_prev_winner: int, rs: RngState,
                  meta: I64, out_active: I32, n_act: int) -> tuple[int, int]:
    """Phase 2 (BAMI ``burstColumn``): every cell of [lo, hi) becomes active; the winner is the
    cell of the best matching segment (which learns) or the least used cell (which grows a new
    segment).  Returns (n_act, winner)."""
    for cell in range(lo, hi):
        out_active[n_act] = cell
        n_act += 1
    if m_hi > m_lo:
        best = match_list[m_lo]
        for k in range(m_lo + 1, m_hi):
            if seg[8][match_list[k]] > seg[8][best]:
                best = match_list[k]
        winner = seg[0][best]
        if learn:
            _learn_on_segment(best, par[8] - seg[8][best], it, seg, syn, pl, par, prev, n_prev_winner,
                              rs, meta)
    else:
        winner = _least_used_cell(lo, hi, seg[9], rs)
        if learn and n_prev_winner > 0:
            _grow_new_segment(winner, it, seg, syn, pl, par, prev, n_prev_winner, rs, meta)
    return n_act, winner


@njit(cache=True)
def _segment_span(lst: I32, n: int, start: int, bound: int, seg_cell: I32) -> int:
    """First index >= start of ``lst[:n]`` (sorted by cell) whose segment's cell is >= bound."""
    while start < n and seg_cell[lst[start]] < bound:
        start += 1
    return start


@njit(cache=True)
def _compute_activity(out_active: I32, n_act: int, it: int, seg: SegArrays, syn: SynArrays, pl: PlArrays,
                      par: Params, touched: I32, act_list: I32, match_list: I32, out_pred: I32, meta: I64) -> int:
    """Phase 4 (BAMI ``activateDendrites``): count each segment's connected and potential
    synapses from the new active cells (presynaptic index walk); active segments (>=
    ``activationThreshold`` connected) and matching ones (>= ``minThreshold`` potential), sorted
    by cell, are the next step's; their cells are the predictive cells.  Returns their number."""
    seg_cell, seg_stamp, seg_nconn, seg_npot = seg[0], seg[6], seg[7], seg[8]
    blk_seg, syn_perm = syn[0], syn[3]
    pl_head, pl_count, pb_ref, pb_next = pl[0], pl[2], pl[3], pl[4]
    nt = 0
    for i in range(n_act):
        p = out_active[i]
        b = pl_head[p]
        rem = pl_count[p]
        while b != -1:
            for j in range(min(PBLK, rem)):
                s = pb_ref[b * PBLK + j]
                g = blk_seg[s // SBLK]
                if seg_stamp[g] != it:
                    seg_stamp[g] = it
                    seg_nconn[g] = 0
                    seg_npot[g] = 0
                    touched[nt] = g
                    nt += 1
                seg_npot[g] += 1
                if syn_perm[s] >= par[4]:
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
        if seg_nconn[g] >= par[1]:
            keys_a[na] = seg_cell[g] * np.int64(gcap) + g
            na += 1
        if seg_npot[g] >= par[2]:
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
    return npred


@njit(cache=True)
def _tm_step(active_cols: I32, learn: bool, par: Params, seg: SegArrays, syn: SynArrays, pl: PlArrays,
             prev: PrevArrays, meta: I64, rs: RngState, touched: I32, act_list: I32, match_list: I32,
             out_active: I32, out_winner: I32, out_pred: I32) -> tuple[int, int, int]:
    """One Temporal Memory step (phases 3, 1/2 per active column, 4 of the module doc);
    returns (n_active_cells, n_winner_cells, n_predicted_cols)."""
    it = meta[M_ITER] + 1
    meta[M_ITER] = it
    prev_active, prev_winner, prev_flag = prev[0], prev[1], prev[2]
    n_prev_active = meta[M_NPREV_ACTIVE]
    n_prev_winner = meta[M_NPREV_WINNER]
    nact = meta[M_NACT]
    nmatch = meta[M_NMATCH]
    for i in range(n_prev_active):
        prev_flag[prev_active[i]] = True
    # punish first: before any segment id is reused by this step
    if learn and par[7] > 0.0:
        _punish_inactive_columns(active_cols, match_list, nmatch, seg, syn, pl, par, prev, meta)
    n_act = 0
    n_win = 0
    n_pred_cols = 0
    ia = 0   # cursor in act_list (sorted by cell)
    im = 0   # cursor in match_list (sorted by cell)
    cpc = par[0]
    for ci in range(active_cols.shape[0]):
        lo = active_cols[ci] * cpc
        hi = lo + cpc
        ia = _segment_span(act_list, nact, ia, lo, seg[0])
        im = _segment_span(match_list, nmatch, im, lo, seg[0])
        a_end = _segment_span(act_list, nact, ia, hi, seg[0])
        m_end = _segment_span(match_list, nmatch, im, hi, seg[0])
        if a_end > ia:
            n_pred_cols += 1
            n_act, n_win = _activate_predicted_column(act_list, ia, a_end, learn, it, seg, syn, pl, par, prev,
                                                      n_prev_winner, rs, meta, out_active, out_winner,
                                                      n_act, n_win)
        else:
            n_act, winner = _burst_column(lo, hi, match_list, im, m_end, learn, it, seg, syn, pl, par, prev,
                                          n_prev_winner, rs, meta, out_active, n_act)
            out_winner[n_win] = winner
            n_win += 1
        ia = a_end
        im = m_end
    for i in range(n_prev_active):
        prev_flag[prev_active[i]] = False
    if learn:
        _enforce_synapse_budget(it, seg, syn, pl, meta, rs, par[11])
    _compute_activity(out_active, n_act, it, seg, syn, pl, par, touched, act_list, match_list,
                      out_pred, meta)
    prev_active[:n_act] = out_active[:n_act]
    prev_winner[:n_win] = out_winner[:n_win]
    meta[M_NPREV_ACTIVE] = n_act
    meta[M_NPREV_WINNER] = n_win
    return n_act, n_win, n_pred_cols
