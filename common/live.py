"""Live sources: event-time watermarks from the wall clock, and publishing without waiting.

The rule (also in README, "Live on the vehicle"): a ROS header stamp is mapped to the wall
clock by tracking, per stream (our key), the offset ``arrival wall time - header stamp`` of
its latest message.  At wall time ``now`` a stream then promises (watermark) that nothing
older than ``now - offset - lateness`` will still come: ``lateness`` (``bridge_ros1.lateness_ms``)
bounds how much more than its predecessor a message may be delayed between its sensor and
the bridge.  A stream that has never had a message uses the offset of the latest message of
any stream (one vehicle, one clock) and a wider bound, ``lateness`` + :data:`UNSEEN_GRACE_NS`
(2 s), so a silent sensor does not stall the event-time merge of the services downstream
(it delays them by 2.2 s) while a sensor whose first message is slow to come through (a ROS
subscription still connecting when ``rosbag play`` starts: 4 keys' first messages were late
by ~0.2 s in a 1x live run) is not late; before any message at all there is no watermark.  Tracking the
latest offset (not the smallest) follows a clock that runs at another rate than the wall
(``rosbag play -r 8``: the offsets shrink, the watermarks follow).  A message older than what
its stream already promised is *late*: it is still published (and recorded) but counted, and
the services reject it as late (:mod:`common.runtime`).

Stalls (``stall_hold_ms``, default 2 s): a stream that has been silent for longer than
``STALL_GAPS`` (4) of its usual gaps between messages (a mean over its recent arrivals), and at
least half the lateness bound, is taken to be held up on its way (``rosbag play`` or the
driver starved of CPU, a rospy thread descheduled, a link pausing), not to have stopped.  Its
watermark then stays where it was at that moment, for at most ``stall_hold_ms``, so the
messages that come out of the stall are not late; its first message ends the hold.  After the
hold the plain rule applies again (the watermark jumps to it), so a sensor that really stopped
holds the services back once, by at most the threshold plus the hold, and never after.  A
stream's gaps are known from its second message on; before that it is never held.  ``0`` gives
the plain rule.

Outages (also in README, "Live on the vehicle"): a live source never waits, but it does not
lose data silently when its consumers become unreachable (its own link to the hub, or the
hub's link to the computer of the consumers, is down).  Every key keeps its last
``outage_frames`` data frames (at most ``outage_bytes``), numbered by the bus
(:class:`common.bus.BusPublisher` ``retain``).  A key that had a subscriber and has none left
(Zenoh's matching status: a cut link is seen when Zenoh closes the transport, its queue
blocked too long or its lease expired -- measured 6 to 9 s after the cut) is in an *outage*: its new messages are kept but not sent, and no watermark is sent for it.  When
a subscriber matches again, every frame kept is sent again, oldest first, before anything
newer: the frames held meanwhile are counted ``delivered_late``; those sent before the outage
was noticed are counted ``resent`` (a consumer that already has them drops them as duplicates,
:class:`common.resume.SequenceGate`, and keeps the ones lost in flight).  A held frame pushed
out of the bound (drop-oldest), or still held at :meth:`LiveSource.end`, is counted
``dropped_outage``: it never reached anyone.  Frames lost in flight before the outage was
noticed and no longer kept are not known here; the consumer counts every frame it never
received (``missing``, from the frame numbers), so recorded + missing == published, always.
The rule is per key and per source: a key that still has a consumer somewhere (one on the
source's side of the cut) is not in an outage, and what the consumers beyond the cut miss
meanwhile is counted only by them (``missing``).
Event time: the held frames are not late when they arrive (their stream sent no watermark
past them; watermarks resume after them), so the services process them normally, in order, a
little later in wall time; a service whose bounded live queue overflows with the burst drops
its oldest inputs, counted ``dropped`` as any overflow.

Latency (:class:`LatencyTracker`): a live source notes when each input stamp arrived and, for
the services' outputs it subscribes to (each carries the stamp of the input that caused it),
the wall time until the output of that stamp came back, per stage; once the outputs ended
(:func:`follow_outputs`) it publishes the percentiles as a :class:`common.messages.LatencyReport`
on :data:`LATENCY_KEY` (:func:`publish_latency`), which the run's recorder keeps.

Everything here takes the wall time as an argument: the source reads the clock, :class:`LiveClock`
only computes (unit-tested without a clock).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from common.bus import Bus, BusPublisher
from common.codec import encode, encode_frame
from common.messages import Header, LatencyReport, LatencyStage, Message
from common.resume import ReplayServer, Retention
from common.worker import WAKE, Sink

__all__ = ["LiveClock", "LiveSource", "LatencyTracker", "LATENCY_KEY", "HEALTH_KEY", "publish_latency",
           "follow_outputs"]

log = logging.getLogger(__name__)


def _bump(d: dict[str, int], k: str, n: int = 1) -> None:
    if n:
        d[k] = d.get(k, 0) + n


#: the key of a live run's :class:`common.messages.LatencyReport`
LATENCY_KEY = "live/latency"
#: the key of a live run's health, a :class:`common.messages.DiagnosticArray` (``launcher/health.py``)
HEALTH_KEY = "live/health"

#: extra bound of a stream that has not had a message yet (ns; see the module doc)
UNSEEN_GRACE_NS = 2_000_000_000
#: longest a stalled stream's watermark is held back (ns; see the module doc: Stalls)
STALL_HOLD_NS = 2_000_000_000
#: a stream silent for more than this many of its mean gaps (and half the lateness bound) is stalled
STALL_GAPS = 4
#: weight of the latest gap in a stream's mean gap (exponential mean over ~20 arrivals)
GAP_WEIGHT = 0.05


class LiveClock:
    """Per-stream offset between header stamps and arrival (ns), and the watermarks it allows."""

    def __init__(self, lateness_ns: int, unseen_grace_ns: int = UNSEEN_GRACE_NS, stall_hold_ns: int = STALL_HOLD_NS):
        if lateness_ns < 0 or unseen_grace_ns < 0 or stall_hold_ns < 0:
            raise ValueError(f"lateness, grace and stall hold must be >= 0 ns, got {lateness_ns}, {unseen_grace_ns}, "
                             f"{stall_hold_ns}")
        self.lateness_ns = lateness_ns
        self.unseen_grace_ns = unseen_grace_ns
        self.stall_hold_ns = stall_hold_ns
        self.stalls: dict[str, int] = {}  # key -> silences that held its watermark back
        self.stalled_ns: dict[str, int] = {}  # key -> wall time they held it back, in all
        self._offset: dict[str, int] = {}
        self._latest: int | None = None  # offset of the latest message of any stream
        self._arrival: dict[str, int] = {}  # key -> arrival of its latest message
        self._gap: dict[str, float] = {}  # key -> mean wall time between its arrivals (exponential, ns)
        self._held: dict[str, int] = {}  # key -> how long its current silence has held it back so far
        self._promised: dict[str, int] = {}  # key -> watermark sent
        self._last_stamp: dict[str, int] = {}

    def observe(self, key: str, stamp_ns: int, arrival_ns: int) -> bool:
        """A message of ``key`` stamped ``stamp_ns`` arrived at ``arrival_ns``; True when it is
        late (older than what the stream already promised, or than its previous message)."""
        late = stamp_ns < self._promised.get(key, -1) or stamp_ns < self._last_stamp.get(key, -1)
        self._offset[key] = self._latest = arrival_ns - stamp_ns
        before = self._arrival.get(key)
        if before is not None:
            gap = max(arrival_ns - before, 0)
            mean = self._gap.get(key)
            self._gap[key] = gap if mean is None else mean + GAP_WEIGHT * (gap - mean)
        self._arrival[key] = arrival_ns if before is None else max(before, arrival_ns)
        self._held.pop(key, None)
        self._last_stamp[key] = max(stamp_ns, self._last_stamp.get(key, -1))
        return late

    def watermark(self, key: str, now_ns: int) -> int | None:
        """The promise stream ``key`` can make at ``now_ns`` if it is newer than what it already
        promised and than its last message's stamp (then it is recorded as promised); else None."""
        offset = self._offset.get(key)
        bound = self.lateness_ns
        if offset is None:
            offset, bound = self._latest, self.lateness_ns + self.unseen_grace_ns
        if offset is None:
            return None
        wm = now_ns - self.hold(key, now_ns) - offset - bound  # hold: 0 for a stream that has not spoken
        if wm <= self._promised.get(key, -1) or wm <= self._last_stamp.get(key, -1):
            return None
        self._promised[key] = wm
        return wm

    def hold(self, key: str, now_ns: int) -> int:
        """How much wall time stream ``key``'s watermark is held back at ``now_ns`` (module notes:
        Stalls): its silence beyond ``STALL_GAPS`` of its mean gaps (at least half the lateness
        bound), while that is at most ``stall_hold_ns``; else 0.  Counts ``stalls``/``stalled_ns``."""
        gap = self._gap.get(key)
        if gap is None or not self.stall_hold_ns:
            return 0
        held = now_ns - self._arrival[key] - max(self.lateness_ns // 2, int(STALL_GAPS * gap))
        if held <= 0 or held > self.stall_hold_ns:
            return 0
        before = self._held.get(key)
        if before is None:
            self.stalls[key] = self.stalls.get(key, 0) + 1
            before = 0
        if held > before:
            self.stalled_ns[key] = self.stalled_ns.get(key, 0) + held - before
            self._held[key] = held
        return held



class LiveSource:
    """What every live source shares (the ROS 1 bridge, :class:`common.driver.SensorDriver`):
    publishing a message at once on its key (never waiting for consumers), the stream's
    watermarks from the wall clock (:class:`LiveClock`, on every key published or
    ``announce``-d), end-of-stream on all of them at the end, and the outage rule of the module
    notes (``outage_frames``/``outage_bytes`` per key).  Thread-safe; counters ``published``,
    ``late``, ``delivered_late``, ``resent``, ``dropped_outage``, ``outages`` (per key) and
    ``watermarks`` (:meth:`counters`)."""

    def __init__(self, bus: Bus, lateness_ns: int, announce: Iterable[str] = (), outage_frames: int = 1000,
                 outage_bytes: int = 64 << 20, retain_ns: int = 0, stall_hold_ns: int = STALL_HOLD_NS):
        if outage_frames < 1 or outage_bytes < 1 or retain_ns < 0:
            raise ValueError(f"the outage buffer needs >= 1 frame and byte and a retention >= 0 ns, got "
                             f"{outage_frames}, {outage_bytes}, {retain_ns}")
        self.bus = bus
        self.clock = LiveClock(lateness_ns, stall_hold_ns=stall_hold_ns)
        self.announce = set(announce)
        self.outage_frames, self.outage_bytes = outage_frames, outage_bytes
        self.retention = Retention(retain_ns, 0)  # the age bound; outage_* bound frames and bytes
        self._replay: ReplayServer | None = None
        self.retained_peak = 0  # bytes kept by all keys at once, at most
        self.newest_stamp = -1  # the newest stamp published (event time, ns): a live run's health
        self.published: dict[str, int] = {}
        self.late: dict[str, int] = {}
        self.delivered_late: dict[str, int] = {}
        self.resent: dict[str, int] = {}
        self.dropped_outage: dict[str, int] = {}
        self.outages: dict[str, int] = {}
        self.watermarks = 0
        self.ended = False
        self._pubs: dict[str, BusPublisher] = {}
        self._matching: dict[str, bool] = {}  # set by Zenoh's matching listener
        self._seen: set[str] = set()  # keys that have had a subscriber
        self._held_from: dict[str, int] = {}  # key in outage -> index of its first held frame
        self._lock = threading.Lock()
        self._ticker: threading.Thread | None = None
        self._stop_ticker = threading.Event()

    def _publisher(self, key: str) -> BusPublisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.bus.publisher(key, retain=True)
            self._matching[key] = pub.has_subscribers()
            pub.on_matching(self._matching_callback(key))
            if self._replay is not None:
                self._replay.add(key, pub)
        return pub

    def serve_replays(self, consumers: dict[str, list[str]]) -> None:
        """Supervised live run: answer a restarted consumer's replay requests from the frames
        kept (:mod:`common.resume`), and forget a frame once every consumer of its key
        (``consumers``: key -> services) checkpointed past it; the bound (``outage_frames``,
        ``outage_bytes`` per key, ``retain_ns`` of event time) holds all the same.  Requests
        are answered by the publishing thread and the watermark ticker, under the lock."""
        with self._lock:
            for key in sorted(self.announce):
                self._publisher(key)
            self._replay = ReplayServer(self.bus, dict(self._pubs), consumers)

    def serve_pending(self) -> None:
        """Answer the replay requests queued (a source that ended and waits for its consumers)."""
        with self._lock:
            self._serve()

    def _serve(self) -> None:
        """Under the lock: answer the replay requests queued."""
        if self._replay is not None and self._replay.pending():
            self._replay.serve()

    def _matching_callback(self, key: str) -> Callable[[bool], None]:
        def on_matching(matching: bool) -> None:
            self._matching[key] = matching
        return on_matching

    def _check_link(self, key: str) -> bool:
        """Under the lock: follow ``key``'s matching status (outage starts / ends, see the module
        notes); True when frames of ``key`` may be sent now."""
        pub = self._publisher(key)
        matching = self._matching.get(key, False)
        if key not in self._held_from:
            if matching:
                self._seen.add(key)
                return True
            if key in self._seen:  # had a consumer, has none: hold from the next frame on
                self._held_from[key] = pub.index
                self.outages[key] = self.outages.get(key, 0) + 1
                log.warning("live source: %s has lost its consumers; holding its frames (at most %d)",
                            key, self.outage_frames)
                return False
            return True  # nobody ever listened: publish as always (a live source never waits)
        if not matching:
            return False
        held_from = self._held_from.pop(key)
        kept = [i for i, _f in pub.retained]  # only this source (under its lock) changes them
        supervised = self._replay is not None
        if supervised:
            # consumers ask for what was lost in flight themselves (a gap is asked for again,
            # common/resume.py): only what was held is sent, as plain frames (no R frame, which a
            # consumer catching up would take for the answer to its own request)
            kept = [i for i in kept if i >= held_from]
        first = kept[0] if kept else pub.index
        if supervised:
            for i, frame in list(pub.retained):
                if i >= first:
                    pub.send_raw(frame)
        else:
            pub.replay(first)
        late = sum(1 for i in kept if i >= held_from)
        _bump(self.delivered_late, key, late)
        _bump(self.resent, key, len(kept) - late)
        log.warning("live source: %s reached again; %d held frames delivered late, %d sent again", key, late,
                    len(kept) - late)
        return True

    def _bound(self, key: str, stamp_ns: int) -> None:
        pub = self._pubs[key]
        gone = self.retention.sent(pub, stamp_ns) + pub.bound(self.outage_frames, self.outage_bytes)
        self.retained_peak = max(self.retained_peak, sum(p.retained_bytes for p in self._pubs.values()))
        held_from = self._held_from.get(key)
        if held_from is not None:
            _bump(self.dropped_outage, key, sum(1 for i in gone if i >= held_from))

    def publish(self, key: str, msg: Message, arrival_ns: int | None = None) -> bool:
        """Publish ``msg`` on ``key`` now (``arrival_ns``: when it reached us, default now); True
        when it was late (older than its stream's promise: published all the same, counted).
        In an outage it is kept instead (module notes).  Nothing is published after :meth:`end`."""
        return self.publish_data(key, msg.type_name, encode(msg), msg.header.stamp, arrival_ns)

    def publish_data(self, key: str, type_name: str, payload: bytes | memoryview, stamp_ns: int,
                     arrival_ns: int | None = None) -> bool:
        """:meth:`publish` of an already encoded message (``stamp_ns``: its header stamp), e.g.
        a recording's payload sent byte for byte."""
        arrival = time.time_ns() if arrival_ns is None else arrival_ns
        with self._lock:
            if self.ended:
                return False
            late = self.clock.observe(key, stamp_ns, arrival)
            self.newest_stamp = max(self.newest_stamp, stamp_ns)
            if late:
                self.late[key] = self.late.get(key, 0) + 1
            self._serve()
            if self._check_link(key):
                self._publisher(key).send_data(type_name, payload, stamp_ns)
            else:
                self._publisher(key).keep_data(type_name, payload)
            self._bound(key, stamp_ns)
            self.published[key] = self.published.get(key, 0) + 1
            return late

    def send_watermarks(self, now_ns: int | None = None) -> int:
        """A wall-clock watermark on every key (published or announced) that can promise more."""
        now = time.time_ns() if now_ns is None else now_ns
        n = 0
        with self._lock:
            if self.ended:
                self._serve()  # a restarted consumer may still catch up after the end
                return 0
            self._serve()
            for key in sorted(set(self._pubs) | self.announce):
                if not self._check_link(key):
                    continue  # in an outage: no promise past the frames held
                wm = self.clock.watermark(key, now)
                if wm is not None:
                    self._publisher(key).send_watermark(wm)
                    n += 1
            self.watermarks += n
        return n

    def start_watermarks(self, interval_s: float) -> None:
        """Send :meth:`send_watermarks` every ``interval_s`` from a thread until :meth:`end`."""
        def loop() -> None:
            while not self._stop_ticker.wait(interval_s):
                self.send_watermarks()
        self._ticker = threading.Thread(target=loop, name="live-watermarks", daemon=True)
        self._ticker.start()

    def end(self) -> None:
        """End-of-stream on every key published or announced (once; publishing stops)."""
        self._stop_ticker.set()
        if self._ticker is not None:
            self._ticker.join(timeout=5)
        with self._lock:
            if self.ended:
                return
            self.ended = True
            for key in sorted(set(self._pubs) | self.announce):
                self._check_link(key)
                held_from = self._held_from.get(key)
                if held_from is not None:  # still cut off: what is held never reaches anyone
                    n = self._pubs[key].index - held_from
                    _bump(self.dropped_outage, key, n)
                    log.error("live source: %s still has no consumer at the end; %d held frames dropped", key, n)
                self._publisher(key).send_eos()

    def counters(self) -> dict[str, Any]:
        """The counters as JSON-ready values (per key; ``watermarks``: how many were sent;
        ``stalls`` / ``stalled_s``: per key, the silences that held its watermark back, and for how
        long in all [s of wall time], module notes: Stalls)."""
        with self._lock:
            out: dict[str, Any] = {
                "published": dict(self.published), "late": dict(self.late),
                "delivered_late": dict(self.delivered_late), "resent": dict(self.resent),
                "dropped_outage": dict(self.dropped_outage), "outages": dict(self.outages),
                "watermarks": self.watermarks, "retained_peak_bytes": self.retained_peak,
                "stalls": dict(self.clock.stalls),
                "stalled_s": {k: round(v / 1e9, 3) for k, v in self.clock.stalled_ns.items()}}
            if self._replay is not None:
                out["replays_served"] = self._replay.served
                out["replay_short"] = dict(self._replay.short)
            return out

    def retention_summary(self) -> dict[str, Any]:
        """Supervised (:meth:`serve_replays`): the bound (``retain_s`` of event time, ``retain_mb``
        per key), the most kept at once (``peak_mb``), ``replays`` answered and, per key, frames
        asked for that were no longer kept (``short``); {} unsupervised."""
        with self._lock:
            if self._replay is None:
                return {}
            return {"retain_s": self.retention.max_age_ns / 1e9, "retain_mb": self.outage_bytes / 1e6,
                    "peak_mb": round(self.retained_peak / 1e6, 3), "replays": self._replay.served,
                    "short": dict(self._replay.short)}

    def publishers(self) -> list[BusPublisher]:
        with self._lock:
            return list(self._pubs.values())


class LatencyTracker:
    """Wall time from a sensor message's arrival to the outputs it caused, per stage.

    Outputs carry the stamp of the input that caused them (:mod:`common.node`), so an output
    is matched to the input of the same stamp (the earliest arrival when several streams share
    it).  Each (stage, stamp) counts once (a map republished for the same event does not).
    The last ``horizon`` input stamps are remembered."""

    def __init__(self, horizon: int = 200_000):
        self.horizon = horizon
        self._arrival: OrderedDict[int, int] = OrderedDict()
        self._seen: dict[str, set[int]] = {}
        self.samples: dict[str, list[float]] = {}
        self.unmatched: dict[str, int] = {}

    def arrived(self, stamp_ns: int, wall_ns: int) -> None:
        if stamp_ns in self._arrival:
            return
        self._arrival[stamp_ns] = wall_ns
        if len(self._arrival) > self.horizon:
            self._arrival.popitem(last=False)

    def output(self, stage: str, stamp_ns: int, wall_ns: int) -> float | None:
        """An output of ``stage`` stamped ``stamp_ns`` was seen at ``wall_ns``: its latency (ms),
        or None (no input of that stamp, or already counted)."""
        seen = self._seen.setdefault(stage, set())
        if stamp_ns in seen:
            return None
        t0 = self._arrival.get(stamp_ns)
        if t0 is None:
            self.unmatched[stage] = self.unmatched.get(stage, 0) + 1
            return None
        seen.add(stamp_ns)
        ms = (wall_ns - t0) / 1e6
        self.samples.setdefault(stage, []).append(ms)
        return ms

    def last_stamp(self) -> int:
        """The newest input stamp remembered (0 before any)."""
        return max(self._arrival, default=0)

    def report(self, source: str, rate: float = 0.0) -> LatencyReport:
        """The :class:`common.messages.LatencyReport` of :meth:`summary`, stamped with the newest input."""
        return LatencyReport(header=Header(seq=0, stamp=self.last_stamp()), source=source, rate=rate,
                             stages={k: LatencyStage(**v) for k, v in self.summary().items()})

    def summary(self) -> dict[str, dict[str, float]]:
        """Per stage: ``n``, ``p50_ms``, ``p95_ms``, ``p99_ms``, ``max_ms`` (and ``unmatched``)."""
        out: dict[str, dict[str, float]] = {}
        for stage in sorted(set(self.samples) | set(self.unmatched)):
            a = np.asarray(self.samples.get(stage, []), dtype=np.float64)
            row: dict[str, float] = {"n": int(a.size), "unmatched": self.unmatched.get(stage, 0)}
            if a.size:
                p50, p95, p99 = np.percentile(a, [50, 95, 99])
                row.update(p50_ms=round(float(p50), 3), p95_ms=round(float(p95), 3), p99_ms=round(float(p99), 3),
                           max_ms=round(float(a.max()), 3))
            out[stage] = row
        return out


def publish_latency(bus: Bus, report: LatencyReport, wait_s: float = 10.0,
                    meanwhile: Callable[[], None] | None = None) -> bool:
    """Publish a live run's ``report`` on :data:`LATENCY_KEY` and its end-of-stream, then wait
    (at most ``wait_s``) until its consumers -- the run's recorder awaits that key
    (:mod:`launcher.live`) -- have left: closing the session earlier could discard it.  True
    when they left (or there were none).  ``meanwhile``: called first, after the publication
    (a supervised source keeps answering replays until its consumers finished).  The frame is
    not numbered: a report is never replayed (a restarted recorder takes it as it comes)."""
    pub = bus.publisher(LATENCY_KEY)
    pub.send_raw(encode_frame(report))
    pub.send_eos()
    if meanwhile is not None:
        meanwhile()
    return bus.drain([pub], wait_s)


def follow_outputs(sink: Sink, keys: Iterable[str], ended: set[str], on_frame: Callable[[str, bytes], None],
                   idle_s: float = 2.0, limit_s: float = 60.0) -> None:
    """After a live source ended its streams the services still finish their inputs: pass what
    ``sink`` receives to ``on_frame`` (which adds a key to ``ended`` at its end-of-stream) until
    every one of ``keys`` ended, or none came for ``idle_s`` (a key no running service
    produces never ends), at most ``limit_s``."""
    want = set(keys)
    deadline = time.monotonic() + limit_s
    quiet_since = time.monotonic()
    while time.monotonic() < deadline and not want <= ended:
        item = sink.next_frame(0.1)
        if item is None or item[0] == WAKE:
            if time.monotonic() - quiet_since > idle_s:
                return
            continue
        quiet_since = time.monotonic()
        on_frame(*item)
