"""Live sources: event-time watermarks from the wall clock, and publishing without waiting.

The rule (also in README, "Live on the vehicle"): a ROS header stamp is mapped to the wall
clock by tracking, per stream (our key), the offset ``arrival wall time - header stamp`` of
its latest message.  At wall time ``now`` a stream then promises (watermark) that nothing
older than ``now - offset - lateness`` will still come: ``lateness`` (``bridge_ros1.lateness_ms``)
bounds how much more than its predecessor a message may be delayed between its sensor and
the bridge.  A stream that has never had a message uses the offset of the latest message of
any stream (one vehicle, one clock), so a silent sensor does not stall the event-time merge
of the services downstream; before any message at all there is no watermark.  Tracking the
latest offset (not the smallest) follows a clock that runs at another rate than the wall
(``rosbag play -r 8``: the offsets shrink, the watermarks follow).  A message older than what
its stream already promised is *late*: it is still published (and recorded) but counted, and
the services reject it as late (:mod:`common.runtime`).

Everything here takes the wall time as an argument: the source reads the clock, :class:`LiveClock`
only computes (unit-tested without a clock).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Iterable

from common.bus import Bus, BusPublisher
from common.messages import Message

__all__ = ["LiveClock", "LiveSource"]


class LiveClock:
    """Per-stream offset between header stamps and arrival (ns), and the watermarks it allows."""

    def __init__(self, lateness_ns: int):
        if lateness_ns < 0:
            raise ValueError(f"lateness must be >= 0 ns, got {lateness_ns}")
        self.lateness_ns = lateness_ns
        self._offset: dict[str, int] = {}
        self._latest: int | None = None  # offset of the latest message of any stream
        self._promised: dict[str, int] = {}  # key -> watermark sent
        self._last_stamp: dict[str, int] = {}

    def observe(self, key: str, stamp_ns: int, arrival_ns: int) -> bool:
        """A message of ``key`` stamped ``stamp_ns`` arrived at ``arrival_ns``; True when it is
        late (older than what the stream already promised, or than its previous message)."""
        late = stamp_ns < self._promised.get(key, -1) or stamp_ns < self._last_stamp.get(key, -1)
        self._offset[key] = self._latest = arrival_ns - stamp_ns
        self._last_stamp[key] = max(stamp_ns, self._last_stamp.get(key, -1))
        return late

    def watermark(self, key: str, now_ns: int) -> int | None:
        """The promise stream ``key`` can make at ``now_ns`` if it is newer than what it already
        promised and than its last message's stamp (then it is recorded as promised); else None."""
        offset = self._offset.get(key, self._latest)
        if offset is None:
            return None
        wm = now_ns - offset - self.lateness_ns
        if wm <= self._promised.get(key, -1) or wm <= self._last_stamp.get(key, -1):
            return None
        self._promised[key] = wm
        return wm



class LiveSource:
    """What every live source shares (the ROS 1 bridge, :class:`common.driver.SensorDriver`):
    publishing a message at once on its key (never waiting for consumers), the stream's
    watermarks from the wall clock (:class:`LiveClock`, on every key published or
    ``announce``-d), end-of-stream on all of them at the end.  Thread-safe; counters
    ``published``, ``late`` (per key) and ``watermarks``."""

    def __init__(self, bus: Bus, lateness_ns: int, announce: Iterable[str] = ()):
        self.bus = bus
        self.clock = LiveClock(lateness_ns)
        self.announce = set(announce)
        self.published: dict[str, int] = {}
        self.late: dict[str, int] = {}
        self.watermarks = 0
        self.ended = False
        self._pubs: dict[str, BusPublisher] = {}
        self._lock = threading.Lock()
        self._ticker: threading.Thread | None = None
        self._stop_ticker = threading.Event()

    def _publisher(self, key: str) -> BusPublisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.bus.publisher(key)
        return pub

    def publish(self, key: str, msg: Message, arrival_ns: int | None = None) -> bool:
        """Publish ``msg`` on ``key`` now (``arrival_ns``: when it reached us, default now); True
        when it was late (older than its stream's promise: published all the same, counted).
        Nothing is published after :meth:`end`."""
        arrival = time.time_ns() if arrival_ns is None else arrival_ns
        with self._lock:
            if self.ended:
                return False
            late = self.clock.observe(key, msg.header.stamp, arrival)
            if late:
                self.late[key] = self.late.get(key, 0) + 1
            self._publisher(key).send(msg)
            self.published[key] = self.published.get(key, 0) + 1
            return late

    def send_watermarks(self, now_ns: int | None = None) -> int:
        """A wall-clock watermark on every key (published or announced) that can promise more."""
        now = time.time_ns() if now_ns is None else now_ns
        n = 0
        with self._lock:
            if self.ended:
                return 0
            for key in sorted(set(self._pubs) | self.announce):
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
                self._publisher(key).send_eos()

    def publishers(self) -> list[BusPublisher]:
        with self._lock:
            return list(self._pubs.values())
