"""``poseidon path MAP --from ID --to ID [--json]``: quickest path over the experience map.

MAP is a map file saved by the expmap service (``expmap.map_path``, npz; with ``poseidon run
--map-dir DIR`` it is ``DIR/expmap.npz``) or a run recording (MCAP), whose last ``map``
message is used (with the ``map_sessions`` message of the same nodes, if any).  Dijkstra over
edge durations (each edge usable both ways; a loop-closure edge takes 0 s, it joins two
experiences of the same place).  Prints the node ids, the total duration (s) and the length
(m, along the map positions).  Exit code 2 on a bad file or node id, or when no route exists.

Sessions (:mod:`services.expmap.session_link`): a map of several sessions plans
across a sonar-verified link between two sessions (a 0 s edge, like a loop closure), never
across the chain edge into a session's first node (it joins two odometry frames and measures
nothing: :func:`services.expmap.routes.session_planning_links`).  When the start and the goal
lie in sessions that no link joins, there is no path: exit code 2 and the message names both
sessions and the groups of linked sessions (:class:`services.expmap.routes.SessionsNotLinked`).
A recording without ``map_sessions`` is one session.

``--json`` prints ``{"map": path, "from": id, "to": id, "nodes": [ids...],
"duration_s": float, "length_m": float, "hops": int, "sessions": [session ids in the order
the path visits them], "crossings": [[source, target], ...] (the path's edges between two
sessions, in path order: the session link, or a loop closure made after it)}`` (one session:
``"sessions": [s], "crossings": []``).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["main", "load_map_links", "PlanningMap"]


@dataclass
class PlanningMap:
    """What ``poseidon path`` plans over: positions (N x 3, m), edges (source, target, duration
    s), the session of each node and the session links (m, n) (node ids)."""

    positions: np.ndarray
    links: list[tuple[int, int, float]]
    node_session: np.ndarray
    session_links: list[tuple[int, int]] = field(default_factory=list)


def _load_recording(path: Path) -> PlanningMap:
    from common.mcap_io import read_messages
    from common.messages import ExperienceMap as MapMessage
    from common.messages import MapSessions
    last = None
    sessions: list[MapSessions] = []
    for r in read_messages(path, keys=["map", "map_sessions"]):
        if r.key == "map":
            last = r
        else:
            ms = r.message()
            if isinstance(ms, MapSessions):
                sessions.append(ms)
    if last is None:
        raise ValueError(f"{path}: no 'map' message in this recording")
    msg = last.message()
    if not isinstance(msg, MapMessage):
        raise ValueError(f"{path}: the 'map' record holds a {type(msg).__name__}, not an experience map")
    pos = np.array([n.position for n in msg.nodes], np.float64).reshape(-1, 3)
    ids = [n.id for n in msg.nodes]
    if ids != list(range(len(ids))):
        raise ValueError(f"{path}: map node ids are not 0..{len(ids) - 1}")
    links = [(ln.source, ln.target, ln.duration_s) for ln in msg.links]
    # the map_sessions of that map: the same stamp, else the last one naming as many nodes
    same = [s for s in sessions if s.header.stamp == last.stamp and len(s.node_session) == len(ids)] or \
        [s for s in sessions if len(s.node_session) == len(ids)]
    if not same:
        if sessions:
            raise ValueError(f"{path}: no map_sessions message names the {len(ids)} nodes of the last map")
        return PlanningMap(pos, links, np.zeros(len(ids), np.int64))
    ms = same[-1]
    return PlanningMap(pos, links, np.asarray(ms.node_session, np.int64),
                       [(lk.source, lk.target) for lk in ms.links])


def load_map_links(path: Path) -> PlanningMap:
    """The :class:`PlanningMap` of a map file (npz) or a run recording (MCAP)."""
    if path.suffix == ".mcap":
        return _load_recording(path)
    from services.expmap.config import ExpMapConfig
    from services.expmap.graph import ExperienceMap
    z = np.load(path, allow_pickle=False)
    meta = json.loads(bytes(z["meta"]).decode())
    em = ExperienceMap.load(path, ExpMapConfig(), meta["lattice_shape"], meta["lattice_spacing"])
    return PlanningMap(em.positions.copy(), [(s, t, d) for s, t, _dl, d, _w, _l in em.edges()],
                       em.sessions.astype(np.int64), [(lk.m, lk.n) for lk in em.session_links])


def main(argv: list[str] | None = None) -> int:
    from services.expmap.routes import quickest_path_sessions
    p = argparse.ArgumentParser(prog="poseidon path", description=__doc__.split("\n\n")[0])
    p.add_argument("map", help="map file (npz, expmap.map_path) or run recording (MCAP)")
    p.add_argument("--from", dest="source", type=int, required=True, help="start node id")
    p.add_argument("--to", dest="target", type=int, required=True, help="goal node id")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    path = Path(args.map)
    try:
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        pm = load_map_links(path)
        nodes, duration, length = quickest_path_sessions(pm.positions, pm.links, pm.node_session,
                                                         pm.session_links, args.source, args.target)
    except (ValueError, OSError, KeyError) as exc:
        print(f"poseidon path: {exc}", file=sys.stderr)
        return 2
    sess = [int(pm.node_session[i]) for i in nodes]
    visited = [s for k, s in enumerate(sess) if k == 0 or s != sess[k - 1]]
    crossings = [[nodes[k - 1], nodes[k]] for k in range(1, len(nodes)) if sess[k] != sess[k - 1]]
    if args.json:
        print(json.dumps({"map": str(path), "from": args.source, "to": args.target, "nodes": nodes,
                          "duration_s": duration, "length_m": length, "hops": len(nodes) - 1,
                          "sessions": visited, "crossings": crossings}))
    else:
        print(f"quickest path {args.source} -> {args.target}: {len(nodes) - 1} edges, {duration:.2f} s, "
              f"{length:.2f} m")
        print("nodes: " + " ".join(str(n) for n in nodes))
        if len(visited) > 1:
            print("sessions: " + " -> ".join(str(s) for s in visited) + "; across "
                  + ", ".join(f"{a}-{b}" for a, b in crossings))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
