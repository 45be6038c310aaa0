"""``poseidon eval``: the command line of :mod:`eval.run_eval` (argument parsing and the text output).

The ``--json`` keys are those of :func:`eval.run_eval.evaluate_run` (documented in :mod:`eval.run_eval`).
Exit status: 0, or 2 when the recording or its configuration cannot be read.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from eval.results import RunEvaluation
from eval.run_eval import evaluate_run
from eval.rundata import add_config_args, config_from_args, report_cli

__all__ = ["format_eval", "main"]


def _f(v: Any, fmt: str = ".3f") -> str:
    return "n/a" if v is None else format(v, fmt)


def format_eval(r: RunEvaluation) -> list[str]:
    """Human-readable lines of an :func:`evaluate_run` result."""
    lc = r["loop_closures"]
    lines = [f"recording          {r['recording']} ({r['duration_s']:.1f} s, config from {r['config_source']})",
             f"events             {r['events']} ({_f(r['events_per_s'])} events/s)",
             f"map                {r['nodes']} nodes, {r['edges']} edges, mean degree {_f(r['mean_degree'])}",
             f"loop closures      {lc['accepted']} accepted: {lc['true']} true, {lc['false']} false "
             f"(d_gt <= {r['far_m']:g} m), {lc['unlabelled']} without ground truth",
             f"loop-closure recall {_f(lc['recall'])} of {lc['opportunities']} revisit opportunities "
             f"(age >= {lc['min_experience_age']} events); {lc['passes_closed']}/{lc['passes']} revisit passes closed"]
    for row in lc["table"]:
        lines.append(f"  event {row['event_seq']}: exp {row['current_exp']} -> {row['matched_exp']}  "
                     f"d_gt {_f(row['d_gt_m'])} m  {row['label'] or '?'}")
    a = r["ate_rmse_m"]
    lines.append(f"ATE RMSE (rigid)   map {_f(a['map'])} m vs dead reckoning {_f(a['dead_reckoning'])} m "
                 f"(at {r['ate']['stamps'] or 'no'} stamps)")
    d = r["drift_pct"]
    lines.append(f"drift              map {_f(d['map'], '.2f')} % vs dead reckoning {_f(d['dead_reckoning'], '.2f')} % "
                 f"of {_f(r['truth_distance_m'], '.1f')} m")
    p = r["proxies"]
    if p:
        q = p["ratios"]
        lines.append(f"proxies MAP/ODOM   span {_f(q['span_norm_map_odom'])}, volume {_f(q['volume_map_odom'])}, "
                     f"end displacement {_f(q['end_displacement_map_odom'])}")
        lines.append(f"proxies MAP/GT     span {_f(q['span_norm_map_gt'])}, volume {_f(q['volume_map_gt'])}, "
                     f"end displacement {_f(q['end_displacement_map_gt'])}")
    lines.append(f"VPR window ok_ratio {_f(r['vpr_ok_ratio'])}")
    se = r.get("sessions")
    if se and se["count"] > 1:
        lines.append(f"sessions           {se['count']} ({se['loaded_nodes']} nodes loaded, {se['unlinked_nodes']} of "
                     f"this run unlinked); {se['links']} links, {se['false_links']} false; time to link "
                     f"{_f(se['time_to_link_s'], '.1f')} s; link error {_f(se['link_error_m'])} m; ATE in the "
                     f"prior map's frame {_f(se['ate_prior_frame_m'])} m over {se['ate_prior_frame_n']} nodes, "
                     f"dead reckoning placed by the link {_f(se['dr_ate_by_link_m'])} m, by the truth at the link "
                     f"{_f(se['dr_ate_at_link_m'])} m")
    lat = r.get("latency")
    if lat:
        lines.append(f"live latency       measured by {lat['source']}" + (f" at {lat['rate']:g}x real time" if lat["rate"]
                                                                          else "") + " (arrival -> output)")
        for stage, v in lat["stages"].items():
            if v["n"]:
                lines.append(f"  {stage:<16} p50 {v['p50_ms']:.1f} ms, p95 {v['p95_ms']:.1f} ms, p99 {v['p99_ms']:.1f} ms, "
                             f"max {v['max_ms']:.1f} ms (n {v['n']}, {v['unmatched']} unmatched)")
    if "relations_file" in r:
        lines.append(f"relations          {r['relations_in_file']} in {r['relations_file']} "
                     "(error: mean +- std over the relations used)")
        for name in ("relations", "relations_odometry"):
            b = r[name]
            label = "map" if name == "relations" else "odometry"
            if b is None:
                why = "no map message" if name == "relations" else "no odometry"
                lines.append(f"  {label:<16} n/a ({why})")
                continue
            t, rot = b["trans_abs_m"], b["rot_abs_deg"]
            lines.append(f"  {label:<16} {_f(t['mean'])} +- {_f(t['std'])} m, {_f(rot['mean'], '.2f')} +- "
                         f"{_f(rot['std'], '.2f')} deg over {b['count']} relations ({b['outside']} outside the "
                         f"trajectory; {b['source']})")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon eval", description="judge a run recording against its ground truth")
    ap.add_argument("recording", type=Path, help="run recording (MCAP) with truth/pose, map, experience_event, ...")
    ap.add_argument("--json", action="store_true", help="print the result as JSON (keys: see the module docstring)")
    ap.add_argument("--far-m", type=float, default=5.0, help="d_gt threshold of a true loop closure (m)")
    ap.add_argument("--min-gap-m", type=float, default=10.0,
                    help="distance travelled before an LVC id re-use counts as a claimed revisit (m)")
    ap.add_argument("--relations", type=Path, default=None, metavar="FILE",
                    help="Freiburg benchmark relations (t_i t_j dx dy dz roll pitch dyaw): score the map-corrected "
                         "trajectory and the raw odometry (eval/relations.py)")
    ap.add_argument("--prior", type=Path, default=None, metavar="PRIOR_RUN.mcap",
                    help="the run that saved the map this run continued (--map-dir): truth of the loaded nodes, "
                         "for the sessions block (eval/sessions.py)")
    add_config_args(ap)
    args = ap.parse_args(argv)
    return report_cli("eval", lambda: evaluate_run(args.recording, far_m=args.far_m, min_gap_m=args.min_gap_m,
                                                   config=config_from_args(args), relations=args.relations,
                                                   prior=args.prior),
                      format_eval, args.json)


if __name__ == "__main__":
    sys.exit(main())
