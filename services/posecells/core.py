"""The pose-cell service's core without transport: odometry -> pose-cell steps, the network,
the event gates and their persistence (Sections 4.2.3-4.2.4; the rules are stated in
:mod:`services.posecells.node`).

:class:`OdometryIntegrator` turns odometry poses (ENU, m; yaw rad) into the motion of one
pose-cell step (Eq. 4.15): each increment ``dp = p_t - p_{t-1}`` is added to a pending
motion expressed in the frame of the odometry yaw ``psi_ref`` at the previous step
(``forward, left = R(-psi_ref) (dx, dy)``, ``up = dz``, ``dyaw`` wrapped to [-pi, pi));
an increment longer than ``max_step`` m is a discontinuity that only moves the reference.

:class:`PoseCellsCore` runs :class:`~services.posecells.network.PoseCellNetwork` and
:class:`~services.posecells.gates.EventGate` on those steps and the LVC frames, and saves /
loads everything needed to continue (``.npz``: the network's arrays plus a JSON
``node_state`` record).  Both are plain classes a notebook or a test drives directly.
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from services.posecells.config import PoseCellsConfig, VprGuardConfig
from services.posecells.gates import EventGate, GateDecision
from services.posecells.network import PoseCellNetwork

__all__ = ["OdometryIntegrator", "PoseCellsCore", "LvcStep", "wrap_angle", "NODE_STATE_VERSION"]

NODE_STATE_VERSION = 1


def wrap_angle(a: float) -> float:
    """``a`` (rad) wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class OdometryIntegrator:
    """Odometry poses -> the (forward, left, up m, dyaw rad) motion of the next pose-cell step."""

    def __init__(self, max_step: float):
        self.max_step = float(max_step)
        self.odom: tuple[list[float], float] | None = None  # latest (position m, yaw rad)
        self.pending = np.zeros(4)  # forward, left, up (m), dyaw (rad) since the last step
        self.ref_yaw = 0.0          # odometry yaw at the last pose-cell step (frame of the pending motion)
        self.last_jump = 0.0        # length of the last increment rejected as a discontinuity (m)

    def update(self, position: Sequence[float], yaw: float) -> str:
        """Take one odometry pose; returns ``first`` (no previous pose), ``step`` (the increment
        joined the pending motion), ``discontinuity`` (longer than ``max_step``: skipped) or
        ``non_finite`` (the pose is ignored)."""
        pos = [float(v) for v in position]
        yaw = float(yaw)
        if not all(math.isfinite(v) for v in pos + [yaw]):
            return "non_finite"
        if self.odom is None:
            self.ref_yaw = yaw
            what = "first"
        else:
            prev, prev_yaw = self.odom
            d = [pos[i] - prev[i] for i in range(3)]
            if math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) > self.max_step:
                self.last_jump = math.sqrt(sum(v * v for v in d))
                what = "discontinuity"
            else:
                c, s = math.cos(self.ref_yaw), math.sin(self.ref_yaw)
                self.pending += (c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2], wrap_angle(yaw - prev_yaw))
                what = "step"
        self.odom = (pos, yaw)
        return what

    def take_step(self) -> tuple[float, float, float, float]:
        """The pending (forward, left, up, dyaw), cleared; the reference becomes the latest yaw."""
        forward, left, up, dyaw = (float(v) for v in self.pending)
        self.pending[:] = 0.0
        if self.odom is not None:
            self.ref_yaw = self.odom[1]
        return forward, left, up, dyaw

    def state(self) -> dict[str, Any]:
        return {"odom": None if self.odom is None else [self.odom[0], self.odom[1]],
                "pending": [float(v) for v in self.pending], "ref_yaw": self.ref_yaw}

    def load_state(self, state: dict[str, Any]) -> None:
        self.odom = None if state["odom"] is None else ([float(v) for v in state["odom"][0]], float(state["odom"][1]))
        self.pending = np.array(state["pending"], dtype=np.float64)
        self.ref_yaw = float(state["ref_yaw"])


