"""Player: publishes the streams of an MCAP recording (every one, or ``keys``) in event-time order.

In ``poseidon run`` the launcher gives it the keys a started service reads, plus the ground
truth; the recorder copies the others from the file (``player.replay``, :func:`launcher.run.plan_run`).

- Pacing: ``rate`` 1 = real time, N = N x real time, 0 = as fast as the consumers take
  it: with ``wait_for`` services, at most ``flow_window_ms`` of event time is in flight
  ahead of the slowest one (they report progress on ``@progress``), so nothing is dropped
  and memory stays bounded at any rate.
- Bundles (``bundle_frames`` > 1, rate 0 only): consecutive data frames of a key up to 16 KiB
  each go out up to ``bundle_frames`` in one sample (:mod:`common.bus`); a bundle is sent when
  full, when its first frame is ``bundle_ms`` of event time old, and before every wait for the
  consumers.  Once held, the player waits for room for ``bundle_ms`` of event time (at most half
  the window), so that what follows goes in full bundles, not one frame per progress report.
- Before the first message it waits until every expected service is alive (Zenoh drops
  what is published before a subscriber exists).
- Payloads are sent byte for byte as recorded (no re-encoding).
- Event-time watermarks go out every ``heartbeat_ms`` of event time on every key that has
  been silent that long (a data frame promises its own stamp, :meth:`common.bus.BusPublisher.heartbeat`),
  and end-of-stream on every key at the end.  Source keys the recording does not have get
  end-of-stream at once, so services waiting on them (e.g. an absent IMU) are not blocked, and no
  watermark after it.  Held by flow control, the player promises the held stamp on every key only
  once the slowest consumer has made no progress for ``PROMISE_AFTER_S`` (it may be waiting for
  event time to pass: a gap in the recording longer than the window); consumers busy with what is
  in flight need no promise (one at every hold was ~2 watermarks per key per event second).
- In its own process (``drain_timeout_s`` > 0) it stays until its consumers have left
  (:meth:`common.bus.Bus.drain`): closing earlier would discard frames still queued.
- Fail fast: a ``wait_for`` service whose liveliness token disappears before it reported
  progress ``END_OF_TIME`` has died; the player then publishes ``@abort`` naming it (so the
  other services and the recorder stop instead of waiting forever) and stops.  An abort
  published by anyone else stops it too.  ``PlayerStats.aborted`` says why.
- Supervised (``supervision``, :mod:`common.resume`): data frames carry their transport
  index (the message's ordinal on its key in the recording); a replay request
  (``@replay/<key>``) is answered by reading the recording again from that message; a
  consumer that leaves may come back (the launcher restarts it) within
  ``supervise.rejoin_timeout_s`` before the run is aborted; at the end the player stays,
  answering replays, until every consumer reported progress ``END_OF_TIME``.

The player is a :class:`common.worker.Source` (abort handling, replay answers, waiting for
the consumers and draining are shared with the services' runner).
"""
from __future__ import annotations

import bisect
import logging
import sys
import time
from array import array
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from common.bus import AliveWatcher, Bus, BusPublisher, ProgressWatcher
from common.codec import encode_sequenced
from common.mcap_io import read_messages, recording_keys, recording_message_count
from common.ordering import END_OF_TIME
from common.resume import Supervision
from common.worker import Source, WorkerStats
from services.player.config import PlayerConfig

__all__ = ["Player", "PlayerStats", "SOURCE_KEYS", "TRUTH_KEYS", "replayed_keys"]

log = logging.getLogger(__name__)

#: keys whose only publisher is the player (sensor inputs and ground truth)
SOURCE_KEYS = (
    "camera/image_raw", "sonar_micron", "sonar_seaking", "sonar_micron_ros", "sonar_seaking_ros",
    "dvl_linkquest", "imu_adis", "imu_adis_ros", "depth_sensor", "odometry", "truth/pose", "truth/revisits",
)


#: input keys a run replays for evaluation even when no service reads them (``player.replay`` consumed)
TRUTH_KEYS = ("truth/pose", "truth/revisits")


def replayed_keys(cfg: PlayerConfig, keys: list[str], read: set[str]) -> list[str]:
    """The keys of ``keys`` (sorted) a run's player publishes: narrowed to ``player.keys`` when
    set, and with ``player.replay`` consumed or copied to the keys some service ``read``s plus
    :data:`TRUTH_KEYS` (the others are logged: left out, or copied by the recorder)."""
    out = sorted(k for k in keys if not cfg.keys or k in cfg.keys)
    if cfg.replay in ("consumed", "copied"):
        left = [k for k in out if k not in read and k not in TRUTH_KEYS]
        out = [k for k in out if k not in left]
        if left:
            what = "not replayed" if cfg.replay == "consumed" else "copied by the recorder from the input, not replayed"
            log.info("player.replay %s: %s (no service reads them): %s", cfg.replay, what, ", ".join(left))
    return out


