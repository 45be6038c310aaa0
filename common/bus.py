"""Zenoh transport: sessions with explicit endpoints, publishers that never drop, liveliness.

Decisions (see ../shared/design/ARCHITECTURE.md):

- Sessions (endpoints, the hub, viewers' ids): :mod:`common.sessions`.
- Keys: ``<namespace>/<key>`` (default ``poseidon``); liveliness: ``<namespace>/@alive/<service>``.
- Publishers are reliable with ``CongestionControl.BLOCK``: Zenoh never drops a frame, except
  to a viewer (:data:`common.sessions.VIEWER_QOS`).
- Flow control is end to end, in event time, not inside Zenoh: every consumer reports how
  far it has got on ``<namespace>/@progress/<service>`` and a replaying player keeps at most
  ``bus.flow_window_ms`` of event time in flight ahead of the slowest one.  Subscriber
  callbacks therefore never block.  (Blocking a callback, the obvious way to push back,
  stalls the Zenoh runtime that routes the consumer's own outputs: with a hub between
  services that deadlocks as soon as a service both consumes and publishes.)
- Bundles: a publisher with ``bundle_max`` > 1 (the player replaying at full speed,
  ``player.bundle_frames``) holds its small data frames and sends up to that many in one sample
  (:func:`common.codec.encode_bundle`); any other frame on the key, :meth:`BusPublisher.flush`
  or a full bundle sends what it holds first, so the order on the key never changes.
  :meth:`Bus.subscribe` splits a bundle into its frames.  Each sample costs every receiver a
  wake-up and a callback, the recorder included; ``docs/DECISIONS.md``, "Bundles".
- ``@`` chunks (``@alive``, ``@progress``, ``@abort``) are verbatim in Zenoh: ``**`` does
  not match them, so the recorder never records control traffic.
- Failing fast without a launcher: a consumer that finishes normally reports progress
  ``END_OF_TIME`` before it leaves.  A service whose liveliness token disappears without
  that report has died; the player then publishes ``<namespace>/@abort`` (UTF-8 text
  naming the service) and every runner and recorder stops on it, so no process waits
  forever for a stream that will never end (:meth:`Bus.on_abort`, :meth:`Bus.watch_alive`).
"""
from __future__ import annotations

import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, Protocol

import zenoh

from common.codec import (
    BUNDLE_TAG,
    ENCODED_EOS,
    DecodeError,
    encode,
    encode_bundle,
    encode_replay_start,
    encode_sequenced,
    encode_watermark,
    split_frames,
)
from common.messages import Message
from common.sessions import open_hub, open_local_session, zenoh_config  # re-exported: services import them from here

__all__ = ["zenoh_config", "open_local_session", "Bus", "BusPublisher", "ProgressReporter", "ProgressWatcher",
           "AliveWatcher", "open_hub", "ALIVE", "PROGRESS", "ABORT"]

log = logging.getLogger(__name__)

ALIVE = "@alive"
PROGRESS = "@progress"
ABORT = "@abort"
#: a data frame larger than this is never bundled (camera images: one sample each)
BUNDLE_FRAME_BYTES = 16384
class FrameSink(Protocol):
    """Where :meth:`Bus.subscribe` puts ``(relative key, frame bytes)``: a queue that never blocks."""

    def put_nowait(self, item: tuple[str, bytes]) -> None: ...


