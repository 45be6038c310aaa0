"""The place-recognition figures of the report (Figs 5.9-5.12, 5.15-5.18 of the
dissertation): similarity and ground-truth revisit matrices, view cells over time,
precision-recall.

Similarity: at most ``max_frames`` frames, evenly spaced.  With ``neocortex/sdr`` the
similarity of frames i and j is the overlap of their fused SDRs,
|A_i & A_j| / max(|A_i|, |A_j|) (0-100 %); without it, 100 % when both frames got the same
LVC id.  Ground truth: ``truth/revisits`` (frames matched to camera frames by stamp).
Pairs less than ``min_gap_m`` of true travel apart (the same pass) are left out of the
precision-recall curves, as the simulator leaves them out of the revisit truth.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from eval.report.data import RunView
from eval.report.style import FigureSpec, apply_layout, decimate, run_color

__all__ = ["Similarity", "frame_similarity", "precision_recall", "similarities", "fig_similarity", "fig_viewcells",
           "fig_pr", "revisit_frames"]


@dataclass
class Similarity:
    """Similarity between sampled frames of one run, and the revisit truth for them."""

    source: str  # "SDR overlap" | "same LVC id"
    stamps: np.ndarray
    frame_total: int
    percent: np.ndarray  # (n, n) uint8, 0-100
    lvc: np.ndarray | None  # LVC id of each sampled frame (-1 unknown)
    truth: np.ndarray | None  # (n, n) bool: same place (either direction), None without revisits
    pair_ok: np.ndarray | None  # (n, n) bool: pairs scored in the PR curve (i > j, far enough apart)
    notes: list[str] = field(default_factory=list)


def _camera_index(stamps: np.ndarray, revisit_stamps: np.ndarray) -> np.ndarray:
    """Camera-frame index of each stamp (nearest revisit-truth stamp within half a frame), -1 if none."""
    valid = np.flatnonzero(revisit_stamps >= 0)
    out = np.full(len(stamps), -1, dtype=np.int64)
    if len(valid) == 0:
        return out
    ref = revisit_stamps[valid]
    order = np.argsort(ref, kind="stable")
    ref, valid = ref[order], valid[order]
    tol = np.median(np.diff(ref)) / 2 if len(ref) > 1 else 0
    pos = np.clip(np.searchsorted(ref, stamps), 1, max(len(ref) - 1, 1))
    left = np.clip(pos - 1, 0, len(ref) - 1)
    right = np.clip(pos, 0, len(ref) - 1)
    pick = np.where(np.abs(ref[left] - stamps) <= np.abs(ref[right] - stamps), left, right)
    close = np.abs(ref[pick] - stamps) <= tol
    out[close] = valid[pick[close]]
    return out


def frame_similarity(run: RunView, max_frames: int = 500, min_gap_m: float = 10.0) -> Similarity | None:
    """The similarity matrix of (at most ``max_frames``) frames of ``run``; None without SDR/LVC frames."""
    lvc_by_stamp = dict(zip(run.lvc_stamps.tolist(), run.lvc_id.tolist()))
    if len(run.sdr_stamps) >= 2:
        k = decimate(len(run.sdr_stamps), max_frames)
        stamps = run.sdr_stamps[k]
        active = [run.sdr_active[j] for j in k]
        bits, inverse = np.unique(np.concatenate(active), return_inverse=True)   # k: at least 2 frames
        dense = np.zeros((len(k), len(bits)), dtype=np.float32)
        start = 0
        for row, a in enumerate(active):
            dense[row, inverse[start:start + len(a)]] = 1.0
            start += len(a)
        inter = dense @ dense.T
        sizes = dense.sum(axis=1)
        denom = np.maximum(np.maximum.outer(sizes, sizes), 1.0)
        percent = np.rint(100.0 * inter / denom).astype(np.uint8)
        source, total = "SDR overlap", len(run.sdr_stamps)
        lvc = np.array([lvc_by_stamp.get(int(s), -1) for s in stamps], dtype=np.int64) if len(run.lvc_id) else None
    elif len(run.lvc_stamps) >= 2:
        k = decimate(len(run.lvc_stamps), max_frames)
        stamps = run.lvc_stamps[k]
        lvc = run.lvc_id[k]
        percent = (100 * (lvc[:, None] == lvc[None, :])).astype(np.uint8)
        source, total = "same LVC id", len(run.lvc_stamps)
    else:
        return None
    sim = Similarity(source, stamps, total, percent, lvc, None, None)
    if len(run.revisit_stamps) == 0:
        sim.notes.append("no truth/revisits in the run: no ground-truth matrix, no precision-recall")
        return sim
    cam = _camera_index(stamps, run.revisit_stamps)
    if (cam < 0).all():
        sim.notes.append("no frame matches a truth/revisits stamp: no ground truth for these frames")
        return sim
    n = len(stamps)
    same = [set(run.revisit_same[c].tolist()) if c >= 0 else set() for c in cam]
    truth = np.zeros((n, n), dtype=bool)
    for a in range(n):
        if cam[a] < 0:
            continue
        for b in range(n):
            if cam[b] >= 0 and cam[b] != cam[a] and (cam[b] in same[a] or cam[a] in same[b]):
                truth[a, b] = True
    aligned = cam >= 0
    pair_ok = np.tril(np.outer(aligned, aligned), k=-1)
    if len(run.truth) >= 2:
        travelled = np.interp((stamps - run.truth.t[0]).astype(np.float64),
                              (run.truth.t - run.truth.t[0]).astype(np.float64), run.truth.cumulative_distance())
        near = np.abs(travelled[:, None] - travelled[None, :]) < min_gap_m
        pair_ok &= ~near | truth
    else:
        sim.notes.append("no truth/pose: pairs from the same pass are not excluded from precision-recall")
    sim.truth, sim.pair_ok = truth, pair_ok
    if (~aligned).any():
        sim.notes.append(f"{int((~aligned).sum())} of {n} sampled frames have no revisit truth (no camera frame "
                         "at their stamp) and are left out of precision-recall")
    return sim


def precision_recall(scores: np.ndarray, labels: np.ndarray) -> dict[str, Any]:
    """Precision and recall at every threshold of ``scores`` (predict positive when score >= threshold).

    Returns ``thresholds``, ``precision``, ``recall`` (arrays, highest threshold first),
    ``average_precision`` (sum of precision x recall increments), ``best_f1`` and its threshold,
    ``positives`` and ``pairs``.
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(labels, dtype=bool)
    positives = int(labels.sum())
    out: dict[str, Any] = {"positives": positives, "pairs": int(len(labels))}
    if positives == 0 or len(scores) == 0:
        out.update(thresholds=np.zeros(0), precision=np.zeros(0), recall=np.zeros(0), average_precision=None,
                   best_f1=None, best_threshold=None)
        return out
    order = np.argsort(-scores, kind="stable")
    s, y = scores[order], labels[order]
    tp = np.cumsum(y)
    fp = np.cumsum(~y)
    last = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]  # last index of each distinct score
    precision = tp[last] / (tp[last] + fp[last])
    recall = tp[last] / positives
    ap = float(np.sum(np.diff(np.r_[0.0, recall]) * precision))
    f1 = np.where(precision + recall > 0, 2 * precision * recall / np.maximum(precision + recall, 1e-12), 0.0)
    b = int(np.argmax(f1))
    out.update(thresholds=s[last], precision=precision, recall=recall, average_precision=ap,
               best_f1=float(f1[b]), best_threshold=float(s[last][b]))
    return out


