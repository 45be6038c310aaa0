"""A live source for the link-outage test: a :class:`common.driver.SensorDriver` publishing a
deterministic IMU and DVL stream (one record of each per tick) (``--rate`` Hz, stamps from the wall clock) for ``--seconds``, then
end-of-stream; prints ``ready`` once the recorder is alive, then its counters as JSON (``published``, ``late``, and the outage counters of
:class:`common.live.LiveSource`).  Run as ``python -m tests.launcher.outage_source ENDPOINT``."""
from __future__ import annotations

import argparse
import json
import sys
import time

from common.bus import Bus
from common.driver import SensorDriver


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("endpoint")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--wait-for", default="recorder")
    ap.add_argument("--buffer", default="2000,100", help="outage buffer (frames) of the IMU and DVL keys")
    ap.add_argument("--trace", action="store_true", help="print each second's matching status to stderr")
    args = ap.parse_args(argv)
    bus = Bus("poseidon", connect=[args.endpoint])
    bus.wait_alive([args.wait_for], 60)
    print("ready", flush=True)
    big, small = (int(n) for n in args.buffer.split(","))
    drv = SensorDriver(bus, outage_frames=big)  # the IMU: a buffer that covers the outage
    drv2 = SensorDriver(bus, outage_frames=small)  # the DVL: one that does not
    period = 1.0 / args.rate
    t0 = time.monotonic()
    slowest = 0.0
    # a fixed number of ticks, each at its time: a late tick near the end must not drop the last one
    for i in range(round(args.rate * args.seconds)):
        now = a = time.monotonic()
        drv.imu(0.001 * i, 0.0, 0.0, gyro=(float(i), 0.0, 0.0))
        drv2.dvl((0.001 * i, 0.0, 0.0), 2.0)
        slowest = max(slowest, time.monotonic() - a)
        n = i + 1  # ticks sent
        if args.trace and n % int(args.rate) == 0:
            pubs = drv.source.publishers() + drv2.source.publishers()
            print(f"{now - t0:6.2f} s: sent {n}, matching {[p.has_subscribers() for p in pubs]}, "
                  f"slowest publish {slowest:.3f} s", file=sys.stderr, flush=True)
            slowest = 0.0
        time.sleep(max(0.0, t0 + n * period - time.monotonic()))
    drv.close()
    drv2.close()
    a, b = drv.source.counters(), drv2.source.counters()
    stats = {k: {**a[k], **b[k]} if isinstance(a[k], dict) else a[k] + b[k] for k in a}
    stats["drained"] = bus.drain(drv.source.publishers() + drv2.source.publishers(), 20.0)
    print(json.dumps(stats), flush=True)
    bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
