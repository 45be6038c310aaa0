"""Pose-cell service: ``Odometry`` + ``local_view_cells`` -> ``experience_event`` (Sections 4.2.3-4.2.4).

Inputs, in priority order for equal stamps: ``Odometry`` first, then ``local_view_cells``, so
a camera frame sees the odometry of its own instant ("latest odometry at or before the
frame's stamp").

- ``Odometry`` (ENU after ``axis_remap``, see ``services/robot_state/frames.py``): the first
  message places a lone packet at the odometry pose (positions modulo the lattice, yaw = the
  odometry yaw), so without injection the pose-cell centroid follows the odometry modulo
  1.5 m.  Every later message adds its increment (Eq. 4.15) ``dp = p_t - p_{t-1}`` to a
  pending motion, expressed in the frame of the odometry yaw ``psi_ref`` at the previous
  pose-cell step (``forward, left = R(-psi_ref) (dx, dy)``, ``up = dz``, ``dyaw`` wrapped):
  the network rotates it back by the packet's heading, which equals ``psi_ref`` while the
  packet agrees with the odometry, so the packet moves by exactly the summed ``dp`` even
  when the vehicle turns between two frames.  An increment longer than
  ``posecells.max_odometry_step`` metres is a discontinuity (a restarted odometry, a later
  mission): it only moves the reference and is counted (``odometry_discontinuities``); a
  non-finite pose is logged, counted (``odometry_non_finite``) and skipped.
- ``local_view_cells`` (one per camera frame) is one time step: the pending motion is path-
  integrated, the active LVCs (the most active one plus up to ``top_k - 1`` others with
  rate >= ``min_exc`` when ``multiple_local_view_active``) inject and learn (Eq. 4.19), the
  attractor updates (Eqs. 4.16-4.17), and the event gate decides (motion gate, then VPR
  Guard, Eqs. 4.11-4.14; combination in ``services/posecells/gates.py``).  An accepted frame
  publishes an ``ExperienceEvent`` whose header stamp and frame_id are the LVC message's,
  with the pose-cell centroid (x, y, z m in ``[0, n * spacing)``, yaw rad in ``[-pi, pi)``), the
  latest odometry pose, the deciding gate (``vpr`` | ``leak`` | ``off``) and ``C_t``.
  A frame before any odometry still enters the VPR window but creates no event
  (``lvc_before_odometry``).

Counters: ``events``, ``events_vpr`` / ``events_leak`` / ``events_off``, ``rejected_motion``,
``rejected_vpr``, ``lvc_before_odometry``, ``odometry_discontinuities``, ``odometry_non_finite``.

With ``posecells.state_path`` set, the activity, the sparse associations, the gates and the
odometry reference are loaded at start when the file exists and saved (``.npz``) when the
inputs end and when the node closes, so a later run continues where this one stopped.
"""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from common.config import PoseidonConfig
from common.geometry import yaw_of_quaternion
from common.messages import ExperienceEvent, LocalViewCells, Message, Odometry
from common.node import ServiceNode
from services.posecells.gates import EventGate
from services.posecells.network import PoseCellNetwork

__all__ = ["PoseCellsNode", "yaw_of_quaternion"]

log = logging.getLogger(__name__)