class BusPublisher:
    """Publishes data, watermark and end-of-stream frames on one key, never dropping.

    Data frames are numbered (``index``: the transport index, see :mod:`common.codec`).  With
    ``retain`` the publisher keeps the frames it sent (``retained``) until :meth:`trim`, so
    that :meth:`replay` can send them again to a restarted consumer (:mod:`common.resume`).
    """

    def __init__(self, session: zenoh.Session, full_key: str, retain: bool = False):
        self.key = full_key
        self._pub = session.declare_publisher(full_key, congestion_control=zenoh.CongestionControl.BLOCK,
                                              reliability=zenoh.Reliability.RELIABLE)
        self.sent = 0
        self.watermark = -1   # last watermark sent
        self.data_stamp = -1  # stamp of the newest data frame sent (when the sender said it)
        self.index = 0  # transport index of the next data frame
        self.ended = False
        self.retain = retain
        self.retained: deque[tuple[int, bytes]] = deque()
        self.retained_bytes = 0
        self._lock = threading.Lock()
        self.bundle_max = 0   # > 1: data frames go out in bundles of up to this many (see :meth:`flush`)
        self._pending: list[bytes] = []
        self.pending_since = -1  # stamp of the oldest data frame held for a bundle (-1: none held)
        self.data_samples = 0    # samples that carried data frames (a bundle counts once)

    def flush(self) -> None:
        """Send the data frames held for a bundle (one sample; a single frame as itself)."""
        pending = self._pending
        if pending:
            self._pending = []
            self.pending_since = -1
            self._pub.put(pending[0] if len(pending) == 1 else encode_bundle(pending))
            self.data_samples += 1

    def send(self, msg: Message) -> None:
        self.send_data(msg.type_name, encode(msg), msg.header.stamp)

    def send_data(self, type_name: str, payload: bytes | memoryview, stamp: int = -1) -> None:
        """A numbered data frame of an encoded message (``stamp``: its header stamp, for
        :meth:`heartbeat`; -1 when unknown)."""
        frame = encode_sequenced(self.index, type_name, payload)
        if self.bundle_max > 1 and len(frame) <= BUNDLE_FRAME_BYTES:
            if not self._pending:
                self.pending_since = stamp
            self._pending.append(frame)
            if len(self._pending) >= self.bundle_max:
                self.flush()
        else:
            self.flush()
            self._pub.put(frame)
            self.data_samples += 1
        self.data_stamp = max(self.data_stamp, stamp)
        if self.retain:
            with self._lock:
                self.retained.append((self.index, frame))
                self.retained_bytes += len(frame)
        self.index += 1
        self.sent += 1

    def keep_data(self, type_name: str, payload: bytes | memoryview) -> None:
        """Number and retain an encoded message's data frame without sending it (:mod:`common.live`, outages)."""
        frame = encode_sequenced(self.index, type_name, payload)
        with self._lock:
            self.retained.append((self.index, frame))
            self.retained_bytes += len(frame)
        self.index += 1
        self.sent += 1

    def bound(self, max_frames: int, max_bytes: int, below: int = 0) -> list[int]:
        """Forget the oldest retained frames beyond ``max_frames`` or ``max_bytes`` or below index
        ``below`` (the newest is always kept); returns the indices forgotten."""
        gone: list[int] = []
        with self._lock:
            while len(self.retained) > 1 and (len(self.retained) > max_frames or self.retained_bytes > max_bytes
                                              or self.retained[0][0] < below):
                i, f = self.retained.popleft()
                self.retained_bytes -= len(f)
                gone.append(i)
        return gone

    def send_raw(self, frame: bytes) -> None:
        self.flush()
        self._pub.put(frame)
        self.sent += 1

    def send_watermark(self, stamp: int) -> None:
        if stamp > self.watermark:
            self.flush()
            self._pub.put(encode_watermark(stamp))
            self.watermark = stamp

    def heartbeat(self, stamp: int, interval_ns: int) -> None:
        """Watermark ``stamp`` unless the key spoke within ``interval_ns`` before it.

        A data frame stamped t already promises W >= t to every consumer's merger
        (:mod:`common.ordering`), so a key with data at least every ``interval_ns`` needs
        no separate watermark: the sonar beams and the IMU send none.  Only the release of other
        streams' messages can wait (at most ``interval_ns`` of event time), not what or in which order."""
        last = max(self.watermark, self.data_stamp)
        if last < 0 or stamp >= last + interval_ns:
            self.send_watermark(stamp)

    def send_eos(self) -> None:
        self.flush()
        self._pub.put(ENCODED_EOS)
        self.ended = True

    def trim(self, below: int) -> None:
        """Forget retained frames with an index below ``below`` (every consumer has them for good)."""
        with self._lock:
            while self.retained and self.retained[0][0] < below:
                self.retained_bytes -= len(self.retained.popleft()[1])

    def replay(self, start: int, frames: Iterable[bytes] | None = None, first: int | None = None,
               by: str = "") -> int:
        """Send again every data frame from index ``start`` (``R`` frame first), then the last
        watermark and, if the stream ended, end-of-stream.  ``frames``/``first``: the frames
        from index ``first`` when they are kept elsewhere (the player re-reads its recording);
        default: the retained ones; ``by``: the consumer that asked (named in the ``R`` frame).
        Returns the index the replay started from (> ``start``: frames before it are lost)."""
        self.flush()
        if frames is None:
            with self._lock:
                kept = [(i, f) for i, f in self.retained if i >= start]
                first = self.retained[0][0] if self.retained else self.index
            begin = min(max(start, first), self.index)
            self._pub.put(encode_replay_start(begin, by))
            for _i, frame in kept:
                self._pub.put(frame)
        else:
            begin = min(max(start, first if first is not None else start), self.index)
            self._pub.put(encode_replay_start(begin, by))
            for frame in frames:
                self._pub.put(frame)
        if self.watermark >= 0:
            self._pub.put(encode_watermark(self.watermark))
        if self.ended:
            self._pub.put(ENCODED_EOS)
        return begin

    def retained_state(self) -> dict[str, Any]:
        """What a checkpoint keeps of this publisher: next index, retained frames, watermark."""
        with self._lock:
            return {"index": self.index, "retained": list(self.retained), "watermark": self.watermark}

    def restore(self, state: dict[str, Any]) -> None:
        with self._lock:
            self.index = int(state["index"])
            self.retained = deque(state["retained"])
            self.retained_bytes = sum(len(f) for _i, f in self.retained)

    def on_matching(self, callback: Callable[[bool], None]) -> None:
        """``callback(matching)`` (Zenoh thread; must not block) on the first/last subscriber."""
        self._listener = self._pub.declare_matching_listener(lambda st: callback(bool(st.matching)))

    def has_subscribers(self) -> bool:
        # zenoh's stub types matching_status as bool; it is a MatchingStatus (.matching: bool)
        return bool(self._pub.matching_status.matching)  # type: ignore[attr-defined]

    def undeclare(self) -> None:
        self._pub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves undeclare() unannotated


