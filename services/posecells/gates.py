"""Event gates of the pose-cell node: the motion gate and the VPR Guard (Section 4.2.3).

:class:`VprGuard` implements Eqs. 4.11-4.14 on the stream of most-active LVC ids:

- Eq. 4.11: ``C_t`` = occurrences of ``l_t`` among the last ``w`` emitted ids, ``l_t``
  included.  Every id the front-end emits enters the window (:meth:`VprGuard.observe`),
  whether or not an event follows, and also with the guard OFF (``vpr_count`` is reported).
- Eq. 4.12: ``g_t = C_t >= r``.
- Eqs. 4.13-4.14 (leak): ``q`` counts consecutive guard rejections; when it reaches
  ``L_max`` the identity is accepted anyway (gate ``"leak"``) and ``q`` is reset, as in the
  worked example.  ``L_max = 0`` disables the leak.
- OFF (``require_vpr_for_event: false``): every id is accepted (gate ``"off"``).

:class:`MotionGate`: an event needs ``>= min_event_trans_xy`` metres of horizontal or
``>= min_event_dz`` metres of vertical odometry displacement since the last event (the first
event always passes); with ``min_event_dyaw_deg`` > 0 (ours; 0 = the dissertation's gate) a
turn of that many degrees also passes, so a robot turning on the spot still makes
experiences (the laser preset: the scan registration between experiences then sees a
bounded turn).

How they combine (our decision, see :meth:`EventGate.decide`): the motion gate is asked
first.  A frame that fails it is not a candidate: its id still enters the VPR window, but
the guard makes no decision, so it neither counts as a rejection nor resets ``q``.  A
candidate frame goes to the guard; ``q`` therefore counts consecutive guard rejections of
*candidate* frames, and a forced (leak) acceptance is never lost to the motion gate.  With
the motion gate disabled every frame is a candidate and Eqs. 4.13-4.14 hold per time step.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

from services.posecells.config import VprGuardConfig

__all__ = ["VprGuard", "MotionGate", "EventGate", "GateDecision"]


@dataclass(frozen=True)
class GateDecision:
    """Outcome for one LVC frame: accepted, which rule decided (``vpr`` | ``leak`` | ``off``
    when accepted; ``motion`` | ``vpr`` when rejected), and ``C_t`` (Eq. 4.11)."""

    accepted: bool
    gate: str
    vpr_count: int


class VprGuard:
    """Temporal-consistency gate on the LVC id stream (Eqs. 4.11-4.14)."""

    def __init__(self, window: int = 26, min_rep: int = 3, leak: int = 20, enabled: bool = True):
        if window < 1 or min_rep < 1 or leak < 0:
            raise ValueError(f"VPR Guard needs window >= 1, min_rep >= 1, leak >= 0; got {window}, {min_rep}, {leak}")
        self.window = int(window)
        self.min_rep = int(min_rep)
        self.leak = int(leak)
        self.enabled = bool(enabled)
        self._ids: deque[int] = deque()
        self._counts: Counter[int] = Counter()
        self.rejection_run = 0  # q of Eq. 4.13

    @classmethod
    def from_config(cls, cfg: VprGuardConfig) -> VprGuard:
        return cls(cfg.vpr_window, cfg.vpr_min_rep, cfg.vpr_leak_rate, cfg.require_vpr_for_event)

    def observe(self, lvc_id: int) -> int:
        """Push an emitted id into the window; returns ``C_t`` (Eq. 4.11)."""
        lvc_id = int(lvc_id)
        self._ids.append(lvc_id)
        self._counts[lvc_id] += 1
        if len(self._ids) > self.window:
            old = self._ids.popleft()
            self._counts[old] -= 1
            if self._counts[old] == 0:
                del self._counts[old]
        return self._counts[lvc_id]

    def decide(self, count: int) -> GateDecision:
        """Decision for a candidate frame whose id has ``C_t = count`` (Eqs. 4.12-4.14)."""
        if not self.enabled:
            return GateDecision(True, "off", count)
        if count >= self.min_rep:
            self.rejection_run = 0
            return GateDecision(True, "vpr", count)
        self.rejection_run += 1
        if self.leak > 0 and self.rejection_run >= self.leak:
            self.rejection_run = 0
            return GateDecision(True, "leak", count)
        return GateDecision(False, "vpr", count)

    def step(self, lvc_id: int) -> GateDecision:
        """:meth:`observe` then :meth:`decide` (every frame a candidate)."""
        return self.decide(self.observe(lvc_id))

    def state(self) -> dict[str, Any]:
        return {"ids": list(self._ids), "rejection_run": self.rejection_run}

    def load_state(self, state: dict[str, Any]) -> None:
        self._ids = deque(int(i) for i in state["ids"][-self.window:])
        self._counts = Counter(self._ids)
        self.rejection_run = int(state["rejection_run"])


class MotionGate:
    """Minimum odometry displacement since the last event (Table 4.1, metres)."""

    def __init__(self, min_xy: float = 0.12, min_dz: float = 0.05, enabled: bool = True, min_dyaw_deg: float = 0.0):
        self.min_xy = float(min_xy)
        self.min_dz = float(min_dz)
        self.min_dyaw = math.radians(min_dyaw_deg)
        self.enabled = bool(enabled)
        self.last: tuple[float, float, float] | None = None
        self.last_yaw = 0.0

    @classmethod
    def from_config(cls, cfg: VprGuardConfig) -> MotionGate:
        return cls(cfg.min_event_trans_xy, cfg.min_event_dz, cfg.motion_gate_enable, cfg.min_event_dyaw_deg)

    def passes(self, position: list[float] | tuple[float, ...], yaw: float = 0.0) -> bool:
        """True when the displacement (or, with ``min_dyaw_deg`` > 0, the turn) since the last
        event reaches a threshold."""
        if not self.enabled or self.last is None:
            return True
        dxy = math.hypot(position[0] - self.last[0], position[1] - self.last[1])
        dz = abs(position[2] - self.last[2])
        turned = self.min_dyaw > 0 and abs(math.remainder(yaw - self.last_yaw, 2 * math.pi)) >= self.min_dyaw
        return dxy >= self.min_xy or dz >= self.min_dz or turned

    def mark(self, position: list[float] | tuple[float, ...], yaw: float = 0.0) -> None:
        """An event was emitted at ``position`` (heading ``yaw``)."""
        self.last = (float(position[0]), float(position[1]), float(position[2]))
        self.last_yaw = float(yaw)

    def state(self) -> dict[str, Any]:
        return {"last": list(self.last) if self.last is not None else None, "last_yaw": self.last_yaw}

    def load_state(self, state: dict[str, Any]) -> None:
        last = state["last"]
        self.last = None if last is None else (float(last[0]), float(last[1]), float(last[2]))
        self.last_yaw = float(state.get("last_yaw", 0.0))


class EventGate:
    """Motion gate, then VPR Guard (module docstring)."""

    def __init__(self, cfg: VprGuardConfig):
        self.motion = MotionGate.from_config(cfg)
        self.vpr = VprGuard.from_config(cfg)

    def decide(self, lvc_id: int, position: list[float] | tuple[float, ...], yaw: float = 0.0) -> GateDecision:
        count = self.vpr.observe(lvc_id)
        if not self.motion.passes(position, yaw):
            return GateDecision(False, "motion", count)
        decision = self.vpr.decide(count)
        if decision.accepted:
            self.motion.mark(position, yaw)
        return decision

    def state(self) -> dict[str, Any]:
        return {"motion": self.motion.state(), "vpr": self.vpr.state()}

    def load_state(self, state: dict[str, Any]) -> None:
        self.motion.load_state(state["motion"])
        self.vpr.load_state(state["vpr"])
