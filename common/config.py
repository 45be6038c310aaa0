"""What every configuration section shares, and how a configuration file is read.

Each service's section lives next to the service (``services/<name>/config.py``); the
sections every process uses (the bus, the cross-topic association window, supervision)
live here; the whole, one field per section, is assembled in ``system/config.py``,
with the file ``deploy/poseidon.yaml`` spelling out every default. A user file only
needs the keys it changes. Loading validates everything with pydantic: a wrong type, a
value out of range or an unknown key fails at start-up with the dotted name of the field
(``htm.sp_numActiveColumns``) and the file it came from. ``--set key=value`` overrides
use the same dotted names and YAML syntax for values (``--set vpr_guard.window=30``).
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

__all__ = ["ConfigSection", "check", "SyncConfig", "BusConfig", "SuperviseConfig", "LiveConfig", "ConfigError",
           "apply_overrides", "read_config_data", "validate_config"]


class ConfigSection(BaseModel):
    """Base of every configuration section: unknown keys are errors, assignments validated."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


def check(cond: bool, what: str) -> None:
    """A cross-field rule of a section: ValueError naming the dotted fields (-> ConfigError)."""
    if not cond:
        raise ValueError(what)


class SyncConfig(ConfigSection):
    sync_stale_sec: float = Field(0.75, gt=0, description="cross-topic association window (s)")


class BusConfig(ConfigSection):
    namespace: str = Field("poseidon", pattern=r"^[A-Za-z0-9_\-/]+$", description="per-vehicle key prefix")
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    flow_window_ms: int = Field(3000, ge=100, description="replay keeps at most this much event time in flight (ms)")
    heartbeat_interval_ms: int = Field(250, ge=1, description="event-time heartbeat of silent streams (ms) in "
                                       "replays: an output key silent this long gets a watermark. Larger: fewer "
                                       "frames (100 -> 250 cut the services' CPU ~8 %, recordings identical; "
                                       "docs/DECISIONS.md), a message may wait longer in event time for a sparse "
                                       "stream. Live runs use live.watermark_interval_ms (latency)")
    batch_scheduling: bool = Field(True, description="replays (poseidon run, not --live): every service "
                                   "process runs under Linux SCHED_BATCH, so a wake-up does not preempt the "
                                   "running service: fewer context switches on a loaded machine (-9 % CPU of all "
                                   "services, -7.5 % wall on the 10-minute mission; docs/DECISIONS.md). Recordings "
                                   "identical")
    startup_timeout_s: float = Field(180.0, gt=0, description="wait for subscribers/services to come alive (a "
                                     "service warms up first: on a cold numba cache the htm compiles for ~50 s on 2 "
                                     "loaded cores)")
    drain_timeout_s: float = Field(3600.0, gt=0, description="a finished publisher waits this long for consumers to finish")


class SuperviseConfig(ConfigSection):
    """Supervision of a distributed run (launcher/supervise.py, common/resume.py)."""

    max_restarts: int = Field(3, ge=0, description="restarts of a service that dies, per service and run; "
                              "0: no supervision, a dying service ends the run (exit 3 naming it)")
    restart_backoff_s: float = Field(0.5, ge=0, description="wait before restart n: n x this (s, wall clock)")
    checkpoint_interval_s: float = Field(120.0, gt=0, description="a service saves its state every this much "
                                         "EVENT time (s) of the inputs it processed (120: on a 3-hour mission htm "
                                         "rewrote ~9 GB per hour at 30; docs/DEPLOY.md)")
    recorder_checkpoint_interval_s: float = Field(5.0, gt=0, description="the recorder ends its MCAP chunk, syncs "
                                                  "the file and reports its position every this much EVENT time (s). "
                                                  "Publishers keep their frames for replay until every consumer, the "
                                                  "recorder included, checkpointed past them, so this bounds what they "
                                                  "hold, and what a killed recorder can lose from its file")
    rejoin_timeout_s: float = Field(60.0, gt=0, description="the player aborts the run when a consumer has "
                                    "been gone this long (s, wall) without coming back")
    replay_retry_s: float = Field(3.0, gt=0, description="a restarted consumer repeats its replay request "
                                  "after this long without an answer (s, wall)")
    state_dir: str = Field("", description="checkpoint folder; empty: <out stem>.state next to the run's output "
                           "(removed after a successful run)")


class LiveConfig(ConfigSection):
    """Live runs (``poseidon run --live``, launcher/live.py): what differs from a replay."""

    queue_frames: int = Field(500, ge=1, description="a service's input queue holds at most this many data frames; "
                              "beyond, the oldest is dropped and counted per key (run summary: dropped)")
    slow_service: str = Field("", description="TEST SETTING: this service sleeps slow_ms before each input "
                              "(shows the drop policy when a service falls behind); '' = none")
    slow_ms: float = Field(0.0, ge=0, description="TEST SETTING: the delay of slow_service per input (ms)")
    lateness_ms: int = Field(200, ge=0, description="the live player's lateness bound (--live mcap; the rule: "
                             "common/live.py); the ROS bridge has its own, bridge_ros1.lateness_ms")
    watermark_interval_ms: int = Field(100, ge=1, description="the live player sends wall-clock watermarks this "
                                       "often; the services' heartbeat in live runs (bus.heartbeat_interval_ms in replays)")
    startup_timeout_s: float = Field(180.0, gt=0, description="wait this long for the services and the recorder "
                                     "(each warmed up: numba kernels compiled) before the source starts")
    stop_timeout_s: float = Field(120.0, gt=0, description="after the source stopped, wait this long for the "
                                  "services and the recorder to finish their inputs")


class ConfigError(ValueError):
    """A configuration that does not validate; the message names the file and the field."""


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


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``key.sub=value`` overrides (value parsed as YAML) to a nested dict."""
    out = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r} is not of the form key.sub=value")
        dotted, raw = item.split("=", 1)
        parts = [p for p in dotted.strip().split(".") if p]
        if not parts:
            raise ConfigError(f"override {item!r} names no field")
        node = out
        for p in parts[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"override {item!r}: {p} is not a section")
            node = nxt
        node[parts[-1]] = yaml.safe_load(raw)
    return out


def read_config_data(path: str | Path | None = None, overrides: list[str] | None = None) -> tuple[dict[str, Any], str]:
    """The raw mapping of a configuration file (``path`` None: empty) with ``overrides`` applied,
    and a description of its source for error messages.  Raises :class:`ConfigError` naming
    the file when it is missing, not YAML or not a mapping."""
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
        data = loaded
    if overrides:
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
