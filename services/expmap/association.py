"""Event-image association of the experience map (the audit image of Fig. 4.1), without transport.

Each experience event gets the camera frame whose stamp is closest to the event's stamp,
within ``slop_ns`` (ties: the earlier frame).  Inputs arrive in event-time order, so the
candidates are the last frame at or before the event and the first frame after it: an event
waits until a frame later than it arrives (or the inputs end, :meth:`EventImageAssociator.flush`)
and no longer.  At most ``buffer_size`` events wait; beyond that the oldest is decided with
the frames seen so far (``overflow``).  Stamps are integer nanoseconds.

:class:`EventImageAssociator` is generic in the frame and header types: anything with
``.header.stamp`` (frames) and ``.stamp`` (event headers).  Every call returns the
:class:`Association` decisions it made, oldest event first.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

__all__ = ["Association", "EventImageAssociator"]



class _Stamped(Protocol):
    @property
    def stamp(self) -> int: ...


F = TypeVar("F")   # a frame: has .header.stamp
H = TypeVar("H", bound=_Stamped)   # an event header: has .stamp


@dataclass
class Association(Generic[H, F]):
    """The decision for one event: ``frame`` None when no frame is within the slop."""

    header: H
    frame: F | None
    overflow: bool = False    # decided early because too many events were waiting


class EventImageAssociator(Generic[H, F]):
    """Closest frame per event within ``slop_ns``; at most ``buffer_size`` events waiting."""

    def __init__(self, slop_ns: int, buffer_size: int):
        self.slop_ns = int(slop_ns)
        self.buffer_size = int(buffer_size)
        self.last_frame: F | None = None
        self.waiting: deque[tuple[H, F | None]] = deque()   # (event header, last frame at or before it)

    @staticmethod
    def _stamp(x: Any) -> int:
        return int(x.header.stamp)

    def on_frame(self, frame: F) -> list[Association[H, F]]:
        """A camera frame: decides every waiting event at or before its stamp."""
        out = []
        while self.waiting and self.waiting[0][0].stamp <= self._stamp(frame):
            hdr, before = self.waiting.popleft()
            out.append(self.decide(hdr, before, frame))
        self.last_frame = frame
        return out

    def on_event(self, header: H) -> list[Association[H, F]]:
        """An event: decided at once when the last frame has its stamp, else it waits."""
        last = self.last_frame
        if last is not None and self._stamp(last) == header.stamp:
            return [self.decide(header, last, None)]      # nothing can be closer
        self.waiting.append((header, last))
        if len(self.waiting) > self.buffer_size:
            h, before = self.waiting.popleft()
            a = self.decide(h, before, None)
            a.overflow = True
            return [a]
        return []

    def flush(self) -> list[Association[H, F]]:
        """The inputs ended: decide every waiting event with the frames seen."""
        out = []
        while self.waiting:
            hdr, before = self.waiting.popleft()
            out.append(self.decide(hdr, before, None))
        return out

    @property
    def oldest_waiting(self) -> int | None:
        """Stamp of the oldest undecided event (ns), None when none waits."""
        return self.waiting[0][0].stamp if self.waiting else None

    def decide(self, header: H, before: F | None, after: F | None) -> Association[H, F]:
        """The closer of ``before`` and ``after`` within the slop (ties: ``before``)."""
        best: F | None = None
        best_d = self.slop_ns + 1
        for frame in (before, after):        # earlier first: ties go to the earlier frame
            if frame is None:
                continue
            d = abs(self._stamp(frame) - header.stamp)
            if d < best_d:
                best, best_d = frame, d
        return Association(header, best)
