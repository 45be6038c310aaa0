"""``poseidon transform IN.mcap --out OUT.mcap [--segments ...]``: the Underwater Cave
Transformed Database protocol (dissertation Section 5.2) on any recording.

Five *source* time ranges of the input (seconds from its first message) are chained into
nine sequential output segments::

    entry | area1 loop1  loop2* loop3* | transition | area2 loop1  loop2* loop3* | exit

Loop 1 of each area is the source range unaltered; loops 2 and 3 replicate every stream
of loop 1 (IMU, DVL, depth, sonars, odometry, ground truth) and perturb each camera image
(``*``): a random horizontal translation of 5 % +- 1 % of the image width (random sign)
and a rotation of 0 +- 0.5 deg about the image centre (Normal draws, seeded), edges
clamped.  Optional extra perturbations of loops 2-3 (the dissertation's future work):
``--illumination G`` (gain change up to +-G and a horizontal lighting gradient),
``--particles N`` (about N marine-snow blobs per image), ``--blur S`` (Gaussian blur of
up to S px), ``--occlusion F`` (a dark blob covering up to a fraction F of the image),
``--scale S`` (zoom by 1 +- S).

``--areas 1`` keeps one area (the demo's short mission): three source ranges (entry, area-1
loop, exit) chained into five output segments ``entry | loop1 loop2* loop3* | exit``; by
default from a sim recording: the approach, the first complete area-1 loop, and the next
``exit`` seconds (30) after it, so a ~5.5-minute ``poseidon sim`` is enough.

``--segments "a:b,c:d,e:f,g:h,i:j"`` gives the five ranges (entry, area-1 loop, transition,
area-2 loop, exit; seconds; half-open).  Default: from a ``poseidon sim`` recording's
metadata (entry = the approach, loop = the first complete loop of each area, transition =
the first transition 1->2, exit = the transition 2->1 that follows the area-2 loops), else
the fractions 0-10-40-50-80-100 % of the duration.

Output timeline: segment k starts 1 ms after segment k-1 ends; stamps are re-based
(strictly increasing per key, 1 ns nudges if the input repeats a stamp), seq is renumbered
per key from 0.  ``truth/revisits`` is rewritten: an image of loop 2 or 3 revisits the
copies (in earlier loops of the same area) of its source frame and of source frames within
``--revisit-tolerance`` frames (default 2); revisits the input's own ``truth/revisits``
declares are carried over to every copy.  Metadata ``poseidon`` records the source
ranges, the output segment table and the perturbation parameters; ``transform_segments``
lists the nine output segments with their output time ranges.
"""
from __future__ import annotations

import argparse
import json
import math
import struct
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numba as nb
import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from tqdm import tqdm

from common.codec import decode_dict, pack_obj
from common.mcap_io import RecordingError, RecordingWriter, read_messages, read_metadata

__all__ = ["main", "transform", "perturb_image", "Perturbation", "parse_segments", "default_segments"]

GAP_NS = 1_000_000  # 1 ms between output segments
DEFAULT_IMAGE_KEY = "camera/image_raw"
SEGMENT_NAMES = ["entry", "area1_loop1", "area1_loop2", "area1_loop3", "transition",
                 "area2_loop1", "area2_loop2", "area2_loop3", "exit"]
# output segment -> (source range index, copy number within the area: 0 unaltered, 1-2 perturbed)
PLAN = [(0, 0), (1, 0), (1, 1), (1, 2), (2, 0), (3, 0), (3, 1), (3, 2), (4, 0)]
# --areas 1: entry | area-1 loop x3 | exit
PLAN_ONE_AREA = [(0, 0), (1, 0), (1, 1), (1, 2), (2, 0)]
SEGMENT_NAMES_ONE_AREA = ["entry", "area1_loop1", "area1_loop2", "area1_loop3", "exit"]
RANGE_NAMES = {2: ("entry", "area-1 loop", "transition", "area-2 loop", "exit"), 1: ("entry", "area-1 loop", "exit")}
ONE_AREA_EXIT_S = 30.0


@dataclass
class Perturbation:
    """Parameters of the image perturbation of loops 2-3 (0 disables an extra)."""

    shift_mean: float = 0.05       # fraction of the width
    shift_std: float = 0.01
    rot_std_deg: float = 0.5
    illumination: float = 0.0
    particles: float = 0.0
    blur: float = 0.0
    occlusion: float = 0.0
    scale: float = 0.0


