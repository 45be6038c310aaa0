"""The per-service figures of a live view, from what the bus carries: :class:`ServiceFigures`.

Input rate (data frames per second on the service's input keys, from their transport indices,
so frames the view skipped count too), lag (event time between the newest source message and
the service's ``@progress`` report, or the lag the launcher's ``live/health`` report gives, see
:meth:`ServiceFigures.health_report`), gaps (transport indices missing in its output streams
that the view follows whole: frames that never reached the view, or that its ring overwrote),
restarts (its ``@alive`` token declared again after it left) and latency p50/p99 (wall time from
a source message to the output of the same stamp, as :class:`common.live.LatencyTracker`
measures at the source; the hub's timestamps when it stamps, else the view's clock; on a
sampled source key, from the frames sampled).  Frames dropped inside a live service's bounded
queue are not on the bus; the run summary has them (``dropped``).
"""
from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from common.messages import DiagnosticArray
from common.ordering import END_OF_TIME

__all__ = ["ServiceFigures", "LatencyWindow", "health_lags"]


def health_lags(msg: DiagnosticArray) -> dict[str, float | None]:
    """Per service, the lag behind the source (event s; None while unknown) of a ``live/health``
    report (:mod:`launcher.health`: statuses named ``poseidon/NAME`` with a ``lag_s`` value)."""
    out: dict[str, float | None] = {}
    for status in msg.status:
        name = status.name.removeprefix("poseidon/")
        value = next((kv.value for kv in status.values if kv.key == "lag_s"), "")
        try:
            out[name] = float(value) if value else None
        except ValueError:
            out[name] = None
    return out


class LatencyWindow:
    """Wall time from a source message to an output of the same stamp, per output key, over
    the last ``window`` outputs (bounded memory for runs of hours)."""

    def __init__(self, horizon: int = 20_000, window: int = 2_000):
        self.horizon = horizon
        self._arrival: OrderedDict[int, int] = OrderedDict()
        self._seen: dict[str, OrderedDict[int, None]] = {}
        self.samples: dict[str, deque[float]] = {}
        self._window = window
        self._added = 0  # samples added so far
        self._cache: dict[tuple[str, ...], tuple[int, tuple[float | None, float | None]]] = {}

    def arrived(self, stamp: int, wall_ns: int) -> None:
        if stamp not in self._arrival:
            self._arrival[stamp] = wall_ns
            if len(self._arrival) > self.horizon:
                self._arrival.popitem(last=False)

    def output(self, key: str, stamp: int, wall_ns: int) -> None:
        seen = self._seen.setdefault(key, OrderedDict())
        t0 = self._arrival.get(stamp)
        if t0 is None or stamp in seen:
            return
        seen[stamp] = None
        if len(seen) > self.horizon:
            seen.popitem(last=False)
        self.samples.setdefault(key, deque(maxlen=self._window)).append((wall_ns - t0) / 1e6)
        self._added += 1

    def percentiles(self, keys: Sequence[str]) -> tuple[float | None, float | None]:
        """p50 and p99 (ms) over the samples of ``keys`` (None without any), computed again only
        after a sample was added."""
        cached = self._cache.get(tuple(keys))
        if cached is not None and cached[0] == self._added:
            return cached[1]
        values = [v for k in keys for v in self.samples.get(k, ())]
        result: tuple[float | None, float | None] = (None, None)
        if values:
            p50, p99 = np.percentile(np.asarray(values), [50, 99])
            result = (round(float(p50), 1), round(float(p99), 1))
        self._cache[tuple(keys)] = (self._added, result)
        return result


