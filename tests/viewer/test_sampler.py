"""The key sampler: one frame per window, windows a period apart, and a gap after a window that
saw nothing (a draining publisher finds the key without subscribers)."""
from __future__ import annotations

from typing import Any

from services.viewer.sampler import KeySampler


class _Sub:
    """A subscriber whose ring holds the frames put in ``pending``."""

    pending: list[str] = []

    def __init__(self, log: list[str], key: str):
        self.log, self.key = log, key
        log.append(f"+{key}")

    def try_recv(self) -> Any:
        return _Sub.pending.pop(0) if _Sub.pending else None

    def undeclare(self) -> None:
        self.log.append(f"-{self.key}")


def _sampler(log: list[str], taken: list[tuple[str, Any]], **kw: float) -> KeySampler:
    _Sub.pending = []
    return KeySampler(lambda k: _Sub(log, k), lambda k, s: (taken.append((k, s)), s == "frame")[1], **kw)


def test_a_window_closes_at_its_first_frame_and_the_next_opens_a_period_later() -> None:
    log: list[str] = []
    taken: list[tuple[str, Any]] = []
    s = _sampler(log, taken, hz=2.0)
    s.add("cam")
    assert s.step(0.0) == 0.02  # open: polled every 20 ms
    assert log == ["+cam"] and s.keys == ["cam"]
    _Sub.pending.append("watermark")
    s.step(0.02)
    assert log == ["+cam"] and taken == [("cam", "watermark")]  # not a data frame: the window stays open
    _Sub.pending.append("frame")
    assert s.step(0.05) == 0.45  # taken and closed; the next window opens 0.5 s after this one opened
    assert log == ["+cam", "-cam"] and taken[-1] == ("cam", "frame")
    s.step(0.3)
    assert log == ["+cam", "-cam"]
    s.step(0.5)
    assert log == ["+cam", "-cam", "+cam"] and s.windows == 2


def test_a_window_without_a_frame_closes_and_leaves_a_gap() -> None:
    log: list[str] = []
    s = _sampler(log, [], hz=2.0, window_s=1.0, gap_s=0.15)
    s.add("cam")
    s.step(0.0)
    s.step(0.9)
    assert log == ["+cam"]
    s.step(1.0)
    assert log == ["+cam", "-cam"]
    s.step(1.1)
    assert log == ["+cam", "-cam"]  # the gap
    s.step(1.15)
    assert log == ["+cam", "-cam", "+cam"]


def test_a_removed_key_closes_its_window_and_stop_closes_every_window() -> None:
    log: list[str] = []
    s = _sampler(log, [], hz=2.0)
    s.add("a")
    s.add("b")
    s.step(0.0)
    s.remove("a")
    s.step(0.01)
    assert s.keys == ["b"] and log == ["+a", "+b", "-a"]
    s.stop()
    assert log[-1] == "-b"
