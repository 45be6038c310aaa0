"""``poseidon export RUN.mcap [--foxglove OUT.mcap] [--ros2 OUT_DIR] [--ros1 OUT.bag] [--tum OUT.txt] [--grid DIR] [--grid-odometry DIR] [--cloud OUT.ply] [--cloud-odometry OUT.ply] [--survex OUT.svx] [--overwrite] [--json]``.

A recording (``poseidon run``/``import``/``sim`` output) for the tools people already use:

- ``--foxglove OUT.mcap``: Foxglove's well-known schemas (camera frames as images, sonar
  beams as point clouds, trajectories as poses and paths, the experience graph as a scene,
  LVC ids and events as logs; everything else as ROS 2 CDR): :mod:`products.foxglove`;
- ``--ros2 OUT_DIR``: a ROS 2 bag folder (sqlite3, CDR) with standard message types where
  they exist and ``poseidon_msgs`` types (definitions in ``products/msg``) for the
  SLAM outputs: :mod:`products.rosbag`, :mod:`products.ros_types`;
- ``--ros1 OUT.bag``: the same as a ROS 1 bag;
- ``--tum OUT.txt``: the run's trajectory as a TUM file (``t x y z qx qy qz qw``), one
  pose per ``Odometry`` stamp, corrected by the final experience map; definition and
  format in :mod:`eval.corrected` (the same trajectory ``poseidon eval --relations``
  scores).  A run without a ``map`` message gives the dead reckoning itself (said on
  stderr).

Maps to take away (:mod:`products.mapsource` reads the run once for all of them; every product
states its frame, units and what it leaves out in its own comments and its ``--json`` entry):

- ``--grid DIR [--resolution R]``: an occupancy grid (``DIR/map.pgm`` + ``DIR/map.yaml``, ROS
  ``map_server`` trinary) of the laser scans, else the horizontal sonar, ray-traced at the
  map-corrected poses, R m per cell (default 0.05): :mod:`products.grid`; with its sharpness
  beside that of the raw-odometry grid of the same run; ``--grid-odometry DIR``: the same at the
  raw odometry poses;
- ``--cloud OUT.ply``: every range return (laser, sonar) as a binary PLY point cloud at the
  map-corrected poses, per point time, intensity, experience id and sensor: :mod:`products.cloud`;
  ``--cloud-odometry OUT.ply`` at the raw odometry poses;
- ``--survex OUT.svx [--survex-spacing M]``: the experience map as a Survex centreline (stations
  every M m, default 2; legs, passage LRUD, loop closures as ``*equate``, a block per session):
  :mod:`products.survex`.

A map product on a run without what it needs (no ``map`` message for the map-corrected ones,
no ``scan``/``sonar_micron`` for a grid, no returns at all for a cloud) is an error (exit 2)
naming what is missing; nothing is written.

Raw-carried messages (keys ``raw/...``, see ``poseidon import``) go back to their original
topic and type; into a bag of the kind they came from, byte for byte.

Exit codes: 0 done, 2 bad input (missing/corrupt recording, output exists).
``--json`` prints ``{"input", "exports": [{"out", "format", "topics": {topic: {"type" or
"schema", "count", ...}}, "raw_converted" (bags only: raw messages re-serialised between
ROS 1 and CDR, per topic)}]}``; the TUM entry is ``{"out", "format": "tum", "poses",
"trajectory": "map_corrected" | "dead_reckoning", "topics": {"Odometry": {"count"}}}``.
The grid entry is ``{"out" (the folder), "format": "grid", "files": ["map.pgm", "map.yaml"],
"trajectory": "map_corrected" | "odometry", "sensor": "scan" | "sonar_micron", "resolution_m",
"width", "height" (cells), "origin": [x, y, yaw] (m, m, rad: the lower-left pixel's corner),
"occupied_cells", "free_cells", "returns" (rays traced), "sharpness" (0..1 or null),
"sharpness_odometry" (map-corrected grid only: the raw odometry grid's), "frame", "left_out",
"topics": {key: {"count"}}}``; the cloud entry ``{"out", "format": "ply", "trajectory", "points",
"fields": ["x", "y", "z", "time", "intensity", "experience", "sensor"], "sensors" (keys, in the
order of the ``sensor`` index), "frame", "left_out", "topics": {key: {"count", "returns"}}}``;
the Survex entry ``{"out", "format": "survex", "spacing_m", "sessions", "stations", "legs",
"length_m" (sum of the legs' tapes), "loop_closures", "equates", "lrud_stations" (stations with
at least one passage dimension), "frame", "left_out", "topics": {"map": {"count"}}}``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from common.codec import DecodeError
from common.mcap_io import RecordingError
from products.rosbag import ExportError

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon export", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="an MCAP recording of PoseidonSLAM")
    ap.add_argument("--foxglove", metavar="OUT.mcap", help="Foxglove-ready MCAP with the well-known schemas")
    ap.add_argument("--ros2", metavar="OUT_DIR", help="ROS 2 bag folder (sqlite3, CDR)")
    ap.add_argument("--ros1", metavar="OUT.bag", help="ROS 1 bag")
    ap.add_argument("--tum", metavar="OUT.txt", help="map-corrected trajectory as a TUM file (t x y z qx qy qz qw)")
    ap.add_argument("--grid", metavar="DIR", help="occupancy grid (map.pgm + map.yaml) at the map-corrected poses")
    ap.add_argument("--grid-odometry", metavar="DIR", help="the same grid at the raw odometry poses")
    ap.add_argument("--resolution", type=float, default=0.05, metavar="R", help="grid cell size (m, default 0.05)")
    ap.add_argument("--cloud", metavar="OUT.ply", help="range returns as a PLY point cloud at the map-corrected poses")
    ap.add_argument("--cloud-odometry", metavar="OUT.ply", help="the same cloud at the raw odometry poses")
    ap.add_argument("--survex", metavar="OUT.svx", help="the experience map as a Survex centreline")
    ap.add_argument("--survex-spacing", type=float, default=2.0, metavar="M",
                    help="Survex station spacing (m, default 2)")
    ap.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    ap.add_argument("--json", action="store_true", help="print the JSON summary on stdout")
    args = ap.parse_args(argv)
    maps = (args.grid, args.grid_odometry, args.cloud, args.cloud_odometry, args.survex)
    if not (args.foxglove or args.ros2 or args.ros1 or args.tum or any(maps)):
        ap.error("nothing to do: give --foxglove, --ros2, --ros1, --tum, --grid, --grid-odometry, --cloud, "
                 "--cloud-odometry and/or --survex")
    from products.foxglove import export_foxglove
    from products.rosbag import export_rosbag

    exports: list[dict[str, Any]] = []
    try:
        if args.foxglove:
            exports.append(export_foxglove(args.run, args.foxglove, overwrite=args.overwrite))
        if args.ros2:
            exports.append(export_rosbag(args.run, args.ros2, ros2=True, overwrite=args.overwrite))
        if args.ros1:
            exports.append(export_rosbag(args.run, args.ros1, ros2=False, overwrite=args.overwrite))
        if args.tum:
            exports.append(export_tum(args.run, args.tum, overwrite=args.overwrite))
        if any(maps):
            exports += export_maps(args)
    except (ExportError, RecordingError, DecodeError, KeyError) as exc:
        print(f"poseidon export: error: {args.run}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        json.dump({"input": args.run, "exports": exports}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        for e in exports:
            n = sum(t["count"] for t in e["topics"].values())
            print(f"wrote {e['out']} ({e['format']}): {n} messages on {len(e['topics'])} topics"
                  + _map_summary(e), file=sys.stderr)
    return 0


def export_maps(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The map products asked for by ``args`` (:mod:`products.grid`, :mod:`products.cloud`,
    :mod:`products.survex`), the run read once; notes on the input go to stderr."""
    from products.cloud import export_cloud
    from products.grid import export_grid
    from products.mapsource import load_map_source
    from products.survex import export_survex

    src = load_map_source(args.run)
    for note in src.notes:
        print(f"poseidon export: {args.run}: {note}", file=sys.stderr)
    out: list[dict[str, Any]] = []
    for path, trajectory in ((args.grid, "map_corrected"), (args.grid_odometry, "odometry")):
        if path:
            out.append(export_grid(src, path, trajectory, args.resolution, overwrite=args.overwrite))
    for path, trajectory in ((args.cloud, "map_corrected"), (args.cloud_odometry, "odometry")):
        if path:
            out.append(export_cloud(src, path, trajectory, overwrite=args.overwrite))
    if args.survex:
        out.append(export_survex(src, args.survex, args.survex_spacing, overwrite=args.overwrite))
    return out


