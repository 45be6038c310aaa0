"""FrameQueue: a sink's unbounded receive queue, whose timed get always returns."""
from __future__ import annotations

import queue
import threading
import time
from pathlib import Path

import pytest

from common.worker import FrameQueue

REPO = Path(__file__).resolve().parents[2]


def test_frames_come_out_in_order_and_an_empty_queue_says_so():
    q = FrameQueue()
    assert q.empty() and q.qsize() == 0
    for i in range(5):
        q.put_nowait((f"k{i}", bytes([i])))
    assert q.qsize() == 5 and not q.empty()
    assert [q.get(timeout=0.1) for _ in range(5)] == [(f"k{i}", bytes([i])) for i in range(5)]
    with pytest.raises(queue.Empty):
        q.get(timeout=0)


def test_a_timed_get_returns_after_its_timeout_whatever_the_timeout():
    """Tiny and ordinary timeouts, after put/get cycles (the pattern under which a timed
    ``queue.SimpleQueue.get`` could wait for ever): each ends with Empty, near its timeout."""
    q = FrameQueue()
    for timeout in (1e-9, 1e-6, 1e-4, 0.01, 0.05):
        q.put_nowait(("k", b"x"))
        q.get(timeout=1.0)
        t0 = time.monotonic()
        with pytest.raises(queue.Empty):
            q.get(timeout=timeout)
        assert time.monotonic() - t0 < timeout + 1.0


def test_a_waiting_get_is_woken_by_a_put_from_another_thread():
    q = FrameQueue()
    got: list[tuple[str, bytes]] = []
    t = threading.Thread(target=lambda: got.append(q.get(timeout=10)))
    t.start()
    time.sleep(0.1)
    t0 = time.monotonic()
    q.put_nowait(("k", b"y"))
    t.join(timeout=5)
    assert got == [("k", b"y")] and time.monotonic() - t0 < 2.0


def test_no_service_waits_on_a_simple_queue():
    """The product's packages take no ``queue.SimpleQueue`` (its timed get can block for ever)."""
    hits = [str(p.relative_to(REPO)) for pkg in ("common", "services", "launcher", "products", "eval", "system")
            for p in (REPO / pkg).rglob("*.py") if "SimpleQueue" in p.read_text().replace(
                "queue.SimpleQueue`", "")]
    assert hits == [], hits
