"""``poseidon deadreckon REC.mcap [--config FILE] [--set k=v] [--cones FILE] [--json]``.

Runs the ``robot_state`` node offline over a recording (:func:`common.node.run_offline`,
the same code path as the live service) and prints a summary of its dead-reckoning
trajectory, next to a naive baseline computed in the same run: **plain integration** =
each valid DVL record's ``velocityinst`` (flag 1, finite; same extrinsic rotation and sign
as the filter) rotated by the DVL's own heading only (Eqs. 3.10-3.11 with roll = pitch = 0),
held until the next valid record and integrated; z = latest depth + ``robot_state.depth.offset_m``.

Every position below is in the world NED frame (m), origin = the filter's start
position; the published ``Odometry`` is converted back from its ``axis_remap`` frame.

``--json`` keys:

- ``recording``, ``frame`` (published frame name), ``messages`` ({key: count read}),
  ``odometry_count``;
- ``duration_s`` (first to last Odometry), ``distance_travelled_m`` (3D path length of the
  filter estimate resampled at 1 s), ``start_position_m``, ``end_position_m``;
- ``counters`` ({name: count}: every rejection and event of the node, e.g.
  ``dvl_invalid_flag``, ``dvl_few_beams``, ``dvl_nonfinite``, ``dvl_too_fast``,
  ``timestamp_backwards``, ``late``, ``gap``, ``dvl_reacquired``);
- ``status_flags`` ({flag: number of Odometry messages carrying it});
- ``plain``: ``distance_travelled_m``, ``end_position_m``, ``dvl_used``, ``dvl_skipped``;
- with ``--cones FILE`` (``pass,stamp,cone,offset_x,offset_y``; stamp in s): ``cones`` =
  ``{"primary": "no_offset", "passes_used", "passes_outside", "filter": V, "plain": V}``
  where ``V = {variant: {"per_cone_m": {cone: distance}, "mean_m": mean}}`` for the
  variants ``no_offset`` (the vehicle positions at the two passes), ``offset`` (cone =
  vehicle + yaw-rotated (offset_x forward, offset_y starboard)) and ``offset_y_flipped``
  (offset_y port-positive; the dataset does not document its sign).  Positions are
  interpolated linearly at the pass stamps, distances are 3D (m);
- with a ``truth/pose`` stream (simulated missions, NED): ``truth`` =
  ``{"filter": T, "plain": T}``, ``T = {"ate_rmse_m", "final_error_m", "final_drift_pct",
  "max_error_m", "truth_distance_m"}``: both estimates are translated so that they start
  at the true start position (no rotation: the heading is absolute), ATE over the truth
  stamps, drift = final horizontal+vertical error / true distance travelled (%).

Exit status: 0 on success, 2 on bad arguments or unreadable input (the message names
the file).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from common.codec import DecodeError
from common.config import ConfigError
from common.geometry import OutputFrame, euler_to_matrix, matrix_to_euler, quaternion_to_matrix, rot_z
from common.mcap_io import RecordingError, read_messages
from common.messages import Depth, LinkquestDvl, Message, Odometry
from common.node import run_offline
from eval.trajectory import NS, Trajectory, anchored_errors
from services.robot_state.config import RobotStateConfig
from services.robot_state.node import RobotStateNode
from system.config import PoseidonConfig, load_config
from system.services import build_node

__all__ = ["main", "PlainIntegrator", "Trajectory", "read_cone_passes", "cone_scores", "truth_scores",
           "run_deadreckon"]


class PlainIntegrator:
    """The naive baseline: DVL velocity rotated by the DVL heading only, integrated (Eq. 3.11)."""

    def __init__(self, cfg: RobotStateConfig):
        self.cfg = cfg
        self.r_bd = euler_to_matrix(*np.radians(cfg.dvl.rotation_rpy_deg))
        self.t: int | None = None
        self.xy = np.zeros(2)
        self.z = 0.0
        self.v = np.zeros(2)
        self.yaw = 0.0
        self.started = False
        self.used = 0
        self.skipped = 0
        self.stamps: list[int] = []
        self.positions: list[np.ndarray] = []
        self.yaws: list[float] = []

    def _advance(self, t: int) -> None:
        if self.t is not None and t > self.t and self.started:
            self.xy += self.v * (t - self.t) / NS
        self.t = t if self.t is None else max(self.t, t)

    def _record(self) -> None:
        if self.started and self.t is not None:
            self.stamps.append(self.t)
            self.positions.append(np.array([self.xy[0], self.xy[1], self.z]))
            self.yaws.append(self.yaw)

    def process(self, key: str, msg: Message) -> None:
        stamp = msg.header.stamp
        if key == "depth_sensor":
            assert isinstance(msg, Depth)
            if math.isfinite(msg.depth):
                self._advance(stamp)
                self.z = msg.depth + self.cfg.depth.offset_m
                self._record()
        elif key == "dvl_linkquest":
            assert isinstance(msg, LinkquestDvl)
            v = np.asarray(msg.velocityinst, dtype=float)
            if msg.velocityinstflag != 1 or not np.all(np.isfinite(v)) or not math.isfinite(msg.heading):
                self.skipped += 1
                return
            self._advance(stamp)
            vb = self.cfg.dvl.velocity_sign * (self.r_bd @ v)
            self.yaw = math.radians(msg.heading)
            self.v = (rot_z(self.yaw) @ vb)[:2]
            self.started = True
            self.used += 1
            self._record()


def _odometry_trajectory(outputs: Iterable[tuple[str, Message]], frame: OutputFrame) -> Trajectory:
    stamps, pos, yaws = [], [], []
    for key, m in outputs:
        if key != "Odometry":
            continue
        assert isinstance(m, Odometry)
        stamps.append(m.header.stamp)
        pos.append(frame.position_to_ned(np.asarray(m.position)))
        yaws.append(matrix_to_euler(frame.rotation_to_ned(quaternion_to_matrix(m.orientation)))[2])
    return Trajectory(stamps, pos, yaws)


def read_cone_passes(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a cone-pass file (``pass,stamp,cone,offset_x,offset_y``; stamp s or ns)."""
    from common.stamps import parse_stamp_ns

    p = Path(path)
    try:
        f = open(p, newline="")
    except FileNotFoundError:
        raise ConfigError(f"cone file not found: {p}") from None
    rows = []
    with f:
        reader = csv.DictReader(f)
        need = {"pass", "stamp", "cone", "offset_x", "offset_y"}
        if reader.fieldnames is None or not need <= set(reader.fieldnames):
            raise ConfigError(f"{p}: expected columns {sorted(need)}, got {reader.fieldnames}")
        for row in reader:
            line = reader.line_num
            try:
                rows.append({"pass": int(row["pass"]), "stamp": parse_stamp_ns(row["stamp"]), "cone": int(row["cone"]),
                             "offset_x": float(row["offset_x"]), "offset_y": float(row["offset_y"])})
            except ValueError as exc:
                raise ConfigError(f"{p}: line {line}: {exc}") from None
    return rows


