"""Sampling a heavy key: transient subscriptions that take about ``hz`` frames a second.

A subscriber on the hub gets every frame of its key; for a camera at 5-20 frames a second of
330 kB each, that is megabytes a second the hub copies to the view, and a view starved of CPU
(it runs under SCHED_IDLE) that stops reading makes the hub's reliable, blocking forwarding
wait on it.  :class:`KeySampler` instead opens a *window* on a key (declares a subscriber),
closes it (undeclares) as soon as one data frame has arrived, and opens the next window a
period later: the hub forwards about one frame per window.

- A window that sees no frame within ``window_s`` closes anyway and reopens after ``gap_s``:
  a publisher draining at its end waits until no subscriber matches (:meth:`common.bus.Bus.drain`,
  polled every 50 ms), and finds the gap.
- A window's subscriber holds its samples in Zenoh's own bounded ring buffer (no Python
  callback, so Zenoh's threads never wait for the interpreter); the sampler's thread polls the
  open windows, hands each sample to ``take`` and closes the window at the first data frame
  (watermarks and the like do not count).
"""
from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["KeySampler"]


@dataclass
class _Window:
    sub: Any = None          # the subscriber while the window is open
    opened: float = 0.0      # monotonic time it opened
    next_open: float = 0.0   # monotonic time the next window opens


class KeySampler:
    """Transient subscriptions on the keys given to :meth:`add` (see the module notes).

    :param declare: declares a subscriber on a key (relative); the result has ``try_recv()``
        (a sample or None) and ``undeclare()``
    :param take: gets ``(key, sample)`` of each sample, on the sampler's thread; True for a data frame
    :param hz: windows opened per second and key [Hz]
    :param window_s: longest a window stays open without a frame [s]
    :param gap_s: pause after a window that saw no frame [s]
    """

    def __init__(self, declare: Callable[[str], Any], take: Callable[[str, Any], bool], hz: float,
                 window_s: float = 1.0, gap_s: float = 0.15, poll_s: float = 0.02):
        self._declare = declare
        self._take = take
        self.poll_s = poll_s
        self.period = 1.0 / hz
        self.window_s = window_s
        self.gap_s = gap_s
        self._windows: dict[str, _Window] = {}
        self._requests: deque[tuple[str, bool]] = deque()  # (key, add) from callbacks and other threads
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.windows = 0  # windows opened

    @property
    def keys(self) -> list[str]:
        """The keys sampled now."""
        return sorted(self._windows)

    def add(self, key: str) -> None:
        """Sample ``key`` from now on (any thread, never blocks)."""
        self._requests.append((key, True))
        self._wake.set()

    def remove(self, key: str) -> None:
        """Stop sampling ``key`` (its stream ended; any thread, never blocks)."""
        self._requests.append((key, False))
        self._wake.set()

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="view-sampler", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and close every open window."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for w in self._windows.values():
            if w.sub is not None:
                w.sub.undeclare()
                w.sub = None

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.clear()
            timeout = self.step(time.monotonic())
            self._wake.wait(timeout)

    def step(self, now: float) -> float:
        """Take the requests, poll the open windows, open and close those due at ``now``; the
        seconds until the next poll or opening."""
        while self._requests:
            key, add = self._requests.popleft()
            if add:
                self._windows.setdefault(key, _Window(next_open=now))
            else:
                w = self._windows.pop(key, None)
                if w is not None and w.sub is not None:
                    w.sub.undeclare()
        due = now + self.period
        for key, w in self._windows.items():
            if w.sub is None and now >= w.next_open:
                w.sub, w.opened = self._declare(key), now
                self.windows += 1
            elif w.sub is not None:
                got = False
                while not got and (sample := w.sub.try_recv()) is not None:
                    got = self._take(key, sample)
                if got or now - w.opened >= self.window_s:
                    w.sub.undeclare()
                    w.sub = None
                    w.next_open = max(w.opened + self.period, now + self.gap_s) if got else now + self.gap_s
            due = min(due, now + self.poll_s if w.sub is not None else w.next_open)
        return max(0.005, due - now)
