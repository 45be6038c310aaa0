"""What limits the experience map against dead reckoning: the relaxation given perfect loops.

``python -m eval.relaxation_oracle RUN.mcap [--json]`` (a run recording with ``truth/pose``,
``Odometry`` and a final ``map``) re-solves the run's map offline, horizontal positions only,
and reports the horizontal ATE (m, after rigid alignment to the truth) of:

- ``dead_reckoning``: the run's ``Odometry`` at the nodes' stamps;
- ``published_map``: the run's final ``map``;
- ``relaxation_recorded_loops``: Eq. 4.20 (odometry edges weight 1, the map's loop edges
  weight ``loop_weight``, each asking the displacement it recorded), solved exactly; this
  reproduces the published map when every correction has settled;
- ``relaxation_oracle_loops``: Eq. 4.20 with *oracle* loop edges instead: every ``spacing``-th
  node paired with the oldest node at least ``min_age`` nodes older whose true position is
  within ``radius_m``, each edge asking the true displacement (a perfect, dense loop detector
  with perfect registration);
- ``dead_reckoning_similarity``: the dead reckoning after a similarity alignment (rotation,
  translation *and scale*), with that ``scale``: what is left of the dead reckoning's error
  once a scale error, which no loop at the same place can observe, is taken out.

Also ``recorded_loop_error_m``: the largest |recorded displacement - true displacement| of the
map's loop edges.  ``--json`` prints ``{"nodes", "loops": {"recorded", "oracle"}, "ate_xy_m":
{<the names above>: m}, "scale", "recorded_loop_error_m"}``.

Why it exists (``docs/DECISIONS.md``, "What limits the map on the sim missions"): on the
15-minute sim missions the map's ATE is about the dead reckoning's, and dense perfect loops do
not change that: most of the dead reckoning's error there is a scale error of 1-2 % (the
simulated DVL's scale and forward bias).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import lsqr
from scipy.spatial import cKDTree

from common.mcap_io import RecordingError
from eval.trajectory import align_rigid

__all__ = ["Mission2D", "solve_positions", "oracle_loops", "ate_xy", "similarity_ate_xy", "analyse", "main"]


@dataclass
class Mission2D:
    """Horizontal inputs of the analysis, NED (m)."""

    odom: np.ndarray       # (n, 2) dead-reckoned positions at the nodes
    truth: np.ndarray      # (n, 2) true positions at the nodes


Loop = tuple[int, int, np.ndarray]   # (older node, newer node, displacement newer - older asked)


def solve_positions(odom: np.ndarray, loops: list[Loop], loop_weight: float = 1.0) -> np.ndarray:
    """Node positions (n, 2) minimising Eq. 4.20: sum over odometry edges of
    |p_i - p_(i-1) - D_i|^2 plus ``loop_weight`` times sum over loops of |p_b - p_a - delta|^2,
    node 0 held at its dead-reckoned position (a sparse linear least-squares problem)."""
    n = len(odom)
    if n < 2:
        raise ValueError(f"need at least 2 nodes, got {n}")
    d = np.diff(odom, axis=0)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    r0 = 0
    i = np.arange(1, n)
    w = math.sqrt(loop_weight)
    for a in range(2):
        r = r0 + np.arange(n - 1)
        rows += [r, r]
        cols += [2 * i + a, 2 * (i - 1) + a]
        vals += [np.ones(n - 1), -np.ones(n - 1)]
        rhs.append(d[:, a])
        r0 += n - 1
        for older, newer, delta in loops:
            rows.append(np.array([r0, r0]))
            cols.append(np.array([2 * newer + a, 2 * older + a]))
            vals.append(np.array([w, -w]))
            rhs.append(np.array([w * float(delta[a])]))
            r0 += 1
        rows.append(np.array([r0]))
        cols.append(np.array([a]))
        vals.append(np.array([100.0]))
        rhs.append(np.array([100.0 * odom[0, a]]))
        r0 += 1
    A = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, 2 * n)).tocsr()
    x: np.ndarray = lsqr(A, np.concatenate(rhs), atol=1e-12, btol=1e-12, iter_lim=100 * n)[0]
    return x.reshape(n, 2)


def oracle_loops(truth: np.ndarray, spacing: int = 10, radius_m: float = 1.0, min_age: int = 200) -> list[Loop]:
    """Every ``spacing``-th node paired with the oldest node >= ``min_age`` nodes older within
    ``radius_m`` (true positions), asking the true displacement."""
    tree = cKDTree(truth)
    out: list[Loop] = []
    for k in range(0, len(truth), spacing):
        near = [j for j in tree.query_ball_point(truth[k], radius_m) if j <= k - min_age]
        if near:
            j = min(near)
            out.append((j, k, truth[k] - truth[j]))
    return out


def ate_xy(p: np.ndarray, truth: np.ndarray) -> float:
    """Horizontal RMSE (m) after the rigid alignment (rotation about the vertical, translation)."""
    z = np.zeros((len(p), 1))
    R, t = align_rigid(np.hstack([p, z]), np.hstack([truth, z]))
    e = np.hstack([p, z]) @ R.T + t - np.hstack([truth, z])
    return float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1))))


def similarity_ate_xy(p: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(scale s, horizontal RMSE (m)) of the best s R p + t against ``truth`` (Umeyama, 2D)."""
    mp, mq = p.mean(axis=0), truth.mean(axis=0)
    U, S, Vt = np.linalg.svd((truth - mq).T @ (p - mp))
    D = np.diag([1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / np.sum((p - mp) ** 2))
    e = s * (p - mp) @ R.T + mq - truth
    return s, float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


def analyse(m: Mission2D, recorded: list[Loop], published: np.ndarray | None = None, spacing: int = 10,
            radius_m: float = 1.0, min_age: int = 200) -> dict[str, Any]:
    """The figures of the module doc for one mission."""
    oracle = oracle_loops(m.truth, spacing, radius_m, min_age)
    scale, sim_ate = similarity_ate_xy(m.odom, m.truth)
    ate = {"dead_reckoning": ate_xy(m.odom, m.truth),
           "published_map": None if published is None else ate_xy(published, m.truth),
           "relaxation_recorded_loops": ate_xy(solve_positions(m.odom, recorded), m.truth),
           "relaxation_oracle_loops": ate_xy(solve_positions(m.odom, oracle), m.truth),
           "dead_reckoning_similarity": sim_ate}
    err = max((float(np.linalg.norm(np.asarray(d) - (m.truth[b] - m.truth[a]))) for a, b, d in recorded), default=None)
    return {"nodes": len(m.odom), "loops": {"recorded": len(recorded), "oracle": len(oracle)},
            "ate_xy_m": {k: None if v is None else round(v, 4) for k, v in ate.items()},
            "scale": round(scale, 5), "recorded_loop_error_m": None if err is None else round(err, 4)}


def _mission_of_run(path: str) -> tuple[Mission2D, list[Loop], np.ndarray]:
    from eval.rundata import load_run
    run = load_run(path)
    if run.final_map is None or not run.final_map.nodes:
        raise ValueError(f"{path}: no map in the recording")
    if run.truth is None or run.odometry_poses is None or not len(run.odometry_poses):
        raise ValueError(f"{path}: needs truth/pose and Odometry")
    nodes = sorted(run.final_map.nodes, key=lambda nd: nd.id)
    st = np.array([nd.stamp for nd in nodes], np.int64)
    ok = run.truth.covered(st)
    if not ok.all():
        raise ValueError(f"{path}: {int((~ok).sum())} map nodes lie outside truth/pose")
    od = run.odometry_poses.interpolate(st)
    m = Mission2D(odom=run.to_ned(od.positions)[:, :2], truth=run.truth.positions_at(st)[:, :2])
    recorded = [(lk.source, lk.target, run.to_ned(np.array([lk.delta], np.float64))[0, :2])
                for lk in run.final_map.links if lk.loop_closure]
    published = run.to_ned(np.array([nd.position for nd in nodes], np.float64))[:, :2]
    return m, recorded, published


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval.relaxation_oracle", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a run recording (truth/pose, Odometry, map)")
    ap.add_argument("--spacing", type=int, default=10, help="oracle loop on every N-th node (default 10)")
    ap.add_argument("--radius-m", type=float, default=1.0, help="oracle loop partner within this, m (default 1)")
    ap.add_argument("--min-age", type=int, default=200, help="oracle loop partner at least this many nodes older")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    try:
        m, recorded, published = _mission_of_run(a.run)
    except (OSError, ValueError, RecordingError) as exc:
        print(f"relaxation_oracle: {exc}", file=sys.stderr)
        return 2
    r = analyse(m, recorded, published, a.spacing, a.radius_m, a.min_age)
    if a.json:
        print(json.dumps(r))
        return 0
    print(f"{a.run}: {r['nodes']} nodes, {r['loops']['recorded']} recorded loops, {r['loops']['oracle']} oracle loops")
    for k, v in r["ate_xy_m"].items():
        print(f"  {k:<28} {'-' if v is None else f'{v:.3f} m'}")
    err = r["recorded_loop_error_m"]
    print(f"  dead reckoning's scale against the truth {r['scale']:.4f}; largest recorded loop error "
          + ("-" if err is None else f"{err:.3f} m"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
