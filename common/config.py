"""What every configuration section shares, and how a configuration file is read.

Each service's section lives next to the service (``services/<name>/config.py``); the
sections every process uses (the bus, the cross-topic association window, supervision,
live runs, debugging knobs) live here; the whole, one field per section, is assembled in
``system/config.py``, with the file ``deploy/poseidon.yaml`` spelling out every default. A
section groups its settings by concern in sub-sections (``htm.sp``, ``expmap.loops``). A
user file only needs the keys it changes. Loading validates everything with pydantic: a
wrong type, a value out of range or an unknown key fails at start-up with the dotted name
of the field (``htm.sp.num_active_columns``) and the file it came from. ``--set key=value``
overrides use the same dotted names and YAML syntax for values (``--set
vpr_guard.vpr_window=30``). A key that was renamed (:data:`RENAMED_KEYS`) is refused with
its new name.

A field's ``description`` says what it does and ends with its unit in brackets
(``[m]``, ``[deg/s]``) when it has one (:func:`unit_of`).
"""
from __future__ import annotations

import copy
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, Self, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

__all__ = ["ConfigSection", "check", "SyncConfig", "BusConfig", "SuperviseConfig", "LiveConfig", "DebugConfig",
           "ConfigError", "RENAMED_KEYS", "renamed_keys_in", "migrate_renamed", "unit_of", "apply_overrides",
           "read_config_data", "validate_config"]


