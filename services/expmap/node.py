"""Experience map service node: ``experience_event`` -> ``map``, ``experience_image``,
``dead_reckoning`` (Section 4.2.4, Eqs. 4.20-4.21; audit contract of Fig. 4.1).

Inputs, in priority order for equal stamps: the camera (``expmap.image.topic``; first, so
the frame that produced an event is already buffered when the event is handled),
``experience_event``, ``Odometry``.  Without ``image.publish_experience`` the camera is not
subscribed.

- Every valid event updates :class:`services.expmap.graph.ExperienceMap` (one node, maybe a
  loop closure, ``corrections.iterations_per_event`` relaxation iterations).  An event the graph
  refuses (non-finite values) is logged with its seq, counted (``events_invalid``) and skipped.
- ``experience_image``: the camera frame whose stamp is closest to the event's stamp, within
  ``min(sync.sync_stale_sec, expmap.image.sync_slop)`` (ties: the earlier frame), published
  with the event's header (seq, stamp, frame_id) and ``source_stamp`` = the frame's stamp.
  Inputs arrive in event-time order, so the candidates are the last frame at or before the
  event and the first frame after it: the decision waits until a frame later than the event
  arrives (or the inputs end) and no longer; meanwhile :meth:`output_watermark` holds the
  outputs' promise at the oldest undecided event.  At most ``image.buffer_size`` events wait;
  beyond that the oldest is decided with the frames seen so far (``image_wait_overflow``).
  No frame within the window: counted (``events_without_image``), nothing published.
  The rule is :class:`services.expmap.association.EventImageAssociator`.
- ``dead_reckoning``: one PoseStamped (position, yaw from the quaternion) per ``Odometry``
  message, or at most one per ``dead_reckoning_period_sec`` of event time; header stamp =
  the odometry stamp.
- ``map``: the whole graph (nodes, odometry and loop links), published after a loop closure
  or when a correction has settled (once nodes/``map_correction_divisor`` events have passed
  since the last map: a map costs O(nodes) to build, send and record, and closures come at a
  steady rate, so without the wait the maps of a mission's third hour cost 2-3x its first's),
  every ``map_publish_every`` events (or every nodes/10 events once the map is larger, so the
  periodic maps add up to ~10x the final map, not a quadratic recording) and always at the end.  At
  the end a pending correction is completed first (each iteration still capped), so the
  final map is the clamped least-squares map.
- ``map_path``: the map is loaded at start when the file exists and saved at the end (after
  settling), to continue in a later mission with the same odometry frame; with
  ``sessions.begin_on_load`` (``poseidon run --map-dir``) the run begins a new session instead, in its
  own odometry frame, linked to the loaded map by a verified recognition
  (:mod:`services.expmap.session_link`).
- ``map_sessions`` (key): a map of more than one session (a continued map, or a kidnapped
  vehicle with ``sessions.jump_m``) publishes, with every ``map``, a ``MapSessions`` with the
  same stamp: the session of every node, how many nodes were loaded, the links made and the
  link candidates refused (per reason).

- sonar (``expmap.scan.topic``, with ``loops.scan_matching``): every beam's wall echo becomes
  a point in the dead-reckoning frame with the latest ``Odometry`` pose; each experience
  keeps the last full sweep, and a loop closure registers the two experiences' sweeps for
  the loop edge's displacement (:mod:`services.expmap.scans`).

- range scans (``expmap.graph: scan_graph``, the laser preset): ``expmap.scan.topic`` carries
  ``LaserScan``; each scan's returns (``scan_graph.min_range_m`` .. ``max_range_m``) become
  points in the dead-reckoning frame with the ``Odometry`` pose interpolated to the scan's
  stamp (after ``scan_graph.sensor_offset``, the sensor's pose on the robot), and an
  experience's frame is the ``Odometry`` pose interpolated to its own stamp (the event waits
  for the next ``Odometry``; ``scan_graph.odometry_at_stamps``, false: the newest pose
  before each, :mod:`services.expmap.laser_input`); it keeps the latest scan expressed in its
  own frame (motion between the scan and the event compensated by the odometry);
  :class:`services.expmap.scan_graph.ScanGraph` registers the
  scans for every edge.  Its counters (``chain_scan``, ``chain_odometry``, ``loop_tried``,
  ``loop_verified``, ``loop_rejected_score``, ``loop_rejected_ambiguous``, ``loop_from_lvc``)
  are added to the node's at the end.
- ``scan_pose`` (key; laser map with ``scan_graph.scan_poses`` and ``odometry_at_stamps``):
  every placed scan, after the inputs of its message are handled, is registered against the
  newest experience's local map (:mod:`services.expmap.scan_poses`) and published with the
  scan's stamp (counters ``scan_pose``, ``scan_pose_weak``, ``scan_pose_unplaced``); a scan
  waiting for the pose after it holds :meth:`output_watermark` at its stamp.

- odometry scale (``expmap.visual_scale.enabled``; off by default): the camera frames and the
  DVL's altitude (``visual_scale.dvl_topic``) feed :class:`services.expmap.visual_scale.VisualScale`;
  before each event, when its estimate (1 when it is further than ``max_deviation`` from 1:
  counted ``visual_scale_implausible``) moved by more than ``update_step`` from the scale the
  map applies, the map's odometry edges of this run are rescaled to it
  (:meth:`ExperienceMap.set_odometry_scale`, a relaxation toward the new optimum); once more at
  the end.  The camera is subscribed for it even with ``image.publish_experience`` off.

Counters: ``events``, ``events_invalid``, ``loop_closures``, ``loop_rejected_interval``,
``loop_rejected_route``, ``loop_rejected_scan`` (the two sweeps do not fit),
``loop_scan_registered`` / ``loop_scan_untrusted`` (how closures got their displacement),
``scan_beams_before_odometry`` (beams before the first pose, unused), ``odometry_without_attitude`` (a zero quaternion, not used for the sweep), ``corrections_clamped`` (a closure scaled to corrections.max_norm),
``relaxation_iterations``, ``relaxation_steps_capped`` (iterations limited by
corrections.max_step), ``experience_images``, ``events_without_image``,
``image_wait_overflow``, ``maps_published``, ``sessions_started``, ``session_links``, ``session_backfill_edges``,
``loop_rejected_link`` (a link candidate the sweeps did not verify); with the odometry scale
``odometry_scale_updates`` and ``visual_scale_<count>`` (frame pairs: ``pairs`` measured,
``inliers``, ``outliers``, ``no_altitude``, ``slow``, ``no_odometry``, ``resized``).
"""
from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.config import ConfigError
from common.geometry import quaternion_to_matrix, yaw_of_quaternion
from common.messages import (
    ExperienceEvent,
    ExperienceImage,
    ExperienceLink,
    ExperienceNode,
    Header,
    Image,
    LaserScan,
    MapSessions,
    Odometry,
    PoseStamped,
    RangeImageBeam,
    ScanPose,
    SessionLinkInfo,
)
from common.messages import ExperienceMap as ExperienceMapMsg
from common.node import ServiceNode
from services.expmap.association import Association, EventImageAssociator
from services.expmap.config import ExpMapConfig
from services.expmap.graph import ExperienceMap
from services.expmap.laser_input import LaserScans
from services.expmap.scan_graph import ScanGraph
from services.expmap.scan_poses import ScanPoses
from services.expmap.scans import SweepBuffer, echo_range
from services.expmap.visual_scale import VisualScale

