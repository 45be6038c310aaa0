"""The ROS 1 bridge: a live source of sensor streams from a ROS master, and our outputs back to ROS.

``poseidon bridge ros1`` (one process on a hub) or the source of ``poseidon run --live ros1``.

- In: every configured topic (``bridge_ros1.topics``, default the importer's mapping) and,
  with ``discover``, every other topic published on the master (polled every
  ``discover_interval_s``; ``ignore_topics`` and our own output topics excepted) is
  subscribed; each message is converted as ``poseidon import`` converts a bag message
  (:mod:`services.bridge_ros1.convert`) and published at once on our key with its ROS
  header stamp.  When the launcher names the keys its services read (``read``: ``poseidon run
  --live ros1``, or ``--read``), only the topics of those keys, of ``keep_keys`` (the ground
  truth) and of the grid's returns are subscribed, unless ``bridge_unread``: a topic no service
  reads costs the bridge rospy's receiving and our conversion for nothing the run uses (the
  simulated missions' duplicate and second sonar streams are two thirds of their messages);
  such topics are listed in the stats' ``unread``.  A source never waits for its consumers: no
  flow control, no waiting for services to be alive.
- Event time: every ``watermark_interval_ms`` (wall) each source key (the keys published so
  far and ``announce``: the sensor keys the services wait on) gets a watermark from the wall
  clock (:mod:`common.live`: the mapping rule and the lateness bound), so a
  silent sensor does not stall the services' event-time merge.
- Out: ``Odometry``, ``dead_reckoning``, ``map`` (Path + MarkerArray, latched, at most every
  ``map_period_s``), ``local_view_cells`` and ``experience_event`` are published on ROS topics
  (table in :mod:`services.bridge_ros1.convert`); the occupancy grid of the laser (else sonar)
  returns it bridges in, at the poses ``Odometry`` and ``map`` give, on ``grid_topic`` (``/map``,
  latched, at most every ``grid_period_s`` of event time, built on a thread of its own:
  :mod:`services.bridge_ros1.grid`); a
  live run's health (``live/health``, :mod:`launcher.health`) on ``diagnostics_topic``
  (``/diagnostics``) as ``diagnostic_msgs/DiagnosticArray``.
- Supervised live runs (``consumers`` given): every key's frames are kept until each consumer
  checkpointed past them, within ``live.retain_s`` / ``live.retain_mb``, and replayed to a
  restarted consumer (:meth:`common.live.LiveSource.serve_replays`).
- Outages: when no consumer of a key is reachable any more (its link to the hub, or the hub's
  to the consumers' computer, is down) the bridge keeps that key's frames (at most
  ``outage_buffer_frames`` / ``outage_buffer_mb``, drop-oldest) and sends them when a consumer
  is back, before anything newer; counted ``delivered_late``, ``resent``, ``dropped_outage``
  (the rule: :mod:`common.live`).
- Latency: the wall time from a sensor message's arrival to the LVC id, experience event and
  map it caused (matched by stamp) and to the Odometry, per stage p50/p95/p99
  (``BridgeStats.latency``, in the run summary); at the end it is published on ``live/latency``
  (:func:`common.live.publish_latency`), so the run's recording holds it.
- End: on :meth:`stop` (SIGINT/SIGTERM, ``--duration``) the bridge sends end-of-stream on
  every key it published or announced (the services then finish and the recorder closes a
  complete file), forwards to ROS what the services still publish until their outputs end
  (or 2 s without any), shuts its ROS node down (waiting at most 5 s:
  ``RosLink.CLOSE_TIMEOUT_S``, a stuck master does not hold the bridge), and publishes its latency on ``live/latency``,
  waiting (at most 10 s) until the recorder has taken it.  It does not wait for its consumers to
  leave (``bus.drain_timeout_s``): the services' outputs ending shows they got its end-of-stream,
  and the services wait for the bridge's own subscription to their outputs to go (a cycle).  A
  second SIGTERM/SIGINT exits at once (``launcher/service_cmd.py``); a bridge that never reaches
  its hub gives up after ``bus.startup_timeout_s`` (exit 2).
"""
from __future__ import annotations

