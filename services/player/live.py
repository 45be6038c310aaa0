"""Live player: a recording played as a live source, paced by the wall clock
(``poseidon run --live mcap --input REC.mcap [--rate R]``).

What a vehicle's sensors do, without ROS: each message of the recording is published at its
own time -- ``start + (stamp - first stamp) / rate`` of wall time -- through
:class:`common.live.LiveSource`, like the ROS 1 bridge and :class:`common.driver.SensorDriver`
(wall-clock watermarks with the lateness bound ``live.lateness_ms`` every
``live.watermark_interval_ms``; it never waits for its consumers; a consumer that falls behind
drops from its bounded queue, counted).  Payloads are sent byte for byte as recorded.  Source
keys the services read that the recording does not have get end-of-stream at once (as the
replay player does), so no service waits 2 s for a sensor that will never speak.

It measures latency as the bridge does (:class:`common.live.LatencyTracker`: the wall time
from a message's publication to the output of the same stamp coming back, per stage) and, at
the end -- the recording exhausted, or :meth:`stop` -- sends end-of-stream on its keys, follows
the services' outputs until they end (or 2 s without any), and publishes the latency on
``live/latency`` (recorded with the run).  ``behind_ms`` says how late the player itself was
against its schedule (p99 and max): a source that cannot keep its pace would make the
latency figures meaningless.

It is the ROS-free live source of the tests and of ``benchmarks/bench_live.py``, and lets a
user try a live deployment (its queues, its drop policy) on any recording.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from common.bus import Bus
from common.codec import DecodeError, decode_frame
from common.live import HEALTH_KEY, LATENCY_KEY, LatencyTracker, LiveSource, follow_outputs, publish_latency
from common.mcap_io import read_messages, recording_keys
from common.ordering import END_OF_TIME
from common.worker import WAKE, Sink, SinkStats, Source
from services.player.player import SOURCE_KEYS

__all__ = ["LivePlayer", "LivePlayerStats", "LIVE_PLAYER_NAME"]

log = logging.getLogger(__name__)

LIVE_PLAYER_NAME = "live_player"


@dataclass
class LivePlayerStats(SinkStats):
    """``input``, ``rate``; ``published`` / ``late`` per key (:mod:`common.live`); ``watermarks``
    sent; ``behind_ms``: ``p99`` / ``max`` of how late each message left against its schedule;
    ``latency``: per stage (:meth:`common.live.LatencyTracker.summary`); ``complete``: the whole
    recording was published (False when stopped before its end); ``retention`` (supervised):
    :meth:`common.live.LiveSource.retention_summary`; ``outages`` / ``delivered_late`` per key:
    the outage rule of :mod:`common.live` (a hub that restarted: every key's consumers were gone
    for a while, its frames held and sent when they were back); ``stalls`` / ``stalled_s`` per
    key: silences long enough to be taken for a stall (the player held up) and the wall time
    they held its watermark back [s] (:mod:`common.live`: Stalls)."""

    input: str = ""
    rate: float = 1.0
    published: dict[str, int] = field(default_factory=dict)
    late: dict[str, int] = field(default_factory=dict)
    watermarks: int = 0
    behind_ms: dict[str, float] = field(default_factory=dict)
    latency: dict[str, dict[str, float]] = field(default_factory=dict)
    complete: bool = False
    retention: dict[str, Any] = field(default_factory=dict)
    outages: dict[str, int] = field(default_factory=dict)
    delivered_late: dict[str, int] = field(default_factory=dict)
    stalls: dict[str, int] = field(default_factory=dict)
    stalled_s: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"service": LIVE_PLAYER_NAME, "input": self.input, "rate": self.rate, "published": self.published,
                "late": self.late, "watermarks": self.watermarks, "behind_ms": self.behind_ms,
                "latency": self.latency, "complete": self.complete, "dropped": self.dropped,
                "aborted": self.aborted, "retention": self.retention, "outages": self.outages,
                "delivered_late": self.delivered_late, "stalls": self.stalls, "stalled_s": self.stalled_s}


class LivePlayer(Sink, Source):
    """Publish ``keys`` of the recording at ``path`` (default all but ``live/latency``) live at
    ``rate`` x real time (module notes); ``stages``: output key -> latency stage;
    ``report_wait_s``: how long the latency report waits for its consumer (the recorder)."""

    stats: LivePlayerStats

    def __init__(self, bus: Bus, path: str | Path, stages: Mapping[str, str], rate: float = 1.0,
                 keys: Iterable[str] | None = None, lateness_ms: int = 200, watermark_interval_ms: int = 100,
                 announce: Iterable[str] = (), report_wait_s: float = 10.0,
                 consumers: Mapping[str, list[str]] | None = None, retain_s: float = 300.0,
                 retain_mb: float = 256.0, end_wait_s: float = 120.0, stall_hold_ms: int = 2000):
        if not rate > 0:
            raise ValueError(f"live player: --rate must be > 0 (x real time), got {rate}")
        super().__init__(LIVE_PLAYER_NAME, bus, LivePlayerStats(input=str(path), rate=rate), None, 0.0)
        self.path = Path(path)
        self.rate = rate
        have = [k for k in recording_keys(self.path) if k not in (LATENCY_KEY, HEALTH_KEY)]
        self.keys = sorted(k for k in have if keys is None or k in set(keys))
        self.absent = sorted(k for k in set(announce) | set(SOURCE_KEYS) if k not in self.keys)
        self.interval_s = watermark_interval_ms / 1000
        if consumers is None:
            self.source = LiveSource(bus, lateness_ms * 1_000_000, stall_hold_ns=stall_hold_ms * 1_000_000)
        else:  # supervised: keep frames for restarted consumers (bounded by retain_s / retain_mb)
            self.source = LiveSource(bus, lateness_ms * 1_000_000, announce=self.keys, outage_frames=1 << 62,
                                     outage_bytes=int(retain_mb * 1e6), retain_ns=int(retain_s * 1e9),
                                     stall_hold_ns=stall_hold_ms * 1_000_000)
            self.source.serve_replays({k: list(v) for k, v in consumers.items()})
        self.consumers = sorted({c for k in self.keys for c in (consumers or {}).get(k, [])})
        self.end_wait_s = end_wait_s
        self.latency = LatencyTracker()
        self.stages = dict(stages)
        self.report_wait_s = report_wait_s
        self._ended: set[str] = set()
        self.subscribe(sorted(self.stages))
        self._progress = bus.watch_progress(self.consumers)

    def finished(self) -> bool:
        return False  # ends when the recording is exhausted or on stop (run)

    def on_frame(self, key: str, data: bytes) -> None:
        """An output of a service: its latency (stage by key), matched by stamp."""
        try:
            frame = decode_frame(data)
            if frame.kind == "eos":
                self._ended.add(key)
            if frame.kind != "data":
                return
            stamp = frame.message().header.stamp
        except DecodeError as exc:
            log.error("live player: frame on %s skipped: %s", key, exc)
            return
        stage = self.stages.get(key)
        if stage is not None:
            self.latency.output(stage, stamp, time.time_ns())

    def _wait_until(self, due: float, next_wm: float) -> float:
        """Receive outputs and send watermarks until ``due`` (monotonic s); the next watermark time."""
        while not self.stop_event.is_set():
            now = time.monotonic()
            if now >= next_wm:
                self.source.send_watermarks(time.time_ns())
                next_wm = now + self.interval_s
            if now >= due:
                return next_wm
            item = self.next_frame(max(0.0, min(due, next_wm) - now))
            if item is not None and item[0] != WAKE:
                self.on_frame(*item)
        return next_wm

    def run(self) -> LivePlayerStats:
        """Publish the recording at its pace, then end every stream and report the latency."""
        for key in self.absent:  # a sensor the recording does not have: nobody waits for it
            self.bus.publisher(key).send_eos()
        self.bus.declare_alive(self.name)
        behind: list[float] = []
        log.info("live player: %s at %.3gx real time on %d keys", self.path, self.rate, len(self.keys))
        try:
            t0 = next_wm = time.monotonic()
            first: int | None = None
            for rec in read_messages(self.path, self.keys):
                first = rec.stamp if first is None else first
                due = t0 + (rec.stamp - first) / 1e9 / self.rate
                next_wm = self._wait_until(due, next_wm)
                if self.stop_event.is_set():
                    break
                behind.append(time.monotonic() - due)
                arrival = time.time_ns()
                self.latency.arrived(rec.stamp, arrival)
                self.source.publish_data(rec.key, rec.type_name, rec.payload, rec.stamp, arrival)
                self.progress.report(self.source.newest_stamp)  # how far the source is: the run's health
            else:
                self.stats.complete = True
        finally:
            self.source.end()
            follow_outputs(self, self.stages, self._ended, self.on_frame)
            counters = self.source.counters()
            self.stats.published, self.stats.late = counters["published"], counters["late"]
            self.stats.watermarks = counters["watermarks"]
            self.stats.stalls, self.stats.stalled_s = counters["stalls"], counters["stalled_s"]
            self.stats.retention = self.source.retention_summary()
            self.stats.outages, self.stats.delivered_late = counters["outages"], counters["delivered_late"]
            if behind:
                b = np.asarray(behind) * 1000
                self.stats.behind_ms = {"p99": round(float(np.percentile(b, 99)), 3), "max": round(float(b.max()), 3)}
            self.stats.latency = self.latency.summary()
            publish_latency(self.bus, self.latency.report(self.name, self.rate), self.report_wait_s,
                            meanwhile=self._await_consumers)
        return self.stats

    def _await_consumers(self) -> None:
        """Supervised: stay, answering replays, until every consumer of the played keys finished
        (a service restarted near the end catches up from this source), at most ``end_wait_s``."""
        if not self.consumers:
            return
        deadline = time.monotonic() + self.end_wait_s
        while time.monotonic() < deadline and not self.stop_event.is_set():
            self.source.serve_pending()
            waiting = [c for c in self.consumers if self._progress.get(c) != END_OF_TIME]
            if not waiting:
                return
            item = self.next_frame(0.1)
            if item is not None and item[0] != WAKE:
                self.on_frame(*item)
        waiting = [c for c in self.consumers if self._progress.get(c) != END_OF_TIME]
        if waiting:
            log.warning("live player: consumers %s still not finished after %.0f s", waiting, self.end_wait_s)