@nb.njit(cache=True, nogil=True)
def _warp(img: np.ndarray, out: np.ndarray, m00: float, m01: float, m02: float, m10: float, m11: float,
          m12: float) -> None:
    """out[y, x, c] = img sampled bilinearly at (sx, sy) = M @ (x, y, 1), edges clamped."""
    h, w, ch = img.shape
    for y in range(h):
        for x in range(w):
            sx = min(max(m00 * x + m01 * y + m02, 0.0), w - 1.0001)
            sy = min(max(m10 * x + m11 * y + m12, 0.0), h - 1.0001)
            x0 = int(sx)
            y0 = int(sy)
            fx = sx - x0
            fy = sy - y0
            for c in range(ch):
                top = img[y0, x0, c] * (1 - fx) + img[y0, x0 + 1, c] * fx
                bot = img[y0 + 1, x0, c] * (1 - fx) + img[y0 + 1, x0 + 1, c] * fx
                out[y, x, c] = top * (1 - fy) + bot * fy


def _gauss_blur(f: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0.05:
        return f
    r = max(1, int(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    pad = [(r, r), (0, 0)] + ([(0, 0)] if f.ndim == 3 else [])
    g = np.pad(f, pad, mode="edge")
    g = sum(k[i] * g[i:i + f.shape[0]] for i in range(2 * r + 1))
    pad = [(0, 0), (r, r)] + ([(0, 0)] if f.ndim == 3 else [])
    g2 = np.pad(g, pad, mode="edge")
    out: np.ndarray = sum(k[i] * g2[:, i:i + f.shape[1]] for i in range(2 * r + 1))
    return out


def perturb_image(img: np.ndarray, rng: np.random.Generator, p: Perturbation) -> tuple[np.ndarray, dict[str, float]]:
    """The loop-2/3 image transformation of Section 5.2 (plus enabled extras); returns the
    image (same dtype and shape) and the drawn parameters."""
    h, w = img.shape[:2]
    shift = float(rng.choice([-1.0, 1.0]) * rng.normal(p.shift_mean, p.shift_std) * w)
    rot = float(rng.normal(0.0, p.rot_std_deg))
    zoom = float(1.0 + rng.uniform(-p.scale, p.scale)) if p.scale > 0 else 1.0
    th = math.radians(rot)
    c, s = math.cos(th), math.sin(th)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32) if (p.illumination > 0 or p.occlusion > 0) else (None, None)
    # output pixel q = R * zoom * (src - centre) + centre + (shift, 0)  ->  src = inverse:
    # sx = (c (x - cx - shift) + s (y - cy)) / zoom + cx,  sy = (-s (x - cx - shift) + c (y - cy)) / zoom + cy
    src = img if img.ndim == 3 else img[:, :, None]
    f = np.empty(src.shape, np.float32)
    _warp(np.ascontiguousarray(src), f, c / zoom, s / zoom, cx - (c * (cx + shift) + s * cy) / zoom,
          -s / zoom, c / zoom, cy - (-s * (cx + shift) + c * cy) / zoom)
    if img.ndim == 2:
        f = f[:, :, 0]
    drawn = {"shift_px": shift, "rotation_deg": rot}
    if p.scale > 0:
        drawn["scale"] = zoom
    if p.illumination > 0:
        gain = 1.0 + rng.uniform(-p.illumination, p.illumination)
        grad = rng.uniform(-p.illumination, p.illumination)
        ramp = 1.0 + grad * (xx / max(w - 1, 1) - 0.5)
        f = f * (gain * ramp)[..., None] if f.ndim == 3 else f * gain * ramp
        drawn["gain"] = gain
        drawn["gradient"] = grad
    if p.blur > 0:
        sigma = float(rng.uniform(0.3, p.blur))
        f = _gauss_blur(f, sigma)
        drawn["blur_sigma_px"] = sigma
    if p.particles > 0:
        n = int(rng.poisson(p.particles))
        top = 255.0 if img.dtype == np.uint8 else float(np.iinfo(img.dtype).max) if img.dtype.kind == "u" else 1.0
        for _ in range(n):
            u, v = rng.uniform(0, w), rng.uniform(0, h)
            rad = rng.uniform(0.6, 3.0)
            amp = rng.uniform(0.2, 0.7) * top
            x0, x1 = max(int(u - 3 * rad), 0), min(int(u + 3 * rad) + 1, w)
            y0, x1b = max(int(v - 3 * rad), 0), min(int(v + 3 * rad) + 1, h)
            if x1 <= x0 or x1b <= y0:
                continue
            gy, gx = np.mgrid[y0:x1b, x0:x1]
            blob = amp * np.exp(-((gx - u) ** 2 + (gy - v) ** 2) / (2 * rad * rad))
            if f.ndim == 3:
                f[y0:x1b, x0:x1] += blob[..., None]
            else:
                f[y0:x1b, x0:x1] += blob
        drawn["particles"] = n
    if p.occlusion > 0:
        frac = float(rng.uniform(0.3, 1.0) * p.occlusion)
        rad = math.sqrt(frac * w * h / math.pi)
        u, v = rng.uniform(0, w), rng.uniform(0, h)
        if xx is None or yy is None:
            raise RuntimeError("pixel grid missing although occlusion is on")
        mask = np.clip((rad - np.hypot(xx - u, yy - v)) / 4.0, 0.0, 1.0) * 0.85
        f = f * (1 - mask[..., None]) if f.ndim == 3 else f * (1 - mask)
        drawn["occlusion_fraction"] = frac
    if img.dtype.kind in "ui":
        info = np.iinfo(img.dtype)
        out = np.clip(np.rint(f), info.min, info.max).astype(img.dtype)
    else:
        out = f.astype(img.dtype)
    return out, drawn


def parse_segments(text: str, areas: int = 2) -> list[tuple[float, float]]:
    """``"a:b,c:d,e:f,g:h,i:j"`` -> five (start_s, end_s) ranges (three with ``areas`` 1)."""
    names = RANGE_NAMES[areas]
    parts = [t.strip() for t in text.split(",") if t.strip()]
    if len(parts) != len(names):
        raise ValueError(f"--segments needs {len(names)} ranges ({', '.join(names)}), "
                         f"got {len(parts)}: {text!r}")
    out = []
    for name, part in zip(names, parts):
        try:
            a, b = (float(x) for x in part.split(":"))
        except ValueError:
            raise ValueError(f"--segments: {name} range {part!r} is not 'start_s:end_s'") from None
        if not (0 <= a < b):
            raise ValueError(f"--segments: {name} range {part!r} must satisfy 0 <= start < end")
        out.append((a, b))
    return out


def default_segments(meta: dict[str, dict[str, str]], duration_s: float,
                     areas: int = 2) -> tuple[list[tuple[float, float]], str]:
    """Source ranges from a sim recording's route segments, else duration fractions."""
    segs = json.loads(meta.get("poseidon", {}).get("segments", "null") or "null")
    if segs:
        def first(pred: Any, after: float = -1.0) -> dict[str, Any] | None:
            return next((s for s in segs if pred(s) and s["start_s"] >= after and s["complete"]), None)

        entry = first(lambda s: s["name"] == "transition_2_1")
        a = first(lambda s: s["name"] == "area1_ellipse", entry["end_s"] - 1e-6 if entry else -1.0)
        if areas == 1:
            if entry and a and a["end_s"] + 1.0 <= duration_s:
                exit_end = min(a["end_s"] + ONE_AREA_EXIT_S, duration_s)
                return ([(entry["start_s"], entry["end_s"]), (a["start_s"], a["end_s"]), (a["end_s"], exit_end)],
                        "sim route segments (one area)")
            raise ValueError("--areas 1 needs a sim recording with the approach, one complete area-1 loop and at "
                             "least 1 s after it (about 5 minutes of 'poseidon sim'), or explicit --segments")
        tr = first(lambda s: s["name"] == "transition_1_2", a["end_s"] - 1e-6) if a else None
        b = first(lambda s: s["name"] == "area2_cave2", tr["end_s"] - 1e-6) if tr else None
        ex = first(lambda s: s["name"] == "transition_2_1", b["end_s"] - 1e-6) if b else None
        if entry and a and tr and b and ex:
            return [(entry["start_s"], entry["end_s"]), (a["start_s"], a["end_s"]), (tr["start_s"], tr["end_s"]),
                    (b["start_s"], b["end_s"]), (ex["start_s"], ex["end_s"])], "sim route segments"
    f = [0.0, 0.1, 0.4, 0.5, 0.8, 1.0]
    return [(f[i] * duration_s, f[i + 1] * duration_s) for i in range(5)], "duration fractions 0-10-40-50-80-100 %"


def _span(path: Path) -> tuple[int, int]:
    """(first, last) log time of the recording."""
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except (McapError, ValueError, EOFError, KeyError, AssertionError, struct.error):
            summary = None  # no usable index (e.g. a killed recorder): read sequentially below
    if summary is not None and summary.statistics is not None and summary.statistics.message_count:
        return summary.statistics.message_start_time, summary.statistics.message_end_time
    first = last = None
    for r in read_messages(path):
        first = r.stamp if first is None else first
        last = r.stamp
    if first is None or last is None:
        raise RecordingError(f"{path}: no messages")
    return first, last


def _keys(path: Path) -> set[str]:
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except (McapError, ValueError, EOFError, KeyError, AssertionError, struct.error):
            summary = None  # unindexed: read sequentially below
    if summary is not None:
        return {c.topic for c in summary.channels.values()}
    return {r.key for r in read_messages(path)}


def _range_messages(path: Path, t0: int, t1: int) -> Iterator[tuple[str, str, int, bytes]]:
    """(key, type name, stamp, payload) of the messages with t0 <= stamp < t1, in time order
    (an indexed recording: only the chunks that can hold them are read)."""
    for r in read_messages(path, start_ns=t0, end_ns=t1):
        yield r.key, r.type_name, r.stamp, r.payload


def _check_transform_args(src: Path, out: Path, areas: int, revisit_tolerance: int) -> None:
    if areas not in RANGE_NAMES:
        raise ValueError(f"areas must be 1 or 2, got {areas}")
    if src.resolve() == out.resolve():
        raise ValueError(f"{out}: output would overwrite the input")
    if not src.is_file():
        raise RecordingError(f"{src}: no such recording")
    if revisit_tolerance < 0:
        raise ValueError(f"revisit tolerance must be >= 0 frames, got {revisit_tolerance}")


def _source_segments(src: Path, meta: dict[str, dict[str, str]], segments: list[tuple[float, float]] | None,
                     duration_s: float, areas: int) -> tuple[list[tuple[float, float]], str]:
    """The source ranges (s) and where they come from; checked against the recording."""
    how = "given"
    if segments is None:
        segments, how = default_segments(meta, duration_s, areas)
    if len(segments) != len(RANGE_NAMES[areas]):
        raise ValueError(f"{len(RANGE_NAMES[areas])} source ranges needed with areas={areas}, got {len(segments)}")
    for (a, b), name in zip(segments, RANGE_NAMES[areas]):
        if a >= duration_s + 1e-9:
            raise ValueError(f"{src}: {name} range {a}:{b} s starts after the recording ends ({duration_s:.3f} s)")
    return segments, how


def _source_revisits(src: Path, image_key: str) -> tuple[dict[int, int], dict[int, set[int]]]:
    """Source camera frame index (0-based, recording order) of each frame stamp, and the
    input's own revisits as a symmetric relation."""
    src_frames: list[int] = []
    src_truth: dict[int, list[int]] = {}
    for r in read_messages(src, keys=[image_key, "truth/revisits"]):
        if r.key == image_key:
            src_frames.append(r.stamp)
        else:
            d = decode_dict(r.payload)
            src_truth[int(d["frame_index"])] = [int(x) for x in np.asarray(d["same_place"])]
    if not src_frames:
        raise ValueError(f"{src}: no messages on the camera key {image_key!r} (keys: {sorted(_keys(src))}); "
                         f"pass --image-key")
    frame_of_stamp = {s: i for i, s in enumerate(src_frames)}
    rel: dict[int, set[int]] = {}
    for i, js in src_truth.items():
        for j in js:
            rel.setdefault(i, set()).add(j)
            rel.setdefault(j, set()).add(i)
    return frame_of_stamp, rel


def _provenance(src: Path, seed: int, how: str, areas: int, segments: list[tuple[float, float]],
                pert: Perturbation, revisit_tolerance: int) -> dict[str, Any]:
    """The head of the output's ``poseidon`` metadata record (the key order is part of the bytes)."""
    return {"tool": "poseidon transform", "source": str(src), "seed": seed, "segments_from": how, "areas": areas,
            "source_segments_s": segments, "perturbation": pert.__dict__, "revisit_tolerance_frames": revisit_tolerance}


def _perturbation_stats(perturb_log: list[dict[str, float]]) -> dict[str, float]:
    if not perturb_log:
        return {}
    sh = np.array([abs(p["shift_px"]) for p in perturb_log])
    ro = np.array([p["rotation_deg"] for p in perturb_log])
    return {"images": len(perturb_log), "shift_px_mean": float(sh.mean()), "shift_px_std": float(sh.std()),
            "rotation_deg_mean": float(ro.mean()), "rotation_deg_std": float(ro.std())}


def transform(src: str | Path, out: str | Path, segments: list[tuple[float, float]] | None = None,
              seed: int = 0, pert: Perturbation | None = None, revisit_tolerance: int = 2,
              progress: bool = True, image_key: str = DEFAULT_IMAGE_KEY, areas: int = 2,
              compression: str = "zstd") -> dict[str, Any]:
    """Write the transformed recording (MCAP chunks in ``compression``); returns a summary (per-key
    counts, segment table). ``image_key`` is the camera stream perturbed and indexed by ``truth/revisits``;
    ``areas`` 2 is the dissertation's nine-segment protocol, 1 keeps area 1 only."""
    src, out = Path(src), Path(out)
    _check_transform_args(src, out, areas, revisit_tolerance)
    plan, seg_names = (PLAN, SEGMENT_NAMES) if areas == 2 else (PLAN_ONE_AREA, SEGMENT_NAMES_ONE_AREA)
    pert = pert or Perturbation()
    first, last = _span(src)
    duration_s = (last - first) / 1e9
    meta = read_metadata(src)
    segments, how = _source_segments(src, meta, segments, duration_s, areas)
    rng = np.random.default_rng([seed, 909])
    frame_of_stamp, rel = _source_revisits(src, image_key)

    part = out.with_name(out.name + ".part")  # renamed on success, removed on failure
    writer = RecordingWriter(part, compression=compression)
    ok = False
    seq: dict[str, int] = {}
    last_stamp: dict[str, int] = {}
    cursor = first
    table = []
    out_frames: list[tuple[int, int, int, int]] = []  # (output stamp, source frame, output segment, copy)
    perturb_log: list[dict[str, float]] = []
    total = 0
    bar = tqdm(desc="transform", unit="msg", disable=not progress)
    try:
        for k, (si, copy) in enumerate(plan):
            a_s, b_s = segments[si]
            t0 = first + int(round(a_s * 1e9))
            t1 = min(first + int(round(b_s * 1e9)), last + 1)
            seg_start = cursor
            seg_last = cursor
            n_seg = 0
            for key, type_name, stamp, payload in _range_messages(src, t0, t1):
                if key == "truth/revisits":
                    continue  # rewritten below
                new = cursor + (stamp - t0)
                if key in last_stamp and new <= last_stamp[key]:
                    new = last_stamp[key] + 1
                last_stamp[key] = new
                d = decode_dict(payload)
                s = seq.get(key, 0)
                seq[key] = s + 1
                d["header"] = dict(d["header"], seq=s, stamp=new)
                if key == image_key:
                    if copy > 0:
                        img, drawn = perturb_image(np.asarray(d["data"]), rng, pert)
                        d["data"] = img
                        perturb_log.append(drawn)
                    out_frames.append((new, frame_of_stamp.get(stamp, -1), k, copy))
                writer.write_encoded(key, type_name, pack_obj(d), new, s)
                seg_last = max(seg_last, new)
                n_seg += 1
                bar.update(1)
            total += n_seg
            end = max(seg_last, seg_start + (t1 - t0))
            table.append({"name": seg_names[k], "source_start_s": a_s, "source_end_s": (t1 - first) / 1e9,
                          "copy": copy, "perturbed": copy > 0, "start_s": (seg_start - first) / 1e9,
                          "end_s": (end - first) / 1e9, "messages": n_seg})
            cursor = end + GAP_NS
        _write_revisits(writer, out_frames, rel, revisit_tolerance, seq, areas)
        pstats = _perturbation_stats(perturb_log)
        writer.add_metadata("poseidon", {**_provenance(src, seed, how, areas, segments, pert, revisit_tolerance),
                                         "perturbation_stats": pstats, "source_metadata": meta.get("poseidon", {})})
        writer.add_metadata("transform_segments", {"segments": table})
        ok = True
    finally:
        bar.close()
        writer.close()
        if ok:
            part.replace(out)
        else:
            part.unlink(missing_ok=True)
    return {"out": str(out), "segments": table, "segments_from": how, "counts": dict(sorted(writer.counts.items())),
            "frames": len(out_frames), "perturbed_frames": len(perturb_log), "perturbation_stats": pstats,
            "duration_s": (cursor - GAP_NS - first) / 1e9}


def _write_revisits(writer: RecordingWriter, frames: list[tuple[int, int, int, int]], rel: dict[int, set[int]],
                    tol: int, seq: dict[str, int], areas: int = 2) -> None:
    """truth/revisits for every output frame (see module docstring)."""
    by_src: dict[int, list[int]] = {}
    for i, (_, s, _, _) in enumerate(frames):
        by_src.setdefault(s, []).append(i)
    # output segment index -> area, for the segments that are loop copies
    area_of = {1: 1, 2: 1, 3: 1, 5: 2, 6: 2, 7: 2} if areas == 2 else {1: 1, 2: 1, 3: 1}
    for i, (stamp, s, seg, copy) in enumerate(frames):
        same: set[int] = set()
        if s >= 0:
            cands = set(rel.get(s, ()))
            if seg in area_of and copy > 0:
                cands.update(range(s - tol, s + tol + 1))
            for s2 in cands:
                for j in by_src.get(s2, ()):
                    if j >= i:
                        break
                    seg_j, copy_j = frames[j][2], frames[j][3]
                    if s2 in rel.get(s, ()):
                        same.add(j)
                    elif seg in area_of and area_of.get(seg_j) == area_of[seg] and copy_j < copy:
                        same.add(j)
        q = seq.get("truth/revisits", 0)
        seq["truth/revisits"] = q + 1
        payload = pack_obj({"header": {"seq": q, "stamp": stamp, "frame_id": "camera"}, "frame_index": i,
                            "same_place": np.array(sorted(same), dtype=np.int32)})
        writer.write_encoded("truth/revisits", "poseidon_msgs/RevisitTruth", payload, stamp, q)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon transform", description=__doc__.split("\n\n")[0])
    ap.add_argument("input", help="input MCAP recording")
    ap.add_argument("--out", required=True, help="output MCAP recording")
    ap.add_argument("--segments", default=None,
                    help='five source ranges "entry,loop1,transition,loop2,exit" as start_s:end_s (three with '
                         '--areas 1: "entry,loop1,exit"; default: see doc)')
    ap.add_argument("--areas", type=int, choices=(1, 2), default=2,
                    help="2: the nine-segment protocol (default); 1: entry, three loops of area 1, exit")
    ap.add_argument("--seed", type=int, default=0, help="perturbation seed (default 0)")
    ap.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                    help="MCAP chunk compression of the output (default zstd)")
    ap.add_argument("--revisit-tolerance", type=int, default=2, help="frames either side counted as the same place")
    ap.add_argument("--image-key", default=DEFAULT_IMAGE_KEY, help="camera key to perturb (default camera/image_raw)")
    ap.add_argument("--illumination", type=float, nargs="?", const=0.25, default=0.0, help="gain change +- G (0.25)")
    ap.add_argument("--particles", type=float, nargs="?", const=40.0, default=0.0, help="snow blobs per image (40)")
    ap.add_argument("--blur", type=float, nargs="?", const=1.5, default=0.0, help="max Gaussian blur sigma px (1.5)")
    ap.add_argument("--occlusion", type=float, nargs="?", const=0.15, default=0.0, help="max occluded fraction (0.15)")
    ap.add_argument("--scale", type=float, nargs="?", const=0.05, default=0.0, help="zoom 1 +- S (0.05)")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    try:
        segs = parse_segments(args.segments, args.areas) if args.segments else None
    except ValueError as exc:
        ap.error(str(exc))
    for name in ("illumination", "particles", "blur", "occlusion", "scale"):
        if getattr(args, name) < 0:
            ap.error(f"--{name} must be >= 0")
    pert = Perturbation(illumination=args.illumination, particles=args.particles, blur=args.blur,
                        occlusion=args.occlusion, scale=args.scale)
    try:
        summary = transform(args.input, args.out, segs, args.seed, pert, args.revisit_tolerance,
                            progress=not args.no_progress, image_key=args.image_key, areas=args.areas,
                            compression=args.compression)
    except (RecordingError, ValueError) as exc:
        print(f"poseidon transform: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(f"wrote {args.out}: {summary['frames']} frames ({summary['perturbed_frames']} perturbed), "
              f"{summary['duration_s']:.1f} s, segments from {summary['segments_from']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
