"""What a run is called on the page: its label (:func:`run_label`) and the line on where it comes
from (:func:`run_details`), read from the run's ``poseidon`` metadata record and those of the
recordings it was made from (a ``poseidon run``'s ``input``, followed back to the mission, the
import or the simulation).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from eval.rundata import RunData, metadata_of_recording

__all__ = ["run_label", "run_details", "run_kind", "recording_name", "preset_of", "KNOWN_RECORDINGS",
           "PRESETS_DIR"]

log = logging.getLogger(__name__)


#: recordings of the public benchmarks, by file stem, as their papers name them
KNOWN_RECORDINGS = {"aces": "ACES", "fr079": "FR079", "mit-csail": "MIT CSAIL",
                    "fr-clinic_robotlaser": "Freiburg clinic"}
#: file suffixes taken off a source's name (``aces.clf.bz2`` -> ``aces``)
_SOURCE_SUFFIXES = (".bz2", ".gz", ".clf", ".log", ".bag", ".db3", ".mcap")
#: where ``poseidon run --config`` presets live (the run's configuration is matched against them)
PRESETS_DIR = Path(__file__).resolve().parents[2] / "deploy" / "presets"


def _stem(name: str) -> str:
    stem = Path(name).name
    while stem.lower().endswith(_SOURCE_SUFFIXES):
        stem = stem.rsplit(".", 1)[0]
    return stem


def _source_chain(run: RunData, depth: int = 5) -> list[tuple[Path, dict[str, Any]]]:
    """The recordings the run was made from, nearest first: each ``poseidon run``'s ``input`` (and
    that recording's metadata, empty when it is gone), up to the first one that is not a run."""
    chain: list[tuple[Path, dict[str, Any]]] = []
    meta = run.metadata
    while meta.get("input") and len(chain) < depth:
        src = Path(str(meta["input"]))
        try:
            meta = metadata_of_recording(src) if src.is_file() else {}
        except Exception:  # noqa: BLE001 - an unreadable input only loses the name
            log.debug("report: %s: metadata unreadable", src, exc_info=True)
            meta = {}
        chain.append((src, meta))
        if meta.get("tool") != "poseidon run":
            break
    return chain


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(d, dict):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: d}


def preset_of(config: dict[str, Any] | None, presets_dir: Path = PRESETS_DIR) -> str | None:
    """The name of the preset (``deploy/presets/NAME.yaml``) whose every field the configuration has, else None."""
    import yaml
    if not isinstance(config, dict) or not presets_dir.is_dir():
        return None
    flat = _flat(config)
    for path in sorted(presets_dir.glob("*.yaml")):
        try:
            fields = _flat(yaml.safe_load(path.read_text(encoding="utf-8")) or {})
        except (OSError, yaml.YAMLError):
            continue
        if fields and all(k in flat and flat[k] == v for k, v in fields.items()):
            return path.stem
    return None


def run_kind(counts: dict[str, int]) -> str:
    """``laser``, ``sonar``, ``camera``, ``camera and sonar`` or "" from the keys a recording holds."""
    laser = bool(counts.get("scan"))
    sonar = any(n and k.startswith("sonar") for k, n in counts.items())
    camera = bool(counts.get("camera/image_raw") or counts.get("experience_image"))
    if laser:
        return "laser"
    return " and ".join(w for w, on in (("camera", camera), ("sonar", sonar)) if on)


def recording_name(run: RunData) -> str:
    """What the run was made of: the imported log or bag (a public benchmark by its name), else the mission
    recording's file stem, else the run's own."""
    chain = _source_chain(run)
    if not chain:
        return run.path.stem
    src, meta = chain[-1]
    sources = meta.get("sources") if meta.get("tool") == "poseidon import" else None
    stem = _stem(str(sources[0])) if isinstance(sources, list) and sources else _stem(src.name)
    return KNOWN_RECORDINGS.get(stem.lower(), stem)


def run_label(run: RunData, compare: bool = False) -> str:
    """A run's name.  One run: what it is, ``<recording> <kind> run (<preset>)`` (:func:`recording_name`,
    :func:`run_kind`, :func:`preset_of`; e.g. ``ACES laser run (laser2d)``).  Runs compared
    (``compare``): ``<file stem> (VPR Guard ON|OFF)`` when the run has events and its configuration says,
    else the file stem."""
    cfg = run.metadata.get("config")
    if compare:
        guard = cfg.get("vpr_guard", {}).get("require_vpr_for_event") if isinstance(cfg, dict) else None
        if guard is None or not run.events:
            return run.path.stem
        return f"{run.path.stem} (VPR Guard {'ON' if guard else 'OFF'})"
    kind = run_kind(run.counts)
    preset = preset_of(cfg)
    return f"{recording_name(run)} {kind + ' ' if kind else ''}run" + (f" ({preset})" if preset else "")


def run_details(run: RunData) -> str:
    """One line on where a run comes from: file, tool, input (and what that was made from), preset,
    duration, code revision."""
    meta = run.metadata
    parts = [run.path.name]
    tool = meta.get("tool")
    chain = _source_chain(run)
    if chain:
        src, smeta = chain[-1]
        what = f"{tool or 'run'} of {chain[0][0].name}"
        sources = smeta.get("sources")
        if smeta.get("tool") == "poseidon import" and isinstance(sources, list) and sources:
            fmt = smeta.get("source_format")
            what += f" (imported from {Path(str(sources[0])).name}{', ' + fmt if fmt else ''})"
        elif len(chain) > 1:
            what += f" (made from {src.name})"
        parts.append(what)
    elif tool:
        parts.append(str(tool))
    preset = preset_of(meta.get("config"))
    if preset:
        parts.append(f"preset {preset}")
    parts.append(f"{run.duration_s:,.1f} s")
    if meta.get("code_revision"):
        parts.append(f"code revision {meta['code_revision']}")
    elif not meta:
        parts.append("no poseidon metadata record")
    return " · ".join(parts)
