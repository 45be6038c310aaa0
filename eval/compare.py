"""``poseidon compare RUN_A.mcap RUN_B.mcap [--json] [--labels A,B] [--config FILE] [--set K=V]``.

Table 5.4 for two runs (``--config``/``--set`` replace both runs' recorded configuration).

Each run is read once (:func:`eval.rundata.load_run`) and judged by
:func:`eval.run_eval.evaluate_run` and :func:`eval.audit.audit_run`; this module only
arranges their figures side by side (every metric is defined there).

``--json`` keys:

- ``runs``: ``{"a": {"recording", "label"}, "b": {...}}`` (labels default ``A``/``B``);
- ``table_5_4``: ``{metric: {"label", "a", "b"}}`` for the metrics of Table 5.4, in its
  order: ``event_density_per_s``, ``nodes``, ``edges``, ``mean_degree``, ``audit_f1``,
  ``dt_mean_s``, ``dt_max_s``, ``vpr_ok_ratio``, ``span_norm_ratio_map_odom``,
  ``volume_ratio_map_odom``, ``end_disp_ratio_map_odom``, ``span_norm_ratio_map_gt``,
  ``volume_ratio_map_gt``, ``end_disp_ratio_map_gt``;
- ``additions``: the same shape for our additions: ``ate_rmse_map_m``,
  ``ate_rmse_dead_reckoning_m``, ``drift_pct_map``, ``drift_pct_dead_reckoning``,
  ``rpe_rmse_map_m``, ``rpe_rmse_dead_reckoning_m``, ``loop_closures_accepted``,
  ``loop_closures_true``, ``loop_closures_false``, ``loop_closure_recall``,
  ``loop_closure_pass_recall``, ``lvc_revisit_recall``;
- ``loop_closures``: ``{"a": rows, "b": rows}``, the rows of Tables 5.2-5.3
  (``loop_closures.table`` of :mod:`eval.run_eval`);
- ``far_m``: the d_gt threshold used.

Exit status: 0, or 2 when a recording cannot be read.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from eval.audit import audit_run
from eval.results import RunEvaluation
from eval.run_eval import evaluate_run
from eval.rundata import RunData, add_config_args, config_from_args, load_run, report_cli
from system.config import PoseidonConfig

__all__ = ["compare_runs", "compare_results", "format_compare", "main", "TABLE_5_4", "ADDITIONS"]

Getter = Callable[[RunEvaluation, dict[str, Any]], Any]


def _get(*path: str) -> Getter:
    def f(ev: RunEvaluation, _au: dict[str, Any]) -> Any:
        v: Any = ev
        for k in path:
            if v is None:
                return None
            v = v.get(k)
        return v
    return f


def _audit(key: str) -> Getter:
    return lambda _ev, au: au.get(key)


#: metric -> (label, getter(evaluation, audit)); Table 5.4's rows in its order
TABLE_5_4: dict[str, tuple[str, Getter]] = {
    "event_density_per_s": ("Event density (events/s)", _get("events_per_s")),
    "nodes": ("Nodes (final)", _get("nodes")),
    "edges": ("Edges (final)", _get("edges")),
    "mean_degree": ("Mean degree (final)", _get("mean_degree")),
    "audit_f1": ("Audit F1 (event <-> image)", _audit("f1")),
    "dt_mean_s": ("dt_real mean (s)", _audit("dt_mean_s")),
    "dt_max_s": ("dt_real max (s)", _audit("dt_max_s")),
    "vpr_ok_ratio": ("VPR window ok_ratio", _get("vpr_ok_ratio")),
    "span_norm_ratio_map_odom": ("Span norm ratio MAP/ODOM", _get("proxies", "ratios", "span_norm_map_odom")),
    "volume_ratio_map_odom": ("Volume ratio MAP/ODOM", _get("proxies", "ratios", "volume_map_odom")),
    "end_disp_ratio_map_odom": ("End-disp ratio MAP/ODOM", _get("proxies", "ratios", "end_displacement_map_odom")),
    "span_norm_ratio_map_gt": ("Span norm ratio MAP/GT", _get("proxies", "ratios", "span_norm_map_gt")),
    "volume_ratio_map_gt": ("Volume ratio MAP/GT", _get("proxies", "ratios", "volume_map_gt")),
    "end_disp_ratio_map_gt": ("End-disp ratio MAP/GT", _get("proxies", "ratios", "end_displacement_map_gt")),
}

#: our additions (not in the dissertation)
ADDITIONS: dict[str, tuple[str, Getter]] = {
    "ate_rmse_map_m": ("ATE RMSE map (m)", _get("ate_rmse_m", "map")),
    "ate_rmse_dead_reckoning_m": ("ATE RMSE dead reckoning (m)", _get("ate_rmse_m", "dead_reckoning")),
    "drift_pct_map": ("Drift map (% of distance)", _get("drift_pct", "map")),
    "drift_pct_dead_reckoning": ("Drift dead reckoning (% of distance)", _get("drift_pct", "dead_reckoning")),
    "rpe_rmse_map_m": ("RPE RMSE map (m / 10 s)", _get("rpe", "map", "rmse_m")),
    "rpe_rmse_dead_reckoning_m": ("RPE RMSE dead reckoning (m / 10 s)", _get("rpe", "dead_reckoning", "rmse_m")),
    "loop_closures_accepted": ("Loop closures accepted", _get("loop_closures", "accepted")),
    "loop_closures_true": ("Loop closures true (d_gt <= far_m)", _get("loop_closures", "true")),
    "loop_closures_false": ("Loop closures false", _get("loop_closures", "false")),
    "loop_closure_recall": ("Loop-closure recall (opportunities)", _get("loop_closures", "recall")),
    "loop_closure_pass_recall": ("Loop-closure recall (revisit passes)", _get("loop_closures", "pass_recall")),
    "lvc_revisit_recall": ("LVC revisit recall (frames)", _get("front_end", "revisit_recall")),
}


def compare_results(ev_a: RunEvaluation, au_a: dict[str, Any], ev_b: RunEvaluation, au_b: dict[str, Any],
                    labels: tuple[str, str] = ("A", "B")) -> dict[str, Any]:
    """Arrange two runs' :func:`evaluate_run` and :func:`audit_run` results (module docstring)."""
    def table(spec: dict[str, tuple[str, Getter]]) -> dict[str, Any]:
        return {k: {"label": lab, "a": g(ev_a, au_a), "b": g(ev_b, au_b)} for k, (lab, g) in spec.items()}

    return {"runs": {"a": {"recording": ev_a["recording"], "label": labels[0]},
                     "b": {"recording": ev_b["recording"], "label": labels[1]}},
            "table_5_4": table(TABLE_5_4), "additions": table(ADDITIONS),
            "loop_closures": {"a": ev_a["loop_closures"]["table"], "b": ev_b["loop_closures"]["table"]},
            "far_m": ev_a["far_m"]}


