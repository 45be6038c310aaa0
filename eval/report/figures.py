"""The figures of the report (Section 5.4 of the dissertation), built with plotly.

Every builder takes the loaded runs (:class:`eval.report.data.RunView`) and returns a
:class:`FigureSpec`: a stable element id (:data:`FIGURE_IDS`), a title, a caption saying
what the figure shows and how to read it, and the plotly figure (or, when the runs lack
the data, a note saying which key is missing).

Display frame: east, north, up (metres), i.e. the NED world frame of ``robot_state``
drawn with z up (up = -depth), so the XY view reads like a map.

Similarity (Figs 5.9-5.10, 5.15-5.18): at most ``max_frames`` frames, evenly spaced.
With ``neocortex/sdr`` the similarity of frames i and j is the overlap of their fused SDRs,
|A_i & A_j| / max(|A_i|, |A_j|) (0-100 %); without it, 100 % when both frames got the same
LVC id.  Ground truth: ``truth/revisits`` (frames matched to camera frames by stamp).
Pairs less than ``min_gap_m`` of true travel apart (the same pass) are left out of the
precision-recall curves, as the simulator leaves them out of the revisit truth.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from eval.report.data import RunView
from eval.trajectory import Trajectory

__all__ = ["FigureSpec", "FIGURE_IDS", "build_figures", "Similarity", "frame_similarity", "precision_recall"]

log = logging.getLogger(__name__)

#: ids of the figure elements of the page, in page order
FIGURE_IDS = ["fig-overlay-3d", "fig-projections", "fig-topology", "fig-deviation-time", "fig-deviation-xy",
              "fig-similarity", "fig-viewcells", "fig-pr", "fig-evidence"]

TRUTH_COLOR = "#2ca02c"
DR_COLOR = "#ff7f0e"
RUN_COLORS = ["#1f77b4", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
FONT = dict(family="Helvetica, Arial, sans-serif", size=13)


@dataclass
class FigureSpec:
    id: str
    title: str
    caption: str
    figure: go.Figure | None = None
    #: non-plotly content (the evidence gallery), already HTML
    html: str = ""
    #: why the figure (or part of it) is not shown
    notes: list[str] = field(default_factory=list)


def _color(i: int) -> str:
    return RUN_COLORS[i % len(RUN_COLORS)]


def _decimate(n: int, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` evenly spaced samples (first and last kept)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def _enu(ned: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(east, north, up) float32 columns of NED positions."""
    ned = np.asarray(ned, dtype=np.float32).reshape(-1, 3)
    return ned[:, 1], ned[:, 0], -ned[:, 2]


def _same_track(a: Trajectory, b: Trajectory) -> bool:
    return a.p.shape == b.p.shape and np.array_equal(a.t, b.t) and np.allclose(a.p, b.p)


def _distinct(runs: list[RunView], attr: str) -> list[tuple[int, Trajectory]]:
    """Tracks (truth or dead reckoning) of the runs, each distinct one once."""
    out: list[tuple[int, Trajectory]] = []
    for i, r in enumerate(runs):
        t: Trajectory = getattr(r, attr)
        if len(t) and not any(_same_track(t, o) for _, o in out):
            out.append((i, t))
    return out


def _track_name(base: str, runs: list[RunView], i: int, n_distinct: int) -> str:
    return base if n_distinct <= 1 else f"{base} ({runs[i].label})"


def _layout(fig: go.Figure, height: int, **kw: Any) -> go.Figure:
    """Common look; the legend goes below the plot, under the x-axis title."""
    bottom = 60
    if "legend" not in kw:
        bottom = 120
        kw["legend"] = dict(orientation="h", yanchor="top", xanchor="left", x=0,
                            y=-75.0 / max(height - 60 - bottom, 100))
    fig.update_layout(height=height, margin=dict(l=60, r=20, t=60, b=bottom), font=FONT, template="plotly_white",
                      showlegend=True, **kw)
    return fig


