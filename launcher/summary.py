"""What a run produced, judged against ground truth when the input has it (sim missions).

Front-end (``local_view_cells`` against ``truth/revisits`` and ``truth/pose``):

- ``frames``, ``lvc_ids`` (distinct ids), ``new_id_fraction`` (frames that created an id);
- ``revisit_frames``: frames whose truth lists earlier frames of the same place;
  ``revisit_recall``: fraction of them whose LVC id is the id of one of those frames;
- ``false_association_rate``: fraction of frames matched to an existing id (``is_new``
  false) that was created more than ``far_m`` (5 m) away in truth -- the dissertation's
  loop-closure false-positive distance.

Dead reckoning (``Odometry`` against ``truth/pose``; both taken to NED, the estimate
translated to start at the true start): ``ate_rmse_m``, ``final_error_m``,
``final_drift_pct`` (final error / true distance), ``truth_distance_m``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from common.config import PoseidonConfig
from common.mcap_io import read_messages
from common.messages import LocalViewCells, Odometry, RevisitTruth

__all__ = ["summarize_run", "format_summary"]


def _truth_trajectory(poses: list[Odometry]) -> Any:
    from services.robot_state.deadreckon import Trajectory
    return Trajectory([m.header.stamp for m in poses], [np.asarray(m.position) for m in poses],
                      [0.0 for _ in poses])


def _front_end(lvcs: list[LocalViewCells], revisits: dict[int, RevisitTruth], truth: Any,
               far_m: float) -> dict[str, Any]:
    ids = [m.most_active_cell for m in lvcs]
    created_at: dict[int, int] = {}
    for i, m in enumerate(lvcs):
        if m.is_new:
            created_at.setdefault(m.most_active_cell, i)
    out: dict[str, Any] = {"frames": len(lvcs), "lvc_ids": len(set(ids)),
                           "new_id_fraction": round(sum(m.is_new for m in lvcs) / max(len(lvcs), 1), 4)}
    if not revisits:
        return out
    hits = total = 0
    for i, m in enumerate(lvcs):
        truth_frames = revisits.get(i)
        if truth_frames is None or len(truth_frames.same_place) == 0:
            continue
        total += 1
        hits += int(ids[i] in {ids[j] for j in truth_frames.same_place.tolist() if j < len(ids)})
    matched = far = 0
    stamps = [m.header.stamp for m in lvcs]
    if truth is not None and len(truth):
        for i, m in enumerate(lvcs):
            j = created_at.get(m.most_active_cell)
            if m.is_new or j is None or not (truth.covers(stamps[i]) and truth.covers(stamps[j])):
                continue
            matched += 1
            far += int(np.linalg.norm(truth.at(stamps[i])[0] - truth.at(stamps[j])[0]) > far_m)
    out.update({"revisit_frames": total, "revisit_recall": round(hits / total, 4) if total else None,
                "matched_frames": matched,
                "false_association_rate": round(far / matched, 4) if matched else None})
    return out


def summarize_run(path: str | Path, config: PoseidonConfig, far_m: float = 5.0) -> dict[str, Any]:
    """Judge the run recorded in ``path`` (see the module docstring for the keys)."""
    lvcs: list[LocalViewCells] = []
    revisits: dict[int, RevisitTruth] = {}
    poses: list[Odometry] = []
    odom: list[Odometry] = []
    for r in read_messages(path, keys=["local_view_cells", "truth/revisits", "truth/pose", "Odometry"]):
        m = r.message()
        if r.key == "local_view_cells":
            lvcs.append(m)
        elif r.key == "truth/revisits":
            revisits[m.frame_index] = m
        elif r.key == "truth/pose":
            poses.append(m)
        else:
            odom.append(m)
    truth = _truth_trajectory(poses) if poses else None
    out: dict[str, Any] = {}
    if lvcs:
        out["front_end"] = _front_end(lvcs, revisits, truth, far_m)
    if odom and truth is not None and len(odom) > 1:
        from services.robot_state.deadreckon import Trajectory, truth_scores
        from services.robot_state.frames import OutputFrame
        frame = OutputFrame(config.robot_state.axis_remap, config.robot_state.axis_sign_z)
        est = Trajectory([m.header.stamp for m in odom], [frame.position_to_ned(np.asarray(m.position)) for m in odom],
                         [0.0 for _ in odom])
        out["dead_reckoning"] = {k: round(v, 4) for k, v in truth_scores(est, truth).items()}
    return out


def format_summary(s: dict[str, Any]) -> list[str]:
    lines = []
    fe = s.get("front_end")
    if fe:
        line = (f"front-end: {fe['frames']} frames -> {fe['lvc_ids']} LVC ids "
                f"({100 * fe['new_id_fraction']:.0f}% of frames created an id)")
        if fe.get("revisit_recall") is not None:
            line += f"; revisits recognised {100 * fe['revisit_recall']:.1f}% of {fe['revisit_frames']} frames"
        if fe.get("false_association_rate") is not None:
            line += (f"; {100 * fe['false_association_rate']:.1f}% of {fe['matched_frames']} matches "
                     f"joined places > 5 m apart")
        lines.append(line)
    dr = s.get("dead_reckoning")
    if dr:
        lines.append(f"dead reckoning: {dr['truth_distance_m']:.1f} m travelled, final error {dr['final_error_m']:.2f} m "
                     f"({dr['final_drift_pct']:.2f}% of distance), ATE RMSE {dr['ate_rmse_m']:.2f} m")
    return lines
