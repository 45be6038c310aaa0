"""The live feed: a read-only subscriber on a running deployment that keeps the view's model.

Never slowing the SLAM:

- No Python code runs on Zenoh's threads: each key's subscriber keeps its samples in Zenoh's
  own ring buffer (the newest few for the camera, the map and the pose-cell activity; up to
  ``queue_frames`` for the other displayed keys, the oldest overwritten when it is full and
  counted in ``view.dropped`` from the transport indices; :data:`FIGURES_RING` for a key read
  for the figures only), so Zenoh's threads, which keep the caller's scheduling (niced by
  ``view.nice``, never SCHED_IDLE: :func:`services.viewer.app.serve_live`), never wait for
  the interpreter and the hub never waits for the view.  Nothing waits for a browser: a page that polls slowly, or none, only
  means fewer snapshots are built.
- The view connects under a viewer id (:data:`common.sessions.VIEWER_IDS`, :func:`connect_bus`): the
  hub forwards to it with congestion control DROP, so a view that stops reading (a suspended
  laptop, a stalled radio link, a view starved of CPU) loses frames, counted in
  ``view.dropped`` from the transport indices, and never holds a frame of the SLAM's consumers
  on the hub (with BLOCK the hub held every key it routed through the view's link until Zenoh
  closed that link, 5 s later: tested in ``tests/viewer/test_viewer_ids.py``).
- A heavy key (a data frame larger than ``view.sample_bytes``: camera images, evidence
  images) is not followed frame by frame: the hub would copy every frame to the view (and the
  view's rings would hold megabytes).  A heavy key that
  is displayed or a service's input is sampled, about ``view.sample_hz`` frames a second
  (:class:`~services.viewer.sampler.KeySampler`); any other (a service output shown nowhere)
  is left after its first frame, the service's other outputs carry its figures.
- A pump thread wakes ``view.update_hz`` times a second, takes what the rings hold, decodes
  it, applies it to the :class:`~services.viewer.model.ViewModel` and updates the per-service
  figures (latency from the hub's timestamps of the samples, when it stamps them).
- Each key has its own subscriber, undeclared at the key's end-of-stream: a finished
  publisher waits until its consumers have left (:meth:`common.bus.Bus.drain`), and the view
  must not be one it waits for.
- The view publishes nothing: no publisher, no liveliness token (a token that disappears
  would read as a dead service, :mod:`common.bus`), no progress report (the player's flow
  control never waits for it).
- The lag of each service comes from the services' ``@progress`` reports (one per input a
  service finished: the busiest stream the view reads) until the launcher's ``live/health``
  report arrives (once a second in a supervised live run, with every service's lag); from
  then on from that report, and the view leaves ``@progress``.

The per-service figures: :mod:`services.viewer.figures`.
"""
from __future__ import annotations

import json
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import zenoh

from common.bus import ABORT, ALIVE, PROGRESS, Bus
from common.codec import DecodeError, Frame, decode_frame, decode_header, split_frames
from common.live import HEALTH_KEY
from common.messages import DiagnosticArray
from common.sessions import VIEWER_IDS, zenoh_config
from services.viewer.config import ViewConfig
from services.viewer.figures import LatencyWindow, ServiceFigures, health_lags
from services.viewer.model import ACTIVITY_KEY, MAP_KEY, ViewModel, view_keys
from services.viewer.sampler import KeySampler

__all__ = ["LiveFeed", "ViewError", "connect_bus", "ServiceFigures", "LatencyWindow"]

log = logging.getLogger(__name__)

#: ring capacity of a latest-only key: its newest data frame survives the watermarks and the
#: end-of-stream that follow it until the pump takes it
LATEST_RING = 16
#: ring capacity of a key read for the per-service figures only (frames of any size, until the
#: first one shows it heavy)
FIGURES_RING = 64
#: while no hub answers, the view tries to connect again this often [ms]
RETRY_MS = 100
#: longest wait for the hub to take one viewer id, once it answered: this many times its first
#: answer took, and at least ID_TIMEOUT_MIN_S [s] (a taken id is refused by a timeout)
ID_TIMEOUT_FACTOR = 5.0
ID_TIMEOUT_MIN_S = 0.3