@dataclass
class PlayerStats(WorkerStats):
    published: dict[str, int] = field(default_factory=dict)
    samples: dict[str, int] = field(default_factory=dict)  # bus samples that carried them (bundles: fewer)
    wall_s: float = 0.0
    event_s: float = 0.0
    replays: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {"service": "player", "published": self.published, "samples": self.samples, "wall_s": round(self.wall_s, 3),
                "event_s": round(self.event_s, 3), "aborted": self.aborted, "replays": self.replays,
                "real_time_factor": round(self.event_s / self.wall_s, 3) if self.wall_s > 0 else None}


#: a player held by flow control promises the held stamp on every key (a watermark) once the
#: slowest consumer has reported no progress for this long (wall clock, s); consumers busy with
#: what is in flight need no promise (module notes)
PROMISE_AFTER_S = 0.05


class Player(Source):
    """Replay ``path`` on ``bus`` (see the module notes)."""

    stats: PlayerStats

    def __init__(self, bus: Bus, path: str | Path, rate: float = 0.0, keys: Iterable[str] | None = None,
                 wait_for: Iterable[str] = (), heartbeat_ms: int = 100, startup_timeout_s: float = 60.0,
                 progress: bool = True, announce_absent: Iterable[str] = SOURCE_KEYS,
                 drain_timeout_s: float = 0.0, flow_window_ms: int = 3000,
                 supervision: Supervision | None = None, bundle_frames: int = 0, bundle_ms: int = 1000):
        if rate < 0:
            raise ValueError(f"player rate must be >= 0, got {rate}")
        self.path = Path(path)
        self.rate = rate
        available = recording_keys(self.path)
        self.keys = sorted(available if keys is None else [k for k in keys if k in available])
        self.absent = sorted(set(announce_absent) - set(self.keys))
        self.wait_for = list(wait_for)
        self.heartbeat_ns = heartbeat_ms * 1_000_000
        self.startup_timeout_s = startup_timeout_s
        self.progress = progress
        self.flow_window_ns = flow_window_ms * 1_000_000
        self.bundle_frames = bundle_frames if rate == 0 else 0  # paced replays: one sample per frame
        self.bundle_ns = bundle_ms * 1_000_000
        self._burst_ns = min(self.bundle_ns, self.flow_window_ns // 2) if self.bundle_frames > 1 else 0
        self._alive: AliveWatcher | None = None
        self._watcher: ProgressWatcher | None = None
        self._left_since: dict[str, float] = {}
        self._next_check = 0.0
        self._stamps: dict[str, array[int]] = {k: array("q") for k in self.keys}  # stamp per transport index
        self._flow_bound = -1  # stamps up to this are within the flow window (slowest progress + window)
        super().__init__("player", bus, PlayerStats(), supervision, drain_timeout_s)

    def _check_consumers(self, grace_s: float = 1.0) -> None:
        """Answer replays; abort the run if a consumer left the bus without finishing (it
        died) and did not come back within ``grace_s`` (``supervise.rejoin_timeout_s`` when
        supervised)."""
        now = time.monotonic()
        self.stats.replays += self.serve_replays(self._replay_source)
        if self._alive is None or self._watcher is None or now < self._next_check or self.stop_event.is_set():
            return
        self._next_check = now + 0.1
        if self.supervision is not None:
            grace_s = self.supervision.rejoin_timeout_s
        alive = self._alive.alive()
        for name in self._alive.left():
            if name not in self.wait_for or self._watcher.get(name) == END_OF_TIME:
                continue
            if name in alive:  # restarted
                self._left_since.pop(name, None)
                continue
            first = self._left_since.setdefault(name, now)
            if now - first >= grace_s:  # its last progress report may still be on the way
                reason = f"service {name} left the bus before the end of its inputs (it died or was stopped)"
                log.error("player: %s; aborting the run", reason)
                self.abort_run(reason)
                return

    def _wait_for_consumers(self, watcher: ProgressWatcher, stamp: int, first: int,
                            live: list[BusPublisher]) -> None:
        """Flow control: hold ``stamp`` until the slowest consumer is within the window.

        Once every consumer has reported, their progress only grows: a stamp within the
        last bound seen then needs no new look."""
        if stamp <= self._flow_bound and not self.stop_event.is_set():
            return
        # bundling: once held, wait for room for a burst (bundle_ms of event time) so that bundles form
        stamp_due = stamp + self._burst_ns
        flushed = promised = False
        seen, since = None, time.monotonic()
        while not self.stop_event.is_set():
            slowest = watcher.slowest(self.wait_for, default=-2)
            if slowest > -2:  # every consumer reported: this bound holds from now on
                self._flow_bound = bound = slowest + self.flow_window_ns
            else:
                bound = watcher.slowest(self.wait_for, default=first) + self.flow_window_ns
            if stamp_due <= bound:
                return
            if not flushed:  # what is held for a bundle goes out before the player waits for it to be taken
                for pub in live:
                    pub.flush()
                flushed = True
            self._check_consumers()
            now = time.monotonic()
            if slowest != seen:
                seen, since = slowest, now
            elif not promised and now - since >= PROMISE_AFTER_S:
                # the slowest consumer stands still: it may be waiting for event time to pass (a
                # gap in the recording longer than the window), which only a promise moves
                for pub in live:
                    pub.send_watermark(stamp)
                promised = True
            # woken by the progress report that lets ``stamp`` go; at the latest after 10 ms, to
            # answer replays and notice an abort or a consumer that left
            watcher.wait_slowest(self.wait_for, first, stamp_due - self.flow_window_ns, 0.01)

    def _replay_source(self, key: str, start: int) -> tuple[int, Iterator[bytes]]:
        """Frames of ``key`` from transport index ``start`` up to the last one sent, read again
        from the recording (lazily: a generator)."""
        stamps = self._stamps.get(key, array("q"))
        n = len(stamps)
        if start >= n:
            return n, iter(())
        t = stamps[start]
        skip = start - bisect.bisect_left(stamps, t)  # messages of the same stamp before index start

        def frames() -> Iterator[bytes]:
            index = start - skip
            for rec in read_messages(self.path, keys=[key], start_ns=t):
                if index >= n:
                    return
                if index >= start:
                    yield encode_sequenced(index, rec.type_name, rec.payload)
                index += 1
        return start, frames()

    def _start(self) -> tuple[dict[str, BusPublisher], ProgressWatcher | None]:
        """Publishers (absent source keys get end-of-stream at once), replay answers when
        supervised, and the consumers: alive before the first message, then watched."""
        pubs = {k: self.bus.publisher(k) for k in self.keys + self.absent}
        for pub in pubs.values():
            pub.bundle_max = self.bundle_frames
        if self.supervision is not None:
            self.serve_replays_for(pubs)
        watcher = self.bus.watch_progress() if self.wait_for else None
        if self.wait_for:
            log.debug("player: waiting for %s", ", ".join(self.wait_for))
            self._alive = self.bus.watch_alive()
            self.bus.wait_alive(self.wait_for, self.startup_timeout_s)
            self._watcher = watcher
        for k in self.absent:
            pubs[k].send_eos()
        return pubs, watcher

    def _publish(self, pubs: dict[str, BusPublisher], watcher: ProgressWatcher | None, total: int | None,
                 t_wall0: float) -> tuple[int | None, int]:
        """Send the ``total`` messages of the recording in event-time order (paced from
        ``t_wall0``, flow-controlled); returns the first and the last stamp sent (None, 0 if
        nothing was)."""
        t_event0 = None
        last_hb = last_flush = -1
        live = [p for p in pubs.values() if not p.ended]  # absent keys ended at once: nothing to promise
        last_stamp = 0
        bar = tqdm(total=total, desc="player", unit="msg", file=sys.stderr, disable=not self.progress,
                   mininterval=1.0)
        try:
            for rec in read_messages(self.path, keys=self.keys):
                if self.stop_event.is_set():
                    log.warning("player: stopped early")
                    break
                if t_event0 is None:
                    t_event0 = rec.stamp
                if self.rate > 0:
                    delay = t_wall0 + (rec.stamp - t_event0) / 1e9 / self.rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                if watcher is not None:
                    self._check_consumers()
                    self._wait_for_consumers(watcher, rec.stamp, t_event0, live)
                    if self.stop_event.is_set():
                        break
                if rec.stamp - last_hb >= self.heartbeat_ns:
                    for pub in live:
                        pub.heartbeat(rec.stamp, self.heartbeat_ns)
                    last_hb = rec.stamp
                if self.bundle_frames > 1 and rec.stamp - last_flush >= self.bundle_ns // 4:
                    for pub in live:  # a bundle goes out at the latest bundle_ms after its first frame
                        if 0 <= pub.pending_since <= rec.stamp - self.bundle_ns:
                            pub.flush()
                    last_flush = rec.stamp
                pubs[rec.key].send_data(rec.type_name, rec.payload, rec.stamp)
                self._stamps[rec.key].append(rec.stamp)
                self.stats.published[rec.key] = self.stats.published.get(rec.key, 0) + 1
                last_stamp = rec.stamp
                bar.update(1)
        finally:
            bar.close()
            if not self.stop_event.is_set():
                for k in self.keys:
                    pubs[k].send_eos()
            elif not self.stats.aborted:  # stopped early: the streams are incomplete, no end-of-stream
                self.abort_run("player stopped before the end of the recording")
            self.stats.samples = {k: pubs[k].data_samples for k in self.keys if pubs[k].data_samples}
        return t_event0, last_stamp

    def run(self) -> PlayerStats:
        """Publish the recording, then stay while the consumers need it (see the module notes)."""
        pubs, watcher = self._start()
        total = recording_message_count(self.path, self.keys)
        t_wall0 = time.monotonic()
        t_event0, last_stamp = self._publish(pubs, watcher, total, t_wall0)
        if self.supervision is not None and watcher is not None and not self.stop_event.is_set():
            self.await_consumers(self.wait_for, watcher, self._check_consumers, lambda: time.sleep(0.02))
        self.drain(pubs.values(), self._check_consumers)
        self.stats.wall_s = time.monotonic() - t_wall0
        self.stats.event_s = (last_stamp - t_event0) / 1e9 if t_event0 is not None else 0.0
        return self.stats
