"""Dead-reckoning drift on synthetic cave missions (``poseidon sim``), filter vs plain integration.

For each seed a mission of ``--minutes`` is generated with the simulator's own noise models
(:mod:`missions.sim.mission`: IMU yaw drift and random walk, gyro bias and noise, DVL noise,
bias, scale, beam dropouts and flagged bursts, DVL compass offset and noise, depth bias and
noise) and cached in ``--cache-dir``.  ``robot_state`` runs offline over it
(:func:`eval.deadreckon.run_deadreckon`) next to the plain-integration
baseline of the same run, and both are scored against ``truth/pose``: final position error
in % of the distance travelled (drift) and ATE RMSE.  Speed: input messages per second of
the node (``run_offline``) and of the plain integrator over the same messages (the
baseline measured in the same run), wall clock.

Reported per seed and over all seeds: the filter / plain ratios of ATE and of drift (< 1:
the filter is better), their mean and worst, and how many seeds the filter loses.  The
default seeds 101-105 are used by no test (seeds the filter was never
tuned on); a 10-minute mission takes ~30-60 s to generate and ~0.9 GB in the cache.

    .venv/bin/python benchmarks/bench_deadreckon.py                      # seeds 101-105, 10 min
    .venv/bin/python benchmarks/bench_deadreckon.py --minutes 10 --seeds 1 2 3 --json

``--json``: ``{"minutes", "runs": [{"seed", "distance_m", "filter_drift_pct",
"plain_drift_pct", "filter_ate_m", "plain_ate_m", "ate_ratio", "drift_ratio",
"filter_max_error_m", "plain_max_error_m", "node_msgs_per_s", "plain_msgs_per_s",
"counters"}], "mean": {same numeric keys}, "worst_ate_ratio", "worst_drift_ratio",
"seeds_filter_worse_ate"}``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from common.mcap_io import read_messages
from common.node import run_offline
from eval.deadreckon import PlainIntegrator, run_deadreckon
from system.config import load_config
from system.services import build_node


def _mission(cache: Path, minutes: float, seed: int) -> Path:
    from missions.sim.mission import SimParams, generate

    path = cache / f"sim_{minutes:g}min_seed{seed}.mcap"
    if not path.exists():
        print(f"generating {path} ({minutes:g} min, seed {seed}) ...", file=sys.stderr)
        tmp = path.with_suffix(".part")
        generate(tmp, SimParams(minutes=minutes, seed=seed), progress=sys.stderr.isatty())
        tmp.rename(path)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105])
    ap.add_argument("--cache-dir", type=Path, default=Path("/tmp/poseidon_bench"))
    ap.add_argument("--config", type=Path, default=None)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    args.cache_dir.mkdir(parents=True, exist_ok=True)
    config = load_config(args.config, args.overrides)
    keys = list(build_node("robot_state", config).inputs) + ["truth/pose"]
    rows = []
    for seed in args.seeds:
        path = _mission(args.cache_dir, args.minutes, seed)
        msgs = [(r.key, r.message()) for r in read_messages(path, keys=keys)]
        node = build_node("robot_state", config)
        n_in = sum(1 for k, _ in msgs if k in node.inputs)
        t0 = time.perf_counter()
        run_offline(node, msgs)
        t_node = time.perf_counter() - t0
        plain = PlainIntegrator(config.robot_state)
        nav = [(k, m) for k, m in msgs if k in ("dvl_linkquest", "depth_sensor")]
        t0 = time.perf_counter()
        for k, m in nav:
            plain.process(k, m)
        t_plain = time.perf_counter() - t0
        s = run_deadreckon(msgs, config, recording=str(path))
        tf, tp = s["truth"]["filter"], s["truth"]["plain"]
        rows.append({
            "seed": seed, "distance_m": tf["truth_distance_m"],
            "filter_drift_pct": tf["final_drift_pct"], "plain_drift_pct": tp["final_drift_pct"],
            "filter_ate_m": tf["ate_rmse_m"], "plain_ate_m": tp["ate_rmse_m"],
            "ate_ratio": tf["ate_rmse_m"] / tp["ate_rmse_m"],
            "drift_ratio": tf["final_drift_pct"] / tp["final_drift_pct"],
            "filter_max_error_m": tf["max_error_m"], "plain_max_error_m": tp["max_error_m"],
            "node_msgs_per_s": n_in / t_node, "plain_msgs_per_s": len(nav) / t_plain,
            "counters": s["counters"],
        })
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k not in ("seed", "counters")}
    worst_ate = max(r["ate_ratio"] for r in rows)
    worst_drift = max(r["drift_ratio"] for r in rows)
    worse = sum(1 for r in rows if r["ate_ratio"] > 1.0)
    if args.json:
        print(json.dumps({"minutes": args.minutes, "runs": rows, "mean": mean, "worst_ate_ratio": worst_ate,
                          "worst_drift_ratio": worst_drift, "seeds_filter_worse_ate": worse}, indent=2))
        return 0
    print(f"dead reckoning on {args.minutes:g}-minute simulated missions (drift = final error / distance; "
          "ratio = filter / plain integration, < 1: the filter is better)")
    print(f"{'seed':>4} {'dist m':>7} {'filter ATE m':>13} {'plain ATE m':>12} {'ATE ratio':>10} {'filter %':>9} "
          f"{'plain %':>8} {'drift ratio':>12} {'node msg/s':>11} {'plain msg/s':>12}")
    for r in rows + [dict(mean, seed="mean")]:
        print(f"{r['seed']!s:>4} {r['distance_m']:7.1f} {r['filter_ate_m']:13.2f} {r['plain_ate_m']:12.2f} "
              f"{r['ate_ratio']:10.2f} {r['filter_drift_pct']:9.2f} {r['plain_drift_pct']:8.2f} "
              f"{r['drift_ratio']:12.2f} {r['node_msgs_per_s']:11.0f} {r['plain_msgs_per_s']:12.0f}")
    print(f"worst ATE ratio {worst_ate:.2f}, worst drift ratio {worst_drift:.2f}; the filter loses on ATE in "
          f"{worse} of {len(rows)} seeds; node speed = {mean['node_msgs_per_s'] / mean['plain_msgs_per_s']:.3f} "
          "x plain integration")
    return 0


if __name__ == "__main__":
    sys.exit(main())
