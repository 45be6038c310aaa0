"""Pose-cell service: ``Odometry`` + ``local_view_cells`` -> ``experience_event`` and
``posecells/activity`` (Sections 4.2.3-4.2.4).

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

Every ``posecells.activity_period_s`` of event time (0: off), a pose-cell step also publishes
``posecells/activity`` (:mod:`services.posecells.activity`): the activity summed over (z, yaw)
and over (x, y) as uint8 images with their scales, and the centroid; header stamp and frame_id
are the LVC message's.

Counters: ``events``, ``events_vpr`` / ``events_leak`` / ``events_off``, ``rejected_motion``,
``rejected_vpr``, ``lvc_before_odometry``, ``odometry_discontinuities``, ``odometry_non_finite``.

With ``posecells.state_path`` set, the activity, the sparse associations, the gates and the
odometry reference are loaded at start when the file exists and saved (``.npz``) when the
inputs end and when the node closes, so a later run continues where this one stopped.

The rules live in :class:`services.posecells.core.PoseCellsCore` (odometry integration in
:class:`~services.posecells.core.OdometryIntegrator`); the node subscribes, calls the core,
publishes, counts and logs.
"""
from __future__ import annotations

import logging
from pathlib import Path

from common.geometry import yaw_of_quaternion
from common.messages import ExperienceEvent, LocalViewCell, LocalViewCells, Message, Odometry
from common.node import ServiceNode
from services.posecells.activity import ACTIVITY_KEY, ActivityClock, activity_message
from services.posecells.config import PoseCellsConfig, VprGuardConfig
from services.posecells.core import PoseCellsCore
from services.posecells.gates import EventGate
from services.posecells.network import PoseCellNetwork

__all__ = ["PoseCellsNode", "yaw_of_quaternion"]

log = logging.getLogger(__name__)


class PoseCellsNode(ServiceNode[PoseCellsConfig]):
    """Runs :class:`PoseCellsCore` on odometry and LVC frames."""

    name = "posecells"
    inputs = ("Odometry", "local_view_cells")
    outputs = ("experience_event", ACTIVITY_KEY)

    @classmethod
    def io_keys(cls, config: PoseCellsConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """``posecells/activity`` only when ``activity_period_s`` > 0."""
        outs = ("experience_event", ACTIVITY_KEY) if config.activity_period_s > 0 else ("experience_event",)
        return tuple(cls.inputs), outs

    def __init__(self, config: PoseCellsConfig, guard: VprGuardConfig):
        """``config``: the ``posecells`` section; ``guard``: the ``vpr_guard`` section."""
        super().__init__(config)
        self.cfg = config
        self.guard = guard
        self.core = PoseCellsCore(self.cfg, guard)
        self.state_path = Path(self.cfg.state_path) if self.cfg.state_path else None
        self._dirty = False
        self.activity_clock = ActivityClock(self.cfg.activity_period_s)
        if self.state_path is not None:
            if self.state_path.exists():
                self.core.load(self.state_path)
                log.info("posecells: loaded state from %s (%d LVC associations)", self.state_path, len(self.net.beta))
            else:
                log.info("posecells: no state at %s yet, starting fresh", self.state_path)

    def warm_up(self) -> None:
        """Compile the network's kernels on a throwaway core: odometry along a line and LVC
        frames, the first ones seen again (injection); the node's own core is untouched."""
        core = PoseCellsCore(self.cfg, self.guard)
        for i in range(30):
            core.on_odometry([0.2 * i, 0.0, 0.0], 0.0)
            lvc = i % 10
            core.on_lvc(lvc, [LocalViewCell(id=lvc, rate=1.0)])

    @property
    def net(self) -> PoseCellNetwork:
        """The pose-cell network of the core."""
        return self.core.net

    @property
    def gate(self) -> EventGate:
        """The event gates of the core."""
        return self.core.gate

    # ---- inputs ---------------------------------------------------------------------------
    def process(self, key: str, msg: Message) -> None:
        if key == "Odometry":
            if not isinstance(msg, Odometry):
                raise TypeError(f"posecells: {key!r} carries {type(msg).__name__}, expected Odometry")
            self._on_odometry(msg)
        elif key == "local_view_cells":
            if not isinstance(msg, LocalViewCells):
                raise TypeError(f"posecells: {key!r} carries {type(msg).__name__}, expected LocalViewCells")
            self._on_lvc(msg)
        else:
            raise KeyError(f"posecells: unexpected input key {key!r}")

    def _on_odometry(self, msg: Odometry) -> None:
        pos = [float(v) for v in msg.position]
        yaw = yaw_of_quaternion(msg.orientation)
        what = self.core.on_odometry(pos, yaw)
        if what == "non_finite":
            log.error("posecells: Odometry seq %d skipped: non-finite pose %s yaw %s", msg.header.seq, pos, yaw)
            self.count("odometry_non_finite")
            return
        if what == "discontinuity":
            log.warning("posecells: Odometry seq %d jumps %.2f m (> posecells.max_odometry_step %.2f m): "
                        "treated as a discontinuity", msg.header.seq, self.core.odometry.last_jump, self.cfg.max_odometry_step)
            self.count("odometry_discontinuities")
        self._dirty = True

    def _on_lvc(self, msg: LocalViewCells) -> None:
        self._dirty = True
        step = self.core.on_lvc(msg.most_active_cell, msg.active_cells)
        decision = step.decision
        if decision is None:
            self.count("lvc_before_odometry")
            return
        if self.activity_clock.due(msg.header.stamp):
            self.publish(ACTIVITY_KEY, activity_message(
                self.net, self.header(ACTIVITY_KEY, msg.header.stamp, msg.header.frame_id)))
        if not decision.accepted:
            self.count(f"rejected_{decision.gate}")
            return
        self.count("events")
        self.count(f"events_{decision.gate}")
        assert step.centroid is not None and step.position is not None   # an accepted step carries both
        self.publish("experience_event", ExperienceEvent(
            header=self.header("experience_event", msg.header.stamp, msg.header.frame_id),
            lvc_id=int(msg.most_active_cell),
            pc_centroid=step.centroid,
            odom_position=step.position,
            odom_yaw=step.yaw,
            gate=decision.gate,
            vpr_count=decision.vpr_count,
        ))

    # ---- persistence ----------------------------------------------------------------------
    def save(self, path: Path) -> None:
        """Write the network and the node's state to ``path`` (``.npz``)."""
        self.core.save(path)

    def _save(self) -> None:
        if self.state_path is not None and self._dirty:
            self.core.save(self.state_path)
            self._dirty = False
            log.info("posecells: saved state to %s (%d LVC associations)", self.state_path, len(self.net.beta))

    def finish(self) -> None:
        self._save()

    def close(self) -> None:
        self._save()
