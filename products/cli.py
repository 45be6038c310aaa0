"""``poseidon export RUN.mcap [--foxglove OUT.mcap] [--ros2 OUT_DIR] [--ros1 OUT.bag] [--tum OUT.txt] [--overwrite] [--json]``.

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

Raw-carried messages (keys ``raw/...``, see ``poseidon import``) go back to their original
topic and type; into a bag of the kind they came from, byte for byte.

Exit codes: 0 done, 2 bad input (missing/corrupt recording, output exists).
``--json`` prints ``{"input", "exports": [{"out", "format", "topics": {topic: {"type" or
"schema", "count", ...}}, "raw_converted" (bags only: raw messages re-serialised between
ROS 1 and CDR, per topic)}]}``; the TUM entry is ``{"out", "format": "tum", "poses",
"trajectory": "map_corrected" | "dead_reckoning", "topics": {"Odometry": {"count"}}}``.
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
    ap.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    ap.add_argument("--json", action="store_true", help="print the JSON summary on stdout")
    args = ap.parse_args(argv)
    if not (args.foxglove or args.ros2 or args.ros1 or args.tum):
        ap.error("nothing to do: give --foxglove, --ros2, --ros1 and/or --tum")
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
    except (ExportError, RecordingError, DecodeError, KeyError) as exc:
        print(f"poseidon export: error: {args.run}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        json.dump({"input": args.run, "exports": exports}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        for e in exports:
            n = sum(t["count"] for t in e["topics"].values())
            print(f"wrote {e['out']} ({e['format']}): {n} messages on {len(e['topics'])} topics", file=sys.stderr)
    return 0


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