def _no_trajectories(runs: list[RunView]) -> bool:
    return not any(len(r.truth) or len(r.dead_reckoning) or len(r.node_ids) for r in runs)


# --------------------------------------------------------------------------- trajectories


def fig_overlay_3d(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec(
        "fig-overlay-3d", "3D overlay: ground truth, dead reckoning and map (cf. Fig. 5.19)",
        "Ground truth (green), dead reckoning (orange) and the final experience map of each run (its nodes in "
        "creation order) in metres, east/north/up. Drag to rotate, scroll to zoom, click a legend entry to hide "
        "it. A good map follows the green path more closely than the orange one; where the map jumps, a loop "
        "closure corrected it. Estimates are anchored to the truth at their first sample (shapes are compared, "
        "not the choice of origin).")
    if _no_trajectories(runs):
        spec.notes.append("no trajectory in the runs (keys truth/pose, Odometry, dead_reckoning, map)")
        return spec
    fig = go.Figure()
    truths, drs = _distinct(runs, "truth"), _distinct(runs, "dead_reckoning")
    for i, t in truths:
        k = _decimate(len(t), max_points)
        x, y, z = _enu(t.p[k])
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", line=dict(color=TRUTH_COLOR, width=4),
                                   name=_track_name("ground truth", runs, i, len(truths))))
    for i, t in drs:
        k = _decimate(len(t), max_points)
        x, y, z = _enu(t.p[k])
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", line=dict(color=DR_COLOR, width=3),
                                   name=_track_name("dead reckoning", runs, i, len(drs))))
    for i, r in enumerate(runs):
        if len(r.node_ids) == 0:
            spec.notes.append(f"{r.label}: no map message")
            continue
        k = _decimate(len(r.node_ids), max_points)
        x, y, z = _enu(r.node_ned[k])
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines+markers", line=dict(color=_color(i), width=3),
                                   marker=dict(size=2, color=_color(i)), name=f"map: {r.label}"))
    # true proportions horizontally; the vertical axis at least a quarter of the largest extent, so a
    # mission at nearly constant depth does not collapse into a plane
    pts = np.concatenate([np.stack(_enu(t.p), axis=1) for _, t in truths + drs]
                         + [np.stack(_enu(r.node_ned), axis=1) for r in runs if len(r.node_ids)])
    extent = np.maximum(np.nanmax(pts, axis=0) - np.nanmin(pts, axis=0), 1e-3)
    ratio = extent / extent[:2].max()
    if extent[2] < 0.01:
        spec.notes.append("constant depth: the vertical axis only gives the depth")
    elif ratio[2] < 0.25:
        spec.notes.append(f"vertical scale exaggerated {0.25 / ratio[2]:.1f}x: the depth range ({extent[2]:.2f} m) is "
                          f"small next to the horizontal extent ({extent[:2].max():.1f} m)")
    box = np.array([ratio[0], ratio[1], max(ratio[2], 0.25)])
    # view from the south-west, above; far enough that the whole box fits whatever its proportions
    eye = np.array([-0.6, -0.85, 0.45]) / np.linalg.norm([-0.6, -0.85, 0.45]) * 0.95 * np.linalg.norm(box)
    _layout(fig, 580, scene=dict(aspectmode="manual", aspectratio=dict(x=float(box[0]), y=float(box[1]),
                                                                       z=float(box[2])),
                                 camera=dict(eye=dict(x=float(eye[0]), y=float(eye[1]), z=float(eye[2])),
                                             center=dict(x=0.0, y=0.0, z=-0.12)),
                                 xaxis_title="east (m)", yaxis_title="north (m)", zaxis_title="up (m)"))
    spec.figure = fig
    return spec


