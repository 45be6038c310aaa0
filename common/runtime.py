"""Runs a :class:`~common.node.ServiceNode` on the bus.

The runner subscribes to the node's inputs, merges them by event time
(:class:`~common.ordering.EventTimeMerger`), calls the node, publishes its outputs, reports
its progress (event time consumed, for the player's flow control), and forwards event-time
watermarks (rate-limited to ``bus.heartbeat_interval_ms`` of event
time) and end-of-stream so downstream services can merge deterministically too.
A message that fails validation is logged with its key and seq, counted and skipped.
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
from common.ordering import END_OF_TIME, EventTimeMerger

__all__ = ["NodeRunner", "RunnerStats"]

log = logging.getLogger(__name__)


@dataclass
class RunnerStats:
    service: str
    received: dict[str, int] = field(default_factory=dict)
    published: dict[str, int] = field(default_factory=dict)
    invalid: dict[str, int] = field(default_factory=dict)
    late: int = 0
    busy_s: float = 0.0
    counters: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"service": self.service, "received": self.received, "published": self.published,
                "invalid": self.invalid, "late": self.late, "busy_s": round(self.busy_s, 3),
                "counters": self.counters}


def _header_seq(payload: bytes | memoryview) -> str:
    try:
        return str(decode_dict(payload).get("header", {}).get("seq", "?"))
    except (DecodeError, AttributeError):
        return "?"


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
        self._publishers = {k: bus.publisher(k) for k in node.outputs}
        for key in node.inputs:
            bus.subscribe(key, self.queue)

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

    def run(self) -> RunnerStats:
        """Process until end of stream on every input (or :attr:`stop_event`)."""
        node = self.node
        merger = EventTimeMerger(list(node.inputs))
        self.bus.declare_alive(node.name)
        while not merger.finished:
            if self.stop_event.is_set():
                log.warning("%s: stopped before end of stream (%d buffered)", node.name, merger.pending())
                break
            try:
                key, data = self.queue.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                frame = decode_frame(data)
            except DecodeError as exc:
                self.stats.invalid[key] = self.stats.invalid.get(key, 0) + 1
                log.error("%s: bad frame on %s skipped: %s", node.name, key, exc)
                continue
            if frame.kind == "data":
                self.stats.received[key] = self.stats.received.get(key, 0) + 1
                try:
                    msg = frame.message()
                except (DecodeError, KeyError) as exc:
                    self.stats.invalid[key] = self.stats.invalid.get(key, 0) + 1
                    log.error("%s: invalid message on %s seq %s skipped: %s", node.name, key,
                              _header_seq(frame.payload), exc)
                    continue
                merger.push(key, msg.header.stamp, msg.header.seq, msg)
            elif frame.kind == "watermark":
                merger.advance(key, frame.stamp)
            else:
                merger.end(key)
            t0 = time.perf_counter()
            for in_key, _stamp, msg in merger.pop_ready():
                node.process(in_key, msg)
                self._publish_outbox()
            self.stats.busy_s += time.perf_counter() - t0
            self._forward_watermark(merger)
            if merger.watermark >= 0:
                self.progress.report(merger.watermark, force=self.queue.empty())
        if merger.finished:
            node.finish()
            self._publish_outbox()
        self._forward_watermark(merger, force=True)
        for pub in self._publishers.values():
            pub.send_eos()
        node.close()
        if self.drain_timeout_s > 0 and not self.stop_event.is_set():
            self.bus.drain(self._publishers.values(), self.drain_timeout_s)
        self.stats.late = merger.late
        self.stats.counters = dict(node.counters)
        return self.stats
