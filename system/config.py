"""The whole configuration, assembled in one place from the sections of the services.

Each section is defined next to its service (``services/<name>/config.py``) or, when every
process uses it, in ``common/config.py``. This is the composition root's view: the
launcher builds each service from its own section and passes what a service needs from
another section explicitly (``system/services.py::build_node``); services never see the
whole. ``deploy/poseidon.yaml`` spells out every default (``python -m system.write_defaults``);
defaults follow Table 4.1 of the dissertation.
"""
from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import annotated_types
import yaml
from pydantic import BaseModel, Field
from pydantic.fields import FieldInfo

from common.config import (
    RENAMED_KEYS,
    BusConfig,
    ConfigError,
    ConfigSection,
    DebugConfig,
    LiveConfig,
    SuperviseConfig,
    SyncConfig,
    read_config_data,
    unit_of,
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
from services.viewer.config import ViewConfig

__all__ = ["PoseidonConfig", "ConfigError", "load_config", "DEFAULT_CONFIG_PATH", "RENAMED_KEYS", "DebugConfig",
           "FieldDoc", "SectionDoc", "RenamedDoc", "UnknownKey", "explain_key", "section_docstring", "show_config",
           "SyncConfig", "BusConfig", "SuperviseConfig", "PlayerConfig", "RecorderConfig", "EncoderConfig",
           "HtmConfig", "RobotStateConfig", "RatSlamLvConfig", "PoseCellsConfig", "VprGuardConfig",
           "ExpMapConfig", "ScanGraphConfig", "BridgeRos1Config", "ViewConfig"]

DEFAULT_CONFIG_PATH = Path(__file__).resolve().parent.parent / "deploy" / "poseidon.yaml"


class PoseidonConfig(ConfigSection):
    """Every parameter of the system; section names follow the services."""

    sync: SyncConfig = Field(default_factory=SyncConfig)
    bus: BusConfig = Field(default_factory=BusConfig)
    player: PlayerConfig = Field(default_factory=PlayerConfig)
    recorder: RecorderConfig = Field(default_factory=RecorderConfig)
    supervise: SuperviseConfig = Field(default_factory=SuperviseConfig)
    live: LiveConfig = Field(default_factory=LiveConfig)
    view: ViewConfig = Field(default_factory=ViewConfig)
    debug: DebugConfig = Field(default_factory=DebugConfig)
    encoder: EncoderConfig = Field(default_factory=EncoderConfig)
    htm: HtmConfig = Field(default_factory=HtmConfig)
    robot_state: RobotStateConfig = Field(default_factory=RobotStateConfig)
    ratslam_lv: RatSlamLvConfig = Field(default_factory=RatSlamLvConfig)
    posecells: PoseCellsConfig = Field(default_factory=PoseCellsConfig)
    vpr_guard: VprGuardConfig = Field(default_factory=VprGuardConfig)
    expmap: ExpMapConfig = Field(default_factory=ExpMapConfig)
    bridge_ros1: BridgeRos1Config = Field(default_factory=BridgeRos1Config)
    services: list[str] = Field(default_factory=list, description="services the launcher starts (empty: every "
                                "service built in this tree)")
    service_classes: dict[str, str] = Field(
        default_factory=dict,
        description="swap or add a service implementation: service name -> 'module:Class' (a ServiceNode subclass)")


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> PoseidonConfig:
    """Load and validate a configuration.

    ``path`` None loads the defaults only.  Raises :class:`ConfigError` naming the file and
    the dotted field of every problem.
    """
    data, source = read_config_data(path, overrides)
    return validate_config(PoseidonConfig, data, source)


# ---------------------------------------------------------------- poseidon config --explain / --show

@dataclass(frozen=True)
class FieldDoc:
    """One configuration field, as ``poseidon config --explain`` prints it."""

    key: str            #: dotted name (``htm.sp.num_active_columns``)
    description: str    #: what it does, without the unit
    type: str           #: its type (``int``, ``Literal['tm', 'sp', 'sdr']``)
    default: Any        #: its default (JSON-like)
    unit: str           #: its unit ('' when it has none)
    range: str          #: the values allowed (``>= 1``, ``> 0, <= 1``; '' when any of its type)


@dataclass(frozen=True)
class SectionDoc:
    """A configuration section: what it is for, its fields and its sub-sections."""

    key: str                         #: dotted name ('' for the whole configuration)
    description: str                 #: the first paragraph of the section class's docstring
    fields: tuple[FieldDoc, ...]     #: its own fields, in order
    sections: tuple[str, ...]        #: dotted names of its sub-sections


@dataclass(frozen=True)
class RenamedDoc:
    """An old key: what it is called now."""

    key: str
    new_key: str


class UnknownKey(KeyError):
    """No configuration key of that name; ``matches`` are the closest names there are."""

    def __init__(self, key: str, matches: list[str]):
        super().__init__(key)
        self.key = key
        self.matches = matches

    def __str__(self) -> str:
        near = f"; did you mean {', '.join(self.matches)}?" if self.matches else ""
        return f"no configuration key {self.key!r}{near}"


def section_docstring(model: type[BaseModel]) -> str:
    """The first paragraph of a section class's docstring, on one line ('' without one)."""
    doc = model.__dict__.get("__doc__") or ""
    return " ".join(doc.strip().split("\n\n")[0].split())


def _section_type(info: FieldInfo) -> type[BaseModel] | None:
    ann = info.annotation
    return ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None


def _type_name(ann: Any) -> str:
    if isinstance(ann, type) and not getattr(ann, "__args__", None):
        return ann.__name__
    text = str(ann).replace("typing.", "")
    return re.sub(r"Annotated\[(\w+), FieldInfo\(.*?\)\]\)\]", r"\1", text)   # list[Annotated[int, ...]] -> list[int]


_BOUNDS = ((annotated_types.Gt, "gt", ">"), (annotated_types.Ge, "ge", ">="), (annotated_types.Lt, "lt", "<"),
           (annotated_types.Le, "le", "<="), (annotated_types.MinLen, "min_length", "length >="),
           (annotated_types.MaxLen, "max_length", "length <="))


def _range(info: FieldInfo) -> str:
    parts = []
    for meta in info.metadata:
        for cls, attr, sym in _BOUNDS:
            if isinstance(meta, cls):
                parts.append(f"{sym} {getattr(meta, attr)}")
        pattern = getattr(meta, "pattern", None)
        if pattern:
            parts.append(f"matches {pattern}")
    ann = info.annotation
    if str(ann).startswith("typing.Literal"):
        parts.append("one of " + ", ".join(str(a) for a in ann.__args__))  # type: ignore[union-attr]
    return ", ".join(parts)


def _field_doc(key: str, info: FieldInfo) -> FieldDoc:
    description, unit = unit_of(info.description)
    default = info.get_default(call_default_factory=True)
    if isinstance(default, BaseModel) or (isinstance(default, dict) and any(isinstance(v, BaseModel)
                                                                             for v in default.values())):
        default = yaml.safe_load(yaml.safe_dump(_jsonable(default)))
    return FieldDoc(key, description, _type_name(info.annotation), default, unit, _range(info))


def _jsonable(value: Any) -> Any:
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return value


def _section_doc(key: str, model: type[BaseModel]) -> SectionDoc:
    prefix = key + "." if key else ""
    fields, sections = [], []
    for name, info in model.model_fields.items():
        if _section_type(info) is not None:
            sections.append(prefix + name)
        else:
            fields.append(_field_doc(prefix + name, info))
    return SectionDoc(key, section_docstring(model), tuple(fields), tuple(sections))


def _all_keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    out = []
    for name, info in model.model_fields.items():
        out.append(prefix + name)
        sub = _section_type(info)
        if sub is not None:
            out += _all_keys(sub, prefix + name + ".")
    return out


def explain_key(key: str) -> FieldDoc | SectionDoc | RenamedDoc:
    """What the configuration key ``key`` (dotted) is: a field, a section ('' or a section's
    name), or an old name and its new one.

    :raises UnknownKey: no such key; its ``matches`` name the closest keys.
    """
    key = key.strip().strip(".")
    model: type[BaseModel] = PoseidonConfig
    if not key:
        return _section_doc("", model)
    parts = key.split(".")
    for i, part in enumerate(parts):
        info = model.model_fields.get(part)
        if info is None:
            break
        sub = _section_type(info)
        if i == len(parts) - 1:
            return _section_doc(key, sub) if sub is not None else _field_doc(key, info)
        if sub is None:
            break
        model = sub
    if key in RENAMED_KEYS:   # a key that exists wins (encoder.embedding_norm was a field, is a section)
        return RenamedDoc(key, RENAMED_KEYS[key])
    known = _all_keys(PoseidonConfig)
    leaf = parts[-1]
    matches = [k for k in known if k.rsplit(".", 1)[-1] == leaf]
    matches += [k for k in difflib.get_close_matches(key, known, n=5, cutoff=0.6)
                if k not in matches]
    raise UnknownKey(key, matches[:6])


def show_config(config: PoseidonConfig) -> str:
    """The configuration ``config`` as YAML (every field, defaults included)."""
    text: str = yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False, width=100)
    return text
