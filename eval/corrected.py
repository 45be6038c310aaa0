"""The map-corrected trajectory of a run, and TUM trajectory files.

One definition serves ``poseidon export RUN --tum OUT.txt`` and ``poseidon eval RUN
--relations FILE`` (:mod:`eval.relations`): :func:`map_corrected`.

Frames: everything stays in the frame the run publishes (``Odometry`` and the ``map``
nodes share it, :mod:`eval.trajectory`); nothing is converted to NED.  Yaw is the rotation
about +z of the ``[x, y, z, w]`` orientation quaternion (:func:`common.geometry.yaws_of_quaternions`).

Definition.  Input: the ``Odometry`` stream (the ``robot_state`` dead reckoning) and the
nodes of the run's **last** ``map`` message (id, position[3], yaw, stamp).  One output pose
per ``Odometry`` stamp t:

1. e = the latest node with stamp <= t (nodes ordered by stamp, then id); before the first
   node, the first node; e' = the node after e (e itself after the last node);
2. the odometry pose at a node's stamp, interpolated from the ``Odometry`` stream between the
   bracketing samples (position linear, orientation SLERP, so yaw moves by the shortest
   angle; clamped to the first / last sample outside the stream's span);
3. a node's correction C = T_map(node) * T_odom(node)^-1, restricted to a rotation about the
   vertical axis: R = Rz(yaw_map - yaw_odom), C(p) = R (p - p_odom(node)) + p_map(node);
4. the pose at t blends the two corrections by time, f = (t - t_e) / (t_e' - t_e) in [0, 1]:
   position (1 - f) C_e(p_odom(t)) + f C_e'(p_odom(t)), heading correction
   psi_e + f wrap(psi_e' - psi_e), orientation q_psi * q_odom(t) (pre-multiplied by the yaw
   rotation), so roll and pitch of a 3D (underwater) odometry are carried through and z is
   shifted by the blended p_map.z - p_odom.z.  At a node's stamp the pose is the node's;
   between nodes the dead reckoning is corrected by a correction that moves smoothly from
   one experience's to the next (why blended: docs/DECISIONS.md, "The corrected trajectory").
   The arithmetic is :func:`common.map_correction.blend_corrections` (the ROS 1 bridge's live
   grid uses it too).

5. with scan poses (``scan_pose``, a laser map's registration of every scan against the local map
   of an experience, :mod:`services.expmap.scan_poses`): each scan pose whose experience is in the
   final map and whose stamp is not an experience's becomes one more correction node, with the
   heading the registration measured (the experience's map yaw plus the pose's yaw) and the
   position of steps 1-4 at its stamp; steps 1-4 then run again over experiences and scan poses.
   Between experiences the heading is the scans', not the odometry's; the position stays the
   experiences' (a single scan's registered translation is noisier than the two experiences'
   blend: docs/LASER.md, "Scan poses").

Without a map message (or with an empty map) the trajectory is the dead reckoning itself.

TUM file (:func:`write_tum`): one line ``t x y z qx qy qz qw`` per pose, t = stamp / 1e9 in
seconds on the input's own clock with exactly 9 decimals (for a CARMEN import that is the
log's ipc timestamp, :mod:`missions.importers.carmen`), the rest with 9 significant
decimals; a ``#`` header line names the columns.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from common.geometry import wrap_angle
from common.map_correction import blend_corrections, interpolate_poses
from common.mcap_io import RecordingError
from common.messages import ExperienceNode, ScanPose
from common.stamps import ns_to_text, seconds_to_ns
from eval.rundata import load_run
from eval.trajectory import PoseSeries

__all__ = ["map_corrected", "corrected_from_recording", "write_tum", "read_tum"]


def map_corrected(odom: PoseSeries, nodes: Sequence[ExperienceNode] | None,
                  scan_poses: Sequence[ScanPose] = ()) -> PoseSeries:
    """The map-corrected pose at every odometry stamp (module docstring, steps 1-5); ``odom``
    itself when there are no nodes."""
    if not nodes or not len(odom):
        return odom
    ns = sorted(nodes, key=lambda n: (n.stamp, n.id))
    nt = np.array([n.stamp for n in ns], dtype=np.int64)
    npos = np.array([n.position for n in ns], dtype=float)
    nyaw = np.array([n.yaw for n in ns], dtype=float)
    p, q = blend_corrections(odom.stamps, odom.positions, odom.quaternions, nt, npos, nyaw)
    yaw_of = {n.id: n.yaw for n in ns}
    at_nodes = set(nt.tolist())
    sel = sorted((s for s in scan_poses if s.experience_id in yaw_of and s.header.stamp not in at_nodes),
                 key=lambda s: s.header.stamp)
    if sel:
        st = np.array([s.header.stamp for s in sel], dtype=np.int64)
        sp, _ = interpolate_poses(odom.stamps, p, q, st)
        syaw = wrap_angle(np.array([yaw_of[s.experience_id] + s.pose[2] for s in sel]))
        order = np.argsort(np.r_[nt, st], kind="stable")
        p, q = blend_corrections(odom.stamps, odom.positions, odom.quaternions, np.r_[nt, st][order],
                                 np.r_[npos, sp][order], np.r_[nyaw, syaw][order])
    return PoseSeries(odom.stamps.copy(), p, q)


def corrected_from_recording(path: str | Path) -> tuple[PoseSeries, bool]:
    """(:func:`map_corrected` of the run at ``path``, whether it had a map message); the
    recording is read by :func:`eval.rundata.load_run` (``Odometry``, ``map`` and ``scan_pose`` only).

    :raises RecordingError: unreadable recording, or no ``Odometry`` messages in it.
    """
    run = load_run(path, keys=("Odometry", "map", "scan_pose"))
    if run.odometry_poses is None:
        raise RecordingError(f"{run.path}: no 'Odometry' messages: nothing to export (is it a run recording?)")
    nodes = run.final_map.nodes if run.final_map is not None else None
    return map_corrected(run.odometry_poses, nodes, run.scan_poses), run.final_map is not None


def write_tum(path: str | Path, poses: PoseSeries) -> int:
    """Write ``poses`` as a TUM trajectory file (module docstring); returns the line count."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w") as f:
        f.write("# t x y z qx qy qz qw\n")
        for t, pp, q in zip(poses.stamps, poses.positions, poses.quaternions):
            f.write(f"{ns_to_text(int(t))} {' '.join(f'{v:.9f}' for v in pp)} {' '.join(f'{v:.9f}' for v in q)}\n")
    return len(poses)


def read_tum(path: str | Path) -> PoseSeries:
    """Read a TUM trajectory file (``#`` lines and blank lines skipped).

    :raises ValueError: a line without 8 numbers (names the file and line).
    """
    p = Path(path)
    t: list[int] = []
    rows: list[list[float]] = []
    for k, line in enumerate(p.read_text().splitlines(), 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        if len(tok) != 8:
            raise ValueError(f"{p}:{k}: {len(tok)} fields, expected 8 (t x y z qx qy qz qw)")
        try:
            t.append(seconds_to_ns(tok[0]))
            rows.append([float(v) for v in tok[1:]])
        except ValueError as exc:
            raise ValueError(f"{p}:{k}: {exc}") from None
    a = np.array(rows, dtype=float).reshape(-1, 7)
    return PoseSeries(np.array(t, dtype=np.int64), a[:, :3], a[:, 3:])
