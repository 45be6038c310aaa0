"""Encoder speed: CPU milliseconds per *camera frame*, sonar included (Eqs. 4.1-4.2).

Each variant encodes a sim-sized camera frame (384x288 RGB uint8) and, as often as the
variant's sonar rule says, the 224x224 polar sonar raster, through
:meth:`MultimodalEncoder.embed` (resize, normalisation, channels_last forward, pooling) plus
standardisation and LSBH -- what :class:`EncoderNode` does per frame.  Variants:

* ``shufflenetv2@224 sonar/frame`` -- the baseline: the Table 4.1 network at 224 px with the
  sonar raster re-encoded with every camera frame (the encoder before issue 8);
* ``efficientnet_lite0@S sonar/frame`` -- EfficientNet-Lite0 to block 10 at S px, sonar every frame;
* ``efficientnet_lite0@S sonar/5`` -- the same with the sonar re-encoded every 5th camera frame
  (the default ``encoder.sonar_encode_sweep_deg`` 45 deg at the Micron's 42 deg/s and a 5 Hz camera);
* ``... unfolded BN`` -- the default before ``encoder.fold_batchnorm`` (batch norm run as its own operator);
* ``... batch 8`` -- eight camera frames per forward pass (what a replay backlog allows).

Every variant but ``unfolded BN`` runs with ``encoder.fold_batchnorm`` (the default).

All timings are medians of interleaved rounds on ``--threads`` torch threads (default
``encoder.torch_threads`` = 1), so the ratio column (variant / baseline, same run) stays
meaningful on a loaded machine; the absolute ms are indicative only.  Weights do not change
the speed: ShuffleNetV2 runs untrained (no weights file needed), EfficientNet-Lite0 on its
packaged weights.

    .venv/bin/python benchmarks/bench_encoder.py [--repeats N] [--threads T]
"""
from __future__ import annotations

import argparse
import logging
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from services.encoder.config import EncoderConfig
from services.encoder.encoder import MultimodalEncoder


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
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (288, 384, 3), dtype=np.uint8) for _ in range(40)]
    sonar = np.repeat(rng.random((224, 224, 1), dtype=np.float32), 3, axis=2)
    base = dict(lsbh_matrix_path="", torch_threads=args.threads, embedding_norm="running")
    variants: dict[str, tuple[Callable[[], None], int]] = {}
    specs = [("shufflenetv2@224 sonar/frame", "shufflenetv2", 224, 1, 1, True),
             ("efficientnet_lite0@224 sonar/frame", "efficientnet_lite0", 224, 1, 1, True),
             ("efficientnet_lite0@160 sonar/frame", "efficientnet_lite0", 160, 1, 1, True),
             ("efficientnet_lite0@160 sonar/5 unfolded BN", "efficientnet_lite0", 160, 5, 1, False),
             ("efficientnet_lite0@160 sonar/5", "efficientnet_lite0", 160, 5, 1, True),
             ("efficientnet_lite0@128 sonar/5", "efficientnet_lite0", 128, 5, 1, True),
             ("efficientnet_lite0@160 sonar/5 batch 8", "efficientnet_lite0", 160, 5, 8, True)]
    encoders: dict[tuple[str, int, bool], MultimodalEncoder] = {}
    for label, name, size, every, batch, fold in specs:
        key = (name, size, fold)
        if key not in encoders:
            encoders[key] = MultimodalEncoder(EncoderConfig(cnn_backbone=name, input_size=size, batch_max=8,
                                                            untrained=name != "efficientnet_lite0",
                                                            fold_batchnorm=fold, **base))
        variants[label] = _variant(encoders[key], frames[:10] if batch == 1 else frames, sonar, every, batch)
    print(f"encoder benchmark: torch {torch.__version__}, {args.threads} thread(s), median of {args.repeats} "
          f"interleaved rounds; camera 384x288 RGB uint8, sonar raster 224x224; LSBH L=2048, s=0.25")
    t = _interleaved({k: fn for k, (fn, _) in variants.items()}, args.repeats)
    per = {k: t[k] / variants[k][1] * 1000.0 for k in variants}
    ref = per[specs[0][0]]
    print(f"{'variant':40s} {'ms/camera frame':>16s} {'vs baseline':>12s}")
    for k, ms in per.items():
        print(f"{k:40s} {ms:13.2f} ms {ms / ref:11.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