@dataclass
class LvcStep:
    """One LVC frame's outcome: ``decision`` None when there is no odometry yet (no step ran)."""

    decision: GateDecision | None
    centroid: list[float] | None = None      # pose-cell centroid after the step (x, y, z m, yaw rad)
    position: list[float] | None = None      # latest odometry position (m)
    yaw: float = 0.0                         # latest odometry yaw (rad)


class PoseCellsCore:
    """Network + event gates + odometry integration of the ``posecells`` service."""

    def __init__(self, cfg: PoseCellsConfig, guard: VprGuardConfig):
        self.cfg = cfg
        self.net = PoseCellNetwork(cfg)
        self.gate = EventGate(guard)
        self.odometry = OdometryIntegrator(cfg.max_odometry_step)
        self.placed = False  # the packet has been placed at an odometry pose

    def on_odometry(self, position: Sequence[float], yaw: float) -> str:
        """:meth:`OdometryIntegrator.update`; the first pose ever places the packet there."""
        what = self.odometry.update(position, yaw)
        if what == "first" and not self.placed:
            odom = self.odometry.odom
            if odom is None:
                raise RuntimeError("posecells: the first odometry pose was not kept")
            pos = odom[0]
            self.net.reset_at_pose(pos[0], pos[1], pos[2], float(yaw))
            self.placed = True
        return what

    def active_lvcs(self, most_active: int, active_cells: Iterable[Any]) -> list[int]:
        """V_l = 1 set of Eq. 4.19: the most active LVC, plus (multi-hypothesis) the others of
        ``active_cells`` (objects with ``id`` and ``rate``) with rate >= ``min_exc``, by rate,
        up to ``top_k`` in all."""
        active = [int(most_active)]
        if self.cfg.multiple_local_view_active:
            others = sorted((c for c in active_cells if c.id != most_active and c.rate >= self.cfg.min_exc),
                            key=lambda c: (-c.rate, c.id))
            active += [int(c.id) for c in others[: self.cfg.top_k - 1]]
        return active

    def on_lvc(self, most_active: int, active_cells: Iterable[Any]) -> LvcStep:
        """One time step: path-integrate the pending motion, inject and learn the active LVCs,
        update the attractor, then the event gate decides (motion gate, VPR Guard)."""
        lvc_id = int(most_active)
        if self.odometry.odom is None:
            self.gate.vpr.observe(lvc_id)
            return LvcStep(decision=None)
        active = self.active_lvcs(most_active, active_cells)
        self.net.step(*self.odometry.take_step(), active)
        position, yaw = self.odometry.odom
        decision = self.gate.decide(lvc_id, position, yaw)
        centroid = self.net.centroid() if decision.accepted else None
        return LvcStep(decision=decision, centroid=centroid, position=list(position), yaw=yaw)

    # ---- persistence ----------------------------------------------------------------------
    def node_state(self) -> dict[str, Any]:
        """The JSON record saved beside the network's arrays."""
        o = self.odometry.state()
        return {"version": NODE_STATE_VERSION, "gate": self.gate.state(), "odom": o["odom"],
                "pending": o["pending"], "ref_yaw": o["ref_yaw"], "placed": self.placed}

    def save(self, path: Path) -> None:
        """Write the network and the core's state to ``path`` (``.npz``)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:  # an open file keeps np.savez from appending ".npz"
            # numpy's savez stub types **kwds against its allow_pickle: bool keyword
            np.savez(f, node_state=np.array(json.dumps(self.node_state())),
                     **self.net.state_arrays())  # type: ignore[arg-type]

    def load(self, path: Path) -> None:
        """Continue from a file written by :meth:`save` (same lattice)."""
        with np.load(path) as f:
            if "node_state" not in f:
                raise ValueError(f"{path}: not a posecells state file (no node_state)")
            self.net.load_arrays(f, source=str(path))
            state = json.loads(str(f["node_state"]))
        if state.get("version") != NODE_STATE_VERSION:
            raise ValueError(f"{path}: posecells node state version {state.get('version')}, "
                             f"expected {NODE_STATE_VERSION}")
        self.placed = bool(state["placed"])
        if self.cfg.state_new_odometry_frame:   # another mission's frame: only the network carries over
            return
        self.gate.load_state(state["gate"])
        self.odometry.load_state(state)
