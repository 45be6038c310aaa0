"""Runs a :class:`~common.node.ServiceNode` on the bus.

The runner subscribes to the node's inputs, merges them by event time
(:class:`~common.ordering.EventTimeMerger`), calls the node, publishes its outputs, reports
its progress (event time consumed, for the player's flow control), and forwards event-time
watermarks (on an output key silent for ``bus.heartbeat_interval_ms`` of event
time, :meth:`common.bus.BusPublisher.heartbeat`) and end-of-stream so downstream services can merge deterministically too.
Any frame that cannot be used is a counted, logged rejection (key, seq when readable, the
reason), never an exception: malformed frames and messages that fail validation
(:mod:`common.codec`), data older than its own stream's watermark (``late``: it would be
processed out of event-time order) and data after the stream's end-of-stream.  Rejections
per key are in ``RunnerStats.invalid``, per reason in ``RunnerStats.rejected``.  An
exception raised by the node itself is a failure of the service: it propagates, naming
the key, seq and stamp of the input being processed.  On a normal end the runner reports
progress ``END_OF_TIME`` (the service finished, see :mod:`common.bus`); an ``@abort`` on
the bus stops it (``RunnerStats.aborted`` says why).

Numbered frames (:mod:`common.codec`) already received are dropped (``RunnerStats.duplicates``).
Supervised (``supervision``, :mod:`common.resume`): the runner checkpoints the node every
``checkpoint_interval`` of event time (``RunnerStats.checkpoints``, ``checkpoint_ms``,
``checkpoint_bytes``), keeps its outputs for replay, answers replay requests, and when
``supervision.resume`` restores the last checkpoint and asks its publishers for the inputs
after it.  A node failure then does not abort the run: the launcher restarts the service.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field

from common.bus import Bus
from common.codec import DecodeError, decode_dict, decode_frame
from common.messages import Message
from common.node import ServiceNode
from common.ordering import END_OF_TIME, EventTimeMerger
from common.resume import (
    ReplayServer,
    SequenceGate,
    Supervision,
    checkpoint_path,
    load_checkpoint,
    report_checkpoint,
    request_replays,
    save_checkpoint,
)

__all__ = ["NodeRunner", "RunnerStats", "ServiceError"]

log = logging.getLogger(__name__)


class ServiceError(RuntimeError):
    """A service's own code failed on an input (the message names the input)."""


@dataclass
class RunnerStats:
    service: str
    received: dict[str, int] = field(default_factory=dict)
    published: dict[str, int] = field(default_factory=dict)
    invalid: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    late: int = 0
    busy_s: float = 0.0
    counters: dict[str, int] = field(default_factory=dict)
    aborted: str = ""
    duplicates: int = 0
    checkpoints: int = 0
    checkpoint_ms: float = 0.0  # total time spent writing checkpoints
    checkpoint_bytes: int = 0  # size of the last one
    replays_served: int = 0

    def reject(self, key: str, reason: str) -> None:
        self.invalid[key] = self.invalid.get(key, 0) + 1
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def as_dict(self) -> dict:
        return {"service": self.service, "received": self.received, "published": self.published,
                "invalid": self.invalid, "rejected": self.rejected, "late": self.late,
                "busy_s": round(self.busy_s, 3), "counters": self.counters, "aborted": self.aborted,
                "duplicates": self.duplicates, "checkpoints": self.checkpoints,
                "checkpoint_ms": round(self.checkpoint_ms, 3), "checkpoint_bytes": self.checkpoint_bytes,
                "replays_served": self.replays_served}


def _header_seq(payload: bytes | memoryview) -> str:
    try:
        header = decode_dict(payload).get("header")
    except DecodeError:
        return "?"
    seq = header.get("seq") if isinstance(header, dict) else None
    return str(seq) if isinstance(seq, int) else "?"