import gc
import logging
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from common.bus import Bus
from common.codec import DecodeError, decode_frame
from common.live import HEALTH_KEY, LatencyTracker, LiveSource, follow_outputs, publish_latency
from common.messages import (
    DiagnosticArray,
    ExperienceEvent,
    ExperienceMap,
    LaserScan,
    LocalViewCells,
    Message,
    Odometry,
    PoseStamped,
    RangeImageBeam,
)
from common.worker import WAKE, Sink, SinkStats, Source
from services.bridge_ros1.config import BridgeRos1Config
from services.bridge_ros1.convert import Incoming, Outgoing
from services.bridge_ros1.grid import LASER_KEY, SONAR_KEY, LiveGrid, SonarModel
from services.bridge_ros1.ros_io import RosLink

__all__ = ["Ros1Bridge", "BridgeStats", "BRIDGE_NAME"]

log = logging.getLogger(__name__)

BRIDGE_NAME = "bridge_ros1"


@dataclass
class BridgeStats(SinkStats):
    """``received``: ROS messages per topic; ``published``: bus messages per key; ``raw``: carried
    raw per key with ``raw_reasons``; ``late``: messages older than their stream's promise, per
    key; ``to_ros``: messages published on ROS per topic; ``watermarks``: wall-clock watermarks
    sent; ``delivered_late``/``resent``/``dropped_outage``/``outages``: per key, the outage rule
    of :mod:`common.live` (frames held while no consumer was reachable and sent after it came
    back / frames sent again that a consumer may already have / held frames never delivered /
    outages seen); ``latency``: per stage (:meth:`LatencyTracker.summary`); ``errors``: conversion failures
    per topic (logged with the reason); ``retention``: supervised, what was kept for restarted
    consumers (:meth:`common.live.LiveSource.retention_summary`); ``unread``: topics configured or
    published and not bridged because no service of the run reads their key
    (``bridge_ros1.bridge_unread`` off); ``grid``: the ``/map`` grid's ``published``, ``returns``
    (traced in the last), ``build_ms_max`` (wall), ``thinned``, ``dropped``, ``too_large`` and
    ``bad_odometry`` (:class:`services.bridge_ros1.grid.LiveGrid`); ``stalls`` / ``stalled_s`` per
    key: silences long enough to be taken for a stall (``rosbag play`` or a rospy thread held up)
    and the wall time they held its watermark back [s] (:mod:`common.live`: Stalls)."""

    received: dict[str, int] = field(default_factory=dict)
    published: dict[str, int] = field(default_factory=dict)
    raw: dict[str, int] = field(default_factory=dict)
    raw_reasons: dict[str, int] = field(default_factory=dict)
    late: dict[str, int] = field(default_factory=dict)
    to_ros: dict[str, int] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)
    delivered_late: dict[str, int] = field(default_factory=dict)
    resent: dict[str, int] = field(default_factory=dict)
    dropped_outage: dict[str, int] = field(default_factory=dict)
    outages: dict[str, int] = field(default_factory=dict)
    watermarks: int = 0
    latency: dict[str, dict[str, float]] = field(default_factory=dict)
    master_uri: str = ""
    retention: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, Any] = field(default_factory=dict)
    unread: list[str] = field(default_factory=list)
    stalls: dict[str, int] = field(default_factory=dict)
    stalled_s: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"service": BRIDGE_NAME, "master_uri": self.master_uri, "received": self.received,
                "published": self.published, "raw": self.raw, "raw_reasons": self.raw_reasons, "late": self.late,
                "to_ros": self.to_ros, "errors": self.errors, "watermarks": self.watermarks,
                "delivered_late": self.delivered_late, "resent": self.resent, "dropped_outage": self.dropped_outage,
                "outages": self.outages, "latency": self.latency, "aborted": self.aborted,
                "retention": self.retention, "grid": self.grid, "unread": self.unread, "stalls": self.stalls,
                "stalled_s": self.stalled_s}


def _bump(d: dict[str, int], k: str, n: int = 1) -> None:
    d[k] = d.get(k, 0) + n


