"""Sequence memory over stored frames: the LVC decision of a frame from its recent sequence (ours).

Single-frame matching (Eqs. 4.6-4.9) fails when a place looks different on a revisit
(Nordland summer vs winter: no summer frame passes the R/F1 gates for its winter frame).
What survives is the *sequence*: the frames of a revisit follow the stored frames of the
first visit in order.  :class:`SequenceMatcher` keeps every stored frame's descriptor D_j
(bit-packed) with the LVC id it was given, and for the current frame t:

1. similarity s_t(j) = F1(D_t, D_j) = 2 |D_t & D_j| / (|D_t| + |D_j|) (the F1 of the LVC
   gate, Eq. 4.9) against every *candidate* frame j: all stored frames except those of the
   current traversal stored in the last ``exclude`` steps (neighbours in time trivially look
   alike; a ``reset()`` starts a new traversal, after which every stored frame is a candidate);
2. causal normalisation (the local contrast enhancement of SeqSLAM, Milford & Wyeth 2012,
   made online): per frame t the z-score of s_t over the candidates, then (``column_norm``)
   per stored frame j the running standardisation of those z-scores over the frames of the
   current traversal that have queried it so far, shrunk towards (0, 1) by ``column_prior``
   pseudo-frames (so a stored frame seen by few queries keeps its row z-score; Nordland,
   K 10, AP of the memory alone with 0 / 3 / 10 / 30 pseudo-frames 0.849 / 0.855 / 0.857 /
   0.855, corridor 0.899 / 0.937 / 0.928 / 0.910; z-score only 0.639 and 0.865);
3. sequence score of a diagonal ending at j: S_t(j) = (1/K) sum_{k<K} z_{t-k}(j - round(v k))
   for each velocity v of ``velocities`` (frames of the memory per frame of the traversal),
   the best v kept; a point outside the history or the candidates of its frame adds 0
   (so a diagonal shorter than K cannot outscore a full one).  The history holds the last
   K normalised rows; with the running diagonal sums the cost per frame is O(#memory x
   #velocities) plus the F1 row of step 1: O(#memory x words) from the packed words, or, for
   a sparse descriptor, O(|D_t| x frames per bit) from the posting lists (:class:`BitPostings`).

``score(D_t)`` does 1-3 and returns (j*, S*, S_2): the best ending frame, its score and the
best score ending outside ``j* +- K`` (uniqueness, as in SeqSLAM; 0, the mean of a z-score,
when there is none; (-1, 0, 0) without candidates), with the frame's own F1 s_t(j*) and
s_t(j2) at the end j2 of that runner-up (``f1``, ``f1_second``: the null sample of the
self-calibrated F1 check, :mod:`services.htm.calibrate`).  ``add(D_t, lvc_id)``
appends the frame to the memory.  Everything is causal: the frame t only uses frames up to t.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit
from numpy.typing import NDArray

from services.htm._bits import pack_bits, popcount64

__all__ = ["SequenceMatcher", "SequenceScore"]

#: descriptors of at most n_bits / this many bits are indexed (:class:`BitPostings`)
SPARSE_DENOMINATOR = 16

I64 = NDArray[np.int64]
U64 = NDArray[np.uint64]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@njit(cache=True, error_model="numpy")
def _f1_row(q: U64, q_size: int | np.int64, mem: U64, sizes: I64, n: int, out: F64) -> None:
    """out[j] = 2 |q & mem_j| / (|q| + |mem_j|) for j < n (packed uint64 rows)."""
    w = q.shape[0]
    for j in range(n):
        c = 0
        for k in range(w):
            c += popcount64(q[k] & mem[j, k])
        den = q_size + sizes[j]
        out[j] = 2.0 * c / den if den > 0 else 0.0


@njit(cache=True)
def _postings_add(bits: I64, j: int, head: I64, tail: I64, fill: I64, blocks: I32, nxt: I64, nblk: int) -> int:
    """Append frame ``j`` to the posting list of each of its ``bits`` (chained blocks); returns
    the blocks in use.  The caller guarantees room for ``bits.size`` new blocks."""
    width = blocks.shape[1]
    for b in bits:
        t = tail[b]
        if t < 0 or fill[b] == width:
            nb = nblk
            nblk += 1
            nxt[nb] = -1
            if t < 0:
                head[b] = nb
            else:
                nxt[t] = nb
            tail[b] = nb
            fill[b] = 0
            t = nb
        blocks[t, fill[b]] = j
        fill[b] += 1
    return nblk


@njit(cache=True, error_model="numpy")
def _f1_row_postings(bits: I64, q_size: int | np.int64, head: I64, tail: I64, fill: I64, blocks: I32, nxt: I64,
                     sizes: I64, n: int, cnt: I64, out: F64) -> None:
    """:func:`_f1_row` from the posting lists of the query's bits: |q & mem_j| counted by walking
    each bit's frames (ascending, so a walk stops at the first j >= n); the same F1 values."""
    for j in range(n):
        cnt[j] = 0
    width = blocks.shape[1]
    for b in bits:
        blk = head[b]
        while blk >= 0:
            m = fill[b] if blk == tail[b] else width
            done = False
            for i in range(m):
                j = blocks[blk, i]
                if j >= n:
                    done = True
                    break
                cnt[j] += 1
            if done:
                break
            blk = nxt[blk]
    for j in range(n):
        den = q_size + sizes[j]
        out[j] = 2.0 * cnt[j] / den if den > 0 else 0.0


