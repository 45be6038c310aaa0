"""Quickest paths over an experience map's edges (``poseidon path``, :mod:`services.expmap.path`).

Sessions: the chain edge into a session's first node joins two odometry frames and
measures nothing (:data:`services.expmap.session_link.SESSION_BREAK_WEIGHT`), so it is no
route: :func:`session_planning_links` drops every chain edge between two sessions and keeps the
sonar-verified links (0 s, like a loop closure).  Two sessions not joined by links are
separate maps: :func:`session_groups` says which are joined, and :func:`quickest_path_sessions`
refuses a path between two groups with :class:`SessionsNotLinked`, naming the sessions.
"""
from __future__ import annotations

import heapq
import math
from collections.abc import Iterable
from typing import Any, Protocol

import numpy as np

__all__ = ["RoutableMap", "quickest_path", "quickest_path_links", "quickest_path_sessions", "session_planning_links",
           "session_groups", "SessionsNotLinked"]


class RoutableMap(Protocol):
    """What a path needs of a map (:class:`services.expmap.graph.ExperienceMap` has it)."""

    @property
    def positions(self) -> np.ndarray: ...

    @property
    def sessions(self) -> np.ndarray: ...

    @property
    def session_links(self) -> list[Any]: ...

    def edges(self) -> list[tuple[int, int, np.ndarray, float, float, bool]]: ...


def quickest_path(em: RoutableMap, source: int, target: int) -> tuple[list[int], float, float]:
    """Quickest path over the map's edges, across linked sessions only (see
    :func:`quickest_path_sessions`)."""
    links = [(s, t, d) for s, t, _dl, d, _w, _l in em.edges()]
    session_links = [(lk.m, lk.n) for lk in em.session_links]
    return quickest_path_sessions(em.positions, links, em.sessions, session_links, source, target)


class SessionsNotLinked(ValueError):
    """Start and goal lie in sessions that no chain of verified links joins."""

    def __init__(self, source: int, target: int, source_session: int, target_session: int,
                 groups: list[list[int]]) -> None:
        self.source_session, self.target_session, self.groups = source_session, target_session, groups
        shown = "; ".join("{" + ", ".join(str(s) for s in g) + "}" for g in groups)
        super().__init__(f"node {source} is in session {source_session} and node {target} in session "
                         f"{target_session}, which are not linked (no sonar-verified link joins them; linked "
                         f"sessions: {shown}): no path between them")


def session_planning_links(links: Iterable[Any], node_session: Any, session_links: Iterable[Any] = ()
                           ) -> list[tuple[int, int, float]]:
    """The edges a path may use: ``links`` (source, target, duration s) without the chain edges
    between two sessions (node ids ``i`` and ``i + 1`` in different sessions of ``node_session``),
    plus each session link (m, n) as a 0 s edge (a loop edge of the map already; added again in
    case the map does not list it)."""
    sess = np.asarray(node_session, np.int64)
    out = []
    for s, t, d in links:
        s, t = int(s), int(t)
        if abs(s - t) == 1 and sess[s] != sess[t]:
            continue                      # the session break: two frames, no measurement
        out.append((s, t, float(d)))
    out += [(int(m), int(n), 0.0) for m, n in session_links]
    return out


def session_groups(node_session: Any, session_links: Iterable[Any]) -> dict[int, list[int]]:
    """Session -> the sorted sessions linked to it (directly or through others) by the links
    (m, n) (node ids)."""
    sess = np.asarray(node_session, np.int64)
    root = {int(s): int(s) for s in np.unique(sess)}

    def find(a: int) -> int:
        while root[a] != a:
            root[a] = root[root[a]]
            a = root[a]
        return a
    for m, n in session_links:
        a, b = find(int(sess[int(m)])), find(int(sess[int(n)]))
        if a != b:
            root[max(a, b)] = min(a, b)
    groups: dict[int, list[int]] = {}
    for s in sorted(root):
        groups.setdefault(find(s), []).append(s)
    return {s: groups[find(s)] for s in root}


def quickest_path_sessions(positions: np.ndarray, links: Iterable[Any], node_session: Any,
                           session_links: Iterable[Any], source: int, target: int) -> tuple[list[int], float, float]:
    """:func:`quickest_path_links` over :func:`session_planning_links`; raises
    :class:`SessionsNotLinked` when ``source`` and ``target`` lie in sessions no link joins."""
    n = len(positions)
    for name, v in (("from", source), ("to", target)):
        if not 0 <= v < n:
            raise ValueError(f"--{name} {v}: the map has nodes 0..{n - 1}")
    sess = np.asarray(node_session, np.int64)
    if len(sess) != n:
        raise ValueError(f"{len(sess)} node sessions for a map of {n} nodes")
    session_links = [(int(m), int(k)) for m, k in session_links]
    groups = session_groups(sess, session_links)
    a, b = int(sess[source]), int(sess[target])
    if groups[a] != groups[b]:
        unique = sorted({tuple(g) for g in groups.values()})
        raise SessionsNotLinked(source, target, a, b, [list(g) for g in unique])
    return quickest_path_links(positions, session_planning_links(links, sess, session_links), source, target)


def quickest_path_links(positions: np.ndarray, links: Iterable[Any], source: int,
                        target: int) -> tuple[list[int], float, float]:
    """Dijkstra over edge durations, each edge usable both ways (a loop edge takes 0 s).

    ``links``: (source, target, duration s).  Returns (node ids from source to target, total
    duration s, length m along the map positions).  Raises ValueError for an unknown node or
    when no route exists.
    """
    n = len(positions)
    for name, v in (("from", source), ("to", target)):
        if not 0 <= v < n:
            raise ValueError(f"--{name} {v}: the map has nodes 0..{n - 1}")
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for s, t, d in links:
        d = max(float(d), 0.0)
        adj[int(s)].append((int(t), d))
        adj[int(t)].append((int(s), d))
    dist = [math.inf] * n
    prev = [-1] * n
    dist[source] = 0.0
    heap = [(0.0, source)]
    while heap:
        d, u = heapq.heappop(heap)
        if u == target:
            break
        if d > dist[u]:
            continue
        for v, w in adj[u]:
            nd = d + w
            if nd < dist[v]:
                dist[v] = nd
                prev[v] = u
                heapq.heappush(heap, (nd, v))
    if not math.isfinite(dist[target]):
        raise ValueError(f"no route from node {source} to node {target}")
    path = [target]
    while path[-1] != source:
        path.append(prev[path[-1]])
    path.reverse()
    p = np.asarray(positions, float)[path]
    length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(path) > 1 else 0.0
    return path, float(dist[target]), length
