"""``poseidon report RUN.mcap [RUN2.mcap ...] --out DIR [--relations FILE] [--json]``: the run(s) as one HTML page.

Writes ``DIR/index.html``: self-contained (plotly.js inlined, images as data URIs; opens
offline), with the figures of Section 5.4 (3D overlay, XY/XZ/YZ projections, final
topology, similarity and ground-truth matrices, view cells over time, precision-recall,
deviation over time and on XY, evidence images), the tables (run summary; per run the
evaluation of :func:`eval.run_eval.evaluate_run` and the audit of
:func:`eval.audit.audit_run`; for two or more runs :func:`eval.compare.compare_runs` of
the first with each other, Table 5.4 and Tables 5.2-5.3), and each run's configuration
and code revision.  The page shows what the runs have data for, in an order that suits
them (:mod:`eval.report.page`): a run without ground truth or with laser scans leads with
its map.  A run with laser scans (key ``scan``) also gets its laser point maps and its
loop closures over time (:mod:`eval.report.benchmark`).  A table whose function cannot be
imported or fails is listed on the page as unavailable with the reason (and logged);
``--strict`` makes that an error.

Options: ``--label L`` (once per run; default for one run its name, e.g. ``ACES laser run
(laser2d)``, :func:`eval.report.naming.run_label`; for several ``<file stem> (VPR Guard
ON|OFF)``), ``--max-points`` (per trajectory, default 3000), ``--max-frames`` (similarity
matrix, default 500), ``--min-gap-m`` (pairs closer in true travel are left out of
precision-recall, default 10 m, the simulator's revisit rule), ``--relations FILE`` (a
Freiburg benchmark relations file: the map and the raw odometry are scored against it,
the table beside the published results shown right after the map; one run only).

Exit codes: 0 written, 2 bad input (unreadable recording, wrong options), 3 ``--strict``
and a table unavailable.

``--json`` prints ``{"out": path of index.html, "bytes": page size, "figures": {figure id:
"shown" | "not shown: reason"}, "tables": [names of the tables on the page], "sections": [ids of the
page's sections, in order], "unavailable": {table name:
reason}, "precision_recall": {run label: {"source", "pairs", "positives",
"average_precision", "best_f1", "lvc_pair_precision", "lvc_pair_recall", "lvc_pair_f1"}}, "runs":
[{"path", "label", "duration_s", "counts": {key: n}}]}``.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from common.codec import DecodeError
from common.mcap_io import RecordingError
from eval.audit import audit_run
from eval.compare import compare_runs
from eval.report.benchmark import benchmark_figures, relations_table
from eval.report.data import RunView, run_view
from eval.report.naming import run_kind
from eval.report.page import render_report
from eval.run_eval import evaluate_run, relations_block
from eval.rundata import RunData, load_run

__all__ = ["main", "evaluation_tables", "load_views", "views_of", "write_report"]

log = logging.getLogger("poseidon.report")


def _guarded(tables: dict[str, dict[str, Any]], unavailable: dict[str, str], name: str,
             func: Callable[..., dict[str, Any]], where: str, *args: Any) -> dict[str, Any] | None:
    """Table ``name`` = ``func(*args)``; when the function fails, the reason in ``unavailable``."""
    try:
        result = func(*args)
    except Exception as exc:  # noqa: BLE001 - reported on the page and in the log, fatal with --strict
        log.exception("report: %s failed", name)
        unavailable[name] = f"{where} failed: {type(exc).__name__}: {exc}"
        return None
    if not isinstance(result, dict):
        unavailable[name] = f"{where} returned {type(result).__name__}, not a dict"
        log.warning("report: %s", unavailable[name])
        return None
    tables[name] = result
    return result


def present_comparison(c: dict[str, Any], label_a: str, label_b: str) -> dict[str, Any]:
    """:func:`eval.compare.compare_runs`'s result with the runs' labels as columns: ``table_5_4`` and
    ``additions`` (``{metric: {"label", "a", "b"}}``) become row tables, ``loop_closures``
    (``{"a": rows, "b": rows}``) one table per run.  Anything else is kept as it is."""
    out: dict[str, Any] = {}
    titles = {"table_5_4": "Table 5.4: VPR Guard ON vs OFF", "additions": "Our additions: trajectory error, "
              "loop-closure recall"}
    for key, value in c.items():
        if key in titles and isinstance(value, dict) and all(
                isinstance(v, dict) and {"a", "b"} <= v.keys() for v in value.values()):
            out[titles[key]] = [{"metric": v.get("label", k), label_a: v["a"], label_b: v["b"]}
                                for k, v in value.items()]
        elif key == "loop_closures" and isinstance(value, dict) and set(value) == {"a", "b"}:
            for side, label in (("a", label_a), ("b", label_b)):
                rows = value[side]
                out[f"Loop closures (Tables 5.2-5.3): {label}"] = rows if rows else "no loop closure"
        elif key == "far_m" and isinstance(value, (int, float)):
            out["loop closure true when d_gt <= (m)"] = value
        elif key == "runs" and isinstance(value, dict) and set(value) == {"a", "b"}:
            continue  # the page names the runs already
        else:
            out[key] = value
    return out


COMPARISON = "Comparison (Table 5.4, Tables 5.2-5.3)"


def evaluation_tables(runs: list[RunData], labels: list[str],
                      relations: Path | None = None) -> tuple[dict[str, dict[str, Any]], dict[str, str], list[str]]:
    """The tables of the eval package for the runs: (name -> dict, name -> why unavailable, names of the
    per-run detail tables, shown folded when there is a comparison)."""
    tables: dict[str, dict[str, Any]] = {}
    unavailable: dict[str, str] = {}
    for run, label in zip(runs[1:], labels[1:]):
        name = f"{COMPARISON}: {labels[0]} vs {label}"
        result = _guarded(tables, unavailable, name, compare_runs, "eval.compare.compare_runs", runs[0], run)
        if result is not None:
            tables[name] = present_comparison(result, labels[0], label)
    details: list[str] = []
    def evaluate(run: RunData) -> dict[str, Any]:
        result = evaluate_run(run) if relations is None else evaluate_run(run, relations=relations)
        return present_evaluation(result) if isinstance(result, dict) else result
    for run, label in zip(runs, labels):
        camera = "camera" in run_kind(run.counts)

        def audit(run: RunData, camera: bool = camera) -> dict[str, Any]:
            result = audit_run(run)
            return present_audit(result, camera) if isinstance(result, dict) else result
        audit_name = f"Audit (event-evidence association): {label}" if camera else \
            f"Audit (message sequences): {label}"
        for name, func, where in ((f"Evaluation (trajectory error, loop closures): {label}", evaluate,
                                   "eval.run_eval.evaluate_run"), (audit_name, audit, "eval.audit.audit_run")):
            _guarded(tables, unavailable, name, func, where, run)
            details.append(name)
    return tables, unavailable, (details if len(runs) > 1 else [])


RELATIONS_TABLE = "Relations (Freiburg benchmark): this run and published results"

#: keys of an evaluation (:func:`eval.run_eval.evaluate_run`) that only ground truth gives a value (None: the
#: whole key): left out of the page for a run without it, where their zeros would read as measured
TRUTH_ONLY: dict[str, tuple[str, ...] | None] = {
    "far_m": None, "ate": None, "ate_rmse_m": None, "rpe": None, "drift_pct": None, "truth_distance_m": None,
    "dead_reckoning": None,
    "loop_closures": ("true", "false", "unlabelled", "precision", "recall", "opportunities", "recalled", "passes",
                      "passes_closed", "pass_recall")}
#: keys of an audit (:func:`eval.audit.audit_run`) about camera evidence: left out for a run without a camera
AUDIT_EVIDENCE = ("slop_s", "images", "associated", "precision", "recall", "f1", "missing_images",
                  "missing_events", "duplicate_images", "late_images", "dt_mean_s", "dt_max_s")


def present_evaluation(result: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`eval.run_eval.evaluate_run`'s result as the page shows it: for a run without ground truth
    (``ground_truth`` false) the keys that need it (:data:`TRUTH_ONLY`) are left out, and so is the
    ``sessions`` block of a map of one session."""
    out = dict(result)
    sessions = out.get("sessions")
    if isinstance(sessions, dict) and (sessions.get("count") or 0) <= 1 and not sessions.get("loaded_nodes"):
        out.pop("sessions")
    if result.get("ground_truth") is not False:
        return out
    for key, sub in TRUTH_ONLY.items():
        if sub is None:
            out.pop(key, None)
        elif isinstance(out.get(key), dict):
            out[key] = {k: v for k, v in out[key].items() if k not in sub}
    return out


