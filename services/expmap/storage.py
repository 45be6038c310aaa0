"""Storage of the experience map: the append-only node columns and the map file (npz).

:class:`ColumnStore` keeps one array per node attribute with amortised doubling;
:class:`SweepStore` keeps every node's sonar sweep in one growing point array.
:func:`save_map` / :func:`load_map` write and read everything needed to continue a map
(:class:`services.expmap.state.ExperienceMapState`, the public state of
:class:`services.expmap.graph.ExperienceMap`): nodes, odometry increments, loop edges,
sonar sweeps, the confirmation chain, the pending correction, the last event's odometry
(a continued mission must use the same odometry frame, unless it begins a new session) and
the sessions (id per node, links, which sessions are linked).  :func:`read_map_file` opens a map
file of either kind (also :mod:`services.expmap.scan_graph`'s).
"""
from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np

from services.expmap.session_link import SessionLink
from services.expmap.state import NODE_COLUMNS, ExperienceMapState

__all__ = ["ColumnStore", "SweepStore", "read_map_file", "save_map", "load_map", "FORMAT_VERSION"]

FORMAT_VERSION = 1


@dataclass
class ColumnStore:
    """Append-only column store with amortised doubling."""

    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    n: int = 0

    def add(self, name: str, shape: tuple[int, ...], dtype: Any) -> None:
        self.arrays[name] = np.zeros((64,) + shape, dtype)

    def reserve(self, n: int) -> None:
        cap = next(iter(self.arrays.values())).shape[0]
        if n <= cap:
            return
        while cap < n:
            cap *= 2
        for k, a in self.arrays.items():
            b = np.zeros((cap,) + a.shape[1:], a.dtype)
            b[: self.n] = a[: self.n]
            self.arrays[k] = b


class SweepStore:
    """Per-node sonar sweeps ((k, 2) float32 points, or None), list-like, in one point array
    with amortised doubling plus per-node (start, length) -- not a Python list of small arrays.

    Why: a checkpoint pickles the map every interval; a list of one small array per
    node is written whole every time (31 MB at the end of a 3-hour mission), while one large
    append-only array falls into the checkpoint's content-addressed blocks
    (:func:`common.resume.save_checkpoint`), of which only the blocks appended to are new.
    ``store[i] = sweep`` of the same length writes in place (a session link rotating its
    sweeps); another length appends the points and moves the node's window there."""

    def __init__(self, sweeps: Sequence[np.ndarray | None] = ()):
        self._pts = np.zeros((1024, 2), np.float32)
        self._start = np.zeros(64, np.int64)
        self._len = np.zeros(64, np.int64)        # -1: no sweep (None)
        self._n = 0
        self._top = 0
        for sw in sweeps:
            self.append(sw)

    def __len__(self) -> int:
        return self._n

    def _put(self, sw: np.ndarray) -> int:
        k = len(sw)
        if self._top + k > len(self._pts):
            cap = len(self._pts)
            while cap < self._top + k:
                cap *= 2
            pts = np.zeros((cap, 2), np.float32)
            pts[:self._top] = self._pts[:self._top]
            self._pts = pts
        self._pts[self._top:self._top + k] = sw
        self._top += k
        return self._top - k

    def append(self, sweep: np.ndarray | None) -> None:
        if self._n == len(self._start):
            self._start = np.concatenate([self._start, np.zeros(self._n, np.int64)])
            self._len = np.concatenate([self._len, np.zeros(self._n, np.int64)])
        i = self._n
        self._n += 1
        self._set(i, sweep)

    def _set(self, i: int, sweep: np.ndarray | None) -> None:
        if sweep is None:
            self._start[i], self._len[i] = 0, -1
            return
        sw = np.asarray(sweep, np.float32).reshape(-1, 2)
        if self._len[i] == len(sw):
            self._pts[self._start[i]:self._start[i] + len(sw)] = sw
        else:
            self._start[i], self._len[i] = self._put(sw), len(sw)

    def _get(self, i: int) -> np.ndarray | None:
        k = int(self._len[i])
        return None if k < 0 else self._pts[self._start[i]:self._start[i] + k].copy()

    @overload
    def __getitem__(self, i: int) -> np.ndarray | None: ...
    @overload
    def __getitem__(self, i: slice) -> list[np.ndarray | None]: ...

    def __getitem__(self, i: int | slice) -> np.ndarray | None | list[np.ndarray | None]:
        if isinstance(i, slice):
            return [self._get(j) for j in range(*i.indices(self._n))]
        if not -self._n <= i < self._n:
            raise IndexError(f"sweep {i} of {self._n}")
        return self._get(i % self._n)

    def __setitem__(self, i: int, sweep: np.ndarray | None) -> None:
        if not -self._n <= i < self._n:
            raise IndexError(f"sweep {i} of {self._n}")
        self._set(i % self._n, sweep)

    def __iter__(self) -> Iterator[np.ndarray | None]:
        return (self._get(j) for j in range(self._n))

    def __getstate__(self) -> dict[str, Any]:
        # the capacity's unused tail is zeros: content-addressed blocks of it cost nothing
        return {"pts": self._pts, "start": self._start, "len": self._len, "n": self._n, "top": self._top}

    def __setstate__(self, st: dict[str, Any]) -> None:
        self._pts, self._start, self._len = st["pts"], st["start"], st["len"]
        self._n, self._top = int(st["n"]), int(st["top"])


