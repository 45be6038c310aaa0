"""Runs a :class:`~common.node.ServiceNode` on the bus: a :class:`~common.worker.Sink` of its
inputs and a :class:`~common.worker.Source` of its outputs (:mod:`common.worker`: the base
the player and the recorder share).

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

Live runs: ``max_queue`` > 0 bounds the input queue's data frames, ``max_queue_bytes`` > 0 their
bytes (drop oldest, counted per key in ``RunnerStats.dropped``;
:class:`common.worker.DropOldestQueue`), and ``delay_s`` > 0 -- a *test
setting* only (``debug.slow_service``, ``debug.slow_ms``) -- makes the runner sleep that long
before each input it hands to the node, to show what happens when a service falls behind.

Numbered frames (:mod:`common.codec`) already received are dropped (``RunnerStats.duplicates``).
Supervised (``supervision``, :mod:`common.resume`): the runner checkpoints the node every
``checkpoint_interval`` of event time (``RunnerStats.checkpoints``, ``checkpoint_ms``,
``checkpoint_bytes``, ``checkpoint_written_bytes``), keeps its outputs for replay, answers replay requests, and when
``supervision.resume`` restores the last checkpoint and asks its publishers for the inputs
after it.  A node failure then does not abort the run: the launcher restarts the service.

Where the service's CPU goes (``RunnerStats``, each in the run's ``--json``): ``startup_cpu_s``,
the process's CPU when the service declared itself alive (imports, the node's models and
kernels, Zenoh, warm-up; in an embedded run, the shared process's); ``node_cpu_s``, the main
thread's CPU inside the node (``process``, ``finish``: the algorithm); ``frame_path_cpu_s``, the
main thread's CPU handling frames around it (decoding, de-duplication, the event-time merge,
encoding and publishing outputs, checkpoints, progress reports).  What the process used beyond
the three (``cpu_s`` of :func:`launcher.service_cmd.process_usage`) is Zenoh's threads,
zenoh-python's callback threads, the receive loop's idle work and the end (drain).  Thread CPU
clocks, ~0.25 us per reading, four readings per frame.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

from common.bus import Bus
from common.codec import DecodeError, decode_dict, decode_frame
from common.messages import Message
from common.node import ServiceNode
from common.ordering import END_OF_TIME, EventTimeMerger
from common.resume import Retention, Supervision
from common.worker import WAKE, Sink, SinkStats, Source

__all__ = ["NodeRunner", "RunnerStats", "ServiceError"]

log = logging.getLogger(__name__)


class ServiceError(RuntimeError):
    """A service's own code failed on an input (the message names the input)."""


@dataclass
class RunnerStats(SinkStats):
    service: str
    received: dict[str, int] = field(default_factory=dict)
    published: dict[str, int] = field(default_factory=dict)
    invalid: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    late: int = 0
    busy_s: float = 0.0
    counters: dict[str, int] = field(default_factory=dict)
    checkpoint_bytes: int = 0  # size of the last checkpoint (its file and the array blocks it names)
    checkpoint_written_bytes: int = 0  # bytes the last checkpoint wrote (the file and its new blocks)
    replays_served: int = 0
    startup_cpu_s: float = 0.0     # process CPU when alive (module notes)
    node_cpu_s: float = 0.0        # main-thread CPU inside the node
    handling_cpu_s: float = 0.0    # main-thread CPU handling frames, the node's included

    def reject(self, key: str, reason: str) -> None:
        self.invalid[key] = self.invalid.get(key, 0) + 1
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def as_dict(self) -> dict[str, Any]:
        return {"service": self.service, "received": self.received, "published": self.published,
                "invalid": self.invalid, "rejected": self.rejected, "late": self.late,
                "busy_s": round(self.busy_s, 3), "counters": self.counters, "aborted": self.aborted,
                "duplicates": self.duplicates, "checkpoints": self.checkpoints,
                "checkpoint_ms": round(self.checkpoint_ms, 3), "checkpoint_bytes": self.checkpoint_bytes,
                "checkpoint_written_bytes": self.checkpoint_written_bytes,
                "replays_served": self.replays_served, "dropped": self.dropped, "missing": self.missing,
                "lost": self.lost, "startup_cpu_s": round(self.startup_cpu_s, 3),
                "node_cpu_s": round(self.node_cpu_s, 3),
                "frame_path_cpu_s": round(max(0.0, self.handling_cpu_s - self.node_cpu_s), 3)}