class ConfigSection(BaseModel):
    """Base of every configuration section: unknown keys are errors, assignments validated."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    def updated(self, changes: Mapping[str, Any]) -> Self:
        """A validated copy with ``changes`` applied.

        :param changes: dotted field name within this section -> new value
            (``{"seqmem.exclude": 2}``).
        :raises ConfigError: a name that is no field, or a value that does not validate.
        """
        data = self.model_dump()
        for dotted, value in changes.items():
            *path, leaf = dotted.split(".")
            node = data
            for part in path:
                if not isinstance(node.get(part), dict):
                    raise ConfigError(f"{dotted}: {part} is not a section")
                node = node[part]
            node[leaf] = value
        return validate_config(type(self), data, "changes " + ", ".join(changes))

    def get(self, dotted: str) -> Any:
        """The value of the dotted field ``dotted`` of this section (``"sp.columns"``)."""
        node: Any = self
        for part in dotted.split("."):
            node = getattr(node, part)
        return node


def check(cond: bool, what: str) -> None:
    """A cross-field rule of a section: ValueError naming the dotted fields (-> ConfigError)."""
    if not cond:
        raise ValueError(what)


_UNIT = re.compile(r"\s*\[([^\[\]]+)\]\s*$")


def unit_of(description: str | None) -> tuple[str, str]:
    """``(description without its unit, unit)``: the unit is the trailing ``[...]`` ('' when none)."""
    text = description or ""
    m = _UNIT.search(text)
    return (text[:m.start()], m.group(1)) if m else (text, "")


class SyncConfig(ConfigSection):
    """Association of messages across topics."""

    sync_stale_sec: float = Field(0.75, gt=0, description="two messages of different topics are associated "
                                  "when their stamps are at most this far apart [s]")


class BusConfig(ConfigSection):
    """The message bus (zenoh) every process joins."""

    namespace: str = Field("poseidon", pattern=r"^[A-Za-z0-9_\-/]+$", description="per-vehicle prefix of every "
                           "bus key")
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"], description="zenoh endpoints "
                               "to connect to (locators)")
    flow_window_ms: int = Field(3000, ge=100, description="replay keeps at most this much event time in "
                                "flight [ms]")
    heartbeat_interval_ms: int = Field(250, ge=1, description="event-time heartbeat of silent streams in "
                                       "replays: an output key silent this long gets a watermark. Larger: fewer "
                                       "frames (100 -> 250 cut the services' CPU ~8 %, recordings identical; "
                                       "docs/DECISIONS.md), a message may wait longer in event time for a sparse "
                                       "stream. Live runs use live.watermark_interval_ms (latency) [ms]")
    batch_scheduling: bool = Field(True, description="replays (poseidon run, not --live): every service "
                                   "process runs under Linux SCHED_BATCH, so a wake-up does not preempt the "
                                   "running service: fewer context switches on a loaded machine (-9 % CPU of all "
                                   "services, -7.5 % wall on the 10-minute mission; docs/DECISIONS.md). Recordings "
                                   "identical")
    replay_nice: int = Field(0, ge=0, le=19, description="replays (poseidon run, not --live): every service "
                             "process but bus.replay_favoured runs this much nicer than the launcher, so the "
                             "encoder gets a core whenever it can use one. 0: every service alike (the default: "
                             "at 5, three alternating rounds on the 60-minute mission gave -11 %, -6.7 % and "
                             "+3.4 % wall time; docs/DECISIONS.md). Recordings identical")
    replay_favoured: list[str] = Field(default_factory=lambda: ["encoder"], description="services left at the "
                                       "launcher's niceness in replays (bus.replay_nice): the encoder does the "
                                       "most work of any one process, and every later stage waits for it")
    startup_timeout_s: float = Field(180.0, gt=0, description="wait this long for subscribers and services to "
                                     "come alive (a service warms up first: on a cold numba cache the htm compiles "
                                     "for ~50 s on 2 loaded cores) [s]")
    drain_timeout_s: float = Field(3600.0, gt=0, description="a finished publisher waits this long for its "
                                   "consumers to finish [s]")


class SuperviseConfig(ConfigSection):
    """Supervision of a distributed run (launcher/supervise.py, common/resume.py)."""

    max_restarts: int = Field(3, ge=0, description="restarts of a service that dies, per service and run; "
                              "0: no supervision, a dying service ends the run (exit 3 naming it) [restarts]")
    restart_backoff_s: float = Field(0.5, ge=0, description="wait before restart n: n x this (wall clock) [s]")
    checkpoint_interval_s: float = Field(120.0, gt=0, description="a service saves its state every this much "
                                         "EVENT time of the inputs it processed (120: on a 3-hour mission htm "
                                         "rewrote ~9 GB per hour at 30; docs/DEPLOY.md) [s]")
    recorder_checkpoint_interval_s: float = Field(5.0, gt=0, description="the recorder ends its MCAP chunk, syncs "
                                                  "the file and reports its position every this much EVENT time. "
                                                  "Publishers keep their frames for replay until every consumer, the "
                                                  "recorder included, checkpointed past them, so this bounds what they "
                                                  "hold, and what a killed recorder can lose from its file [s]")
    rejoin_timeout_s: float = Field(60.0, gt=0, description="the player aborts the run when a consumer has "
                                    "been gone this long (wall clock) without coming back [s]")
    replay_retry_s: float = Field(3.0, gt=0, description="a restarted consumer repeats its replay request "
                                  "after this long without an answer (wall clock) [s]")
    state_dir: str = Field("", description="checkpoint folder; empty: <out stem>.state next to the run's output "
                           "(removed after a successful run)")
    health_interval_s: float = Field(1.0, gt=0, description="live runs: the launcher publishes every service's "
                                     "health (alive, restarts, lag, checkpoint age) on live/health this often "
                                     "(wall clock; the ROS 1 bridge republishes it on /diagnostics) [s]")
    caught_up_lag_s: float = Field(2.0, gt=0, description="live runs: a service within this much EVENT time of "
                                   "the source is caught up (a restarted one's recovery ends there; beyond it the "
                                   "health says WARN) [s]")


class LiveConfig(ConfigSection):
    """Live runs (``poseidon run --live``, launcher/live.py): what differs from a replay."""

    queue_frames: int = Field(2000, ge=1, description="a service's input queue holds at most this many data "
                              "frames; beyond, the oldest is dropped and counted per key (run summary: dropped). "
                              "At 16x real time 2000 frames are ~3 s of the map service's inputs on the demo mission, "
                              "~4 s of the encoder's (docs/DECISIONS.md, Live queues) [frames]")
    queue_mb: float = Field(256.0, gt=0, description="and at most this many MB of data frames: the bound on a "
                            "service's queue memory (the simulated camera's frames are 0.33 MB each) [MB]")
    lateness_ms: int = Field(200, ge=0, description="the live player's lateness bound (--live mcap; the rule: "
                             "common/live.py); the ROS bridge has its own, bridge_ros1.lateness_ms [ms]")
    stall_hold_ms: int = Field(2000, ge=0, description="the live player: a key silent for over 4 of its mean "
                               "gaps and half lateness_ms is taken to be held up, and its watermark stops advancing "
                               "for at most this long, so its messages after the stall are not late; 0: watermarks "
                               "follow the wall clock throughout (common/live.py: Stalls); the ROS bridge has its "
                               "own, bridge_ros1.stall_hold_ms [ms]")
    watermark_interval_ms: int = Field(100, ge=1, description="the live player sends wall-clock watermarks this "
                                       "often; the services' heartbeat in live runs (bus.heartbeat_interval_ms in "
                                       "replays) [ms]")
    startup_timeout_s: float = Field(180.0, gt=0, description="wait this long for the services and the recorder "
                                     "(each warmed up: numba kernels compiled) before the source starts [s]")
    stop_timeout_s: float = Field(120.0, gt=0, description="after the source stopped, wait this long for the "
                                  "services and the recorder to finish their inputs [s]")
    retain_s: float = Field(300.0, gt=0, description="supervised live runs: a live source keeps each key's frames "
                            "until every consumer checkpointed past them (supervise.checkpoint_interval_s), at most "
                            "this much EVENT time, so that a restarted service catches up on what it missed; a "
                            "restart that needs older frames counts them lost per key (run summary: lost) and "
                            "continues [s]")
    retain_mb: float = Field(256.0, gt=0, description="supervised live runs: at most this much kept per key by a "
                             "live source for restarted consumers (see retain_s) [MB]")


class DebugConfig(ConfigSection):
    """Fault injection and test knobs, not production settings; each is off by default. The launcher
    passes each to the one service or runner that uses it (system/services.py)."""

    slow_service: str = Field("", description="live runs: this service sleeps slow_ms before each input "
                              "(shows the drop policy when a service falls behind); '' = none")
    slow_ms: float = Field(0.0, ge=0, description="live runs: the delay of slow_service per input [ms]")
    fault_jump_at_s: float = Field(0.0, ge=0, description="robot_state: from this long after the first "
                                   "published Odometry on, add fault_jump_m to every published position (a "
                                   "kidnapped vehicle, an odometry reset); 0: off [s]")
    fault_jump_m: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3,
                                      description="robot_state: the jump of fault_jump_at_s, x y z in the "
                                      "published frame [m]")


class ConfigError(ValueError):
    """A configuration that does not validate; the message names the file and the field."""


#: every key that was renamed: old dotted key -> new dotted key. Reading a configuration file or an
#: override that uses an old key fails naming the new one (:func:`read_config_data`); a configuration
#: stored by an older recording or state file is read through :func:`migrate_renamed`.
RENAMED_KEYS: dict[str, str] = {
    "htm.sp_enable": "htm.sp.enabled",
    "htm.sp_columns": "htm.sp.columns",
    "htm.sp_numActiveColumns": "htm.sp.num_active_columns",
    "htm.sp_potentialRadius": "htm.sp.potential_radius",
    "htm.sp_potentialPct": "htm.sp.potential_pct",
    "htm.sp_synPermActiveInc": "htm.sp.syn_perm_active_inc",
    "htm.sp_synPermInactiveDec": "htm.sp.syn_perm_inactive_dec",
    "htm.sp_synPermConnected": "htm.sp.syn_perm_connected",
    "htm.sp_boostStrength": "htm.sp.boost_strength",
    "htm.sp_dutyCyclePeriod": "htm.sp.duty_cycle_period",
    "htm.sp_minPctOverlapDutyCycle": "htm.sp.min_pct_overlap_duty_cycle",
    "htm.sp_learn_steps": "htm.sp.learn_steps",
    "htm.sp_overlap_norm_steps": "htm.sp.overlap_norm_steps",
    "htm.tm_cellsPerColumn": "htm.tm.cells_per_column",
    "htm.tm_activationThreshold": "htm.tm.activation_threshold",
    "htm.tm_minThreshold": "htm.tm.min_threshold",
    "htm.tm_initialPermanence": "htm.tm.initial_permanence",
    "htm.tm_connectedPermanence": "htm.tm.connected_permanence",
    "htm.tm_maxNewSynapseCount": "htm.tm.max_new_synapse_count",
    "htm.tm_permanenceIncrement": "htm.tm.permanence_increment",
    "htm.tm_permanenceDecrement": "htm.tm.permanence_decrement",
    "htm.tm_predictedSegmentDecrement": "htm.tm.predicted_segment_decrement",
    "htm.tm_maxSegmentsPerCell": "htm.tm.max_segments_per_cell",
    "htm.tm_maxSynapsesPerSegment": "htm.tm.max_synapses_per_segment",
    "htm.tm_maxSynapses": "htm.tm.max_synapses",
    "htm.tm_input_columns": "htm.tm.input_columns",
    "htm.sv_tm_decide": "htm.tm.decide",
    "htm.sv_tm_share": "htm.tm.decide_share",
    "htm.sv_descriptor_source": "htm.descriptor.source",
    "htm.sv_tm_window": "htm.descriptor.tm_window",
    "htm.sv_tm_topk": "htm.descriptor.tm_topk",
    "htm.sv_tm_bits": "htm.descriptor.tm_bits",
    "htm.interval_mode": "htm.descriptor.interval_mode",
    "htm.theta_alpha": "htm.descriptor.theta_alpha",
    "htm.theta_rho": "htm.descriptor.theta_rho",
    "htm.max_bits": "htm.descriptor.max_bits",
    "htm.sv_match_threshold": "htm.lvc.match_threshold",
    "htm.sv_tm_match_threshold": "htm.lvc.tm_match_threshold",
    "htm.sv_min_intersection": "htm.lvc.min_intersection",
    "htm.sv_enable_f1_gate": "htm.lvc.f1_gate",
    "htm.min_f1": "htm.lvc.min_f1",
    "htm.sv_use_iou_tiebreak": "htm.lvc.iou_tiebreak",
    "htm.sv_require_multimodal": "htm.lvc.require_multimodal",
    "htm.sv_min_img_score": "htm.lvc.min_camera_score",
    "htm.sv_min_sonar_score": "htm.lvc.min_sonar_score",
    "htm.sv_seq_match_threshold": "htm.lvc.successor_threshold",
    "htm.sv_seq_hops": "htm.lvc.successor_hops",
    "htm.sv_seqmem_length": "htm.seqmem.length",
    "htm.sv_seqmem_velocities": "htm.seqmem.velocities",
    "htm.sv_seqmem_exclude": "htm.seqmem.exclude",
    "htm.sv_seqmem_threshold": "htm.seqmem.threshold",
    "htm.sv_seqmem_margin": "htm.seqmem.margin",
    "htm.sv_seqmem_store": "htm.seqmem.store",
    "htm.sv_seqmem_every_frame_limit": "htm.seqmem.every_frame_limit",
    "htm.sv_seqmem_override": "htm.seqmem.override",
    "htm.sv_seqmem_min_f1": "htm.seqmem.min_f1",
    "htm.sv_seqmem_f1_quantile": "htm.seqmem.f1_quantile",
    "htm.sv_seqmem_confident_margin": "htm.seqmem.confident_margin",
    "htm.sv_seqmem_calib_warmup": "htm.seqmem.calib_warmup",
    "htm.sv_seqmem_column_norm": "htm.seqmem.column_norm",
    "htm.sv_dr_gate": "htm.dr_gate.enabled",
    "htm.sv_dr_gate_min_m": "htm.dr_gate.min_m",
    "htm.sv_dr_gate_drift": "htm.dr_gate.drift",
    "htm.sv_dr_gate_min_path_m": "htm.dr_gate.min_path_m",
    "htm.sv_dr_gate_seqmem_threshold": "htm.dr_gate.seqmem_threshold",
    "htm.sv_dr_gate_seqmem_margin": "htm.dr_gate.seqmem_margin",
    "htm.sv_dr_gate_jump_m": "htm.dr_gate.jump_m",
    "expmap.loop_confirmations": "expmap.loops.confirmations",
    "expmap.loop_confirmation_gap": "expmap.loops.confirmation_gap",
    "expmap.loop_edge_weight": "expmap.loops.edge_weight",
    "expmap.loop_place_radius_m": "expmap.loops.place_radius_m",
    "expmap.loop_scan_matching": "expmap.loops.scan_matching",
    "expmap.min_correction_route_len": "expmap.corrections.min_route_len",
    "expmap.max_correction_norm": "expmap.corrections.max_norm",
    "expmap.max_correction_step": "expmap.corrections.max_step",
    "expmap.min_correction_interval_sec": "expmap.corrections.min_interval_sec",
    "expmap.relax_iterations_per_event": "expmap.corrections.iterations_per_event",
    "expmap.image_topic": "expmap.image.topic",
    "expmap.image_transport": "expmap.image.transport",
    "expmap.publish_experience_image": "expmap.image.publish_experience",
    "expmap.image_buffer_size": "expmap.image.buffer_size",
    "expmap.image_sync_slop": "expmap.image.sync_slop",
    "expmap.scan_topic": "expmap.scan.topic",
    "expmap.scan_sweep_deg": "expmap.scan.sweep_deg",
    "expmap.scan_min_range_m": "expmap.scan.min_range_m",
    "expmap.scan_echo_threshold": "expmap.scan.echo_threshold",
    "expmap.scan_cell_m": "expmap.scan.cell_m",
    "expmap.scan_search_radius_m": "expmap.scan.search_radius_m",
    "expmap.scan_max_rotation_deg": "expmap.scan.max_rotation_deg",
    "expmap.scan_rotation_step_deg": "expmap.scan.rotation_step_deg",
    "expmap.scan_min_points": "expmap.scan.min_points",
    "expmap.scan_min_inlier_fraction": "expmap.scan.min_inlier_fraction",
    "expmap.scan_reject_inconsistent": "expmap.scan.reject_inconsistent",
    "expmap.scan_ambiguity_margin_m": "expmap.scan.ambiguity_margin_m",
    "expmap.scan_max_ambiguity_m": "expmap.scan.max_ambiguity_m",
    "expmap.map_sessions": "expmap.sessions.begin_on_load",
    "expmap.session_jump_m": "expmap.sessions.jump_m",
    "expmap.session_link_min_inliers": "expmap.sessions.link_min_inliers",
    "expmap.session_link_rotate": "expmap.sessions.link_rotate",
    "expmap.session_link_max_rotation_deg": "expmap.sessions.link_max_rotation_deg",
    "expmap.session_link_rotation_step_deg": "expmap.sessions.link_rotation_step_deg",
    "expmap.session_backfill_radius_m": "expmap.sessions.backfill_radius_m",
    "expmap.session_backfill_spacing_m": "expmap.sessions.backfill_spacing_m",
    "expmap.session_backfill_search_m": "expmap.sessions.backfill_search_m",
    "encoder.sonar_polar_width": "encoder.sonar.polar_width",
    "encoder.sonar_polar_height": "encoder.sonar.polar_height",
    "encoder.sonar_rmax": "encoder.sonar.max_range_m",
    "encoder.sonar_use_intensities": "encoder.sonar.use_intensities",
    "encoder.sonar_topic": "encoder.sonar.topic",
    "encoder.sonar_encode_sweep_deg": "encoder.sonar.encode_sweep_deg",
    "encoder.embedding_norm": "encoder.embedding_norm.mode",
    "encoder.embedding_norm_warmup": "encoder.embedding_norm.warmup",
    "encoder.embedding_norm_rate": "encoder.embedding_norm.rate",
    "encoder.embedding_norm_scale": "encoder.embedding_norm.scale",
    "encoder.embedding_norm_path": "encoder.embedding_norm.path",
    "encoder.embedding_norm_hold": "encoder.embedding_norm.hold",
    "encoder.embedding_norm_hold_max_s": "encoder.embedding_norm.hold_max_s",
    "encoder.lsbh_matrix_path": "encoder.lsbh.matrix_path",
    "encoder.lsbh_seed": "encoder.lsbh.seed",
    "encoder.lsbh_s": "encoder.lsbh.s",
    "robot_state.dvl_rotation_rpy_deg": "robot_state.dvl.rotation_rpy_deg",
    "robot_state.dvl_translation_m": "robot_state.dvl.translation_m",
    "robot_state.dvl_velocity_sigma": "robot_state.dvl.velocity_sigma",
    "robot_state.dvl_max_speed": "robot_state.dvl.max_speed",
    "robot_state.dvl_timeout_s": "robot_state.dvl.timeout_s",
    "robot_state.dvl_velocity_sign": "robot_state.dvl.velocity_sign",
    "robot_state.dvl_min_good_beams": "robot_state.dvl.min_good_beams",
    "robot_state.dvl_gate_chi2": "robot_state.dvl.gate_chi2",
    "robot_state.dvl_dropout_decay_s": "robot_state.dvl.dropout_decay_s",
    "robot_state.dropout_speed_sigma": "robot_state.dvl.dropout_speed_sigma",
    "robot_state.dvl_heading_fusion": "robot_state.dvl.heading_fusion",
    "robot_state.dvl_heading_sigma_deg": "robot_state.dvl.heading_sigma_deg",
    "robot_state.dvl_heading_offset_sigma_deg": "robot_state.dvl.heading_offset_sigma_deg",
    "robot_state.use_imu": "robot_state.imu.enabled",
    "robot_state.imu_topic": "robot_state.imu.topic",
    "robot_state.imu_rotation_rpy_deg": "robot_state.imu.rotation_rpy_deg",
    "robot_state.imu_timeout_s": "robot_state.imu.timeout_s",
    "robot_state.gyro_sigma_deg_s": "robot_state.imu.gyro_sigma_deg_s",
    "robot_state.roll_pitch_sigma_deg": "robot_state.imu.roll_pitch_sigma_deg",
    "robot_state.imu_yaw_drift_sigma_deg_s": "robot_state.imu.yaw_drift_sigma_deg_s",
    "robot_state.gyro_bias_sigma_deg_s": "robot_state.imu.gyro_bias_sigma_deg_s",
    "robot_state.gyro_bias_rw_deg_s": "robot_state.imu.gyro_bias_rw_deg_s",
    "robot_state.imu_yaw_drift_rate_sigma_deg_min": "robot_state.imu.yaw_drift_rate_sigma_deg_min",
    "robot_state.imu_yaw_drift_rate_rw_deg_min_s": "robot_state.imu.yaw_drift_rate_rw_deg_min_s",
    "robot_state.depth_offset_m": "robot_state.depth.offset_m",
    "robot_state.depth_sigma": "robot_state.depth.sigma",
    "robot_state.depth_timeout_s": "robot_state.depth.timeout_s",
    "robot_state.heading_sigma_deg": "robot_state.imu.heading_sigma_deg",
    "live.slow_service": "debug.slow_service",
    "live.slow_ms": "debug.slow_ms",
    "robot_state.fault_jump_at_s": "debug.fault_jump_at_s",
    "robot_state.fault_jump_m": "debug.fault_jump_m",
}


def _dotted_items(data: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for k, v in data.items():
        key = f"{prefix}{k}"
        yield key, v
        if isinstance(v, Mapping):
            yield from _dotted_items(v, key + ".")


def renamed_keys_in(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """``(old, new)`` for every renamed key (:data:`RENAMED_KEYS`) that ``data`` uses.

    :param data: a configuration mapping (or, with ``prefix``, the mapping at that dotted key).
    :param prefix: the dotted key ``data`` sits at, ending in ``.`` (``"htm."``); '' for the whole.
    """
    # every old key was a leaf: a mapping at one is the new section of that name (encoder.embedding_norm)
    return [(key, RENAMED_KEYS[key]) for key, value in _dotted_items(data, prefix)
            if key in RENAMED_KEYS and not isinstance(value, Mapping)]


def _refuse_renamed(data: Mapping[str, Any], source: str, prefix: str = "") -> None:
    found = renamed_keys_in(data, prefix)
    if found:
        raise ConfigError(f"renamed configuration keys ({source}):\n"
                          + "\n".join(f"  {old} was renamed {new}" for old, new in found))


def migrate_renamed(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A copy of ``data`` with every renamed key moved to its new name: reads a configuration
    stored by an older version (a recording's ``poseidon`` metadata, a state file).

    :param data: a configuration mapping; with ``prefix`` (``"htm."``) one section of it.
    """
    out = copy.deepcopy(dict(data))
    for old, new in renamed_keys_in(data, prefix):
        *old_path, old_leaf = old[len(prefix):].split(".")
        node = out
        for p in old_path:
            node = node[p]
        value = node.pop(old_leaf)
        if not new.startswith(prefix):
            continue            # moved to another section (debug): not part of this mapping
        *new_path, new_leaf = new[len(prefix):].split(".")
        node = out
        for p in new_path:
            nxt = node.get(p)
            if not isinstance(nxt, dict):
                nxt = node[p] = {}
            node = nxt
        node[new_leaf] = value
    return out