_NODE_STATE_VERSION = 1


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class PoseCellsNode(ServiceNode):
    """Runs :class:`PoseCellNetwork` and the event gates on odometry and LVC frames."""

    name = "posecells"
    inputs = ("Odometry", "local_view_cells")
    outputs = ("experience_event",)

    def __init__(self, config: PoseidonConfig):
        super().__init__(config)
        self.cfg = config.posecells
        self.net = PoseCellNetwork(self.cfg)
        self.gate = EventGate(config.vpr_guard)
        self._odom: tuple[list[float], float] | None = None  # latest (position, yaw)
        self._pending = np.zeros(4)  # forward, left, up (m), dyaw (rad) since the last frame
        self._ref_yaw = 0.0  # odometry yaw at the last pose-cell step (frame of the pending motion)
        self._placed = False  # the packet has been placed at an odometry pose
        self.state_path = Path(self.cfg.state_path) if self.cfg.state_path else None
        self._dirty = False
        if self.state_path is not None:
            if self.state_path.exists():
                self._load(self.state_path)
                log.info("posecells: loaded state from %s (%d LVC associations)", self.state_path, len(self.net.beta))
            else:
                log.info("posecells: no state at %s yet, starting fresh", self.state_path)

    # ---- inputs ---------------------------------------------------------------------------
    def process(self, key: str, msg: Message) -> None:
        if key == "Odometry":
            self._on_odometry(msg)  # type: ignore[arg-type]
        elif key == "local_view_cells":
            self._on_lvc(msg)  # type: ignore[arg-type]
        else:
            raise KeyError(f"posecells: unexpected input key {key!r}")

    def _on_odometry(self, msg: Odometry) -> None:
        pos = [float(v) for v in msg.position]
        yaw = yaw_of_quaternion(msg.orientation)
        if not all(math.isfinite(v) for v in pos + [yaw]):
            log.error("posecells: Odometry seq %d skipped: non-finite pose %s yaw %s", msg.header.seq, pos, yaw)
            self.count("odometry_non_finite")
            return
        if self._odom is None:
            if not self._placed:
                self.net.reset_at_pose(pos[0], pos[1], pos[2], yaw)
                self._placed = True
            self._ref_yaw = yaw
        else:
            prev, prev_yaw = self._odom
            d = [pos[i] - prev[i] for i in range(3)]
            if math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) > self.cfg.max_odometry_step:
                log.warning("posecells: Odometry seq %d jumps %.2f m (> posecells.max_odometry_step %.2f m): "
                            "treated as a discontinuity", msg.header.seq, math.sqrt(sum(v * v for v in d)),
                            self.cfg.max_odometry_step)
                self.count("odometry_discontinuities")
            else:
                c, s = math.cos(self._ref_yaw), math.sin(self._ref_yaw)
                self._pending += (c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2], _wrap(yaw - prev_yaw))
        self._odom = (pos, yaw)
        self._dirty = True

    def active_lvcs(self, msg: LocalViewCells) -> list[int]:
        """V_l = 1 set of Eq. 4.19: the most active LVC, plus (multi-hypothesis) the others
        of ``active_cells`` with rate >= ``min_exc``, by rate, up to ``top_k`` in all."""
        active = [int(msg.most_active_cell)]
        if self.cfg.multiple_local_view_active:
            others = sorted((c for c in msg.active_cells if c.id != msg.most_active_cell and c.rate >= self.cfg.min_exc),
                            key=lambda c: (-c.rate, c.id))
            active += [int(c.id) for c in others[: self.cfg.top_k - 1]]
        return active

    def _on_lvc(self, msg: LocalViewCells) -> None:
        lvc_id = int(msg.most_active_cell)
        self._dirty = True
        if self._odom is None:
            self.gate.vpr.observe(lvc_id)
            self.count("lvc_before_odometry")
            return
        forward, left, up, dyaw = (float(v) for v in self._pending)
        self._pending[:] = 0.0
        self._ref_yaw = self._odom[1]
        self.net.step(forward, left, up, dyaw, self.active_lvcs(msg))
        position, yaw = self._odom
        decision = self.gate.decide(lvc_id, position, yaw)
        if not decision.accepted:
            self.count(f"rejected_{decision.gate}")
            return
        self.count("events")
        self.count(f"events_{decision.gate}")
        self.publish("experience_event", ExperienceEvent(
            header=self.header("experience_event", msg.header.stamp, msg.header.frame_id),
            lvc_id=lvc_id,
            pc_centroid=self.net.centroid(),
            odom_position=list(position),
            odom_yaw=yaw,
            gate=decision.gate,
            vpr_count=decision.vpr_count,
        ))

    # ---- persistence ----------------------------------------------------------------------
    def _node_state(self) -> dict:
        return {"version": _NODE_STATE_VERSION, "gate": self.gate.state(),
                "odom": None if self._odom is None else [self._odom[0], self._odom[1]],
                "pending": [float(v) for v in self._pending], "ref_yaw": self._ref_yaw, "placed": self._placed}

    def save(self, path: Path) -> None:
        """Write the network and the node's state to ``path`` (``.npz``)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:  # an open file keeps np.savez from appending ".npz"
            np.savez(f, node_state=np.array(json.dumps(self._node_state())), **self.net.state_arrays())

    def _load(self, path: Path) -> None:
        with np.load(path) as f:
            if "node_state" not in f:
                raise ValueError(f"{path}: not a posecells state file (no node_state)")
            self.net.load_arrays(f, source=str(path))
            state = json.loads(str(f["node_state"]))
        if state.get("version") != _NODE_STATE_VERSION:
            raise ValueError(f"{path}: posecells node state version {state.get('version')}, "
                             f"expected {_NODE_STATE_VERSION}")
        self.gate.load_state(state["gate"])
        self._odom = None if state["odom"] is None else ([float(v) for v in state["odom"][0]], float(state["odom"][1]))
        self._pending = np.array(state["pending"], dtype=np.float64)
        self._ref_yaw = float(state["ref_yaw"])
        self._placed = bool(state["placed"])

    def _save(self) -> None:
        if self.state_path is not None and self._dirty:
            self.save(self.state_path)
            self._dirty = False
            log.info("posecells: saved state to %s (%d LVC associations)", self.state_path, len(self.net.beta))

    def finish(self) -> None:
        self._save()

    def close(self) -> None:
        self._save()
