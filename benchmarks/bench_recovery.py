"""Recovery of a live run through ROS 1: the demo mission with services killed mid-loop.

The demo's mission (``poseidon demo``'s cave, seed ``--seed``; made or reused in
``--cache-dir``) is exported as a ROS 1 bag (``poseidon export --ros1``) and played with
``rosbag play`` at ``--rate`` (default 1x) into ``poseidon run --live ros1`` against a private
``roscore``, twice in the same run of this script:

- **baseline**: no fault;
- **killed**: each of ``--kill`` (default encoder and expmap) SIGKILLed once, in the middle of
  the loop the baseline closed at mid-mission (the encoder ``--lead`` seconds before that loop
  closure's stamp, expmap as long after).

Printed: loop closures and map ATE of both (``poseidon eval``), whether the killed run's loop
closures are the baseline's; per kill, wall seconds from the death to the restart, to the
first input the restarted service finished and to the end of its catch-up (``recoveries``),
p50 and max; peak RSS of the source (the bridge) and the recorder in both runs.

    .venv/bin/python benchmarks/bench_recovery.py            # ~2 x 14 min at 1x
    .venv/bin/python benchmarks/bench_recovery.py --rate 4 --json

``--json``: ``{"mission", "rate", "kills": [{"service", "at_s"}], "baseline": RUN, "killed": RUN,
"same_loop_closures", "recovery": {"restarted_s" | "resumed_s" | "caught_up_s": {"p50", "max"}}}``
(``lateness_ms`` 2000 by default for both runs: a message late on a loaded machine would make them
differ whatever the kills).
with RUN = ``{"wall_s", "loop_closures", "ate_m", "restarts", "recoveries", "peak_rss_mb":
{"bridge_ros1", "recorder"}, "lost"}``.  Needs ROS 1 (``deploy/setup.sh`` installs it).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from ros1_live import Roscore, demo_bag, live_run

from common.mcap_io import read_messages
from eval.run_eval import evaluate_run


def _loop_closures(run: Path) -> list[tuple[int, int, int]]:
    """The loop-closure links of the run's final map: (stamp of the later node, source, target)."""
    from common.codec import decode
    from common.messages import ExperienceMap
    last = None
    for rec in read_messages(run, keys=["map"]):
        last = rec.payload
    if last is None:
        return []
    m = decode(last, ExperienceMap)
    stamp = {n.id: n.stamp for n in m.nodes}
    return sorted((max(stamp[lk.source], stamp[lk.target]), lk.source, lk.target) for lk in m.links if lk.loop_closure)


def _run(core: Roscore, bag: Path, out: Path, rate: float, kills: list[tuple[str, float]],
         lateness_ms: int) -> dict[str, Any]:
    """One live run of ``bag``; ``kills``: (service, wall seconds after the first message)."""
    result = live_run(core, bag, out, rate, kills, [f"bridge_ros1.lateness_ms={lateness_ms}"])
    ate = evaluate_run(out)["ate_rmse_m"]["map"]
    services = result["services"]
    return {"wall_s": result["wall_s"], "loop_closures": len(_loop_closures(out)), "ate_m": ate,
            "restarts": result["restarts"], "recoveries": result["recoveries"],
            "peak_rss_mb": {n: services.get(n, {}).get("peak_rss_mb") for n in ("bridge_ros1", "recorder")},
            "lost": {n: s.get("lost") for n, s in services.items() if s.get("lost")}}


def _stats(values: list[float]) -> dict[str, float | None]:
    v = [x for x in values if x is not None]
    return {"p50": round(float(np.median(v)), 2) if v else None, "max": round(max(v), 2) if v else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1, help="the demo mission's seed")
    ap.add_argument("--rate", type=float, default=1.0, help="rosbag play -r")
    ap.add_argument("--kill", default="encoder,expmap")
    ap.add_argument("--lead", type=float, default=4.0, help="seconds between a kill and the mid-mission loop closure")
    ap.add_argument("--lateness-ms", type=int, default=2000,
                    help="bridge_ros1.lateness_ms of both runs: a message late on a loaded machine would make the "
                         "runs differ whatever the kills")
    ap.add_argument("--cache-dir", default="/tmp/poseidon-recovery-bench")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    cache = Path(args.cache_dir)
    mission, bag = demo_bag(cache, args.seed)
    first = next(iter(read_messages(mission))).stamp
    core = Roscore(cache / "roshome")
    try:
        print(f"baseline: {bag} at {args.rate:g}x", file=sys.stderr)
        base = _run(core, bag, cache / "baseline.mcap", args.rate, [], args.lateness_ms)
        loops = _loop_closures(cache / "baseline.mcap")
        if not loops:
            raise RuntimeError("the baseline closed no loop: nothing to kill in the middle of")
        mid = (loops[len(loops) // 2][0] - first) / 1e9 / args.rate
        names = [n for n in args.kill.split(",") if n]
        kills = [(n, mid + (i * 2 - 1) * args.lead / args.rate) for i, n in enumerate(names)]
        print(f"killed: {kills}", file=sys.stderr)
        killed = _run(core, bag, cache / "killed.mcap", args.rate, kills, args.lateness_ms)
        same = _loop_closures(cache / "killed.mcap") == loops
    finally:
        core.stop()
    rec = killed["recoveries"]
    out = {"mission": str(mission), "rate": args.rate, "kills": [{"service": n, "at_s": round(t, 1)} for n, t in kills],
           "baseline": base, "killed": killed, "same_loop_closures": same,
           "recovery": {k: _stats([r[k] for r in rec]) for k in ("restarted_s", "resumed_s", "caught_up_s")}}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"demo mission through ROS 1 at {args.rate:g}x; kills {out['kills']}")
    print(f"{'run':10} {'loop closures':>14} {'map ATE (m)':>12} {'restarts':>20} {'bridge RSS MB':>14} {'recorder RSS MB':>16}")
    for name, r in (("baseline", base), ("killed", killed)):
        ate = f"{r['ate_m']:.3f}" if r["ate_m"] is not None else "-"
        print(f"{name:10} {r['loop_closures']:>14} {ate:>12} {json.dumps(r['restarts']):>20} "
              f"{r['peak_rss_mb']['bridge_ros1']!s:>14} {r['peak_rss_mb']['recorder']!s:>16}")
    print(f"same loop closures (the final map's loop links) as the baseline: {same}")
    for k, v in out["recovery"].items():
        print(f"  {k:12} p50 {v['p50']} s, max {v['max']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
