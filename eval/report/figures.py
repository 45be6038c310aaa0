"""The figures of the report (Section 5.4 of the dissertation), built with plotly.

Every builder takes the runs' :class:`eval.report.data.RunView` and returns a
:class:`FigureSpec`: a stable element id (:data:`FIGURE_IDS`), a title, a caption saying
what the figure shows and how to read it, and the plotly figure (or, when the runs lack
the data, a note saying which key is missing).  The trajectory figures are in
:mod:`eval.report.fig_trajectories`, the place-recognition ones (and the similarity
definition) in :mod:`eval.report.fig_recognition`, what they share in
:mod:`eval.report.style`; the evidence gallery and :func:`build_figures` are here.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from eval.report.data import RunView
from eval.report.fig_recognition import (
    Similarity,
    fig_pr,
    fig_similarity,
    fig_viewcells,
    frame_similarity,
    precision_recall,
    similarities,
)
from eval.report.fig_trajectories import (
    fig_deviation_time,
    fig_deviation_xy,
    fig_overlay_3d,
    fig_projections,
    fig_topology,
)
from eval.report.style import FIGURE_IDS, FigureSpec

__all__ = ["FigureSpec", "FIGURE_IDS", "build_figures", "Similarity", "frame_similarity",
           "precision_recall"]


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
    sims = similarities(runs, max_frames, min_gap_m)
    pr_spec, pr_summary = fig_pr(runs, sims)
    specs = [fig_overlay_3d(runs, max_points), fig_projections(runs, max_points), fig_topology(runs, max_points),
             fig_deviation_time(runs, max_points), fig_deviation_xy(runs, max_points), fig_similarity(runs, sims),
             fig_viewcells(runs, max_points, min_gap_m), pr_spec, fig_evidence(runs)]
    assert [s.id for s in specs] == FIGURE_IDS
    return specs, pr_summary
