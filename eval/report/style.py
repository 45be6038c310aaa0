"""What every figure of the report shares: the :class:`FigureSpec` it returns, its id
(:data:`FIGURE_IDS`), colours (of runs and of a map's sessions: :func:`session_groups`),
font, layout, decimation and the display frame.

Display frame: east, north, up (metres), i.e. the NED world frame of ``robot_state``
drawn with z up (up = -depth), so the XY view reads like a map.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import plotly.graph_objects as go

from eval.report.data import RunView
from eval.trajectory import Trajectory

__all__ = ["FigureSpec", "FIGURE_IDS", "TRUTH_COLOR", "DR_COLOR", "RUN_COLORS", "SESSION_COLORS", "SESSION_LINK_COLOR",
           "FONT", "run_color", "session_color", "SessionGroup", "session_groups", "decimate",
           "enu_columns", "distinct_tracks", "track_name", "apply_layout", "no_trajectories"]


#: ids of the figure elements of the page, in page order
FIGURE_IDS = ["fig-overlay-3d", "fig-projections", "fig-topology", "fig-deviation-time", "fig-deviation-xy",
              "fig-similarity", "fig-viewcells", "fig-pr", "fig-evidence"]

TRUTH_COLOR = "#2ca02c"
DR_COLOR = "#ff7f0e"
RUN_COLORS = ["#1f77b4", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
#: map sessions, session 0 first: none is the truth's green, the dead reckoning's orange
#: or the loop closures' red
SESSION_COLORS = ["#1f77b4", "#9467bd", "#17becf", "#8c564b", "#e377c2", "#bcbd22", "#7f7f7f"]
SESSION_LINK_COLOR = "#000000"
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


def run_color(i: int) -> str:
    return RUN_COLORS[i % len(RUN_COLORS)]


def session_color(s: int) -> str:
    return SESSION_COLORS[s % len(SESSION_COLORS)]


@dataclass
class SessionGroup:
    """The nodes of one session of a run's map (indices into ``RunView.node_ids``) and its colour."""

    session: int
    color: str
    index: np.ndarray

    @property
    def name(self) -> str:
        return f"session {self.session}"


def session_groups(view: RunView, run_index: int = 0) -> list[SessionGroup]:
    """The map's nodes by session, oldest first, each in its own colour; a map of one session is
    one group in the run's colour (:func:`run_color`)."""
    if not len(view.node_ids):
        return []
    sess = view.node_session if len(view.node_session) == len(view.node_ids) else \
        np.zeros(len(view.node_ids), dtype=np.int64)
    ids = np.unique(sess).tolist()
    if len(ids) == 1:
        return [SessionGroup(int(ids[0]), run_color(run_index), np.arange(len(sess)))]
    return [SessionGroup(int(s), session_color(int(s)), np.flatnonzero(sess == s)) for s in ids]


def decimate(n: int, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` evenly spaced samples (first and last kept)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def enu_columns(ned: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(east, north, up) float32 columns of NED positions."""
    ned = np.asarray(ned, dtype=np.float32).reshape(-1, 3)
    return ned[:, 1], ned[:, 0], -ned[:, 2]


def _same_track(a: Trajectory, b: Trajectory) -> bool:
    return a.p.shape == b.p.shape and np.array_equal(a.t, b.t) and np.allclose(a.p, b.p)


def distinct_tracks(runs: list[RunView], attr: str) -> list[tuple[int, Trajectory]]:
    """Tracks (truth or dead reckoning) of the runs, each distinct one once."""
    out: list[tuple[int, Trajectory]] = []
    for i, r in enumerate(runs):
        t: Trajectory = getattr(r, attr)
        if len(t) and not any(_same_track(t, o) for _, o in out):
            out.append((i, t))
    return out


def track_name(base: str, runs: list[RunView], i: int, n_distinct: int) -> str:
    return base if n_distinct <= 1 else f"{base} ({runs[i].label})"


def apply_layout(fig: go.Figure, height: int, **kw: Any) -> go.Figure:
    """Common look; the legend goes below the plot, under the x-axis title."""
    bottom = 60
    if "legend" not in kw:
        bottom = 120
        kw["legend"] = dict(orientation="h", yanchor="top", xanchor="left", x=0,
                            y=-75.0 / max(height - 60 - bottom, 100))
    fig.update_layout(height=height, margin=dict(l=60, r=20, t=60, b=bottom), font=FONT, template="plotly_white",
                      showlegend=True, **kw)
    return fig


def no_trajectories(runs: list[RunView]) -> bool:
    return not any(len(r.truth) or len(r.dead_reckoning) or len(r.node_ids) for r in runs)