@njit(cache=True, error_model="numpy")
def _normalise(s: F64, nc: int, cnt: F64, s1: F64, s2: F64, use_column: bool, prior: float, update: bool,
               z: F64) -> None:
    """z[:nc] = z-score of s over the candidates, then (``use_column``) standardised per stored
    frame by its running mean / variance over the traversal, shrunk towards (0, 1) by ``prior``
    pseudo-frames; updates those per-frame statistics when ``update``."""
    if nc == 0:
        return
    m = 0.0
    for j in range(nc):
        m += s[j]
    m /= nc
    var = 0.0
    for j in range(nc):
        var += (s[j] - m) ** 2
    sd = np.sqrt(var / nc)
    for j in range(nc):
        z[j] = (s[j] - m) / sd if sd > 1e-12 else 0.0
    if not use_column:
        return
    for j in range(nc):
        v = z[j]
        if update:
            cnt[j] += 1.0
            s1[j] += v
            s2[j] += v * v
        n = cnt[j] + prior
        if n <= 0.0:
            continue
        mu = s1[j] / n
        var = (s2[j] + prior) / n - mu * mu
        z[j] = (v - mu) / np.sqrt(var) if var > 1e-12 else 0.0


@njit(cache=True)
def _diagonals(hist: F64, hist_len: I64, head: int, n_hist: int, nc: int, length: int, offsets: I64, acc: F64,
               out: F64) -> None:
    """out[j] = max over velocities of (1/K) sum_k hist[t-k][j - offsets[v, k]] (missing points: 0)."""
    h = hist.shape[0]
    for j in range(nc):
        out[j] = -1e300
    for v in range(offsets.shape[0]):
        for j in range(nc):
            acc[j] = 0.0
        for k in range(min(length, n_hist)):
            r = (head - k) % h
            off = offsets[v, k]
            hi = min(nc, hist_len[r] + off)
            for j in range(off, hi):
                acc[j] += hist[r, j - off]
        for j in range(nc):
            if acc[j] > out[j]:
                out[j] = acc[j]
    for j in range(nc):
        out[j] /= length


@njit(cache=True)
def _diag_sums(hist: F64, hist_len: I64, head: int, length: int, steps: I64, hi: int, diag: F64) -> None:
    """diag[v, j] = sum_k hist[t-k][j - k steps[v]] over the valid points (j < hi), in the order of
    :func:`_diagonals` (k = 0 first): the incremental sums rebuilt from the history rows."""
    h = hist.shape[0]
    for v in range(steps.shape[0]):
        for j in range(hi):
            diag[v, j] = 0.0
        for k in range(length):
            r = (head - k) % h
            off = k * steps[v]
            top = min(hi, hist_len[r] + off)
            for j in range(off, top):
                diag[v, j] += hist[r, j - off]


@njit(cache=True)
def _diag_advance(diag: F64, steps: I64, length: int, old: F64, old_len: int, hi: int) -> None:
    """One frame on: diag[v, j] <- diag[v, j - step] - old[j - K step] for j < hi (in place, j
    descending; points outside the previous sums or the expiring row ``old`` count 0)."""
    for v in range(steps.shape[0]):
        st = steps[v]
        drop = length * st
        for j in range(hi - 1, -1, -1):
            x = diag[v, j - st] if j - st >= 0 else 0.0
            i = j - drop
            if 0 <= i < old_len:
                x -= old[i]
            diag[v, j] = x