def _header_seq(payload: bytes | memoryview) -> str:
    try:
        header = decode_dict(payload).get("header")
    except DecodeError:
        return "?"
    seq = header.get("seq") if isinstance(header, dict) else None
    return str(seq) if isinstance(seq, int) else "?"


class NodeRunner(Sink, Source):
    """Drive ``node`` from ``bus`` until every input has ended."""

    stats: RunnerStats

    def __init__(self, node: ServiceNode[Any], bus: Bus, heartbeat_ms: int = 100, drain_timeout_s: float = 0.0,
                 supervision: Supervision | None = None, max_queue: int = 0, delay_s: float = 0.0,
                 max_queue_bytes: int = 0):
        self.node = node
        declared = type(node).io_keys(node.config)
        if (tuple(node.inputs), tuple(node.outputs)) != (tuple(declared[0]), tuple(declared[1])):
            log.warning("%s: the instance's keys %s -> %s differ from %s.io_keys(config) %s -> %s, which the "
                        "launcher wires: declare them once, in io_keys", node.name, node.inputs, node.outputs,
                        type(node).__name__, *declared)
        self._publishers = {k: bus.publisher(k, retain=supervision is not None) for k in node.outputs}
        super().__init__(node.name, bus, RunnerStats(node.name), supervision, drain_timeout_s)
        self.subscribe(node.inputs, max_queue, max_queue_bytes)
        self.delay_s = delay_s
        self._index_of: dict[int, tuple[str, int]] = {}  # id(message in the merger) -> (key, transport index)
        self._last_stamp: int | None = None  # stamp of the last processed input
        self.heartbeat_ns = heartbeat_ms * 1_000_000
        self._merger = EventTimeMerger(list(node.inputs))
        self._consumer_progress = None
        # a live run: what the outputs keep for restarted consumers is bounded (live.retain_s / retain_mb)
        self._retention = (Retention(supervision.retain_ns, supervision.retain_bytes)
                           if supervision is not None and supervision.live else None)
        if supervision is not None:
            self.serve_replays_for(self._publishers, wake=self.wake)
            self._consumer_progress = bus.watch_progress(supervision.consumers_of(node.outputs))

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
            self.gate.replay(key, frame.index, frame.type_name)
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
            pub = self._publishers[key]
            pub.send(msg)
            if self._retention is not None:
                self._retention.sent(pub, msg.header.stamp)
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
        if self.delay_s > 0:  # test setting: a service that falls behind (debug.slow_service)
            time.sleep(self.delay_s)
        c0 = time.thread_time()
        try:
            self.node.process(key, msg)
        except Exception as exc:
            raise ServiceError(f"{self.node.name} failed on {key} seq {msg.header.seq} stamp "
                               f"{msg.header.stamp}: {type(exc).__name__}: {exc}") from exc
        self.stats.node_cpu_s += time.thread_time() - c0
        self._publish_outbox()

    # ---- the receive loop (common.worker.Sink) ------------------------------------------
    def finished(self) -> bool:
        return self._merger.finished

    def tick(self) -> None:
        """Ask for the replays still missing; answer the replay requests queued."""
        super().tick()
        self.stats.replays_served += self.serve_replays()

    def on_frame(self, key: str, data: bytes) -> None:
        c0 = time.thread_time()
        try:
            self._handle_frame(key, data)
        finally:
            self.stats.handling_cpu_s += time.thread_time() - c0

    def _handle_frame(self, key: str, data: bytes) -> None:
        merger = self._merger
        res = self.accept(merger, key, data)
        if res is None:
            return
        if type(res) is str:  # never compared with a message: that is pydantic's __eq__, per frame
            if res == "duplicate":
                self.progress.repeat()
            if res in ("duplicate", "skipped", "replay"):
                return
        t0 = time.perf_counter()
        for in_key, _stamp, msg in merger.pop_ready():
            self.process(in_key, msg)
        self.stats.busy_s += time.perf_counter() - t0
        sup = self.supervision
        if sup is not None and self.checkpoint_due(self._last_stamp, sup.checkpoint_interval_ns):
            self.checkpoint()
        self._forward_watermark(merger)
        if merger.watermark >= 0:
            self.progress.report(merger.watermark, force=self.queue.empty())

    # ---- supervision ------------------------------------------------------------------
    def _positions(self) -> dict[str, int]:
        """Per input key, the transport index of the first frame not processed yet."""
        pos = {k: self.gate.expected.get(k, 0) for k in self.node.inputs}
        for key, index in self._index_of.values():  # accepted, still waiting in the merger
            pos[key] = min(pos[key], index)
        return pos

    def checkpoint(self, finished: bool = False) -> None:
        """Save the node, the input positions and the retained outputs (see :mod:`common.resume`)."""
        t0 = time.perf_counter()
        positions = self._positions()
        state = {"service": self.node.name, "node": self.node.checkpoint_state(), "positions": positions,
                 "stamp": self._last_stamp, "finished": finished,
                 "outputs": {k: p.retained_state() for k, p in self._publishers.items()}}
        size = self.save_state(state, positions, self._last_stamp, t0)
        self.stats.checkpoint_bytes, self.stats.checkpoint_written_bytes = size.total, size.written

    def _restore(self) -> bool:
        """Load the last checkpoint (resume); returns True if the service had already finished."""
        state = self.load_state()
        inputs = list(self.node.inputs)
        if state is None:
            log.warning("%s: restarted without a checkpoint: starting over, inputs replayed from the start",
                        self.node.name)
            self.resume_gate({}, inputs)
            return False
        self.node.restore_checkpoint(state["node"])
        for key, st in state["outputs"].items():
            if key in self._publishers:
                self._publishers[key].restore(st)
        finished = bool(state["finished"])
        self.resume_gate(state["positions"], [] if finished else inputs)
        self._last_stamp = self._ckpt_stamp = state["stamp"]
        log.warning("%s: resumed from %s (event time %s, inputs from %s%s)", self.node.name, self.state_path(),
                    state["stamp"], state["positions"], ", already finished" if finished else "")
        return finished

    def _idle(self) -> None:
        """While waiting for the consumers: a frame from a restarted player is answered with
        our progress (it learns we finished)."""
        item = self.next_frame(0.05)
        if item is not None and item[0] != WAKE:
            self.progress.repeat()

    # ---- run ----------------------------------------------------------------------------
    def run(self) -> RunnerStats:
        """Process until end of stream on every input (or :attr:`stop_event`, or an abort).

        Stopped early, the runner publishes no end-of-stream (its outputs are incomplete)
        but an abort naming itself, so that nobody waits for streams that will not end.
        A node failure also aborts the run before the exception propagates (unless
        supervised: the launcher restarts the service).
        """
        node, merger, sup = self.node, self._merger, self.supervision
        finished_before = self._restore() if sup is not None and sup.resume else False
        if finished_before:
            for key in node.inputs:
                merger.end(key)
        else:
            t0 = time.perf_counter()
            node.warm_up()
            log.debug("%s: warmed up in %.2f s", node.name, time.perf_counter() - t0)
        self.stats.startup_cpu_s = time.process_time()
        self.bus.declare_alive(node.name)
        try:
            if not self.receive():
                log.warning("%s: stopped before end of stream (%d buffered)", node.name, merger.pending())
            if merger.finished and not finished_before:
                c0 = time.thread_time()
                node.finish()
                finish_s = time.thread_time() - c0
                self.stats.node_cpu_s += finish_s
                self.stats.handling_cpu_s += finish_s  # node time is inside the handling total
                self._publish_outbox()
        except BaseException as exc:
            if sup is None:
                self.abort_run(f"service {node.name} failed: {exc}")
            raise
        self.stats.counters = dict(node.counters)
        if not merger.finished:
            if not self.stats.aborted:
                self.abort_run(f"service {node.name} stopped before the end of its inputs")
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
            assert self._consumer_progress is not None
            self.await_consumers(sup.consumers_of(node.outputs), self._consumer_progress, self.tick, self._idle)
        self.drain(self._publishers.values(), self.tick)
        self.stats.counters = dict(node.counters)
        self.stats.replays_served = self.replays_served
        return self.stats