def _same_similarity(a: Similarity, b: Similarity) -> bool:
    return a.source == b.source and np.array_equal(a.stamps, b.stamps) and np.array_equal(a.percent, b.percent)


def _same_array(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Both absent, or both present and equal."""
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def similarities(runs: list[RunView], max_frames: int, min_gap_m: float) -> list[tuple[int, Similarity | None]]:
    return [(i, frame_similarity(r, max_frames, min_gap_m)) for i, r in enumerate(runs)]


def fig_similarity(runs: list[RunView], sims: list[tuple[int, Similarity | None]]) -> FigureSpec:
    spec = FigureSpec(
        "fig-similarity", "Similarity matrix and ground-truth revisit matrix (cf. Figs 5.9-5.10, 5.15-5.16)",
        "Left: similarity between every pair of frames (row = frame, column = frame, both in time order; "
        "brighter = more similar; hover for the exact value). The bright diagonal is each frame with itself and "
        "its neighbours; bright off-diagonal bands are places recognised again; scattered bright spots away "
        "from the truth's bands are perceptual aliasing (risk of false loop closures). Right: the ground truth "
        "of the same frames, white where two frames show the same place (truth/revisits). A good front-end's "
        "left panel reproduces the right panel's off-diagonal bands and little else.")
    shown: list[tuple[int, Similarity]] = []
    for i, sim in sims:
        if sim is None:
            spec.notes.append(f"{runs[i].label}: no neocortex/sdr or local_view_cells frames")
            continue
        twin = next((j for j, o in shown if _same_similarity(o, sim)), None)
        if twin is not None:
            spec.notes.append(f"{runs[i].label}: same matrix as {runs[twin].label} (same front-end output)")
            continue
        shown.append((i, sim))
        spec.notes += [f"{runs[i].label}: {n}" for n in sim.notes]
    if not shown:
        return spec
    cols = 2 if any(sim.truth is not None for _, sim in shown) else 1
    if cols == 1:
        spec.title = "Similarity matrix (cf. Figs 5.9-5.10)"
        spec.caption = ("Similarity between every pair of frames (row = frame, column = frame, both in time order; "
                        "brighter = more similar; hover for the exact value). The bright diagonal is each frame "
                        "with itself and its neighbours; bright off-diagonal bands are places recognised again; "
                        "scattered bright spots can be perceptual aliasing (risk of false loop closures). The run "
                        "has no revisit ground truth (truth/revisits) to compare with.")
    titles = []
    for i, sim in shown:
        sub = f"{len(sim.stamps)} of {sim.frame_total} frames" if len(sim.stamps) < sim.frame_total else \
            f"{sim.frame_total} frames"
        titles += [f"{runs[i].label}: {sim.source} ({sub})"]
        if cols == 2:
            titles.append("ground truth: same place" if sim.truth is not None else "no ground truth")
    fig = make_subplots(rows=len(shown), cols=cols, subplot_titles=titles, horizontal_spacing=0.08,
                        vertical_spacing=0.08)
    for row, (i, sim) in enumerate(shown, start=1):
        t = runs[i].seconds(sim.stamps).astype(np.float32)
        fig.add_trace(go.Heatmap(z=sim.percent, x=t, y=t, coloraxis="coloraxis", name=runs[i].label,
                                 hovertemplate="frame at %{y:.1f} s vs %{x:.1f} s: %{z}%<extra></extra>"),
                      row=row, col=1)
        if sim.truth is not None:
            fig.add_trace(go.Heatmap(z=sim.truth.astype(np.uint8), x=t, y=t, showscale=False, zmin=0, zmax=1,
                                     colorscale=[[0, "#000000"], [1, "#ffffff"]], name="ground truth",
                                     hovertemplate="%{y:.1f} s vs %{x:.1f} s: same place %{z}<extra></extra>"),
                          row=row, col=2)
        for col in range(1, cols + 1):
            fig.update_xaxes(title_text="time (s)", row=row, col=col)
            fig.update_yaxes(title_text="time (s)", autorange="reversed", row=row, col=col)
        if cols == 1:  # one matrix a row: square, not stretched across the page
            fig.update_xaxes(constrain="domain", row=row, col=1)
            fig.update_yaxes(scaleanchor="x" if row == 1 else f"x{row}", constrain="domain", row=row, col=1)
    # colour range from the off-diagonal values (1st to 99.9th percentile): a dense SDR's chance overlap is far
    # above 0 %, and a 0-100 scale would wash the structure out
    off = np.concatenate([sim.percent[~np.eye(len(sim.stamps), dtype=bool)] for _, sim in shown])
    lo, hi = (float(np.percentile(off, 1)), float(np.percentile(off, 99.9))) if len(off) else (0.0, 100.0)
    if hi <= lo:
        lo, hi = 0.0, 100.0
    spec.notes.append(f"colour scale {lo:.0f}-{hi:.0f} % (1st-99.9th percentile of the off-diagonal similarity)")
    fig.update_layout(coloraxis=dict(colorscale="Viridis", cmin=lo, cmax=hi,
                                     colorbar=dict(title="%", len=1.0 / len(shown), y=1.0, yanchor="top")))
    spec.figure = apply_layout(fig, 520 * len(shown))
    return spec


def revisit_frames(r: RunView, min_gap_m: float) -> np.ndarray:
    """Frames matched to an existing cell created at least ``min_gap_m`` of travel earlier (truth, else
    dead reckoning; without either, 60 s earlier)."""
    created: dict[int, int] = {}
    for k, (cell, new) in enumerate(zip(r.lvc_id.tolist(), r.lvc_new.tolist())):
        if new or cell not in created:
            created.setdefault(cell, k)
    first = np.array([created[c] for c in r.lvc_id.tolist()], dtype=np.int64)
    track = r.truth if len(r.truth) >= 2 else r.dead_reckoning
    if len(track) >= 2:
        along = np.interp((r.lvc_stamps - track.t[0]).astype(np.float64),
                          (track.t - track.t[0]).astype(np.float64), track.cumulative_distance())
        gap, limit = along - along[first], min_gap_m
    else:
        gap, limit = (r.lvc_stamps - r.lvc_stamps[first]) / 1e9, 60.0
    revisit: np.ndarray = ~r.lvc_new & (gap >= limit)
    return revisit


def fig_viewcells(runs: list[RunView], max_points: int, min_gap_m: float = 10.0) -> FigureSpec:
    truth = any(r.revisit_same for r in runs)
    spec = FigureSpec(
        "fig-viewcells", "View cells over time: creation and recognition (cf. Figs 5.11-5.12)",
        ("One panel per run. " if len(runs) > 1 else "")
        + "Each frame's local view cell (LVC) id against time: blue crosses are frames that "
        "created a new cell (a place not seen before); grey dots matched a cell created moments before (the same "
        "pass over a place); red circles matched a cell created at least the minimum travel earlier (a place "
        "recognised again, a loop-closure candidate); black diamonds are loop closures the experience map "
        "accepted. A rising staircase is exploration; red circles at low ids late in the run are revisits of "
        "early places" + (" (compare with the ground-truth matrix above)." if truth else "."))
    with_lvc = [(i, r) for i, r in enumerate(runs) if len(r.lvc_stamps)]
    for r in runs:
        if not len(r.lvc_stamps):
            spec.notes.append(f"{r.label}: no local_view_cells")
    if not with_lvc:
        return spec
    titles = [f"{r.label}: {len(np.unique(r.lvc_id))} view cells, {int(revisit_frames(r, min_gap_m).sum())} frames "
              f"recognised after >= {min_gap_m:g} m, {int(r.link_loop.sum())} map loop closures" for _, r in with_lvc]
    fig = make_subplots(rows=len(with_lvc), cols=1, subplot_titles=titles, shared_xaxes=False,
                        vertical_spacing=0.12 if len(with_lvc) > 1 else 0.1)
    for row, (_i, r) in enumerate(with_lvc, start=1):
        t = r.seconds(r.lvc_stamps).astype(np.float32)
        revisit = revisit_frames(r, min_gap_m)
        same_pass = ~r.lvc_new & ~revisit
        for mask, name, marker in ((same_pass, "matched a cell of the same pass",
                                    dict(symbol="circle", size=3, color="#bbbbbb")),
                                   (r.lvc_new, "new view cell", dict(symbol="x-thin", size=6, color="#1f77b4",
                                                                     line=dict(width=1.5, color="#1f77b4"))),
                                   (revisit, f"recognised a cell from >= {min_gap_m:g} m of travel earlier",
                                    dict(symbol="circle-open", size=8, color="#d62728", line=dict(width=1.5)))):
            idx = np.flatnonzero(mask)
            idx = idx[decimate(len(idx), max_points)]
            fig.add_trace(go.Scatter(x=t[idx], y=r.lvc_id[idx], mode="markers", name=name, legendgroup=name,
                                     showlegend=row == 1, marker=marker), row=row, col=1)
        if r.link_loop.any():
            legend_lc = row > 1 and any(o.link_loop.any() for _, o in with_lvc[:row - 1])
            index = {int(nid): j for j, nid in enumerate(r.node_ids)}
            later = [max(index[a], index[b], key=lambda j: r.node_stamps[j])
                     for a, b in r.links[r.link_loop].tolist() if a in index and b in index]
            fig.add_trace(go.Scatter(x=r.seconds(r.node_stamps[later]).astype(np.float32), y=r.node_lvc[later],
                                     mode="markers", name="map loop closure", legendgroup="map loop closure",
                                     showlegend=not legend_lc, marker=dict(symbol="diamond", size=10, color="black")),
                          row=row, col=1)
        fig.update_xaxes(title_text="time since the start of the run (s)", row=row, col=1)
        fig.update_yaxes(title_text="LVC id", row=row, col=1)
    spec.figure = apply_layout(fig, 380 * len(with_lvc))
    return spec


def fig_pr(runs: list[RunView], sims: list[tuple[int, Similarity | None]]) -> tuple[FigureSpec, dict[str, Any]]:
    spec = FigureSpec(
        "fig-pr", "Precision-recall of place recognition (cf. Figs 5.17-5.18)",
        "Each curve sweeps a threshold over the similarity matrix: a pair of frames (at least the minimum "
        "travel apart) is called the same place when its similarity reaches the threshold, and is scored "
        "against the ground-truth matrix. Precision = correct / called; recall = correct / true revisits. "
        "Up and to the right is better; AP (average precision, area under the curve) and the best F1 are in the "
        "legend. The star marks the front-end's actual decision as a frame-pair measure: two frames are called the "
        "same place when they carry the same LVC id (pair precision P, pair recall R over the same pairs; "
        "eval/frontend.py lvc_pair_metrics). It is not the per-frame revisit precision/recall of the evaluation "
        "table (does a frame's id point to an earlier visit of its place).")
    summary: dict[str, Any] = {}
    fig = go.Figure()
    drawn = False
    shown: list[tuple[int, Similarity]] = []
    for i, sim in sims:
        r = runs[i]
        if sim is None or sim.truth is None or sim.pair_ok is None:
            spec.notes.append(f"{r.label}: no similarity/ground truth (see the similarity matrix)")
            continue
        twin = next((j for j, o in shown if _same_similarity(o, sim) and _same_array(o.truth, sim.truth)
                     and _same_array(o.lvc, sim.lvc)), None)
        if twin is not None:
            spec.notes.append(f"{r.label}: same curve as {runs[twin].label} (same front-end output and truth)")
            summary[r.label] = summary[runs[twin].label]
            continue
        shown.append((i, sim))
        ok = sim.pair_ok
        labels = sim.truth[ok]
        pr = precision_recall(sim.percent[ok].astype(np.float64), labels)
        entry: dict[str, Any] = {"source": sim.source, "pairs": pr["pairs"], "positives": pr["positives"],
                                 "average_precision": pr["average_precision"], "best_f1": pr["best_f1"]}
        if pr["positives"] == 0:
            spec.notes.append(f"{r.label}: no true revisit among the sampled frame pairs")
            summary[r.label] = entry
            continue
        if sim.source == "SDR overlap":
            fig.add_trace(go.Scatter(x=pr["recall"].astype(np.float32), y=pr["precision"].astype(np.float32),
                                     mode="lines", line=dict(color=run_color(i), width=2), customdata=pr["thresholds"],
                                     hovertemplate="threshold %{customdata}%: recall %{x:.3f}, precision "
                                                   "%{y:.3f}<extra></extra>",
                                     name=f"{r.label}: SDR overlap (AP {pr['average_precision']:.3f}, "
                                          f"best F1 {pr['best_f1']:.3f})"))
            drawn = True
        if sim.lvc is not None and (sim.lvc >= 0).any():
            known = sim.lvc >= 0
            both = ok & np.outer(known, known)
            predicted = (sim.lvc[:, None] == sim.lvc[None, :])[both]
            truth = sim.truth[both]
            tp = int((predicted & truth).sum())
            called = int(predicted.sum())
            pos = int(truth.sum())
            if pos:
                p = tp / called if called else 1.0
                rc = tp / pos
                f1 = 2 * p * rc / (p + rc) if p + rc else 0.0
                entry.update(lvc_pair_precision=p, lvc_pair_recall=rc, lvc_pair_f1=f1)
                fig.add_trace(go.Scatter(x=[rc], y=[p], mode="markers", marker=dict(symbol="star", size=14,
                                                                                   color=run_color(i)),
                                         name=f"{r.label}: frame pairs with the same LVC id (pair P {p:.3f}, "
                                              f"pair R {rc:.3f}, F1 {f1:.3f})"))
                drawn = True
        summary[r.label] = entry
    if drawn:
        fig.update_xaxes(title_text="recall", range=[0, 1.02])
        fig.update_yaxes(title_text="precision", range=[0, 1.02])
        spec.figure = apply_layout(fig, 460, legend=dict(orientation="v", x=1.02, y=1, xanchor="left"))
    return spec, summary
