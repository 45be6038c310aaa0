"""ProgressWatcher.wait_slowest: woken by the report that lets the slowest consumer reach the target."""
import threading
import time

from common.bus import ProgressWatcher


def test_wait_slowest_wakes_on_the_report_that_reaches_the_target():
    w = ProgressWatcher()
    w.update("a", 100)
    assert w.wait_slowest(["a", "b"], default=50, at_least=50, timeout_s=0.0)  # b not reported: counts as 50
    assert not w.wait_slowest(["a", "b"], default=50, at_least=80, timeout_s=0.02)  # nobody reports: times out
    t = threading.Timer(0.05, lambda: (w.update("b", 70), w.update("b", 90)))
    t0 = time.monotonic()
    t.start()
    assert w.wait_slowest(["a", "b"], default=50, at_least=80, timeout_s=5.0)
    assert time.monotonic() - t0 < 2.0 and w.slowest(["a", "b"], default=50) == 90
    t.join()
    w.update("a", 95)  # no waiter: nothing to wake, nothing kept waiting
    assert w.slowest(["a", "b"], default=0) == 90
