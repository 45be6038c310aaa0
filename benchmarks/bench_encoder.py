"""Encoder speed: CPU milliseconds per *camera frame*, sonar included (Eqs. 4.1-4.2).

Each variant encodes a sim-sized camera frame (384x288 RGB uint8) and, as often as the
variant's sonar rule says, the 224x224 polar sonar raster, through
:meth:`MultimodalEncoder.embed` (resize, normalisation, channels_last forward, pooling) plus
standardisation and LSBH -- what :class:`EncoderNode` does per frame.  Variants:

* ``shufflenetv2@224 sonar/frame`` -- the baseline: the Table 4.1 network at 224 px with the
  sonar raster re-encoded with every camera frame (the dissertation's encoder);
* ``efficientnet_lite0@S sonar/frame`` -- EfficientNet-Lite0 to block 10 at S px, sonar every frame;
* ``efficientnet_lite0@S sonar/5`` -- the same with the sonar re-encoded every 5th camera frame
  (the default ``encoder.sonar.encode_sweep_deg`` 45 deg at the Micron's 42 deg/s and a 5 Hz camera);
* ``... unfolded BN`` -- the default before ``encoder.fold_batchnorm`` (batch norm run as its own operator);
* ``... batch 8`` -- eight camera frames per forward pass (what a replay backlog allows);
* ``... onnxruntime`` / ``... openvino`` -- the default path with the backbone on another
  ``encoder.runtime`` (:mod:`services.encoder.runtime`; f32, same threads); ``... openvino-bf16``
  -- openvino with ``encoder.precision`` bf16 (``--mission`` also prints the share of torch's
  fused SDR bits it keeps).

A second table times the backbone alone per image on each runtime (one 160 px image per
call, already pre-processed; torch channels_last as in the encoder) for each backbone, with
the ratio to torch in the same run, and the largest relative difference of the pooled
embedding from torch's.  A runtime whose package is missing is left out (and said so).

Every variant but ``unfolded BN`` runs with ``encoder.fold_batchnorm`` (the default).

All timings are medians of interleaved rounds on ``--threads`` torch threads (default
``encoder.torch_threads`` = 1), so the ratio column (variant / baseline, same run) stays
meaningful on a loaded machine; the absolute ms are indicative only.  Weights do not change
the speed: ShuffleNetV2 runs untrained (no weights file needed), EfficientNet-Lite0 on its
packaged weights.  BLAS runs on one thread (``OPENBLAS_NUM_THREADS`` 1 unless set), as in
``poseidon run``.

``--mission REC.mcap`` adds the whole-run figure: the recording's camera frames and sonar
beams through the encoder node (:class:`EncoderNode`, the default configuration, no
transport) once per runtime, the process CPU seconds of each run (rounds interleaved by
runtime, median) and whether its fused and per-modality SDRs equal torch's, frame by frame.

    .venv/bin/python benchmarks/bench_encoder.py [--repeats N] [--threads T] [--mission REC.mcap [--rounds R]]
"""
from __future__ import annotations

import os

# one BLAS thread, as `poseidon` sets for every service (launcher/cli.py), before numpy loads
for _blas in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas, "1")

import argparse
import logging
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.encoder.config import EncoderConfig
from services.encoder.encoder import MultimodalEncoder
from services.encoder.runtime import RUNTIMES, RuntimeUnavailable

#: extra --runtimes value: openvino with encoder.precision bf16
BF16 = "openvino-bf16"


def _fields(rt: str) -> dict[str, str]:
    """The encoder fields of a --runtimes value: an encoder.runtime in f32, or ``openvino-bf16``."""
    return {"runtime": "openvino", "precision": "bf16"} if rt == BF16 else {"runtime": rt, "precision": "f32"}


def _encoder(cfg: EncoderConfig, rt: str) -> MultimodalEncoder:
    return MultimodalEncoder(cfg.model_copy(update=_fields(rt)))


def _interleaved(fns: dict[str, Callable[[], None]], repeats: int) -> dict[str, float]:
    """Median seconds of each callable, timed in alternating rounds (fair under shared CPUs)."""
    for fn in fns.values():
        fn()  # warm-up
        fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t)
    return {k: statistics.median(v) for k, v in times.items()}


