"""Runs a :class:`~common.node.ServiceNode` on the bus.

The runner subscribes to the node's inputs, merges them by event time
(:class:`~common.ordering.EventTimeMerger`), calls the node, publishes its outputs, reports
its progress (event time consumed, for the player's flow control), and forwards event-time
watermarks (rate-limited to ``bus.heartbeat_interval_ms`` of event
time) and end-of-stream so downstream services can merge deterministically too.
Any frame that cannot be used is a counted, logged rejection (key, seq when readable, the
reason), never an exception: malformed frames and messages that fail validation
(:mod:`common.codec`), data older than its own stream's watermark (``late``: it would be
processed out of event-time order) and data after the stream's end-of-stream.  Rejections
per key are in ``RunnerStats.invalid``, per reason in ``RunnerStats.rejected``.  An
exception raised by the node itself is a failure of the service: it propagates, naming
the key, seq and stamp of the input being processed.  On a normal end the runner reports
progress ``END_OF_TIME`` (the service finished, see :mod:`common.bus`); an ``@abort`` on
the bus stops it (``RunnerStats.aborted`` says why).
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field

from common.bus import Bus
from common.codec import DecodeError, decode_dict, decode_frame
from common.node import ServiceNode
from common.messages import Message
from common.ordering import END_OF_TIME, EventTimeMerger

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

    def reject(self, key: str, reason: str) -> None:
        self.invalid[key] = self.invalid.get(key, 0) + 1
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def as_dict(self) -> dict:
        return {"service": self.service, "received": self.received, "published": self.published,
                "invalid": self.invalid, "rejected": self.rejected, "late": self.late,
                "busy_s": round(self.busy_s, 3), "counters": self.counters, "aborted": self.aborted}


def _header_seq(payload: bytes | memoryview) -> str:
    try:
        header = decode_dict(payload).get("header")
    except DecodeError:
        return "?"
    seq = header.get("seq") if isinstance(header, dict) else None
    return str(seq) if isinstance(seq, int) else "?"


class NodeRunner:
    """Drive ``node`` from ``bus`` until every input has ended."""

    def __init__(self, node: ServiceNode, bus: Bus, heartbeat_ms: int = 100, drain_timeout_s: float = 0.0):
        self.node = node
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
        self._publishers = {k: bus.publisher(k) for k in node.outputs}
        for key in node.inputs:
            bus.subscribe(key, self.queue)
        bus.on_abort(self._on_abort)

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
        if frame.kind == "watermark":
            merger.advance(key, frame.stamp)
            return "watermark"
        if frame.kind == "eos":
            merger.end(key)
            return "eos"
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
            if force or out >= pub.watermark + self.heartbeat_ns:
                pub.send_watermark(out)

    def process(self, key: str, msg: Message) -> None:
        """Hand one merged input to the node and publish what it emits.  A node exception
        is the service's failure: re-raised naming the input that provoked it."""
        try:
            self.node.process(key, msg)
        except Exception as exc:
            raise ServiceError(f"{self.node.name} failed on {key} seq {msg.header.seq} stamp "
                               f"{msg.header.stamp}: {type(exc).__name__}: {exc}") from exc
        self._publish_outbox()

    def run(self) -> RunnerStats:
        """Process until end of stream on every input (or :attr:`stop_event`, or an abort).

        Stopped early, the runner publishes no end-of-stream (its outputs are incomplete)
        but an abort naming itself, so that nobody waits for streams that will not end.
        A node failure also aborts the run before the exception propagates.
        """
        node = self.node
        merger = EventTimeMerger(list(node.inputs))
        self.bus.declare_alive(node.name)
        try:
            while not merger.finished:
                if self.stop_event.is_set():
                    log.warning("%s: stopped before end of stream (%d buffered)", node.name, merger.pending())
                    break
                try:
                    key, data = self.queue.get(timeout=0.2)
                except queue.Empty:
                    continue
                if self.accept(merger, key, data) is None:
                    continue
                t0 = time.perf_counter()
                for in_key, _stamp, msg in merger.pop_ready():
                    self.process(in_key, msg)
                self.stats.busy_s += time.perf_counter() - t0
                self._forward_watermark(merger)
                if merger.watermark >= 0:
                    self.progress.report(merger.watermark, force=self.queue.empty())
            if merger.finished:
                node.finish()
                self._publish_outbox()
        except BaseException as exc:
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
        self.progress.report(END_OF_TIME, force=True)  # finished normally (see common.bus)
        node.close()
        if self.drain_timeout_s > 0:
            self.bus.drain(self._publishers.values(), self.drain_timeout_s, stop=self.stop_event)
        self.stats.counters = dict(node.counters)
        return self.stats
