"""The ``sessions`` block of ``poseidon eval``: a map built over several missions
(``poseidon run --map-dir``) or a mission whose odometry jumped (kidnapped vehicle), judged
against ground truth.

The run's last ``map_sessions`` message (:class:`common.messages.MapSessions`) gives the
session of every node of the final ``map``, how many nodes were loaded from the map of
earlier missions (their stamps are those missions', so their truth comes from ``prior``: the
recording of the run that saved the map, ``poseidon eval --prior PRIOR_RUN.mcap``) and the
links made.  Truth of a node = ``truth/pose`` of its own mission at its stamp.

Keys (``null`` when not computable: no truth for an end, no link, no ``--prior``):

- ``count``: sessions in the final map (1 for a map without ``map_sessions``, 0 without map);
- ``loaded_nodes``: nodes that came from the map directory; ``unlinked_nodes``: nodes of this
  run whose session is not linked to session 0 at the end;
- ``links``: session links in the final map; ``false_links``: links whose transform is off
  by more than ``link_far_m`` (2 m) or ``link_far_deg`` (10 degrees) against truth;
- ``table``: per link ``{session, to_session, source, target, stamp_s (mission s of this
  run), error_m, rotation_error_deg, false, time_to_link_s, inlier_fraction}``.  ``error_m``
  = |R delta - (g_target - g_source)| with delta the displacement the link asks for (taken to
  NED) and R the rotation of the rigid alignment of session 0's nodes to their truth (the
  map's frame in the world); ``rotation_error_deg`` = the heading error of the link's target
  node in the final map relative to its source node's (their map headings against their true
  headings: after a link that applies its rotation, the link's heading error; with
  ``expmap.sessions.link_rotate`` off, the frames' heading difference);
- ``time_to_link_s``: for the first link of this run, the mission seconds from the first
  ``truth/pose`` sample of the linked session within ``place_m`` (2 m, horizontally) of the
  true position of an older node (first entering a mapped place) to the link's event.  An
  older node is one loaded from another mission's map, or one of this mission made at least
  ``expmap.min_experience_age`` experiences before the sample (the rule of a revisit
  opportunity in ``loop_closures``: the place just passed is no revisit; for a kidnapped
  vehicle the place of the jump, which it was mapping at that moment, is not one); negative
  when the link came before (the sonar registers up to ``expmap.scan.search_radius_m`` apart);
- ``link_error_m``: mean ``error_m`` over the links with truth at both ends;
- ``cross_loop_closures``: ``{accepted, true, false, unlabelled}`` of the loop closures of
  the final map with one end loaded from the map directory and the other made by this run
  (the loaded map's own closures are not counted), session links excepted (they are
  left out of ``loop_closures``, whose truth is this run's only); true when the two ends'
  truths are within ``far_m`` (5 m), as there;
- ``ate_prior_frame_m``: RMSE (m) of this run's nodes linked to session 0 against truth
  after the rigid alignment of session 0's nodes only (no re-alignment: the error of the
  map in the prior map's frame); ``ate_prior_frame_n``: nodes used;
- ``dr_ate_at_link_m``: the same nodes' dead reckoning (this run's ``Odometry`` at their
  stamps) against truth after the rigid transform (yaw and translation) that puts the dead
  reckoning's pose at the first link's node on its true pose (the issue's comparison: the map
  in the prior frame against dead reckoning aligned at the link); ``dr_ate_at_link_n``: nodes;
- ``ate_prior_frame_after_link_m``, ``dr_ate_at_link_after_m``: the same two over the nodes
  from the first link on (what the prior map does for the rest of the mission);
- ``dr_ate_by_link_m``, ``dr_ate_by_link_after_m``: the same dead reckoning put into the prior
  frame by the link itself instead of the truth: its pose at the first link's node placed on
  that node's pose in the final map (session 0's alignment to the world applied, as for
  ``ate_prior_frame_m``).  This is what a vehicle has without the map's corrections: it knows
  where it is in the prior frame only through the link, so it carries the prior map's error
  at the link place, as the map does.  ``dr_ate_at_link_m`` (truth at the link) is the
  stricter baseline: a vehicle told exactly where it was, which no vehicle is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from eval.results import CrossLoopClosures, SessionLinkRow, SessionsBlock
from eval.rundata import RunData
from eval.trajectory import align_rigid

__all__ = ["sessions_block", "LINK_FAR_M", "LINK_FAR_DEG", "PLACE_M"]

LINK_FAR_M = 2.0
LINK_FAR_DEG = 10.0
PLACE_M = 2.0


def _truth(run: RunData | None, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3) NED, yaw (n,) rad) of ``run``'s truth at ``stamps``; NaN outside it."""
    pos = np.full((len(stamps), 3), np.nan)
    yaw = np.full(len(stamps), np.nan)
    if run is None or not run.has_truth or not len(stamps):
        return pos, yaw
    tr = run.truth
    assert tr is not None
    ok = tr.covered(stamps)
    if ok.any():
        pos[ok] = tr.positions_at(stamps[ok])
        if run.truth_yaw is not None:
            t = np.asarray(tr.t, np.float64)
            yu = np.unwrap(run.truth_yaw)
            yaw[ok] = np.interp(stamps[ok].astype(np.float64), t, yu)
    return pos, yaw


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _r(v: float | None, nd: int = 4) -> float | None:
    return None if v is None or not math.isfinite(v) else round(float(v), nd)


