"""Service nodes used only by the bus tests (loaded through config.service_classes)."""
from __future__ import annotations

import os
import threading
import time
from typing import Any

from common.bus import Bus, open_local_session
from common.messages import Depth
from common.node import ServiceNode
from common.runtime import NodeRunner


class SlowEcho(ServiceNode):
    """Echoes depth with a deliberate 2 ms delay per message: a slow consumer."""

    name = "slow_echo"
    inputs = ("depth_sensor", "camera/image_raw")
    outputs = ("echo/depth",)

    def process(self, key, msg):
        time.sleep(0.002)
        if key == "depth_sensor":
            self.publish("echo/depth", Depth(header=self.header("echo/depth", msg.header.stamp), depth=msg.depth))
        else:
            self.count("images")


class Boom(ServiceNode):
    """Fails on its 50th depth message."""

    name = "boom"
    inputs = ("depth_sensor",)
    outputs = ("boom/depth",)

    def process(self, key, msg):
        if msg.header.seq == 50:
            raise RuntimeError("deliberate failure at seq 50")
        self.publish("boom/depth", Depth(header=self.header("boom/depth", msg.header.stamp), depth=msg.depth))


class ImageRows(ServiceNode):
    """Trusts the Image header: reshapes data to (height, width, 3) and publishes its mean as a depth."""

    name = "image_rows"
    inputs = ("camera/image_raw",)
    outputs = ("image_rows/mean",)

    def process(self, key, msg):
        rows = msg.data.reshape(msg.height, msg.width, 3)
        self.publish("image_rows/mean", Depth(header=self.header("image_rows/mean", msg.header.stamp),
                                              depth=float(rows.mean())))


class Stall(ServiceNode):
    """Takes 0.2 s per depth message: a run with it outlives a short --timeout."""

    name = "stall"
    inputs = ("depth_sensor",)
    outputs = ()

    def process(self, key, msg):
        time.sleep(0.2)


class CannotStart(ServiceNode):
    """Its constructor rejects the configuration."""

    name = "cannot_start"
    inputs = ("depth_sensor",)
    outputs = ()

    def __init__(self, config):
        super().__init__(config)
        raise ValueError("cannot_start: refuses every configuration")


class Chatty(ServiceNode):
    """Writes to file descriptor 1 (as a native library's logging would) on start and per depth message."""

    name = "chatty"
    inputs = ("depth_sensor",)
    outputs = ()

    def __init__(self, config):
        super().__init__(config)
        os.write(1, b"CHATTY SERVICE ON FD 1\n")

    def process(self, key, msg):
        if msg.header.seq == 1:
            os.write(1, b"CHATTY SERVICE ON FD 1\n")


class SlowWarmUp(SlowEcho):
    """SlowEcho whose warm-up takes 0.5 s and records when it ended."""

    name = "slow_warm_up"

    def warm_up(self):
        time.sleep(0.5)
        self.warmed_at = time.monotonic()


def _burn(seconds: float) -> None:
    """Spend ``seconds`` of this thread's CPU."""
    t = time.thread_time()
    while time.thread_time() - t < seconds:
        pass


class Burner(ServiceNode):
    """Spends 0.15 s of CPU warming up and 0.05 s on each depth message, which it echoes."""

    name = "burner"
    inputs = ("depth_sensor",)
    outputs = ("burner/depth",)

    def warm_up(self):
        _burn(0.15)

    def process(self, key, msg):
        _burn(0.05)
        self.publish("burner/depth", Depth(header=self.header("burner/depth", msg.header.stamp), depth=msg.depth))


def start_local_runner(node: ServiceNode) -> tuple[Any, Bus, threading.Thread, dict[str, Any]]:
    """``node`` run by a :class:`NodeRunner` on a thread, on a Zenoh session of its own, once it
    is alive: (session, bus, thread, result), the runner's stats in ``result["stats"]`` at its end."""
    session = open_local_session()
    bus = Bus(session=session)
    runner = NodeRunner(node, bus)
    result: dict[str, Any] = {}
    t = threading.Thread(target=lambda: result.setdefault("stats", runner.run()))
    t.start()
    bus.wait_alive([node.name], 10)
    return session, bus, t, result
