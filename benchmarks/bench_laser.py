"""The Freiburg SLAM benchmark through the distributed services: speed and relation error.

For each CARMEN log named (default ``aces``; ``fr079`` too with ``--logs aces,fr079``) from
``../shared/data/radish``: ``poseidon import`` (cached in ``--cache-dir``), then the full
pipeline with ``deploy/presets/laser2d.yaml`` (every service its own process, player rate 0),
and in the same run the baseline: the player and the recorder alone on the same input (the
transport's ceiling).  Reported per log: wall time and real-time factor of both, and the
benchmark's relation error (``eval/relations.py``) of the map beside the raw odometry's and
the published rows (Kuemmerle et al. 2009; Hess et al. 2016, Table II).

    .venv/bin/python benchmarks/bench_laser.py                    # ACES (1366 s): ~2.5 min
    .venv/bin/python benchmarks/bench_laser.py --logs aces,fr079 --json

``--json``: ``{log: {"pipeline": {"wall_s", "log_s", "real_time_factor"}, "transport_only":
{same}, "relations": {count, trans_abs_m: {mean, std}, rot_abs_deg: {mean, std}, ...},
"relations_odometry": {same}, "loop_closures", "experiences"}}``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from eval.run_eval import evaluate_run
from launcher.cli import isolate_stdout
from launcher.run import run_distributed
from missions.importers.cli import main as import_main
from system.config import load_config

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "radish"
PRESET = ROOT / "deploy" / "presets" / "laser2d.yaml"
#: published translational error (m, mean +- std) on the benchmark's relations
PUBLISHED = {
    "aces": {"scan matching": (0.173, 0.614), "GMapping": (0.060, 0.049), "graph mapping": (0.044, 0.044),
             "Cartographer": (0.0375, 0.0426)},
    "fr079": {"scan matching": (0.258, 0.427), "GMapping": (0.061, 0.044), "graph mapping": (0.056, 0.042),
              "Cartographer": (0.0452, 0.0354)},
}


def one_log(name: str, cache: Path) -> dict[str, Any]:
    log, rel = DATA / f"{name}.clf.bz2", DATA / f"{name}.relations"
    if not log.exists() or not rel.exists():
        raise FileNotFoundError(f"{log} or {rel} missing (the benchmark needs ../shared/data/radish)")
    imported = cache / f"{name}.mcap"
    if not imported.exists():
        if import_main([str(log), "--out", str(imported)]) != 0:
            raise RuntimeError(f"import of {log} failed")
    cfg = load_config(PRESET, overrides=[f"encoder.lsbh.matrix_path={cache}/lsbh_{{backbone}}_{{modality}}.npy"])
    print(f"{name}: transport only (player -> recorder)", file=sys.stderr)
    base = run_distributed(cfg, imported, cache / f"{name}_transport.mcap", services=[], progress=False)
    print(f"{name}: full pipeline, laser preset", file=sys.stderr)
    res = run_distributed(cfg, imported, cache / f"{name}_run.mcap", progress=True)
    ev = evaluate_run(cache / f"{name}_run.mcap", relations=rel)
    log_s = float(res.recording["duration_s"])
    counts = res.recording["counts"]
    return {
        "pipeline": {"wall_s": round(res.wall_s, 1), "log_s": round(log_s, 1),
                     "real_time_factor": round(log_s / res.wall_s, 2)},
        "transport_only": {"wall_s": round(base.wall_s, 1), "log_s": round(log_s, 1),
                           "real_time_factor": round(log_s / base.wall_s, 2)},
        "relations": ev["relations"], "relations_odometry": ev["relations_odometry"],
        "loop_closures": res.services.get("expmap", {}).get("counters", {}).get("loop_closures", 0),
        "experiences": counts.get("experience_event", 0),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", default="aces", help="comma-separated: aces, fr079")
    ap.add_argument("--cache-dir", default="/tmp/poseidon-laser")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    isolate_stdout()
    cache = Path(args.cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    out = {name: one_log(name, cache) for name in args.logs.split(",") if name}
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for name, r in out.items():
        p, t, m, o = r["pipeline"], r["transport_only"], r["relations"], r["relations_odometry"]
        print(f"{name}: {p['log_s']} s log; pipeline {p['wall_s']} s = {p['real_time_factor']}x real time; "
              f"player + recorder alone {t['wall_s']} s = {t['real_time_factor']}x; "
              f"{r['experiences']} experiences, {r['loop_closures']} loop closures")
        print(f"  relation error (m, deg; {m['count']} relations): map {m['trans_abs_m']['mean']:.3f} +- "
              f"{m['trans_abs_m']['std']:.3f} m, {m['rot_abs_deg']['mean']:.2f} +- {m['rot_abs_deg']['std']:.2f} deg; "
              f"raw odometry {o['trans_abs_m']['mean']:.3f} +- {o['trans_abs_m']['std']:.3f} m, "
              f"{o['rot_abs_deg']['mean']:.2f} +- {o['rot_abs_deg']['std']:.2f} deg")
        for method, (mean, std) in PUBLISHED.get(name, {}).items():
            print(f"  published {method}: {mean:.3f} +- {std:.3f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
