"""Our pose-graph optimisers and GTSAM's Levenberg-Marquardt side by side on the same graphs.

Per graph, the experience map is rebuilt twice from the same upstream outputs, once per
optimiser: the ``expmap`` service alone (in this process, ``run_embedded``) on a full run's
recording, so both see the very same experience events, scans and odometry (the demo's Guard OFF
run does the same with posecells + expmap), with the run's own recorded configuration and only
the optimiser changed (``expmap.scan_graph.optimizer`` for the laser map,
``expmap.corrections.optimizer`` for the 3D experience map; services/expmap/gtsam_graph.py).
Every solve during the run is timed (thread CPU of the solve: the player and the recorder run as
other threads of this process) and its iterations counted.  Then each output is judged:

- laser logs (``--laser aces=RUN.mcap,fr079=RUN.mcap``, runs of ``deploy/presets/laser2d.yaml``;
  a name alone: imported from ``../shared/data/radish`` and run into ``--cache-dir``): the
  Freiburg relation error of the map-corrected trajectory (``poseidon eval --relations``),
  translation m and heading deg, mean;
- sim missions (``--seeds 301,302,303``, ``--minutes 20``: ``poseidon sim`` and a full run with
  the defaults, cached in ``--cache-dir``): the map's ATE (RMSE after rigid alignment) against the
  ground truth (``poseidon eval``); the 3D map relaxes positions only, so no heading figure.

Offline replay (labelled so in the output): the final graph of the ours-run, saved through
``expmap.map_path``, re-solved by both optimisers from the same initial poses (the laser map: its
chain edges composed from node 0; the 3D map: the odometry chain): CPU s (``time.process_time``),
iterations, and the largest difference between the two optima.

    .venv/bin/python benchmarks/bench_optimizers.py --cache-dir DIR --laser aces=RUN.mcap,fr079=RUN.mcap \\
        --seeds 301,302,303 --minutes 20 --json
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.mcap_io import read_metadata
from eval.run_eval import evaluate_run
from launcher.cli import isolate_stdout
from launcher.run import run_distributed, run_embedded
from services.expmap import graph as graph_mod
from services.expmap import gtsam_graph
from services.expmap import scan_graph as scan_graph_mod
from services.expmap.graph import ExperienceMap
from services.expmap.pose_graph import compose, relative_pose, relax_se2, wrap_angle
from services.expmap.relaxation import solve_optimum
from services.expmap.scan_graph import ScanGraph
from system.config import PoseidonConfig, load_config

DATA = ROOT.parent / "shared" / "data" / "radish"
PRESET = ROOT / "deploy" / "presets" / "laser2d.yaml"
#: (field, ours, GTSAM) per map kind
FIELDS = {"scan_graph": ("expmap.scan_graph.optimizer", "gauss_newton", "gtsam_lm"),
          "experience_map": ("expmap.corrections.optimizer", "series_reduction", "gtsam_lm")}


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---- sources: a full run per graph ---------------------------------------------------------
def laser_source(name: str, path: str, cache: Path) -> Path:
    """The laser preset's full run of log ``name``: ``path`` when given, else imported and run."""
    if path:
        return Path(path)
    from missions.importers.cli import main as import_main
    imported, run = cache / f"{name}.mcap", cache / f"{name}_run.mcap"
    if not imported.exists() and import_main([str(DATA / f"{name}.clf.bz2"), "--out", str(imported)]) != 0:
        raise RuntimeError(f"import of {name} failed")
    if not run.exists():
        _say(f"{name}: full pipeline, laser preset -> {run}")
        run_distributed(load_config(PRESET), imported, run, progress=False)
    return run


def sim_source(seed: int, minutes: float, cache: Path) -> Path:
    """``poseidon sim --minutes M --seed S`` and its full run with the defaults (cached)."""
    from missions.sim.cli import main as sim_main
    mission, run = cache / f"sim_{minutes:g}min_seed{seed}.mcap", cache / f"sim_{minutes:g}min_seed{seed}_run.mcap"
    if not mission.exists():
        _say(f"seed {seed}: simulating {minutes:g} minutes -> {mission}")
        if sim_main(["--minutes", str(minutes), "--seed", str(seed), "--out", str(mission)]) != 0:
            raise RuntimeError(f"simulation of seed {seed} failed")
    if not run.exists():
        _say(f"seed {seed}: full pipeline, defaults -> {run}")
        run_distributed(load_config(None), mission, run, progress=False)
    return run


def recorded_config(run: Path) -> PoseidonConfig:
    """The configuration the run recorded (its sensor offsets already taken from its input)."""
    return PoseidonConfig.model_validate(json.loads(read_metadata(run)["poseidon"]["config"]))