_VARIANTS = {"no_offset": 0.0, "offset": 1.0, "offset_y_flipped": -1.0}


def cone_scores(traj: Trajectory, passes: list[dict[str, Any]]) -> tuple[dict[str, Any], int, int]:
    """Per-cone distance (m) between the estimated positions of its passes, per offset variant."""
    out: dict[str, Any] = {}
    used = [r for r in passes if traj.covers(r["stamp"])]
    for name, ysign in _VARIANTS.items():
        pos: dict[int, list[np.ndarray]] = {}
        for r in used:
            p, yaw = traj.at(r["stamp"])
            if name != "no_offset":
                off = np.array([r["offset_x"], ysign * r["offset_y"], 0.0])
                p = p + rot_z(yaw) @ off
            pos.setdefault(r["cone"], []).append(p)
        per = {str(c): float(np.linalg.norm(ps[-1] - ps[0])) for c, ps in sorted(pos.items()) if len(ps) >= 2}
        out[name] = {"per_cone_m": per, "mean_m": float(np.mean(list(per.values()))) if per else None}
    return out, len(used), len(passes) - len(used)


def truth_scores(traj: Trajectory, truth: Trajectory) -> dict[str, float]:
    """ATE and drift of an estimate against the true trajectory (both NED), start-anchored
    (:func:`eval.trajectory.anchored_errors`)."""
    return anchored_errors(traj, truth)


