"""The trajectory figures of the report (Figs 5.19-5.21, 5.24-5.25 of the dissertation):
3D overlay, planar projections, final topology, deviation from ground truth over time and
on the XY plane.  Each builder takes the runs' :class:`eval.report.data.RunView` and
returns a :class:`eval.report.style.FigureSpec` (display frame: east, north, up, metres).
"""
from __future__ import annotations

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from eval.report.data import RunView
from eval.report.style import (
    DR_COLOR,
    SESSION_LINK_COLOR,
    TRUTH_COLOR,
    FigureSpec,
    SessionGroup,
    apply_layout,
    decimate,
    distinct_tracks,
    enu_columns,
    no_trajectories,
    run_color,
    session_groups,
    track_name,
)
from eval.trajectory import Trajectory

__all__ = ["fig_overlay_3d", "fig_projections", "fig_topology", "fig_deviation_time", "fig_deviation_xy", "PLANAR_M"]

#: a run whose trajectories span less than this vertically is planar: no 3D view, no side views (m)
PLANAR_M = 0.01


def _map_points(r: RunView, max_points: int) -> np.ndarray:
    """The map's nodes (decimated, creation order) as one line; a map of several sessions gets a
    gap (NaN row) where one session ends and the next begins (two odometry frames, no move)."""
    k = decimate(len(r.node_ids), max_points)
    p: np.ndarray = r.node_ned[k]
    if len(r.node_session) != len(r.node_ids):
        return p
    s = r.node_session[k]
    breaks = np.flatnonzero(s[1:] != s[:-1]) + 1
    return np.insert(p, breaks, np.nan, axis=0) if len(breaks) else p