def compare_runs(a: str | Path | RunData, b: str | Path | RunData, labels: tuple[str, str] = ("A", "B"),
                 far_m: float = 5.0, config: PoseidonConfig | None = None) -> dict[str, Any]:
    """Table 5.4, Tables 5.2-5.3 and our additions for two run recordings (paths, or runs
    already loaded with :func:`eval.rundata.load_run`; module docstring)."""
    results = []
    for p in (a, b):
        run = p if isinstance(p, RunData) else load_run(p, config)
        results.append((evaluate_run(run, far_m=far_m), audit_run(run)))
    return compare_results(results[0][0], results[0][1], results[1][0], results[1][1], labels)


def _cell(v: Any) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool) or isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.6f}" if abs(v) < 1e5 else f"{v:.4g}"
    return str(v)


def format_compare(c: dict[str, Any]) -> list[str]:
    """Human-readable text tables of a :func:`compare_runs` result."""
    la, lb = c["runs"]["a"]["label"], c["runs"]["b"]["label"]
    lines = [f"{la}: {c['runs']['a']['recording']}", f"{lb}: {c['runs']['b']['recording']}", ""]
    for title, block in (("Table 5.4 (dissertation's metrics)", c["table_5_4"]),
                         ("Our additions", c["additions"])):
        lines.append(title)
        lines.append(f"  {'metric':<40} {la:>14} {lb:>14}")
        for row in block.values():
            lines.append(f"  {row['label']:<40} {_cell(row['a']):>14} {_cell(row['b']):>14}")
        lines.append("")
    for side, lab in (("a", la), ("b", lb)):
        rows = c["loop_closures"][side]
        lines.append(f"Accepted loop closures, {lab} (Tables 5.2-5.3; TP iff d_gt <= {c['far_m']:g} m): {len(rows)}")
        if rows:
            lines.append(f"  {'event_seq':>9} {'current':>8} {'matched':>8} {'d_gt (m)':>9}  "
                         f"{'current_gt (x,y,z)':<26} {'matched_gt (x,y,z)':<26} label")
        for r in rows:
            def xyz(p: Any) -> str:
                return "n/a" if p is None else "(" + ", ".join(f"{v:.3f}" for v in p) + ")"
            lines.append(f"  {_cell(r['event_seq']):>9} {r['current_exp']:>8} {r['matched_exp']:>8} "
                         f"{_cell(r['d_gt_m']) if r['d_gt_m'] is None else format(r['d_gt_m'], '.3f'):>9}  "
                         f"{xyz(r['current_gt']):<26} {xyz(r['matched_gt']):<26} {r['label'] or 'n/a'}")
        lines.append("")
    return lines[:-1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon compare",
                                 description="Table 5.4, loop-closure tables and our additions for two runs")
    ap.add_argument("run_a", type=Path)
    ap.add_argument("run_b", type=Path)
    ap.add_argument("--labels", default="A,B", help="column names, e.g. 'Guard ON,Guard OFF'")
    ap.add_argument("--far-m", type=float, default=5.0, help="d_gt threshold of a true loop closure (m)")
    ap.add_argument("--json", action="store_true", help="print the result as JSON (keys: see the module docstring)")
    add_config_args(ap)
    args = ap.parse_args(argv)
    labels = [s.strip() for s in args.labels.split(",")]
    if len(labels) != 2 or not all(labels):
        print(f"poseidon compare: --labels needs two comma-separated names, got {args.labels!r}", file=sys.stderr)
        return 2
    return report_cli("compare", lambda: compare_runs(args.run_a, args.run_b, (labels[0], labels[1]),
                                                      far_m=args.far_m, config=config_from_args(args)),
                      format_compare, args.json)


if __name__ == "__main__":
    sys.exit(main())
