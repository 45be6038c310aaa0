"""Local View Cell id matcher (Section 4.2.2, Eqs. 4.6-4.10).

For the current descriptor D_t and every stored prototype D_l:
I = |D_t & D_l| (Eq. 4.6), R = I / |D_t| (Eq. 4.7); l* = argmax R (Eq. 4.8), ties broken by
the larger IoU = I / |D_t | D_l| (``lvc.iou_tiebreak``), then the lowest id. l* is
accepted iff I >= I_min and R >= tau_R (Eq. 4.9) and, with the F1 gate on,
F1 = 2 I / (|D_t| + |D_l|) >= min_f1; otherwise a new id is created with prototype D_t
(Eq. 4.10). Ids are 0, 1, 2, ... in creation order, so the first place seen is LVC 0.

The arg max is exact integer arithmetic: with a common |D_t|, a larger R is a larger I, and
for equal I a larger IoU is a smaller |D_l|. The gates compare the float64 ratios R and F1
with the thresholds, so R = 0.30 exactly passes tau_R = 0.30.

Two exact searches, the same l*: a sparse descriptor space (the TM's cells: L = 2048 x 40)
walks an inverted index bit -> prototype ids (chains of 64-entry blocks), whose cost is the sum
of the posting lengths of the query's bits; a space of at most ``PACKED_MAX_BITS`` bits (the
fused SDR, the SP's columns) keeps every prototype bit-packed and counts I by popcount over
L / 64 words per prototype.  The fused SDR has ~900 of 2048 bits on, so a query's postings
sum to ~0.4 x #LVCs x 900: at 1000 LVCs the popcount is ~15x cheaper (the default chain's budget is 1 ms per frame).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from services.htm._bits import pack_bits, popcount64

__all__ = ["LvcMatcher", "LvcResult", "overlap_scores"]

PB = 64  # postings per block
PACKED_MAX_BITS = 8192  # descriptor spaces up to this many bits are matched bit-packed

I32 = NDArray[np.int32]
I64 = NDArray[np.int64]
U64 = NDArray[np.uint64]


@dataclass(frozen=True)
class LvcResult:
    """Outcome of one match: the published id, R (rate), whether Eq. 4.10 created it, I.

    ``lvc_id`` is -1 only for query-only matching (``NeocortexHtm.step(store=False)``)
    when Eq. 4.9 rejects every candidate.

    ``best_*`` describe the best stored candidate l* before the new id was created
    (-1 / 0 when there was none) for diagnostics; ``anomaly`` is the TM anomaly of the
    step (0 when the TM did not run) and ``descriptor_bits`` = |D_t|.  With the sequence memory
    (:mod:`services.htm.sequence`): ``by_sequence`` when the id came from the sequence match,
    ``frame`` the stored frame (memory index) whose diagonal ended best, ``seq_score`` its
    score S* and ``seq_margin`` S* minus the best score ending elsewhere (z units; 0 when off).
    With the TM decision (``tm.decide``, :mod:`services.htm.tm_match`): ``by_tm`` when the id
    came from the TM's predictions, ``tm_frame`` the stored frame j* they point at and ``tm_share``
    the fraction of the frame's active columns predicted in j*'s context.
    """

    lvc_id: int
    rate: float
    is_new: bool
    intersection: int
    best_candidate: int = -1
    best_rate: float = 0.0
    best_intersection: int = 0
    descriptor_bits: int = 0
    anomaly: float = 0.0
    by_sequence: bool = False
    frame: int = -1
    seq_score: float = 0.0
    seq_margin: float = 0.0
    by_tm: bool = False
    by_prior: bool = False
    tm_frame: int = -1
    tm_share: float = 0.0


def overlap_scores(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """I, R = I/|a| (Eq. 4.7), IoU and F1 (Dice) of two active-bit sets."""
    a = np.unique(np.asarray(a))
    b = np.unique(np.asarray(b))
    i = np.intersect1d(a, b, assume_unique=True).size
    union = a.size + b.size - i
    return {
        "I": float(i),
        "R": i / a.size if a.size else 0.0,
        "IoU": i / union if union else 0.0,
        "F1": 2.0 * i / (a.size + b.size) if (a.size + b.size) else 0.0,
    }


@njit(cache=True)
def _query(bits: I32, head: I32, count: I32, pst: I32, nxt: I32, counts: I32, touched: I32) -> int:
    """Count I for every prototype sharing a bit with the query; returns how many were touched."""
    nt = 0
    for q in range(bits.shape[0]):
        b = head[bits[q]]
        rem = count[bits[q]]
        while b != -1:
            lim = min(PB, rem)
            for j in range(lim):
                pid = pst[b * PB + j]
                if counts[pid] == 0:
                    touched[nt] = pid
                    nt += 1
                counts[pid] += 1
            rem -= PB
            b = nxt[b]
    return nt


@njit(cache=True)
def _select(touched: I32, nt: int, counts: I32, proto_len: I32, iou_tiebreak: bool) -> tuple[int, int]:
    """Best touched prototype by (I desc, |D_l| asc when IoU tie-break, id asc); resets counts."""
    best = -1
    best_i = 0
    for k in range(nt):
        pid = touched[k]
        i = counts[pid]
        counts[pid] = 0
        if best == -1 or i > best_i:
            better = True
        elif i < best_i:
            better = False
        elif iou_tiebreak and proto_len[pid] != proto_len[best]:
            better = proto_len[pid] < proto_len[best]
        else:
            better = pid < best
        if better:
            best = pid
            best_i = i
    return best, best_i


@njit(cache=True)
def _best_packed(q: U64, packed: U64, proto_len: I32, n: int, iou_tiebreak: bool) -> tuple[int, int]:
    """Best prototype by (I desc, |D_l| asc when IoU tie-break, id asc) among those with I > 0."""
    best = -1
    best_i = 0
    w = q.shape[0]
    for pid in range(n):
        i = 0
        for k in range(w):
            i += popcount64(q[k] & packed[pid, k])
        if i == 0:
            continue
        if best == -1 or i > best_i or (i == best_i and iou_tiebreak and proto_len[pid] < proto_len[best]):
            best = pid
            best_i = i
    return best, best_i


@njit(cache=True)
def _insert(bits: I32, pid: int, head: I32, tail: I32, count: I32, pst: I32, nxt: I32, top: int) -> int:
    for q in range(bits.shape[0]):
        bit = bits[q]
        c = count[bit]
        if c % PB == 0:
            b = top
            top += 1
            nxt[b] = -1
            if head[bit] == -1:
                head[bit] = b
            else:
                nxt[tail[bit]] = b
            tail[bit] = b
        pst[tail[bit] * PB + c % PB] = pid
        count[bit] = c + 1
    return top


class LvcMatcher:
    """Eqs. 4.6-4.10 over an inverted index or bit-packed prototypes (module doc); ids are dense from 0.

    ``search``: ``auto`` (packed up to ``PACKED_MAX_BITS`` bits), ``inverted`` or ``packed``.
    """

    def __init__(self, n_bits: int, min_intersection: int, tau_r: float, f1_gate: bool,
                 min_f1: float, iou_tiebreak: bool, search: str = "auto"):
        if search not in ("auto", "inverted", "packed"):
            raise ValueError(f"LVC search must be auto, inverted or packed, got {search!r}")
        self.packed = search == "packed" or (search == "auto" and n_bits <= PACKED_MAX_BITS)
        self.words = (int(n_bits) + 63) // 64
        self.n_bits = int(n_bits)
        self.min_intersection = int(min_intersection)
        self.tau_r = float(tau_r)
        self.f1_gate = bool(f1_gate)
        self.min_f1 = float(min_f1)
        self.iou_tiebreak = bool(iou_tiebreak)
        self._clear()

    def _clear(self) -> None:
        """No prototypes: an empty inverted index with the initial capacities."""
        self._head = np.full(self.n_bits, -1, np.int32)
        self._tail = np.full(self.n_bits, -1, np.int32)
        self._count = np.zeros(self.n_bits, np.int32)
        self._pst = np.zeros(1024 * PB, np.int32)
        self._nxt = np.full(1024, -1, np.int32)
        self._top = 0
        self._proto_len = np.zeros(1024, np.int32)
        self._counts = np.zeros(1024, np.int32)
        self._touched = np.zeros(1024, np.int32)
        self._bits = np.zeros(4096, np.int32)      # prototypes, concatenated
        self._start = np.zeros(1025, np.int64)      # prototype l = _bits[_start[l]:_start[l+1]]
        self._packed = np.zeros((1024 if self.packed else 0, self.words), np.uint64)
        self.size = 0

    def __len__(self) -> int:
        return self.size

    def prototype_size(self, lvc_id: int) -> int:
        """|D_l| of a stored prototype."""
        return int(self._proto_len[lvc_id])

    def prototype(self, lvc_id: int) -> np.ndarray:
        if not 0 <= lvc_id < self.size:
            raise IndexError(f"LVC {lvc_id} does not exist ({self.size} stored)")
        return self._bits[self._start[lvc_id]:self._start[lvc_id + 1]].copy()

    def _pack(self, d: np.ndarray) -> np.ndarray:
        """Sorted bit indices -> uint64 words."""
        return pack_bits(d.astype(np.int64), self.words)

    def _check(self, d: np.ndarray) -> np.ndarray:
        d = np.ascontiguousarray(d, dtype=np.int32)
        if d.ndim != 1 or (d.size and (d[0] < 0 or d[-1] >= self.n_bits or np.any(np.diff(d) <= 0))):
            raise ValueError(f"descriptor must be sorted unique bit indices in [0, {self.n_bits})")
        return d

    def best(self, d: np.ndarray) -> tuple[int, int]:
        """(l*, I) of Eq. 4.8 with the tie-breaks, or (-1, 0) when no prototype shares a bit."""
        d = self._check(d)
        if self.packed:
            best, best_i = _best_packed(self._pack(d), self._packed, self._proto_len, self.size, self.iou_tiebreak)
            return int(best), int(best_i)
        nt = _query(d, self._head, self._count, self._pst, self._nxt, self._counts, self._touched)
        best, best_i = _select(self._touched, nt, self._counts, self._proto_len, self.iou_tiebreak)
        return int(best), int(best_i)

    def accepts(self, i: int, n_query: int, n_proto: int) -> bool:
        """Eq. 4.9 (+ F1 gate) for a candidate with intersection i."""
        if n_query == 0 or i < self.min_intersection or i / n_query < self.tau_r:
            return False
        if self.f1_gate and 2.0 * i / (n_query + n_proto) < self.min_f1:
            return False
        return True

    def match(self, d: np.ndarray, veto: Callable[[int], bool] | None = None) -> LvcResult:
        """Match D_t (sorted unique bit indices) or create a new LVC (Eqs. 4.6-4.10).

        ``veto(l*)`` returning True rejects a candidate that passed Eq. 4.9 (used for the
        per-modality validation of ``lvc.require_multimodal``).
        """
        d = self._check(d)
        best, best_i = self.best(d)
        n = d.size
        best_rate = best_i / n if n else 0.0
        if best >= 0 and self.accepts(best_i, n, int(self._proto_len[best])) and not (veto and veto(best)):
            return LvcResult(best, best_rate, False, best_i, best, best_rate, best_i, n)
        new_id = self.add(d)
        return LvcResult(new_id, 1.0 if n else 0.0, True, 0, best, best_rate, best_i, n)

    def add(self, d: np.ndarray) -> int:
        """Store D_t as the prototype of a new LVC (Eq. 4.10); returns its id."""
        d = self._check(d)
        pid = self.size
        self._reserve(pid + 1, d.size)
        if self.packed:
            self._packed[pid] = self._pack(d)
        else:
            self._top = _insert(d, pid, self._head, self._tail, self._count, self._pst, self._nxt, self._top)
        self._proto_len[pid] = d.size
        s = self._start[pid]
        self._bits[s:s + d.size] = d
        self._start[pid + 1] = s + d.size
        self.size = pid + 1
        return pid

    def _reserve(self, n_protos: int, n_bits: int) -> None:
        cap = self._proto_len.shape[0]
        if n_protos > cap:
            new = 2 * cap
            for name in ("_proto_len", "_counts", "_touched"):
                arr = np.zeros(new, np.int32)
                arr[:cap] = getattr(self, name)
                setattr(self, name, arr)
            start = np.zeros(new + 1, np.int64)
            start[:cap + 1] = self._start
            self._start = start
            if self.packed:
                packed = np.zeros((new, self.words), np.uint64)
                packed[:cap] = self._packed
                self._packed = packed
        need = int(self._start[n_protos - 1]) + n_bits
        if need > self._bits.shape[0]:
            arr = np.zeros(max(2 * self._bits.shape[0], need), np.int32)
            arr[:self._bits.shape[0]] = self._bits
            self._bits = arr
        if self.packed:
            return
        bneed = self._top + n_bits
        bcap = self._nxt.shape[0]
        if bneed > bcap:
            new = max(2 * bcap, bneed)
            nxt = np.full(new, -1, np.int32)
            nxt[:bcap] = self._nxt
            pst = np.zeros(new * PB, np.int32)
            pst[:bcap * PB] = self._pst
            self._nxt, self._pst = nxt, pst

    # ---- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        return {"bits": self._bits[: self._start[self.size]].copy(),
                "start": self._start[: self.size + 1].copy()}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        """Rebuild the prototypes and the inverted index (ids and order preserved)."""
        self._clear()
        bits, start = st["bits"], st["start"]
        for k in range(start.size - 1):
            self.add(bits[start[k]:start[k + 1]])