def fig_overlay_3d(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec(
        "fig-overlay-3d", "3D overlay: ground truth, dead reckoning and map (cf. Fig. 5.19)",
        "Ground truth (green), dead reckoning (orange) and the final experience map of each run (its nodes in "
        "creation order) in metres, east/north/up. Drag to rotate, scroll to zoom, click a legend entry to hide "
        "it. A good map follows the green path more closely than the orange one; where the map jumps, a loop "
        "closure corrected it. Estimates are anchored to the truth at their first sample (shapes are compared, "
        "not the choice of origin).")
    if not any(len(r.truth) for r in runs):
        spec.title = "3D view: dead reckoning and map (cf. Fig. 5.19)"
        spec.caption = ("Dead reckoning (orange) and the final experience map of each run (its nodes in creation "
                        "order) in metres, east/north/up. Drag to rotate, scroll to zoom, click a legend entry to "
                        "hide it. Where the map leaves the dead reckoning, a loop closure corrected it.")
    if no_trajectories(runs):
        spec.notes.append("no trajectory in the runs (keys truth/pose, Odometry, dead_reckoning, map)")
        return spec
    fig = go.Figure()
    truths, drs = distinct_tracks(runs, "truth"), distinct_tracks(runs, "dead_reckoning")
    for i, t in truths:
        k = decimate(len(t), max_points)
        x, y, z = enu_columns(t.p[k])
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", line=dict(color=TRUTH_COLOR, width=4),
                                   name=track_name("ground truth", runs, i, len(truths))))
    for i, t in drs:
        k = decimate(len(t), max_points)
        x, y, z = enu_columns(t.p[k])
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines", line=dict(color=DR_COLOR, width=3),
                                   name=track_name("dead reckoning", runs, i, len(drs))))
    for i, r in enumerate(runs):
        if len(r.node_ids) == 0:
            spec.notes.append(f"{r.label}: no map message")
            continue
        x, y, z = enu_columns(_map_points(r, max_points))
        fig.add_trace(go.Scatter3d(x=x, y=y, z=z, mode="lines+markers", line=dict(color=run_color(i), width=3),
                                   marker=dict(size=2, color=run_color(i)), name=f"map: {r.label}"))
    # true proportions horizontally; the vertical axis at least a quarter of the largest extent, so a
    # mission at nearly constant depth does not collapse into a plane
    pts = np.concatenate([np.stack(enu_columns(t.p), axis=1) for _, t in truths + drs]
                         + [np.stack(enu_columns(r.node_ned), axis=1) for r in runs if len(r.node_ids)])
    extent = np.maximum(np.nanmax(pts, axis=0) - np.nanmin(pts, axis=0), 1e-3)
    ratio = extent / extent[:2].max()
    if extent[2] < PLANAR_M:
        spec.notes.append("every trajectory at one depth (a planar run): the top views show it all")
        return spec
    if ratio[2] < 0.25:
        spec.notes.append(f"vertical scale exaggerated {0.25 / ratio[2]:.1f}x: the depth range ({extent[2]:.2f} m) is "
                          f"small next to the horizontal extent ({extent[:2].max():.1f} m)")
    box = np.array([ratio[0], ratio[1], max(ratio[2], 0.25)])
    # view from the south-west, above; far enough that the whole box fits whatever its proportions
    eye = np.array([-0.6, -0.85, 0.45]) / np.linalg.norm([-0.6, -0.85, 0.45]) * 0.95 * np.linalg.norm(box)
    apply_layout(fig, 580, scene=dict(aspectmode="manual", aspectratio=dict(x=float(box[0]), y=float(box[1]),
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
    if no_trajectories(runs):
        spec.notes.append("no trajectory in the runs")
        return spec
    series: list[tuple[str, str, np.ndarray, str]] = []
    truths, drs = distinct_tracks(runs, "truth"), distinct_tracks(runs, "dead_reckoning")
    series += [(track_name("ground truth", runs, i, len(truths)), TRUTH_COLOR, t.p[decimate(len(t), max_points)],
                "lines") for i, t in truths]
    series += [(track_name("dead reckoning", runs, i, len(drs)), DR_COLOR, t.p[decimate(len(t), max_points)],
                "lines") for i, t in drs]
    series += [(f"map: {r.label}", run_color(i), _map_points(r, max_points), "lines+markers")
               for i, r in enumerate(runs) if len(r.node_ids)]
    up = np.concatenate([enu_columns(ned)[2] for _, _, ned, _ in series])
    planar = not len(up) or float(np.nanmax(up) - np.nanmin(up)) < PLANAR_M
    panels = [("XY (top view)", "east (m)", "north (m)"), ("XZ (side view)", "east (m)", "up (m)"),
              ("YZ (side view)", "north (m)", "up (m)")][:1 if planar else 3]
    if planar:
        spec.title = "Top view (XY)"
        spec.caption = ("The trajectories seen from above (east vs north, equal scales): horizontal alignment and "
                        "loop geometry. Every trajectory is at one depth (a planar run): no side views. Zoom by "
                        "dragging a box; double-click to reset.")
    fig = make_subplots(rows=1, cols=len(panels), subplot_titles=[p[0] for p in panels], horizontal_spacing=0.07)
    for name, color, ned, mode in series:
        e, n, u = enu_columns(ned)
        for col, (a, b) in enumerate(((e, n), (e, u), (n, u))[:len(panels)], start=1):
            fig.add_trace(go.Scatter(x=a, y=b, mode=mode, name=name, legendgroup=name, showlegend=col == 1,
                                     line=dict(color=color, width=2), marker=dict(size=3, color=color)),
                          row=1, col=col)
    for col, (_, xt, yt) in enumerate(panels, start=1):
        fig.update_xaxes(title_text=xt, row=1, col=col)
        fig.update_yaxes(title_text=yt, row=1, col=col)
    fig.update_yaxes(scaleanchor="x", scaleratio=1, row=1, col=1)
    spec.figure = apply_layout(fig, 600 if planar else 480)
    return spec


def _segments(ned: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """East/north arrays of line segments separated by NaN gaps."""
    e, n, _ = enu_columns(ned)
    xs = np.full(len(pairs) * 3, np.nan, dtype=np.float32)
    ys = np.full(len(pairs) * 3, np.nan, dtype=np.float32)
    xs[0::3], xs[1::3] = e[pairs[:, 0]], e[pairs[:, 1]]
    ys[0::3], ys[1::3] = n[pairs[:, 0]], n[pairs[:, 1]]
    return xs, ys


def _draw_one_session(fig: go.Figure, r: RunView, i: int, odo: np.ndarray, max_points: int, first: bool,
                      row: int, col: int) -> None:
    """Odometry links (grey) and nodes (the run's colour) of a map of one session."""
    if len(odo) > max_points:
        odo = odo[decimate(len(odo), max_points)]
    if len(odo):
        xs, ys = _segments(r.node_ned, odo)
        fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", name="odometry link", legendgroup="odometry link",
                                 showlegend=first, hoverinfo="skip", line=dict(color="#888888", width=1)),
                      row=row, col=col)
    k = decimate(len(r.node_ids), max_points)
    e, n, _ = enu_columns(r.node_ned[k])
    fig.add_trace(go.Scatter(x=e, y=n, mode="markers", name=f"nodes: {r.label}",
                             marker=dict(size=4, color=run_color(i)),
                             customdata=np.stack([r.node_ids[k], r.node_lvc[k]], axis=1),
                             hovertemplate="node %{customdata[0]} (LVC %{customdata[1]})<extra></extra>"),
                  row=row, col=col)


def _draw_sessions(fig: go.Figure, r: RunView, groups: list[SessionGroup], pairs: np.ndarray, loop: np.ndarray,
                   max_points: int, row: int, col: int, several_runs: bool) -> np.ndarray:
    """Nodes and odometry links of each session in its colour, the session links (black dashed);
    returns the loop-closure mask of ``pairs`` without the session links (drawn here)."""
    sess = np.zeros(len(r.node_ids), dtype=np.int64)
    for g in groups:
        sess[g.index] = g.session
    index = {int(nid): j for j, nid in enumerate(r.node_ids)}
    wanted = {frozenset((index[a], index[b])) for a, b in r.session_links.tolist() if a in index and b in index}
    is_link = np.array([frozenset(p) in wanted for p in pairs.tolist()], dtype=bool)
    budget = max(1, max_points // len(groups))
    for g in groups:
        name = g.name if not several_runs else f"{g.name}: {r.label}"
        odo = pairs[~loop & (sess[pairs[:, 0]] == g.session) & (sess[pairs[:, 1]] == g.session)] \
            if len(pairs) else pairs
        if len(odo) > budget:
            odo = odo[decimate(len(odo), budget)]
        if len(odo):
            xs, ys = _segments(r.node_ned, odo)
            fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", name=f"{name} odometry link", legendgroup=name,
                                     showlegend=False, hoverinfo="skip", opacity=0.6,
                                     line=dict(color=g.color, width=1)), row=row, col=col)
        k = g.index[decimate(len(g.index), budget)]
        e, n, _ = enu_columns(r.node_ned[k])
        fig.add_trace(go.Scatter(x=e, y=n, mode="markers", name=name, legendgroup=name,
                                 marker=dict(size=4, color=g.color),
                                 customdata=np.stack([r.node_ids[k], r.node_lvc[k], sess[k]], axis=1),
                                 hovertemplate="node %{customdata[0]} (LVC %{customdata[1]}, session "
                                               "%{customdata[2]})<extra></extra>"),
                      row=row, col=col)
    sl = pairs[is_link] if len(pairs) else pairs
    if len(sl):
        xs, ys = _segments(r.node_ned, sl)
        text = [f"session link node {r.node_ids[a]} (session {sess[a]}) - node {r.node_ids[b]} (session {sess[b]})"
                for a, b in sl.tolist()]
        fig.add_trace(go.Scatter(x=xs, y=ys, mode="lines", name="session link", legendgroup="session link",
                                 hoverinfo="skip", line=dict(color=SESSION_LINK_COLOR, width=4, dash="dash")),
                      row=row, col=col)
        fig.add_trace(go.Scatter(x=(xs[0::3] + xs[1::3]) / 2, y=(ys[0::3] + ys[1::3]) / 2, mode="markers",
                                 name="session link (hover)", legendgroup="session link", showlegend=False,
                                 text=text, hovertemplate="%{text}<extra></extra>",
                                 marker=dict(size=11, color=SESSION_LINK_COLOR, symbol="star")), row=row, col=col)
    return np.asarray(loop & ~is_link, dtype=bool) if len(pairs) else loop


def _topology_caption(runs: list[RunView]) -> str:
    """The topology's caption, saying only what the runs draw."""
    truth = any(len(r.truth) for r in runs)
    refs = [w for w, on in (("ground truth (green)", truth), ("dead reckoning (orange)",
                                                             any(len(r.dead_reckoning) for r in runs))) if on]
    parts = [f"The final experience map seen from above{', one panel per run' if len(runs) > 1 else ''}: "
             "nodes (dots), odometry links (grey) and loop-closure links (thick red; hover one for "
             + ("the true distance between the two places it joins: a loop closure between places more than 5 m "
                "apart is false, Tables 5.2-5.3)." if truth else "the two experiences it joins).")]
    if refs:
        parts.append(f"{' and '.join(refs).capitalize()} drawn faintly for reference.")
    parts.append("A denser trace means more experiences (events) were created.")
    if any(len(np.unique(r.node_session)) > 1 for r in runs):
        parts.append("A map of several sessions (missions continued with poseidon run --map-dir) draws each "
                     "session's nodes and odometry links in its own colour (legend: session 0, session 1, ...; the "
                     "chain edge between two sessions joins two odometry frames and is not drawn) and its "
                     "sonar-verified session links as thick black dashed lines (hover one for the link).")
    return " ".join(parts)


def fig_topology(runs: list[RunView], max_points: int) -> FigureSpec:
    spec = FigureSpec("fig-topology", "Final topology of each run (cf. Fig. 5.21)" if len(runs) > 1 else
                      "Final topology: the experience map (cf. Fig. 5.21)", _topology_caption(runs))
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
        n_sess = len(session_groups(r))
        titles.append(f"{r.label}: {len(r.node_ids)} nodes, {len(r.links)} links, "
                      f"{int(r.link_loop.sum())} loop closures"
                      + (f", {n_sess} sessions, {len(r.session_links)} session links" if n_sess > 1 else ""))
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=titles, horizontal_spacing=0.06, vertical_spacing=0.12)
    for slot, (i, r) in enumerate(mapped):
        row, col = slot // cols + 1, slot % cols + 1
        first = slot == 0
        for t, color, name in ((r.truth, TRUTH_COLOR, "ground truth"), (r.dead_reckoning, DR_COLOR, "dead reckoning")):
            if len(t):
                k = decimate(len(t), max_points)
                e, n, _ = enu_columns(t.p[k])
                fig.add_trace(go.Scatter(x=e, y=n, mode="lines", name=name, legendgroup=name, showlegend=first,
                                         opacity=0.35, line=dict(color=color, width=1.5)), row=row, col=col)
        index = {int(nid): j for j, nid in enumerate(r.node_ids)}
        known = np.array([a in index and b in index for a, b in r.links.tolist()], dtype=bool)
        if len(r.links) and not known.all():
            spec.notes.append(f"{r.label}: {int((~known).sum())} links name nodes absent from the map, not drawn")
        pairs = np.array([[index[a], index[b]] for a, b in r.links[known].tolist()], dtype=np.int64).reshape(-1, 2)
        loop = r.link_loop[known]
        groups = session_groups(r, i)
        if len(groups) > 1:
            loop = _draw_sessions(fig, r, groups, pairs, loop, max_points, row, col, len(mapped) > 1)
        else:
            _draw_one_session(fig, r, i, pairs[~loop], max_points, first, row, col)
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
    spec.figure = apply_layout(fig, 460 * rows)
    return spec


