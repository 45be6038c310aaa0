"""``poseidon info REC.mcap``: what a recording holds, whether it is complete, and its recovery.

:func:`recording_info` gathers the summary (the ``--json`` document, keys in :mod:`launcher.cli`),
:func:`format_info` writes it as text, :func:`cmd_info` reads the arguments and chooses the exit
code: 0 for a complete recording (or one recovered with ``--recover``), 1 for a damaged one (what
is readable is listed, with how to recover it), 2 for a file that is not a readable MCAP recording.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NotRequired, TypedDict, cast

__all__ = ["Recovered", "KeyDigest", "RecordingInfo", "recording_info", "format_info", "cmd_info"]


class Recovered(TypedDict):
    """The complete file ``--recover`` wrote and how many messages it holds."""

    path: str
    messages: int


class KeyDigest(TypedDict):
    """One key's stream digest (:func:`common.mcap_io.key_digests`)."""

    messages: int
    sha256: str


class RecordingInfo(TypedDict):
    """``poseidon info --json``: counts and types per key, time span (ns, s), metadata record
    name -> field names, completeness and where a damaged file stops being readable."""

    counts: dict[str, int]
    types: dict[str, str]
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    digests: NotRequired[dict[str, KeyDigest]]
    metadata: dict[str, list[str]]
    complete: bool
    damage: str
    recovered: NotRequired[Recovered]


def recording_info(path: str | Path, recover: str | None = None, digests: bool = False) -> RecordingInfo:
    """The summary of the recording at ``path``.

    :param recover: write every intact message to this file (a complete recording)
    :param digests: add each key's stream digest
    :raises common.mcap_io.RecordingError: ``path`` is not a readable MCAP recording
    """
    from common.mcap_io import (
        key_digests,
        read_metadata,
        recording_keys,
        recording_status,
        recording_summary,
        recover_recording,
    )
    status = recording_status(path)
    summary = recording_summary(path)
    summary["types"] = recording_keys(path)
    meta = read_metadata(path)
    recovered = None
    if digests:
        summary["digests"] = key_digests(path)
    if recover:
        recovered = recover_recording(path, recover)
    summary["metadata"] = {name: sorted(rec) for name, rec in meta.items()}
    summary["complete"] = status["complete"]
    summary["damage"] = status["error"]
    if recovered is not None:
        summary["recovered"] = {"path": recover, "messages": recovered}
    return cast(RecordingInfo, summary)


def format_info(path: str | Path, info: RecordingInfo) -> list[str]:
    """The readable summary: time span, then per key its message count and type, the metadata
    records' fields and (with digests) each key's sha256."""
    lines = [f"{path}: {info['duration_s']:.1f} s"]
    for k, n in sorted(info["counts"].items()):
        lines.append(f"  {k:<24} {n:>8}  {info['types'].get(k, '')}")
    for name, fields in info["metadata"].items():
        lines.append(f"  metadata {name}: {', '.join(fields)}")
    for k, d in info.get("digests", {}).items():
        lines.append(f"  sha256 {k:<24} {d['sha256']}")
    return lines


def cmd_info(args: argparse.Namespace) -> int:
    """``poseidon info``: print the summary (``--json`` or text); exit 0, 1 (damaged) or 2 (unreadable)."""
    from common.mcap_io import RecordingError
    try:
        info = recording_info(args.recording, args.recover, getattr(args, "digests", False))
    except RecordingError as exc:
        print(f"poseidon info: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for line in format_info(args.recording, info):
            print(line)
    if "recovered" in info:
        print(f"poseidon info: {info['recovered']['messages']} messages written to {args.recover} "
              "(a complete recording)", file=sys.stderr)
        return 0
    if not info["complete"]:
        print(f"poseidon info: damaged or unfinished recording: {info['damage']}; the messages listed are intact; "
              f"'poseidon info {args.recording} --recover FIXED.mcap' writes them to a complete file",
              file=sys.stderr)
        return 1
    return 0
