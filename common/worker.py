"""The shared base of everything that runs on the bus: sources, sinks and services.

Three kinds of worker take part in a run, and this module holds what they share:

- a :class:`Source` publishes (the player: a recording's streams);
- a :class:`Sink` subscribes (the recorder: every key into a file);
- a service's :class:`~common.runtime.NodeRunner` is both (its inputs in, its outputs out).

Shared by all (:class:`Worker`): the name, the bus, the :class:`WorkerStats` (``aborted``
says why a run stopped early), :attr:`Worker.stop_event`, abort handling (an ``@abort`` on
the bus stops the worker; :meth:`Worker.abort_run` publishes one, the first reason wins)
and the optional :class:`~common.resume.Supervision`.

A :class:`Sink` owns the receive loop: frames from its subscriptions queue up and are
handed to :meth:`Sink.on_frame` one at a time until :meth:`Sink.finished` (or a stop); it
de-duplicates numbered frames (:class:`~common.resume.SequenceGate`), asks publishers for
replays while a restarted sink catches up, repeats its progress when idle under
supervision (so a restarted player learns where it is), and checkpoints every so much
event time (:meth:`Sink.checkpoint_due`, :meth:`Sink.save_state`).

A :class:`Source` answers replay requests for its publishers
(:class:`~common.resume.ReplayServer`) and, at its end, stays until its consumers are done:
supervised, until every consumer reported progress ``END_OF_TIME`` (answering replays
meanwhile); in its own process (``drain_timeout_s`` > 0), until no subscriber is left
(:meth:`common.bus.Bus.drain`: closing a session earlier discards queued frames).

Live runs (``poseidon run --live``) bound a sink's queue (:class:`DropOldestQueue`,
``live.queue_frames``, ``live.queue_mb``): when a service falls behind a live source, the oldest
queued data frame is dropped, counted per key (``SinkStats.dropped``, in the run summary), so memory
stays flat and the newest data flows; watermarks, end-of-stream and replay frames are never
dropped.  Replays keep the unbounded queue: their flow control loses nothing.

Durations: ``*_s`` wall-clock seconds, ``*_ns`` event-time nanoseconds.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.bus import Bus, BusPublisher, ProgressWatcher
from common.ordering import END_OF_TIME
from common.resume import (
    CheckpointSize,
    ReplayServer,
    SequenceGate,
    Supervision,
    checkpoint_path,
    load_checkpoint,
    report_checkpoint,
    request_replays,
    save_checkpoint,
)

__all__ = ["Worker", "WorkerStats", "Sink", "SinkStats", "Source", "WAKE", "DropOldestQueue", "FrameQueue"]

log = logging.getLogger(__name__)

#: queue item that only wakes a sink's receive loop (e.g. a replay request arrived)
WAKE = "@wake"

#: how long a supervised source waits for its consumers when no drain timeout is set (s)
SUPERVISED_WAIT_S = 3600.0
#: drain bound once every consumer reported its end (supervised): the last frames are out (s)
SUPERVISED_DRAIN_S = 5.0


@dataclass(kw_only=True)
class WorkerStats(ABC):
    """Counters every worker reports; ``aborted`` is why the run stopped early ("" if it did not)."""

    aborted: str = ""

    @abstractmethod
    def as_dict(self) -> dict[str, Any]:
        """The counters as JSON-ready values (each kind of worker names its own)."""


@dataclass(kw_only=True)
class SinkStats(WorkerStats):
    """A sink's counters: numbered frames dropped as already received, checkpoints written
    and the wall time they took (ms, total); ``dropped``: data frames dropped per key by a
    bounded (live) queue; ``missing``: numbered frames per key that never arrived (the
    publisher's frame numbers jumped over them: lost on the way, see :mod:`common.live`); ``lost``:
    of those, the frames a supervised live run could not catch up on per key (the source no
    longer kept them, :class:`common.resume.SequenceGate`)."""

    duplicates: int = 0
    checkpoints: int = 0
    checkpoint_ms: float = 0.0
    dropped: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)
    lost: dict[str, int] = field(default_factory=dict)


#: first byte of a data frame (plain or numbered, :mod:`common.codec`)
_DATA_TAGS = (ord("D"), ord("S"))
_SEQ_TAG = ord("S")
#: dropped indices remembered per key (a consumer asks about a gap as soon as the next frame comes)
_DROPPED_MEMORY = 100_000
#: a bounded queue keeps every frame this long (wall s) after its sink caught up on every key
LOSSLESS_GRACE_S = 2.0


class FrameQueue:
    """A sink's unbounded receive queue: ``put_nowait`` never blocks (Zenoh callbacks), ``get``
    waits at most ``timeout`` seconds.  Not :class:`queue.SimpleQueue`: in CPython 3.11 its
    ``get(timeout)`` recomputes the time left after taking its lock on an empty queue, and a
    thread descheduled past the deadline in between waits with a negative timeout, which is
    for ever (seen under load: a live player blocked in ``get`` with -924 us while nothing was
    left to put, so the run never ended).  Here the wait is :meth:`threading.Condition.wait_for`."""

    def __init__(self) -> None:
        self._items: deque[tuple[str, bytes]] = deque()
        self._cond = threading.Condition(threading.Lock())

    def put_nowait(self, item: tuple[str, bytes]) -> None:
        with self._cond:
            self._items.append(item)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> tuple[str, bytes]:
        """The oldest item; :class:`queue.Empty` after ``timeout`` seconds without one."""
        try:
            return self._items.popleft()  # one consumer: the common case takes no lock
        except IndexError:
            pass
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._items), timeout):
                raise queue.Empty
            return self._items.popleft()

    def empty(self) -> bool:
        return not self._items

    def qsize(self) -> int:
        return len(self._items)


class DropOldestQueue:
    """A sink's receive queue holding at most ``max_data`` data frames and ``max_bytes`` bytes of
    them (0: no byte bound): a frame that would pass either bound first drops the oldest queued
    data frames, counted per key in ``dropped``; the newest frame is always kept.  Control frames
    (watermark, end-of-stream, replay, wake) are always kept.  The put never blocks (Zenoh
    callbacks).  The transport indices it dropped are remembered, so that a gap it made is told
    from frames lost in transit (:meth:`dropped_between`)."""

    def __init__(self, max_data: int, dropped: dict[str, int] | None = None, max_bytes: int = 0):
        if max_data < 1:
            raise ValueError(f"a bounded queue needs max_data >= 1, got {max_data}")
        if max_bytes < 0:
            raise ValueError(f"max_bytes must be >= 0 (0: no byte bound), got {max_bytes}")
        self.max_data = max_data
        self.max_bytes = max_bytes
        self._bytes = 0
        self.dropped = dropped if dropped is not None else {}
        self._dropped_index: dict[str, set[int]] = {}
        #: keep every frame, beyond ``max_data`` too: a restarted consumer catching up (its replays
        #: must not be dropped; bounded by what its publishers keep, ``live.retain_s``/``retain_mb``)
        self.lossless = False
        self._items: deque[tuple[str, bytes]] = deque()
        self._data = 0
        self._cond = threading.Condition()

    @staticmethod
    def _is_data(item: tuple[str, bytes]) -> bool:
        return bool(item[1]) and item[1][0] in _DATA_TAGS and item[0] != WAKE

    def _over(self, size: int) -> bool:
        """Would one more data frame of ``size`` bytes pass a bound?"""
        if self._data == 0:
            return False
        return self._data >= self.max_data or (self.max_bytes > 0 and self._bytes + size > self.max_bytes)

    def _drop_oldest_data(self) -> None:
        for i, old in enumerate(self._items):
            if self._is_data(old):
                del self._items[i]
                self._data -= 1
                self._bytes -= len(old[1])
                self.dropped[old[0]] = self.dropped.get(old[0], 0) + 1
                if old[1][0] == _SEQ_TAG and len(old[1]) >= 9:
                    kept = self._dropped_index.setdefault(old[0], set())
                    if len(kept) < _DROPPED_MEMORY:
                        kept.add(int.from_bytes(old[1][1:9], "little"))
                return

    def put_nowait(self, item: tuple[str, bytes]) -> None:
        with self._cond:
            if self._is_data(item):
                if not self.lossless:
                    while self._over(len(item[1])):
                        self._drop_oldest_data()
                self._data += 1
                self._bytes += len(item[1])
            self._items.append(item)
            self._cond.notify()

    def get(self, timeout: float | None = None) -> tuple[str, bytes]:
        """The oldest item; :class:`queue.Empty` after ``timeout`` seconds without one."""
        with self._cond:
            if not self._items and not self._cond.wait_for(lambda: bool(self._items), timeout):
                raise queue.Empty
            item = self._items.popleft()
            if self._is_data(item):
                self._data -= 1
                self._bytes -= len(item[1])
            return item

    def empty(self) -> bool:
        with self._cond:
            return not self._items

    def data_frames(self) -> int:
        """Data frames queued now."""
        with self._cond:
            return self._data

    def data_bytes(self) -> int:
        """Bytes of the data frames queued now."""
        with self._cond:
            return self._bytes

    def within_bounds(self) -> bool:
        """Are the data frames queued now within ``max_data`` and ``max_bytes``?"""
        with self._cond:
            return self._data <= self.max_data and (self.max_bytes == 0 or self._bytes <= self.max_bytes)

    def dropped_between(self, key: str, lo: int, hi: int) -> int:
        """How many of ``key``'s indices ``lo..hi-1`` this queue dropped (and forget those below ``hi``)."""
        with self._cond:
            kept = self._dropped_index.get(key)
            if not kept:
                return 0
            n = sum(1 for i in kept if lo <= i < hi)
            self._dropped_index[key] = {i for i in kept if i >= hi}
            return n

    def qsize(self) -> int:
        with self._cond:
            return len(self._items)


class Worker(ABC):
    """One participant of a run: name, bus, stats, stop and abort, supervision."""

    def __init__(self, name: str, bus: Bus, stats: WorkerStats, supervision: Supervision | None = None,
                 drain_timeout_s: float = 0.0) -> None:
        self.name = name
        self.bus = bus
        self.stats = stats
        self.supervision = supervision
        self.drain_timeout_s = drain_timeout_s
        self.stop_event = threading.Event()
        bus.on_abort(self._on_abort)

    @abstractmethod
    def run(self) -> Any:
        """Work until the end (or a stop, or an abort); returns :attr:`stats`."""

    def stop(self) -> None:
        """Ask :meth:`run` to stop (thread-safe; a signal handler may call it)."""
        self.stop_event.set()

    def _on_abort(self, reason: str) -> None:
        """Somebody aborted the run (``@abort``): stop; the first reason is kept."""
        if not self.stats.aborted:
            log.error("%s: run aborted: %s", self.name, reason)
            self.stats.aborted = reason or "aborted"
        self.stop_event.set()

    def abort_run(self, reason: str) -> None:
        """Stop this worker and every other one: publish ``@abort`` with ``reason``."""
        if not self.stats.aborted:
            self.stats.aborted = reason
        self.bus.abort(reason)
        self.stop_event.set()


class Sink(Worker):
    """A worker that consumes keys: receive loop, de-duplication, replay requests, checkpoints.

    Subclasses call :meth:`subscribe` once in ``__init__`` and implement :meth:`on_frame`
    and :meth:`finished`; :meth:`receive` runs the loop.
    """

    stats: SinkStats
    #: on a stop, True: leave at once; False: first handle what has already arrived
    stop_at_once = True

    def subscribe(self, keys: Iterable[str], max_queue: int = 0, max_queue_bytes: int = 0) -> None:
        """Subscribe to ``keys`` (key expressions) into the sink's queue; progress publisher, gate.
        ``max_queue`` > 0: a :class:`DropOldestQueue` of that many data frames and at most
        ``max_queue_bytes`` of them (0: no byte bound; live runs)."""
        self.queue: FrameQueue | DropOldestQueue = (
            DropOldestQueue(max_queue, self.stats.dropped, max_queue_bytes) if max_queue > 0 else FrameQueue())
        self.progress = self.bus.progress_publisher(self.name)
        self.gate = self._gate({}, ())
        if isinstance(self.queue, DropOldestQueue) and self.supervision is not None and self.supervision.resume:
            self.queue.lossless = True  # a restart: nothing dropped before it caught up (tick)
        self._asked: dict[str, float] = {}
        self._ckpt_stamp: int | None = None
        self._in_step_since: float | None = None
        for key in keys:
            self.bus.subscribe(key, self.queue)

    def wake(self) -> None:
        """Wake the receive loop (thread-safe)."""
        self.queue.put_nowait((WAKE, b""))

    # ---- the receive loop -------------------------------------------------------------
    @abstractmethod
    def finished(self) -> bool:
        """True once every input the sink waits for has ended."""

    @abstractmethod
    def on_frame(self, key: str, data: bytes) -> None:
        """Handle one received frame (any kind: data, watermark, end-of-stream, replay)."""

    def tick(self) -> None:
        """Once per loop turn: ask (again) for the replays a restarted sink still needs.  A
        bounded (live) queue keeps every frame while the sink catches up, and drops again once
        it is in step on every key and back within its bound."""
        sup = self.supervision
        if sup is not None and self.gate.catch_up:
            request_replays(self.bus, self.gate, self.name, self._asked, sup.replay_retry_s)
        q = self.queue
        if isinstance(q, DropOldestQueue):
            if self.gate.catch_up:
                q.lossless = True
                self._in_step_since = None
            elif q.lossless:
                # a replay's frames follow its R frame in a burst: drop again only once the burst
                # is in (LOSSLESS_GRACE_S after the last key came in step) and the queue within bound
                now = time.monotonic()
                self._in_step_since = self._in_step_since or now
                if now - self._in_step_since >= LOSSLESS_GRACE_S and q.within_bounds():
                    q.lossless = False

    def next_frame(self, timeout_s: float = 0.2) -> tuple[str, bytes] | None:
        """The next queued frame, or None after ``timeout_s`` (supervised: progress repeated,
        so that a restarted player learns where this sink is)."""
        try:
            return self.queue.get(timeout=timeout_s)
        except queue.Empty:
            if self.supervision is not None:
                self.progress.repeat(1.0)
            return None

    def receive(self) -> bool:
        """Hand frames to :meth:`on_frame` until :meth:`finished`; False if stopped before."""
        while not self.finished():
            if self.stop_event.is_set() and (self.stop_at_once or self.queue.empty()):
                return False
            self.tick()
            item = self.next_frame()
            if item is None or item[0] == WAKE:
                continue
            self.on_frame(*item)
        return True

    # ---- checkpoints (supervision) ------------------------------------------------------
    def checkpoint_due(self, stamp: int | None, interval_ns: int) -> bool:
        """True when ``interval_ns`` of event time passed since the last checkpoint; the
        interval counts from the first stamp seen.  Always False unsupervised."""
        if self.supervision is None or stamp is None or stamp < 0:
            return False
        if self._ckpt_stamp is None:
            self._ckpt_stamp = stamp
            return False
        return stamp - self._ckpt_stamp >= interval_ns

    def save_state(self, state: dict[str, Any], positions: dict[str, int], stamp: int | None,
                   started: float) -> CheckpointSize:
        """Write checkpoint ``state`` (atomically), tell the publishers ``positions`` (next
        transport index per key) and count it; ``started``: its ``perf_counter`` start.
        Returns the checkpoint's size and the bytes written to make it."""
        size = save_checkpoint(self.state_path(), state)
        report_checkpoint(self.bus, self.name, positions)
        self._ckpt_stamp = stamp
        self.stats.checkpoints += 1
        ms = (time.perf_counter() - started) * 1e3
        self.stats.checkpoint_ms += ms
        log.debug("%s: checkpoint at event time %s (%.1f ms, %.2f MB, %.2f MB written)", self.name, stamp, ms,
                  size.total / 1e6, size.written / 1e6)
        return size

    def state_path(self) -> Path:
        """Where this sink's checkpoint is (supervised only)."""
        assert self.supervision is not None
        return checkpoint_path(self.supervision.state_dir, self.name)

    def load_state(self) -> dict[str, Any] | None:
        """The last checkpoint of this sink (None when there is none)."""
        return load_checkpoint(self.state_path())

    def resume_gate(self, positions: dict[str, int], catch_up: Iterable[str]) -> None:
        """Restarted: expect ``positions`` next; ``catch_up`` keys wait for their replay (a
        bounded queue keeps every frame until then: :meth:`tick`)."""
        self.gate = self._gate(positions, catch_up)
        if isinstance(self.queue, DropOldestQueue) and self.gate.catch_up:
            self.queue.lossless = True

    def _gate(self, positions: dict[str, int], catch_up: Iterable[str]) -> SequenceGate:
        live = self.supervision is not None and self.supervision.live
        dropped = self.queue.dropped_between if isinstance(self.queue, DropOldestQueue) else None
        return SequenceGate(positions, catch_up=catch_up, owner=self.name, missing=self.stats.missing, live=live,
                            queue_dropped=dropped, lost=self.stats.lost)


class Source(Worker):
    """A worker that publishes keys: replay answers, waiting for its consumers, draining."""

    _replay: ReplayServer | None = None

    def serve_replays_for(self, publishers: dict[str, BusPublisher],
                          wake: Callable[[], None] | None = None) -> None:
        """Supervised: answer replay requests for ``publishers`` (see :meth:`serve_replays`)."""
        assert self.supervision is not None
        self._replay = ReplayServer(self.bus, publishers, self.supervision.consumers, wake=wake)

    def serve_replays(self, source: Callable[[str, int], tuple[int, Iterable[bytes]]] | None = None) -> int:
        """Answer the replay requests queued (``source``: frames kept elsewhere, see
        :meth:`common.resume.ReplayServer.serve`); returns how many."""
        if self._replay is None or not self._replay.pending():
            return 0
        return self._replay.serve(source)

    @property
    def replays_served(self) -> int:
        return self._replay.served if self._replay is not None else 0

    def await_consumers(self, consumers: Iterable[str], watcher: ProgressWatcher, tick: Callable[[], None],
                        idle: Callable[[], None]) -> bool:
        """Supervised end: stay until every one of ``consumers`` reported progress
        ``END_OF_TIME``, calling ``tick`` (answer replays...) and ``idle`` (wait a little) in
        turn; at most ``drain_timeout_s`` (``SUPERVISED_WAIT_S`` if 0).  False on a timeout
        (logged) or a stop."""
        names = sorted(consumers)
        timeout_s = self.drain_timeout_s if self.drain_timeout_s > 0 else SUPERVISED_WAIT_S
        deadline = time.monotonic() + timeout_s
        while not self.stop_event.is_set():
            tick()
            waiting = [c for c in names if watcher.get(c) != END_OF_TIME]
            if not waiting:
                return True
            if time.monotonic() > deadline:
                log.warning("%s: consumers %s not finished after %.0f s; leaving", self.name, waiting, timeout_s)
                return False
            idle()
        return False

    def drain(self, publishers: Iterable[BusPublisher], tick: Callable[[], None] | None = None) -> bool:
        """In its own process (``drain_timeout_s`` > 0): stay until no subscriber of
        ``publishers`` is left, calling ``tick`` every 0.2 s; at most ``drain_timeout_s``
        (``SUPERVISED_DRAIN_S`` when supervised: the consumers already reported their end).
        A timeout is logged unless supervised.  True when drained; False on a timeout or a stop."""
        if self.drain_timeout_s <= 0 or self.stop_event.is_set():
            return False
        pubs = list(publishers)
        timeout_s = SUPERVISED_DRAIN_S if self.supervision is not None else self.drain_timeout_s
        deadline = time.monotonic() + timeout_s
        while not self.stop_event.is_set() and time.monotonic() < deadline:
            if self.bus.drain(pubs, 0.2, stop=self.stop_event, warn=False):
                return True
            if tick is not None:
                tick()
        if self.supervision is None and not self.stop_event.is_set():
            busy = [p.key for p in pubs if p.has_subscribers()]
            log.warning("%s: consumers of %s still present after %.0f s; closing anyway", self.name, busy, timeout_s)
        return False
