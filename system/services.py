"""Which services exist, and the one factory that builds any worker of a run by name.

Algorithm services are :class:`~common.node.ServiceNode` subclasses found at
``services.<name>.node:<Class>``.  A service whose module is not in the tree yet is simply
absent from :func:`available_services`; one that is present but fails to import is an
error (never hidden).

:func:`build_worker` builds the player, the recorder or an algorithm service's
:class:`~common.runtime.NodeRunner` (every one a :class:`common.worker.Worker`) from its
name, the configuration and a :class:`WorkerSpec` (what the launcher knows beyond the
configuration).  Both launchers use it: ``poseidon service NAME`` (one process) and the
embedded run (threads).  An unknown name is an :class:`UnknownService` error listing the
names there are.
"""
from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from common.bus import Bus
from common.node import ServiceNode
from common.resume import Supervision
from common.runtime import NodeRunner
from common.worker import Worker
from services.player.player import Player
from services.recorder.recorder import Recorder
from system.config import PoseidonConfig

__all__ = ["ALGORITHM_SERVICES", "OPTIONAL_SERVICES", "available_services", "node_class", "build_node",
           "PIPELINE_ORDER", "PLAYER", "RECORDER", "BRIDGE_ROS1", "LIVE_PLAYER", "latency_stages", "UnknownService",
           "WorkerSpec", "build_worker", "WIRING", "node_section", "node_io"]

#: the names of the workers that are not algorithm services (the ROS 1 bridge and the live player: live sources)
PLAYER, RECORDER, BRIDGE_ROS1, LIVE_PLAYER = "player", "recorder", "bridge_ros1", "live_player"


def latency_stages(config: PoseidonConfig) -> dict[str, str]:
    """Output key -> latency stage of a live run (the keys the ROS bridge publishes back)."""
    return config.bridge_ros1.output_stages()

#: name -> "module:Class", in pipeline order
ALGORITHM_SERVICES: dict[str, str] = {
    "encoder": "services.encoder.node:EncoderNode",
    "htm": "services.htm.node:HtmNode",
    "robot_state": "services.robot_state.node:RobotStateNode",
    "posecells": "services.posecells.node:PoseCellsNode",
    "expmap": "services.expmap.node:ExpMapNode",
}
PIPELINE_ORDER = list(ALGORITHM_SERVICES)

#: built alternatives started only when named (``--services``, ``services: [...]``), because
#: they publish a key a default service publishes too: name -> "module:Class"
OPTIONAL_SERVICES: dict[str, str] = {
    "ratslam_lv": "services.ratslam_lv.node:RatSlamViewNode",  # RatSLAM front-end: local_view_cells like htm
}


