"""Sessions of the experience map and the rigid move that links two of them.

A map continued by another mission (``sessions.begin_on_load``, ``poseidon run
--map-dir``) or a vehicle whose odometry jumps by more than ``sessions.jump_m`` between two
events (kidnapped) begins a new *session* (:meth:`~services.expmap.graph.ExperienceMap.begin_session`): its first
node sits at its own odometry position (its own frame, unlinked to the earlier nodes), the
chain edge from the previous node is kept with weight :data:`SESSION_BREAK_WEIGHT` (a
resistance of 1e6: it carries the chain's bookkeeping, not a measurement) and every node
carries its session id.  Every node of an earlier session is a loop candidate, whatever
``min_experience_age`` (another mission is never "the place just passed").  A confirmed
match (``loops.confirmations`` consecutive events, as a loop closure) between sessions not yet linked is a *link candidate*: it becomes a link only
when the two experiences' sonar sweeps register trusted along both axes with at least
``sessions.link_min_inliers`` inliers (:func:`services.expmap.loop_policy.link_displacement`,
searched around "the same place", since the separation of two unlinked frames means
nothing); otherwise it is rejected (``rejected = "link"``, the reason counted in
:attr:`~services.expmap.graph.ExperienceMap.link_rejections`).  A link moves the newer component (every session
linked to the new one) rigidly so that the two experiences sit at the measured displacement,
records the link as a loop edge (so relaxation treats it like one from then on; the interval
and route rules do not apply to it) and joins the components: the older one's frame (session
0's, the prior map's) is the frame of both.  The move is a rigid transform about n: the
registration's translation *and* rotation (``sessions.link_rotate``, searched within
``sessions.link_max_rotation_deg``): the newer component's positions, headings, sweeps, chain
deltas and loop deltas turn with it, and so does the odometry of the rest of the session
(:attr:`~services.expmap.graph.ExperienceMap.frame_yaw`).  Depth is not rotated (pressure depth is absolute).  Both
angles are recorded with the link (:class:`SessionLink`: measured and applied).

Backfill: the part of the newer component mapped before the link hangs from the link node
through its odometry chain alone, so it carries the older map's error at that one place plus
the odometry's drift away from it.  Right after the move, every experience i of the newer
component (one per ``sessions.backfill_spacing_m`` of path) is paired with the nearest
experience j of the older component within ``sessions.backfill_radius_m`` in the linked frame;
their sweeps are registered around the separation p_i - p_j (``sessions.backfill_search_m``)
and kept as a loop edge only when trusted along both axes with at least
``sessions.link_min_inliers`` inliers (the link's rule).  The relaxation that follows the link
then pins that part to the older map at every such place (:func:`backfill_pairs` chooses the
pairs; the count is :attr:`SessionLink.backfill_edges`).

:class:`~services.expmap.graph.ExperienceMap` applies these rules for each event; this module
holds what a session link is (:class:`SessionLink`) and the move itself
(:func:`move_component`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from services.expmap.loop_policy import link_displacement

if TYPE_CHECKING:
    from services.expmap.config import ExpMapConfig
    from services.expmap.loop_policy import LoopEdges

__all__ = ["SESSION_BREAK_WEIGHT", "SessionLink", "rot2", "move_component", "backfill_pairs", "backfill"]


#: weight of the chain edge into a session's first node (its displacement is not a measurement)
SESSION_BREAK_WEIGHT = 1e-6


def rot2(theta: float) -> np.ndarray:
    """2-D rotation matrix of ``theta`` rad (counter-clockwise in the map's x, y)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


@dataclass
class SessionLink:
    """A link between two sessions: p_n - p_m = ``delta`` (m), made at event ``stamp`` (ns)."""

    session: int                # the session of n (the newer component's)
    to_session: int             # the session of m
    m: int
    n: int
    stamp: int
    delta: np.ndarray           # (3,) m, map frame
    shift: np.ndarray           # (3,) m: how far the newer component moved
    rotation_deg: float         # heading disagreement of the two sweeps (deg, the registration's)
    inlier_fraction: float
    applied_deg: float = 0.0    # the rotation applied to the newer component (deg; 0: translation only)
    backfill_edges: int = 0     # loop edges the backfill added with the link (module notes)


class MutableSweeps(Protocol):
    """Per-node sonar sweeps, read and replaced by node id (:class:`services.expmap.storage.SweepStore`)."""

    def __getitem__(self, i: int, /) -> np.ndarray | None: ...

    def __setitem__(self, i: int, sweep: np.ndarray | None, /) -> None: ...


def move_component(A: dict[str, np.ndarray], N: int, mask: np.ndarray, n: int, target_n: np.ndarray, theta: float,
                   loop_edges: LoopEdges, scans: MutableSweeps) -> None:
    """Move the nodes ``mask`` (the newer component, node n among them) of the node columns
    ``A`` (first N rows) rigidly about n: x -> R (x - p_n) + ``target_n``, R the rotation of
    ``theta`` rad about the vertical (the registration's: it lays n's sweep onto m's).

    With a rotation, what the moved sessions measured in their own frame turns with them:
    chain deltas inside them, their loop edges, headings and sweeps (relative to their node).
    The chain's bookkeeping: the break edges into and out of the moved sessions absorb the move."""
    R = rot2(theta)
    before = A["pos"][:N].copy()
    moved = before[mask]
    moved[:, :2] = (moved[:, :2] - before[n, :2]) @ R.T
    moved[:, 2] -= before[n, 2]
    A["pos"][:N][mask] = moved + target_n
    if theta != 0.0:
        inner = np.nonzero(mask[1:] & mask[:-1])[0] + 1
        A["delta"][inner, :2] = A["delta"][inner, :2] @ R.T
        for k, (a, b, _w, _s) in enumerate(loop_edges.loops):
            if mask[a] and mask[b]:
                d = loop_edges.deltas[k]
                d[:2] = R @ d[:2]
        A["yaw"][:N][mask] += theta
        for i in np.flatnonzero(mask).tolist():
            sw = scans[i]
            if sw is not None:
                scans[i] = (sw.astype(np.float64) @ R.T).astype(np.float32)
    edge = np.nonzero(mask[1:] != mask[:-1])[0] + 1
    move = A["pos"][:N] - before
    A["delta"][edge] += np.where(mask[edge][:, None], move[edge], -move[edge - 1])
    A["cum"][:N] = np.cumsum(A["delta"][:N], axis=0)


def backfill_pairs(pos: np.ndarray, newer: np.ndarray, older: np.ndarray, has_sweep: np.ndarray, radius_m: float,
                   spacing_m: float) -> list[tuple[int, int]]:
    """(j, i) pairs for the backfill of a link (module notes): i walks the ``newer`` nodes in
    order, at most one per ``spacing_m`` of horizontal path, each with a sweep; j is the nearest
    ``older`` node with a sweep within ``radius_m`` of i horizontally (ties: the oldest).
    ``pos``: node positions (N x 3, m) in the linked frame; the masks are (N,) bool."""
    ref = np.flatnonzero(older & has_sweep)
    out: list[tuple[int, int]] = []
    if ref.size == 0 or radius_m <= 0.0:
        return out
    ref_xy = pos[ref, :2]
    last: np.ndarray | None = None
    for i in np.flatnonzero(newer & has_sweep).tolist():
        xy = pos[i, :2]
        if last is not None and float(np.hypot(*(xy - last))) < spacing_m:
            continue
        d2 = np.sum((ref_xy - xy) ** 2, axis=1)
        k = int(np.argmin(d2))
        if d2[k] <= radius_m * radius_m:
            out.append((int(ref[k]), i))
            last = xy
    return out


def backfill(cfg: ExpMapConfig, pos: np.ndarray, odom: np.ndarray, scans: list[np.ndarray | None],
             newer: np.ndarray, older: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """The backfill of a link just made (module notes): (j, i, delta) for every pair of
    :func:`backfill_pairs` whose sweeps register as strictly as a link's around their separation
    p_i - p_j (:func:`~services.expmap.loop_policy.link_displacement`), delta = p_i - p_j measured
    (m; height from the odometry, pressure depth being absolute)."""
    has_sweep = np.array([sw is not None for sw in scans], bool)
    out = []
    for j, i in backfill_pairs(pos, newer, older, has_sweep, cfg.sessions.backfill_radius_m,
                               cfg.sessions.backfill_spacing_m):
        delta, _reg, _why = link_displacement(cfg, scans[j], scans[i], float(odom[i, 2] - odom[j, 2]),
                                              separation=pos[i] - pos[j], search_radius_m=cfg.sessions.backfill_search_m)
        if delta is not None:
            out.append((j, i, delta))
    return out
