"""A picture of a simulated mission for the docs: camera frames, sonar rasters, the map.

Generates a mission (default 25 minutes, seed 0: area 1, the transition and area 2) into a temporary recording, then
composes: eight camera frames (evenly spaced, plus the frames nearest the traffic cone
of area 1), one full 360 deg turn of the Micron MSIS (polar -> Cartesian, 20 m), the
SeaKing profiler beams of the same period as a range x time raster, and a top view of the
cave (free space) with the path flown so far.

    .venv/bin/python -m missions.sim.montage --out docs/images/sim_montage.png
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image as PILImage
from PIL import ImageDraw

from common.mcap_io import read_messages, read_metadata
from common.messages import Image, Odometry, RangeImageBeam
from missions.sim.mission import SimParams, generate
from missions.sim.world import build_world

__all__ = ["make_montage", "main"]


def _polar(beams: list[tuple[float, np.ndarray]], size: int, max_range: float) -> np.ndarray:
    out = np.zeros((size, size), np.float32)
    for a, b in beams:
        r = (np.arange(len(b)) + 0.5) * max_range / len(b)
        for dr in (-0.4, 0.0, 0.4):  # fill gaps between bins
            rr = r + dr * max_range / len(b)
            x = (size / 2 - rr * np.cos(a) / max_range * size / 2).astype(int)
            y = (size / 2 + rr * np.sin(a) / max_range * size / 2).astype(int)
            ok = (x >= 0) & (x < size) & (y >= 0) & (y < size)
            np.maximum.at(out, (x[ok], y[ok]), b[ok].astype(np.float32))
    return out


def _sonar_colour(v: np.ndarray) -> np.ndarray:
    t = np.clip((v - 8.0) / 183.0, 0, 1) ** 0.8  # above the noise floor
    return (np.stack([t * 255, t ** 0.6 * 220, t ** 2 * 120], axis=-1)).astype(np.uint8)


def _top_view(seed: int, tp: np.ndarray, cones: list[dict[str, Any]], w_avail: int, size: int) -> PILImage.Image:
    """Top view of the cave with the path ``tp`` (truth positions) and the cones, scaled to
    fit ``w_avail`` x ``size`` pixels."""
    world = build_world(seed)
    free = world.free[::2, ::2]
    tv_rgb = np.where(free[..., None], np.array([70, 90, 110], np.uint8), np.array([25, 22, 20], np.uint8))
    tv = PILImage.fromarray(tv_rgb.astype(np.uint8))
    tdraw = ImageDraw.Draw(tv)
    res = world.grid_res * 2
    pts = [((p[1] - world.grid_y0) / res, (p[0] - world.grid_x0) / res) for p in tp[::5]]
    tdraw.line(pts, fill=(255, 220, 60), width=3)
    for c in cones:
        cx, cy = (c["y"] - world.grid_y0) / res, (c["x"] - world.grid_x0) / res
        tdraw.ellipse([cx - 5, cy - 5, cx + 5, cy + 5], fill=(255, 100, 20))
    scale = min(w_avail / tv.width, size / tv.height)
    return tv.resize((int(tv.width * scale), int(tv.height * scale)), PILImage.Resampling.BILINEAR).transpose(
        PILImage.Transpose.FLIP_TOP_BOTTOM)


def make_montage(out_png: str | Path, seed: int = 0, minutes: float = 25.0) -> Path:
    """Write the montage PNG; returns its path."""
    out_png = Path(out_png)
    with tempfile.TemporaryDirectory() as d:
        rec = Path(d) / "m.mcap"
        generate(rec, SimParams(minutes=minutes, seed=seed), progress=False)
        meta = read_metadata(rec)["poseidon"]
        features = json.loads(meta["features"])
        frames, stamps, truth, micron, seaking = [], [], [], [], []
        for r in read_messages(rec, keys=["camera/image_raw", "truth/pose", "sonar_micron", "sonar_seaking"]):
            m = r.message()
            if r.key == "camera/image_raw" and isinstance(m, Image):
                frames.append(np.asarray(m.data))
                stamps.append(r.stamp)
            elif r.key == "truth/pose" and isinstance(m, Odometry):
                truth.append((r.stamp, m.position))
            elif r.key == "sonar_micron" and isinstance(m, RangeImageBeam):
                micron.append((r.stamp, m.angle_rad, np.asarray(m.beam_data)))
            elif isinstance(m, RangeImageBeam):
                seaking.append((r.stamp, m.angle_rad, np.asarray(m.beam_data)))
            else:
                raise TypeError(f"montage: {r.key!r} carries an unexpected {type(m).__name__}")
    tt = np.array([s for s, _ in truth], float)
    tp = np.array([p for _, p in truth])
    fpos = np.stack([np.interp(np.array(stamps, float), tt, tp[:, k]) for k in range(3)], axis=1)
    picks = list(np.linspace(5, len(frames) - 5, 6).astype(int))
    cones = [f for f in features if f["kind"] == "cone"]
    for c in cones:
        d = np.hypot(fpos[:, 0] + 0.4 - c["x"], fpos[:, 1] - c["y"])
        k = int(np.argmin(d))
        if d[k] < 1.2 and k not in picks:
            picks.append(k)
    picks = sorted(picks)[:8]
    while len(picks) < 8:
        picks.append(int(len(frames) * (len(picks) + 0.5) / 9))
    picks = sorted(picks)
    fw, fh = frames[0].shape[1], frames[0].shape[0]
    size = 2 * fh
    canvas = PILImage.new("RGB", (4 * fw, 2 * fh + size + 24), (16, 16, 16))
    draw = ImageDraw.Draw(canvas)
    for i, k in enumerate(picks):
        x, y = (i % 4) * fw, (i // 4) * fh
        canvas.paste(PILImage.fromarray(frames[k]), (x, y))
        draw.text((x + 4, y + 4), f"frame {k}  t={(stamps[k] - stamps[0]) / 1e9:.1f} s", fill=(255, 255, 255))
    y0 = 2 * fh
    # one Micron turn (200 beams at 1.8 deg) around the middle of the mission
    mid = len(micron) // 2
    turn = [(a, b) for _, a, b in micron[mid:mid + 200]]
    canvas.paste(PILImage.fromarray(_sonar_colour(_polar(turn, size, 20.0))), (0, y0))
    draw.text((4, y0 + 4), "Micron MSIS, one 360 deg turn, 20 m", fill=(255, 255, 255))
    # SeaKing: the same period, beams as columns (range down), coloured
    s0 = micron[mid][0]
    s1 = micron[min(mid + 199, len(micron) - 1)][0]
    sk = [b for s, _, b in seaking if s0 <= s <= s1]
    if sk:
        ras = np.stack(sk, axis=1).astype(np.float32)
        img = PILImage.fromarray(_sonar_colour(ras)).resize((size, size), PILImage.Resampling.NEAREST)
        canvas.paste(img, (size, y0))
    draw.text((size + 4, y0 + 4), "SeaKing profiler: range (down, 10 m) x beams", fill=(255, 255, 255))
    tv = _top_view(seed, tp, cones, 4 * fw - 2 * size, size)
    canvas.paste(tv, (2 * size, y0 + (size - tv.height) // 2))
    draw.text((2 * size + 4, y0 + 4), "top view (north up, east right): cave, path (yellow), cones (orange)",
              fill=(255, 255, 255))
    draw.text((4, 2 * fh + size + 6), f"poseidon sim --minutes {minutes:g} --seed {seed}: downward camera 384x288 "
              f"(turbidity, lamp cone, blue-green cast, marine snow, noise), sonars from the cave geometry",
              fill=(200, 200, 200))
    out_png.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(out_png, optimize=True)
    return out_png


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="montage of a simulated mission")
    ap.add_argument("--out", default="docs/images/sim_montage.png")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--minutes", type=float, default=25.0)
    args = ap.parse_args(argv)
    print(make_montage(args.out, args.seed, args.minutes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