def read_map_file(path: Path, what: str) -> tuple[Any, dict[str, Any]]:
    """The arrays and the ``meta`` JSON record of a map file written by a ``save`` (npz);
    ValueError naming the file when it is not one (``what``: the kind, for the message)."""
    try:
        z = np.load(path, allow_pickle=False)
        return z, json.loads(bytes(z["meta"]).decode())
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: not {what} file ({exc})") from None


def save_map(state: ExperienceMapState, path: str | Path) -> None:
    """Write everything needed to continue a map (npz, written to a temporary name then moved).

    :param state: the map's state (:meth:`services.expmap.graph.ExperienceMap.state`)
    :param path: the map file
    """
    meta = {
        "format": FORMAT_VERSION, "lattice_shape": list(state.lattice_shape),
        "lattice_spacing": list(state.lattice_spacing), "last_match": state.last_match,
        "confirmations": state.confirmations, "last_correction_stamp": state.last_correction_stamp,
        "corrections": state.corrections, "solves": state.solves,
        "phi": state.phi, "peak": state.peak,
        "session": state.session, "session_pending": state.session_pending,
        "session_root": {str(k): v for k, v in state.session_root.items()},
        "session_links": [{"session": lk.session, "to_session": lk.to_session, "m": lk.m, "n": lk.n,
                           "stamp": lk.stamp, "delta": lk.delta.tolist(), "shift": lk.shift.tolist(),
                           "rotation_deg": lk.rotation_deg, "inlier_fraction": lk.inlier_fraction,
                           "applied_deg": lk.applied_deg, "backfill_edges": lk.backfill_edges}
                          for lk in state.session_links],
        "link_rejections": state.link_rejections, "frame_yaw": state.frame_yaw,
    }
    loops = np.array([(m, n, s) for m, n, _w, s in state.loops], np.int64).reshape(-1, 3)
    loop_w = np.array([w for _m, _n, w, _s in state.loops], np.float64)
    loop_d = np.asarray(state.loop_deltas, np.float64).reshape(-1, 3)
    last_odom = state.last_odom if state.last_odom is not None else np.full(3, np.nan)
    sweeps = [np.zeros((0, 2), np.float32) if a is None else a for a in state.sweeps]
    sweep_ptr = np.concatenate([[0], np.cumsum([len(a) for a in sweeps])]).astype(np.int64)
    sweep_pts = np.concatenate(sweeps).astype(np.float32) if sweeps else np.zeros((0, 2), np.float32)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    # numpy's savez stub types **kwds against its allow_pickle: bool keyword
    np.savez(tmp, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), loops=loops, loop_weight=loop_w,
             loop_delta=loop_d, last_odom=last_odom, sweep_ptr=sweep_ptr, sweep_pts=sweep_pts,
             **state.columns)  # type: ignore[arg-type]
    tmp.replace(path)


def _check_header(path: Path, meta: dict[str, Any], lattice_shape: tuple[int, ...],
                  lattice_spacing: tuple[float, ...]) -> None:
    if meta.get("format") != FORMAT_VERSION:
        raise ValueError(f"{path}: map format {meta.get('format')} (this build reads {FORMAT_VERSION})")
    if list(meta["lattice_shape"]) != [int(v) for v in lattice_shape] or \
            not np.allclose(meta["lattice_spacing"], lattice_spacing):
        raise ValueError(f"{path}: saved with pose-cell lattice {meta['lattice_shape']} x "
                         f"{meta['lattice_spacing']} m, configured {list(lattice_shape)} x {list(lattice_spacing)}")


