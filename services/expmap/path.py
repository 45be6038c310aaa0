"""``poseidon path MAP --from ID --to ID [--json]``: quickest path over the experience map.

MAP is a map file saved by the expmap service (``expmap.map_path``, npz) or a run
recording (MCAP), whose last ``map`` message is used.  Dijkstra over edge durations (each
edge usable both ways; a loop-closure edge takes 0 s, it joins two experiences of the same
place).  Prints the node ids, the total duration (s) and the length (m, along the map
positions).  Exit code 2 on a bad file or node id, or when no route exists.

``--json`` prints ``{"map": path, "from": id, "to": id, "nodes": [ids...],
"duration_s": float, "length_m": float, "hops": int}``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["main", "load_map_links"]


def load_map_links(path: Path) -> tuple[np.ndarray, list[tuple[int, int, float]]]:
    """Positions (N x 3, m) and links (source, target, duration s) of a map file or a run."""
    if path.suffix == ".mcap":
        from common.mcap_io import read_messages
        last = None
        for r in read_messages(path, keys=["map"]):
            last = r
        if last is None:
            raise ValueError(f"{path}: no 'map' message in this recording")
        from common.messages import ExperienceMap as MapMessage
        msg = last.message()
        if not isinstance(msg, MapMessage):
            raise ValueError(f"{path}: the 'map' record holds a {type(msg).__name__}, not an experience map")
        pos = np.array([n.position for n in msg.nodes], np.float64).reshape(-1, 3)
        ids = [n.id for n in msg.nodes]
        if ids != list(range(len(ids))):
            raise ValueError(f"{path}: map node ids are not 0..{len(ids) - 1}")
        return pos, [(ln.source, ln.target, ln.duration_s) for ln in msg.links]
    from services.expmap.config import ExpMapConfig
    from services.expmap.graph import ExperienceMap
    z = np.load(path, allow_pickle=False)
    meta = json.loads(bytes(z["meta"]).decode())
    em = ExperienceMap.load(path, ExpMapConfig(), meta["lattice_shape"], meta["lattice_spacing"])
    return em.positions.copy(), [(s, t, d) for s, t, _dl, d, _w, _l in em.edges()]


def main(argv: list[str] | None = None) -> int:
    from services.expmap.graph import quickest_path_links
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
        pos, links = load_map_links(path)
        nodes, duration, length = quickest_path_links(pos, links, args.source, args.target)
    except (ValueError, OSError, KeyError) as exc:
        print(f"poseidon path: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"map": str(path), "from": args.source, "to": args.target, "nodes": nodes,
                          "duration_s": duration, "length_m": length, "hops": len(nodes) - 1}))
    else:
        print(f"quickest path {args.source} -> {args.target}: {len(nodes) - 1} edges, {duration:.2f} s, "
              f"{length:.2f} m")
        print("nodes: " + " ".join(str(n) for n in nodes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