def present_audit(result: Mapping[str, Any], camera: bool) -> dict[str, Any]:
    """:func:`eval.audit.audit_run`'s result as the page shows it: for a run without a camera only the
    message-sequence part (the evidence keys, :data:`AUDIT_EVIDENCE`, are left out)."""
    return dict(result) if camera else {k: v for k, v in result.items() if k not in AUDIT_EVIDENCE}


def _benchmark(run: RunData, relations: Path | None, tables: dict[str, dict[str, Any]]) -> list[Any]:
    """The laser maps and loop closures of a run with scans (:mod:`eval.report.benchmark`); with
    ``relations``, the relations table is added to ``tables``."""
    if relations is not None:
        tables[RELATIONS_TABLE] = {"relation error, mean ± population std over the relations used":
                                   relations_table(relations_block(run, relations))}
    return benchmark_figures(run) if run.counts.get("scan") else []


def load_views(paths: list[Path], labels: list[str]) -> list[RunView]:
    """Each recording read once and viewed for the figures; labels made unique.

    :raises RecordingError: a missing, unreadable or empty recording (named).
    """
    runs = []
    for p in paths:
        if not p.is_file():
            raise RecordingError(f"{p}: no such recording")
        runs.append(load_run(p))
    return views_of(runs, labels)


def views_of(runs: list[RunData], labels: list[str]) -> list[RunView]:
    """The figures' views of runs already loaded (:func:`load_views` reads them; ``poseidon demo``
    passes the runs it has just judged); labels made unique.

    :raises RecordingError: an empty recording (named).
    """
    views = []
    for i, run in enumerate(runs):
        if not run.counts:
            raise RecordingError(f"{run.path}: no readable message (not an MCAP recording, or an empty one)")
        views.append(run_view(run, label=(labels[i] if labels else None), compare=len(runs) > 1))
    names = [v.label for v in views]
    if len(set(names)) != len(names):  # labels name the series and table columns: make them unique
        for i, v in enumerate(views):
            v.label = f"{i + 1}: {v.label}"
    return views


