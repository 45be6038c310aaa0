"""Hand-made experience-event streams for the expmap tests (small, deterministic)."""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from services.expmap.config import ExpMapConfig
from services.expmap.graph import EventResult, ExperienceMap

SEC = 1_000_000_000
PERIOD = 1.5  # pose-cell lattice period in x, y, z (15 cells x 0.1 m)


def pc_of(p: Sequence[float] | np.ndarray, yaw: float = 0.0) -> list[float]:
    """The pose-cell centroid a perfect attractor would report at true position p."""
    return [p[0] % PERIOD, p[1] % PERIOD, p[2] % PERIOD, yaw % (2 * math.pi)]


def feed(em: ExperienceMap, events: Iterable[Event]) -> list[EventResult]:
    """events: (t_s, lvc, pc, odom) tuples."""
    return [em.add_event(int(round(t * SEC)), lvc, pc, odom, 0.0) for t, lvc, pc, odom in events]


#: (t_s, lvc, pc, odom) of one experience event
Event = tuple[float, int, list[float], list[float]]


def line_lap(n: int, t0: float = 0.0, lvc0: int = 0) -> list[Event]:
    """n events 1 s and 1 m apart along x; LVC id = lvc0 + index."""
    return [(t0 + i, lvc0 + i, pc_of((float(i), 0.0, 0.0)), [float(i), 0.0, 0.0]) for i in range(n)]


def revisit(t: float, lvc: int, odom_x: float = 0.0) -> Event:
    """An event at time t seeing place `lvc` of a line lap (pose cells agree), odometry elsewhere."""
    return (t, lvc, pc_of((float(lvc), 0.0, 0.0)), [odom_x, 5.0, 0.0])


def loop_laps(laps: int, per_lap: int = 300, radius: float = 20.0,
              drift_per_event: tuple[float, float, float] = (0.004, -0.002, 0.0005),
              dt: float = 0.5, seed: int = 0) -> tuple[list[Event], np.ndarray]:
    """A vehicle circling `laps` times; each place keeps its LVC id; odometry drifts linearly
    plus a little noise.  Returns (events, true positions)."""
    rng = np.random.default_rng(seed)
    events: list[Event] = []
    truth: list[np.ndarray] = []
    drift = np.zeros(3)
    for k in range(laps * per_lap):
        a = 2 * math.pi * (k % per_lap) / per_lap
        p = np.array([radius * math.cos(a), radius * math.sin(a), -5.0 + math.sin(3 * a)])
        if k:
            drift += np.asarray(drift_per_event) + rng.normal(0, 0.002, 3)
        events.append((k * dt, k % per_lap, pc_of(p, a), list(p + drift)))
        truth.append(p)
    return events, np.array(truth)


def small_cfg(changes: Mapping[str, Any] | None = None) -> ExpMapConfig:
    """A small map's configuration with ``changes`` (dotted field -> value) applied."""
    base: dict[str, Any] = {"min_experience_age": 20, "loops.confirmations": 2, "corrections.min_route_len": 25,
                            "corrections.min_interval_sec": 15.0, "loops.confirmation_gap": 3}
    return ExpMapConfig().updated({**base, **(changes or {})})
