"""The Freiburg-benchmark section of ``poseidon report RUN --relations FILE --out DIR``.

For a run on a real robot log (a CARMEN import, :mod:`missions.importers.carmen`, run
through the services) the page gets a section "Benchmark (laser maps, loop closures,
relations)":

- ``fig-scan-maps``: the laser scans (key ``scan``) drawn as a point map twice, side by
  side: at the final map's corrected poses (the trajectory of :func:`eval.corrected.map_corrected`,
  the one ``poseidon export --tum`` writes, interpolated at each scan stamp) and at the raw
  odometry poses (``wheel_odometry`` when present, else ``Odometry``).  Beam i of a scan
  points at ``angle_min + i * angle_increment`` in the laser frame; the laser sits at the
  offset the import measured (``poseidon`` metadata ``laser_offsets`` of the recording, else
  of the input recording a run names in its metadata, else zero: said in a note).  Beams at or beyond ``range_max`` (no return) or beyond
  :data:`MAX_DRAW_RANGE_M` are left out; scans outside the trajectory's span are left out.
  Each panel is a raster (PNG, data URI): a pixel is darker the more beam end points fall in
  it, at :func:`raster_resolution` metres per pixel (at most :data:`MAX_PIXELS` pixels
  across), with a scale bar;
- ``fig-loop-closures``: loop closures of the final map over time (the newer node's stamp,
  seconds since the run's first message), cumulative count, hover = node ids;
- table "Relations (Freiburg benchmark)": this run's relation error (map and raw odometry,
  :mod:`eval.relations`) beside the published rows for the same data set (:data:`PUBLISHED`;
  the data set is taken from the relations file's name: ``aces`` / ``fr079``; another name
  shows every published row).
"""
from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import plotly.graph_objects as go

from common.mcap_io import read_messages, read_metadata
from common.messages import LaserScan
from common.occupancy import MAX_LASER_RANGE_M, laser_points, scan_endpoints
from eval.corrected import map_corrected
from eval.report.style import FONT, RUN_COLORS, FigureSpec
from eval.rundata import RunData
from eval.trajectory import PoseSeries

__all__ = ["PUBLISHED", "MAX_DRAW_RANGE_M", "MAX_PIXELS", "benchmark_figures", "relations_table", "scan_endpoints",
           "raster_png", "raster_resolution", "dataset_of"]

#: beams longer than this are not drawn (m): far returns blur indoor maps
MAX_DRAW_RANGE_M = MAX_LASER_RANGE_M
#: pixels along the longer side of a point-map raster
MAX_PIXELS = 900

#: published relation errors: (data set, method, trans mean, trans std (m), rot mean, rot std (deg) or None, source)
PUBLISHED: list[tuple[str, str, float, float, float | None, float | None, str]] = [
    ("aces", "scan matching", 0.173, 0.614, None, None, "Kümmerle et al. 2009"),
    ("aces", "GMapping", 0.060, 0.049, None, None, "Kümmerle et al. 2009"),
    ("aces", "graph mapping", 0.044, 0.044, 0.4, 0.4, "Kümmerle et al. 2009"),
    ("aces", "Cartographer", 0.0375, 0.0426, 0.37, 0.47, "Hess et al. ICRA 2016, Table II"),
    ("fr079", "scan matching", 0.258, 0.427, None, None, "Kümmerle et al. 2009"),
    ("fr079", "GMapping", 0.061, 0.044, None, None, "Kümmerle et al. 2009"),
    ("fr079", "graph mapping", 0.056, 0.042, 0.6, 0.6, "Kümmerle et al. 2009"),
    ("fr079", "Cartographer", 0.0452, 0.0354, 0.54, 0.72, "Hess et al. ICRA 2016, Table II"),
]


def dataset_of(relations: str | Path) -> str | None:
    """``aces`` / ``fr079`` when the relations file's name says so, else None."""
    name = Path(relations).name.lower()
    for ds in ("aces", "fr079"):
        if ds in name:
            return ds
    return None


def _pm(mean: float | None, std: float | None, fmt: str) -> str:
    return "n/a" if mean is None or std is None else f"{mean:{fmt}} ± {std:{fmt}}"


