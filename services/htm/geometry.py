"""Dead-reckoning consistency of a revisit claim (ours).

Repeated structure makes a cave stretch look like an earlier one frame by frame, *in order*:
no appearance score and no sequence score tells the two apart (on sim seed 2103, 37 of the 62
wrong sequence matches were such stretches).  What does tell them apart is where the vehicle
thinks it is.  Dead reckoning drifts, but slowly: the error between two instants grows with the
path flown between them.  :class:`DeadReckoningGate` keeps the dead-reckoned position p_j and
the path length s_j of every stored frame and calls frame j a *plausible* earlier visit of the
current frame t when

    |p_t - p_j| <= r_min + drift * (s_t - s_j)   and   s_t - s_j >= s_min       (G.1)

``r_min`` (m) is the scale of a place (the sensors' footprint: a revisit seen from further away
is another view), ``drift`` (a fraction of the path) the dead reckoning's error growth, and
``s_min`` (m) says what a revisit is: the vehicle flew away and came back (a frame a few metres
back along the path trivially looks alike and is no revisit).  Defaults (htm.dr_gate.*):
r_min 2 m, drift 1 % of the path, s_min 10 m.  They were chosen on sim seeds 1234, 77 and
2101-2105 (r_min 1.5 / 2 m x margin 0.75 / 1.0: 2 m, margin 0.75 kept the lowest seed's
precision at 0.973) and are reported on seeds never used (README).  1 % is about ten times the
simulated DVL's drift and the usual specification of a DVL-aided vehicle (0.2-1 % of distance
travelled): set ``drift`` to your navigation's.  A frame or a stored frame
without a position (no ``Odometry`` yet, an image-set run) is not checked: G.1 holds.

How :class:`services.htm.pipeline.NeocortexHtm` applies it: the frame where the sequence
memory's best diagonal ends, or the TM's frame, must pass; an l* (Eq. 4.9, distance only: the
id carried on from the last metres is no revisit claim) or a prior id counts only if one of its
frames passes.  The best diagonal is still chosen over every stored frame, so a far-off
look-alike keeps the margin low: a veto, not a selector (selecting among plausible frames made
the margin test meaningless, precision 0.963 -> 0.92 on seed 77).  A sequence match the gate
checked (both positions known) needs only ``dr_gate.seqmem_threshold`` / ``_margin`` (1.0 /
0.75 against 1.5 / 1.75 on appearance alone): the far-off look-alikes the higher margin guarded
against are gone.

The path length is the sum of the position increments, so it only needs the positions.  A step
longer than ``jump_m`` between two frames is an odometry discontinuity (a restarted filter, a
kidnapped vehicle): the positions stored before it are forgotten, as are those of a map loaded
from an earlier session (its odometry frame is not this run's).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["DeadReckoningGate"]


class DeadReckoningGate:
    """Positions and path lengths of the stored frames; Eq. G.1 for the frames a claim names."""

    def __init__(self, min_radius_m: float, drift: float, jump_m: float = 2.0, min_path_m: float = 0.0):
        if min_radius_m < 0 or drift < 0 or jump_m <= 0 or min_path_m < 0:
            raise ValueError(f"dead-reckoning gate needs min_radius_m >= 0, drift >= 0, jump_m > 0 and "
                             f"min_path_m >= 0, got {min_radius_m}, {drift}, {jump_m}, {min_path_m}")
        self.min_path_m = float(min_path_m)
        self.min_radius_m = float(min_radius_m)
        self.drift = float(drift)
        self.jump_m = float(jump_m)
        self.discontinuities = 0
        self.pos = np.full((256, 3), np.nan)
        self.path = np.full(256, np.nan)
        self.size = 0
        self.current: NDArray[np.float64] | None = None   # the current frame's position (None: unknown)
        self.current_path = 0.0
        self._last: NDArray[np.float64] | None = None      # last known position (path length increments)

    def locate(self, position: NDArray[np.float64] | list[float] | None) -> None:
        """Set the current frame's dead-reckoned position (m; None: unknown) and advance the path length."""
        if position is None:
            self.current = None
            return
        p = np.asarray(position, np.float64).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ValueError(f"dead-reckoned position must be finite, got {p.tolist()}")
        if self._last is not None:
            step = float(np.linalg.norm(p - self._last))
            if step > self.jump_m:      # a restarted or jumped odometry: earlier positions are in another frame
                self.forget_positions()
                self.discontinuities += 1
            else:
                self.current_path += step
        self._last = p
        self.current = p

    def add(self) -> None:
        """Store the current frame's position (unknown: NaN) as the next memory frame."""
        if self.size == self.pos.shape[0]:
            self.pos = np.vstack([self.pos, np.full_like(self.pos, np.nan)])
            self.path = np.concatenate([self.path, np.full_like(self.path, np.nan)])
        if self.current is not None:
            self.pos[self.size] = self.current
            self.path[self.size] = self.current_path
        self.size += 1

    def passes(self, frames: NDArray[np.int64], revisit: bool = True) -> NDArray[np.bool_] | None:
        """Eq. G.1 per stored frame of ``frames`` (None: the current position is unknown, nothing is
        checked); ``revisit`` False checks the distance only."""
        if self.current is None:
            return None
        d = np.linalg.norm(self.pos[frames] - self.current, axis=1)
        gap = self.current_path - self.path[frames]
        far = d > self.min_radius_m + self.drift * np.maximum(gap, 0.0)
        out: NDArray[np.bool_] = ~((far | (gap < self.min_path_m)) if revisit else far)
        return out      # NaN (an unknown stored position) passes both tests

    def checks(self, frame: int) -> bool:
        """True when Eq. G.1 can be checked for stored ``frame``: both positions are known."""
        return self.current is not None and 0 <= frame < self.size and not np.isnan(self.pos[frame, 0])

    def plausible(self, frame: int, revisit: bool = True) -> bool:
        """Eq. G.1 for one stored frame (scalar arithmetic: the common case of one candidate);
        True when either position is unknown."""
        if self.current is None:
            return True
        p = self.pos[frame]
        if p[0] != p[0]:                 # NaN: unknown stored position
            return True
        gap = self.current_path - float(self.path[frame])
        if revisit and gap < self.min_path_m:
            return False
        c = self.current
        d = math.sqrt((c[0] - p[0]) ** 2 + (c[1] - p[1]) ** 2 + (c[2] - p[2]) ** 2)
        return bool(d <= self.min_radius_m + self.drift * max(gap, 0.0))

    def any_plausible(self, frames: NDArray[np.int64], revisit: bool = True) -> bool:
        """True when one of the stored ``frames`` passes Eq. G.1 (or the frame is unknown); ``revisit``
        False checks the distance only: an id the vehicle carries on from its last frames is no revisit
        claim, but it must still be where the vehicle is."""
        if self.current is None or frames.size == 0:
            return True
        ok = self.passes(frames, revisit)
        return ok is None or bool(np.any(ok))

    def forget_positions(self) -> None:
        """The stored positions are in another odometry frame (a discontinuity, a map loaded from an
        earlier session): they are no longer compared (NaN passes Eq. G.1)."""
        self.pos[:self.size] = np.nan
        self.path[:self.size] = np.nan
        self._last = None

    # ---- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        last = self._last if self._last is not None else np.full(3, np.nan)
        return {"pos": self.pos[:self.size].copy(), "path": self.path[:self.size].copy(),
                "last": last.copy(), "current_path": np.array([self.current_path])}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        if "pos" not in st:
            return
        n = st["pos"].shape[0]
        cap = max(256, n)
        self.pos = np.full((cap, 3), np.nan)
        self.path = np.full(cap, np.nan)
        self.pos[:n], self.path[:n] = st["pos"], st["path"]
        self.size = n
        last = np.asarray(st["last"], np.float64)
        self._last = None if np.any(np.isnan(last)) else last
        self.current_path = float(st["current_path"][0])