class ViewError(RuntimeError):
    """The view cannot start: the message names the bad input (an address, a file)."""


def connect_bus(namespace: str, endpoint: str, timeout_s: float, config_file: str | None = None,
                tls_dir: str | None = None, tls_host: str | None = None, user: str | None = None,
                password_file: str | None = None) -> Bus:
    """A client :class:`Bus` on the hub at ``endpoint`` under the first free viewer id
    (:data:`common.sessions.VIEWER_IDS`: the hub drops what the view's link cannot take instead of
    holding the SLAM's frames); :class:`ViewError` when no hub answers within ``timeout_s`` (a
    service would wait forever; a view started by hand should not) or every viewer id is taken.

    Zenoh answers a session whose id is taken as it answers an absent hub, by a timeout, so a
    session under a passing id first asks whether the hub answers at all, and how long it takes
    to; then each viewer id gets :data:`ID_TIMEOUT_FACTOR` times that, at least
    :data:`ID_TIMEOUT_MIN_S`.  ``tls_dir``, ``tls_host``, ``user``, ``password_file``: the
    secured profile (:func:`common.sessions.zenoh_config`)."""
    def conf(zenoh_id: str | None, wait_s: float) -> zenoh.Config:
        c = zenoh_config("client", connect=[endpoint], config_file=config_file, tls_dir=tls_dir, tls_host=tls_host,
                         user=user, password_file=password_file, zenoh_id=zenoh_id)
        c.insert_json5("connect/timeout_ms", json.dumps(int(wait_s * 1000)))
        c.insert_json5("connect/exit_on_failure", "true")
        # a view started before its hub (poseidon run --view) connects within RETRY_MS of it listening
        c.insert_json5("connect/retry", json.dumps({"period_init_ms": RETRY_MS, "period_max_ms": RETRY_MS,
                                                    "period_increase_factor": 1.0}))
        return c

    t0 = time.monotonic()
    try:
        zenoh.open(conf(None, timeout_s)).close()  # type: ignore[no-untyped-call]  # close() is unannotated
    except zenoh.ZError:
        raise ViewError(f"no hub answers at {endpoint} within {timeout_s:.0f} s (start one with 'poseidon hub' "
                        f"or 'poseidon run', or pass its address with --connect)") from None
    id_timeout_s = max(ID_TIMEOUT_MIN_S, ID_TIMEOUT_FACTOR * (time.monotonic() - t0))
    for zenoh_id in VIEWER_IDS:
        try:
            session = zenoh.open(conf(zenoh_id, id_timeout_s))
        except zenoh.ZError:
            log.info("view: viewer id %s taken on %s (or the hub left); trying the next", zenoh_id, endpoint)
            continue
        return Bus(namespace, session=session)
    raise ViewError(f"the hub at {endpoint} answers but takes none of the {len(VIEWER_IDS)} viewer ids: "
                    f"that many views are connected already (or the hub left meanwhile)")


