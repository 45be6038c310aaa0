"""The experience map's state as data: what :meth:`services.expmap.graph.ExperienceMap.state`
gives, :meth:`~services.expmap.graph.ExperienceMap.load_state` takes and
:mod:`services.expmap.storage` writes to and reads from a map file.

:data:`NODE_COLUMNS` is the layout of the per-node columns (name, shape of one row, dtype), in
the order the map holds and the file stores them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from services.expmap.session_link import SessionLink

__all__ = ["NODE_COLUMNS", "ExperienceMapState"]

NODE_COLUMNS: dict[str, tuple[tuple[int, ...], Any]] = {
    "pos": ((3,), np.float64),       # map position (m)
    "delta": ((3,), np.float64),     # odometry increment from the previous node (edge k-1 -> k)
    "cum": ((3,), np.float64),       # sum of the increments up to the node
    "cumres": ((), np.float64),      # sum of 1/w of the odometry edges up to the node
    "weight": ((), np.float64),      # w of edge k-1 -> k
    "yaw": ((), np.float64),
    "lvc": ((), np.int64),
    "pc": ((4,), np.float64),
    "stamp": ((), np.int64),
    "rem": ((3,), np.float64),       # correction being applied (m): position = pos + phi * rem
    "session": ((), np.int64),       # session id (0: the map's first)
    "odom": ((3,), np.float64),      # the event's odometry position, in its session's frame
}


@dataclass
class ExperienceMapState:
    """Everything needed to continue an experience map (the rules that use each field:
    :mod:`services.expmap.graph`).

    :param lattice_shape: pose-cell lattice (x, y, z, yaw cells) the map was built on
    :param lattice_spacing: lattice cell size (x, y, z, m)
    :param columns: per node, one array per :data:`NODE_COLUMNS` name (N rows each)
    :param loops: loop edges (m, n, weight, stamp ns), in the order they were closed
    :param loop_deltas: per loop edge, the displacement p_n - p_m it asks for (m, (3,))
    :param sweeps: per node, its sonar sweep ((k, 2) float32 points, m) or None
    :param phi: fraction of the pending correction applied
    :param peak: largest node displacement of the pending correction (m; 0: none pending)
    :param last_odom: the last event's odometry position (m), None before the first event
    :param last_match: node the last event matched (-1: none)
    :param confirmations: consecutive confirmations of the current match chain
    :param last_correction_stamp: stamp of the last loop closure (ns; -1: none)
    :param corrections: loop closures so far
    :param solves: exact solves of the optimum so far
    :param session: the session of the newest node
    :param session_pending: the next event's node begins a new session
    :param session_root: session -> the oldest session of the component it is linked into
    :param session_links: the sonar-verified links between sessions, in the order made
    :param link_rejections: links refused so far, by reason
    :param frame_yaw: the newest session's odometry frame turned into the map's (rad)
    """

    lattice_shape: tuple[int, ...]
    lattice_spacing: tuple[float, ...]
    columns: dict[str, np.ndarray]
    loops: list[tuple[int, int, float, int]] = field(default_factory=list)
    loop_deltas: list[np.ndarray] = field(default_factory=list)
    sweeps: list[np.ndarray | None] = field(default_factory=list)
    phi: float = 0.0
    peak: float = 0.0
    last_odom: np.ndarray | None = None
    last_match: int = -1
    confirmations: int = 0
    last_correction_stamp: int = -1
    corrections: int = 0
    solves: int = 0
    session: int = 0
    session_pending: bool = False
    session_root: dict[int, int] = field(default_factory=lambda: {0: 0})
    session_links: list[SessionLink] = field(default_factory=list)
    link_rejections: dict[str, int] = field(default_factory=dict)
    frame_yaw: float = 0.0

    @property
    def n_nodes(self) -> int:
        return int(self.columns["pos"].shape[0])

    def check_fits(self, lattice_shape: tuple[int, ...], lattice_spacing: tuple[float, ...]) -> None:
        """Raise ValueError unless this state is of a map on the given lattice and complete
        (every :data:`NODE_COLUMNS` column, one sweep per node, one delta per loop edge)."""
        if tuple(int(v) for v in self.lattice_shape) != tuple(lattice_shape) or \
                not np.allclose(self.lattice_spacing, lattice_spacing):
            raise ValueError(f"state on pose-cell lattice {list(self.lattice_shape)} x {list(self.lattice_spacing)} m, "
                             f"the map's {list(lattice_shape)} x {list(lattice_spacing)}")
        missing = [k for k in NODE_COLUMNS if k not in self.columns]
        if missing:
            raise ValueError(f"state lacks the node columns {missing}")
        n = self.n_nodes
        if len(self.sweeps) != n or len(self.loop_deltas) != len(self.loops):
            raise ValueError(f"state holds {len(self.sweeps)} sonar sweeps for {n} experiences and "
                             f"{len(self.loop_deltas)} loop displacements for {len(self.loops)} loop edges")
