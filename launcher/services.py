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
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.bus import Bus
from common.config import PoseidonConfig
from common.node import ServiceNode
from common.resume import Supervision
from common.runtime import NodeRunner
from common.worker import Worker
from services.player.player import Player
from services.recorder.recorder import Recorder

__all__ = ["ALGORITHM_SERVICES", "OPTIONAL_SERVICES", "available_services", "node_class", "build_node",
           "PIPELINE_ORDER", "PLAYER", "RECORDER", "UnknownService", "WorkerSpec", "build_worker"]

#: the names of the two workers that are not algorithm services
PLAYER, RECORDER = "player", "recorder"

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


def node_class(name: str, config: PoseidonConfig | None = None) -> type[ServiceNode]:
    """The node class of service ``name``; ``config.service_classes`` may swap or add one."""
    target = ((config.service_classes.get(name) if config is not None else None) or ALGORITHM_SERVICES.get(name)
              or OPTIONAL_SERVICES.get(name))
    if target is None:
        raise UnknownService(f"unknown service {name!r}; services: {PLAYER}, {RECORDER}, "
                             f"{', '.join([*ALGORITHM_SERVICES, *OPTIONAL_SERVICES])}"
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


def build_node(name: str, config: PoseidonConfig) -> ServiceNode:
    """The node of algorithm service ``name`` built from ``config``."""
    return node_class(name, config)(config)


@dataclass
class WorkerSpec:
    """What a launcher knows about one worker beyond the configuration.

    ``drain``: the worker has its own process and stays until its consumers have left
    (``bus.drain_timeout_s``).  Player: ``input`` (required), ``keys`` (None:
    ``player.keys``, else every key of the recording), ``rate`` (None: ``player.rate``),
    ``wait_for`` (services it waits for and watches), ``progress`` (bar on stderr).
    Recorder: ``out`` (required), ``expect`` (keys whose end-of-stream ends the recording),
    ``metadata`` (the ``poseidon`` metadata record).  Service: ``node`` already built (None:
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
    node: ServiceNode | None = None


def build_worker(name: str, config: PoseidonConfig, bus: Bus, spec: WorkerSpec | None = None) -> Worker:
    """The worker called ``name`` (player, recorder or an algorithm service) on ``bus``.

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
                      supervision=spec.supervision)
    if name == RECORDER:
        if spec.out is None:
            raise ValueError("the recorder needs an output file")
        return Recorder(bus, spec.out, expect=spec.expect, metadata=spec.metadata,
                        compression=config.recorder.compression, chunk_size=config.recorder.chunk_size,
                        supervision=spec.supervision)
    node = spec.node if spec.node is not None else build_node(name, config)
    return NodeRunner(node, bus, config.bus.heartbeat_interval_ms, drain_timeout_s=drain_s,
                      supervision=spec.supervision)