def _empty_block() -> SessionsBlock:
    return {"count": 0, "loaded_nodes": 0, "unlinked_nodes": 0, "links": 0, "false_links": 0,
            "time_to_link_s": None, "link_error_m": None, "ate_prior_frame_m": None,
            "ate_prior_frame_n": 0, "dr_ate_at_link_m": None, "dr_ate_at_link_n": 0,
            "ate_prior_frame_after_link_m": None, "dr_ate_at_link_after_m": None,
            "dr_ate_by_link_m": None, "dr_ate_by_link_after_m": None,
            "cross_loop_closures": {"accepted": 0, "true": 0, "false": 0, "unlabelled": 0},
            "table": []}


@dataclass
class _MapNodes:
    """The final map's nodes (in id order) with their truth: the loaded ones' from ``prior``."""

    sess: np.ndarray        # (n,) session id
    loaded: int             # nodes loaded from the map directory (the first ``loaded``)
    stamps: np.ndarray      # (n,) ns
    pos_ned: np.ndarray     # (n, 3) map positions taken to NED
    yaw_ned: np.ndarray     # (n,) map headings in NED
    g: np.ndarray           # (n, 3) true positions, NED (NaN: no truth)
    gy: np.ndarray          # (n,) true headings (NaN: no truth)


def _map_nodes(run: RunData, prior: RunData | None, nodes: list[Any], sess: np.ndarray, loaded: int) -> _MapNodes:
    n_nodes = len(nodes)
    stamps = np.array([n.stamp for n in nodes], np.int64)
    pos_ned = run.to_ned(np.array([n.position for n in nodes], np.float64))
    # the nodes' odometry heading in NED: the published heading vector taken to NED
    yaw_pub = np.array([n.yaw for n in nodes])
    hv = run.to_ned(np.stack([np.cos(yaw_pub), np.sin(yaw_pub), np.zeros(n_nodes)], axis=1))
    yaw_ned = np.arctan2(hv[:, 1], hv[:, 0])
    g = np.full((n_nodes, 3), np.nan)
    gy = np.full(n_nodes, np.nan)
    g[:loaded], gy[:loaded] = _truth(prior, stamps[:loaded])
    g[loaded:], gy[loaded:] = _truth(run, stamps[loaded:])
    return _MapNodes(sess, loaded, stamps, pos_ned, yaw_ned, g, gy)


def _linked_to_first(count: int, links: list[Any], sess: np.ndarray) -> np.ndarray:
    """Per node: its session is linked to session 0 at the end."""
    root = {s: s for s in range(count)}
    for lk in links:
        a, b = root[lk.session], root[lk.to_session]
        for s, r in root.items():
            if r == a:
                root[s] = b
    return np.array([root[int(s)] == 0 for s in sess])


