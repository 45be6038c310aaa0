"""Live event time: watermarks for ROS streams from the wall clock (:class:`LiveClock`, in
:mod:`common.live`, shared with every live source), and latency percentiles.

The watermark rule (a stream's offset ``arrival - stamp``, the lateness bound, silent
streams, late messages) is stated once, in :mod:`common.live`.

Everything here takes the wall time as an argument: the bridge reads the clock, these
classes only compute (unit-tested without ROS or a clock).
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np

from common.live import LiveClock

__all__ = ["LiveClock", "LatencyTracker"]


class LatencyTracker:
    """Wall time from a sensor message's arrival to the outputs it caused, per stage.

    Outputs carry the stamp of the input that caused them (:mod:`common.node`), so an output
    is matched to the input of the same stamp (the earliest arrival when several streams share
    it).  Each (stage, stamp) counts once (a map republished for the same event does not).
    The last ``horizon`` input stamps are remembered."""

    def __init__(self, horizon: int = 200_000):
        self.horizon = horizon
        self._arrival: OrderedDict[int, int] = OrderedDict()
        self._seen: dict[str, set[int]] = {}
        self.samples: dict[str, list[float]] = {}
        self.unmatched: dict[str, int] = {}

    def arrived(self, stamp_ns: int, wall_ns: int) -> None:
        if stamp_ns in self._arrival:
            return
        self._arrival[stamp_ns] = wall_ns
        if len(self._arrival) > self.horizon:
            self._arrival.popitem(last=False)

    def output(self, stage: str, stamp_ns: int, wall_ns: int) -> float | None:
        """An output of ``stage`` stamped ``stamp_ns`` was seen at ``wall_ns``: its latency (ms),
        or None (no input of that stamp, or already counted)."""
        seen = self._seen.setdefault(stage, set())
        if stamp_ns in seen:
            return None
        t0 = self._arrival.get(stamp_ns)
        if t0 is None:
            self.unmatched[stage] = self.unmatched.get(stage, 0) + 1
            return None
        seen.add(stamp_ns)
        ms = (wall_ns - t0) / 1e6
        self.samples.setdefault(stage, []).append(ms)
        return ms

    def summary(self) -> dict[str, dict[str, float]]:
        """Per stage: ``n``, ``p50_ms``, ``p95_ms``, ``p99_ms``, ``max_ms`` (and ``unmatched``)."""
        out: dict[str, dict[str, float]] = {}
        for stage in sorted(set(self.samples) | set(self.unmatched)):
            a = np.asarray(self.samples.get(stage, []), dtype=np.float64)
            row: dict[str, float] = {"n": int(a.size), "unmatched": self.unmatched.get(stage, 0)}
            if a.size:
                p50, p95, p99 = np.percentile(a, [50, 95, 99])
                row.update(p50_ms=round(float(p50), 3), p95_ms=round(float(p95), 3), p99_ms=round(float(p99), 3),
                           max_ms=round(float(a.max()), 3))
            out[stage] = row
        return out
