"""Which services exist, and how to build them from a configuration.

Algorithm services are :class:`~common.node.ServiceNode` subclasses found at
``services.<name>.node:<Class>``.  A service whose module is not in the tree yet is simply
absent from :func:`available_services`; one that is present but fails to import is an
error (never hidden).
"""
from __future__ import annotations

import importlib
import importlib.util

from common.config import PoseidonConfig
from common.node import ServiceNode

__all__ = ["ALGORITHM_SERVICES", "OPTIONAL_SERVICES", "available_services", "node_class", "build_node",
           "PIPELINE_ORDER"]

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
        raise KeyError(f"unknown service {name!r}; services: player, recorder, "
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


def build_node(name: str, config: PoseidonConfig) -> ServiceNode:
    return node_class(name, config)(config)