# ---- the solves during a run: timed wrappers at the two call sites ----------------------------
class SolveLog:
    """Thread CPU (s) and iterations of every relaxation during a run, per call site."""

    def __init__(self) -> None:
        self.cpu_s: list[float] = []
        self.iterations: list[int] = []
        self.nodes: list[int] = []

    def planar(self, optimizer: str, poses: np.ndarray, *args: Any, **kw: Any) -> tuple[np.ndarray, int]:
        t = time.thread_time()
        out, it = gtsam_graph.relax_planar(optimizer, poses, *args, **kw)
        self.cpu_s.append(time.thread_time() - t)
        self.iterations.append(int(it))
        self.nodes.append(int(len(poses)))
        return out, it

    def relaxation(self, optimizer: str, cum: np.ndarray, cumres: np.ndarray, loops: Any, deltas: Any,
                   fixed: np.ndarray) -> tuple[np.ndarray, bool]:
        stats: dict[str, int] = {}
        t = time.thread_time()
        if optimizer == "gtsam_lm":
            out = gtsam_graph.solve_optimum_gtsam(cum, cumres, loops, deltas, fixed, stats=stats)
        else:
            out = solve_optimum(cum, cumres, loops, deltas, fixed)
        self.cpu_s.append(time.thread_time() - t)
        self.iterations.append(stats.get("steps", 1))       # ours: one direct solve
        self.nodes.append(int(len(cum)))
        return out

    def summary(self) -> dict[str, Any]:
        c = self.cpu_s
        return {"solves": len(c), "cpu_s_total": round(sum(c), 4),
                "cpu_s_per_solve": {"mean": round(statistics.fmean(c), 5) if c else None,
                                    "max": round(max(c), 5) if c else None},
                "iterations": {"mean": round(statistics.fmean(self.iterations), 2) if c else None,
                               "max": max(self.iterations) if c else None},
                "nodes_at_last_solve": self.nodes[-1] if c else 0}


def rerun_expmap(source: Path, optimizer: str, cache: Path, label: str) -> tuple[Path, Path, dict[str, Any]]:
    """The expmap service alone on ``source`` with ``optimizer``: (output run, saved map, solves)."""
    cfg = recorded_config(source)
    kind = cfg.expmap.graph
    field = FIELDS[kind][0]
    out, map_path = cache / f"{label}_{optimizer}_expmap.mcap", cache / f"{label}_{optimizer}_map.npz"
    map_path.unlink(missing_ok=True)     # the service would load it at start
    # only the keys a service reads (and the truth) are replayed: the outputs stay small
    cfg = cfg.updated({field: optimizer, "expmap.map_path": str(map_path), "player.replay": "consumed"})
    log = SolveLog()
    saved = scan_graph_mod.relax_planar, graph_mod.relaxation_optimum
    scan_graph_mod.relax_planar, graph_mod.relaxation_optimum = log.planar, log.relaxation  # type: ignore[assignment]
    try:
        t = time.monotonic()
        run_embedded(cfg, source, out, services=["expmap"], progress=False)
        wall = time.monotonic() - t
    finally:
        scan_graph_mod.relax_planar, graph_mod.relaxation_optimum = saved
    return out, map_path, {**log.summary(), "wall_s": round(wall, 1)}


def map_error(run: Path, relations: Path | None) -> dict[str, Any]:
    """Relation error (laser) or map ATE (sim) of a run, as ``poseidon eval`` reports them."""
    ev = evaluate_run(run, relations=relations)
    lc = ev["loop_closures"]
    out: dict[str, Any] = {"nodes": ev["nodes"],
                           "loop_closures": {"accepted": lc["accepted"], "true": lc["true"], "false": lc["false"]}}
    if relations is not None:
        r = ev.get("relations") or {}
        out.update({"trans_m": r.get("trans_abs_m", {}).get("mean"), "heading_deg": r.get("rot_abs_deg", {}).get("mean")})
    else:
        out.update({"ate_map_m": ev["ate_rmse_m"]["map"], "ate_dead_reckoning_m": ev["ate_rmse_m"]["dead_reckoning"]})
    return out


def warm_up() -> None:
    """Import gtsam and load the numba kernels once, so that no timed solve pays for them."""
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.1]])
    e0, e1, z, w = np.array([0]), np.array([1]), np.array([[1.0, 0.0, 0.0]]), np.ones((1, 3))
    for opt in gtsam_graph.PLANAR_OPTIMIZERS:
        gtsam_graph.relax_planar(opt, poses, e0, e1, z, w)
    for opt in gtsam_graph.RELAXATION_OPTIMIZERS:
        gtsam_graph.relaxation_optimum(opt, np.zeros((3, 3)), np.arange(3.0), [(0, 2, 1.0, 0)], [np.ones(3)], np.zeros(3))


# ---- offline replay of the final graph -----------------------------------------------------------
def _timed(fn: Callable[[], tuple[np.ndarray, Any]]) -> tuple[np.ndarray, Any, float]:
    t = time.process_time()
    x, it = fn()
    return x, it, time.process_time() - t


