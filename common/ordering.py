"""Event-time ordering of several input streams (dataflow watermarks).

A service must give the same outputs however the network interleaves its inputs.  The
:class:`EventTimeMerger` buffers messages and releases them in ``(stamp, stream priority,
seq)`` order, and only once every input stream has promised (by data or by a heartbeat
watermark) that nothing older than the released stamp can still arrive.

Watermark semantics: ``W`` on a stream means no later message on it has ``stamp < W``.
A data message with stamp ``t`` implies ``W >= t``.  The oldest buffered message
``(t, p)`` (stamp, priority of its stream) is released when every *other* stream ``s``
has ``W_s > t``, or ``W_s == t`` and a lower priority than ``p`` (anything it may still
send sorts after).  Its own stream never holds it back: a stream delivers in its own order.
"""
from __future__ import annotations

import heapq
from collections.abc import Iterator
from typing import Any

__all__ = ["EventTimeMerger", "END_OF_TIME"]

END_OF_TIME = (1 << 63) - 1


class EventTimeMerger:
    """Deterministic merge of ``streams`` (listed in priority order)."""

    def __init__(self, streams: list[str] | tuple[str, ...]):
        if len(set(streams)) != len(streams):
            raise ValueError(f"duplicate stream names in {streams}")
        self._priority = {s: i for i, s in enumerate(streams)}
        self._watermark = {s: -1 for s in streams}
        self._heap: list[tuple[int, int, int, int, Any]] = []
        self._counter = 0  # arrival order, only to keep heap entries comparable
        self.late = 0  # messages older than the stream's own watermark (a publisher bug)

    @property
    def streams(self) -> list[str]:
        return list(self._priority)

    def push(self, stream: str, stamp: int, seq: int, item: Any) -> None:
        """Buffer a data message of ``stream``."""
        if stamp < self._watermark[stream]:
            self.late += 1
        self._watermark[stream] = max(self._watermark[stream], stamp)
        heapq.heappush(self._heap, (stamp, self._priority[stream], seq, self._counter, item))
        self._counter += 1

    def advance(self, stream: str, watermark: int) -> None:
        """Record a heartbeat: nothing older than ``watermark`` will follow on ``stream``."""
        if watermark > self._watermark[stream]:
            self._watermark[stream] = watermark

    def end(self, stream: str) -> None:
        """End of stream: nothing more will follow."""
        self._watermark[stream] = END_OF_TIME

    def stream_watermark(self, stream: str) -> int:
        """The watermark of one stream (-1 before it spoke, END_OF_TIME after its end)."""
        return self._watermark[stream]

    @property
    def watermark(self) -> int:
        """The minimum watermark over all streams (-1 before every stream spoke)."""
        return min(self._watermark.values()) if self._watermark else END_OF_TIME

    @property
    def finished(self) -> bool:
        return self.watermark == END_OF_TIME and not self._heap

    def pending(self) -> int:
        return len(self._heap)

    def pop_ready(self) -> Iterator[tuple[str, int, Any]]:
        """Yield ``(stream, stamp, item)`` for every message that is safe to process now."""
        names = list(self._priority)
        while self._heap:
            stamp, prio = self._heap[0][0], self._heap[0][1]
            for other, wm in self._watermark.items():
                op = self._priority[other]
                if op != prio and not (wm > stamp or (wm == stamp and op > prio)):
                    return
            stamp, prio, _seq, _c, item = heapq.heappop(self._heap)
            yield names[prio], stamp, item