def _time_to_link(run: RunData, lk: Any, nd: _MapNodes) -> float | None:
    """Mission seconds from the linked session first entering a mapped place (its truth within
    :data:`PLACE_M` of an older node's: one loaded from another mission, or one of this mission
    made at least ``expmap.min_experience_age`` experiences before) to the link (module docstring)."""
    first = int(np.flatnonzero(nd.sess == lk.session)[0])
    known = np.all(np.isfinite(nd.g[:first]), axis=1)
    if not (run.has_truth and known.any() and lk.target >= nd.loaded):
        return None
    tr = run.truth
    assert tr is not None
    ts = np.asarray(tr.t, np.int64)
    ts = ts[ts >= nd.stamps[first]]
    tp = tr.positions_at(ts)
    ids = np.arange(first)
    # the experience being made at each truth sample (this mission's nodes are in stamp order)
    made = nd.loaded + np.searchsorted(nd.stamps[nd.loaded:], ts, side="right") - 1
    age = run.config.expmap.min_experience_age
    for i, p in enumerate(tp):
        mapped = known & ((ids < nd.loaded) | (ids <= made[i] - age))
        if mapped.any() and float(np.min(np.hypot(*(nd.g[:first][mapped, :2] - p[:2]).T))) <= PLACE_M:
            return _r((lk.stamp - int(ts[i])) * 1e-9, 3)
    return None


def _link_row(run: RunData, lk: Any, nd: _MapNodes, rot: np.ndarray | None, t0: int) -> tuple[SessionLinkRow, float | None]:
    """One link's row of the ``table`` and its position error (m; None without truth)."""
    i, j = lk.source, lk.target
    row: SessionLinkRow = {"session": lk.session, "to_session": lk.to_session, "source": i, "target": j,
                           "stamp_s": _r((lk.stamp - t0) * 1e-9, 3), "error_m": None,
                           "rotation_error_deg": None, "false": None, "time_to_link_s": None,
                           "inlier_fraction": _r(lk.inlier_fraction)}
    err = None
    g, gy = nd.g, nd.gy
    if rot is not None and np.all(np.isfinite(g[[i, j]])):
        d_ned = run.to_ned(np.asarray(lk.delta, np.float64)[None, :])[0]
        err = float(np.linalg.norm(rot @ d_ned - (g[j] - g[i])))
        row["error_m"] = _r(err)
        if math.isfinite(gy[i]) and math.isfinite(gy[j]):
            e_i, e_j = _wrap(nd.yaw_ned[i] - gy[i]), _wrap(nd.yaw_ned[j] - gy[j])
            rot_err = _r(math.degrees(abs(_wrap(e_j - e_i))), 3)
            row["rotation_error_deg"] = rot_err
            row["false"] = bool(err > LINK_FAR_M or (rot_err is not None and rot_err > LINK_FAR_DEG))
    row["time_to_link_s"] = _time_to_link(run, lk, nd)
    return row, err


def _count_cross_loop_closures(cross: CrossLoopClosures, map_links: list[Any], session_links: set[tuple[int, int]],
                               nd: _MapNodes, far_m: float) -> None:
    """Loop closures with one end loaded from the map directory and the other made by this
    run, session links excepted (the loaded map's own closures are the prior run's)."""
    n_nodes = len(nd.stamps)
    for e in map_links:
        a, b = min(e.source, e.target), max(e.source, e.target)
        if (not e.loop_closure or a >= nd.loaded or b < nd.loaded or (a, b) in session_links
                or not (0 <= a < n_nodes and 0 <= b < n_nodes)):
            continue
        cross["accepted"] += 1
        if not np.all(np.isfinite(nd.g[[a, b]])):
            cross["unlabelled"] += 1
        elif float(np.linalg.norm(nd.g[a] - nd.g[b])) <= far_m:
            cross["true"] += 1
        else:
            cross["false"] += 1


