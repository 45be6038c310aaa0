"""What a run produced, judged against ground truth when the input has it: the summary
``poseidon run`` / ``poseidon demo`` print (their ``--json`` ``"evaluation"`` block).

Every figure is computed by :func:`eval.run_eval.evaluate_run` and
:func:`eval.audit.audit_run` (where each is defined and documented); this module picks the
ones a run summary shows.  Keys (each block present only when the run has its inputs):

- ``front_end`` (``local_view_cells``, with ``truth/revisits`` / ``truth/pose``):
  ``frames``, ``lvc_ids``, ``new_id_fraction``, ``frame_matching``, ``revisit_frames``,
  ``revisit_recall``, ``claimed_revisits``, ``revisit_precision`` (the *per-frame* revisit
  recall / precision of :func:`eval.frontend.lvc_revisit_metrics`; the frame-pair measure is
  :func:`eval.frontend.lvc_pair_metrics`), ``min_gap_m``,
  ``matched_frames``, ``false_association_rate`` (``front_end`` of :mod:`eval.run_eval`);
- ``dead_reckoning`` (``Odometry`` and ``truth/pose``): ``ate_rmse_m``, ``final_error_m``,
  ``final_drift_pct``, ``max_error_m``, ``truth_distance_m`` (start-anchored, no rotation;
  ``dead_reckoning`` of :mod:`eval.run_eval`);
- ``back_end`` (``experience_event`` or ``map``): ``events``, ``events_per_s``, ``nodes``,
  ``edges``, ``mean_degree``, ``loop_closures`` (``accepted``, ``true``, ``false``,
  ``recall``, ``pass_recall``), ``ate_rmse_m`` (``map``, ``dead_reckoning``: rigid,
  at the map node stamps), ``drift_pct`` (``map``, ``dead_reckoning``), ``audit``
  (``f1``, ``missing_events``, ``missing_images``, ``dt_max_s``).
"""
from __future__ import annotations

from pathlib import Path

from eval.audit import audit_run
from eval.results import RunSummary
from eval.run_eval import evaluate_run
from eval.rundata import load_run
from system.config import PoseidonConfig

__all__ = ["summarize_run", "format_summary"]


def summarize_run(path: str | Path, config: PoseidonConfig | None = None, far_m: float = 5.0) -> RunSummary:
    """Judge the run recorded in ``path``: the blocks of :class:`eval.results.RunSummary` (keys
    in the module docstring, units there).

    :param config: replaces the configuration recorded in the run
    :param far_m: d_gt threshold of a true loop closure (m)
    """
    run = load_run(path, config)
    ev = evaluate_run(run, far_m=far_m)
    out: RunSummary = {}
    if ev["front_end"] is not None:
        out["front_end"] = ev["front_end"]
    if ev["dead_reckoning"] is not None:
        out["dead_reckoning"] = ev["dead_reckoning"]
    if run.events or run.final_map is not None:
        au = audit_run(run)
        lc = ev["loop_closures"]
        out["back_end"] = {
            "events": ev["events"], "events_per_s": ev["events_per_s"], "nodes": ev["nodes"], "edges": ev["edges"],
            "mean_degree": ev["mean_degree"],
            "loop_closures": {"accepted": lc["accepted"], "true": lc["true"], "false": lc["false"],
                              "recall": lc["recall"], "pass_recall": lc["pass_recall"]},
            "ate_rmse_m": ev["ate_rmse_m"], "drift_pct": ev["drift_pct"],
            "audit": {"f1": au["f1"], "missing_events": au["missing_events"], "missing_images": au["missing_images"],
                      "dt_max_s": au["dt_max_s"]},
        }
    return out


def _pct(v: float | None, nd: int = 1) -> str:
    return "n/a" if v is None else f"{100 * v:.{nd}f}%"


def _m(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f} m"


def format_summary(s: RunSummary) -> list[str]:
    """Human-readable lines of a :func:`summarize_run` result."""
    lines = []
    fe = s.get("front_end")
    if fe:
        line = (f"front-end: {fe['frames']} frames -> {fe['lvc_ids']} LVC ids "
                f"({100 * fe['new_id_fraction']:.0f}% of frames created an id)")
        recall, precision, false_rate = (fe.get("revisit_recall"), fe.get("revisit_precision"),
                                         fe.get("false_association_rate"))
        if recall is not None:
            line += (f"; per-frame revisit recall {100 * recall:.1f}% of {fe['revisit_frames']} frames"
                     f" (the frame's id points to an earlier visit of its place)")
        if precision is not None:
            line += f", per-frame revisit precision {100 * precision:.1f}% of {fe['claimed_revisits']} claims"
        if false_rate is not None:
            line += (f"; {100 * false_rate:.1f}% of {fe['matched_frames']} matches "
                     f"joined places > 5 m apart")
        lines.append(line)
    dr = s.get("dead_reckoning")
    if dr:
        lines.append(f"dead reckoning: {dr['truth_distance_m']:.1f} m travelled, final error {dr['final_error_m']:.2f} m "
                     f"({dr['final_drift_pct']:.2f}% of distance), ATE RMSE {dr['ate_rmse_m']:.2f} m")
    be = s.get("back_end")
    if be:
        lc = be["loop_closures"]
        rate = "n/a" if be["events_per_s"] is None else f"{be['events_per_s']:.3f}"
        lines.append(f"back-end: {be['events']} events ({rate}/s), map {be['nodes']} nodes / {be['edges']} edges; "
                     f"loop closures {lc['accepted']} accepted ({lc['true']} true, {lc['false']} false), "
                     f"recall {_pct(lc['recall'])} of revisit opportunities")
        a = be["ate_rmse_m"]
        if a["map"] is not None or a["dead_reckoning"] is not None:
            lines.append(f"map vs dead reckoning: ATE RMSE {_m(a['map'])} vs {_m(a['dead_reckoning'])} "
                         f"(rigid alignment, at the map's node stamps)")
        au = be["audit"]
        f1 = "n/a" if au["f1"] is None else f"{au['f1']:.3f}"
        lines.append(f"audit: event-evidence F1 {f1}, {au['missing_images']} events without image, "
                     f"{au['missing_events']} images without event")
    return lines
