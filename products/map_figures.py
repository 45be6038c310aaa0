"""``python -m products.map_figures OUT.png LEFT RIGHT [--titles A B]``: two map products of
``poseidon export`` side by side as one PNG, top views (x east / y north up), for the docs.

A panel is drawn from: a grid folder (``map.yaml`` + its image, shown as it is), a ``.ply``
cloud (its x, y rasterised by :func:`eval.report.benchmark.raster_png`, the report's point-map
raster, darker where more points fall), a Survex ``.3d`` file (cavern's output, read with
``dump3d``: the adjusted centreline's legs, loop-closure legs in red) or a run recording
(``.mcap``: the raw odometry path, :mod:`products.mapsource`).  Every panel is scaled to at most
:data:`PANEL_PX` pixels across and gets its title and a scale bar.
"""
from __future__ import annotations

import argparse
import base64
import io
import math
import subprocess
from pathlib import Path

import numpy as np
import yaml
from PIL import Image, ImageDraw

from eval.report.benchmark import raster_png, raster_resolution

__all__ = ["main", "panel", "PANEL_PX"]

PANEL_PX = 700


def _lines_image(segments: list[tuple[np.ndarray, tuple[int, int, int]]], size: int) -> tuple[Image.Image, float]:
    """Polylines (k, 2) in metres drawn in a white image; returns it and its metres per pixel."""
    allp = np.vstack([s for s, _ in segments])
    lo, hi = allp.min(axis=0) - 2.0, allp.max(axis=0) + 2.0
    res = float(max(hi - lo)) / size
    w, h = int(math.ceil((hi[0] - lo[0]) / res)) + 1, int(math.ceil((hi[1] - lo[1]) / res)) + 1
    img = Image.new("RGB", (w, h), "white")
    draw = ImageDraw.Draw(img)
    for seg, color in segments:
        draw.line([((x - lo[0]) / res, h - 1 - (y - lo[1]) / res) for x, y in seg], fill=color, width=2)
    return img, res


def _survey(path: Path) -> tuple[Image.Image, float]:
    """The legs of a cavern ``.3d`` file (``dump3d`` text): MOVE starts a polyline, LINE continues it."""
    text = subprocess.run(["dump3d", str(path)], capture_output=True, text=True, check=True, timeout=60).stdout
    segs: list[tuple[np.ndarray, tuple[int, int, int]]] = []
    last: list[float] = []
    for line in text.splitlines():
        tok = line.split()
        if tok and tok[0] in ("MOVE", "LINE"):
            p = [float(tok[1]), float(tok[2])]
            if tok[0] == "LINE" and last:
                dup = "DUPLICATE" in line
                segs.append((np.array([last, p]), (214, 39, 40) if dup else (31, 119, 180)))
            last = p
    if not segs:
        raise ValueError(f"{path}: no legs in the survey")
    return _lines_image(segs, PANEL_PX)


def panel(path: Path) -> tuple[Image.Image, float | None]:
    """The top view of one product (module docstring) and its metres per pixel (None: it has a scale bar)."""
    if (path / "map.yaml").is_file():
        meta = yaml.safe_load((path / "map.yaml").read_text())
        img = Image.open(path / meta["image"]).convert("RGB")
        res = float(meta["resolution"])
        k = max(1.0, max(img.size) / PANEL_PX)
        return img.resize((int(img.size[0] / k), int(img.size[1] / k)), Image.Resampling.LANCZOS), res * k
    if path.suffix == ".ply":
        from plyfile import PlyData

        v = PlyData.read(str(path))["vertex"]
        pts = np.column_stack([v["x"], v["y"]])
        res = raster_resolution(pts, PANEL_PX)
        uri = raster_png(pts, res)
        return Image.open(io.BytesIO(base64.b64decode(uri.split(",", 1)[1]))).convert("RGB"), None
    if path.suffix == ".3d":
        return _survey(path)
    if path.suffix == ".mcap":
        from products.mapsource import load_map_source

        src = load_map_source(path)
        if src.raw is None:
            raise ValueError(f"{path}: no odometry to draw")
        return _lines_image([(src.raw.positions[:, :2], (31, 119, 180))], PANEL_PX)
    raise ValueError(f"{path}: not a grid folder, .ply, .3d or .mcap")


def _titled(img: Image.Image, res: float | None, title: str) -> Image.Image:
    """The panel with its title above and, unless ``res`` is None (the raster has its own), a scale bar."""
    out = Image.new("RGB", (img.size[0] + 20, img.size[1] + 60), "white")
    out.paste(img, (10, 30))
    draw = ImageDraw.Draw(out)
    draw.text((10, 8), title, fill=(0, 0, 0))
    if res is None:
        return out
    bar_m = 10.0 ** math.floor(math.log10(max(img.size[0] * res / 4, 1e-3)))
    y = img.size[1] + 45
    draw.line([(10, y), (10 + bar_m / res, y)], fill=(214, 39, 40), width=3)
    draw.text((14 + bar_m / res, y - 6), f"{bar_m:g} m", fill=(214, 39, 40))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m products.map_figures", description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="the PNG to write")
    ap.add_argument("left")
    ap.add_argument("right")
    ap.add_argument("--titles", nargs=2, default=None, metavar=("LEFT", "RIGHT"))
    args = ap.parse_args(argv)
    titles = args.titles or [Path(args.left).name, Path(args.right).name]
    panels = [_titled(*panel(Path(p)), t) for p, t in zip((args.left, args.right), titles)]
    w = sum(p.size[0] for p in panels)
    h = max(p.size[1] for p in panels)
    fig = Image.new("RGB", (w, h), "white")
    x = 0
    for p in panels:
        fig.paste(p, (x, 0))
        x += p.size[0]
    fig.save(args.out, optimize=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