def _ate_in_frame(nd: _MapNodes, use: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> float | None:
    """RMSE (m) of the nodes ``use`` against truth in the frame of session 0's alignment."""
    e = nd.pos_ned[use] @ rot.T + trans - nd.g[use]
    return _r(float(np.sqrt(np.mean(np.sum(e * e, axis=1)))))


def sessions_block(run: RunData, prior: RunData | None = None, far_m: float = 5.0) -> SessionsBlock:
    """The ``sessions`` block (module docstring)."""
    m = run.final_map
    out = _empty_block()
    if m is None or not m.nodes:
        return out
    nodes = sorted(m.nodes, key=lambda n: n.id)
    n_nodes = len(nodes)
    ms = run.final_sessions
    if ms is None:
        out["count"] = 1
        return out
    if len(ms.node_session) != n_nodes:
        raise ValueError(f"{run.path}: map_sessions names {len(ms.node_session)} nodes, the final map has {n_nodes}")
    sess = np.asarray(ms.node_session, np.int64)
    loaded = int(ms.loaded_nodes)
    out["count"], out["loaded_nodes"], out["links"] = int(sess.max()) + 1, loaded, len(ms.links)
    nd = _map_nodes(run, prior, nodes, sess, loaded)
    stamps, g = nd.stamps, nd.g
    # the map's frame in the world: session 0's nodes aligned to their truth
    ref = (sess == 0) & np.all(np.isfinite(g), axis=1)
    rot = trans = None
    if ref.sum() >= 3:
        rot, trans = align_rigid(nd.pos_ned[ref], g[ref])
    mine = np.arange(n_nodes) >= loaded
    linked0 = _linked_to_first(out["count"], ms.links, sess)
    out["unlinked_nodes"] = int((mine & ~linked0).sum())
    t0 = run.start_ns if run.start_ns is not None else 0
    errors = []
    for lk in ms.links:
        row, err = _link_row(run, lk, nd, rot, t0)
        if err is not None:
            errors.append(err)
        out["table"].append(row)
    out["false_links"] = sum(bool(r["false"]) for r in out["table"])
    mine_links = [r for r in out["table"] if r["target"] >= loaded]
    if mine_links:
        out["time_to_link_s"] = mine_links[0]["time_to_link_s"]
    out["link_error_m"] = _r(float(np.mean(errors))) if errors else None
    _count_cross_loop_closures(out["cross_loop_closures"], m.links, {(lk.source, lk.target) for lk in ms.links},
                               nd, far_m)
    use = mine & linked0 & np.all(np.isfinite(g), axis=1)
    if rot is not None and trans is not None and use.any():
        out["ate_prior_frame_m"] = _ate_in_frame(nd, use, rot, trans)
        out["ate_prior_frame_n"] = int(use.sum())
    if mine_links and use.any():
        j = int(mine_links[0]["target"])
        after = use & (stamps >= stamps[j])
        truth_anchor = (g[j], float(nd.gy[j]))
        out["dr_ate_at_link_m"], out["dr_ate_at_link_n"] = _dr_anchored(run, stamps, g, use, j, truth_anchor)
        if rot is not None and trans is not None:
            map_anchor = (rot @ nd.pos_ned[j] + trans, float(nd.yaw_ned[j]) + math.atan2(rot[1, 0], rot[0, 0]))
            out["dr_ate_by_link_m"] = _dr_anchored(run, stamps, g, use, j, map_anchor)[0]
            if after.any():
                out["ate_prior_frame_after_link_m"] = _ate_in_frame(nd, after, rot, trans)
                out["dr_ate_at_link_after_m"] = _dr_anchored(run, stamps, g, after, j, truth_anchor)[0]
                out["dr_ate_by_link_after_m"] = _dr_anchored(run, stamps, g, after, j, map_anchor)[0]
    return out


def _dr_anchored(run: RunData, stamps: np.ndarray, g: np.ndarray, use: np.ndarray, j: int,
                 anchor: tuple[np.ndarray, float]) -> tuple[float | None, int]:
    """RMSE (m) of this run's dead reckoning at the stamps of the nodes ``use`` against their
    truth ``g``, after the rigid transform (yaw about the vertical and translation) that puts
    the dead-reckoning pose at node ``j``'s stamp on ``anchor`` (position NED, heading rad, in
    the world): the truth at ``j`` (a vehicle told exactly where it was, and which way it faced,
    at the link) or node ``j``'s pose in the prior frame (what the link tells the vehicle)."""
    od = run.odometry_poses
    where, heading = anchor
    if od is None or not len(od) or not run.has_truth or not np.all(np.isfinite(where)) or not math.isfinite(heading):
        return None, 0
    at = od.interpolate(stamps[use])
    p = run.to_ned(at.positions)
    yv = run.to_ned(np.stack([np.cos(at.yaws), np.sin(at.yaws), np.zeros(len(at))], axis=1))
    y = np.arctan2(yv[:, 1], yv[:, 0])
    k = int(np.flatnonzero(np.flatnonzero(use) == j)[0]) if use[j] else -1
    if k < 0:
        return None, 0
    a = _wrap(heading - float(y[k]))
    c, s_ = math.cos(a), math.sin(a)
    R = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    q = (p - p[k]) @ R.T + np.asarray(where, np.float64)
    e = q - g[use]
    return _r(float(np.sqrt(np.mean(np.sum(e * e, axis=1))))), int(use.sum())
