"""``poseidon sim --minutes M --seed S [--world-seed W] [--start area1|area2] [--first-loops N] --out FILE.mcap [--json]``:
a synthetic cave mission.

Writes every stream of :mod:`missions.sim.mission` plus ground truth (``truth/pose``,
``truth/revisits``) and a ``poseidon`` metadata record (tool, seed, minutes, all sensor
noise parameters, route segments with their time ranges, the revisit definition).  The
same seed and minutes give the same bytes.

``--json`` prints a summary object to stdout:

- ``out``: the recording path; ``seed`` (route, motion and noise); ``world_seed`` (the cave;
  ``--world-seed``, default the seed); ``start`` (``area1`` or ``area2``); ``first_loops``
  (loops of the start area before the first transition, ``--first-loops``, default 3); ``minutes``;
  ``duration_s`` (s);
- ``distance_m``: path length flown (m);
- ``counts``: messages written per key;
- ``frames``: camera frames; ``frames_with_revisits``: frames with >= 1 earlier frame of
  the same place;
- ``loops``: completed loops per area (``area1_ellipse``, ``area2_cave2``);
- ``segments``: route pieces flown in order (name, loop, start_s, end_s, complete);
- ``wall_s``: generation wall time (s), ``frames_per_s``, ``realtime_factor``
  (mission duration / wall time).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from missions.sim.mission import SimParams, generate

__all__ = ["main", "simulate_cached"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon sim", description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="mission duration in minutes (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="route, motion and noise seed; also the world's unless "
                    "--world-seed is given (default 0)")
    ap.add_argument("--world-seed", type=int, default=None,
                    help="the cave's seed (default: --seed); two missions with the same world seed fly the same "
                         "cave, their truth in one world frame")
    ap.add_argument("--start", choices=("area1", "area2"), default="area1",
                    help="where the route starts: area1 (default) or area2, the second area of the same cave")
    ap.add_argument("--first-loops", type=int, default=None, choices=(1, 2, 3),
                    help="loops of the start area before the first transition (default 3, as every later pass); "
                         "--start area2 --first-loops 1 reaches area 1 after one loop of area 2")
    ap.add_argument("--out", required=True, help="output MCAP recording")
    ap.add_argument("--speed", type=float, default=0.3, help="mean vehicle speed, m/s (default 0.3)")
    ap.add_argument("--camera-hz", type=float, default=None, help="camera rate, Hz (default 5)")
    ap.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                    help="MCAP chunk compression (default zstd: the smallest file; lz4 and none are faster to write "
                    "and read: on the demo mission 1.24x and 1.41x zstd's size)")
    ap.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    args = ap.parse_args(argv)
    if args.minutes <= 0:
        ap.error(f"--minutes must be > 0, got {args.minutes}")
    if args.speed <= 0:
        ap.error(f"--speed must be > 0 m/s, got {args.speed}")
    params = SimParams(minutes=args.minutes, seed=args.seed, speed_m_s=args.speed, world_seed=args.world_seed,
                       start=args.start, first_loops=args.first_loops)
    if args.camera_hz is not None:
        if args.camera_hz <= 0:
            ap.error(f"--camera-hz must be > 0, got {args.camera_hz}")
        params.camera.rate_hz = args.camera_hz
    t0 = time.perf_counter()
    summary = generate(args.out, params, progress=not args.no_progress, compression=args.compression)
    wall = time.perf_counter() - t0
    summary["wall_s"] = round(wall, 3)
    summary["frames_per_s"] = round(summary["frames"] / wall, 2) if wall > 0 else None
    summary["realtime_factor"] = round(summary["duration_s"] / wall, 2) if wall > 0 else None
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(f"wrote {args.out}: {summary['duration_s']:.0f} s mission, {summary['distance_m']:.0f} m, "
              f"{summary['frames']} frames ({summary['frames_with_revisits']} with revisits), loops {summary['loops']}, "
              f"{wall:.1f} s wall ({summary['realtime_factor']}x real time)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


def simulate_cached(out: Path, minutes: float, seed: int, progress: bool = True) -> Path:
    """``out``, simulated first (``poseidon sim --minutes --seed``) unless it exists: the
    benchmarks' cached missions.  RuntimeError when the simulation fails."""
    if not out.exists():
        print(f"simulating {minutes:g} minutes -> {out}", file=sys.stderr)
        argv = ["--minutes", str(minutes), "--seed", str(seed), "--out", str(out)]
        if main(argv + ([] if progress else ["--no-progress"])) != 0:
            raise RuntimeError(f"poseidon sim {' '.join(argv)} failed")
    return out
