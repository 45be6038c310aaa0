"""A folder of image frames -> ``camera/image_raw`` Image messages.

With a timestamps file: it lists ``<frame file name> <stamp>`` per line (tab, space or comma;
stamp in seconds with a decimal fraction, or integer nanoseconds), as
``camera_frame_timestamps.txt`` of the Girona caves data.  It is looked for as the given
path, else a ``*timestamps*.txt``/``.csv`` file inside the folder, else one next to the
folder; seq = position in the timestamps file.  Without one (a plain folder of JPEG/PNG
frames), every image of the folder in file-name order, frame ``i`` stamped ``i / rate_hz``
seconds (``poseidon import --frame-rate``, default :data:`DEFAULT_RATE_HZ`); seq = ``i``.
Frames are yielded in timestamp order, loaded lazily (Pillow), as rgb8 (colour) or mono8
(grey) images.
"""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from common.messages import Header, Image
from missions.importers.errors import InputFormatError
from missions.importers.rostopic_csv import read_frame_timestamps

__all__ = ["IMAGE_SUFFIXES", "DEFAULT_RATE_HZ", "find_timestamps", "frames_plan", "load_frame"]

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
#: frames per second of a folder without a timestamps file
DEFAULT_RATE_HZ = 1.0


def find_timestamps(folder: Path, explicit: Path | None = None) -> Path | None:
    """The timestamps file of ``folder`` (``explicit`` when given), None when there is none."""
    if explicit is not None:
        if not explicit.is_file():
            raise InputFormatError(f"{explicit}: no such timestamps file")
        return explicit
    for where in (folder, folder.parent):
        cands = sorted(p for p in where.iterdir()
                       if p.is_file() and "timestamp" in p.name.lower() and p.suffix.lower() in (".txt", ".csv"))
        if len(cands) == 1:
            return cands[0]
        if len(cands) > 1:
            raise InputFormatError(f"{folder}: several timestamps files {[c.name for c in cands]} in {where}; "
                                   f"pass one with --frames-timestamps")
    return None


def frames_plan(folder: str | Path, timestamps: str | Path | None = None,
                rate_hz: float | None = None) -> list[tuple[int, int, Path]]:
    """``(stamp ns, seq, file)`` of every frame, in stamp order: by the timestamps file, or
    without one in file-name order at ``rate_hz`` (default :data:`DEFAULT_RATE_HZ`).  Raises
    :class:`InputFormatError` for an empty folder, a missing explicit timestamps file, a listed
    frame that does not exist, or a rate that is not > 0."""
    d = Path(folder)
    if not d.is_dir():
        raise InputFormatError(f"{d}: not a folder of frames")
    images = {p.name for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
    if not images:
        raise InputFormatError(f"{d}: empty folder: no image frames ({', '.join(sorted(IMAGE_SUFFIXES))})")
    ts = find_timestamps(d, Path(timestamps) if timestamps else None)
    if ts is None:
        rate = DEFAULT_RATE_HZ if rate_hz is None else rate_hz
        if not rate > 0:
            raise InputFormatError(f"--frame-rate must be > 0 frames/s, got {rate}")
        return [(int(round(i * 1e9 / rate)), i, d / name) for i, name in enumerate(sorted(images))]
    plan = []
    for seq, (name, stamp) in enumerate(read_frame_timestamps(ts)):
        if name not in images:
            raise InputFormatError(f"{ts}: frame {name!r} is listed but not in {d}")
        plan.append((stamp, seq, d / name))
    plan.sort(key=lambda x: (x[0], x[1]))
    return plan


def load_frame(path: Path, stamp: int, seq: int, frame_id: str = "camera") -> Image:
    from PIL import Image as PILImage
    from PIL import UnidentifiedImageError

    try:
        with PILImage.open(path) as pil:
            pil.load()
            if pil.mode in ("L", "I;16", "1"):
                arr = np.asarray(pil.convert("L"))
                enc = "mono8"
            else:
                arr = np.asarray(pil.convert("RGB"))
                enc = "rgb8"
    except (UnidentifiedImageError, OSError) as exc:
        raise InputFormatError(f"{path}: cannot read image: {exc}") from None
    return Image(header=Header(seq=seq, stamp=stamp, frame_id=frame_id), height=arr.shape[0], width=arr.shape[1],
                 encoding=enc, data=np.ascontiguousarray(arr))


def iter_frames(plan: list[tuple[int, int, Path]]) -> Iterator[tuple[int, str, Image]]:
    for stamp, seq, path in plan:
        yield stamp, "camera/image_raw", load_frame(path, stamp, seq)
