"""EventImageAssociator driven directly with plain stand-ins for frames and event headers."""
from types import SimpleNamespace
from typing import Any

from services.expmap.association import Association, EventImageAssociator

MS = 1_000_000
Assoc = EventImageAssociator[Any, SimpleNamespace]  # events: plain namespaces with a stamp


def fr(t_ms: int, name: str = "") -> SimpleNamespace:
    return SimpleNamespace(header=SimpleNamespace(stamp=t_ms * MS), name=name or f"f{t_ms}")


def ev(t_ms: int) -> SimpleNamespace:
    return SimpleNamespace(stamp=t_ms * MS)


def names(decisions: list[Association[Any, SimpleNamespace]]) -> list[tuple[int, str | None, bool]]:
    return [(d.header.stamp // MS, None if d.frame is None else d.frame.name, d.overflow) for d in decisions]


def test_the_closest_frame_by_stamp_waits_for_the_next_frame() -> None:
    a: Assoc = EventImageAssociator(slop_ns=100 * MS, buffer_size=8)
    assert a.on_frame(fr(0)) == []
    assert a.on_event(ev(70)) == [] and a.oldest_waiting == 70 * MS
    assert names(a.on_frame(fr(100))) == [(70, "f100", False)]      # 30 ms after beats 70 ms before
    assert a.oldest_waiting is None
    a.on_event(ev(120))
    assert names(a.on_frame(fr(200))) == [(120, "f100", False)]     # 20 ms before beats 80 after


def test_ties_go_to_the_earlier_frame_and_an_equal_stamp_decides_at_once() -> None:
    a: Assoc = EventImageAssociator(slop_ns=100 * MS, buffer_size=8)
    a.on_frame(fr(0))
    a.on_event(ev(50))
    assert names(a.on_frame(fr(100))) == [(50, "f0", False)]
    assert names(a.on_event(ev(100))) == [(100, "f100", False)]


def test_no_frame_within_the_slop_gives_none() -> None:
    a: Assoc = EventImageAssociator(slop_ns=10 * MS, buffer_size=8)
    a.on_frame(fr(0))
    a.on_event(ev(50))
    assert names(a.on_frame(fr(100))) == [(50, None, False)]


def test_overflow_decides_the_oldest_with_the_frames_seen_and_flush_decides_the_rest() -> None:
    a: Assoc = EventImageAssociator(slop_ns=100 * MS, buffer_size=2)
    a.on_frame(fr(0))
    assert a.on_event(ev(10)) == [] and a.on_event(ev(20)) == []
    assert names(a.on_event(ev(30))) == [(10, "f0", True)]
    assert a.oldest_waiting == 20 * MS
    assert names(a.flush()) == [(20, "f0", False), (30, "f0", False)]
    assert a.flush() == []


def test_one_frame_decides_every_event_before_it_in_order() -> None:
    a: Assoc = EventImageAssociator(slop_ns=100 * MS, buffer_size=8)
    for t in (5, 6, 7):
        a.on_event(ev(t))
    assert names(a.on_frame(fr(8))) == [(5, "f8", False), (6, "f8", False), (7, "f8", False)]