class ProgressReporter:
    """Tells the player how far (event time, ns) a consumer has taken its inputs."""

    def __init__(self, session: zenoh.Session, full_key: str, min_interval_s: float = 0.02):
        self._pub = session.declare_publisher(full_key, congestion_control=zenoh.CongestionControl.BLOCK,
                                              reliability=zenoh.Reliability.RELIABLE)
        self._last = -2
        self._last_wall = 0.0
        self._min_interval_s = min_interval_s

    def report(self, stamp: int, force: bool = False) -> None:
        now = time.monotonic()
        if stamp > self._last and (force or now - self._last_wall >= self._min_interval_s):
            self._pub.put(struct.pack("<q", stamp))
            self._last, self._last_wall = stamp, now

    def repeat(self, min_interval_s: float = 0.2) -> None:
        """Say the last progress again (at most every ``min_interval_s``): a restarted player
        learns it from the duplicates it sends (progress reports are not kept by the bus)."""
        now = time.monotonic()
        if self._last > -2 and now - self._last_wall >= min_interval_s:
            self._pub.put(struct.pack("<q", self._last))
            self._last_wall = now


class ProgressWatcher:
    """The latest progress of every consumer (thread-safe, filled by a Zenoh callback)."""

    def __init__(self) -> None:
        self._progress: dict[str, int] = {}
        self._lock = threading.Lock()
        self._awaited: tuple[list[str], int, int] | None = None  # (services, default, progress) of wait_slowest
        self._reached = threading.Event()

    def update(self, service: str, stamp: int) -> None:
        with self._lock:
            if stamp > self._progress.get(service, -2):
                self._progress[service] = stamp
                awaited = self._awaited
                if awaited is not None and self._slowest(awaited[0], awaited[1]) >= awaited[2]:
                    self._reached.set()

    def _slowest(self, services: Iterable[str], default: int) -> int:
        values = [self._progress.get(s, default) for s in services]
        return min(values) if values else default

    def get(self, service: str, default: int = -2) -> int:
        with self._lock:
            return self._progress.get(service, default)

    def slowest(self, services: Iterable[str], default: int) -> int:
        """Minimum progress over ``services``; one that has not reported counts as ``default``."""
        with self._lock:
            return self._slowest(services, default)

    def wait_slowest(self, services: Iterable[str], default: int, at_least: int, timeout_s: float) -> bool:
        """Wait (at most ``timeout_s``) until :meth:`slowest` reaches ``at_least``; True if it has.
        Woken by the progress report that gets it there (no polling)."""
        services = list(services)
        with self._lock:
            if self._slowest(services, default) >= at_least:
                return True
            self._awaited = (services, default, at_least)
            self._reached.clear()
        reached = self._reached.wait(timeout_s)
        with self._lock:
            self._awaited = None
        return reached


