"""Live latency: a simulated mission played live (no ROS) through every service, per stage.

``--minutes`` (default 2) of ``poseidon sim`` (cached in
``--cache-dir``) is played by the live player (``poseidon run --live mcap``,
:mod:`services.player.live`) by the wall clock at each of ``--rates`` (default 1 and 4 x real
time), every service in its own process with its bounded live queue.  For each rate:

- **pipeline**: every service; the latency from a sensor message's arrival at the source
  to the LVC id, the experience event, the map, the Odometry and the dead reckoning it
  caused (p50/p95/p99/max, ms), as the run recorded it on ``live/latency`` and
  ``poseidon eval`` reads it back; frames dropped by the services' queues; messages late;
  how far behind its schedule the source published (a source that cannot keep its pace
  would make the figures meaningless);
- **baseline** (the same rate, the same run of this script): robot_state alone, the cheapest
  service -- its Odometry latency is what the transport and the event-time merge cost
  (a service waits at most the lateness bound ``live.lateness_ms`` of event time, i.e. that
  divided by the rate of wall time, plus up to ``live.watermark_interval_ms`` of wall time
  between watermarks; less when its other inputs' data frames advance its merge).  Each stage's p50 is printed as a ratio to the
  baseline's Odometry p50: what the services themselves add.

    .venv/bin/python benchmarks/bench_live.py                 # 2 min at 1x and 4x (~6 min)
    .venv/bin/python benchmarks/bench_live.py --rates 8 --json
    .venv/bin/python benchmarks/bench_live.py --rates 4 --set robot_state.publish_rate_hz=10   # another setting

Nothing else should run on the machine meanwhile (late messages and drops follow the load).
The run recordings are deleted once measured (``--keep-outputs`` keeps them).

``--json``: ``{"minutes", "mission", "overrides" (``--set``), "floor_ms": {"lateness_ms", "watermark_interval_ms"},
"rates": {"<rate>": {"pipeline": RUN, "baseline": RUN, "p50_ratio": {stage: pipeline p50 /
baseline odometry p50}}}}`` with RUN = ``{"wall_s", "latency": {stage: {n, unmatched, p50_ms,
p95_ms, p99_ms, max_ms}}, "dropped": {service: {key: frames}}, "late": {key: messages},
"behind_ms": {"p99", "max"}, "lvc_ids", "events", "loop_closures"}``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from eval.run_eval import evaluate_run
from launcher.cli import isolate_stdout
from launcher.live import run_live
from missions.sim.cli import simulate_cached
from system.config import PoseidonConfig, load_config
from system.services import LIVE_PLAYER

STAGES = ("lvc", "event", "map", "odometry", "dead_reckoning")


def _measure(cfg: PoseidonConfig, mission: Path, out: Path, rate: float, services: list[str] | None,
             keep: bool) -> dict[str, Any]:
    """One live run of ``mission`` at ``rate``: its latency as recorded, drops, late messages."""
    res = run_live(cfg, "mcap", out, services=services, input_path=mission, rate=rate)
    ev = evaluate_run(out)
    if not keep:
        out.unlink(missing_ok=True)
    src = res.services.get(LIVE_PLAYER, {})
    counts = res.recording["counts"]
    return {"wall_s": round(res.wall_s, 1),
            "latency": (ev["latency"] or {}).get("stages", {}),
            "dropped": {n: st["dropped"] for n, st in res.services.items() if st.get("dropped")},
            "late": src.get("late", {}), "behind_ms": src.get("behind_ms", {}),
            "lvc_ids": counts.get("local_view_cells", 0), "events": counts.get("experience_event", 0),
            "loop_closures": ev["loop_closures"]["accepted"]}


def _row(name: str, lat: dict[str, Any], base_p50: float | None) -> str:
    if not lat.get("n"):
        return f"    {name:<15} (no output)"
    ratio = f"  {lat['p50_ms'] / base_p50:5.2f}x baseline" if base_p50 else ""
    return (f"    {name:<15} p50 {lat['p50_ms']:7.1f}  p95 {lat['p95_ms']:7.1f}  p99 {lat['p99_ms']:7.1f}  "
            f"max {lat['max_ms']:7.1f} ms  (n {lat['n']}){ratio}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--rates", default="1,4", help="comma-separated x real time")
    ap.add_argument("--cache-dir", default="/tmp/poseidon-live-bench")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--keep-outputs", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override one configuration field of both runs (repeatable), e.g. to measure a "
                         "default against its predecessor")
    args = ap.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",") if r]
    if not rates or min(rates) <= 0:
        ap.error(f"--rates {args.rates}: give rates > 0")
    isolate_stdout()  # the in-process hub's native log lines go to stderr, not into --json
    cache = Path(args.cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    mission = simulate_cached(cache / f"live_{args.minutes:g}min_seed{args.seed}.mcap", args.minutes, args.seed,
                              progress=False)
    cfg = load_config(overrides=[f"encoder.lsbh.matrix_path={cache}/lsbh_{{backbone}}_{{modality}}.npy", *args.set])
    out: dict[str, Any] = {"minutes": args.minutes, "mission": str(mission), "overrides": list(args.set),
                           "floor_ms": {"lateness_ms": cfg.live.lateness_ms,
                                        "watermark_interval_ms": cfg.live.watermark_interval_ms},
                           "rates": {}}
    for rate in rates:
        print(f"{rate:g}x: baseline (robot_state alone)", file=sys.stderr)
        base = _measure(cfg, mission, cache / f"base_{rate:g}x.mcap", rate, ["robot_state"], args.keep_outputs)
        print(f"{rate:g}x: every service", file=sys.stderr)
        pipe = _measure(cfg, mission, cache / f"live_{rate:g}x.mcap", rate, None, args.keep_outputs)
        b50 = base["latency"].get("odometry", {}).get("p50_ms")
        out["rates"][f"{rate:g}"] = {
            "pipeline": pipe, "baseline": base,
            "p50_ratio": {s: round(v["p50_ms"] / b50, 3) for s, v in pipe["latency"].items() if v.get("n") and b50}}
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    f = out["floor_ms"]
    print(f"{args.minutes:g}-minute mission played live.  A service waits for the event-time merge at most the "
          f"lateness bound ({f['lateness_ms']} ms of event time: {f['lateness_ms']} ms / rate of wall time) plus up "
          f"to {f['watermark_interval_ms']} ms (wall) between watermarks; less when its other inputs' data advance it")
    for rate, r in out["rates"].items():
        p, b = r["pipeline"], r["baseline"]
        b50 = b["latency"].get("odometry", {}).get("p50_ms")
        print(f"{rate}x real time: every service ({p['wall_s']} s wall; {p['lvc_ids']} LVC ids, {p['events']} events, "
              f"{p['loop_closures']} loop closures; dropped {p['dropped'] or 0}; late {sum(p['late'].values())}; "
              f"source behind schedule p99 {p['behind_ms'].get('p99', 0):.1f} ms)")
        for s in STAGES:
            print(_row(s, p["latency"].get(s, {}), b50))
        print(f"  baseline, robot_state alone ({b['wall_s']} s wall; dropped {b['dropped'] or 0}; "
              f"late {sum(b['late'].values())}):")
        print(_row("odometry", b["latency"].get("odometry", {}), None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
