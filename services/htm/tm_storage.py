"""Storage kernels of the Temporal Memory (:mod:`services.htm.temporal_memory` states the
data layout): the xorshift64* generator, the presynaptic index (chains of ``PBLK``-entry
blocks per cell), and synapse and segment bookkeeping (blocks of ``SBLK`` slots per segment),
with the ``meta`` indices and the array types the step kernels of
:mod:`services.htm.tm_kernels` share.  Plain numba functions over flat arrays."""
from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numba import njit
from numpy.typing import NDArray

SBLK = 32   # synapse slots per segment block
PBLK = 16   # entries per presynaptic-index block

# indices into the int64 ``meta`` array
M_SEG_TOP, M_SEG_FREE, M_BLK_TOP, M_BLK_FREE, M_PB_TOP, M_PB_FREE = 0, 1, 2, 3, 4, 5
M_ITER, M_NACT, M_NMATCH, M_NPREV_ACTIVE, M_NPREV_WINNER, M_NPRED = 6, 7, 8, 9, 10, 11
M_EVICTED = 12   # segments the synapse budget evicted
M_NSYN = 13      # live synapses
M_LEN = 14
EVICT_SAMPLES = 32   # segments drawn per eviction of the synapse budget

# array types of the kernels (numba compiles from the values; these are for the type checker)
I32: TypeAlias = NDArray[np.int32]
I64: TypeAlias = NDArray[np.int64]
F32: TypeAlias = NDArray[np.float32]
Flags: TypeAlias = NDArray[np.bool_]
RngState: TypeAlias = NDArray[np.uint64]
SegArrays: TypeAlias = tuple[I32, I32, I32, I64, I32, I32, I64, I32, I32, I32]
SynArrays: TypeAlias = tuple[I32, I32, I32, F32]
PlArrays: TypeAlias = tuple[I32, I32, I32, I32, I32, I32]
PrevArrays: TypeAlias = tuple[I32, I32, Flags, Flags]
Params: TypeAlias = tuple[int, int, int, float, float, float, float, float, int, int, int, int]


# --------------------------------------------------------------------------- random numbers
@njit(cache=True)
def _rand_u64(rs: RngState) -> np.uint64:
    x: np.uint64 = rs[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    rs[0] = x
    return x * np.uint64(2685821657736338717)


@njit(cache=True)
def _rand_below(rs: RngState, n: int) -> int:
    return int((_rand_u64(rs) >> np.uint64(11)) % np.uint64(n))


# --------------------------------------------------------------------------- presynaptic index
@njit(cache=True)
def _pl_append(p: int, ref: int, pl_head: I32, pl_tail: I32, pl_count: I32, pb_ref: I32, pb_next: I32,
               pb_free: I32, meta: I64) -> None:
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
def _pl_remove(p: int, ref: int, pl_head: I32, pl_tail: I32, pl_count: I32, pb_ref: I32, pb_next: I32,
               pb_free: I32, meta: I64) -> None:
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
def _destroy_synapse(g: int, slot: int, seg_nsyn: I32, syn_pre: I32, pl_head: I32, pl_tail: I32,
                     pl_count: I32, pb_ref: I32, pb_next: I32, pb_free: I32, meta: I64) -> None:
    p = syn_pre[slot]
    _pl_remove(p, slot, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta)
    syn_pre[slot] = -1
    seg_nsyn[g] -= 1
    meta[M_NSYN] -= 1


@njit(cache=True)
def _slot_id(seg_blk: I32, g: int, j: int) -> int:
    b: int = seg_blk[g, j // SBLK]
    return b * SBLK + j % SBLK


@njit(cache=True)
def _add_synapse(g: int, pre: int, perm0: float, seg_nsyn: I32, seg_nslots: I32, seg_blk: I32, blk_seg: I32,
                 blk_free: I32, syn_pre: I32, syn_perm: F32, pl_head: I32, pl_tail: I32, pl_count: I32,
                 pb_ref: I32, pb_next: I32, pb_free: I32, meta: I64) -> None:
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
    meta[M_NSYN] += 1
    _pl_append(pre, slot, pl_head, pl_tail, pl_count, pb_ref, pb_next, pb_free, meta)


@njit(cache=True)
def _destroy_segment(g: int, seg_cell: I32, seg_nsyn: I32, seg_nslots: I32, seg_blk: I32, blk_free: I32,
                     cell_nseg: I32, seg_free: I32, syn_pre: I32, pl_head: I32, pl_tail: I32, pl_count: I32,
                     pb_ref: I32, pb_next: I32, pb_free: I32, meta: I64) -> None:
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
def _adapt_segment(g: int, prev_flag: Flags, inc: float, dec: float, seg_nsyn: I32, seg_nslots: I32,
                   seg_blk: I32, syn_pre: I32, syn_perm: F32, pl_head: I32, pl_tail: I32, pl_count: I32,
                   pb_ref: I32, pb_next: I32, pb_free: I32, meta: I64) -> None:
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
def _grow_synapses(g: int, n_desired: int, prev_winners: I32, n_prev_winners: int, max_syn: int, perm0: float,
                   mark: Flags, rs: RngState, seg_nsyn: I32, seg_nslots: I32, seg_blk: I32, blk_seg: I32,
                   blk_free: I32, syn_pre: I32, syn_perm: F32, pl_head: I32, pl_tail: I32, pl_count: I32,
                   pb_ref: I32, pb_next: I32, pb_free: I32, meta: I64) -> None:
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