def replay_scan_graph(map_path: Path, cfg: PoseidonConfig) -> dict[str, Any]:
    """The final laser graph re-solved by both from its chain composed from node 0."""
    g = ScanGraph.load(map_path, cfg.expmap.scan_graph)
    ei, ej, z, w = np.asarray(g.ei), np.asarray(g.ej), np.asarray(g.z), np.asarray(g.w)
    loop = np.asarray(g.is_loop)
    init = np.zeros((g.n_nodes, 3))
    init[0] = np.column_stack([g.positions[:, :2], g.yaws])[0]
    for k in np.flatnonzero(~loop):
        init[ej[k]] = compose(init[ei[k]], z[k])
    c = cfg.expmap.scan_graph
    out: dict[str, Any] = {"nodes": g.n_nodes, "edges": int(ei.size), "loop_edges": int(loop.sum())}
    sols = {}
    for name, fn in (("gauss_newton", relax_se2), ("gtsam_lm", gtsam_graph.relax_se2_gtsam)):
        for iters in (c.relax_iterations, 100):
            x, it, cpu = _timed(lambda fn=fn, iters=iters: fn(init, ei, ej, z, w, huber=c.huber, iterations=iters))
            sols[(name, iters)] = x
            r = relative_pose(x[ei], x[ej]) - z
            r[:, 2] = wrap_angle(r[:, 2])
            out[f"{name}_{iters}it"] = {"cpu_s": round(cpu, 4), "iterations": int(it),
                                        "cost": round(float(np.sum(w * r * r)), 3)}
    a, b = sols[("gauss_newton", 100)], sols[("gtsam_lm", 100)]
    out["optima_differ_m"] = float(np.max(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])))
    out["optima_differ_deg"] = float(np.degrees(np.max(np.abs(wrap_angle(a[:, 2] - b[:, 2])))))
    return out


def replay_experience_map(map_path: Path, cfg: PoseidonConfig) -> dict[str, Any]:
    """The final 3D map's Eq. 4.20 re-solved by both (GTSAM from the odometry chain)."""
    em = ExperienceMap.load(map_path, cfg.expmap, cfg.posecells.number_of_neurons, cfg.posecells.distance_between_neurons)
    cols = em.state().columns
    cum, cumres, fixed = cols["cum"], cols["cumres"], em.positions[0]
    stats: dict[str, int] = {}
    a, _s, cpu_a = _timed(lambda: solve_optimum(cum, cumres, em.loops, em.loop_deltas, fixed))
    b, _s, cpu_b = _timed(lambda: gtsam_graph.solve_optimum_gtsam(cum, cumres, em.loops, em.loop_deltas, fixed,
                                                                  stats=stats))
    return {"nodes": em.n_nodes, "loop_edges": len(em.loops),
            "series_reduction": {"cpu_s": round(cpu_a, 4), "iterations": 1},
            "gtsam_lm": {"cpu_s": round(cpu_b, 4), "iterations": stats.get("steps")},
            "optima_differ_m": float(np.max(np.linalg.norm(a - b, axis=1))) if len(a) else 0.0}


def one_graph(label: str, source: Path, cache: Path, relations: Path | None) -> dict[str, Any]:
    kind = recorded_config(source).expmap.graph
    _field, ours, theirs = FIELDS[kind]
    out: dict[str, Any] = {"source": str(source), "graph": kind, "source_run": map_error(source, relations)}
    for opt in (ours, theirs):
        _say(f"{label}: expmap alone with {opt}")
        run, map_path, solves = rerun_expmap(source, opt, cache, label)
        out[opt] = {"map": map_error(run, relations), "solves_in_pipeline": solves}
        if opt == ours:
            cfg = recorded_config(source)
            replay = replay_scan_graph if kind == "scan_graph" else replay_experience_map
            out["offline_replay_of_final_graph"] = replay(map_path, cfg)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache-dir", required=True, help="missions, runs and outputs go here")
    ap.add_argument("--laser", default="aces,fr079",
                    help="comma-separated NAME or NAME=RUN.mcap (a laser-preset run of ../shared/data/radish/NAME)")
    ap.add_argument("--seeds", default="301,302,303", help="comma-separated sim seeds ('' for none)")
    ap.add_argument("--minutes", type=float, default=20.0, help="sim mission length")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    isolate_stdout()
    cache = Path(args.cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    warm_up()
    res: dict[str, Any] = {}
    for item in filter(None, args.laser.split(",")):
        name, _eq, path = item.partition("=")
        res[name] = one_graph(name, laser_source(name, path, cache), cache, DATA / f"{name}.relations")
    for seed in filter(None, args.seeds.split(",")):
        label = f"sim{args.minutes:g}_seed{seed}"
        res[label] = one_graph(label, sim_source(int(seed), args.minutes, cache), cache, None)
    if args.json:
        print(json.dumps(res, indent=1))
    else:
        for label, r in res.items():
            print(label, json.dumps({k: v for k, v in r.items() if k != "source"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