@njit(cache=True, error_model="numpy")
def _diag_add_max(diag: F64, row: F64, nc: int, length: int, out: F64) -> None:
    """diag[v, j] += row[j] (the new frame's points, j < nc); out[j] = max_v diag[v, j] / K."""
    for j in range(nc):
        out[j] = -1e300
    for v in range(diag.shape[0]):
        for j in range(nc):
            diag[v, j] += row[j]
            if diag[v, j] > out[j]:
                out[j] = diag[v, j]
    for j in range(nc):
        out[j] /= length


def _unique_bits(d: np.ndarray) -> I64:
    """A descriptor's bits, sorted and unique (int64)."""
    return np.unique(np.asarray(d, np.int64))


class BitPostings:
    """Inverted index of the memory: per descriptor bit, the stored frames holding it (ascending).

    For sparse descriptors (the ``tm`` source: ``descriptor.tm_topk`` 15 of 2048 column bits) the F1
    row of step 1 from the query's posting lists touches ~|D_t| x (frames per bit) entries
    instead of every stored frame's packed words: same values, a fraction of the memory
    traffic on a memory of hours (docs/DECISIONS.md, "HTM cost per frame").  The default ``sdr``
    descriptor is dense (~900 of 2048 bits, the union of the camera and sonar codes): there the
    packed words are always cheaper, so :class:`SequenceMatcher` keeps no index once a dense
    frame is stored."""

    BLOCK = 32  # frames per block of a posting list

    def __init__(self, n_bits: int):
        self.head = np.full(n_bits, -1, np.int64)
        self.tail = np.full(n_bits, -1, np.int64)
        self.fill = np.zeros(n_bits, np.int64)
        self.entries = np.zeros(n_bits, np.int64)  # frames per bit
        self.blocks = np.zeros((64, self.BLOCK), np.int32)
        self.nxt = np.full(64, -1, np.int64)
        self.nblk = 0

    def add(self, bits: np.ndarray, j: int) -> None:
        """Frame ``j`` (larger than every frame added before) holds ``bits`` (sorted, unique)."""
        need = self.nblk + bits.size
        if need > self.blocks.shape[0]:
            cap = max(2 * self.blocks.shape[0], need)
            blocks = np.zeros((cap, self.BLOCK), np.int32)
            blocks[:self.nblk] = self.blocks[:self.nblk]
            nxt = np.full(cap, -1, np.int64)
            nxt[:self.nblk] = self.nxt[:self.nblk]
            self.blocks, self.nxt = blocks, nxt
        self.nblk = _postings_add(bits, j, self.head, self.tail, self.fill, self.blocks, self.nxt, self.nblk)
        self.entries[bits] += 1

    def cost(self, bits: np.ndarray) -> int:
        """Entries a query with ``bits`` walks (at most)."""
        return int(self.entries[bits].sum())


class SequenceScore:
    """Outcome of :meth:`SequenceMatcher.score`: best ending frame, its score, the runner-up."""

    __slots__ = ("frame", "score", "second", "last", "f1", "f1_second")

    def __init__(self, frame: int, score: float, second: float, last: float = 0.0, f1: float = 0.0,
                 f1_second: float = -1.0):
        self.frame = frame      # memory index j* (-1: no candidate)
        self.score = score      # S*(j*), z units
        self.second = second    # best S outside j* +- K (0: none)
        self.last = last        # the current frame's own normalised similarity z_t(j*)
        self.f1 = f1            # the current frame's own F1 with frame j*: s_t(j*)
        self.f1_second = f1_second  # s_t(j2), j2 the end of the best diagonal outside j* +- K (-1: none)

    def __repr__(self) -> str:
        return f"SequenceScore(frame={self.frame}, score={self.score:.3f}, second={self.second:.3f})"


