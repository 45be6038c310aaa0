"""Live through ROS 1 at increasing rates: where frames start to drop.

The demo's mission (``poseidon demo``'s cave, seed ``--seed``; made or reused in
``--cache-dir``) is exported as a ROS 1 bag and played with ``rosbag play -r RATE`` into
``poseidon run --live ros1`` (every service, its own process, against a private ``roscore``)
at each of ``--rates``.  In the same run of this script, the baseline: the same mission
replayed from its recording (``poseidon run --input``, no live queues, nothing can drop).

Per rate: wall time; frames dropped by each service's bounded live queue (run summary
``dropped``, per key); messages a service received and rejected (run summary ``invalid``, per
key: late, i.e. older than what their stream had already promised by its wall-clock watermark
(``common/live.py``), or not valid); source messages missing from the recording (bag count
minus recorded, over the keys the bridge bridged: by default it subscribes only to the topics
the services read and the ground truth, ``bridge_ros1.bridge_unread``); LVC ids, experiences, loop closures and map ATE beside the replay's; the first
rate where any input was lost (dropped, rejected or missing).  Nothing else should run on the
machine meanwhile (drops follow the load).

    .venv/bin/python benchmarks/bench_live_ros1.py                    # 8, 12, 16, 20x: ~8 min
    .venv/bin/python benchmarks/bench_live_ros1.py --rates 16 --json

``--set KEY=VALUE`` (repeatable) applies to the live runs, not the replay.  ``--json``:
``{"mission", "settings": those values, "source_messages": {key: messages in the bag}, "replay": RUN,
"rates": {"<rate>": RUN}, "drops_start_at": the first rate with anything in ``dropped``, ``rejected``
or ``missing``, or null}`` with RUN = ``{"wall_s", "dropped": {service: {key: frames}}, "rejected":
{service: {key: messages}}, "missing": {key: source messages not recorded}, "unread": [source keys the
bridge did not bridge, no service reading them], "stalls": {key: times the bridge took the key's
silence for a stall and held its watermark, ``common/live.py``}, "lvc_ids", "experiences",
"loop_closures", "ate_m"}`` (``dropped``, ``rejected``, ``missing``, ``unread`` and ``stalls`` empty
for the replay).  Needs
ROS 1 (``deploy/setup.sh`` installs it).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from ros1_live import CLI, REPO, Roscore, demo_bag, live_run

from common.mcap_io import read_messages
from eval.run_eval import evaluate_run

SOURCE_KEYS = ("camera/image_raw", "depth_sensor", "dvl_linkquest", "imu_adis", "odometry", "sonar_micron",
               "sonar_seaking")


def _counts(path: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    for rec in read_messages(path):
        counts[rec.key] = counts.get(rec.key, 0) + 1
    return counts


def _figures(out: Path, wall_s: float, dropped: dict[str, Any], rejected: dict[str, Any],
             missing: dict[str, int], unread: list[str], stalls: dict[str, int]) -> dict[str, Any]:
    ev = evaluate_run(out)
    counts = _counts(out)
    return {"wall_s": round(wall_s, 1), "dropped": dropped, "rejected": rejected, "missing": missing,
            "unread": unread, "stalls": stalls,
            "lvc_ids": counts.get("local_view_cells", 0), "experiences": counts.get("experience_event", 0),
            "loop_closures": ev["loop_closures"]["accepted"], "ate_m": ev["ate_rmse_m"]["map"]}


def _lost(run: dict[str, Any]) -> bool:
    """Did the run lose any input: dropped by a queue, rejected by a service, or not recorded?"""
    return bool(run["dropped"] or run["rejected"] or run["missing"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1, help="the demo mission's seed")
    ap.add_argument("--rates", default="8,12,16,20", help="comma-separated rosbag play -r values")
    ap.add_argument("--cache-dir", default="/tmp/poseidon-live-ros1-bench")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="settings",
                    help="a configuration field of the live runs (repeatable), e.g. live.queue_frames=500 to "
                         "measure a default against its predecessor")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",") if r]
    if not rates or min(rates) <= 0:
        ap.error(f"--rates {args.rates}: give rates > 0")
    cache = Path(args.cache_dir)
    mission, bag = demo_bag(cache, args.seed)
    source = {k: n for k, n in _counts(mission).items() if k in SOURCE_KEYS}
    print(f"replay of {mission.name} (the baseline)", file=sys.stderr)
    replay_out = cache / "replay.mcap"
    proc = subprocess.run(CLI + ["run", "--input", str(mission), "--out", str(replay_out), "--json"], cwd=REPO,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"replay failed: {proc.stderr[-3000:]}")
    out: dict[str, Any] = {"mission": str(mission), "settings": args.settings, "source_messages": source,
                           "replay": _figures(replay_out, json.loads(proc.stdout)["wall_s"], {}, {}, {}, [], {}),
                           "rates": {}}
    core = Roscore(cache / "roshome")
    try:
        for rate in rates:
            print(f"{rate:g}x: rosbag play into run --live ros1", file=sys.stderr)
            run_out = cache / f"live_{rate:g}x.mcap"
            result = live_run(core, bag, run_out, rate, settings=args.settings)
            dropped = {n: st["dropped"] for n, st in result["services"].items() if st.get("dropped")}
            rejected = {n: st["invalid"] for n, st in result["services"].items() if st.get("invalid")}
            recorded = result["recording"]["counts"]
            unread = sorted(t.lstrip("/") for t in result["services"]["bridge_ros1"]["unread"])
            missing = {k: n - recorded.get(k, 0) for k, n in source.items()
                       if recorded.get(k, 0) != n and k not in unread}
            stalls = result["services"]["bridge_ros1"]["stalls"]
            out["rates"][f"{rate:g}"] = _figures(run_out, result["wall_s"], dropped, rejected, missing, unread, stalls)
    finally:
        core.stop()
    out["drops_start_at"] = next((float(r) for r, v in out["rates"].items() if _lost(v)), None)
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    print(f"demo mission ({sum(source.values())} source messages) through ROS 1, every service in its own process")
    print(f"{'run':>10} {'wall s':>7} {'LVC ids':>8} {'exps':>6} {'loops':>6} {'map ATE m':>10}  "
          "dropped / rejected / missing")
    rows = [("replay", out["replay"])] + [(f"{r}x live", v) for r, v in out["rates"].items()]
    for name, v in rows:
        ate = f"{v['ate_m']:.3f}" if v["ate_m"] is not None else "-"
        lost = (f"{json.dumps(v['dropped'])} / {json.dumps(v['rejected'])} / {json.dumps(v['missing'])}"
                if _lost(v) else "none")
        print(f"{name:>10} {v['wall_s']:>7} {v['lvc_ids']:>8} {v['experiences']:>6} {v['loop_closures']:>6} "
              f"{ate:>10}  {lost}")
    start = out["drops_start_at"]
    print(f"inputs lost from {start:g}x" if start is not None else f"no input lost up to {max(rates):g}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
