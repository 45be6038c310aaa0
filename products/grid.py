"""``poseidon export RUN --grid DIR`` / ``--grid-odometry DIR``: an occupancy grid of the run's
horizontal returns (laser ``scan``, else the ``sonar_micron`` sweeps; :mod:`products.mapsource`)
as a ROS ``map_server`` map: ``DIR/map.pgm`` + ``DIR/map.yaml``.

Grid (:mod:`common.occupancy`, which the ROS 1 bridge's live ``/map`` uses too).  Square cells
of ``resolution`` m (default 0.05 m) over the bounding box of every sensor origin and return,
grown by 1 m; cell (i, j) covers x in [origin_x + i r, origin_x + (i+1) r),
likewise y.  Every return is a ray from its sensor origin to its end point, traced through the
cells by Bresenham's line (numba): the end cell gets a hit, each cell before it a miss.  A cell's
log-odds is ``hits * logit(0.7) + misses * logit(0.4)`` (the usual sensor model of OctoMap), its
occupancy probability p the logistic of that.  Written trinary, as ``map_saver`` does: occupied
(p > ``occupied_thresh`` 0.65) pixel 0, free (p < ``free_thresh`` 0.196) pixel 254, else
(never observed, or undecided) 205.  Image row 0 is the top (largest y); the YAML's origin is
the lower-left corner of the lower-left pixel, yaw 0.  The frame is the run's published frame
(``robot_state``'s, ENU by default: x east, y north), metres; a map-corrected grid at the
:func:`eval.corrected.map_corrected` poses, an odometry grid at the raw odometry.

Left out: the vertical profiler (``sonar_seaking``), returns outside the trajectory's span,
beams without a return (they clear no free space), laser beams beyond 30 m, sonar echoes
nearer than ``expmap.scan.min_range_m`` or weaker than ``expmap.scan.echo_threshold``.

Sharpness (:func:`sharpness`): the returns are split at the median stamp into the first and
the second half of the run, each half mapped alone on the same cells.  Of the occupied cells of
one half that the other half observed (hit or crossed by a ray, within ``SHARP_COVER_M`` 0.5 m),
the fraction with an occupied cell of the other half within one cell (8-neighbourhood); both
directions pooled.  1 = every wall seen in both halves lands on the same cells; a wall drawn
twice (drift between the visits) lowers it.  None when no occupied cell qualifies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import maximum_filter

from common.occupancy import (
    DEFAULT_RESOLUTION_M,
    FREE_THRESH,
    MAX_CELLS,
    OCCUPIED_THRESH,
    accumulate,
    frame_of,
    probability,
    trinary,
)
from products.mapsource import MapSource, Returns, write_outputs
from products.rosbag import ExportError

__all__ = ["Grid", "make_grid", "sharpness", "export_grid", "grid_yaml", "DEFAULT_RESOLUTION_M",
           "OCCUPIED_THRESH", "FREE_THRESH", "SHARP_COVER_M"]

#: a half's occupied cell counts for the sharpness only where the other half observed within this (m)
SHARP_COVER_M = 0.5
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205


@dataclass
class Grid:
    """Hit and miss counts per cell of each half of the run (``[row from the bottom, column]``)."""

    resolution: float
    origin: tuple[float, float]
    hits: tuple[np.ndarray, np.ndarray]
    misses: tuple[np.ndarray, np.ndarray]
    returns: int

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in cells."""
        h, w = self.hits[0].shape
        return int(h), int(w)

    def probability(self, half: int | None = None) -> np.ndarray:
        """Occupancy probability per cell (0.5 where never observed); ``half`` 0 or 1: that half alone."""
        if half is None:
            return probability(self.hits[0] + self.hits[1], self.misses[0] + self.misses[1])
        return probability(self.hits[half], self.misses[half])

    def occupied(self, half: int | None = None) -> np.ndarray:
        """Cells with p > :data:`OCCUPIED_THRESH`."""
        occ: np.ndarray = self.probability(half) > OCCUPIED_THRESH
        return occ

    def observed(self, half: int) -> np.ndarray:
        """Cells of that half hit or crossed by a ray."""
        seen: np.ndarray = (self.hits[half] + self.misses[half]) > 0
        return seen

    def image(self) -> np.ndarray:
        """The trinary map_server image (uint8, row 0 at the top)."""
        img = trinary(self.probability(), PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN)
        out: np.ndarray = img[::-1].copy()
        return out


