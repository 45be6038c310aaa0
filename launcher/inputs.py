"""What each service of a run received on its inputs, and what the recording had that no
service read: the run's ``inputs`` summary (``poseidon run --json`` key ``inputs``).

Per service, every input key it subscribes to with the number of messages it received;
``missing``: the inputs that received nothing, except the reference keys a run replays for
evaluation (:data:`REFERENCE_KEYS`), which no service needs.  When a service is missing
inputs, ``hint`` says in one line which keys of the recording no service read and the exact
``poseidon import`` mapping (``--topic TOPIC=KEY``, :mod:`missions.importers.cli`) that puts
them on keys the service reads, matched by message type (:data:`common.messages.KEYS`),
with the setting the run then needs when the service reads that key only under another
configuration (:data:`ALTERNATIVES`, e.g. ``robot_state.source=wheel_odometry`` for a
ground robot's wheel odometry).  Inputs a service does not need under the run's configuration
(:func:`optional_inputs`: the sonar of an encoder fusing the camera alone) are never missing.  A service missing only what other services of the run
publish is named with them (``htm: no input on Odometry (robot_state published nothing)``).
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from common.config import apply_overrides
from common.live import HEALTH_KEY, LATENCY_KEY
from common.mcap_io import read_metadata, recording_keys
from common.messages import KEYS, RAW_KEY_PREFIX
from system.config import PoseidonConfig
from system.services import node_io

__all__ = ["REFERENCE_KEYS", "ALTERNATIVES", "optional_inputs", "input_report", "format_inputs"]

#: inputs that are references for evaluation (ground truth), never needed by a service
REFERENCE_KEYS = ("odometry", "truth/pose", "truth/revisits")

def optional_inputs(name: str, config: PoseidonConfig) -> set[str]:
    """Inputs service ``name`` subscribes to but does not need under ``config`` (the encoder's
    other modality when it fuses one alone)."""
    if name == "encoder":
        mode = config.encoder.fusion_mode
        return {config.encoder.sonar.topic} if mode == "camera" else {"camera/image_raw"} if mode == "sonar" else set()
    return set()


#: settings under which a service reads other inputs: tried when its inputs are missing
ALTERNATIVES: dict[str, tuple[str, ...]] = {
    "robot_state": ("robot_state.source=wheel_odometry",),
}


def _type_of(key: str) -> str | None:
    t = KEYS.get(key)
    return t.type_name if t is not None else None


def _unused_keys(recording: Mapping[str, str], io: Mapping[str, tuple[tuple[str, ...], tuple[str, ...]]]) -> dict[str, str]:
    """Keys of the recording (key -> type name) that no service reads or produces."""
    read = {k for ins, _o in io.values() for k in ins}
    made = {k for _i, outs in io.values() for k in outs}
    return {k: t for k, t in sorted(recording.items())
            if k not in read and k not in made and k not in REFERENCE_KEYS and k not in (LATENCY_KEY, HEALTH_KEY)
            and not k.startswith(RAW_KEY_PREFIX)}


def _matches(needed: list[str], unused: dict[str, str]) -> dict[str, str]:
    """Unused recording key -> the needed key of the same message type (each used once)."""
    out: dict[str, str] = {}
    free = list(needed)
    for rec_key, type_name in unused.items():
        target = next((k for k in free if _type_of(k) == type_name), None)
        if target is not None:
            out[rec_key] = target
            free.remove(target)
    return out


def _mapping(name: str, config: PoseidonConfig, missing: list[str],
             unused: dict[str, str]) -> tuple[dict[str, str], str | None]:
    """The mapping of unused recording keys for service ``name``: under an alternative setting
    when that one covers every input it would need, else onto its missing inputs as configured."""
    for setting in ALTERNATIVES.get(name, ()):
        variant = PoseidonConfig.model_validate(apply_overrides(config.model_dump(mode="json"), [setting]))
        needs = [k for k in node_io(name, variant)[0] if k not in REFERENCE_KEYS]
        found = _matches(needs, unused)
        if found and len(found) == len(needs):
            return found, setting
    return _matches(missing, unused), None


def _source_of(input_path: str | Path) -> tuple[str, dict[str, dict[str, Any]]]:
    """The import's source(s) of a recording (``SOURCE`` when it was not imported) and its
    bag topics (topic -> ``{"type", "key"}``)."""
    meta = read_metadata(input_path).get("poseidon", {})
    if meta.get("tool") != "poseidon import":
        return "SOURCE", {}
    try:
        sources = json.loads(meta.get("sources", "[]"))
        topics = json.loads(meta.get("topics", "{}"))
    except json.JSONDecodeError:
        return "SOURCE", {}
    return " ".join(str(s) for s in sources) or "SOURCE", topics if isinstance(topics, dict) else {}


def _hint(name: str, missing: list[str], unused: dict[str, str], mapping: dict[str, str], setting: str | None,
          input_path: str | Path) -> str:
    source, topics = _source_of(input_path)
    topic_of = {v.get("key"): t for t, v in topics.items() if isinstance(v, dict)}
    ros_type = {v.get("key"): v.get("type") for v in topics.values() if isinstance(v, dict)}
    line = f"{name}: no input on {', '.join(missing)}"
    if not unused:
        wanted = sorted({_type_of(k) or "?" for k in missing})
        return line + f"; the recording has nothing else of type {', '.join(t.split('/')[-1] for t in wanted)}"
    has = ", ".join(f"{k} ({ros_type.get(k) or t})" for k, t in unused.items())
    line += f"; the recording has {has}, which no service reads"
    if not mapping:
        return line + " (none of them is of a type it reads)"
    topic_args = " ".join(f"--topic {topic_of.get(k, '/' + k)}={key}" for k, key in mapping.items())
    line += f": map them with 'poseidon import {source} {topic_args} --out {input_path}'"
    if setting is not None:
        line += f" and run with '--set {setting}'"
    return line


def input_report(config: PoseidonConfig, io: Mapping[str, tuple[tuple[str, ...], tuple[str, ...]]],
                 services: Mapping[str, Mapping[str, Any]], input_path: str | Path | None) -> dict[str, Any]:
    """``{service: {"received": {key: n}, "missing": [key], "hint": str}}`` of a finished run.

    :param io: each algorithm service's (inputs, outputs) as the run wired them
    :param services: the services' final counters (``received``: messages per input key)
    :param input_path: the replayed recording (None: a live source, no recording to search)
    """
    recording = recording_keys(input_path) if input_path is not None else {}
    unused = _unused_keys(recording, io)
    producer = {k: n for n, (_i, outs) in io.items() for k in outs}
    report: dict[str, Any] = {}
    for name, (ins, _outs) in io.items():
        got = dict((services.get(name) or {}).get("received") or {})
        received = {k: int(got.get(k, 0)) for k in ins}
        missing = [k for k, n in received.items()
                   if n == 0 and k not in REFERENCE_KEYS and k not in optional_inputs(name, config)]
        sensors = [k for k in missing if k not in producer]   # what the recording (a source) had to give
        hint = ""
        if sensors and input_path is not None:
            mapping, setting = _mapping(name, config, sensors, unused)
            hint = _hint(name, missing, unused, mapping, setting, input_path)
        elif missing:
            silent = sorted({producer[k] for k in missing if k in producer})
            hint = f"{name}: no input on {', '.join(missing)}" + (
                f" ({', '.join(silent)} published nothing)" if silent else "")
        report[name] = {"received": received, "missing": missing, "hint": hint}
    return report


def format_inputs(report: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The readable lines of :func:`input_report`: per service its inputs and counts, then
    one line per service that received nothing on an input it needs."""
    lines = ["inputs received per service:"] if report else []
    for name, r in report.items():
        counts = ", ".join(f"{k} {n}" for k, n in r["received"].items()) or "(no inputs)"
        lines.append(f"  [{name}] {counts}")
    lines += [f"  {r['hint']}" for r in report.values() if r.get("hint")]
    return lines
