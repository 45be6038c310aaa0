"""``poseidon export RUN --survex OUT.svx [--survex-spacing M]``: the final experience map as a
Survex centreline (``cavern OUT.svx`` processes it; ``aven`` draws it).

- Stations: the experiences (named ``e<id>``), thinned per session in time order: a node is kept
  when it lies at least ``spacing`` m (default 2 m, straight line) from the last kept one; the
  first and last node of a session and both ends of every loop closure are always kept.
- Legs (``*data normal from to tape compass clino``) between consecutive kept stations of a
  session, from their map-corrected positions (the final map's nodes): tape in metres (3D
  distance), compass in degrees clockwise from north, clino in degrees above the horizontal
  (``UP``/``DOWN`` with compass ``-`` for a vertical leg).  North, east and up are the run's
  published frame taken to ENU (:meth:`products.mapsource.MapSource.to_enu`; with the default
  ENU frame: north = +y, east = +x).
- Passage dimensions (``*data passage station left right up down``, m) at each station from the
  range returns at the map-corrected poses (:mod:`products.mapsource`) within +-``LRUD_WINDOW_S``
  (5 s) of the station's stamp, in the station's frame (direction = from the previous to the next
  station, horizontal): left/right = the nearest return to that side within ``LRUD_BAND_M``
  (1 m) along the passage and vertically; up/down = the nearest return above/below within 1 m
  along and across.  ``-`` where no return qualifies (a planar laser or horizontal sonar never
  gives up/down).
- Loop closures (links of the final map flagged ``loop_closure``, delta = p_target - p_source
  measured by the map): a leg flagged ``duplicate`` from the source station to a station
  ``lc<k>`` at the measured delta, and ``*equate`` of ``lc<k>`` with the target station (a plain
  ``*equate`` of the two when the delta is under 1 mm).  cavern's loop misclosures are then the
  disagreement between the map-corrected positions and the loop closures' own measurements;
  ``duplicate`` keeps them out of the survey length.
- Each session of a multi-session map (``map_sessions``) is its own ``*begin s<session>`` /
  ``*end`` block inside ``*begin poseidon``; the first station of a session not joined to an
  earlier one by a loop closure is ``*fix``-ed at its map position (E, N, up; m), so the survey's
  coordinates are the map's.  ``*date`` per session from its first experience's stamp (UTC).
- Comments: the input, the recording's code revision and input, the exporter's code revision,
  the recording's time span (from its stamps, not the wall clock), frame, units, what is left out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from common.mcap_io import code_revision
from common.messages import ExperienceMap
from products.mapsource import MapSource, Returns, write_outputs
from products.rosbag import ExportError

__all__ = ["export_survex", "DEFAULT_SPACING_M", "LRUD_WINDOW_S", "LRUD_BAND_M"]

DEFAULT_SPACING_M = 2.0
LRUD_WINDOW_S = 5.0
LRUD_BAND_M = 1.0


@dataclass
class _Session:
    sid: int
    ids: list[int]          # kept node ids, time order
    legs: list[tuple[int, int, float]]   # from, to, tape (m)


def _utc(ns: int) -> datetime:
    return datetime.fromtimestamp(ns / 1e9, tz=UTC)


def _leg(d: np.ndarray) -> tuple[str, float]:
    """``tape compass clino`` text of an ENU displacement, and the tape (m, as written)."""
    tape = float(np.linalg.norm(d))
    horiz = math.hypot(d[0], d[1])
    if horiz < 1e-6:
        return f"{tape:.3f} - {'UP' if d[2] > 0 else 'DOWN'}", round(tape, 3)
    compass = math.degrees(math.atan2(d[0], d[1])) % 360.0
    clino = math.degrees(math.atan2(d[2], horiz))
    return f"{tape:.3f} {compass:.3f} {clino:.3f}", round(tape, 3)


def _thin(m: ExperienceMap, node_session: np.ndarray, enu: dict[int, np.ndarray], spacing: float,
          keep: set[int]) -> list[_Session]:
    """The kept stations and legs of every session (module docstring)."""
    by_session: dict[int, list[tuple[int, int]]] = {}
    for k, n in enumerate(m.nodes):
        by_session.setdefault(int(node_session[k]), []).append((n.stamp, n.id))
    out = []
    for sid in sorted(by_session):
        nodes = [i for _, i in sorted(by_session[sid])]
        kept = [nodes[0]]
        for k, i in enumerate(nodes[1:], 1):
            far = np.linalg.norm(enu[i] - enu[kept[-1]]) >= spacing
            if far or i in keep or k == len(nodes) - 1:
                kept.append(i)
        legs = [(a, b, _leg(enu[b] - enu[a])[1]) for a, b in zip(kept, kept[1:])]
        out.append(_Session(sid, kept, legs))
    return out


def _lrud(ret: Returns | None, enu_pts: np.ndarray | None, at: np.ndarray, stamp: int,
          direction: np.ndarray) -> list[str]:
    """Left, right, up, down (m, text; ``-`` when unknown) at ENU position ``at``."""
    if ret is None or enu_pts is None:
        return ["-"] * 4
    lo, hi = np.searchsorted(ret.stamps, [stamp - int(LRUD_WINDOW_S * 1e9), stamp + int(LRUD_WINDOW_S * 1e9)],
                             side="left")
    v = enu_pts[lo:hi] - at
    h = np.array([direction[0], direction[1]]) / max(float(np.hypot(direction[0], direction[1])), 1e-12)
    along = v[:, 0] * h[0] + v[:, 1] * h[1]
    lateral = -v[:, 0] * h[1] + v[:, 1] * h[0]          # positive to the left
    near = np.abs(along) <= LRUD_BAND_M

    def nearest(x: np.ndarray) -> str:
        x = x[x > 0]
        return f"{float(x.min()):.2f}" if len(x) else "-"

    flat = near & (np.abs(v[:, 2]) <= LRUD_BAND_M)
    column = near & (np.abs(lateral) <= LRUD_BAND_M)
    return [nearest(lateral[flat]), nearest(-lateral[flat]), nearest(v[column, 2]), nearest(-v[column, 2])]


def _sessions_to_fix(sids: list[int], joins: list[tuple[int, int]]) -> set[int]:
    """The sessions not joined to an earlier one by a loop closure (``joins``: session pairs)."""
    root = {s: s for s in sids}

    def find(a: int) -> int:
        while root[a] != a:
            a = root[a]
        return a

    for a, b in joins:
        ra, rb = find(a), find(b)
        root[max(ra, rb)] = min(ra, rb)
    return {s for s in sids if find(s) == s}


def _header(src: MapSource, spacing: float, first_ns: int, last_ns: int) -> list[str]:
    """The comment lines: input, code revisions, time span, frame, units, what is left out."""
    meta = src.metadata
    t0 = src.start_ns if src.start_ns is not None else first_ns
    return [f"; PoseidonSLAM experience map of {src.path.name} as a Survex centreline",
            f"; recording: {src.path.name}, recorded by code revision {meta.get('code_revision', 'unknown')}, "
            f"its input: {meta.get('input', 'unknown')}",
            f"; exported by code revision {code_revision()}",
            f"; recorded from {_utc(t0).isoformat()} to {_utc(last_ns).isoformat()} (the recording's stamps, UTC)",
            "; frame: the run's published frame taken to east/north/up (robot_state's ENU by default); "
            "stations at the map-corrected experience positions",
            "; units: tape and LRUD metres; compass degrees clockwise from north; clino degrees above horizontal",
            f"; stations: experiences e<id>, thinned to {spacing:g} m per session (loop closure ends kept); "
            "lc<k>: a loop closure's measured end (legs flagged duplicate)",
            f"; LRUD: nearest range return within {LRUD_WINDOW_S:g} s of the station's stamp and {LRUD_BAND_M:g} m "
            "along the passage; '-' where none",
            "; left out: experiences between kept stations, links other than the time chain and the loop "
            "closures, experience yaws, the map's link weights"]


def export_survex(src: MapSource, out: str, spacing: float = DEFAULT_SPACING_M,
                  overwrite: bool = False) -> dict[str, Any]:
    """Write the Survex centreline of ``src``'s final map to ``out``; returns the ``--json`` entry.

    :raises ExportError: no map, a spacing that is not positive, ``out`` exists.
    """
    if not (spacing > 0 and math.isfinite(spacing)):
        raise ExportError(f"--survex-spacing must be a positive number of metres, got {spacing}")
    m = src.require_map("the Survex centreline")
    enu = dict(zip((n.id for n in m.nodes), src.to_enu(np.array([n.position for n in m.nodes], dtype=float))))
    stamp = {n.id: n.stamp for n in m.nodes}
    loops = [ln for ln in m.links if ln.loop_closure and ln.source in enu and ln.target in enu]
    sessions = _thin(m, src.node_session, enu, spacing, {i for ln in loops for i in (ln.source, ln.target)})
    session_of = {n.id: int(src.node_session[k]) for k, n in enumerate(m.nodes)}
    has_returns = src.laser is not None or bool(src.sonar)
    ret = src.returns_at("map_corrected", horizontal_only=False) if has_returns else None
    enu_pts = src.to_enu(ret.points) if ret is not None else None
    fixed = _sessions_to_fix([x.sid for x in sessions], [(session_of[ln.source], session_of[ln.target]) for ln in loops])
    lines = _header(src, spacing, min(stamp.values()), max(stamp.values()))
    lines += ["*begin poseidon", "*units tape metres", "*units compass clino degrees"]
    aux: list[tuple[int, int, np.ndarray]] = []      # (k, source, measured ENU delta) of loop closures
    equates: list[str] = []
    for k, ln in enumerate(loops):
        d = src.to_enu(np.array([ln.delta], dtype=float))[0]
        end = f"s{session_of[ln.target]}.e{ln.target}"
        if np.linalg.norm(d) < 1e-3:
            equates.append(f"*equate s{session_of[ln.source]}.e{ln.source} {end}")
        else:
            aux.append((k, ln.source, d))
            equates.append(f"*equate s{session_of[ln.source]}.lc{k} {end}")
    lrud_known = 0
    for s in sessions:
        lines += [f"*begin s{s.sid}", f"*date {_utc(stamp[s.ids[0]]).strftime('%Y.%m.%d')}"]
        if s.sid in fixed:
            e = enu[s.ids[0]]
            lines.append(f"*fix e{s.ids[0]} {e[0]:.3f} {e[1]:.3f} {e[2]:.3f}")
        if s.legs:
            lines.append("*data normal from to tape compass clino")
            lines += [f"e{a} e{b} {_leg(enu[b] - enu[a])[0]}" for a, b, _ in s.legs]
        mine = [(k, a, b) for k, a, b in aux if session_of[a] == s.sid]
        if mine:
            lines += ["*data normal from to tape compass clino", "*flags duplicate"]
            lines += [f"e{a} lc{k} {_leg(d)[0]}" for k, a, d in mine]
            lines.append("*flags not duplicate")
        if len(s.ids) > 1:
            lines.append("*data passage station left right up down")
            for j, i in enumerate(s.ids):
                d = enu[s.ids[min(j + 1, len(s.ids) - 1)]] - enu[s.ids[max(j - 1, 0)]]
                lr = _lrud(ret, enu_pts, enu[i], stamp[i], d)
                lrud_known += any(v != "-" for v in lr)
                lines.append(f"e{i} {' '.join(lr)}")
        lines.append(f"*end s{s.sid}")
    lines += equates
    lines.append("*end poseidon")
    write_outputs({Path(out): ("\n".join(lines) + "\n").encode()}, overwrite)
    length = sum(t for s in sessions for _, _, t in s.legs)
    return {"out": out, "format": "survex", "spacing_m": spacing, "sessions": len(sessions),
            "stations": sum(len(s.ids) for s in sessions), "legs": sum(len(s.legs) for s in sessions),
            "length_m": round(length, 3), "loop_closures": len(loops), "equates": len(equates),
            "lrud_stations": lrud_known,
            "frame": "east/north/up of the run's published frame, metres and degrees",
            "left_out": "experiences between kept stations, experience yaws, link weights",
            "topics": {"map": {"count": src.counts.get("map", 0)}}}