def make_grid(ret: Returns, resolution: float = DEFAULT_RESOLUTION_M) -> Grid:
    """Trace ``ret`` (sorted by stamp) into a grid of ``resolution`` m cells (module docstring;
    :mod:`common.occupancy`), each half of the run counted apart.

    :raises ExportError: a resolution that is not positive, or a grid of more than 2e8 cells.
    """
    try:
        frame = frame_of(np.vstack([ret.origins[:, :2], ret.points[:, :2]]), resolution, MAX_CELLS)
    except ValueError as exc:
        msg = str(exc).replace("resolution", "--resolution")
        raise ExportError(msg + (": give a coarser --resolution" if "cells" in msg else "")) from None
    mid = ret.stamps[len(ret) // 2] if len(ret) else 0
    hits, misses = [], []
    for part in (ret.stamps < mid, ret.stamps >= mid):
        hh, mm = accumulate(frame, ret.origins[part], ret.points[part])
        hits.append(hh)
        misses.append(mm)
    return Grid(frame.resolution, frame.origin, (hits[0], hits[1]), (misses[0], misses[1]), len(ret))


def sharpness(g: Grid) -> float | None:
    """The grid's sharpness (module docstring): fraction in [0, 1], or None."""
    r = max(1, int(math.ceil(SHARP_COVER_M / g.resolution)))
    occ = [g.occupied(0), g.occupied(1)]
    near = [maximum_filter(o, size=3) for o in occ]
    cover = [maximum_filter(g.observed(k), size=2 * r + 1) for k in (0, 1)]
    counted = agree = 0
    for a, b in ((0, 1), (1, 0)):
        c = occ[a] & cover[b]
        counted += int(c.sum())
        agree += int((c & near[b]).sum())
    return agree / counted if counted else None


def grid_yaml(g: Grid, image: str, comments: list[str]) -> str:
    """The map_server YAML of ``g`` with ``#`` comment lines first."""
    lines = [f"# {c}" for c in comments]
    lines += [f"image: {image}", f"resolution: {g.resolution:.6f}",
              f"origin: [{g.origin[0]:.6f}, {g.origin[1]:.6f}, 0.000000]", "negate: 0",
              f"occupied_thresh: {OCCUPIED_THRESH}", f"free_thresh: {FREE_THRESH}", "mode: trinary"]
    return "\n".join(lines) + "\n"


def _pgm(img: np.ndarray) -> bytes:
    h, w = img.shape
    return f"P5\n{w} {h}\n255\n".encode() + img.tobytes()


def grid_of(src: MapSource, trajectory: str, resolution: float) -> Grid:
    """The grid of ``src`` at ``trajectory``'s poses (computed once per source, trajectory and resolution)."""
    key = ("grid", trajectory, resolution)
    if key not in src.cache:
        src.cache[key] = make_grid(src.returns_at(trajectory, horizontal_only=True), resolution)
    g: Grid = src.cache[key]
    return g


def export_grid(src: MapSource, out: str, trajectory: str, resolution: float = DEFAULT_RESOLUTION_M,
                overwrite: bool = False) -> dict[str, Any]:
    """Write ``out/map.pgm`` and ``out/map.yaml`` (module docstring); returns the ``--json`` entry.

    :raises ExportError: no returns / no map (for ``map_corrected``), outputs exist, bad resolution.
    """
    g = grid_of(src, trajectory, resolution)
    sharp = sharpness(g)
    other = "odometry" if trajectory == "map_corrected" else None
    sharp_odo = sharpness(grid_of(src, other, resolution)) if other else None
    frame = ("the run's published frame (robot_state's; ENU by default: x east, y north), metres; origin = "
             "lower-left corner of the lower-left pixel, yaw 0 rad")
    left_out = ("the vertical profiler (sonar_seaking), returns outside the trajectory's span, beams without a "
                "return (they clear no free space), laser beams beyond 30 m, sonar echoes nearer than "
                "expmap.scan.min_range_m or weaker than expmap.scan.echo_threshold")
    poses = ("map-corrected poses (eval.corrected.map_corrected, the final map)" if trajectory == "map_corrected"
             else f"raw odometry poses ({src.raw_name})")
    img = g.image()
    occ, free = int((img == PIXEL_OCCUPIED).sum()), int((img == PIXEL_FREE).sum())

    def fmt(v: float | None) -> str:
        return "n/a" if v is None else f"{v:.3f}"

    comments = [f"PoseidonSLAM occupancy grid of {src.path.name} ({src.sensor_name} returns at the {poses})",
                f"frame: {frame}", f"left out: {left_out}",
                f"cells: {g.shape[1]} x {g.shape[0]}, {occ} occupied, {free} free; {g.returns} returns traced",
                f"sharpness (halves agree within one cell): {fmt(sharp)}"
                + (f"; raw odometry grid of the same run: {fmt(sharp_odo)}" if other else ""),
                f"recording code revision: {src.metadata.get('code_revision', 'unknown')}"]
    d = Path(out)
    write_outputs({d / "map.pgm": _pgm(img), d / "map.yaml": grid_yaml(g, "map.pgm", comments).encode()}, overwrite)
    entry: dict[str, Any] = {
        "out": out, "format": "grid", "files": ["map.pgm", "map.yaml"], "trajectory": trajectory,
        "sensor": src.sensor_name, "resolution_m": g.resolution, "width": g.shape[1], "height": g.shape[0],
        "origin": [g.origin[0], g.origin[1], 0.0], "occupied_cells": occ, "free_cells": free, "returns": g.returns,
        "sharpness": sharp, "frame": frame, "left_out": left_out,
        "topics": {k: {"count": src.counts.get(k, 0)} for k in (src.sensor_name, "Odometry", "map")}}
    if other:
        entry["sharpness_odometry"] = sharp_odo
    return entry