class ServiceFigures:
    """The bus-side counters behind the per-service table (thread-safe)."""

    def __init__(self, io: Mapping[str, tuple[Sequence[str], Sequence[str]]]):
        self.io: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {}
        self.produced: set[str] = set()
        self.frames: dict[str, int] = {}
        self.next_index: dict[str, int] = {}
        self.gaps: dict[str, int] = {}
        self.invalid: dict[str, int] = {}
        self.declared: dict[str, int] = {}
        self.alive: set[str] = set()
        self.progress: dict[str, int] = {}
        self.health_lag: dict[str, float | None] | None = None  # the lags of the last live/health report
        self.newest_source = -1
        self.latency = LatencyWindow()
        self.partial: set[str] = set()  # keys the view takes only some frames of (latest-only, sampled): no gaps
        self._mark: dict[str, tuple[int, float]] = {}  # key -> (newest index, monotonic time it arrived)
        self._mark_ref: dict[str, tuple[int, float]] = {}  # the marks at the last rate update
        self._rate: dict[str, float] = {}
        self._last: tuple[float, dict[str, int]] = (time.monotonic(), {})
        self.lock = threading.Lock()
        self.add_io(io)

    def add_io(self, io: Mapping[str, tuple[Sequence[str], Sequence[str]]]) -> None:
        """Services and their input and output keys, added to the table."""
        with self.lock:
            self.io.update({n: (tuple(i), tuple(o)) for n, (i, o) in io.items()})
            self.produced = {k for _i, outs in self.io.values() for k in outs}

    def data(self, key: str, index: int, stamp: int, wall_ns: int) -> None:
        with self.lock:
            self.frames[key] = self.frames.get(key, 0) + 1
            if index >= 0:
                self._mark[key] = (index, time.monotonic())
            if index >= 0 and key not in self.partial:
                expected = self.next_index.get(key, index)
                if index > expected:
                    self.gaps[key] = self.gaps.get(key, 0) + index - expected
                if index >= expected:
                    self.next_index[key] = index + 1
            if stamp < 0:
                return
            if key in self.produced:
                self.latency.output(key, stamp, wall_ns)
            else:
                self.newest_source = max(self.newest_source, stamp)
                self.latency.arrived(stamp, wall_ns)

    def token(self, service: str, present: bool) -> None:
        with self.lock:
            if present:
                self.declared[service] = self.declared.get(service, 0) + 1
                self.alive.add(service)
            else:
                self.alive.discard(service)

    def progress_report(self, service: str, stamp: int) -> None:
        with self.lock:
            if stamp > self.progress.get(service, -2):
                self.progress[service] = stamp

    def health_report(self, lags: Mapping[str, float | None]) -> None:
        """The lags (event s) of a ``live/health`` report (:func:`health_lags`): the table's lag
        from now on (0 and the process gone: done)."""
        with self.lock:
            self.health_lag = dict(lags)

    def _lag(self, name: str) -> tuple[float | None, bool]:
        """``(lag s, done)`` of a service (call under the lock)."""
        progress = self.progress.get(name)
        if progress == END_OF_TIME:
            return None, True
        if self.health_lag is not None and name in self.health_lag:
            lag = self.health_lag[name]
            if lag == 0.0 and name not in self.alive and name in self.declared:
                return None, True
            return (None if lag is None else round(lag, 2)), False
        if progress is not None and self.newest_source >= 0:
            return round(max(0, self.newest_source - progress) / 1e9, 2), False
        return None, False

    def newest_index(self, key: str) -> int:
        """Transport index of the newest frame of ``key`` taken (-1: none)."""
        with self.lock:
            return self._mark.get(key, (-1, 0.0))[0]

    def _index_rate(self, key: str, now: float) -> None:
        """A key's rate from its transport indices over the times the view took them (0 once
        none came for 3 s)."""
        mark, ref = self._mark.get(key), self._mark_ref.get(key)
        if mark is None:
            self._rate[key] = 0.0
            return
        if ref is not None and mark[1] > ref[1] and mark[0] >= ref[0]:
            self._rate[key] = (mark[0] - ref[0]) / (mark[1] - ref[1])
        elif now - mark[1] > 3.0:
            self._rate[key] = 0.0
        if ref is None or mark[1] > ref[1]:
            self._mark_ref[key] = mark

    def table(self) -> dict[str, dict[str, Any]]:
        """Per service: ``alive``, ``rate_hz``, ``lag_s``, ``done``, ``gaps``, ``restarts``, ``p50_ms``, ``p99_ms``."""
        with self.lock:
            now = time.monotonic()
            t_last, counts = self._last
            if now - t_last >= 1.0:  # rates over at least one second
                for key, n in self.frames.items():
                    if key in self._mark:
                        self._index_rate(key, now)
                    else:
                        self._rate[key] = (n - counts.get(key, 0)) / (now - t_last)
                self._last = (now, dict(self.frames))
            names = sorted(set(self.io) | set(self.progress) | set(self.declared))
            out: dict[str, dict[str, Any]] = {}
            for name in names:
                ins, outs = self.io.get(name, ((), ()))
                lag, done = self._lag(name)
                p50, p99 = self.latency.percentiles(outs)
                out[name] = {"alive": name in self.alive, "rate_hz": round(sum(self._rate.get(k, 0.0) for k in ins), 1),
                             "lag_s": lag, "done": done, "gaps": sum(self.gaps.get(k, 0) for k in outs),
                             "restarts": max(0, self.declared.get(name, 0) - 1), "p50_ms": p50, "p99_ms": p99}
            return out