def fig_projections(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec(
        "fig-projections", "Planar projections XY, XZ, YZ (cf. Fig. 5.20)",
        "The same trajectories seen from above (XY: east vs north, equal scales), from the south (XZ: east vs "
        "up) and from the west (YZ: north vs up). XY shows horizontal alignment and loop geometry; XZ and YZ "
        "show how the vertical structure differs between dead reckoning and the map. Zoom into one panel by "
        "dragging a box; double-click to reset.")
    if _no_trajectories(runs):
        spec.notes.append("no trajectory in the runs")
        return spec
    fig = make_subplots(rows=1, cols=3, subplot_titles=("XY (top view)", "XZ (side view)", "YZ (side view)"),
                        horizontal_spacing=0.07)
    series: list[tuple[str, str, np.ndarray, str]] = []
    truths, drs = _distinct(runs, "truth"), _distinct(runs, "dead_reckoning")
    series += [(_track_name("ground truth", runs, i, len(truths)), TRUTH_COLOR, t.p, "lines") for i, t in truths]
    series += [(_track_name("dead reckoning", runs, i, len(drs)), DR_COLOR, t.p, "lines") for i, t in drs]
    series += [(f"map: {r.label}", _color(i), r.node_ned, "lines+markers") for i, r in enumerate(runs)
               if len(r.node_ids)]
    for name, color, ned, mode in series:
        k = _decimate(len(ned), max_points)
        e, n, u = _enu(ned[k])
        for col, (a, b) in enumerate(((e, n), (e, u), (n, u)), start=1):
            fig.add_trace(go.Scatter(x=a, y=b, mode=mode, name=name, legendgroup=name, showlegend=col == 1,
                                     line=dict(color=color, width=2), marker=dict(size=3, color=color)),
                          row=1, col=col)
    for col, (xt, yt) in enumerate((("east (m)", "north (m)"), ("east (m)", "up (m)"), ("north (m)", "up (m)")),
                                   start=1):
        fig.update_xaxes(title_text=xt, row=1, col=col)
        fig.update_yaxes(title_text=yt, row=1, col=col)
    fig.update_yaxes(scaleanchor="x", scaleratio=1, row=1, col=1)
    spec.figure = _layout(fig, 480)
    return spec


def _segments(ned: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """East/north arrays of line segments separated by NaN gaps."""
    e, n, _ = _enu(ned)
    xs = np.full(len(pairs) * 3, np.nan, dtype=np.float32)
    ys = np.full(len(pairs) * 3, np.nan, dtype=np.float32)
    xs[0::3], xs[1::3] = e[pairs[:, 0]], e[pairs[:, 1]]
    ys[0::3], ys[1::3] = n[pairs[:, 0]], n[pairs[:, 1]]
    return xs, ys


def fig_topology(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec(
        "fig-topology", "Final topology of each run (cf. Fig. 5.21)",
        "The final experience map seen from above, one panel per run (VPR Guard ON and OFF side by side when "
        "two runs are given): nodes (dots), odometry links (grey) and loop-closure links (thick red; hover one "
        "for the true distance between the two places it joins: a loop closure between places more than 5 m "
        "apart is false, Tables 5.2-5.3). Ground truth (green) and dead reckoning (orange) are drawn faintly "
        "for reference. A denser trace means more experiences (events) were created.")
    mapped = [(i, r) for i, r in enumerate(runs) if len(r.node_ids)]
    for r in runs:
        if not len(r.node_ids):
            spec.notes.append(f"{r.label}: no map message, no topology")
    if not mapped:
        return spec
    cols = min(len(mapped), 3)
    rows = (len(mapped) + cols - 1) // cols
    titles = []
    for _, r in mapped:
        titles.append(f"{r.label}: {len(r.node_ids)} nodes, {len(r.links)} links, "
                      f"{int(r.link_loop.sum())} loop closures")
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=titles, horizontal_spacing=0.06, vertical_spacing=0.12)
    for slot, (i, r) in enumerate(mapped):
        row, col = slot // cols + 1, slot % cols + 1
        first = slot == 0
        for t, color, name in ((r.truth, TRUTH_COLOR, "ground truth"), (r.dead_reckoning, DR_COLOR, "dead reckoning")):
            if len(t):
                k = _decimate(len(t), max_points)
                e, n, _ = _enu(t.p[k])
                fig.add_trace(go.Scatter(x=e, y=n, mode="lines", name=name, legendgroup=name, showlegend=first,
                                         opacity=0.35, line=dict(color=color, width=1.5)), row=row, col=col)
        index = {int(nid): j for j, nid in enumerate(r.node_ids)}
        known = np.array([a in index and b in index for a, b in r.links.tolist()], dtype=bool)
        if len(r.links) and not known.all():
            spec.notes.append(f"{r.label}: {int((~known).sum())} links name nodes absent from the map, not drawn")
        pairs = np.array([[index[a], index[b]] for a, b in r.links[known].tolist()], dtype=np.int64).reshape(-1, 2)
        loop = r.link_loop[known]
        odo = pairs[~loop]
        if len(odo) > max_points:
            odo = odo[_decimate(len(odo), max_points)]
        if len(odo):
            xs, ys = _segments(r.node_ned, odo)
            fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", name="odometry link", legendgroup="odometry link",
                                     showlegend=first, hoverinfo="skip", line=dict(color="#888888", width=1)),
                          row=row, col=col)
        k = _decimate(len(r.node_ids), max_points)
        e, n, _ = _enu(r.node_ned[k])
        fig.add_trace(go.Scatter(x=e, y=n, mode="markers", name=f"nodes: {r.label}", marker=dict(size=4, color=_color(i)),
                                 customdata=np.stack([r.node_ids[k], r.node_lvc[k]], axis=1),
                                 hovertemplate="node %{customdata[0]} (LVC %{customdata[1]})<extra></extra>"),
                      row=row, col=col)
        lc = pairs[loop]
        if len(lc):
            xs, ys = _segments(r.node_ned, lc)
            fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", name="loop-closure link", legendgroup="loop closure",
                                     showlegend=True if first else False, hoverinfo="skip",
                                     line=dict(color="#d62728", width=4)), row=row, col=col)
            truth_a = r.truth.positions_within(r.node_stamps[lc[:, 0]])
            truth_b = r.truth.positions_within(r.node_stamps[lc[:, 1]])
            d_gt = np.linalg.norm(truth_a - truth_b, axis=1)
            mid_e = (xs[0::3] + xs[1::3]) / 2
            mid_n = (ys[0::3] + ys[1::3]) / 2
            text = [f"loop closure node {r.node_ids[a]} - node {r.node_ids[b]}<br>"
                    + (f"true distance d_gt = {d:.2f} m" if np.isfinite(d) else "no ground truth at these stamps")
                    for (a, b), d in zip(lc.tolist(), d_gt)]
            fig.add_trace(go.Scatter(x=mid_e, y=mid_n, mode="markers", name="loop closure (hover)",
                                     legendgroup="loop closure", showlegend=False, text=text,
                                     hovertemplate="%{text}<extra></extra>",
                                     marker=dict(size=9, color="#d62728", symbol="diamond")), row=row, col=col)
        axis = "" if slot == 0 else str(slot + 1)
        fig.update_xaxes(title_text="east (m)", row=row, col=col)
        fig.update_yaxes(title_text="north (m)", scaleanchor=f"x{axis}", scaleratio=1, row=row, col=col)
    spec.figure = _layout(fig, 460 * rows)
    return spec