def write_report(runs: list[RunView], out: str | Path, relations: Path | None = None, max_points: int = 3000,
                 max_frames: int = 500, min_gap_m: float = 10.0) -> tuple[dict[str, Any], dict[str, str]]:
    """Evaluate ``runs`` and write the report into ``out``; returns (what was written, the
    tables that were unavailable and why).

    :raises RecordingError, DecodeError, ValueError: the relations file cannot be used (named).
    """
    tables, unavailable, details = evaluation_tables([r.run for r in runs], [r.label for r in runs])
    extra = _benchmark(runs[0].run, relations, tables) if len(runs) == 1 else []
    result = render_report(runs, tables, out, unavailable=unavailable, folded=details, max_points=max_points,
                           max_frames=max_frames, min_gap_m=min_gap_m, extra_figures=extra,
                           lead_tables=[RELATIONS_TABLE] if relations is not None else [])
    result["runs"] = [{"path": str(r.path), "label": r.label, "duration_s": round(r.duration_s, 3),
                       "counts": r.counts} for r in runs]
    return result, unavailable


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon report", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="run recordings (MCAP); for the ON/OFF comparison give ON first, then OFF")
    ap.add_argument("--out", required=True, help="output folder (index.html is written there)")
    ap.add_argument("--label", action="append", default=[], help="name of a run (once per run, in order)")
    ap.add_argument("--json", action="store_true", help="print what was written as JSON")
    ap.add_argument("--strict", action="store_true", help="fail (exit 3) when a table is unavailable")
    ap.add_argument("--relations", type=Path, default=None, metavar="FILE",
                    help="Freiburg benchmark relations file: relation errors, laser point maps, loop closures over "
                         "time, published results (one run)")
    ap.add_argument("--max-points", type=int, default=3000, help="points per trajectory drawn")
    ap.add_argument("--max-frames", type=int, default=500, help="frames of the similarity matrix")
    ap.add_argument("--min-gap-m", type=float, default=10.0,
                    help="pairs of frames closer than this in true travel are left out of precision-recall (m)")
    args = ap.parse_args(argv)
    if args.label and len(args.label) != len(args.runs):
        print(f"poseidon report: {len(args.label)} --label for {len(args.runs)} runs", file=sys.stderr)
        return 2
    if args.max_points < 2 or args.max_frames < 2:
        print("poseidon report: --max-points and --max-frames must be at least 2", file=sys.stderr)
        return 2
    if args.relations is not None and len(args.runs) != 1:
        print(f"poseidon report: --relations takes one run, got {len(args.runs)}", file=sys.stderr)
        return 2
    paths = [Path(p) for p in args.runs]
    try:
        runs = load_views(paths, args.label)
    except (RecordingError, DecodeError, KeyError) as exc:
        print(f"poseidon report: {exc}", file=sys.stderr)
        return 2
    try:
        result, unavailable = write_report(runs, args.out, args.relations, max_points=args.max_points,
                                           max_frames=args.max_frames, min_gap_m=args.min_gap_m)
    except (RecordingError, DecodeError, ValueError) as exc:
        if args.relations is None:   # only the relations file is user input here; anything else is a bug
            raise
        print(f"poseidon report: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"report written: {result['out']} ({result['bytes'] / 1e6:.1f} MB); open it in a browser")
        missing = {k: v for k, v in result["figures"].items() if v != "shown"}
        for fid, why in missing.items():
            print(f"  {fid}: {why}")
        for name, why in unavailable.items():
            print(f"  table unavailable: {name}: {why}")
    if args.strict and unavailable:
        print(f"poseidon report: {len(unavailable)} table(s) unavailable (--strict)", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