def _columns(path: Path, z: Any) -> dict[str, np.ndarray]:
    """The node columns of an open map file, in :data:`NODE_COLUMNS` order and dtypes."""
    n = int(z["pos"].shape[0])
    columns = {}
    for k, (shape, dtype) in NODE_COLUMNS.items():
        if k in z:
            col = np.asarray(z[k])
        elif k == "session":              # a map file without session ids: one session
            col = np.zeros(n)
        elif k == "odom":                 # ... and their odometry is their positions' chain
            col = z["cum"] + (z["pos"][0] if n else 0.0)
        else:
            raise ValueError(f"{path}: missing array {k!r}")
        out = np.zeros((n,) + shape, dtype)
        out[:] = col
        columns[k] = out
    return columns


def _session_link(d: dict[str, Any]) -> SessionLink:
    return SessionLink(session=int(d["session"]), to_session=int(d["to_session"]), m=int(d["m"]),
                       n=int(d["n"]), stamp=int(d["stamp"]), delta=np.asarray(d["delta"], np.float64),
                       shift=np.asarray(d["shift"], np.float64), rotation_deg=float(d["rotation_deg"]),
                       inlier_fraction=float(d["inlier_fraction"]),
                       applied_deg=float(d.get("applied_deg", 0.0)),
                       backfill_edges=int(d.get("backfill_edges", 0)))


def load_map(path: str | Path, lattice_shape: tuple[int, ...], lattice_spacing: tuple[float, ...]
             ) -> ExperienceMapState:
    """Read a map file written by :func:`save_map`.

    :param path: the map file
    :param lattice_shape: the run's pose-cell lattice (cells), which must be the saved one
    :param lattice_spacing: the run's lattice cell size (m), which must be the saved one
    :raises ValueError: not a map file, another format version, another lattice, or a
        missing or inconsistent array (the message names the file)
    """
    path = Path(path)
    z, meta = read_map_file(path, "an experience map")
    _check_header(path, meta, lattice_shape, lattice_spacing)
    columns = _columns(path, z)
    n = int(columns["pos"].shape[0])
    loops = [(int(m), int(k), float(w), int(s)) for (m, k, s), w in zip(z["loops"], z["loop_weight"])]
    deltas = z["loop_delta"] if "loop_delta" in z else np.zeros((len(loops), 3))
    if "sweep_ptr" in z:                      # maps saved before sonar sweeps existed have none
        ptr, pts = z["sweep_ptr"], z["sweep_pts"]
        if len(ptr) != n + 1:
            raise ValueError(f"{path}: {len(ptr) - 1} sonar sweeps for {n} experiences")
        sweeps = [pts[ptr[i]:ptr[i + 1]] if ptr[i + 1] > ptr[i] else None for i in range(n)]
    else:
        sweeps = [None] * n
    lo = z["last_odom"]
    return ExperienceMapState(
        lattice_shape=tuple(int(v) for v in meta["lattice_shape"]),
        lattice_spacing=tuple(float(v) for v in meta["lattice_spacing"]),
        columns=columns, loops=loops, loop_deltas=[np.asarray(d, np.float64) for d in deltas], sweeps=sweeps,
        phi=float(meta["phi"]), peak=float(meta["peak"]),
        last_odom=None if np.any(np.isnan(lo)) else lo.astype(np.float64),
        last_match=int(meta["last_match"]), confirmations=int(meta["confirmations"]),
        last_correction_stamp=int(meta["last_correction_stamp"]), corrections=int(meta["corrections"]),
        solves=int(meta["solves"]), session=int(meta.get("session", 0)),
        session_pending=bool(meta.get("session_pending", False)),
        session_root={int(k): int(v) for k, v in meta.get("session_root", {"0": 0}).items()},
        session_links=[_session_link(d) for d in meta.get("session_links", [])],
        link_rejections={k: int(v) for k, v in meta.get("link_rejections", {}).items()},
        frame_yaw=float(meta.get("frame_yaw", 0.0)))