def _deviation(est: Trajectory, truth: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps, distance to truth in m, truth NED) where truth covers the estimate."""
    ref = truth.positions_within(est.t)
    ok = ~np.isnan(ref).any(axis=1)
    return est.t[ok], np.linalg.norm(est.p[ok] - ref[ok], axis=1), ref[ok]


def _deviation_series(runs: list[RunView]) -> list[tuple[str, str, RunView, np.ndarray, np.ndarray, np.ndarray]]:
    out = []
    drs = _distinct(runs, "dead_reckoning")
    for i, t in drs:
        if len(runs[i].truth):
            out.append((_track_name("dead reckoning", runs, i, len(drs)), DR_COLOR, runs[i],
                        *_deviation(t, runs[i].truth)))
    for i, r in enumerate(runs):
        if len(r.node_ids) and len(r.truth):
            order = np.argsort(r.node_stamps, kind="stable")
            out.append((f"map: {r.label}", _color(i), r,
                        *_deviation(Trajectory(r.node_stamps[order], r.node_ned[order], source="map"), r.truth)))
    return [s for s in out if len(s[3])]


def fig_deviation_time(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec(
        "fig-deviation-time", "Deviation from ground truth over time (cf. Fig. 5.24)",
        "Distance (m) between each estimate and the ground-truth position at the same event time: dead "
        "reckoning at every odometry sample, the final map at every node's stamp. Unlike the dissertation's "
        "proxy this is time-aligned. Dead reckoning drifts as time goes on; a map whose curve stays below the "
        "orange one is better than dead reckoning, and drops show loop closures pulling the map back.")
    series = _deviation_series(runs)
    if not series:
        spec.notes.append("needs truth/pose and Odometry/dead_reckoning or map in the same run")
        return spec
    fig = go.Figure()
    for name, color, r, st, d, _ in series:
        k = _decimate(len(st), max_points)
        fig.add_trace(go.Scatter(x=r.seconds(st[k]).astype(np.float32), y=d[k].astype(np.float32),
                                 mode="lines", name=f"{name} (mean {d.mean():.2f} m, max {d.max():.2f} m)",
                                 line=dict(color=color, width=2)))
    fig.update_xaxes(title_text="time since the start of the run (s)")
    fig.update_yaxes(title_text="distance to ground truth (m)", rangemode="tozero")
    spec.figure = _layout(fig, 420)
    return spec


def fig_deviation_xy(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec(
        "fig-deviation-xy", "Where the deviation occurs, on the XY plane (cf. Fig. 5.25)",
        "One panel per estimate: the true positions (top view, east vs north) coloured by the estimate's "
        "distance to the truth there (same colour scale in every panel, metres). Bright regions are where the "
        "estimate is worst; compare the dead-reckoning panel with the map panels.")
    series = _deviation_series(runs)
    if not series:
        spec.notes.append("needs truth/pose and Odometry/dead_reckoning or map in the same run")
        return spec
    cols = min(len(series), 3)
    rows = (len(series) + cols - 1) // cols
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=[s[0] for s in series], horizontal_spacing=0.06,
                        vertical_spacing=0.12)
    vmax = float(max(s[4].max() for s in series))
    for slot, (name, _color_, _r, _st, d, ref) in enumerate(series):
        row, col = slot // cols + 1, slot % cols + 1
        k = _decimate(len(d), max_points)
        e, n, _ = _enu(ref[k])
        fig.add_trace(go.Scatter(x=e, y=n, mode="markers", name=name, showlegend=False,
                                 marker=dict(size=5, color=d[k].astype(np.float32), coloraxis="coloraxis"),
                                 hovertemplate="deviation %{marker.color:.2f} m<extra></extra>"), row=row, col=col)
        axis = "" if slot == 0 else str(slot + 1)
        fig.update_xaxes(title_text="east (m)", row=row, col=col)
        fig.update_yaxes(title_text="north (m)", scaleanchor=f"x{axis}", scaleratio=1, row=row, col=col)
    fig.update_layout(coloraxis=dict(colorscale="Viridis", cmin=0.0, cmax=max(vmax, 1e-6),
                                     colorbar=dict(title="m")))
    spec.figure = _layout(fig, 420 * rows)
    return spec


# --------------------------------------------------------------------------- place recognition


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
        k = _decimate(len(run.sdr_stamps), max_frames)
        stamps = run.sdr_stamps[k]
        active = [run.sdr_active[j] for j in k]
        bits, inverse = np.unique(np.concatenate(active), return_inverse=True) if active else (np.zeros(0), None)
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
        k = _decimate(len(run.lvc_stamps), max_frames)
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


def _similarities(runs: list[RunView], max_frames: int, min_gap_m: float) -> list[tuple[int, Similarity | None]]:
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
    titles = []
    for i, sim in shown:
        sub = f"{len(sim.stamps)} of {sim.frame_total} frames" if len(sim.stamps) < sim.frame_total else \
            f"{sim.frame_total} frames"
        titles += [f"{runs[i].label}: {sim.source} ({sub})", "ground truth: same place"]
    fig = make_subplots(rows=len(shown), cols=2, subplot_titles=titles, horizontal_spacing=0.08,
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
        for col in (1, 2):
            fig.update_xaxes(title_text="time (s)", row=row, col=col)
            fig.update_yaxes(title_text="time (s)", autorange="reversed", row=row, col=col)
    # colour range from the off-diagonal values (1st to 99.9th percentile): a dense SDR's chance overlap is far
    # above 0 %, and a 0-100 scale would wash the structure out
    off = np.concatenate([sim.percent[~np.eye(len(sim.stamps), dtype=bool)] for _, sim in shown])
    lo, hi = (float(np.percentile(off, 1)), float(np.percentile(off, 99.9))) if len(off) else (0.0, 100.0)
    if hi <= lo:
        lo, hi = 0.0, 100.0
    spec.notes.append(f"colour scale {lo:.0f}-{hi:.0f} % (1st-99.9th percentile of the off-diagonal similarity)")
    fig.update_layout(coloraxis=dict(colorscale="Viridis", cmin=lo, cmax=hi,
                                     colorbar=dict(title="%", len=1.0 / len(shown), y=1.0, yanchor="top")))
    spec.figure = _layout(fig, 520 * len(shown))
    return spec


def _revisit_frames(r: RunView, min_gap_m: float) -> np.ndarray:
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
    return ~r.lvc_new & (gap >= limit)


def fig_viewcells(runs: list[RunView], max_points: int, min_gap_m: float = 10.0) -> FigureSpec:
    spec = FigureSpec(
        "fig-viewcells", "View cells over time: creation and recognition (cf. Figs 5.11-5.12)",
        "One panel per run. Each frame's local view cell (LVC) id against time: blue crosses are frames that "
        "created a new cell (a place not seen before); grey dots matched a cell created moments before (the same "
        "pass over a place); red circles matched a cell created at least the minimum travel earlier (a place "
        "recognised again, a loop-closure candidate); black diamonds are loop closures the experience map "
        "accepted. A rising staircase is exploration; red circles at low ids late in the run are revisits of "
        "early places (compare with the ground-truth matrix above).")
    with_lvc = [(i, r) for i, r in enumerate(runs) if len(r.lvc_stamps)]
    for r in runs:
        if not len(r.lvc_stamps):
            spec.notes.append(f"{r.label}: no local_view_cells")
    if not with_lvc:
        return spec
    titles = [f"{r.label}: {len(np.unique(r.lvc_id))} view cells, {int(_revisit_frames(r, min_gap_m).sum())} frames "
              f"recognised after >= {min_gap_m:g} m, {int(r.link_loop.sum())} map loop closures" for _, r in with_lvc]
    fig = make_subplots(rows=len(with_lvc), cols=1, subplot_titles=titles, shared_xaxes=False,
                        vertical_spacing=0.12 if len(with_lvc) > 1 else 0.1)
    for row, (i, r) in enumerate(with_lvc, start=1):
        t = r.seconds(r.lvc_stamps).astype(np.float32)
        revisit = _revisit_frames(r, min_gap_m)
        same_pass = ~r.lvc_new & ~revisit
        for mask, name, marker in ((same_pass, "matched a cell of the same pass",
                                    dict(symbol="circle", size=3, color="#bbbbbb")),
                                   (r.lvc_new, "new view cell", dict(symbol="x-thin", size=6, color="#1f77b4",
                                                                     line=dict(width=1.5, color="#1f77b4"))),
                                   (revisit, f"recognised a cell from >= {min_gap_m:g} m of travel earlier",
                                    dict(symbol="circle-open", size=8, color="#d62728", line=dict(width=1.5)))):
            idx = np.flatnonzero(mask)
            idx = idx[_decimate(len(idx), max_points)]
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
    spec.figure = _layout(fig, 380 * len(with_lvc))
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
        twin = next((j for j, o in shown if _same_similarity(o, sim) and np.array_equal(o.truth, sim.truth)
                     and np.array_equal(o.lvc, sim.lvc)), None)
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
                                     mode="lines", line=dict(color=_color(i), width=2), customdata=pr["thresholds"],
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
                                                                                   color=_color(i)),
                                         name=f"{r.label}: frame pairs with the same LVC id (pair P {p:.3f}, "
                                              f"pair R {rc:.3f}, F1 {f1:.3f})"))
                drawn = True
        summary[r.label] = entry
    if drawn:
        fig.update_xaxes(title_text="recall", range=[0, 1.02])
        fig.update_yaxes(title_text="precision", range=[0, 1.02])
        spec.figure = _layout(fig, 460, legend=dict(orientation="v", x=1.02, y=1, xanchor="left"))
    return spec, summary


def fig_evidence(runs: list[RunView]) -> FigureSpec:
    import html as _html
    spec = FigureSpec(
        "fig-evidence", "Evidence: camera frames stored with experience events",
        "A few experience_image frames, evenly spaced over each run: the camera frame stored as evidence of an "
        "accepted experience event (the audit associates every event with one of these). Caption: time since the "
        "start of the run and the event's LVC id.")
    parts = []
    for i, r in enumerate(runs):
        if not r.images:
            spec.notes.append(f"{r.label}: no experience_image")
            continue
        cells = []
        for j, (stamp, lvc, uri, size) in enumerate(r.images):
            lvc_txt = f"LVC {lvc}" if lvc >= 0 else "no matching event"
            cells.append(f'<figure class="thumb"><img id="evidence-{i}-{j}" src="{uri}" alt="experience image at '
                         f'{r.seconds(np.array([stamp]))[0]:.1f} s"><figcaption>{r.seconds(np.array([stamp]))[0]:.1f} s'
                         f' &middot; {lvc_txt} &middot; {size}</figcaption></figure>')
        parts.append(f'<h4>{_html.escape(r.label)}: {len(r.images)} of {r.image_count} images</h4>'
                     f'<div class="gallery">{"".join(cells)}</div>')
    spec.html = "".join(parts)
    return spec


def build_figures(runs: list[RunView], max_points: int = 3000, max_frames: int = 500,
                  min_gap_m: float = 10.0) -> tuple[list[FigureSpec], dict[str, Any]]:
    """Every figure of the page, in :data:`FIGURE_IDS` order, and the PR summary per run."""
    sims = _similarities(runs, max_frames, min_gap_m)
    pr_spec, pr_summary = fig_pr(runs, sims)
    specs = [fig_overlay_3d(runs, max_points), fig_projections(runs, max_points), fig_topology(runs, max_points),
             fig_deviation_time(runs, max_points), fig_deviation_xy(runs, max_points), fig_similarity(runs, sims),
             fig_viewcells(runs, max_points, min_gap_m), pr_spec, fig_evidence(runs)]
    assert [s.id for s in specs] == FIGURE_IDS
    return specs, pr_summary
