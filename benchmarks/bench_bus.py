"""Bus benchmark: throughput and one-way latency of PoseidonSLAM's bus next to raw Zenoh.

For 100 B and 330 KB messages (a 384x288 RGB image), in one process (one session) and
across processes (publisher and subscriber are separate processes, both clients of a hub
on loopback, as in ``poseidon run``), it measures:

- throughput: N messages published back to back, messages/s and MB/s at the subscriber;
- latency: messages paced apart, one-way time from publish to the subscriber's callback
  (ours: after decoding and validating the message), p50 and p99 in microseconds.

"ours" sends pydantic messages through :class:`common.bus.BusPublisher` (msgpack frame)
and decodes them to validated messages on arrival; "raw" puts the same number of bytes
with ``zenoh`` directly.  The figure is the ratio ours/raw measured in the same run.

    .venv/bin/python benchmarks/bench_bus.py [--quick]
"""
from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.bus import Bus, open_hub, open_local_session, zenoh_config
from common.codec import decode_frame
from common.messages import Header, Image, Sdr

SIZES = {"100B": 100, "330KB": 288 * 384 * 3}


def make_message(size_name: str, stamp: int) -> Sdr | Image:
    if size_name == "100B":  # an SDR with 8 active bits encodes to ~100 bytes
        return Sdr(header=Header(seq=0, stamp=stamp), modality="camera", size=2048,
                   active=np.arange(8, dtype=np.uint32))
    return Image(header=Header(seq=0, stamp=stamp), height=288, width=384,
                 data=np.zeros((288, 384, 3), np.uint8))


class Sink:
    """Collects arrival times; ours decodes and validates, raw only reads the stamp."""

    def __init__(self, kind: str, expected: int):
        self.kind = kind
        self.expected = expected
        self.latencies: list[int] = []
        self.first = self.last = 0
        self.done = threading.Event()

    def __call__(self, payload: bytes) -> None:
        now = time.monotonic_ns()
        if self.kind == "ours":
            sent = decode_frame(payload).message().header.stamp
        else:
            sent = int.from_bytes(payload[:8], "little")
        if not self.latencies:
            self.first = now
        self.latencies.append(now - sent)
        self.last = now
        if len(self.latencies) >= self.expected:
            self.done.set()


def publish(session: zenoh.Session, kind: str, size_name: str, n: int, pace_s: float) -> None:
    key = f"bench/{kind}/{size_name}"
    if kind == "ours":
        bus = Bus("bench", session=session)
        pub = bus.publisher(f"{kind}/{size_name}")
        template = make_message(size_name, 0)
        for _ in range(n):
            template.header.stamp = time.monotonic_ns()
            pub.send(template)
            if pace_s:
                time.sleep(pace_s)
    else:
        raw_pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                        reliability=zenoh.Reliability.RELIABLE)
        body = bytearray(SIZES[size_name])
        for _ in range(n):
            body[:8] = time.monotonic_ns().to_bytes(8, "little")
            raw_pub.put(bytes(body))
            if pace_s:
                time.sleep(pace_s)
        raw_pub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it unannotated


def summarise(sink: Sink, nbytes: int) -> dict[str, Any]:
    lat = np.array(sink.latencies) / 1000.0
    dur = max(sink.last - sink.first, 1) / 1e9
    return {"received": len(sink.latencies), "p50_us": float(np.percentile(lat, 50)),
            "p99_us": float(np.percentile(lat, 99)), "msgs_per_s": len(sink.latencies) / dur,
            "mb_per_s": len(sink.latencies) * nbytes / dur / 1e6}


def subscriber_role(endpoint: str, kind: str, size_name: str, n: int) -> None:
    session = zenoh.open(zenoh_config("client", connect=[endpoint]))
    sink = Sink(kind, n)
    sub = session.declare_subscriber(f"bench/{kind}/{size_name}", lambda s: sink(s.payload.to_bytes()))
    token = session.liveliness().declare_token(f"bench/@alive/{kind}-{size_name}")
    ok = sink.done.wait(timeout=120)
    print(json.dumps({"ok": ok, **summarise(sink, SIZES[size_name])}))
    sys.stdout.flush()
    del sub, token
    session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it unannotated


def wait_token(session: zenoh.Session, name: str) -> None:
    for _ in range(400):
        if any(r.ok for r in session.liveliness().get(f"bench/@alive/{name}", timeout=1.0)):
            return
        time.sleep(0.025)
    raise TimeoutError(f"subscriber {name} did not come up")


def run_case(mode: str, kind: str, size_name: str, n: int, pace_s: float, endpoint: str) -> dict[str, Any]:
    if mode == "in-process":
        session = open_local_session()
        sink = Sink(kind, n)
        sub = session.declare_subscriber(f"bench/{kind}/{size_name}", lambda s: sink(s.payload.to_bytes()))
        publish(session, kind, size_name, n, pace_s)
        sink.done.wait(timeout=120)
        out = summarise(sink, SIZES[size_name])
        sub.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it unannotated
        session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it unannotated
        return out
    proc = subprocess.Popen([sys.executable, __file__, "--role", "sub", "--endpoint", endpoint, "--kind", kind,
                             "--size", size_name, "-n", str(n)], stdout=subprocess.PIPE, text=True)
    session = zenoh.open(zenoh_config("client", connect=[endpoint]))
    try:
        wait_token(session, f"{kind}-{size_name}")
        publish(session, kind, size_name, n, pace_s)
        result: dict[str, Any] = json.loads(proc.communicate(timeout=180)[0].strip().splitlines()[-1])
    finally:
        session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it unannotated
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--role", default="bench")
    ap.add_argument("--endpoint")
    ap.add_argument("--kind")
    ap.add_argument("--size")
    ap.add_argument("-n", type=int)
    ap.add_argument("--quick", action="store_true", help="fewer messages")
    args = ap.parse_args()
    if args.role == "sub":
        subscriber_role(args.endpoint, args.kind, args.size, args.n)
        return 0
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    hub = open_hub(endpoint)
    scale = 0.2 if args.quick else 1.0
    plan = {"100B": (int(20000 * scale), int(2000 * scale), 0.0005),
            "330KB": (int(1000 * scale), int(300 * scale), 0.005)}
    print(f"{'mode':<14}{'size':<7}{'measure':<12}{'ours':>12}{'raw':>12}{'ours/raw':>10}")
    try:
        for mode in ("in-process", "cross-process"):
            for size_name, (n_burst, n_lat, pace) in plan.items():
                res = {}
                for kind in ("raw", "ours"):
                    res[kind] = {"burst": run_case(mode, kind, size_name, n_burst, 0.0, endpoint),
                                 "paced": run_case(mode, kind, size_name, n_lat, pace, endpoint)}
                for label, phase, field in (("msgs/s", "burst", "msgs_per_s"),
                                            ("MB/s", "burst", "mb_per_s"),
                                            ("p50 us", "paced", "p50_us"),
                                            ("p99 us", "paced", "p99_us")):
                    o, r = res["ours"][phase][field], res["raw"][phase][field]
                    print(f"{mode:<14}{size_name:<7}{label:<12}{o:>12.1f}{r:>12.1f}{o / r:>10.2f}")
                for kind in ("raw", "ours"):
                    for phase in ("burst", "paced"):
                        want = n_burst if phase == "burst" else n_lat
                        if res[kind][phase]["received"] != want:
                            print(f"  LOST: {kind} {phase} received {res[kind][phase]['received']} of {want}")
    finally:
        hub.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it unannotated
    return 0


if __name__ == "__main__":
    sys.exit(main())
