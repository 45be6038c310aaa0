"""The summary of a finished ``poseidon run``: the ``--json`` document and its readable lines.

:func:`complete_run` adds to a run's result (:class:`launcher.run.RunResult`) its evaluation
(:mod:`eval.summary`), the places its front-end recognised (:mod:`launcher.places`) and its log
file; :func:`format_run` writes the readable summary; :func:`input_hints` are the lines a user must
act on (inputs that received nothing), shown also with ``--json``.  The keys are documented in
:mod:`launcher.cli`.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict, cast

if TYPE_CHECKING:
    from eval.results import RunSummary
    from system.config import PoseidonConfig

__all__ = ["RunReport", "complete_run", "format_run", "format_service", "input_hints"]


class RunReport(TypedDict):
    """``poseidon run --json``: the run (output, mode, wall seconds, per-service counters, the
    recording's counts and duration, restarts, inputs) with its evaluation, places and log file."""

    output: str
    mode: str
    wall_s: float
    services: dict[str, dict[str, Any]]
    recording: dict[str, Any]
    restarts: NotRequired[dict[str, int]]
    inputs: NotRequired[dict[str, Any]]
    health: NotRequired[dict[str, Any]]       # live runs: launcher/health.py
    recoveries: NotRequired[list[dict[str, Any]]]
    evaluation: RunSummary
    places: dict[str, Any] | None
    log: str | None


def complete_run(result: Mapping[str, Any], config: PoseidonConfig | None) -> RunReport:
    """``result`` (:meth:`launcher.run.RunResult.as_dict`) with ``evaluation``, ``places`` and
    ``log`` added (after its own keys)."""
    from eval.summary import summarize_run
    from launcher.logs import log_file
    from launcher.places import places_summary
    log_path = log_file()
    report = {**result, "evaluation": summarize_run(result["output"], config),
              "places": places_summary(result["output"]),
              "log": str(log_path) if log_path is not None else None}
    return cast(RunReport, report)


def input_hints(report: RunReport) -> list[str]:
    """The one-line hints of the services that received nothing on an input they need."""
    return [r["hint"] for r in (report.get("inputs") or {}).values() if r.get("hint")]


def cpu_split_text(st: Mapping[str, Any]) -> str:
    """`` (start-up a s, node b s, frame path c s)`` for an algorithm service's counters
    (:mod:`common.runtime`), '' for the others."""
    if "node_cpu_s" not in st:
        return ""
    return (f" (start-up {st['startup_cpu_s']:.2f} s, node {st['node_cpu_s']:.2f} s, "
            f"frame path {st['frame_path_cpu_s']:.2f} s)")


def format_service(name: str, st: Mapping[str, Any]) -> list[str]:
    """One service's counters on a line (``[name] ok`` when there is nothing to say), then its
    latency per stage."""
    extra = []
    if st.get("invalid"):
        extra.append(f"invalid {st['invalid']}")
    if st.get("counters"):
        extra.append(", ".join(f"{k} {v}" for k, v in sorted(st["counters"].items())))
    if "busy_s" in st:
        extra.append(f"busy {st['busy_s']:.2f} s")
    if "cpu_s" in st:
        extra.append(f"process CPU {st['cpu_s']:.2f} s" + cpu_split_text(st))
    if "peak_rss_mb" in st:
        extra.append(f"peak memory {st['peak_rss_mb']:.0f} MB")
    if st.get("real_time_factor"):
        extra.append(f"{st['real_time_factor']:.1f}x real time")
    if st.get("dropped"):
        extra.append(f"dropped (queue full, oldest first) {st['dropped']}")
    if st.get("late"):
        extra.append(f"late {st['late']}")
    if st.get("behind_ms"):
        extra.append(f"published behind its schedule by p99 {st['behind_ms']['p99']:.1f} ms, "
                     f"max {st['behind_ms']['max']:.1f} ms" + ("" if st.get("complete") else " (stopped early)"))
    if st.get("outages"):
        extra.append(f"link outages {st['outages']}: delivered late {st.get('delivered_late') or {}}, "
                     f"sent again {st.get('resent') or {}}, dropped (outage buffer full) "
                     f"{st.get('dropped_outage') or {}}")
    if st.get("missing"):
        extra.append(f"missing (never arrived) {st['missing']}")
    if st.get("lost"):
        extra.append(f"lost (no longer kept for its catch-up) {st['lost']}")
    if st.get("retention"):
        r = st["retention"]
        extra.append(f"kept for restarted consumers at most {r['peak_mb']:.1f} MB (bound {r['retain_s']:.0f} s, "
                     f"{r['retain_mb']:.0f} MB per key), {r['replays']} replays")
    if st.get("raw"):
        extra.append(f"carried raw {st['raw']}")
    lines = [f"  [{name}] " + "; ".join(extra) if extra else f"  [{name}] ok"]
    for stage, lat in (st.get("latency") or {}).items():
        if lat.get("n"):
            lines.append(f"    latency arrival -> {stage:<9} p50 {lat['p50_ms']:8.1f} ms  p95 {lat['p95_ms']:8.1f} ms  "
                         f"p99 {lat['p99_ms']:8.1f} ms  (n {lat['n']})")
    return lines


def format_run(report: RunReport) -> list[str]:
    """The readable summary: wall time and output, messages per key, each service's counters,
    the inputs received, the evaluation, the places and the log file."""
    from eval.summary import format_summary
    from launcher.inputs import format_inputs
    from launcher.places import format_places
    rec = report["recording"]
    lines = [f"run finished ({report['mode']}) in {report['wall_s']:.1f} s wall; "
             f"{rec['duration_s']:.1f} s of mission -> {report['output']}",
             "recorded messages per key:"]
    lines += [f"  {key:<24} {n:>8}" for key, n in sorted(rec["counts"].items())]
    for name, st in report["services"].items():
        lines += format_service(name, st)
    if report.get("restarts"):
        lines.append("restarts: " + ", ".join(f"{n} {k}" for n, k in sorted(report["restarts"].items())))
    for r in report.get("recoveries") or []:
        lines.append(f"  {r['service']} ({r['cause']}): restarted after {r['restarted_s']} s, first input done "
                     f"after {r['resumed_s']} s, caught up after {r['caught_up_s']} s")
    lines += format_inputs(report.get("inputs") or {})
    lines += format_summary(report["evaluation"])
    lines += format_places(report["places"])
    if report["log"] is not None:
        lines.append(f"log: {report['log']}")
    return lines