def _variant(enc: MultimodalEncoder, frames: list[np.ndarray], sonar: np.ndarray, sonar_every: int,
             batch: int) -> tuple[Callable[[], None], int]:
    """A callable encoding ``len(frames)`` camera frames (sonar every ``sonar_every``-th) and that count."""

    def run() -> None:
        for i in range(0, len(frames), batch):
            chunk = frames[i:i + batch]
            with_sonar = [k for k in range(i, i + len(chunk)) if k % sonar_every == 0]
            ys = enc.embed(chunk + [sonar] * len(with_sonar))
            for y in ys[:len(chunk)]:
                enc.sdr("camera", y)
            for y in ys[len(chunk):]:
                enc.sdr("sonar", y)

    return run, len(frames)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.ERROR)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--threads", type=int, default=EncoderConfig().torch_threads,
                    help="torch threads (default: encoder.torch_threads)")
    ap.add_argument("--runtimes", default=",".join((*RUNTIMES, BF16)),
                    help=f"encoder.runtime values to time ({BF16}: openvino with encoder.precision bf16)")
    ap.add_argument("--backbones", default="efficientnet_lite0,shufflenetv2,alexnet_conv3",
                    help="backbones of the per-runtime table")
    ap.add_argument("--mission", default="", help="a recording: also time the whole run through the encoder node")
    ap.add_argument("--rounds", type=int, default=1, help="--mission: rounds per runtime")
    ap.add_argument("--mission-only", action="store_true", help="skip the per-frame tables")
    args = ap.parse_args(argv)
    runtimes = [r for r in args.runtimes.split(",") if r]
    if args.mission_only:
        _mission(args, runtimes)
        return 0
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (288, 384, 3), dtype=np.uint8) for _ in range(40)]
    sonar = np.repeat(rng.random((224, 224, 1), dtype=np.float32), 3, axis=2)
    base: dict[str, Any] = dict(lsbh={"matrix_path": ""}, torch_threads=args.threads, embedding_norm={"mode": "running"})
    variants: dict[str, tuple[Callable[[], None], int]] = {}
    # label, backbone, input px, sonar every n-th frame, batch, fold batch norm, runtime
    specs: list[tuple[str, str, int, int, int, bool, str]] = [
        ("shufflenetv2@224 sonar/frame", "shufflenetv2", 224, 1, 1, True, "torch"),
        ("efficientnet_lite0@224 sonar/frame", "efficientnet_lite0", 224, 1, 1, True, "torch"),
        ("efficientnet_lite0@160 sonar/frame", "efficientnet_lite0", 160, 1, 1, True, "torch"),
        ("efficientnet_lite0@160 sonar/5 unfolded BN", "efficientnet_lite0", 160, 5, 1, False, "torch"),
        ("efficientnet_lite0@160 sonar/5", "efficientnet_lite0", 160, 5, 1, True, "torch"),
        ("efficientnet_lite0@128 sonar/5", "efficientnet_lite0", 128, 5, 1, True, "torch"),
        ("efficientnet_lite0@160 sonar/5 batch 8", "efficientnet_lite0", 160, 5, 8, True, "torch")]
    missing: dict[str, str] = {}
    for rt in runtimes:
        if rt != "torch":
            try:
                _encoder(EncoderConfig(input_size=32, **base), rt)
            except RuntimeUnavailable as exc:
                missing[rt] = str(exc)
    runtimes = [r for r in runtimes if r not in missing]
    specs += [(f"efficientnet_lite0@160 sonar/5 {rt}", "efficientnet_lite0", 160, 5, 1, True, rt)
              for rt in runtimes if rt != "torch"]
    encoders: dict[tuple[str, int, bool, str], MultimodalEncoder] = {}
    for label, name, size, every, batch, fold, rt in specs:
        key = (name, size, fold, rt)
        if key not in encoders:
            encoders[key] = _encoder(EncoderConfig(cnn_backbone=name, input_size=size, batch_max=8,
                                                   untrained=name != "efficientnet_lite0", fold_batchnorm=fold,
                                                   **base), rt)
        variants[label] = _variant(encoders[key], frames[:10] if batch == 1 else frames, sonar, every, batch)
    print(f"encoder benchmark: torch {torch.__version__}, {args.threads} thread(s), median of {args.repeats} "
          f"interleaved rounds; camera 384x288 RGB uint8, sonar raster 224x224; LSBH L=2048, s=0.25")
    t = _interleaved({k: fn for k, (fn, _) in variants.items()}, args.repeats)
    per = {k: t[k] / variants[k][1] * 1000.0 for k in variants}
    ref = per[specs[0][0]]
    print(f"{'variant':40s} {'ms/camera frame':>16s} {'vs baseline':>12s}")
    for k, ms in per.items():
        print(f"{k:40s} {ms:13.2f} ms {ms / ref:11.2f}x")
    for rt, why in missing.items():
        print(f"{rt}: not timed ({why})")
    _per_runtime(args, runtimes, frames, base)
    if args.mission:
        _mission(args, runtimes)
    return 0