def run_deadreckon(messages: list[tuple[str, Message]], config: PoseidonConfig,
                   cones: list[dict[str, Any]] | None = None, recording: str = "") -> dict[str, Any]:
    """Run the node and the plain baseline over ``messages``; the summary documented above."""
    node = build_node("robot_state", config)
    assert isinstance(node, RobotStateNode)
    frame = node.frame
    plain = PlainIntegrator(config.robot_state)
    counts: dict[str, int] = {}
    truth_rows: list[Odometry] = []
    for key, msg in messages:
        counts[key] = counts.get(key, 0) + 1
        if key == "truth/pose":
            assert isinstance(msg, Odometry)
            truth_rows.append(msg)
    # the baseline sees the same records in the same event-time order
    ordered = sorted(((k, m) for k, m in messages if k in ("dvl_linkquest", "depth_sensor")),
                     key=lambda km: (km[1].header.stamp, km[0] != "dvl_linkquest", km[1].header.seq))
    for key, msg in ordered:
        plain.process(key, msg)
    outputs = run_offline(node, messages)
    traj = _odometry_trajectory(outputs, frame)
    flags: dict[str, int] = {}
    for key, m in outputs:
        if key == "Odometry":
            for s in m.status:  # type: ignore[attr-defined]
                flags[s] = flags.get(s, 0) + 1
    summary: dict[str, Any] = {
        "recording": recording, "frame": frame.name, "messages": counts, "odometry_count": len(traj),
        "counters": dict(sorted(node.counters.items())), "status_flags": dict(sorted(flags.items())),
    }
    if len(traj) == 0:
        summary.update({"duration_s": 0.0, "distance_travelled_m": 0.0, "start_position_m": None,
                        "end_position_m": None})
        return summary
    origin = traj.p[0].copy()
    origin[2] = 0.0
    summary.update({
        "duration_s": float((traj.t[-1] - traj.t[0]) / NS),
        "distance_travelled_m": traj.distance(),
        "start_position_m": [float(v) for v in traj.p[0] - origin],
        "end_position_m": [float(v) for v in traj.p[-1] - origin],
    })
    ptraj = Trajectory(plain.stamps, plain.positions, plain.yaws)
    if len(ptraj):
        # same origin convention: the plain estimate starts where the filter does
        p0, _ = ptraj.at(int(traj.t[0])) if ptraj.covers(int(traj.t[0])) else (ptraj.p[0], 0.0)
        shift = traj.p[0] - p0
        shift[2] = 0.0
        ptraj.p = ptraj.p + shift
    summary["plain"] = {"distance_travelled_m": ptraj.distance(),
                        "end_position_m": [float(v) for v in ptraj.p[-1] - origin] if len(ptraj) else None,
                        "dvl_used": plain.used, "dvl_skipped": plain.skipped}
    if cones is not None:
        f_scores, used, outside = cone_scores(traj, cones)
        p_scores, _, _ = cone_scores(ptraj, cones) if len(ptraj) else ({}, 0, 0)
        summary["cones"] = {"primary": "no_offset", "passes_used": used, "passes_outside": outside,
                            "filter": f_scores, "plain": p_scores}
    if truth_rows:
        truth = Trajectory([m.header.stamp for m in truth_rows], [np.asarray(m.position) for m in truth_rows],
                           [matrix_to_euler(quaternion_to_matrix(m.orientation))[2] for m in truth_rows])
        summary["truth"] = {"filter": truth_scores(traj, truth)}
        if len(ptraj) > 1:
            summary["truth"]["plain"] = truth_scores(ptraj, truth)
    return summary