class Ros1Bridge(Sink, Source):
    """Bridge the ROS master of ``config`` and ``bus`` until stopped (see the module notes)."""

    stats: BridgeStats

    def __init__(self, bus: Bus, config: BridgeRos1Config, announce: Iterable[str] = (),
                 drain_timeout_s: float = 0.0, consumers: Mapping[str, list[str]] | None = None,
                 retain_s: float = 300.0, retain_mb: float = 256.0, sonar: SonarModel | None = None,
                 read: Iterable[str] | None = None):
        super().__init__(BRIDGE_NAME, bus, BridgeStats(), None, drain_timeout_s)
        self.config = config
        self.announce = sorted(set(announce))
        self.incoming = Incoming(config.topics, config.discover)
        self.outgoing = Outgoing()
        if consumers is None:
            self.source = LiveSource(bus, config.lateness_ms * 1_000_000, self.announce,
                                     config.outage_buffer_frames, int(config.outage_buffer_mb * 1e6),
                                     stall_hold_ns=config.stall_hold_ms * 1_000_000)
        else:  # a supervised live run: frames kept for restarted consumers (common/live.py)
            self.source = LiveSource(bus, config.lateness_ms * 1_000_000, self.announce, 1 << 62,
                                     int(retain_mb * 1e6), int(retain_s * 1e9), config.stall_hold_ms * 1_000_000)
            self.source.serve_replays({k: list(v) for k, v in consumers.items()})
        self.latency = LatencyTracker()
        self._lock = threading.Lock()  # stats and latency: rospy threads and the main loop
        self._out_keys = config.output_stages()
        self._own_topics = {config.odometry_topic, config.dead_reckoning_topic, config.path_topic,
                            config.markers_topic, config.lvc_topic, config.event_topic, config.diagnostics_topic}
        self.grid = LiveGrid(config.grid_period_s, config.grid_resolution_m, config.grid_max_returns,
                             config.grid_max_poses, config.grid_max_cells, sonar)
        if self.grid.enabled:  # off, a /map of someone else's is bridged in like any topic
            self._own_topics.add(config.grid_topic)
        #: keys bridged (None: every topic): what the run reads, the ground truth, the grid's returns
        self.wanted: frozenset[str] | None = None
        if read is not None and not config.bridge_unread:
            grid_keys = {LASER_KEY, SONAR_KEY} if self.grid.enabled else set()
            self.wanted = frozenset({*read, *config.keep_keys, *grid_keys})
        self._outputs_ended: set[str] = set()
        self._pending_map: ExperienceMap | None = None
        self._grid_thread: threading.Thread | None = None
        self._last_map_wall = 0.0
        self._last_grid_wall = -float("inf")
        self.link: RosLink | None = None
        self.subscribe(sorted({*self._out_keys, HEALTH_KEY}))

    # ---- ROS -> bus (rospy threads) -----------------------------------------------------------
    def on_ros(self, topic: str, ros_type: str, md5: str, definition: str, data: bytes, arrival_ns: int) -> None:
        """One ROS message (any thread): convert, publish on the bus at once, note its arrival."""
        if self.source.ended:
            return
        try:
            out = self.incoming.convert(topic, ros_type, md5, definition, data, arrival_ns)
        except Exception as exc:  # never let one message stop the bridge: counted, logged with the topic
            with self._lock:
                _bump(self.stats.errors, topic)
            log.error("bridge_ros1: message on %s (%s) skipped: %s: %s", topic, ros_type, type(exc).__name__, exc)
            return
        if out is None:
            return
        key, msg, why = out
        with self._lock:
            _bump(self.stats.received, topic)
            if why:
                _bump(self.stats.raw, key)
                _bump(self.stats.raw_reasons, why.split(":")[0])
            self.latency.arrived(msg.header.stamp, arrival_ns)
        self.source.publish(key, msg, arrival_ns)
        if self.grid.enabled:  # the returns the /map grid is made of (grid.py: thread-safe)
            if key == LASER_KEY and isinstance(msg, LaserScan):
                self.grid.add_scan(msg)
            elif key == SONAR_KEY and isinstance(msg, RangeImageBeam):
                self.grid.add_sonar(msg)

    # ---- bus -> ROS --------------------------------------------------------------------------
    def finished(self) -> bool:
        return False  # a live source runs until stopped

    def on_frame(self, key: str, data: bytes) -> None:
        try:
            frame = decode_frame(data)
            if frame.kind == "eos":
                self._outputs_ended.add(key)
            if frame.kind != "data":
                return
            msg = frame.message()
        except DecodeError as exc:
            _bump(self.stats.errors, key)
            log.error("bridge_ros1: frame on %s skipped: %s", key, exc)
            return
        stage = self._out_keys.get(key)
        if stage is not None:
            with self._lock:
                self.latency.output(stage, msg.header.stamp, time.time_ns())
        self.to_ros(key, msg)
        if self.grid.enabled:
            if key == self.config.odometry_key and isinstance(msg, Odometry):
                self.grid.add_odometry(msg)
            elif key == self.config.map_key and isinstance(msg, ExperienceMap):
                self.grid.set_map(msg)
            self.flush_grid()

    def to_ros(self, key: str, msg: Message) -> None:
        """Publish one of our outputs on its ROS topic(s) (the map at most every ``map_period_s``)."""
        link, c = self.link, self.config
        if link is None:
            return
        if key == c.map_key and isinstance(msg, ExperienceMap):
            self._pending_map = msg
            self.flush_map()
            return
        if key == c.odometry_key and isinstance(msg, Odometry):
            topic, (_t, data) = c.odometry_topic, self.outgoing.standard(msg)
        elif key == c.dead_reckoning_key and isinstance(msg, PoseStamped):
            topic, (_t, data) = c.dead_reckoning_topic, self.outgoing.standard(msg)
        elif key == c.lvc_key and isinstance(msg, LocalViewCells):
            topic, data = c.lvc_topic, self.outgoing.lvc_id(msg)
        elif key == c.event_key and isinstance(msg, ExperienceEvent):
            topic, data = c.event_topic, self.outgoing.event(msg)
        elif key == HEALTH_KEY and isinstance(msg, DiagnosticArray):
            topic, (_t, data) = c.diagnostics_topic, self.outgoing.standard(msg)
        else:
            _bump(self.stats.errors, key)
            log.error("bridge_ros1: %s on %s has no ROS form here (expected types: see convert.py)",
                      type(msg).__name__, key)
            return
        link.publish(topic, data)
        _bump(self.stats.to_ros, topic)

    def flush_map(self, force: bool = False) -> None:
        """Publish the latest map (Path + markers) if ``map_period_s`` has passed (or ``force``)."""
        m, link = self._pending_map, self.link
        if m is None or link is None:
            return
        now = time.monotonic()
        if not force and now - self._last_map_wall < self.config.map_period_s:
            return
        self._pending_map, self._last_map_wall = None, now
        link.publish(self.config.path_topic, self.outgoing.path(m))
        link.publish(self.config.markers_topic, self.outgoing.markers(m))
        _bump(self.stats.to_ros, self.config.path_topic)
        _bump(self.stats.to_ros, self.config.markers_topic)

    def flush_grid(self, force: bool = False) -> None:
        """Rebuild and publish the ``/map`` grid when due (``grid_period_s`` of event time, and
        ``grid_wall_period_s`` of wall time since the last build began) on a thread of its own, so a
        large grid never holds up the bridge; with ``force`` (the end) here, after the one running."""
        if self.link is None or not (force or self.grid.due()):
            return
        now = time.monotonic()
        if not force and now - self._last_grid_wall < self.config.grid_wall_period_s:
            return
        self._last_grid_wall = now
        running = self._grid_thread
        if force:
            if running is not None:
                running.join()
            self._publish_grid(True)
        elif running is None or not running.is_alive():
            self._grid_thread = threading.Thread(target=self._publish_grid, args=(False,), name="bridge_ros1-grid",
                                                 daemon=True)
            self._grid_thread.start()

    def _publish_grid(self, force: bool) -> None:
        link = self.link
        t0 = time.monotonic()
        g = self.grid.build(force)
        ms = (time.monotonic() - t0) * 1000
        with self._lock:
            st = self.stats.grid
            st["build_ms_max"] = round(max(st.get("build_ms_max", 0.0), ms), 1)
        if g is None or link is None:
            return
        link.publish(self.config.grid_topic, self.outgoing.occupancy_grid(g))
        with self._lock:
            _bump(self.stats.to_ros, self.config.grid_topic)
            st["published"], st["returns"] = st.get("published", 0) + 1, g.returns

    # ---- run --------------------------------------------------------------------------------
    def _advertise(self, link: RosLink) -> None:
        c, o = self.config, self.outgoing
        for topic, ros_type, latch in ((c.odometry_topic, "nav_msgs/Odometry", False),
                                       (c.dead_reckoning_topic, "geometry_msgs/PoseStamped", False),
                                       (c.path_topic, "nav_msgs/Path", True),
                                       (c.markers_topic, "visualization_msgs/MarkerArray", True),
                                       (c.lvc_topic, "std_msgs/Int32", False),
                                       (c.event_topic, "std_msgs/String", True),
                                       (c.diagnostics_topic, "diagnostic_msgs/DiagnosticArray", False)):
            link.advertise(topic, ros_type, *o.definition(ros_type), latch=latch)
        if self.grid.enabled:
            link.advertise(c.grid_topic, "nav_msgs/OccupancyGrid", *o.definition("nav_msgs/OccupancyGrid"), latch=True)

    def discover(self, link: RosLink) -> None:
        """Subscribe to the configured topics, and with ``discover`` to every other published one."""
        want = [t for t, r in self.config.topics.items() if r.key is not None]
        if self.config.discover:
            skip = set(self.config.ignore_topics) | self._own_topics
            want += [t for t, _ty in link.published_topics() if t not in skip and self.incoming.key(t) is not None]
        if self.wanted is not None:
            unread = sorted({t for t in want if self.incoming.key(t) not in self.wanted} - set(self.stats.unread))
            if unread:
                log.info("bridge_ros1: not bridged, no service reads them: %s", ", ".join(unread))
                self.stats.unread = sorted({*self.stats.unread, *unread})
            want = [t for t in want if self.incoming.key(t) in self.wanted]
        for t in want:
            if t not in link.subscribed():
                log.info("bridge_ros1: subscribing to %s", t)
                link.subscribe(t)

    def run(self) -> BridgeStats:
        """Connect to the master, bridge until stopped, then end every stream."""
        c = self.config
        link = self.link = RosLink(c.master_uri, c.node_name, c.ros_python_path, self.on_ros, c.ros_queue_size)
        self.stats.master_uri = link.master_uri
        self.grid.warm_up()  # the /map grid's first build would otherwise stall the bridge mid-run
        link.connect(c.master_timeout_s)  # no master: RosUnavailable, nothing was published
        try:
            self._advertise(link)
            self.discover(link)
            self.bus.declare_alive(self.name)
            # start-up's objects (rospy, rosbags' types, pydantic) out of the collector's reach: a full
            # collection then stops the rospy threads for ~30 ms, not ~140 ms, and a message it holds up
            # is less often older than its stream's promise (late)
            gc.freeze()
            wm_every = c.watermark_interval_ms / 1000
            next_wm = next_discover = time.monotonic()
            while not self.stop_event.is_set():
                item = self.next_frame(min(wm_every, 0.05))
                if item is not None and item[0] != WAKE:
                    self.on_frame(*item)
                now = time.monotonic()
                if now >= next_wm:
                    self.source.send_watermarks(time.time_ns())
                    self.progress.report(self.source.newest_stamp)  # how far the source is: the run's health
                    self.flush_map()
                    self.flush_grid()
                    next_wm = now + wm_every
                if c.discover and now >= next_discover:
                    self.discover(link)
                    next_discover = now + c.discover_interval_s
        finally:
            self.source.end()
            follow_outputs(self, self._out_keys, self._outputs_ended, self.on_frame)  # forwarded to ROS
            self.flush_map(force=True)
            self.flush_grid(force=True)
            g = self.grid
            self.stats.grid.update(thinned=g.thinned, dropped=g.dropped, too_large=g.too_large,
                                   bad_odometry=g.bad_odometry)
            with self._lock:
                self.stats.latency = self.latency.summary()
                report = self.latency.report(BRIDGE_NAME)
            counters = self.source.counters()
            self.stats.published, self.stats.late = counters["published"], counters["late"]
            self.stats.delivered_late, self.stats.resent = counters["delivered_late"], counters["resent"]
            self.stats.dropped_outage, self.stats.outages = counters["dropped_outage"], counters["outages"]
            self.stats.watermarks = counters["watermarks"]
            self.stats.stalls, self.stats.stalled_s = counters["stalls"], counters["stalled_s"]
            self.stats.retention = self.source.retention_summary()
            link.close()
            self.drain(self.source.publishers())  # a no-op after a stop: see the module notes
            publish_latency(self.bus, report)  # recorded with the run (poseidon eval reads it)
        return self.stats
