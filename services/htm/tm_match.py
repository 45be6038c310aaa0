"""The temporal memory's revisit decision: which stored frame the TM's predictions say we are at (ours).

The TM learns the mission as one long sequence of SP column sets.  A cell of the TM is a
column *in a temporal context*: a frame's winner cells name the frame's place and the
path that led there.  When the vehicle comes back along a stretch it has travelled, the
columns of a frame that the TM *predicted* activate exactly the cells learnt on the first
pass (predicted columns do not burst), so the correctly predicted cells of frame t are the
winner cells of the stored frame(s) j the TM believes it is replaying.

:class:`TmFrameIndex` keeps, per cell, the list of stored frames where it was a winner (an
inverted index: a chain of entries per cell, appended in O(1)), and ``vote(hits, nc)``
counts for every candidate frame j < ``nc`` how many of the correctly predicted cells
``hits`` were winners at j.  The TM decision of a frame is the frame j* with the most votes
(ties to the latest frame) and its share ``votes / |active columns|`` -- the fraction of the
frame's columns the TM predicted *in the context of j**.  A novel place bursts (share 0);
a stretch that re-enters a learned sequence is predicted (share up to 1).  Cost per frame:
O(sum over the hit cells of the stored frames they won in).
"""
from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["TmFrameIndex"]

I64 = NDArray[np.int64]


@njit(cache=True)
def _append(cells: I64, frame: int, head: I64, nxt: I64, frm: I64, top: int) -> int:
    for c in cells:
        e = top
        frm[e] = frame
        nxt[e] = head[c]
        head[c] = e
        top += 1
    return top


@njit(cache=True)
def _vote(hits: I64, nc: int, head: I64, nxt: I64, frm: I64, votes: I64, touched: I64) -> tuple[int, int]:
    """votes[j] += 1 for every hit cell that was a winner at frame j < nc; returns (best, count)
    (the latest frame among ties) and the number of touched frames (then cleared)."""
    nt = 0
    for c in hits:
        e = head[c]
        last = -1
        while e >= 0:
            j = frm[e]
            if j < nc and j != last:      # a cell counted once per frame
                if votes[j] == 0:
                    touched[nt] = j
                    nt += 1
                votes[j] += 1
            last = j
            e = nxt[e]
    best, cnt = -1, 0
    for t in range(nt):
        j = touched[t]
        v = votes[j]
        if v > cnt or (v == cnt and j > best):
            best, cnt = j, v
        votes[j] = 0
    return best, cnt


class TmFrameIndex:
    """Cell -> stored frames where it won (see the module doc)."""

    def __init__(self, num_cells: int):
        self.num_cells = int(num_cells)
        self.head = np.full(self.num_cells, -1, np.int64)
        self.nxt = np.zeros(1024, np.int64)
        self.frm = np.zeros(1024, np.int64)
        self.top = 0
        self.size = 0
        self._votes = np.zeros(256, np.int64)
        self._touched = np.zeros(256, np.int64)

    def __len__(self) -> int:
        return self.size

    def add(self, winner_cells: np.ndarray) -> int:
        """Append one stored frame (its winner cells); returns its index."""
        cells = np.ascontiguousarray(winner_cells, np.int64)
        need = self.top + cells.size
        if need > self.nxt.size:
            new = max(2 * self.nxt.size, need)
            self.nxt = np.concatenate([self.nxt, np.zeros(new - self.nxt.size, np.int64)])
            self.frm = np.concatenate([self.frm, np.zeros(new - self.frm.size, np.int64)])
        j = self.size
        self.top = int(_append(cells, j, self.head, self.nxt, self.frm, self.top))
        self.size += 1
        if self.size > self._votes.size:
            self._votes = np.zeros(2 * self.size, np.int64)
            self._touched = np.zeros(2 * self.size, np.int64)
        return j

    def vote(self, hits: np.ndarray, nc: int) -> tuple[int, int]:
        """(frame j*, votes) among the frames j < ``nc`` for the correctly predicted cells ``hits``."""
        if nc <= 0 or len(hits) == 0:
            return -1, 0
        best, cnt = _vote(np.ascontiguousarray(hits, np.int64), int(nc), self.head, self.nxt, self.frm,
                          self._votes, self._touched)
        return int(best), int(cnt)

    # ---- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        return {"head": self.head, "nxt": self.nxt[:self.top].copy(), "frm": self.frm[:self.top].copy(),
                "counters": np.array([self.top, self.size], np.int64)}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        if "head" not in st:
            return
        if st["head"].size != self.num_cells:
            raise ValueError(f"TM frame index saved for {st['head'].size} cells, configuration has {self.num_cells}")
        self.head = np.array(st["head"], np.int64)
        self.top, self.size = (int(x) for x in st["counters"])
        cap = max(1024, self.top)
        self.nxt = np.zeros(cap, np.int64)
        self.frm = np.zeros(cap, np.int64)
        self.nxt[:self.top], self.frm[:self.top] = st["nxt"], st["frm"]
        self._votes = np.zeros(max(256, 2 * self.size), np.int64)
        self._touched = np.zeros(max(256, 2 * self.size), np.int64)
