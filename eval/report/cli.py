"""``poseidon report RUN.mcap [RUN2.mcap ...] --out DIR [--relations FILE] [--json]``: the run(s) as one HTML page.

Writes ``DIR/index.html``: self-contained (plotly.js inlined, images as data URIs; opens
offline), with the figures of Section 5.4 (3D overlay, XY/XZ/YZ projections, final
topology, similarity and ground-truth matrices, view cells over time, precision-recall,
deviation over time and on XY, evidence images), the tables (run summary; per run the
evaluation of :func:`eval.run_eval.evaluate_run` and the audit of
:func:`eval.audit.audit_run`; for two or more runs :func:`eval.compare.compare_runs` of
the first with each other, Table 5.4 and Tables 5.2-5.3), and each run's configuration
and code revision.  A table whose function cannot be imported or fails is listed on the
page as unavailable with the reason (and logged); ``--strict`` makes that an error.

Options: ``--label L`` (once per run, default ``<file stem> (VPR Guard ON|OFF)``),
``--max-points`` (per trajectory, default 3000), ``--max-frames`` (similarity matrix,
default 500), ``--min-gap-m`` (pairs closer in true travel are left out of
precision-recall, default 10 m, the simulator's revisit rule), ``--relations FILE`` (a
Freiburg benchmark relations file: the evaluation tables score the map and the raw
odometry against it, and a section "Benchmark" adds the laser point maps at corrected and
raw poses, the loop closures over time and the relations table beside the published
results: :mod:`eval.report.benchmark`; one run only).

Exit codes: 0 written, 2 bad input (unreadable recording, wrong options), 3 ``--strict``
and a table unavailable.

``--json`` prints ``{"out": path of index.html, "bytes": page size, "figures": {figure id:
"shown" | "not shown: reason"}, "tables": [table names], "unavailable": {table name:
reason}, "precision_recall": {run label: {"source", "pairs", "positives",
"average_precision", "best_f1", "lvc_pair_precision", "lvc_pair_recall", "lvc_pair_f1"}}, "runs":
[{"path", "label", "duration_s", "counts": {key: n}}]}``.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any, Callable

from common.mcap_io import RecordingError

__all__ = ["main", "evaluation_tables"]

log = logging.getLogger("poseidon.report")


def _import(module: str, name: str, optional: bool = False) -> tuple[Callable[..., Any] | None, str]:
    """The function, or None and why it cannot be imported."""
    import importlib
    try:
        return getattr(importlib.import_module(module), name), ""
    except (ImportError, AttributeError) as exc:
        reason = f"{module}.{name} is not available in this build ({type(exc).__name__}: {exc})"
        log.log(logging.INFO if optional else logging.WARNING, "report: %s", reason)
        return None, reason


def _guarded(tables: dict[str, dict], unavailable: dict[str, str], name: str,
             func: Callable[..., dict] | None, where: str, *args: Any) -> dict | None:
    """Table ``name`` = ``func(*args)``; when the function is missing or fails, the reason."""
    if func is None:
        unavailable[name] = where
        return None
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


def evaluation_tables(paths: list[Path], labels: list[str],
                      relations: Path | None = None) -> tuple[dict[str, dict], dict[str, str], list[str]]:
    """The tables of the eval package for the runs: (name -> dict, name -> why unavailable, names of the
    per-run detail tables, shown folded when there is a comparison)."""
    tables: dict[str, dict] = {}
    unavailable: dict[str, str] = {}
    found = {name: _import(module, name) for module, name in
             (("eval.run_eval", "evaluate_run"), ("eval.audit", "audit_run"), ("eval.compare", "compare_runs"))}
    evaluate_run, why_eval = found["evaluate_run"][0], found["evaluate_run"][1] or "eval.run_eval.evaluate_run"
    audit_run, why_audit = found["audit_run"][0], found["audit_run"][1] or "eval.audit.audit_run"
    compare_runs, why_compare = found["compare_runs"][0], found["compare_runs"][1] or "eval.compare.compare_runs"
    # the eval functions take a path or a run loaded once by eval.rundata.load_run (read each file once)
    loader, _ = _import("eval.rundata", "load_run", optional=True)
    inputs: list[Any] = list(paths)
    if loader is not None and any(f is not None for f in (evaluate_run, audit_run, compare_runs)):
        for i, p in enumerate(paths):
            try:
                inputs[i] = loader(p)
            except Exception:  # noqa: BLE001 - each table then reports its own failure on the path
                log.exception("report: eval.rundata.load_run(%s) failed; the eval functions get the path", p)
    for inp, label in zip(inputs[1:], labels[1:]):
        name = f"{COMPARISON}: {labels[0]} vs {label}"
        result = _guarded(tables, unavailable, name, compare_runs, why_compare, inputs[0], inp)
        if result is not None:
            tables[name] = present_comparison(result, labels[0], label)
    details: list[str] = []
    if relations is not None and evaluate_run is not None:
        evaluate = evaluate_run
        evaluate_run = lambda run: evaluate(run, relations=relations)  # noqa: E731
    for inp, label in zip(inputs, labels):
        for name, func, why in ((f"Evaluation (trajectory error, loop closures): {label}", evaluate_run, why_eval),
                                (f"Audit (event-evidence association): {label}", audit_run, why_audit)):
            _guarded(tables, unavailable, name, func, why, inp)
            details.append(name)
    return tables, unavailable, (details if len(paths) > 1 else [])


RELATIONS_TABLE = "Relations (Freiburg benchmark): this run and published results"


def _benchmark_section(path: Path, relations: Path, tables: dict[str, dict]) -> tuple[str, str, list[Any]]:
    """Adds the relations table to ``tables``; returns the benchmark section (:mod:`eval.report.benchmark`)."""
    from eval.report.benchmark import benchmark_figures, relations_table
    from eval.rundata import load_run as load_eval_run
    from eval.run_eval import relations_block

    run = load_eval_run(path)
    tables[RELATIONS_TABLE] = {"relation error, mean ± population std over the relations used":
                               relations_table(relations_block(run, relations))}
    return "sec-benchmark", "Benchmark (laser maps, loop closures, relations)", benchmark_figures(run)


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
    from common.codec import DecodeError
    from eval.report.data import load_run
    from eval.report.page import render_report
    paths = [Path(p) for p in args.runs]
    try:
        runs = [load_run(p, label=(args.label[i] if args.label else None)) for i, p in enumerate(paths)]
    except (RecordingError, DecodeError, KeyError) as exc:
        print(f"poseidon report: {exc}", file=sys.stderr)
        return 2
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):  # labels name the series and table columns: make them unique
        for i, r in enumerate(runs):
            r.label = f"{i + 1}: {r.label}"
    tables, unavailable, details = evaluation_tables(paths, [r.label for r in runs], args.relations)
    extra = []
    if args.relations is not None:
        try:
            extra = [_benchmark_section(paths[0], args.relations, tables)]
        except (RecordingError, DecodeError, ValueError) as exc:
            print(f"poseidon report: {exc}", file=sys.stderr)
            return 2
    result = render_report(runs, tables, args.out, unavailable=unavailable, folded=details,
                           max_points=args.max_points,
                           max_frames=args.max_frames, min_gap_m=args.min_gap_m, extra_sections=extra)
    result["runs"] = [{"path": str(r.path), "label": r.label, "duration_s": round(r.duration_s, 3),
                       "counts": r.counts} for r in runs]
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
