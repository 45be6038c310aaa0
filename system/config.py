"""The whole configuration, assembled in one place from the sections of the services.

Each section is defined next to its service (``services/<name>/config.py``) or, when every
process uses it, in ``common/config.py``. This is the composition root's view: the
launcher builds each service from its own section and passes what a service needs from
another section explicitly (``system/services.py::build_node``); services never see the
whole. ``deploy/poseidon.yaml`` spells out every default (``python -m system.write_defaults``);
defaults follow Table 4.1 of the dissertation.
"""
from __future__ import annotations

from pathlib import Path

from pydantic import Field

from common.config import (
    BusConfig,
    ConfigError,
    ConfigSection,
    LiveConfig,
    SuperviseConfig,
    SyncConfig,
    read_config_data,
    validate_config,
)
from services.bridge_ros1.config import BridgeRos1Config
from services.encoder.config import EncoderConfig
from services.expmap.config import ExpMapConfig, ScanGraphConfig
from services.htm.config import HtmConfig
from services.player.config import PlayerConfig
from services.posecells.config import PoseCellsConfig, VprGuardConfig
from services.ratslam_lv.config import RatSlamLvConfig
from services.recorder.config import RecorderConfig
from services.robot_state.config import RobotStateConfig

__all__ = ["PoseidonConfig", "ConfigError", "load_config", "DEFAULT_CONFIG_PATH",
           "SyncConfig", "BusConfig", "SuperviseConfig", "PlayerConfig", "RecorderConfig", "EncoderConfig",
           "HtmConfig", "RobotStateConfig", "RatSlamLvConfig", "PoseCellsConfig", "VprGuardConfig",
           "ExpMapConfig", "ScanGraphConfig", "BridgeRos1Config"]

DEFAULT_CONFIG_PATH = Path(__file__).resolve().parent.parent / "deploy" / "poseidon.yaml"


class PoseidonConfig(ConfigSection):
    """Every parameter of the system; section names follow the services."""

    sync: SyncConfig = Field(default_factory=SyncConfig)
    bus: BusConfig = Field(default_factory=BusConfig)
    player: PlayerConfig = Field(default_factory=PlayerConfig)
    recorder: RecorderConfig = Field(default_factory=RecorderConfig)
    supervise: SuperviseConfig = Field(default_factory=SuperviseConfig)
    live: LiveConfig = Field(default_factory=LiveConfig)
    encoder: EncoderConfig = Field(default_factory=EncoderConfig)
    htm: HtmConfig = Field(default_factory=HtmConfig)
    robot_state: RobotStateConfig = Field(default_factory=RobotStateConfig)
    ratslam_lv: RatSlamLvConfig = Field(default_factory=RatSlamLvConfig)
    posecells: PoseCellsConfig = Field(default_factory=PoseCellsConfig)
    vpr_guard: VprGuardConfig = Field(default_factory=VprGuardConfig)
    expmap: ExpMapConfig = Field(default_factory=ExpMapConfig)
    bridge_ros1: BridgeRos1Config = Field(default_factory=BridgeRos1Config)
    services: list[str] = Field(default_factory=list, description="services the launcher starts (empty: all built)")
    service_classes: dict[str, str] = Field(
        default_factory=dict,
        description="swap or add a service implementation: name -> 'module:Class' (a ServiceNode subclass)")


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> PoseidonConfig:
    """Load and validate a configuration.

    ``path`` None loads the defaults only.  Raises :class:`ConfigError` naming the file and
    the dotted field of every problem.
    """
    data, source = read_config_data(path, overrides)
    return validate_config(PoseidonConfig, data, source)