def _mission(args: argparse.Namespace, runtimes: list[str]) -> None:
    """Whole recording through the encoder node per runtime: CPU seconds and SDR equality with torch."""
    from common.mcap_io import read_messages
    from common.node import run_offline
    from system.config import PoseidonConfig
    from system.services import build_node

    base = PoseidonConfig.model_validate({"encoder": {"lsbh": {"matrix_path": ""}, "torch_threads": args.threads}})
    keys = ["camera/image_raw", base.encoder.sonar.topic]
    msgs = [(m.key, m.message()) for m in read_messages(args.mission, keys=keys)]
    n_cam = sum(k == "camera/image_raw" for k, _ in msgs)
    cpu: dict[str, list[float]] = {rt: [] for rt in runtimes}
    outs: dict[str, list[Any]] = {}
    for _ in range(args.rounds):
        for rt in runtimes:
            cfg = PoseidonConfig.model_validate({"encoder": {**base.encoder.model_dump(), **_fields(rt)}})
            node = build_node("encoder", cfg)  # start-up (export, compile) outside the timing
            t = time.process_time()
            outs[rt] = [m for _, m in run_offline(node, msgs)]
            cpu[rt].append(time.process_time() - t)
    print(f"\nwhole run through the encoder node: {args.mission} ({n_cam} camera frames, "
          f"{len(msgs) - n_cam} sonar messages), process CPU s, median of {args.rounds} round(s)")
    print(f"{'runtime':14s} {'CPU s':>8s} {'ms/frame':>9s} {'vs torch':>9s} {'SDRs equal torch':>17s} "
          f"{'fused bits kept':>16s}")
    ref = outs.get("torch")
    for rt in runtimes:
        c = statistics.median(cpu[rt])
        same, kept = "-", "-"
        if ref is not None:
            eq = sum(np.array_equal(a.fused.active, b.fused.active)
                     and all(np.array_equal(x.active, y.active) for x, y in zip(a.modalities, b.modalities))
                     for a, b in zip(outs[rt], ref))
            same = f"{eq}/{len(ref)}" + ("" if len(outs[rt]) == len(ref) else f" ({len(outs[rt])} outputs)")
            # share of torch's active fused bits this runtime also sets, mean over frames
            share = [np.intersect1d(a.fused.active, b.fused.active).size / max(b.fused.active.size, 1)
                     for a, b in zip(outs[rt], ref)]
            kept = f"{np.mean(share):.4f}"
        ratio = f"{c / statistics.median(cpu['torch']):8.2f}x" if "torch" in cpu else "-"
        print(f"{rt:14s} {c:8.1f} {c / max(n_cam, 1) * 1000:9.2f} {ratio:>9s} {same:>17s} {kept:>16s}")


def _per_runtime(args: argparse.Namespace, runtimes: list[str], frames: list[np.ndarray], base: dict[str, Any]) -> None:
    """Backbone forward + pooling per image on each runtime, ratio to torch (same run)."""
    print(f"\nbackbone per image (160 px, pre-processed, pooled 4x4), median of {args.repeats} interleaved rounds "
          f"of 10 images")
    print(f"{'backbone':20s} {'runtime':12s} {'ms/image':>10s} {'vs torch':>9s} {'max rel diff':>13s}")
    for name in [b for b in args.backbones.split(",") if b]:
        cfg = EncoderConfig(cnn_backbone=name, input_size=160, untrained=name != "efficientnet_lite0", **base)
        encs = {rt: _encoder(cfg, rt) for rt in runtimes}
        xs = {rt: [e.preprocess([f]) for f in frames[:10]] for rt, e in encs.items()}

        def run(e: MultimodalEncoder, batches: list[torch.Tensor]) -> Callable[[], None]:
            def go() -> None:
                with torch.inference_mode():
                    for x in batches:
                        torch.nn.functional.adaptive_avg_pool2d(e._features(x), e.cfg.pool_grid)
            return go

        t = _interleaved({rt: run(e, xs[rt]) for rt, e in encs.items()}, args.repeats)
        ref_y = encs["torch"].embed(frames[:4]) if "torch" in encs else None
        for rt in runtimes:
            diff = "-"
            if ref_y is not None:
                y = encs[rt].embed(frames[:4])
                diff = f"{max(float(np.abs(a - b).max() / np.abs(b).max()) for a, b in zip(y, ref_y)):.1e}"
            ratio = f"{t[rt] / t['torch']:8.2f}x" if "torch" in t else "-"
            print(f"{name:20s} {rt:12s} {t[rt] / 10 * 1000:7.2f} ms {ratio:>9s} {diff:>13s}")


if __name__ == "__main__":
    raise SystemExit(main())
