"""``poseidon export RUN --cloud OUT.ply`` / ``--cloud-odometry OUT.ply``: every range return of
the run (laser ``scan``, sonar ``sonar_micron`` and ``sonar_seaking``; :mod:`products.mapsource`)
as a 3D point cloud, binary little-endian PLY.

One vertex per return, properties: ``x y z`` (double, m, the run's published frame --
``robot_state``'s, ENU by default: x east, y north, z up), ``time`` (double, s: the return's
stamp on the input's own clock, ns / 1e9), ``intensity`` (float: the echo of the sonar bin, the
laser's intensity value, 0 when the scan has none), ``experience`` (int: the id of the final
map's experience the pose belongs to, :meth:`products.mapsource.MapSource.experience_of`; -1 in
an odometry cloud of a run without a map), ``sensor`` (uchar: index into the header comment
``sensors``).  Vertices in time order.  The header's comments state the frame, the units, the
poses and what is left out.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from products.mapsource import MapSource, write_outputs

__all__ = ["export_cloud", "PLY_DTYPE"]

PLY_DTYPE = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("time", "<f8"), ("intensity", "<f4"),
                      ("experience", "<i4"), ("sensor", "u1")])
_PLY_TYPES = {"<f8": "double", "<f4": "float", "<i4": "int", "|u1": "uchar"}


def export_cloud(src: MapSource, out: str, trajectory: str, overwrite: bool = False) -> dict[str, Any]:
    """Write the PLY cloud of ``src`` at ``trajectory``'s poses to ``out``; returns the ``--json`` entry.

    :raises ExportError: no returns, no map (for ``map_corrected``), ``out`` exists.
    """
    ret = src.returns_at(trajectory, horizontal_only=False)
    sensors = sorted(set(ret.sensor.tolist()))
    v = np.zeros(len(ret), dtype=PLY_DTYPE)
    v["x"], v["y"], v["z"] = ret.points[:, 0], ret.points[:, 1], ret.points[:, 2]
    v["time"] = ret.stamps / 1e9
    v["intensity"] = ret.intensity
    v["experience"] = src.experience_of(ret.stamps)
    v["sensor"] = np.searchsorted(np.array(sensors), ret.sensor)
    poses = ("map-corrected poses (eval.corrected.map_corrected, the final map)" if trajectory == "map_corrected"
             else f"raw odometry poses ({src.raw_name})")
    frame = "the run's published frame (robot_state's; ENU by default: x east, y north, z up), metres"
    left_out = ("returns outside the trajectory's span, beams without a return, laser beams beyond 30 m, sonar "
                "echoes nearer than expmap.scan.min_range_m or weaker than expmap.scan.echo_threshold, every "
                "sonar bin but the beam's echo; the sonar's lever arm")
    comments = [f"PoseidonSLAM point cloud of {src.path.name}: one vertex per range return at the {poses}",
                f"frame: {frame}", "time: s on the input's clock (stamp ns / 1e9); intensity: echo value",
                "experience: id of the final map's experience the pose belongs to (-1: no map)",
                "sensors: " + " ".join(f"{k}={s}" for k, s in enumerate(sensors)),
                f"left out: {left_out}", f"recording code revision: {src.metadata.get('code_revision', 'unknown')}"]
    header = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments),
              f"element vertex {len(v)}",
              *(f"property {_PLY_TYPES[PLY_DTYPE[n].str]} {n}" for n in PLY_DTYPE.names or ()), "end_header"]
    write_outputs({Path(out): ("\n".join(header) + "\n").encode("ascii", "backslashreplace") + v.tobytes()}, overwrite)
    counts = {s: int((ret.sensor == s).sum()) for s in sensors}
    return {"out": out, "format": "ply", "trajectory": trajectory, "points": len(v),
            "fields": list(PLY_DTYPE.names or ()), "sensors": sensors, "frame": frame, "left_out": left_out,
            "topics": {s: {"count": src.counts.get(s, 0), "returns": counts[s]} for s in sensors}}