def _map_summary(e: dict[str, Any]) -> str:
    """The text summary's figures of a map product ('' for the other formats)."""
    def f(v: float | None) -> str:
        return "n/a" if v is None else f"{v:.3f}"

    if e["format"] == "grid":
        text = (f"; {e['width']} x {e['height']} cells of {e['resolution_m']:g} m at the {e['trajectory']} poses, "
                f"{e['occupied_cells']} occupied; sharpness {f(e['sharpness'])}")
        return text + (f" (raw odometry grid: {f(e['sharpness_odometry'])})" if "sharpness_odometry" in e else "")
    if e["format"] == "ply":
        return f"; {e['points']} points at the {e['trajectory']} poses"
    if e["format"] == "survex":
        return (f"; {e['stations']} stations, {e['legs']} legs, {e['length_m']:.2f} m, "
                f"{e['loop_closures']} loop closures")
    return ""


def export_tum(run: str, out: str, overwrite: bool = False) -> dict[str, Any]:
    """Write the map-corrected trajectory of ``run`` to the TUM file ``out`` (:mod:`eval.corrected`).

    :raises ExportError: ``out`` exists and ``overwrite`` is false.
    :raises RecordingError: unreadable run, or one without ``Odometry``.
    """
    from eval.corrected import corrected_from_recording, write_tum

    if Path(out).exists() and not overwrite:
        raise ExportError(f"{out} exists (--overwrite replaces it)")
    poses, has_map = corrected_from_recording(run)
    if not has_map:
        print(f"poseidon export: {run} has no map message: the TUM trajectory is the dead reckoning (Odometry) "
              "itself", file=sys.stderr)
    n = write_tum(out, poses)
    return {"out": out, "format": "tum", "poses": n, "trajectory": "map_corrected" if has_map else "dead_reckoning",
            "topics": {"Odometry": {"count": n}}}


if __name__ == "__main__":
    raise SystemExit(main())
