"""LVC matching time (Eqs. 4.6-4.9) at 1k, 10k and 100k stored prototypes, ms per query.

Ours: the inverted index of services/htm/lvc.py (``LvcMatcher.best`` + the Eq. 4.9 gate).
Baseline, measured in the same run: brute force in numpy over a padded prototype matrix
(``I = mask[protos].sum(1)``, then arg max R with the IoU / lowest-id tie-breaks). Both
answers are compared on every query.

Descriptor spaces: ``tm`` 15 bits of 81 920 TM cells (htm.descriptor.tm_topk, default), ``sp`` 20 of
2048 columns, ``sdr`` 512 of 2048 SDR bits (the raw LSBH code, baseline matcher).

Then the sequence memory (``services/htm/sequence.py``, default K = ``htm.seqmem.length``)
at the same numbers of stored *frames* (``--seq-bits`` active of 2048, default 900 = fused
camera OR sonar): ms per ``score`` (F1 against every stored frame, normalisation, diagonals),
next to the inverted-index LVC query of the ``sdr`` space at the same size, same run.

    NUMBA_CACHE_DIR=/tmp/numba_cache .venv/bin/python benchmarks/bench_lvc.py
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from tqdm import tqdm

from services.htm.config import HtmConfig
from services.htm.lvc import LvcMatcher
from services.htm.sequence import SequenceMatcher

SPACES = {"tm": (81920, 15), "sp": (2048, 20), "sdr": (2048, 512)}


def brute_force(protos: np.ndarray, lens: np.ndarray, q: np.ndarray, mask: np.ndarray) -> tuple[int, int]:
    mask[q] = True
    inter = mask[protos].sum(1)
    mask[q] = False
    best_i = inter.max()
    if best_i == 0:
        return -1, 0
    cand = np.flatnonzero(inter == best_i)
    cand = cand[lens[cand] == lens[cand].min()]      # IoU tie-break, then lowest id
    return int(cand[0]), int(best_i)


def run(space: str, n_protos: int, n_queries: int, seed: int) -> tuple[float, float]:
    n_bits, k = SPACES[space]
    rng = np.random.default_rng(seed)
    m = LvcMatcher(n_bits, 12, 0.30, True, 0.55, True)
    protos = np.empty((n_protos, k), np.int32)
    for i in tqdm(range(n_protos), desc=f"{space}: store {n_protos}", file=sys.stderr, mininterval=1.0, leave=False):
        protos[i] = np.sort(rng.choice(n_bits, k, replace=False))
        m.add(protos[i])
    lens = np.full(n_protos, k, np.int32)
    mask = np.zeros(n_bits + 1, bool)
    queries = []
    for j in range(n_queries):
        if j % 2 == 0:   # a revisit: a stored prototype with 20 % of its bits replaced
            base = protos[rng.integers(n_protos)].copy()
            swap = rng.random(k) < 0.2
            base[swap] = rng.integers(0, n_bits, int(swap.sum()))
            queries.append(np.unique(base).astype(np.int32))
        else:            # a new place
            queries.append(np.sort(rng.choice(n_bits, k, replace=False)).astype(np.int32))
    for q in queries[:3]:
        m.best(q)
    t0 = time.perf_counter()
    ours = []
    for q in queries:
        best, i = m.best(q)
        if best >= 0:
            m.accepts(i, q.size, int(m._proto_len[best]))
        ours.append((best, i))
    t1 = time.perf_counter()
    base = [brute_force(protos, lens, q, mask) for q in queries]
    t2 = time.perf_counter()
    if ours != base:
        bad = sum(a != b for a, b in zip(ours, base))
        raise AssertionError(f"{space} {n_protos}: inverted index and brute force disagree on {bad} queries")
    return 1e3 * (t1 - t0) / n_queries, 1e3 * (t2 - t1) / n_queries


def run_sequence(n_frames: int, n_queries: int, bits: int, seed: int) -> float:
    """ms per SequenceMatcher.score with ``n_frames`` stored frames (default configuration)."""
    cfg = HtmConfig()
    rng = np.random.default_rng(seed)
    m = SequenceMatcher(2048, cfg.seqmem.length, cfg.seqmem.velocities, cfg.seqmem.exclude,
                        cfg.seqmem.column_norm)
    frames = [np.sort(rng.choice(2048, bits, replace=False)) for _ in range(min(n_frames, 2000))]
    for i in tqdm(range(n_frames), desc=f"seq: store {n_frames}", file=sys.stderr, mininterval=1.0, leave=False):
        m.add(frames[i % len(frames)], i)
    m.reset()
    queries = [np.sort(rng.choice(2048, bits, replace=False)) for _ in range(n_queries)]
    for q in queries[:3]:
        m.score(q)
    t0 = time.perf_counter()
    for q in queries:
        m.score(q)
    return 1e3 * (time.perf_counter() - t0) / n_queries


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    ap.add_argument("--spaces", nargs="+", default=["tm", "sp", "sdr"], choices=list(SPACES))
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seq-bits", type=int, default=900, help="active bits per stored frame (sequence memory)")
    args = ap.parse_args(argv)
    print(f"{'space':5} {'prototypes':>10} {'index ms/query':>15} {'brute ms/query':>15} {'speed-up':>9}")
    for space in args.spaces:
        for n in args.sizes:
            ours, brute = run(space, n, args.queries, args.seed)
            print(f"{space:5} {n:>10} {ours:>15.4f} {brute:>15.4f} {brute / ours:>8.1f}x", flush=True)
    print(f"{'frames':>10} {'seq memory ms/frame':>20} {'sdr LVC index ms/query':>23} {'ratio':>6}")
    for n in args.sizes:
        seq = run_sequence(n, args.queries, args.seq_bits, args.seed)
        lvc, _ = run("sdr", n, args.queries, args.seed)
        print(f"{n:>10} {seq:>20.4f} {lvc:>23.4f} {seq / lvc:>6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