def relations_table(result: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Rows ``{data set, method, translation (m), rotation (deg), relations, source}``: this run's
    ``relations`` / ``relations_odometry`` (an :func:`eval.run_eval.evaluate_run` result with
    ``--relations``) and the published rows of the same data set."""
    ds = dataset_of(result["relations_file"])
    rows: list[dict[str, Any]] = []
    for key, method in (("relations", "this run: map-corrected"), ("relations_odometry", "this run: raw odometry")):
        b = result.get(key)
        if b is None:
            rows.append({"data set": ds or Path(result["relations_file"]).name, "method": method,
                         "translation (m)": "n/a", "rotation (deg)": "n/a", "relations": 0,
                         "source": "no map message" if key == "relations" else "no odometry"})
            continue
        t, a = b["trans_abs_m"], b["rot_abs_deg"]
        rows.append({"data set": ds or Path(result["relations_file"]).name, "method": method,
                     "translation (m)": _pm(t["mean"], t["std"], ".4f"), "rotation (deg)": _pm(a["mean"], a["std"], ".2f"),
                     "relations": f"{b['count']} ({b['outside']} outside)", "source": b["source"]})
    for d, method, tm, ts, rm, rs, src in PUBLISHED:
        if ds is None or d == ds:
            rows.append({"data set": d, "method": method, "translation (m)": _pm(tm, ts, ".4f"),
                         "rotation (deg)": _pm(rm, rs, ".2f"), "relations": "published", "source": src})
    return rows


def _world_points(stamps: np.ndarray, local: list[np.ndarray], poses: PoseSeries,
                  offset: tuple[float, float, float]) -> np.ndarray:
    """End points in the world frame, each scan at the pose interpolated at its stamp (laser at
    ``offset`` = dx, dy, dtheta in the robot frame); scans outside the poses' span are dropped."""
    inside = (stamps >= poses.stamps[0]) & (stamps <= poses.stamps[-1])
    if not inside.any():
        return np.zeros((0, 2))
    at = poses.interpolate(stamps[inside])
    return laser_points(at.positions, at.yaws, [local[i] for i in np.flatnonzero(inside)], offset)


def raster_resolution(points: np.ndarray, max_pixels: int = MAX_PIXELS) -> float:
    """Metres per pixel: the longer side of the points' bounding box over ``max_pixels``, at least 0.05 m."""
    ext = float(np.max(points.max(axis=0) - points.min(axis=0))) if len(points) else 0.0
    return max(0.05, ext / max_pixels)


def raster_png(points: np.ndarray, resolution: float, path_xy: np.ndarray | None = None) -> str:
    """A PNG data URI of the points (x east, y north: up on the image), darker where more fall in a
    pixel, the trajectory ``path_xy`` in blue, a scale bar bottom left."""
    from PIL import Image, ImageDraw

    allp = points if path_xy is None or not len(path_xy) else np.vstack([points, path_xy])
    lo = allp.min(axis=0) - 2.0
    hi = allp.max(axis=0) + 2.0
    w = int(math.ceil((hi[0] - lo[0]) / resolution - 1e-9)) + 1
    h = int(math.ceil((hi[1] - lo[1]) / resolution - 1e-9)) + 1
    counts = np.zeros((h, w), dtype=np.int64)
    if len(points):
        col = ((points[:, 0] - lo[0]) / resolution).astype(np.int64)
        row = (h - 1 - (points[:, 1] - lo[1]) / resolution).astype(np.int64)
        np.add.at(counts, (row, col), 1)
    grey = (255 * (1.0 - np.minimum(1.0, np.log1p(counts) / math.log(6.0)))).astype(np.uint8)
    img = Image.fromarray(grey, mode="L").convert("RGB")
    draw = ImageDraw.Draw(img)
    if path_xy is not None and len(path_xy) > 1:
        xy = [((x - lo[0]) / resolution, h - 1 - (y - lo[1]) / resolution) for x, y in path_xy]
        draw.line(xy, fill=(31, 119, 180), width=1)
    bar_m = 10.0 ** math.floor(math.log10(max(w * resolution / 4, 1e-3)))
    bar_px = bar_m / resolution
    draw.line([(10, h - 12), (10 + bar_px, h - 12)], fill=(214, 39, 40), width=3)
    draw.text((12, h - 28), f"{bar_m:g} m", fill=(214, 39, 40))
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _laser_offset(path: Path) -> tuple[tuple[float, float, float], str | None]:
    """The ``scan`` laser offset (dx, dy, dtheta) from the recording's ``poseidon`` metadata, else
    from that of its input recording (a run's metadata names it: ``input``), else zero; and a note
    when it is not the recording's own."""
    meta = read_metadata(path).get("poseidon", {})
    where = None
    if "laser_offsets" not in meta and meta.get("input") and Path(meta["input"]).is_file():
        where = meta["input"]
        meta = read_metadata(where).get("poseidon", {})
    raw = meta.get("laser_offsets")
    if raw is None:
        return (0.0, 0.0, 0.0), "no laser offset in the recording's metadata (nor its input's): the laser is drawn " \
                                "at the robot pose"
    o = json.loads(raw).get("scan")
    if not isinstance(o, dict):
        return (0.0, 0.0, 0.0), f"metadata laser_offsets has no 'scan' entry ({raw!r}): laser drawn at the robot pose"
    note = None if where is None else f"laser offset from the input recording {where}"
    return (float(o["dx"]), float(o["dy"]), float(o["dtheta"])), note


def fig_scan_maps(run: RunData) -> FigureSpec:
    """``fig-scan-maps`` (module docstring)."""
    spec = FigureSpec("fig-scan-maps", "Laser point maps: final map's corrected poses vs raw odometry",
                      "Every laser scan drawn at the pose the run estimates for its stamp. Left: the final "
                      "experience map's correction applied to the dead reckoning (the poseidon export --tum "
                      "trajectory). Right: the raw odometry. Walls that are sharp and single on the left but "
                      "doubled or smeared on the right are what the loop closures fixed; the blue line is the "
                      "trajectory.")
    scans = [r.message() for r in read_messages(run.path, keys=["scan"])]
    if not scans:
        spec.notes.append(f"{run.path.name}: no 'scan' messages")
        return spec
    stamps, local = scan_endpoints([s for s in scans if isinstance(s, LaserScan)])
    offset, note = _laser_offset(run.path)
    if note:
        spec.notes.append(note)
    raw, raw_name = ((run.wheel_odometry, "wheel_odometry") if run.wheel_odometry is not None
                     else (run.odometry_poses, "Odometry"))
    panels: list[tuple[str, PoseSeries]] = []
    if run.odometry_poses is not None and run.final_map is not None and run.final_map.nodes:
        panels.append(("map-corrected (final map)", map_corrected(run.odometry_poses, run.final_map.nodes,
                                                                            run.scan_poses)))
    else:
        spec.notes.append("no map message (or no Odometry): only the raw odometry map is drawn")
    if raw is not None:
        panels.append((f"raw odometry ({raw_name})", raw))
    if not panels:
        spec.notes.append("no odometry to place the scans")
        return spec
    parts = []
    for title, poses in panels:
        pts = _world_points(stamps, local, poses, offset)
        if not len(pts):
            spec.notes.append(f"{title}: no scan inside the trajectory's span")
            continue
        res = raster_resolution(pts)
        uri = raster_png(pts, res, poses.positions[:, :2])
        parts.append(f'<figure class="thumb scan-map"><img src="{uri}" '
                     f'alt="{html.escape(title)}"><figcaption>{html.escape(title)}: {len(pts)} beam end points, '
                     f'{res:.2f} m per pixel</figcaption></figure>')
    if parts:
        spec.html = '<div class="gallery">' + "".join(parts) + "</div>"
    return spec


def fig_loop_closures(run: RunData) -> FigureSpec:
    """``fig-loop-closures`` (module docstring)."""
    spec = FigureSpec("fig-loop-closures", "Loop closures over time",
                      "Cumulative number of loop closures in the final map, at the time of the newer experience "
                      "of each (seconds since the first message). Hover a point for the two experience ids.")
    m = run.final_map
    if m is None:
        spec.notes.append(f"{run.path.name}: no map message")
        return spec
    stamp = {n.id: n.stamp for n in m.nodes}
    rows = sorted((stamp[max(ln.source, ln.target)], max(ln.source, ln.target), min(ln.source, ln.target))
                  for ln in m.links if ln.loop_closure and ln.source in stamp and ln.target in stamp)
    if not rows:
        spec.notes.append(f"{run.path.name}: the final map has no loop closure")
        return spec
    t0 = run.start_ns or 0
    t = [(r[0] - t0) / 1e9 for r in rows]
    fig = go.Figure(go.Scatter(x=t, y=list(range(1, len(rows) + 1)), mode="lines+markers", line_shape="hv",
                               marker=dict(color=RUN_COLORS[0]), name="loop closures",
                               text=[f"experience {a} -> {b}" for _, a, b in rows],
                               hovertemplate="%{x:.1f} s: %{text}<extra></extra>"))
    fig.update_layout(height=320, font=FONT, margin=dict(l=60, r=20, t=20, b=50), xaxis_title="time (s)",
                      yaxis_title="loop closures (cumulative)", template="plotly_white")
    spec.figure = fig
    return spec


def benchmark_figures(run: RunData) -> list[FigureSpec]:
    """The section's figures for one run (eval.rundata.load_run result)."""
    return [fig_scan_maps(run), fig_loop_closures(run)]