def _module_present(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def available_services(config: PoseidonConfig | None = None) -> list[str]:
    """Algorithm services present in this tree (pipeline order), then any added by configuration."""
    names = [name for name, target in ALGORITHM_SERVICES.items() if _module_present(target.split(":")[0])]
    if config is not None:
        names += [n for n in config.service_classes if n not in names]
    return names


def node_class(name: str, config: PoseidonConfig | None = None) -> type[ServiceNode[Any]]:
    """The node class of service ``name``; ``config.service_classes`` may swap or add one."""
    target = ((config.service_classes.get(name) if config is not None else None) or ALGORITHM_SERVICES.get(name)
              or OPTIONAL_SERVICES.get(name))
    if target is None:
        raise UnknownService(f"unknown service {name!r}; services: {PLAYER}, {RECORDER}, "
                             f"{', '.join([*ALGORITHM_SERVICES, *OPTIONAL_SERVICES, BRIDGE_ROS1, LIVE_PLAYER])}"
                             " (or add one with service_classes in the configuration)")
    if ":" not in target:
        raise KeyError(f"service {name!r}: {target!r} is not of the form 'module:Class'")
    module, cls_name = target.split(":", 1)
    if not _module_present(module):
        raise KeyError(f"service {name!r} is not built in this tree (no module {module})")
    cls = getattr(importlib.import_module(module), cls_name, None)
    if not (isinstance(cls, type) and issubclass(cls, ServiceNode)):
        raise KeyError(f"service {name!r}: {target} is not a ServiceNode subclass")
    return cls


class UnknownService(KeyError):
    """No worker of that name (the message lists the names there are)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown service"


@dataclass(frozen=True)
class _Wiring:
    """How the launcher builds one of our services: its own section, and the values it
    needs from other sections, passed as explicit keyword arguments."""

    section: Callable[[PoseidonConfig], BaseModel]
    links: Callable[[PoseidonConfig], dict[str, Any]] = lambda config: {}


#: every algorithm service of this tree: the one place where a value crosses sections
WIRING: dict[str, _Wiring] = {
    "encoder": _Wiring(lambda c: c.encoder, lambda c: {
        "sync_stale_sec": c.sync.sync_stale_sec, "lvc_map_persisted": bool(c.htm.state_path),
        "flow_window_s": c.bus.flow_window_ms / 1000.0}),
    "htm": _Wiring(lambda c: c.htm),
    "robot_state": _Wiring(lambda c: c.robot_state, lambda c: {
        "fault_jump_at_s": c.debug.fault_jump_at_s, "fault_jump_m": list(c.debug.fault_jump_m)}),
    "posecells": _Wiring(lambda c: c.posecells, lambda c: {"guard": c.vpr_guard}),
    "expmap": _Wiring(lambda c: c.expmap, lambda c: {
        "sync_stale_sec": c.sync.sync_stale_sec,
        "pose_cell_shape": list(c.posecells.number_of_neurons),
        "pose_cell_spacing": list(c.posecells.distance_between_neurons),
        "odometry_axis_remap": c.robot_state.axis_remap, "odometry_axis_sign_z": c.robot_state.axis_sign_z}),
    "ratslam_lv": _Wiring(lambda c: c.ratslam_lv),
}


def node_section(name: str, config: PoseidonConfig) -> BaseModel:
    """The configuration a node of service ``name`` is built from: its own section for a
    service of this tree (or a class swapped in for one, ``service_classes``), the whole
    configuration for a service added under a new name (it has no section of its own)."""
    wiring = WIRING.get(name)
    return wiring.section(config) if wiring is not None else config


def node_io(name: str, config: PoseidonConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Input and output keys of service ``name`` under ``config`` (its class's ``io_keys``)."""
    ins, outs = node_class(name, config).io_keys(node_section(name, config))
    return tuple(ins), tuple(outs)


def build_node(name: str, config: PoseidonConfig, **extra: Any) -> ServiceNode[Any]:
    """The node of algorithm service ``name`` built from ``config``: its own section plus,
    explicitly, what it needs of the others (:data:`WIRING`); ``extra`` keyword arguments
    go to the node's constructor too (tests: a stand-in encoder)."""
    wiring = WIRING.get(name)
    links = wiring.links(config) if wiring is not None else {}
    return node_class(name, config)(node_section(name, config), **links, **extra)


@dataclass
class WorkerSpec:
    """What a launcher knows about one worker beyond the configuration.

    ``drain``: the worker has its own process and stays until its consumers have left
    (``bus.drain_timeout_s``).  Player: ``input`` (required), ``keys`` (None:
    ``player.keys``, else every key of the recording), ``rate`` (None: ``player.rate``),
    ``wait_for`` (services it waits for and watches), ``progress`` (bar on stderr).
    Recorder: ``out`` (required), ``expect`` (keys whose end-of-stream ends the recording),
    ``metadata`` (the ``poseidon`` metadata record), ``copy_from`` and ``copy_keys`` (input keys it
    copies from the input recording itself: ``player.replay`` copied), ``input_digest`` (returns the SHA-256 it
writes into the metadata's ``input_sha256`` at the end: a replay's input).  ROS 1 bridge: ``announce`` (source keys
    it keeps alive with wall-clock watermarks and ends at its stop), ``read`` (the keys the run's
    services read; None: not known, every topic is bridged).  ``live``: a service of a
    live run (bounded input queue ``live.queue_frames``; ``debug.slow_service`` is slowed).  Service: ``node`` already built (None:
    built here).
    """

    supervision: Supervision | None = None
    drain: bool = False
    input: str | Path | None = None
    keys: Sequence[str] | None = None
    rate: float | None = None
    wait_for: Sequence[str] = ()
    progress: bool = True
    out: str | Path | None = None
    expect: Sequence[str] | None = None
    metadata: dict[str, Any] | None = None
    copy_from: str | Path | None = None
    copy_keys: Sequence[str] = ()
    input_digest: Callable[[], str] | None = None
    node: ServiceNode[Any] | None = None
    announce: Sequence[str] = ()
    read: Sequence[str] | None = None
    live: bool = False


def build_worker(name: str, config: PoseidonConfig, bus: Bus, spec: WorkerSpec | None = None) -> Worker:
    """The worker called ``name`` (player, recorder, ROS 1 bridge or an algorithm service) on ``bus``.

    ValueError when the spec lacks what the worker needs (the player's input, the
    recorder's output); :class:`UnknownService` (a KeyError) for a name that is none of them.
    """
    spec = spec or WorkerSpec()
    drain_s = config.bus.drain_timeout_s if spec.drain else 0.0
    if name == PLAYER:
        if spec.input is None:
            raise ValueError("the player needs an input recording")
        keys = spec.keys if spec.keys is not None else (config.player.keys or None)
        return Player(bus, spec.input, rate=config.player.rate if spec.rate is None else spec.rate, keys=keys,
                      wait_for=spec.wait_for, heartbeat_ms=config.bus.heartbeat_interval_ms,
                      startup_timeout_s=config.bus.startup_timeout_s, progress=spec.progress,
                      drain_timeout_s=drain_s, flow_window_ms=config.bus.flow_window_ms,
                      supervision=spec.supervision, bundle_frames=config.player.bundle_frames,
                      bundle_ms=config.player.bundle_ms)
    if name == RECORDER:
        if spec.out is None:
            raise ValueError("the recorder needs an output file")
        return Recorder(bus, spec.out, expect=spec.expect, metadata=spec.metadata,
                        compression=config.recorder.compression, chunk_size=config.recorder.chunk_size,
                        supervision=spec.supervision, copy_from=spec.copy_from, copy_keys=spec.copy_keys,
                        zstd_level=config.recorder.zstd_level, input_digest=spec.input_digest)
    if name == LIVE_PLAYER:
        if spec.input is None:
            raise ValueError("the live player needs an input recording")
        from services.player.live import LivePlayer
        return LivePlayer(bus, spec.input, latency_stages(config), rate=1.0 if spec.rate is None else spec.rate,
                          keys=spec.keys, lateness_ms=config.live.lateness_ms,
                          watermark_interval_ms=config.live.watermark_interval_ms, announce=spec.announce,
                          consumers=spec.supervision.consumers if spec.supervision is not None else None,
                          retain_s=config.live.retain_s, retain_mb=config.live.retain_mb,
                          end_wait_s=config.live.stop_timeout_s, stall_hold_ms=config.live.stall_hold_ms)
    if name == BRIDGE_ROS1:
        from services.bridge_ros1.bridge import Ros1Bridge  # rospy is imported only when it runs
        from services.bridge_ros1.grid import SonarModel
        sonar = SonarModel(config.expmap.scan.min_range_m, config.expmap.scan.echo_threshold,
                           float(config.robot_state.axis_sign_z))
        return Ros1Bridge(bus, config.bridge_ros1, announce=spec.announce, drain_timeout_s=drain_s,
                          consumers=spec.supervision.consumers if spec.supervision is not None else None,
                          retain_s=config.live.retain_s, retain_mb=config.live.retain_mb, sonar=sonar,
                          read=spec.read)
    node = spec.node if spec.node is not None else build_node(name, config)
    live, debug = config.live, config.debug
    # live: a message waits for a silent stream's watermark in wall time, so the live interval
    heartbeat_ms = live.watermark_interval_ms if spec.live else config.bus.heartbeat_interval_ms
    return NodeRunner(node, bus, heartbeat_ms, drain_timeout_s=drain_s,
                      supervision=spec.supervision, max_queue=live.queue_frames if spec.live else 0,
                      max_queue_bytes=int(live.queue_mb * 1e6) if spec.live else 0,
                      delay_s=debug.slow_ms / 1000 if spec.live and debug.slow_service == name else 0.0)
