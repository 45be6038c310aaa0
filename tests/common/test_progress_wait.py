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


def test_watch_progress_of_named_services_follows_only_those():
    """A supervised service follows the progress of its own consumers only (each report is a
    callback in every process that follows it)."""
    from common.bus import Bus, open_local_session

    session = open_local_session()
    bus = Bus(session=session)
    named, every = bus.watch_progress(["htm", "recorder"]), bus.watch_progress()
    for name, stamp in [("htm", 10), ("recorder", 20), ("expmap", 30)]:
        bus.progress_publisher(name).report(stamp, force=True)
    deadline = time.monotonic() + 5.0
    def arrived() -> bool:   # each subscription's callbacks arrive on their own thread: wait for all five
        return (every.get("htm"), every.get("recorder"), every.get("expmap"), named.get("htm"),
                named.get("recorder")) == (10, 20, 30, 10, 20)
    while not arrived() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert every.get("expmap") == 30 and every.slowest(["htm", "recorder"], default=-2) == 10
    assert named.get("htm") == 10 and named.get("recorder") == 20
    assert named.get("expmap") == -2  # not followed
    bus.close()
    session.close()