class SequenceMatcher:
    """Frame memory + online SeqSLAM-style sequence scores (see the module doc)."""

    def __init__(self, n_bits: int, length: int, velocities: Sequence[float], exclude: int,
                 column_norm: bool = True, column_prior: float = 10.0, incremental: bool = True):
        if length < 1:
            raise ValueError(f"sequence length must be >= 1, got {length}")
        if not velocities or any(v <= 0 for v in velocities):
            raise ValueError(f"sequence velocities must be > 0, got {list(velocities)}")
        self.n_bits = int(n_bits)
        self.length = int(length)
        self.velocities = [float(v) for v in velocities]
        self.exclude = int(exclude)
        self.column_norm = bool(column_norm)
        self.column_prior = float(column_prior)
        self.words = (self.n_bits + 63) // 64
        self._offsets = np.array([[int(np.floor(v * k + 0.5)) for k in range(self.length)]
                                  for v in self.velocities], np.int64)
        # incremental diagonal sums when every velocity's offsets are k x an integer step (v = 1: step 1)
        steps = self._offsets[:, 1] if self.length > 1 else np.zeros(len(self.velocities), np.int64)
        arithmetic = bool(np.array_equal(self._offsets, np.arange(self.length)[None, :] * steps[:, None]))
        self.incremental = bool(incremental) and arithmetic
        self._steps = np.ascontiguousarray(steps, np.int64)
        self._diag_hi = 0          # diag[:, j] is exactly 0 for j >= _diag_hi (never touched since reset)
        self._alloc(256)
        self.size = 0
        self.traversal_start = 0   # memory frames before this index were stored before the last reset()
        self.steps = 0             # frames scored since the last reset()
        self._head = -1
        self._scratch = np.zeros(256, np.float64)
        self._counts = np.zeros(256, np.int64)
        self._postings: BitPostings | None = BitPostings(self.n_bits)  # None: a dense frame is stored

    def _sparse(self, size: int) -> bool:
        """A descriptor of ``size`` bits for which the posting lists can pay (at most 1/16 of the bits)."""
        return size * SPARSE_DENOMINATOR <= self.n_bits

    def _alloc(self, cap: int) -> None:
        self.mem = np.zeros((cap, self.words), np.uint64)
        self.sizes = np.zeros(cap, np.int64)
        self.ids = np.zeros(cap, np.int64)
        self.cnt = np.zeros(cap, np.float64)
        self.s1 = np.zeros(cap, np.float64)
        self.s2 = np.zeros(cap, np.float64)
        self.hist = np.zeros((self.length, cap), np.float64)
        self.hist_len = np.zeros(self.length, np.int64)
        # a diagonal can end up to (K - 1) x step past the last candidate: room for those ends
        reach = int(self._steps.max()) * (self.length - 1) if self.incremental else 0
        self.diag = np.zeros((len(self.velocities) if self.incremental else 0, cap + reach), np.float64)

    def _grow(self, need: int) -> None:
        cap = self.mem.shape[0]
        if need <= cap:
            return
        new = max(2 * cap, need)
        old = (self.mem, self.sizes, self.ids, self.cnt, self.s1, self.s2, self.hist, self.diag)
        hist_len = self.hist_len
        self._alloc(new)
        for dst, src in zip((self.mem, self.sizes, self.ids, self.cnt, self.s1, self.s2), old[:6]):
            dst[:cap] = src
        self.hist[:, :cap] = old[6]
        self.diag[:, :old[7].shape[1]] = old[7]
        self.hist_len = hist_len

    def __len__(self) -> int:
        return self.size

    def pack(self, d: np.ndarray) -> np.ndarray:
        """Descriptor (sorted unique bit indices) -> packed uint64 words."""
        d = np.ascontiguousarray(d, np.int64)
        if d.size and (d.min() < 0 or d.max() >= self.n_bits):
            raise ValueError(f"descriptor bit out of range [0, {self.n_bits})")
        return pack_bits(d, self.words)

    def candidates(self) -> int:
        """Number of candidate frames (a prefix of the memory): all but the last ``exclude``
        frames stored in the current traversal."""
        return max(min(self.traversal_start, self.size), self.size - self.exclude, 0)

    def score(self, d: np.ndarray, update: bool = True) -> SequenceScore:
        """Steps 1-3 of the module doc for the current frame's descriptor; pushes its row.

        ``update`` False leaves the per-frame (column) statistics unchanged.
        """
        q = self.pack(d)
        nc = self.candidates()
        if self._scratch.shape[0] < self.size:
            self._scratch = np.zeros(self.mem.shape[0], np.float64)
        s = self._scratch
        q_size = np.int64(np.asarray(d).size)
        ix = self._postings
        if ix is not None and ix.cost(bits := _unique_bits(d)) * 4 < nc * self.words:  # the cheaper exact way
            if self._counts.shape[0] < nc:
                self._counts = np.zeros(self.mem.shape[0], np.int64)
            _f1_row_postings(bits, q_size, ix.head, ix.tail, ix.fill, ix.blocks, ix.nxt, self.sizes, nc,
                             self._counts, s)
        else:
            _f1_row(q, q_size, self.mem, self.sizes, nc, s)
        self._head = (self._head + 1) % self.length
        row = self.hist[self._head]
        if self.incremental:
            # the slot's row (frame t - K) leaves every diagonal before the new row overwrites it
            self.hist_len[self._head], old_len = 0, int(self.hist_len[self._head])
            self._diag_hi = min(self.diag.shape[1], max(self._diag_hi, nc + int(self._steps.max()) * (self.length - 1)))
            _diag_advance(self.diag, self._steps, self.length, row, old_len, self._diag_hi)
        _normalise(s, nc, self.cnt, self.s1, self.s2, self.column_norm, self.column_prior, update, row)
        self.hist_len[self._head] = nc
        self.steps += 1
        if nc == 0:
            return SequenceScore(-1, 0.0, 0.0)
        out = np.empty(nc, np.float64)
        if self.incremental:
            _diag_add_max(self.diag, row, nc, self.length, out)
        else:
            _diagonals(self.hist, self.hist_len, self._head, self.steps, nc, self.length, self._offsets,
                       np.empty(nc, np.float64), out)
        j = int(np.argmax(out))
        lo, hi = max(0, j - self.length), min(nc, j + self.length + 1)
        best = float(out[j])
        second, f1_second = 0.0, -1.0
        if lo > 0 or hi < nc:
            out[lo:hi] = -np.inf
            j2 = int(np.argmax(out))
            second, f1_second = float(out[j2]), float(s[j2])
        return SequenceScore(j, best, second, float(row[j]), float(s[j]), f1_second)

    def add(self, d: np.ndarray, lvc_id: int) -> int:
        """Append a frame with its LVC id to the memory; returns its memory index."""
        q = self.pack(d)
        self._grow(self.size + 1)
        j = self.size
        self.mem[j] = q
        self.sizes[j] = np.asarray(d).size
        self.ids[j] = int(lvc_id)
        if self._postings is not None:
            if self._sparse(int(self.sizes[j])):
                self._postings.add(_unique_bits(d), j)
            else:  # the index must hold every frame; a dense memory scores from the packed words
                self._postings = None
        self.size += 1
        return j

    def reset(self) -> None:
        """A new traversal: forget the history rows and the per-frame statistics (they describe
        how the stored frames look from the current traversal); every stored frame becomes a candidate."""
        self.hist_len[:] = 0
        self.diag[:] = 0.0
        self._diag_hi = 0
        self.cnt[:] = 0.0
        self.s1[:] = 0.0
        self.s2[:] = 0.0
        self.steps = 0
        self._head = -1
        self.traversal_start = self.size

    # ---- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        n = self.size
        return {"mem": self.mem[:n].copy(), "sizes": self.sizes[:n].copy(), "ids": self.ids[:n].copy(),
                "cnt": self.cnt[:n].copy(), "s1": self.s1[:n].copy(), "s2": self.s2[:n].copy(),
                "hist": self.hist[:, :n].copy(), "hist_len": self.hist_len.copy(),
                "diag": self.diag[:, :self._diag_hi].copy(),
                "counters": np.array([self.traversal_start, self.steps, self._head], np.int64)}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        if "mem" not in st:      # a state saved before the sequence memory existed
            return
        n = st["mem"].shape[0]
        if st["mem"].shape[1] != self.words or st["hist"].shape[0] != self.length:
            raise ValueError(f"sequence memory saved with {st['mem'].shape[1]} words x length {st['hist'].shape[0]}, "
                             f"configuration has {self.words} x {self.length}")
        self._alloc(max(256, n))
        self.mem[:n], self.sizes[:n], self.ids[:n] = st["mem"], st["sizes"], st["ids"]
        self.cnt[:n], self.s1[:n], self.s2[:n] = st["cnt"], st["s1"], st["s2"]
        self.hist[:, :n] = st["hist"]
        self.hist_len = st["hist_len"].astype(np.int64).copy()
        self.traversal_start, self.steps, self._head = (int(x) for x in st["counters"])
        self.size = n
        self._postings = None  # derived from the memory, not saved; kept only while every frame is sparse
        if all(self._sparse(int(x)) for x in self.sizes[:n]):
            self._postings = BitPostings(self.n_bits)
            for j in range(n):
                self._postings.add(np.flatnonzero(np.unpackbits(self.mem[j].view(np.uint8), bitorder="little")), j)
        if self.incremental:
            diag = st.get("diag")
            if diag is not None and diag.shape[0] == self.diag.shape[0] and diag.shape[1] <= self.diag.shape[1]:
                self._diag_hi = diag.shape[1]
                self.diag[:, :self._diag_hi] = diag
            else:  # saved by the full computation (or another velocity set): rebuilt from the history
                self._diag_hi = min(self.diag.shape[1],
                                    int(self.hist_len.max()) + int(self._steps.max()) * (self.length - 1))
                _diag_sums(self.hist, self.hist_len, max(self._head, 0), self.length, self._steps, self._diag_hi,
                           self.diag)