class NodeRunner:
    """Drive ``node`` from ``bus`` until every input has ended."""

    def __init__(self, node: ServiceNode, bus: Bus, heartbeat_ms: int = 100, drain_timeout_s: float = 0.0,
                 supervision: Supervision | None = None):
        self.node = node
        self.supervision = supervision
        self.gate = SequenceGate(owner=node.name)
        self._index_of: dict[int, tuple[str, int]] = {}  # id(message in the merger) -> (key, transport index)
        self._last_stamp: int | None = None  # stamp of the last processed input
        self._ckpt_stamp: int | None = None
        self._asked: dict[str, float] = {}
        self.bus = bus
        self.queue: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self.progress = bus.progress_publisher(node.name)
        self.heartbeat_ns = heartbeat_ms * 1_000_000
        self.stats = RunnerStats(node.name)
        self.stop_event = threading.Event()
        self.drain_timeout_s = drain_timeout_s
        declared = type(node).io_keys(node.config)
        if (tuple(node.inputs), tuple(node.outputs)) != (tuple(declared[0]), tuple(declared[1])):
            log.warning("%s: the instance's keys %s -> %s differ from %s.io_keys(config) %s -> %s, which the "
                        "launcher wires: declare them once, in io_keys", node.name, node.inputs, node.outputs,
                        type(node).__name__, *declared)
        self._publishers = {k: bus.publisher(k, retain=supervision is not None) for k in node.outputs}
        for key in node.inputs:
            bus.subscribe(key, self.queue)
        bus.on_abort(self._on_abort)
        self.replay_server: ReplayServer | None = None
        self._consumer_progress = None
        if supervision is not None:
            self.replay_server = ReplayServer(bus, self._publishers, supervision.consumers,
                                              wake=lambda: self.queue.put_nowait((_WAKE, b"")))
            self._consumer_progress = bus.watch_progress()

    def _on_abort(self, reason: str) -> None:
        if not self.stats.aborted:
            log.error("%s: run aborted: %s", self.node.name, reason)
        self.stats.aborted = reason or "aborted"
        self.stop_event.set()

    def accept(self, merger: EventTimeMerger, key: str, data: bytes | memoryview) -> Message | str | None:
        """Decode one received frame and apply it to ``merger``.

        Returns the message pushed (data), ``"watermark"``/``"eos"``, or None when the frame
        was rejected (counted in :attr:`stats` and logged with key, seq and reason).
        """
        name = self.node.name
        try:
            frame = decode_frame(data)
        except DecodeError as exc:
            self.stats.reject(key, "bad_frame")
            log.error("%s: bad frame on %s skipped: %s", name, key, exc)
            return None
        if frame.kind == "replay":
            self.gate.replay(key, frame.index)
            return "replay"
        if frame.kind in ("watermark", "eos") and not self.gate.control(key):
            return "skipped"  # a restarted consumer out of step on this key: its replay brings them again
        if frame.kind == "watermark":
            merger.advance(key, frame.stamp)
            return "watermark"
        if frame.kind == "eos":
            merger.end(key)
            return "eos"
        if not self.gate.data(key, frame.index):
            self.stats.duplicates += 1
            return "duplicate"
        self.stats.received[key] = self.stats.received.get(key, 0) + 1
        try:
            msg = frame.message()
        except DecodeError as exc:
            self.stats.reject(key, "invalid_message")
            log.error("%s: invalid message on %s seq %s skipped: %s", name, key, _header_seq(frame.payload), exc)
            return None
        own = merger.stream_watermark(key)
        if own == END_OF_TIME:
            self.stats.reject(key, "after_end_of_stream")
            log.error("%s: message on %s seq %d after its end-of-stream skipped", name, key, msg.header.seq)
            return None
        if msg.header.stamp < own:
            self.stats.reject(key, "late")
            self.stats.late += 1
            log.error("%s: late message on %s seq %d skipped: stamp %d is older than the stream's watermark %d",
                      name, key, msg.header.seq, msg.header.stamp, own)
            return None
        merger.push(key, msg.header.stamp, msg.header.seq, msg)
        if frame.index >= 0:
            self._index_of[id(msg)] = (key, frame.index)
        return msg

    def _publish_outbox(self) -> None:
        for key, msg in self.node.take_outbox():
            self._publishers[key].send(msg)
            self.stats.published[key] = self.stats.published.get(key, 0) + 1

    def _forward_watermark(self, merger: EventTimeMerger, force: bool = False) -> None:
        wm = merger.watermark
        if wm < 0 or wm == END_OF_TIME:
            return
        out = self.node.output_watermark(wm)
        for pub in self._publishers.values():
            if force:
                pub.send_watermark(out)
            else:
                pub.heartbeat(out, self.heartbeat_ns)

    def process(self, key: str, msg: Message) -> None:
        """Hand one merged input to the node and publish what it emits.  A node exception
        is the service's failure: re-raised naming the input that provoked it."""
        self._index_of.pop(id(msg), None)
        self._last_stamp = msg.header.stamp
        try:
            self.node.process(key, msg)
        except Exception as exc:
            raise ServiceError(f"{self.node.name} failed on {key} seq {msg.header.seq} stamp "
                               f"{msg.header.stamp}: {type(exc).__name__}: {exc}") from exc
        self._publish_outbox()

    # ---- supervision ------------------------------------------------------------------
    def _positions(self) -> dict[str, int]:
        """Per input key, the transport index of the first frame not processed yet."""
        pos = {k: self.gate.expected.get(k, 0) for k in self.node.inputs}
        for key, index in self._index_of.values():  # accepted, still waiting in the merger
            pos[key] = min(pos[key], index)
        return pos

    def checkpoint(self, finished: bool = False) -> None:
        """Save the node, the input positions and the retained outputs (see :mod:`common.resume`)."""
        sup = self.supervision
        assert sup is not None
        t0 = time.perf_counter()
        positions = self._positions()
        state = {"service": self.node.name, "node": self.node.checkpoint_state(), "positions": positions,
                 "stamp": self._last_stamp, "finished": finished,
                 "outputs": {k: p.retained_state() for k, p in self._publishers.items()}}
        self.stats.checkpoint_bytes = save_checkpoint(checkpoint_path(sup.state_dir, self.node.name), state)
        report_checkpoint(self.bus, self.node.name, positions)
        self._ckpt_stamp = self._last_stamp
        self.stats.checkpoints += 1
        ms = (time.perf_counter() - t0) * 1e3
        self.stats.checkpoint_ms += ms
        log.info("%s: checkpoint at event time %s (%.1f ms, %.2f MB)", self.node.name, self._last_stamp, ms,
                 self.stats.checkpoint_bytes / 1e6)

    def _maybe_checkpoint(self) -> None:
        sup = self.supervision
        if sup is None or self._last_stamp is None:
            return
        if self._ckpt_stamp is None:
            self._ckpt_stamp = self._last_stamp  # the interval counts from the first input
        elif self._last_stamp - self._ckpt_stamp >= sup.checkpoint_interval_ns:
            self.checkpoint()

    def _restore(self) -> bool:
        """Load the last checkpoint (resume); returns True if the service had already finished."""
        sup = self.supervision
        assert sup is not None
        path = checkpoint_path(sup.state_dir, self.node.name)
        state = load_checkpoint(path)
        inputs = list(self.node.inputs)
        if state is None:
            log.warning("%s: restarted without a checkpoint: starting over, inputs replayed from the start",
                        self.node.name)
            self.gate = SequenceGate({}, catch_up=inputs, owner=self.node.name)
            return False
        self.node.restore_checkpoint(state["node"])
        for key, st in state["outputs"].items():
            if key in self._publishers:
                self._publishers[key].restore(st)
        finished = bool(state["finished"])
        self.gate = SequenceGate(state["positions"], catch_up=[] if finished else inputs, owner=self.node.name)
        self._last_stamp = self._ckpt_stamp = state["stamp"]
        log.warning("%s: resumed from %s (event time %s, inputs from %s%s)", self.node.name, path, state["stamp"],
                    state["positions"], ", already finished" if finished else "")
        return finished

    def _tick(self) -> None:
        """Ask for the replays still missing; answer the replay requests queued."""
        sup = self.supervision
        if sup is None:
            return
        if self.gate.catch_up:
            request_replays(self.bus, self.gate, self.node.name, self._asked, sup.replay_retry_s)
        assert self.replay_server is not None
        if self.replay_server.pending():
            self.stats.replays_served += self.replay_server.serve()

    def _wait_for_consumers(self, timeout_s: float) -> None:
        """Supervised end: stay (answering replays) until every consumer of the outputs finished."""
        sup = self.supervision
        assert sup is not None and self._consumer_progress is not None
        consumers = sorted(sup.consumers_of(self.node.outputs))
        deadline = time.monotonic() + timeout_s
        while not self.stop_event.is_set():
            self._tick()
            waiting = [c for c in consumers if self._consumer_progress.get(c) != END_OF_TIME]
            if not waiting:
                return
            if time.monotonic() > deadline:
                log.warning("%s: consumers %s not finished after %.0f s; leaving", self.node.name, waiting, timeout_s)
                return
            try:
                key, _data = self.queue.get(timeout=0.05)
            except queue.Empty:
                self.progress.repeat(1.0)
                continue
            if key != _WAKE:  # a restarted player sends its recording again: it learns we finished
                self.progress.repeat()

    def run(self) -> RunnerStats:
        """Process until end of stream on every input (or :attr:`stop_event`, or an abort).

        Stopped early, the runner publishes no end-of-stream (its outputs are incomplete)
        but an abort naming itself, so that nobody waits for streams that will not end.
        A node failure also aborts the run before the exception propagates (unless
        supervised: the launcher restarts the service).
        """
        node = self.node
        merger = EventTimeMerger(list(node.inputs))
        sup = self.supervision
        finished_before = self._restore() if sup is not None and sup.resume else False
        if finished_before:
            for key in node.inputs:
                merger.end(key)
        self.bus.declare_alive(node.name)
        try:
            while not merger.finished:
                if self.stop_event.is_set():
                    log.warning("%s: stopped before end of stream (%d buffered)", node.name, merger.pending())
                    break
                self._tick()
                try:
                    key, data = self.queue.get(timeout=0.2)
                except queue.Empty:
                    if self.supervision is not None:  # a restarted player learns where we are
                        self.progress.repeat(1.0)
                    continue
                if key == _WAKE:
                    continue
                res = self.accept(merger, key, data)
                if res == "duplicate":
                    self.progress.repeat()
                if res is None or res in ("duplicate", "skipped", "replay"):
                    continue
                t0 = time.perf_counter()
                for in_key, _stamp, msg in merger.pop_ready():
                    self.process(in_key, msg)
                self.stats.busy_s += time.perf_counter() - t0
                self._maybe_checkpoint()
                self._forward_watermark(merger)
                if merger.watermark >= 0:
                    self.progress.report(merger.watermark, force=self.queue.empty())
            if merger.finished and not finished_before:
                node.finish()
                self._publish_outbox()
        except BaseException as exc:
            if sup is None:
                self.bus.abort(f"service {node.name} failed: {exc}")
            raise
        self.stats.counters = dict(node.counters)
        if not merger.finished:
            if not self.stats.aborted:
                self.bus.abort(f"service {node.name} stopped before the end of its inputs")
            node.close()
            return self.stats
        self._forward_watermark(merger, force=True)
        for pub in self._publishers.values():
            pub.send_eos()
        if sup is not None and not finished_before:
            self.checkpoint(finished=True)
        self.progress.report(END_OF_TIME, force=True)  # finished normally (see common.bus)
        node.close()
        if sup is not None:
            self._wait_for_consumers(self.drain_timeout_s if self.drain_timeout_s > 0 else 3600.0)
            if self.drain_timeout_s > 0:  # the frames of the last replay reach the consumers before closing
                self.bus.drain(self._publishers.values(), 5.0, stop=self.stop_event, warn=False)
        elif self.drain_timeout_s > 0:
            self.bus.drain(self._publishers.values(), self.drain_timeout_s, stop=self.stop_event)
        self.stats.counters = dict(node.counters)
        self.stats.replays_served = self.replay_server.served if self.replay_server is not None else 0
        return self.stats


_WAKE = "@wake"  # queue item that only wakes the run loop (a replay request arrived)