class LiveFeed:
    """Subscribes to ``keys`` (:func:`~services.viewer.model.view_keys` and every key of ``io``,
    which :meth:`add_io` may extend after the start) on ``bus`` and keeps ``model`` current (see
    the module notes).  ``on_update`` is called from the pump thread after each update, under
    :attr:`lock` (the Foxglove server)."""

    def __init__(self, bus: Bus, cfg: ViewConfig, io: Mapping[str, tuple[Sequence[str], Sequence[str]]] | None = None,
                 on_update: Callable[[ViewModel], None] | None = None, queue_frames: int = 1000):
        self.bus = bus
        self.cfg = cfg
        self.model = ViewModel(cfg)
        self.figures = ServiceFigures({})
        self.shown = set(view_keys(cfg))
        self.inputs: set[str] = set()
        self.keys = sorted({*self.shown, HEALTH_KEY})
        self._started = False
        self.heavy: set[str] = set()  # keys whose frames exceed cfg.sample_bytes (see the module notes)
        self.sampler = KeySampler(self._declare_latest, self._take_latest, cfg.sample_hz)
        self.received_bytes = 0  # bytes of data keys the hub delivered to the view
        self.received_by_key: dict[str, int] = {}  # the same per key
        self.lock = threading.Lock()  # the model: the pump applies, the server's threads take snapshots
        self._latest: dict[str, Frame] = {}  # key -> latest data frame (camera, map, activity, sampled keys)
        self._latest_keys = {cfg.camera_key, MAP_KEY, ACTIVITY_KEY, HEALTH_KEY}
        self.figures.partial |= self._latest_keys
        self._ring = queue_frames
        self._taken_index: dict[str, int] = {}  # displayed key -> transport index of the newest frame taken
        self.dropped = 0  # displayed frames overwritten in a ring before the pump took them
        self.invalid = 0
        self.aborted = ""  # the reason of the run's abort, if one was published
        self.ended: set[str] = set()
        self._subs: dict[str, Any] = {}
        self._control: list[tuple[Any, Callable[[zenoh.Sample], None]]] = []  # @alive, @abort, @progress
        self._progress_sub: Any = None  # @progress, until a live/health report gives the lags
        self.progress_reports = 0  # @progress samples the hub delivered
        self._subs_lock = threading.Lock()  # _subs and keys: start, stop, add_io and the pump's undeclaring
        self._undeclare: deque[str] = deque()
        self._on_update = on_update
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.updates = 0
        self.final = ""  # the recording whose final state replaced the live one (:meth:`finish`)
        if io:
            self.add_io(io)

    # ---- taking samples out of the rings (the pump and the sampler's threads) -------------
    def _declare(self, key: str) -> Any:
        capacity = LATEST_RING if key in self._latest_keys else self._ring if key in self.shown else FIGURES_RING
        return self.bus.session.declare_subscriber(self.bus.full_key(key), zenoh.handlers.RingChannel(capacity))

    def _declare_latest(self, key: str) -> Any:
        return self.bus.session.declare_subscriber(self.bus.full_key(key), zenoh.handlers.RingChannel(LATEST_RING))

    def _take(self, key: str, sample: zenoh.Sample) -> list[Frame]:
        """Count one sample of ``key``; its data frames the page shows (a replay's bundle holds several)."""
        data = sample.payload.to_bytes()
        self.received_bytes += len(data)
        self.received_by_key[key] = self.received_by_key.get(key, 0) + len(data)
        try:
            frames = split_frames(data)
        except DecodeError as exc:
            self.invalid += 1
            log.error("view: bad frame on %s skipped: %s", key, exc)
            return []
        ts = sample.timestamp  # the hub's time of routing it, when the hub stamps (a router does)
        wall_ns = int(ts.get_time().timestamp() * 1e9) if ts is not None else time.time_ns()
        return [f for f in (self._take_frame(key, d, wall_ns) for d in frames) if f is not None]

    def _take_frame(self, key: str, data: bytes, wall_ns: int) -> Frame | None:
        try:
            frame = decode_frame(data)
            if frame.kind == "eos":
                self.ended.add(key)
                self._undeclare.append(key)
                self.sampler.remove(key)
                return None
            if frame.kind != "data":
                return None
            if key not in self.heavy and len(data) > self.cfg.sample_bytes:
                self._heavy(key)
            stamp = decode_header(frame.payload).get("stamp", -1)  # the body only if the page shows it
        except DecodeError as exc:
            self.invalid += 1
            log.error("view: bad frame on %s skipped: %s", key, exc)
            return None
        if key == HEALTH_KEY:  # read for the lags only: neither a source nor an output
            return frame
        self.figures.data(key, frame.index, stamp if isinstance(stamp, int) else -1, wall_ns)
        if key not in self.shown:
            return None
        if frame.index >= 0 and key not in self._latest_keys and key not in self.heavy:
            last = self._taken_index.get(key, frame.index - 1)
            self.dropped += max(0, frame.index - last - 1)
            self._taken_index[key] = frame.index
        return frame

    def _take_latest(self, key: str, sample: zenoh.Sample) -> bool:
        """Keep the newest data frame of ``sample`` of a sampled key as its latest; whether it held one."""
        frames = self._take(key, sample)
        if frames:
            self._latest[key] = frames[-1]
        return bool(frames)

    def _heavy(self, key: str) -> None:
        """``key`` carries heavy frames: leave its subscription; sample it if it is shown or an input."""
        self.heavy.add(key)
        self._undeclare.append(key)
        sampled = key in self.shown or key in self.inputs
        if sampled:
            with self.figures.lock:
                self.figures.partial.add(key)
            self.sampler.add(key)
        log.debug("view: %s carries frames over %d bytes; %s", key, self.cfg.sample_bytes, "sampled" if sampled else "left")

    def _on_token(self, sample: zenoh.Sample) -> None:
        prefix = self.bus.full_key(ALIVE) + "/"
        key = str(sample.key_expr)
        if key.startswith(prefix):
            self.figures.token(key[len(prefix):], sample.kind == zenoh.SampleKind.PUT)

    def _on_abort(self, sample: zenoh.Sample) -> None:
        self.aborted = sample.payload.to_bytes().decode("utf-8", "replace")[:500]

    def _on_progress(self, sample: zenoh.Sample) -> None:
        self.progress_reports += 1
        data = sample.payload.to_bytes()
        if len(data) != 8:
            self.invalid += 1
            log.error("view: progress report of %d bytes on %s skipped", len(data), sample.key_expr)
            return
        self.figures.progress_report(str(sample.key_expr).rsplit("/", 1)[-1], struct.unpack("<q", data)[0])

    # ---- life -------------------------------------------------------------------------------
    def start(self) -> None:
        """Declare the subscribers and start the pump."""
        session = self.bus.session
        with self._subs_lock:
            self._started = True
            for key in self.keys:
                self._subs[key] = self._declare(key)
        self._progress_sub = session.declare_subscriber(self.bus.full_key(f"{PROGRESS}/*"),
                                                        zenoh.handlers.RingChannel(self._ring))
        self._control = [
            (session.liveliness().declare_subscriber(self.bus.full_key(f"{ALIVE}/*"),
                                                     zenoh.handlers.RingChannel(self._ring), history=True),
             self._on_token),
            (session.declare_subscriber(self.bus.full_key(ABORT), zenoh.handlers.RingChannel(8)), self._on_abort),
            (self._progress_sub, self._on_progress)]
        self._thread = threading.Thread(target=self._pump, name="view-pump", daemon=True)
        self._thread.start()
        self.sampler.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.sampler.stop()
        with self._subs_lock:
            for sub in self._subs.values():
                sub.undeclare()
            self._subs.clear()
            for sub, _handle in self._control:
                sub.undeclare()
            self._control = []

    def add_io(self, io: Mapping[str, tuple[Sequence[str], Sequence[str]]]) -> None:
        """Follow the services of ``io`` too: their figures, and their keys (subscribed at once
        when the feed runs)."""
        self.figures.add_io(io)
        with self._subs_lock:
            self.inputs |= {k for ins, _outs in io.values() for k in ins}
            new = sorted((self.inputs | self.figures.produced) - set(self.keys))
            self.keys = sorted({*self.keys, *new})
            if self._started and not self._stop.is_set():
                for key in new:
                    self._subs[key] = self._declare(key)

    def _pump(self) -> None:
        period = 1.0 / self.cfg.update_hz
        while not self._stop.wait(period):
            self.update()

    def _drain(self) -> list[tuple[str, Frame]]:
        """Everything the rings hold: control reports handled, displayed frames returned (the
        newest only of a latest-only key)."""
        with self._subs_lock:
            control = list(self._control)
            subs = list(self._subs.items())
        for sub, handle in control:
            while (sample := sub.try_recv()) is not None:
                handle(sample)
        batch: list[tuple[str, Frame]] = []
        for key, sub in subs:
            while (sample := sub.try_recv()) is not None:
                for frame in self._take(key, sample):
                    if key in self._latest_keys:
                        self._latest[key] = frame
                    else:
                        batch.append((key, frame))
        return batch

    def update(self) -> None:
        """Take what the rings hold, undeclare ended keys, decode and apply what was kept,
        refresh the figures (the pump calls it; tests call it directly)."""
        batch = self._drain()
        while self._undeclare:
            key = self._undeclare.popleft()
            with self._subs_lock:
                sub = self._subs.pop(key, None)
            if sub is not None:
                sub.undeclare()
        for key in list(self._latest):
            latest = self._latest.pop(key, None)
            if latest is not None:
                batch.append((key, latest))
        with self.lock:
            if self.final:  # the recording's final state is shown: late frames no longer change it
                batch = [(k, f) for k, f in batch if k == HEALTH_KEY]
            for key, frame in batch:
                try:
                    msg = frame.message()
                except DecodeError as exc:
                    self.invalid += 1
                    log.error("view: message on %s skipped: %s", key, exc)
                    continue
                if key == HEALTH_KEY:
                    self._health(msg)
                else:
                    self.model.apply(key, msg)
            self.updates += 1
            if self._on_update is not None:
                self._on_update(self.model)

    def finish(self, model: ViewModel, recording: str) -> None:
        """The run ended and ``model`` holds its recording's final state: show that from now on.

        A view that fell behind lost frames (``view.dropped``, and the map's and the activity's
        superseded frames), so its own final state can miss the last map or LVC frames; the
        recording has every message.  The versions continue the live ones, so a page and the
        Foxglove server draw the new state; the last camera frame received stays shown."""
        with self.lock:
            model.continue_from(self.model)
            self.model = model
            self.final = recording
            self.updates += 1
            if self._on_update is not None:
                self._on_update(self.model)

    def _health(self, msg: Any) -> None:
        """A ``live/health`` report: the services' lags from it, and leave ``@progress``."""
        if not isinstance(msg, DiagnosticArray):
            return
        self.figures.health_report(health_lags(msg))
        with self._subs_lock:
            sub, self._progress_sub = self._progress_sub, None
            self._control = [c for c in self._control if c[0] is not sub]
        if sub is not None:
            sub.undeclare()
            log.debug("view: the lags come from %s; @progress left", HEALTH_KEY)

    def snapshot(self, have: Mapping[str, str], t_s: float = 0.0) -> dict[str, Any]:
        """The model's snapshot for a client holding ``have``, with the live figures (``t_s``:
        unused, a live view is always at its newest time)."""
        with self.lock:
            snap = self.model.snapshot(have)
            camera_version = self.model.camera_version
        snap["mode"] = "live"
        snap["camera_version"] = camera_version
        snap["services"] = self.figures.table()
        snap["view"] = {"dropped": self.dropped, "invalid": self.invalid, "ended": sorted(self.ended),
                        "aborted": self.aborted, "keys": self.keys, "sampled": self.sampler.keys,
                        "received_bytes": self.received_bytes, "received_by_key": dict(self.received_by_key),
                        "lag_from": HEALTH_KEY if self.figures.health_lag is not None else "@progress",
                        "progress_reports": self.progress_reports, "final": self.final,
                        "updates": self.updates}
        return snap

    def camera(self) -> tuple[int, bytes]:
        with self.lock:
            return self.model.camera_jpeg()