class AliveWatcher:
    """Which services are alive now, and which have left since they were first seen."""

    def __init__(self) -> None:
        self._alive: set[str] = set()
        self._left: list[str] = []
        self._lock = threading.Lock()

    def update(self, service: str, alive: bool) -> None:
        with self._lock:
            if alive:
                self._alive.add(service)
            elif service in self._alive:
                self._alive.discard(service)
                self._left.append(service)

    def alive(self) -> set[str]:
        with self._lock:
            return set(self._alive)

    def left(self) -> list[str]:
        """Services that were alive and are no longer, in the order they left."""
        with self._lock:
            return list(self._left)


class Bus:
    """One Zenoh session of a process, scoped to a vehicle namespace.

    ``session`` may be shared (embedded mode: every service on one session)."""

    def __init__(self, namespace: str = "poseidon", connect: Iterable[str] = ("tcp/127.0.0.1:7447",),
                 mode: str = "client", listen: Iterable[str] = (), session: zenoh.Session | None = None,
                 config_file: str | None = None, **secure: str | None):
        self.namespace = namespace.strip("/")
        self._own_session = session is None
        self.session = session if session is not None else zenoh.open(
            zenoh_config(mode, connect=connect, listen=listen, config_file=config_file, **secure))
        self._keepalive: list[object] = []
        self._alive_watcher: AliveWatcher | None = None

    def full_key(self, key: str) -> str:
        return f"{self.namespace}/{key}"

    def relative_key(self, full_key: str) -> str:
        prefix = self.namespace + "/"
        return full_key[len(prefix):] if full_key.startswith(prefix) else full_key

    def publisher(self, key: str, retain: bool = False) -> BusPublisher:
        return BusPublisher(self.session, self.full_key(key), retain=retain)

    def subscribe(self, key: str, sink: FrameSink) -> None:
        """Deliver ``(relative key, frame bytes)`` of ``key`` (wildcards allowed) into ``sink``.

        The callback never blocks (see the module notes on flow control).
        """
        relative: dict[str, str] = {}  # full key -> relative key (one lookup per frame)

        def on_sample(sample: zenoh.Sample) -> None:
            full = str(sample.key_expr)
            rel = relative.get(full)
            if rel is None:
                rel = self.relative_key(full)
                if len(relative) < 4096:  # a wildcard subscription meets a bounded number of keys
                    relative[full] = rel
            data = sample.payload.to_bytes()
            if data[:1] == BUNDLE_TAG:
                try:
                    frames = split_frames(data)
                except DecodeError:
                    frames = [data]  # the consumer's decode names what is wrong with it
                for f in frames:
                    sink.put_nowait((rel, f))
            else:
                sink.put_nowait((rel, data))
        self._keepalive.append(self.session.declare_subscriber(self.full_key(key), on_sample))

    def subscribe_callback(self, key: str, callback: Callable[[str, bytes], None]) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            callback(self.relative_key(str(sample.key_expr)), sample.payload.to_bytes())
        self._keepalive.append(self.session.declare_subscriber(self.full_key(key), on_sample))

    def progress_publisher(self, service: str) -> ProgressReporter:
        return ProgressReporter(self.session, self.full_key(f"{PROGRESS}/{service}"))

    def watch_progress(self, services: Iterable[str] | None = None) -> ProgressWatcher:
        """Follow the progress of ``services`` (default: all; each report is a callback here)."""
        watcher, prefix = ProgressWatcher(), self.full_key(PROGRESS) + "/"

        def on_sample(sample: zenoh.Sample) -> None:
            data = sample.payload.to_bytes()
            if len(data) == 8:
                watcher.update(str(sample.key_expr)[len(prefix):], struct.unpack("<q", data)[0])
            else:
                log.error("progress report of %d bytes on %s ignored", len(data), sample.key_expr)
        for name in ["*"] if services is None else sorted(services):
            self._keepalive.append(self.session.declare_subscriber(self.full_key(f"{PROGRESS}/{name}"), on_sample))
        return watcher

    def watch_alive(self) -> AliveWatcher:
        """Follow the liveliness tokens of this namespace (history included)."""
        watcher = AliveWatcher()
        prefix = self.full_key(ALIVE) + "/"

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            if key.startswith(prefix):
                watcher.update(key[len(prefix):], sample.kind == zenoh.SampleKind.PUT)
        self._keepalive.append(self.session.liveliness().declare_subscriber(
            self.full_key(f"{ALIVE}/*"), on_sample, history=True))
        return watcher

    def abort(self, reason: str) -> None:
        """Tell every process of the namespace to stop: the run cannot complete (``reason`` says why)."""
        self.session.put(self.full_key(ABORT), reason.encode("utf-8", "replace"))

    def on_abort(self, callback: Callable[[str], None]) -> None:
        """Call ``callback(reason)`` when any process publishes an abort."""
        def on_sample(sample: zenoh.Sample) -> None:
            callback(sample.payload.to_bytes().decode("utf-8", "replace")[:500])
        self._keepalive.append(self.session.declare_subscriber(self.full_key(ABORT), on_sample))

    def declare_alive(self, service: str) -> None:
        """Announce that ``service`` has declared its subscribers and is ready."""
        self._keepalive.append(self.session.liveliness().declare_token(self.full_key(f"{ALIVE}/{service}")))

    def alive(self) -> set[str]:
        """Names of the services currently alive in this namespace.

        Follows the liveliness tokens with a subscriber (history included) rather than a
        liveliness query: the secured profile's access control lets subscribers through
        but answers no liveliness query with replies of other sessions' tokens.
        """
        if self._alive_watcher is None:
            self._alive_watcher = self.watch_alive()
        return self._alive_watcher.alive()

    def wait_alive(self, services: Iterable[str], timeout_s: float, poll_s: float = 0.05) -> None:
        """Block until every service in ``services`` is alive; TimeoutError names the missing ones."""
        wanted = set(services)
        deadline = time.monotonic() + timeout_s
        missing = wanted
        while True:
            missing = wanted - self.alive()
            if not missing:
                return
            if time.monotonic() > deadline:
                raise TimeoutError(f"services not alive after {timeout_s:.0f} s: {sorted(missing)}")
            time.sleep(poll_s)

    def drain(self, publishers: Iterable[BusPublisher], timeout_s: float, poll_s: float = 0.05,
              stop: threading.Event | None = None, warn: bool = True) -> bool:
        """Wait until no subscriber matches any of ``publishers`` (all consumers have finished).

        Closing a Zenoh session discards frames still queued for sending, so a process
        that published end-of-stream waits here before it exits: consumers leave only after
        end-of-stream, which arrives after every data frame of the key.  Returns False (and
        logs which keys) if consumers are still there after ``timeout_s`` or once ``stop`` is set.
        """
        pubs = list(publishers)
        deadline = time.monotonic() + timeout_s
        while True:
            busy = [p.key for p in pubs if p.has_subscribers()]
            if not busy:
                return True
            if time.monotonic() > deadline or (stop is not None and stop.is_set()):
                if warn:
                    log.warning("consumers of %s still present after %.0f s; closing anyway", busy, timeout_s)
                return False
            time.sleep(poll_s)

    def close(self) -> None:
        for entity in self._keepalive:
            undeclare = getattr(entity, "undeclare", None)
            if undeclare is not None:
                undeclare()
        self._keepalive.clear()
        if self._own_session:
            self.session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves close() unannotated
