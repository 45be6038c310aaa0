"""Quickest paths over an experience map's edges (``poseidon path``, :mod:`services.expmap.path`)."""
from __future__ import annotations

import heapq
import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from services.expmap.graph import ExperienceMap

__all__ = ["quickest_path", "quickest_path_links"]


def quickest_path(em: ExperienceMap, source: int, target: int) -> tuple[list[int], float, float]:
    """Quickest path over the map's edges (see :func:`quickest_path_links`)."""
    return quickest_path_links(em.positions, [(s, t, d) for s, t, _dl, d, _w, _l in em.edges()], source, target)


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
