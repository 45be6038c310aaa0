"""Encoder speed: milliseconds per frame of the CNN embedding + LSBH (Eqs. 4.1-4.2).

For each backbone (ShuffleNetV2 x1.0 stage3, AlexNet conv3) and batch size (1, 8):

* ``encoder``   -- :meth:`MultimodalEncoder.embed` + standardisation + LSBH: resize 640x480 -> 224x224,
  normalisation, channels_last forward, pooling, projection, top/bottom-k;
* baselines measured in the same run: the same encoder in contiguous (NCHW) memory format,
  and the raw backbone forward alone (a ready 224x224 channels_last tensor, no pre- or
  post-processing).

Printed ratios: encoder / contiguous (< 1: channels_last helps) and encoder / raw forward
(the overhead of pre-processing and LSBH).  Seeded weights (speed does not depend on them).

    .venv/bin/python benchmarks/bench_encoder.py [--repeats N] [--threads T]
"""
from __future__ import annotations

import argparse
import copy
import logging
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common.config import EncoderConfig  # noqa: E402
from services.encoder.backbones import load_backbone  # noqa: E402
from services.encoder.encoder import MultimodalEncoder  # noqa: E402


def _interleaved(fns: dict[str, object], repeats: int) -> dict[str, float]:
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


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.ERROR)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--threads", type=int, default=EncoderConfig().torch_threads,
                    help="torch threads (default: encoder.torch_threads)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (480, 640, 3), dtype=np.uint8) for _ in range(8)]
    print(f"encoder benchmark: torch {torch.__version__}, {args.threads} threads, median of {args.repeats} "
          f"interleaved rounds, input 640x480 RGB uint8, L=2048, s=0.25, seeded weights")
    print(f"{'backbone':14s} {'batch':>5s} {'encoder':>12s} {'contiguous':>12s} {'raw fwd':>12s} "
          f"{'enc/contig':>10s} {'enc/raw':>8s}")
    for name in ("shufflenetv2", "alexnet_conv3"):
        for batch in (1, 8):
            cfg = EncoderConfig(cnn_backbone=name, lsbh_matrix_path="", torch_threads=args.threads,
                                batch_max=batch)
            bb_cl = load_backbone(name, seed=cfg.lsbh_seed)
            bb_nc = copy.deepcopy(bb_cl)
            enc_cl = MultimodalEncoder(cfg, backbone=bb_cl, channels_last=True)
            enc_nc = MultimodalEncoder(cfg, backbone=bb_nc, channels_last=False)
            enc_nc._lsbh["camera"] = enc_cl.lsbh("camera")
            imgs = frames[:batch]
            x = enc_cl.preprocess(imgs)

            def encoder(enc: MultimodalEncoder = enc_cl) -> None:
                enc.sdr_batch("camera", enc.embed(imgs))

            def contiguous(enc: MultimodalEncoder = enc_nc) -> None:
                enc.sdr_batch("camera", enc.embed(imgs))

            def raw() -> None:
                with torch.inference_mode():
                    bb_cl.features(x)

            t = _interleaved({"encoder": encoder, "contiguous": contiguous, "raw": raw}, args.repeats)
            ms = 1000.0 / batch
            print(f"{name:14s} {batch:5d} {t['encoder'] * ms:9.2f} ms {t['contiguous'] * ms:9.2f} ms "
                  f"{t['raw'] * ms:9.2f} ms {t['encoder'] / t['contiguous']:10.2f} "
                  f"{t['encoder'] / t['raw']:8.2f}   (per frame)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