__all__ = ["ExpMapNode", "map_message"]

log = logging.getLogger(__name__)


def map_message(em: ExperienceMap | ScanGraph, header: Header) -> ExperienceMapMsg:
    """The ``map`` message of the graph (nodes with map positions, odometry and loop links)."""
    pos, yaw, lvc, st = em.positions, em.yaws, em.lvc_ids, em.stamps
    nodes = [ExperienceNode.model_construct(id=i, lvc_id=int(lvc[i]), position=[float(v) for v in pos[i]],
                                            yaw=float(yaw[i]), stamp=int(st[i])) for i in range(em.n_nodes)]
    links = [ExperienceLink.model_construct(source=s, target=t, delta=[float(v) for v in d], duration_s=float(du),
                                            weight=float(w), loop_closure=lc)
             for s, t, d, du, w, lc in em.edges()]
    return ExperienceMapMsg(header=header, nodes=nodes, links=links, current=em.n_nodes - 1,
                            corrections=em.corrections)


def _visual_scale_on(cfg: ExpMapConfig) -> bool:
    """The camera measures the odometry's scale (``expmap.visual_scale``; experience_map only)."""
    return cfg.visual_scale.enabled and cfg.graph == "experience_map"


def _scan_poses_on(cfg: ExpMapConfig) -> bool:
    """Every scan registered and published (``expmap.scan_graph.scan_poses``; laser map, scans at their stamps)."""
    return cfg.graph == "scan_graph" and cfg.scan_graph.scan_poses and cfg.scan_graph.odometry_at_stamps