def _deviation(est: Trajectory, truth: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps, distance to truth in m, truth NED) where truth covers the estimate."""
    ref = truth.positions_within(est.t)
    ok = ~np.isnan(ref).any(axis=1)
    return est.t[ok], np.linalg.norm(est.p[ok] - ref[ok], axis=1), ref[ok]


def _deviation_series(runs: list[RunView]) -> list[tuple[str, str, RunView, np.ndarray, np.ndarray, np.ndarray]]:
    out = []
    drs = distinct_tracks(runs, "dead_reckoning")
    for i, t in drs:
        if len(runs[i].truth):
            out.append((track_name("dead reckoning", runs, i, len(drs)), DR_COLOR, runs[i],
                        *_deviation(t, runs[i].truth)))
    for i, r in enumerate(runs):
        if len(r.node_ids) and len(r.truth):
            order = np.argsort(r.node_stamps, kind="stable")
            out.append((f"map: {r.label}", run_color(i), r,
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
        k = decimate(len(st), max_points)
        fig.add_trace(go.Scatter(x=r.seconds(st[k]).astype(np.float32), y=d[k].astype(np.float32),
                                 mode="lines", name=f"{name} (mean {d.mean():.2f} m, max {d.max():.2f} m)",
                                 line=dict(color=color, width=2)))
    fig.update_xaxes(title_text="time since the start of the run (s)")
    fig.update_yaxes(title_text="distance to ground truth (m)", rangemode="tozero")
    spec.figure = apply_layout(fig, 420)
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
    for slot, (name, _color, _r, _st, d, ref) in enumerate(series):
        row, col = slot // cols + 1, slot % cols + 1
        k = decimate(len(d), max_points)
        e, n, _ = enu_columns(ref[k])
        fig.add_trace(go.Scatter(x=e, y=n, mode="markers", name=name, showlegend=False,
                                 marker=dict(size=5, color=d[k].astype(np.float32), coloraxis="coloraxis"),
                                 hovertemplate="deviation %{marker.color:.2f} m<extra></extra>"), row=row, col=col)
        axis = "" if slot == 0 else str(slot + 1)
        fig.update_xaxes(title_text="east (m)", row=row, col=col)
        fig.update_yaxes(title_text="north (m)", scaleanchor=f"x{axis}", scaleratio=1, row=row, col=col)
    fig.update_layout(coloraxis=dict(colorscale="Viridis", cmin=0.0, cmax=max(vmax, 1e-6),
                                     colorbar=dict(title="m")))
    spec.figure = apply_layout(fig, 420 * rows)
    return spec