def _load(path: Path, keys: list[str]) -> list[tuple[str, Message]]:
    out: list[tuple[str, Message]] = []
    for rec in tqdm(read_messages(path, keys=keys), desc="deadreckon read", unit="msg", file=sys.stderr,
                    disable=not sys.stderr.isatty()):
        try:
            out.append((rec.key, rec.message()))
        except DecodeError as exc:
            raise RecordingError(f"{path}: message {rec.key!r} stamped {rec.stamp}: {exc}") from None
    return out


def _print_text(s: dict[str, Any]) -> None:
    print(f"recording          {s['recording']}")
    print(f"odometry           {s['odometry_count']} messages, frame {s['frame']}")
    print(f"duration           {s['duration_s']:.1f} s")
    print(f"distance travelled {s['distance_travelled_m']:.2f} m (plain integration "
          f"{s.get('plain', {}).get('distance_travelled_m', float('nan')):.2f} m)")
    if s.get("start_position_m") is not None:
        print("start / end (NED)  " + " ".join(f"{v:.2f}" for v in s["start_position_m"]) + "  /  "
              + " ".join(f"{v:.2f}" for v in s["end_position_m"]) + " m")
    print("counters           " + (", ".join(f"{k}={v}" for k, v in s["counters"].items()) or "none"))
    print("status flags       " + (", ".join(f"{k}={v}" for k, v in s["status_flags"].items()) or "none"))
    if "cones" in s:
        c = s["cones"]
        print(f"cone passes        {c['passes_used']} used, {c['passes_outside']} outside the trajectory")
        for variant in _VARIANTS:
            f, p = c["filter"].get(variant, {}), c["plain"].get(variant, {})
            per_f, per_p = f.get("per_cone_m", {}), p.get("per_cone_m", {})
            cells = " ".join(f"{k}:{per_f[k]:.2f}/{per_p.get(k, float('nan')):.2f}" for k in per_f)
            print(f"  {variant:17s} filter/plain per cone (m) {cells}; mean {f.get('mean_m') or float('nan'):.2f}"
                  f" / {p.get('mean_m') or float('nan'):.2f} m")
    if "truth" in s:
        for name, t in s["truth"].items():
            print(f"truth {name:6s}       ATE {t['ate_rmse_m']:.2f} m, final error {t['final_error_m']:.2f} m = "
                  f"{t['final_drift_pct']:.2f} % of {t['truth_distance_m']:.1f} m")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon deadreckon",
                                 description="dead-reckoning trajectory summary of a recording (robot_state offline)")
    ap.add_argument("recording", type=Path, help="MCAP recording with dvl_linkquest / imu / depth_sensor")
    ap.add_argument("--config", type=Path, default=None, help="configuration YAML (default: built-in defaults)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="K=V",
                    help="override a configuration value, e.g. robot_state.dvl.velocity_sign=-1")
    ap.add_argument("--cones", type=Path, default=None, help="cone_passes.csv (pass,stamp,cone,offset_x,offset_y)")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = ap.parse_args(argv)
    try:
        config = load_config(args.config, args.overrides)
        cones = read_cone_passes(args.cones) if args.cones is not None else None
        node_inputs = list(build_node("robot_state", config).inputs)
        messages = _load(args.recording, node_inputs + ["truth/pose"])
        summary = run_deadreckon(messages, config, cones, recording=str(args.recording))
    except (ConfigError, RecordingError) as exc:
        print(f"poseidon deadreckon: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print_text(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
