"""A run judged against ground truth: the figures of ``poseidon eval`` (its command line:
:mod:`eval.cli.run_eval`).

``poseidon eval RUN.mcap [--json] [--far-m 5] [--min-gap-m 10] [--relations FILE] [--prior PRIOR_RUN.mcap] [--config FILE] [--set K=V]``.  :func:`evaluate_run` reads a run recording once
(:func:`eval.rundata.load_run`; the configuration recorded in the run's metadata, defaults
when it has none; ``--config`` / ``--set`` replace it) and returns the dict
below.  Values that cannot be computed (no map, no ground truth, zero denominators) are
``null``.  Positions are NED metres (``truth/pose`` is NED; ``Odometry`` and map node
positions are converted from the published frame, :mod:`eval.trajectory`).  "Ground
truth of an experience" = ``truth/pose`` interpolated at the node's stamp.

``--json`` keys:

- ``recording``, ``config_source`` (``recording`` | ``given`` | ``defaults``),
  ``duration_s`` (first to last message of any key), ``ground_truth`` (bool: the run
  carries ``truth/pose``), ``far_m`` (the 5 m threshold of Tables 5.2-5.3);
- ``events`` (``experience_event`` messages), ``events_per_s`` (events / ``duration_s``,
  Table 5.4's event density), ``map_messages``;
- ``nodes``, ``edges`` (of the last ``map`` message), ``mean_degree`` (2 edges / nodes);
- ``loop_closures``: every link of the final map with ``loop_closure`` true.  Its newer
  end (larger node id) is the *current* experience, the other the *matched* one;
  d_gt = |g_current - g_matched| (m), label ``TP`` iff d_gt <= ``far_m``, else ``FP``
  (``null`` when a node's stamp is outside the ground truth).  Keys: ``accepted``,
  ``true``, ``false``, ``unlabelled``, ``precision`` (true / labelled), ``table`` (rows
  ``{"event_seq", "current_exp", "matched_exp", "d_gt_m", "current_gt", "matched_gt",
  "label"}``, Tables 5.2-5.3; ``event_seq`` = header seq of the ``experience_event`` with
  the current node's stamp, null if none), and recall:
  a **revisit opportunity** is an experience k (nodes in id order, truth known) for which
  some experience j with id(k) - id(j) >= ``expmap.min_experience_age`` has
  |g_k - g_j| <= ``far_m``.  ``opportunities`` counts them, ``recalled`` those that are
  the current experience of a TP closure, ``recall`` = recalled / opportunities;
  ``passes`` = maximal runs of opportunities with consecutive node ids (one revisit of a
  place), ``passes_closed`` = passes containing the current experience of a TP closure,
  ``pass_recall`` = passes_closed / passes; ``min_experience_age`` echoes the rule used;
- ``ate_rmse_m``: ``{"map", "dead_reckoning"}`` time-aligned ATE RMSE after rigid
  alignment (:func:`eval.trajectory.ate`) at the final map's node stamps (map = node
  positions; dead reckoning = ``Odometry`` interpolated at the same stamps); without a
  map, dead reckoning at the ``truth/pose`` stamps; ``ate`` holds the full figures
  ``{"stamps": "map_nodes" | "truth_pose", "map": {rmse_m, mean_m, max_m, final_m, n},
  "dead_reckoning": {...}}``;
- ``rpe``: ``{"delta_s", "map": {rmse_m, mean_m, n, delta_s}, "dead_reckoning": {...}}``
  (:func:`eval.trajectory.rpe` at the same stamps, delta 10 s);
- ``drift_pct``: ``{"map", "dead_reckoning"}`` final error / true distance travelled
  between the first and last stamp (%), the estimate translated to start at the true
  start, no rotation (:func:`eval.trajectory.anchored_errors`); ``truth_distance_m``;
- ``proxies`` (Table 5.4's stability proxies; MAP = final node positions in id order,
  ODOM = ``Odometry`` and GT = ``truth/pose`` interpolated at the node stamps, only
  stamps all three cover): ``samples``; ``span_norm_m`` = norm of the axis-aligned
  bounding-box diagonal (max - min per NED axis); ``volume_m3`` = product of the
  bounding-box extents; ``end_displacement_m`` = |last - first position|; each
  ``{"map", "odom", "gt"}``; ``ratios`` = ``{"span_norm_map_odom", "volume_map_odom",
  "end_displacement_map_odom", "span_norm_map_gt", "volume_map_gt",
  "end_displacement_map_gt"}`` (MAP value / reference value, null for a zero reference);
- ``vpr_ok_ratio``: :func:`eval.frontend.vpr_window_ok_ratio` on ``local_view_cells``
  with the run's ``vpr_guard.vpr_window`` / ``vpr_min_rep``;
- ``front_end``: ``frames``, ``lvc_ids``, ``new_id_fraction``, ``frame_matching``
  (``stamp`` | ``order``: how LVC messages were matched to camera-frame indices) and with
  ``truth/revisits``: ``revisit_frames``, ``revisit_recall``, ``claimed_revisits``,
  ``revisit_precision`` (claims need ``--min-gap-m`` travelled, default 10 m, the sim's
  ``revisit_min_gap_m``) (:func:`eval.frontend.lvc_revisit_metrics`), and with
  ``truth/pose``: ``matched_frames``, ``false_association_rate``
  (:func:`eval.frontend.lvc_false_associations`);
- ``dead_reckoning``: the whole ``Odometry`` stream against ``truth/pose``
  (:func:`eval.trajectory.anchored_errors`): ``ate_rmse_m``, ``final_error_m``,
  ``final_drift_pct``, ``max_error_m``, ``truth_distance_m``;
- with ``--relations FILE`` (the Freiburg benchmark's reference relations; error definition
  in :mod:`eval.relations`): ``relations_file``, ``relations_in_file``; ``relations`` = the
  error of the map-corrected trajectory (:func:`eval.corrected.map_corrected`, the trajectory
  ``poseidon export --tum`` writes), null without a ``map`` message or ``Odometry``;
  ``relations_odometry`` = the error of the raw odometry, null without any; each
  ``{source, count, outside, trans_abs_m: {mean, std}, rot_abs_deg: {mean, std},
  trans_sq_m2: {mean, std}}``, ``source`` = ``map_corrected`` | ``wheel_odometry`` (when
  the recording has it, e.g. a CARMEN import) | ``Odometry`` (the dead reckoning).  Works
  on an imported log alone (no run): ``relations`` null, ``relations_odometry`` filled.

- ``latency``: a live run's latency (``poseidon run --live``), as its source measured and
  recorded it on ``live/latency`` (:class:`common.messages.LatencyReport`); null for a replay:
  ``source`` (``bridge_ros1`` | ``live_player``), ``rate`` (the live player's x real time, 0
  for a sensor source), ``stages``: per stage (``lvc``, ``event``, ``map``, ``odometry``,
  ``dead_reckoning``) ``n``, ``unmatched``, ``p50_ms``, ``p95_ms``, ``p99_ms``, ``max_ms`` --
  the wall time from a sensor message's arrival at the source to the output it caused
  (matched by stamp) arriving back there;
- ``sessions``: the map's sessions (a map continued over missions with ``poseidon run
  --map-dir``, or a kidnapped vehicle): ``count``, ``loaded_nodes``, ``unlinked_nodes``,
  ``links``, ``false_links``, ``time_to_link_s``, ``link_error_m``, ``ate_prior_frame_m``,
  ``ate_prior_frame_n``, the dead reckoning's ATE in the same frame placed by the truth at the
  link (``dr_ate_at_link_m``) and by the link (``dr_ate_by_link_m``), ``cross_loop_closures`` and a ``table`` per link; every key defined in :mod:`eval.sessions`.
  With ``--prior PRIOR_RUN.mcap`` (the run that saved the map) the loaded nodes get their
  truth.  Nodes loaded from an earlier mission's map carry that mission's stamps: every other
  block here (``nodes`` excepted) uses this run's nodes only, and loop closures with a loaded
  end are judged in ``sessions``, not in ``loop_closures``.

"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from eval.corrected import map_corrected
from eval.frontend import frame_indices, lvc_false_associations, lvc_revisit_metrics, vpr_window_ok_ratio
from eval.relations import read_relations, relation_summary
from eval.results import (
    AteBlock,
    AteFigures,
    DeadReckoningErrors,
    FrontEnd,
    LatencyBlock,
    LatencyStageFigures,
    LoopClosureRow,
    LoopClosures,
    MapAndDeadReckoning,
    ProxyRatios,
    RelationErrors,
    RelationsBlock,
    RpeBlock,
    RpeFigures,
    RunEvaluation,
    StabilityProxies,
)
from eval.rundata import RunData, load_run
from eval.sessions import sessions_block
from eval.trajectory import PoseSeries, Trajectory, anchored_errors, ate, drift_pct, rpe
from system.config import PoseidonConfig

__all__ = ["evaluate_run", "map_trajectory", "loop_closure_table", "front_end_metrics",
           "stability_proxies", "relations_block", "RPE_DELTA_S"]

RPE_DELTA_S = 10.0


def _r(v: float | int | None, nd: int = 6) -> float | int | None:
    """Rounded for JSON; ints stay ints, NaN/inf become None."""
    if v is None or isinstance(v, (bool, int, np.integer)):
        return None if v is None else int(v)
    return round(float(v), nd) if math.isfinite(v) else None


def map_trajectory(run: RunData) -> tuple[Trajectory | None, list[int]]:
    """Final map nodes as a NED trajectory (id order) and their ids (same order)."""
    m = run.final_map
    if m is None or not m.nodes:
        return None, []
    nodes = sorted((n for n in m.nodes if n.id >= run.loaded_nodes), key=lambda n: n.id)
    if not nodes:
        return None, []
    pos = run.to_ned(np.array([n.position for n in nodes], dtype=float))
    traj = Trajectory([n.stamp for n in nodes], pos, [0.0] * len(nodes))
    return traj, [n.id for n in nodes]


def _truth_at(run: RunData, stamps: list[int]) -> np.ndarray:
    """Truth positions at ``stamps`` (NaN rows outside the truth's span)."""
    out = np.full((len(stamps), 3), np.nan)
    if not run.has_truth or not stamps:
        return out
    s = np.asarray(stamps, dtype=np.int64)
    ok = run.truth.covered(s)  # type: ignore[union-attr]
    if ok.any():
        out[ok] = run.truth.positions_at(s[ok])  # type: ignore[union-attr]
    return out


def loop_closure_table(run: RunData, far_m: float = 5.0) -> LoopClosures:
    """The ``loop_closures`` block (module docstring)."""
    age = run.config.expmap.min_experience_age
    out: LoopClosures = {"accepted": 0, "true": 0, "false": 0, "unlabelled": 0, "precision": None,
                           "recall": None, "opportunities": 0, "recalled": 0, "passes": 0, "passes_closed": 0,
                           "pass_recall": None, "min_experience_age": age, "table": []}
    m = run.final_map
    if m is None:
        return out
    nodes = {n.id: n for n in m.nodes if n.id >= run.loaded_nodes}   # loaded nodes: eval.sessions
    seq_of_stamp = {e.header.stamp: e.header.seq for e in run.events}
    rows: list[LoopClosureRow] = []
    for link in m.links:
        if not link.loop_closure:
            continue
        cur, mat = max(link.source, link.target), min(link.source, link.target)
        if mat < run.loaded_nodes:
            continue
        if cur not in nodes or mat not in nodes:
            raise ValueError(f"{run.path}: map loop-closure link {link.source}->{link.target} names a missing node")
        g = _truth_at(run, [nodes[cur].stamp, nodes[mat].stamp])
        known = bool(np.all(np.isfinite(g)))
        d = float(np.linalg.norm(g[0] - g[1])) if known else None
        rows.append({"event_seq": seq_of_stamp.get(nodes[cur].stamp), "current_exp": cur, "matched_exp": mat,
                     "d_gt_m": _r(d), "current_gt": [_r(v) for v in g[0]] if known else None,
                     "matched_gt": [_r(v) for v in g[1]] if known else None,
                     "label": None if d is None else ("TP" if d <= far_m else "FP")})
    rows.sort(key=lambda r: (r["current_exp"], r["matched_exp"]))
    out["table"] = rows
    out["accepted"] = len(rows)
    out["true"] = sum(r["label"] == "TP" for r in rows)
    out["false"] = sum(r["label"] == "FP" for r in rows)
    out["unlabelled"] = sum(r["label"] is None for r in rows)
    labelled = out["true"] + out["false"]
    out["precision"] = _r(out["true"] / labelled) if labelled else None
    if not run.has_truth:
        return out
    ids = sorted(nodes)
    g = _truth_at(run, [nodes[i].stamp for i in ids])
    known = np.all(np.isfinite(g), axis=1)
    opp = [ids[k] for k in np.flatnonzero(_revisit_opportunities(np.asarray(ids, dtype=np.int64), g, known,
                                                                   age, far_m))]
    tp_current = {r["current_exp"] for r in rows if r["label"] == "TP"}
    passes: list[list[int]] = []
    pos_of = {i: n for n, i in enumerate(ids)}
    for i in opp:
        if passes and pos_of[i] == pos_of[passes[-1][-1]] + 1:
            passes[-1].append(i)
        else:
            passes.append([i])
    out["opportunities"] = len(opp)
    out["recalled"] = sum(i in tp_current for i in opp)
    out["recall"] = _r(out["recalled"] / len(opp)) if opp else None
    out["passes"] = len(passes)
    out["passes_closed"] = sum(any(i in tp_current for i in ps) for ps in passes)
    out["pass_recall"] = _r(out["passes_closed"] / len(passes)) if passes else None
    return out


def _revisit_opportunities(ids: np.ndarray, g: np.ndarray, known: np.ndarray, age: int, far_m: float) -> np.ndarray:
    """Mask of nodes k having a node j with ids[j] <= ids[k] - age (j != k) within ``far_m``
    in truth.  Grid of ``far_m`` cells: only the 27 neighbouring cells are searched."""
    cells: dict[tuple[int, int, int], list[int]] = {}
    key = np.floor(np.where(known[:, None], g, 0.0) / far_m).astype(np.int64)
    for k in np.flatnonzero(known):
        cells.setdefault((int(key[k, 0]), int(key[k, 1]), int(key[k, 2])), []).append(int(k))
    arrays = {c: np.asarray(v, dtype=np.int64) for c, v in cells.items()}
    out = np.zeros(len(ids), dtype=bool)
    offsets = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    for k in np.flatnonzero(known):
        kx, ky, kz = (int(v) for v in key[k])
        for dx, dy, dz in offsets:
            js = arrays.get((kx + dx, ky + dy, kz + dz))
            if js is None:
                continue
            js = js[(ids[js] <= ids[k] - age) & (js != k)]
            if len(js) and float(np.min(np.linalg.norm(g[js] - g[k], axis=1))) <= far_m:
                out[k] = True
                break
    return out


def _box(p: np.ndarray) -> tuple[float, float, float]:
    ext = p.max(axis=0) - p.min(axis=0)
    return float(np.linalg.norm(ext)), float(np.prod(ext)), float(np.linalg.norm(p[-1] - p[0]))


def stability_proxies(mp: np.ndarray, odom: np.ndarray | None, gt: np.ndarray | None) -> StabilityProxies:
    """Span norm, bounding-box volume and end displacement of MAP, ODOM, GT point sequences
    (each (n, 3), NED, same order) and the MAP/ODOM, MAP/GT ratios (module docstring)."""
    vals = {"map": _box(mp)}
    if odom is not None:
        vals["odom"] = _box(odom)
    if gt is not None:
        vals["gt"] = _box(gt)
    def per_source(k: int) -> dict[str, float | None]:
        return {src: _r(v[k]) for src, v in vals.items()}

    def ratio(k: int, ref: str) -> float | None:
        r = vals.get(ref)
        return _r(vals["map"][k] / r[k]) if r is not None and r[k] > 0 else None

    ratios: ProxyRatios = {
        "span_norm_map_odom": ratio(0, "odom"), "volume_map_odom": ratio(1, "odom"),
        "end_displacement_map_odom": ratio(2, "odom"), "span_norm_map_gt": ratio(0, "gt"),
        "volume_map_gt": ratio(1, "gt"), "end_displacement_map_gt": ratio(2, "gt")}
    return {"samples": int(len(mp)), "span_norm_m": per_source(0), "volume_m3": per_source(1),
            "end_displacement_m": per_source(2), "ratios": ratios}


def front_end_metrics(run: RunData, far_m: float = 5.0, min_gap_m: float = 10.0) -> FrontEnd | None:
    """The ``front_end`` block (module docstring); None without ``local_view_cells``."""
    lvcs = run.lvcs
    if not lvcs:
        return None
    ids = [m.most_active_cell for m in lvcs]
    stamps = [m.header.stamp for m in lvcs]
    by_stamp = {r.header.stamp: r.frame_index for r in run.revisits.values()}
    frames, how = frame_indices(stamps, by_stamp)
    out: FrontEnd = {"frames": len(lvcs), "lvc_ids": len(set(ids)),
                     "new_id_fraction": round(sum(m.is_new for m in lvcs) / len(lvcs), 4), "frame_matching": how}
    if run.revisits:
        # ground truth row of each LVC message, re-indexed to LVC message positions
        pos_of_frame = {f: i for i, f in enumerate(frames)}
        rows = []
        for f in frames:
            r = run.revisits.get(f)
            same = [] if r is None else [pos_of_frame[j] for j in r.same_place.tolist() if j in pos_of_frame]
            rows.append(same)
        travelled = run.truth.travelled_at(stamps) if run.has_truth else None  # type: ignore[union-attr]
        s = lvc_revisit_metrics(ids, rows, travelled, min_gap_m if travelled is not None else 0.0)
        out.update({"revisit_frames": s["revisit_frames"], "revisit_recall": _r(s["recall"], 4),
                    "claimed_revisits": s["claimed"], "revisit_precision": _r(s["precision"], 4),
                    "min_gap_m": min_gap_m if travelled is not None else None})
    if run.has_truth:
        fa = lvc_false_associations(ids, [m.is_new for m in lvcs], _truth_at(run, stamps), far_m)
        out.update({"matched_frames": fa["matched_frames"],
                    "false_association_rate": _r(fa["false_association_rate"], 4)})
    return out


def _ate_figures(e: Trajectory, ref: Trajectory, s: np.ndarray) -> AteFigures:
    a = ate(e, ref, s)
    return {"rmse_m": _r(a["rmse_m"]), "mean_m": _r(a["mean_m"]), "max_m": _r(a["max_m"]),
            "final_m": _r(a["final_m"]), "n": int(a["n"])}


def _rpe_figures(e: Trajectory, ref: Trajectory, s: np.ndarray) -> RpeFigures:
    r = rpe(e, ref, RPE_DELTA_S, s)
    return {"rmse_m": _r(r["rmse_m"]), "mean_m": _r(r["mean_m"]), "n": int(r["n"] or 0), "delta_s": RPE_DELTA_S}


def _ate_block(run: RunData, mp: Trajectory | None
               ) -> tuple[AteBlock, RpeBlock, MapAndDeadReckoning, float | None]:
    """The ``ate``, ``rpe`` and ``drift_pct`` blocks and the true distance travelled (m)."""
    ate_d: AteBlock = {"stamps": None, "map": None, "dead_reckoning": None}
    rpe_d: RpeBlock = {"delta_s": RPE_DELTA_S, "map": None, "dead_reckoning": None}
    drift: MapAndDeadReckoning = {"map": None, "dead_reckoning": None}
    dist = None
    if not run.has_truth:
        return ate_d, rpe_d, drift, dist
    truth = run.truth
    assert truth is not None
    if mp is not None:
        s = mp.t[truth.covered(mp.t)]
        if run.odometry is not None:
            s = s[run.odometry.covered(s)]
        ate_d["stamps"] = "map_nodes"
    elif run.odometry is not None:
        s = truth.t[run.odometry.covered(truth.t)]
        ate_d["stamps"] = "truth_pose"
    else:
        return ate_d, rpe_d, drift, dist
    if not len(s):
        return ate_d, rpe_d, drift, dist
    ref = truth.resampled(s)
    dist = float(truth.travelled_at([s[-1]])[0] - truth.travelled_at([s[0]])[0])
    for name, est in (("map", mp), ("dead_reckoning", run.odometry)):
        if est is None:
            continue
        e = est.resampled(s)
        p = e.p + (ref.p[0] - e.p[0])
        d = _r(drift_pct(float(np.linalg.norm(p[-1] - ref.p[-1])), dist))
        if name == "map":
            ate_d["map"], rpe_d["map"], drift["map"] = _ate_figures(e, ref, s), _rpe_figures(e, ref, s), d
        else:
            ate_d["dead_reckoning"], rpe_d["dead_reckoning"] = _ate_figures(e, ref, s), _rpe_figures(e, ref, s)
            drift["dead_reckoning"] = d
    return ate_d, rpe_d, drift, dist


def _scored(source: str, poses: PoseSeries, rel: Any) -> RelationErrors:
    return {"source": source, **relation_summary(poses.stamps, poses.positions[:, 0], poses.positions[:, 1],
                                                 poses.yaws, rel)}


def relations_block(run: RunData, relations: str | Path) -> RelationsBlock:
    """``relations_file``, ``relations_in_file``, ``relations``, ``relations_odometry`` (module docstring).

    :raises ValueError: unreadable or malformed relations file (names file and line).
    """
    rel = read_relations(relations)
    out: RelationsBlock = {"relations_file": str(relations), "relations_in_file": len(rel), "relations": None,
                           "relations_odometry": None}
    if run.odometry_poses is not None and run.final_map is not None and run.final_map.nodes:
        out["relations"] = _scored("map_corrected", map_corrected(run.odometry_poses, run.final_map.nodes,
                                                                      run.scan_poses), rel)
    if run.wheel_odometry is not None:
        out["relations_odometry"] = _scored("wheel_odometry", run.wheel_odometry, rel)
    elif run.odometry_poses is not None:
        out["relations_odometry"] = _scored("Odometry", run.odometry_poses, rel)
    return out


def evaluate_run(path: str | Path | RunData, far_m: float = 5.0, config: PoseidonConfig | None = None,
                 min_gap_m: float = 10.0, relations: str | Path | None = None,
                 prior: str | Path | None = None) -> RunEvaluation:
    """Judge a run recording (``path`` or an already loaded :class:`RunData`): the figures of
    :class:`eval.results.RunEvaluation` (each key with its unit there; definitions in the module docstring).

    :param far_m: d_gt threshold of a true loop closure (m)
    :param config: replaces the configuration recorded in the run
    :param min_gap_m: travel before a re-used LVC id claims a revisit (m)
    :param relations: a Freiburg relations file to score the map and the odometry against
    :param prior: the recording of the run that saved the map this run continued (truth of the loaded nodes)
    """
    run = path if isinstance(path, RunData) else load_run(path, config)
    prior_run = load_run(prior, keys=["truth/pose"]) if prior is not None else None
    mp, _ = map_trajectory(run)
    m = run.final_map
    nodes = len(m.nodes) if m is not None else 0
    edges = len(m.links) if m is not None else 0
    loop_closures = loop_closure_table(run, far_m)
    ate_d, rpe_d, drift, dist = _ate_block(run, mp)
    ate_map, ate_dr = ate_d["map"], ate_d["dead_reckoning"]
    proxies = None
    if mp is not None:
        s = mp.t.copy()
        keep = np.ones(len(s), dtype=bool)
        if run.odometry is not None:
            keep &= run.odometry.covered(s)
        if run.has_truth:
            keep &= run.truth.covered(s)  # type: ignore[union-attr]
        if keep.sum() >= 2:
            s = s[keep]
            proxies = stability_proxies(
                mp.p[keep], run.odometry.positions_at(s) if run.odometry is not None else None,
                run.truth.positions_at(s) if run.has_truth else None)  # type: ignore[union-attr]
    vg = run.config.vpr_guard
    out: RunEvaluation = {
        "recording": str(run.path), "config_source": run.config_source, "duration_s": _r(run.duration_s, 3),
        "ground_truth": run.has_truth, "far_m": far_m,
        "events": len(run.events),
        "events_per_s": _r(len(run.events) / run.duration_s) if run.duration_s > 0 else None,
        "map_messages": run.map_messages, "nodes": nodes, "edges": edges,
        "mean_degree": _r(2.0 * edges / nodes) if nodes else None,
        "loop_closures": loop_closures,
        "ate_rmse_m": {"map": ate_map["rmse_m"] if ate_map is not None else None,
                       "dead_reckoning": ate_dr["rmse_m"] if ate_dr is not None else None},
        "ate": ate_d, "rpe": rpe_d, "drift_pct": drift, "truth_distance_m": _r(dist), "proxies": proxies,
        "vpr_ok_ratio": _r(vpr_window_ok_ratio([x.most_active_cell for x in run.lvcs], vg.vpr_window,
                                               vg.vpr_min_rep)) if run.lvcs else None,
        "front_end": front_end_metrics(run, far_m, min_gap_m),
        "dead_reckoning": _dead_reckoning(run),
        "sessions": sessions_block(run, prior_run, far_m),
        "latency": latency_block(run),
    }
    if relations is not None:
        rb = relations_block(run, relations)
        out["relations_file"], out["relations_in_file"] = rb["relations_file"], rb["relations_in_file"]
        out["relations"], out["relations_odometry"] = rb["relations"], rb["relations_odometry"]
    return out


def _dead_reckoning(run: RunData) -> DeadReckoningErrors | None:
    """The ``dead_reckoning`` block: the whole ``Odometry`` stream against the truth (None without either)."""
    if run.truth is None or not len(run.truth) or run.odometry is None or len(run.odometry) <= 1:
        return None
    e = anchored_errors(run.odometry, run.truth)
    return {"ate_rmse_m": _r(e["ate_rmse_m"], 4), "final_error_m": _r(e["final_error_m"], 4),
            "final_drift_pct": _r(e["final_drift_pct"], 4), "max_error_m": _r(e["max_error_m"], 4),
            "truth_distance_m": _r(e["truth_distance_m"], 4)}


def latency_block(run: RunData) -> LatencyBlock | None:
    """The ``latency`` key: a live run's report as recorded (null for a replay)."""
    r = run.latency
    if r is None:
        return None
    stages: dict[str, LatencyStageFigures] = {
        k: {"n": v.n, "unmatched": v.unmatched, "p50_ms": v.p50_ms, "p95_ms": v.p95_ms, "p99_ms": v.p99_ms,
            "max_ms": v.max_ms} for k, v in sorted(r.stages.items())}
    return {"source": r.source, "rate": r.rate, "stages": stages}