def _format_errors(err: ValidationError, source: str) -> str:
    lines = [f"invalid configuration ({source}):"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "<root>"
        if e["type"] == "extra_forbidden":
            lines.append(f"  {loc}: unknown field")
        elif e["type"] == "value_error" and isinstance(e.get("input"), dict):  # a cross-field rule of a section
            lines.append(f"  {loc}: {e['msg'].removeprefix('Value error, ')}")
        else:
            lines.append(f"  {loc}: {e['msg']} (got {e.get('input')!r})")
    return "\n".join(lines)


def _parse_override(item: str) -> tuple[list[str], Any]:
    if "=" not in item:
        raise ConfigError(f"override {item!r} is not of the form key.sub=value")
    dotted, raw = item.split("=", 1)
    parts = [p for p in dotted.strip().split(".") if p]
    if not parts:
        raise ConfigError(f"override {item!r} names no field")
    return parts, yaml.safe_load(raw)


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``key.sub=value`` overrides (value parsed as YAML) to a nested dict."""
    out = copy.deepcopy(data)
    for item in overrides:
        parts, value = _parse_override(item)
        node = out
        for p in parts[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"override {item!r}: {p} is not a section")
            node = nxt
        node[parts[-1]] = value
    return out


def read_config_data(path: str | Path | None = None, overrides: list[str] | None = None) -> tuple[dict[str, Any], str]:
    """The raw mapping of a configuration file (``path`` None: empty) with ``overrides`` applied,
    and a description of its source for error messages.

    :raises ConfigError: naming the file when it is missing, not YAML or not a mapping, and
        naming the file or the override when either uses a renamed key (:data:`RENAMED_KEYS`).
    """
    data: dict[str, Any] = {}
    source = "defaults"
    if path is not None:
        p = Path(path)
        source = str(p)
        try:
            loaded = yaml.safe_load(p.read_text())
        except FileNotFoundError:
            raise ConfigError(f"configuration file not found: {p}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"configuration file {p} is not valid YAML: {exc}") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"configuration file {p}: top level must be a mapping, got {type(loaded).__name__}")
        _refuse_renamed(loaded, source)
        data = loaded
    if overrides:
        for item in overrides:
            parts, value = _parse_override(item)
            _refuse_renamed({parts[-1]: value}, f"--set {item}", ".".join(parts[:-1]) + "." if parts[:-1] else "")
        data = apply_overrides(data, overrides)
        source += " + --set " + " ".join(overrides)
    return data, source


ModelT = TypeVar("ModelT", bound=BaseModel)


def validate_config(model: type[ModelT], data: dict[str, Any], source: str) -> ModelT:
    """Validate ``data`` as ``model``; :class:`ConfigError` naming ``source`` and every bad dotted field."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format_errors(err, source)) from None
