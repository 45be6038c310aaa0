"""Example driver: stream a folder of images onto the bus at a given rate (common/driver.py).

    python deploy/examples/stream_images.py FOLDER --rate 5 --connect tcp/127.0.0.1:7447 [--key camera/image_raw]

Images (png, jpg, ...; sorted by name) are read with Pillow as RGB (``--mono``: grey) and
published one every 1/rate seconds on an absolute schedule, each stamped with its scheduled
instant (wall clock; :class:`common.driver.Pacer`); the driver keeps the key alive with
watermarks and ends it when the folder is done (or at Ctrl-C).  A vendor's driver is the same
loop around its own SDK's callback.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

import numpy as np
from PIL import Image as PILImage

from common.bus import Bus
from common.driver import Pacer, SensorDriver

SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}


def stream_folder(driver: SensorDriver, folder: Path, rate_hz: float, key: str = "camera/image_raw",
                  mono: bool = False, stop: threading.Event | None = None, pacer: Pacer | None = None) -> int:
    """Publish every image of ``folder`` (sorted by name) at ``rate_hz``; returns how many.

    Each frame is read first, then published at its instant of the schedule (:class:`Pacer`),
    stamped with that instant: reading a frame never shifts its stamp.  ``pacer``: the schedule
    (default ``Pacer(rate_hz)``, the wall clock; tests pass one with their own clock)."""
    if rate_hz <= 0:
        raise ValueError(f"--rate must be > 0 frames/s, got {rate_hz}")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in SUFFIXES)
    if not files:
        raise FileNotFoundError(f"{folder}: no images ({', '.join(sorted(SUFFIXES))})")
    pacer = pacer or Pacer(rate_hz)
    for i, path in enumerate(files):
        if stop is not None and stop.is_set():
            return i
        with PILImage.open(path) as img:
            data = np.asarray(img.convert("L" if mono else "RGB"))
        driver.camera_frame(data, stamp_ns=pacer.wait(i), key=key)
    return len(files)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--rate", type=float, default=5.0, help="frames per second")
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447", help="Zenoh endpoint of the hub")
    ap.add_argument("--namespace", default="poseidon")
    ap.add_argument("--key", default="camera/image_raw")
    ap.add_argument("--mono", action="store_true", help="publish grey (mono8) frames")
    args = ap.parse_args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    bus = Bus(args.namespace, connect=[args.connect])
    try:
        with SensorDriver(bus) as driver:
            n = stream_folder(driver, args.folder, args.rate, args.key, args.mono, stop)
    except (ValueError, FileNotFoundError) as exc:
        print(f"stream_images: {exc}", file=sys.stderr)
        return 2
    finally:
        bus.close()
    print(f"stream_images: {n} frames on {args.namespace}/{args.key}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