class ExpMapNode(ServiceNode[ExpMapConfig]):
    """Transport wrapper of :class:`ExperienceMap` (or :class:`ScanGraph`) and :class:`EventImageAssociator`."""

    name = "expmap"
    inputs = ("camera/image_raw", "experience_event", "Odometry")
    outputs = ("map", "dead_reckoning", "experience_image", "map_sessions")

    @classmethod
    def io_keys(cls, config: ExpMapConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """Input keys under ``config`` (the camera key is configurable, and optional)."""
        cfg = config
        vs = _visual_scale_on(cfg)
        ins = ((cfg.image.topic,) if cfg.image.publish_experience or vs else ()) + ("experience_event", "Odometry")
        if cfg.loops.scan_matching or cfg.graph == "scan_graph":
            ins += (cfg.scan.topic,)
        if vs:
            ins += (cfg.visual_scale.dvl_topic,)
        return ins, cls.outputs + (("scan_pose",) if _scan_poses_on(cfg) else ())

    def __init__(self, config: ExpMapConfig, *, sync_stale_sec: float, pose_cell_shape: Sequence[int],
                 pose_cell_spacing: Sequence[float], odometry_axis_remap: str = "yxz",
                 odometry_axis_sign_z: float = -1.0):
        """``config``: the ``expmap`` section.  From other sections, explicitly:
        ``sync_stale_sec`` (``sync``, s), the pose-cell lattice ``pose_cell_shape`` (x y z yaw
        cells) and ``pose_cell_spacing`` (m; ``posecells.number_of_neurons`` and
        ``distance_between_neurons``, which place experiences, Eq. 4.20), and the odometry's
        frame (``robot_state.axis_remap``, ``axis_sign_z``: the laser sweeps need z vertical
        and the heading's sign)."""
        super().__init__(config)
        self.cfg = cfg = config
        self.image_key = cfg.image.topic
        self.images: EventImageAssociator[Header, Image] = EventImageAssociator(
            int(round(min(sync_stale_sec, cfg.image.sync_slop) * 1e9)), cfg.image.buffer_size)
        shape, spacing = list(pose_cell_shape), list(pose_cell_spacing)
        self.map_path = Path(cfg.map_path) if cfg.map_path else None
        self.scan_graph = cfg.graph == "scan_graph"
        self.graph: ExperienceMap | ScanGraph
        if self.scan_graph:
            self.graph = (ScanGraph.load(self.map_path, cfg.scan_graph)
                          if self.map_path is not None and self.map_path.exists() else ScanGraph(cfg.scan_graph))
        elif self.map_path is not None and self.map_path.exists():
            self.graph = ExperienceMap.load(self.map_path, cfg, shape, spacing)
            log.info("expmap: loaded %d experiences (%d loop closures) from %s", self.graph.n_nodes,
                     len(self.graph.loops), self.map_path)
        else:
            self.graph = ExperienceMap(cfg, shape, spacing)
        self.loaded_nodes = self.graph.n_nodes
        if cfg.sessions.begin_on_load and isinstance(self.graph, ExperienceMap) and self.graph.n_nodes:
            self.graph.begin_session()
            log.info("expmap: this run begins session %d, unlinked to the %d loaded experiences",
                     int(self.graph.sessions.max()) + 1, self.graph.n_nodes)
        self._last_stamp = 0
        self._promised = 0
        self._last_dr_stamp: int | None = None
        self._since_map = 0
        self._map_owed = False     # a loop closure or a settled correction not in a published map yet
        self._dirty = False
        self._waiting_events: list[ExperienceEvent] = []   # laser map: events waiting for the pose after them
        self.scan_key = cfg.scan.topic if (cfg.loops.scan_matching or self.scan_graph) else None
        sg = cfg.scan_graph
        self.laser = LaserScans(sg.min_range_m, sg.max_range_m, sg.sensor_offset, keep_placed=_scan_poses_on(cfg))
        self.scan_poses = ScanPoses(sg) if _scan_poses_on(cfg) else None
        if self.scan_key is not None and odometry_axis_remap[2] != "z":
            raise ConfigError(f"expmap.loops.scan_matching needs a vertical published z axis, but "
                              f"robot_state.axis_remap={odometry_axis_remap!r}; set "
                              "expmap.loops.scan_matching=false or keep z last")
        self.sweeps = SweepBuffer(head_sign=odometry_axis_sign_z, sweep_deg=cfg.scan.sweep_deg)
        self.visual: VisualScale | None = None
        if _visual_scale_on(cfg):
            if odometry_axis_remap[2] != "z":
                raise ConfigError(f"expmap.visual_scale needs a vertical published z axis, but "
                                  f"robot_state.axis_remap={odometry_axis_remap!r}; set "
                                  "expmap.visual_scale.enabled=false or keep z last")
            self.visual = VisualScale(cfg.visual_scale)
            self.dvl_key = cfg.visual_scale.dvl_topic
            if isinstance(self.graph, ExperienceMap):
                self.graph.run_first = self.graph.n_nodes

    # ---- inputs ---------------------------------------------------------------------
    def process(self, key: str, msg: Any) -> None:
        self._last_stamp = max(self._last_stamp, msg.header.stamp)
        if key == "experience_event":
            self._on_event(msg)
        elif key == "Odometry":
            self._on_odometry(msg)
        elif key == self.image_key:
            self._on_image(msg)
        elif key == self.scan_key:
            self._on_beam(msg)
        elif self.visual is not None and key == self.dvl_key:
            alt = getattr(msg, "altitude", None)
            if alt is None:
                raise ConfigError(f"expmap.visual_scale.dvl_topic {key!r} carries {type(msg).__name__}, which has "
                                  "no altitude; set expmap.visual_scale.enabled=false")
            self.visual.add_altitude(msg.header.stamp, float(alt))
        else:
            raise KeyError(f"expmap: unexpected input key {key!r} (inputs {self.inputs})")
        if self.scan_poses is not None:
            self._publish_scan_poses()

    def _on_event(self, ev: ExperienceEvent) -> None:
        if self.scan_graph and self.cfg.scan_graph.odometry_at_stamps:
            # the experience's frame is the odometry at its own stamp: wait for the pose after it
            if self.laser.covers(ev.header.stamp) or self.laser.odom_pose is None:
                self._add_event(self._at_own_stamp(ev))
            else:
                self._waiting_events.append(ev)
            return
        self._add_event(ev)

    def _at_own_stamp(self, ev: ExperienceEvent) -> ExperienceEvent:
        """The event with its odometry pose replaced by the odometry at its stamp (laser map)."""
        pose = self.laser.pose_at(ev.header.stamp)
        if pose is None:
            return ev
        return ev.model_copy(update={"odom_position": [float(pose[0]), float(pose[1]), ev.odom_position[2]],
                                     "odom_yaw": float(pose[2])})

    def _release_events(self, until: int | None) -> None:
        """Add the waiting events stamped at or before ``until`` (None: all) at their own stamps."""
        ready = [e for e in self._waiting_events if until is None or e.header.stamp <= until]
        self._waiting_events = [e for e in self._waiting_events if until is not None and e.header.stamp > until]
        for ev in ready:
            self._add_event(self._at_own_stamp(ev))

    def _add_event(self, ev: ExperienceEvent) -> None:
        if self.visual is not None and isinstance(self.graph, ExperienceMap):
            self._follow_scale()
        try:
            if self.scan_graph:
                sweep = self.laser.sweep_for(ev.odom_position[0], ev.odom_position[1], ev.odom_yaw)
            else:
                sweep = self.sweeps.sweep(ev.odom_position[:2]) if self.scan_key is not None else None
            res = self.graph.add_event(ev.header.stamp, ev.lvc_id, ev.pc_centroid, ev.odom_position, ev.odom_yaw,
                                       sweep=sweep)
        except ValueError as exc:
            log.error("expmap: experience_event seq %d skipped: %s", ev.header.seq, exc)
            self.count("events_invalid")
            return
        self._dirty = True
        self.count("events")
        if res.session_started:
            self.count("sessions_started")
            log.info("expmap: session %d begins at experience %d", self.graph.session, res.node)  # type: ignore[union-attr]
        if res.linked and isinstance(self.graph, ExperienceMap):
            self.count("session_links")
            lk = self.graph.session_links[-1]
            self.count("session_backfill_edges", lk.backfill_edges)
            log.info("expmap: session %d linked to session %d at %d -> %d (shift %s m, turned %.1f deg, inliers %.2f, "
                     "%d backfill edges)", lk.session, lk.to_session, lk.m, lk.n, " ".join(f"{v:.2f}" for v in lk.shift),
                     lk.applied_deg, lk.inlier_fraction, lk.backfill_edges)
        if res.loop_closed and isinstance(self.graph, ScanGraph):
            self.count("loop_closures")
            log.debug("expmap: loop closure %d -> %d (score %.3f, correction %.2f m)", res.match, res.node,
                      res.score, res.correction_norm)
        elif res.loop_closed and isinstance(self.graph, ExperienceMap):
            self.count("loop_closures")
            reg = self.graph.last_registration
            how = "zero displacement (no sweep)" if self.scan_key is not None else "zero displacement"
            if reg is not None:
                how = (f"sonar registration{' along one axis' if reg.ambiguous_axis is not None else ''}, "
                       f"inliers {reg.inlier_fraction:.2f}" if reg.trusted else f"zero displacement ({reg.reason})")
                self.count("loop_scan_registered" if reg.trusted else "loop_scan_untrusted")
            log.debug("expmap: loop closure %d -> %d (score %.3f, correction %.2f m%s; loop edge %s: %s)", res.match,
                     res.node, res.score, res.correction_norm, ", clamped" if res.correction_clamped else "",
                     " ".join(f"{v:.2f}" for v in self.graph.loop_deltas[-1]), how)
        if res.rejected:
            self.count(f"loop_rejected_{res.rejected}")
            if res.rejected == "scan" and isinstance(self.graph, ExperienceMap):
                rejected_by = self.graph.last_registration
                if rejected_by is None:
                    raise RuntimeError("expmap: a loop rejected by its scans left no registration")
                log.debug("expmap: loop closure %d -> %d rejected: the sonar sweeps do not fit (%s)", res.match,
                          res.node, rejected_by.reason)
        if res.correction_clamped:
            self.count("corrections_clamped")
        if res.iterations:
            self.count("relaxation_iterations", res.iterations)
        if res.step_capped:
            self.count("relaxation_steps_capped")
        self._since_map += 1
        every = self.cfg.map_publish_every
        if every:
            every = max(every, self.graph.n_nodes // 10)
        self._map_owed |= res.loop_closed or res.settled
        div = self.cfg.map_correction_divisor
        gap = self.graph.n_nodes // div if div else 0
        if (self._map_owed and self._since_map >= gap) or (every and self._since_map >= every):
            self._publish_map(ev.header.stamp)
        if self.cfg.image.publish_experience:
            self._publish_images(self.images.on_event(ev.header))

    def _follow_scale(self) -> None:
        """Apply the camera's odometry scale when it moved by more than ``update_step``."""
        assert self.visual is not None and isinstance(self.graph, ExperienceMap)
        scale, applied = self.visual.scale, self.graph.odometry_scale
        if scale is not None and abs(scale - 1.0) > self.cfg.visual_scale.max_deviation:
            self.count("visual_scale_implausible")
            scale = 1.0                     # not the DVL: the camera's measure is wrong
        if scale is None or abs(scale / applied - 1.0) <= self.cfg.visual_scale.update_step:
            return
        res = self.graph.set_odometry_scale(scale)
        self.count("odometry_scale_updates")
        if res.correction_clamped:
            self.count("corrections_clamped")
        log.debug("expmap: odometry scale %.4f (camera, %d of %d frame pairs)", scale, self.visual.counts["inliers"],
                 self.visual.counts["pairs"])

    def _on_odometry(self, od: Odometry) -> None:
        if self.visual is not None:
            self.visual.add_odometry(od.header.stamp, od.position[0], od.position[1])
        if self.scan_graph:
            if np.all(np.isfinite(od.position)) and any(od.orientation):
                at_stamps = self.cfg.scan_graph.odometry_at_stamps
                self.laser.set_pose(od.position[0], od.position[1], yaw_of_quaternion(od.orientation),
                                    od.header.stamp if at_stamps else None)
                if self._waiting_events:
                    self._release_events(od.header.stamp)
        elif self.scan_key is not None:
            try:
                self.sweeps.add_pose(od.position, quaternion_to_matrix(od.orientation), od.header.stamp,
                                     od.linear_velocity, od.angular_velocity)
            except ValueError as exc:   # a zero quaternion: no attitude to place the beams with
                log.warning("expmap: Odometry seq %d not used for the sonar sweep: %s", od.header.seq, exc)
                self.count("odometry_without_attitude")
        period = int(round(self.cfg.dead_reckoning_period_sec * 1e9))
        t = od.header.stamp
        if self._last_dr_stamp is not None and period > 0 and t - self._last_dr_stamp < period:
            return
        self._last_dr_stamp = t
        self.publish("dead_reckoning", PoseStamped(
            header=self.header("dead_reckoning", t, od.header.frame_id),
            position=list(od.position), yaw=yaw_of_quaternion(od.orientation)))

    def _on_beam(self, beam: RangeImageBeam | LaserScan) -> None:
        if isinstance(beam, LaserScan):
            self._on_scan(beam)
            return
        c = self.cfg
        rng = echo_range(beam.beam_data, float(beam.max_range), c.scan.min_range_m, c.scan.echo_threshold)
        if not self.sweeps.add_beam(beam.angle_rad, rng, beam.header.stamp):
            self.count("scan_beams_before_odometry")

    def _on_scan(self, scan: LaserScan) -> None:
        """Keep the scan's returns in the odometry frame (latest pose at or before its stamp)."""
        if not self.scan_graph:
            raise ConfigError(f"expmap: {self.scan_key} carries LaserScan; range scans need expmap.graph=scan_graph")
        stamp = scan.header.stamp if self.cfg.scan_graph.odometry_at_stamps else None
        if not self.laser.add_scan(scan.ranges, scan.angle_min, scan.angle_increment, scan.range_min,
                                   scan.range_max, stamp):
            self.count("scans_before_odometry")
            return
        self.count("scans")

    def _on_image(self, img: Image) -> None:
        if self.visual is not None:
            d = img.data
            self.visual.add_frame(img.header.stamp, d[:, :, 1] if d.ndim == 3 else d)   # green: the clearest in water
        if self.cfg.image.publish_experience:
            self._publish_images(self.images.on_frame(img))

    # ---- event-image association (services.expmap.association) ----------------------------
    def _publish_images(self, decisions: list[Association[Header, Image]]) -> None:
        for a in decisions:
            if a.overflow:
                self.count("image_wait_overflow")
            best = a.frame
            if best is None:
                self.count("events_without_image")
                continue
            self.count("experience_images")
            self.publish("experience_image", ExperienceImage(
                header=a.header.model_copy(), height=best.height, width=best.width, encoding=best.encoding,
                data=best.data, source_stamp=best.header.stamp))

    def _publish_scan_poses(self) -> None:
        """Register the scans placed since the last input against the newest experience
        (:mod:`services.expmap.scan_poses`) and publish their poses."""
        assert self.scan_poses is not None and isinstance(self.graph, ScanGraph)
        for stamp, odom_pose, pts in self.laser.take_placed():
            if stamp is None:    # only a scan placed without odometry_at_stamps, which turns scan poses off
                continue
            sp = self.scan_poses.place(self.graph, pts, odom_pose)
            if sp is None:
                continue
            self.publish("scan_pose", ScanPose(header=self.header("scan_pose", stamp), experience_id=sp.experience,
                                               pose=[float(v) for v in sp.pose], score=min(1.0, max(0.0, sp.score))))

    def output_watermark(self, input_watermark: int) -> int:
        """Hold the promise at the oldest event still waiting for its image, and never past
        the newest input processed: the final map is stamped with that input's stamp, which
        does not depend on which heartbeats happened to arrive (a resumed run equals an
        uninterrupted one)."""
        out = min(input_watermark, self._last_stamp)
        oldest = self.images.oldest_waiting
        if oldest is not None:
            out = min(out, oldest)
        waiting_scan = self.laser.oldest_waiting if self.scan_poses is not None else None
        if waiting_scan is not None:
            out = min(out, waiting_scan)
        self._promised = max(self._promised, out)
        return out

    # ---- outputs ------------------------------------------------------------------------
    def _publish_map(self, stamp: int) -> None:
        self._since_map = 0
        self._map_owed = False
        self.count("maps_published")
        self.publish("map", map_message(self.graph, self.header("map", stamp)))
        g = self.graph
        if isinstance(g, ExperienceMap) and g.n_sessions > 1:
            links = [SessionLinkInfo(session=lk.session, to_session=lk.to_session, source=lk.m, target=lk.n,
                                     stamp=lk.stamp, delta=[float(v) for v in lk.delta],
                                     shift=[float(v) for v in lk.shift], rotation_deg=lk.rotation_deg,
                                     inlier_fraction=lk.inlier_fraction, applied_deg=lk.applied_deg)
                     for lk in g.session_links]
            self.publish("map_sessions", MapSessions(
                header=self.header("map_sessions", stamp), node_session=[int(v) for v in g.sessions],
                loaded_nodes=self.loaded_nodes, links=links, rejections=dict(g.link_rejections)))

    def finish(self) -> None:
        if self.visual is not None:
            for k, v in self.visual.counts.items():
                self.count(f"visual_scale_{k}", v - self.counters.get(f"visual_scale_{k}", 0))
            log.info("expmap: odometry scale measured by the camera: %s (applied %.4f)", self.visual.scale,
                     getattr(self.graph, "odometry_scale", 1.0))
        if self.visual is not None and isinstance(self.graph, ExperienceMap):
            self._follow_scale()
        if self.scan_graph:
            self.laser.flush()
            self._release_events(None)
        if self.scan_poses is not None:
            self._publish_scan_poses()
        if isinstance(self.graph, ScanGraph):
            counters = dict(self.graph.counters, **(self.scan_poses.counters if self.scan_poses is not None else {}))
            for k, v in counters.items():
                self.count(k, v - self.counters.get(k, 0))
        self._publish_images(self.images.flush())
        if self.graph.pending:
            self.count("relaxation_iterations", self.graph.settle())
        if self.graph.n_nodes:
            self._publish_map(max(self._last_stamp, self._promised))
        self._save()

    def _save(self) -> None:
        if self.map_path is not None and self._dirty:
            self.graph.save(self.map_path)
            self._dirty = False
            log.info("expmap: saved %d experiences to %s", self.graph.n_nodes, self.map_path)

    def close(self) -> None:
        self._save()
