"""A view takes a reserved viewer id, and the hub drops what a stalled view cannot take instead of
holding every other consumer's frames (:data:`common.sessions.VIEWER_QOS`)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from common.bus import Bus
from common.sessions import VIEWER_IDS, open_hub
from services.viewer.live import ViewError, connect_bus
from tests.viewer.runs import free_port

REPO = Path(__file__).resolve().parents[2]

#: frames of 200 kB sent while the view is stopped: 100 MB, far more than its link and socket hold
N = 500
#: a view process: connects as a viewer, subscribes to every key into a small ring it never reads
VIEW_PROCESS = """
import sys, time, zenoh
from services.viewer.live import connect_bus
bus = connect_bus("ns", sys.argv[1], 5.0)
sub = bus.session.declare_subscriber(bus.full_key("**"), zenoh.handlers.RingChannel(4))
print(bus.session.info.zid(), flush=True)
time.sleep(120)
"""


def test_views_take_the_viewer_ids_in_order_and_are_told_when_none_is_left(monkeypatch: pytest.MonkeyPatch) -> None:
    ids = VIEWER_IDS[:3]   # a taken id costs a timeout: three show the order
    monkeypatch.setattr("services.viewer.live.VIEWER_IDS", ids)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_hub(endpoint)
    buses: list[Bus] = []
    try:
        for _ in ids:
            buses.append(connect_bus("ns", endpoint, 5.0))
        assert [str(b.session.info.zid()) for b in buses] == list(ids)
        with pytest.raises(ViewError, match=f"takes none of the {len(ids)} viewer ids"):
            connect_bus("ns", endpoint, 5.0)
        buses.pop(0).close()   # a view leaves: its id is free again
        time.sleep(0.5)
        buses.append(connect_bus("ns", endpoint, 5.0))
        assert str(buses[-1].session.info.zid()) == VIEWER_IDS[0]
    finally:
        for b in buses:
            b.close()
        hub.close()  # type: ignore[no-untyped-call]


def test_a_stopped_view_never_holds_the_other_consumers_frames() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_hub(endpoint)
    view = subprocess.Popen([sys.executable, "-c", VIEW_PROCESS, endpoint], cwd=REPO, stdout=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    consumer, source = Bus("ns", connect=[endpoint]), Bus("ns", connect=[endpoint])
    try:
        assert view.stdout is not None
        assert view.stdout.readline().strip() == VIEWER_IDS[0]
        got: list[int] = []
        done = threading.Event()

        def count(sample: object) -> None:
            got.append(1)
            if len(got) == N:
                done.set()
        consumer.session.declare_subscriber(consumer.full_key("camera"), count)
        pub = source.publisher("camera")
        time.sleep(0.5)
        os.kill(view.pid, signal.SIGSTOP)   # a suspended laptop: its link backs up at once
        payload = bytes(200_000)
        t0 = time.monotonic()
        for _ in range(N):
            pub.send_raw(payload)
        # with BLOCK towards the view the hub would hold these until Zenoh closes its link (5 s)
        assert done.wait(3.0), f"the consumer got {len(got)} of {N} frames while the view was stopped"
        assert time.monotonic() - t0 < 3.0
    finally:
        view.kill()
        view.wait()
        consumer.close()
        source.close()
        hub.close()  # type: ignore[no-untyped-call]
