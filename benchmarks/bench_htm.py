"""SP + TM learning step at the dissertation's parameters (Table 5.1 / Table 4.1), in ms;
then the default chain (sdr descriptor -> LVC) per frame with and without the sequence memory.

Stream: a route of ``--places`` places, each an LSBH-like fused SDR (``--bits`` active of
L = 2048; 512 = one modality with s = 0.25, ~1024 = camera OR sonar), visited for
``--hold`` frames with ``--noise`` of its bits replaced per frame, looped for ``--steps``
frames. The reference is htm.core (C++): ~0.41 ms per SP+TM learning step on this machine
class (ARCHITECTURE.md); the ratio printed is ours / 0.41 ms.

Second part (``--pipeline-frames`` N, 0 skips it): whole ``NeocortexHtm.step`` calls over N
frames of the same kind of stream (``--pipeline-bits`` active bits, default 900 = camera OR
sonar; ``--pipeline-places`` places, default 1000 x 3 frames, so a 6000-frame stream is two laps
of mostly new places: the TM's worst case, it grows segments while it bursts) storing LVCs as
online; printed: ms per frame over the last 1000 frames (when the frame memory holds ~N frames)
for the default configuration, each named chain of ``services/htm/chains.py`` (``sdr_seqmem``:
fused SDR + sequence memory, no SP/TM; ``sp_tm``: SP + TM + sequence memory) and
``sdr_seqmem`` without the sequence memory, all in the same run.

    NUMBA_CACHE_DIR=/tmp/numba_cache .venv/bin/python benchmarks/bench_htm.py
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from tqdm import tqdm

from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm

HTM_CORE_MS = 0.41


def make_stream(steps: int, places: int, hold: int, bits: int, noise: float, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    L = 2048
    route = [np.sort(rng.choice(L, bits, replace=False)) for _ in range(places)]
    out = []
    for t in range(steps):
        p = route[(t // hold) % places]
        keep = rng.random(p.size) >= noise
        extra = rng.choice(L, int((~keep).sum()), replace=False)
        out.append(np.unique(np.concatenate([p[keep], extra])).astype(np.uint32))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--places", type=int, default=100)
    ap.add_argument("--hold", type=int, default=3, help="frames per place")
    ap.add_argument("--bits", type=int, default=512, help="active bits of the fused SDR")
    ap.add_argument("--noise", type=float, default=0.05, help="fraction of bits replaced per frame")
    ap.add_argument("--boost", type=float, default=None, help="htm.sp_boostStrength (default: config)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pipeline-frames", type=int, default=6000,
                    help="frames for the default-chain timing (6000 = a 20-min mission at 5 Hz; 0: skip)")
    ap.add_argument("--pipeline-bits", type=int, default=900, help="active bits of the fused SDR in that part")
    ap.add_argument("--pipeline-places", type=int, default=1000, help="places of the stream in that part")
    args = ap.parse_args(argv)

    stream = make_stream(args.steps, args.places, args.hold, args.bits, args.noise, args.seed)
    # sp_learn_steps 0: the SP learns on every step (the learning step is what is timed)
    tm = dict(sv_descriptor_source="tm")  # the SP+TM chain is what this benchmark times
    cfg = HtmConfig(sp_learn_steps=0, **tm) if args.boost is None else HtmConfig(sp_boostStrength=args.boost, **tm,
                                                                           sp_learn_steps=0)
    warm = NeocortexHtm(cfg)          # compiles / loads the numba kernels
    for f in stream[:5]:
        warm.step(f)
    h = NeocortexHtm(cfg)
    sp, tmem = h.sp, h.tm
    if sp is None or tmem is None:
        raise SystemExit("bench_htm: this configuration builds no spatial pooler or temporal memory to time")
    t_sp = np.empty(len(stream))
    t_tm = np.empty(len(stream))
    t_rest = np.empty(len(stream))
    anomalies = np.empty(len(stream))
    for i, f in enumerate(tqdm(stream, desc="htm steps", file=sys.stderr, mininterval=1.0)):
        a = f.astype(np.int64)
        t0 = time.perf_counter()
        cols = sp.compute(a, True)
        t1 = time.perf_counter()
        winners = tmem.compute(cols, True)
        t2 = time.perf_counter()
        src = np.unique(winners.astype(np.int64) // tmem.cpc) if h.tm_columns else winners.astype(np.int64)
        d = h.descriptor.update(src)
        h.lvc.match(d)
        t3 = time.perf_counter()
        t_sp[i], t_tm[i], t_rest[i] = t1 - t0, t2 - t1, t3 - t2
        anomalies[i] = tmem.anomaly

    def ms(x: np.ndarray) -> float:
        return 1e3 * float(np.mean(x))

    def med(x: np.ndarray) -> float:
        return 1e3 * float(np.median(x))

    sptm = t_sp + t_tm
    print(f"stream: {args.steps} frames, {args.places} places x {args.hold} frames, {args.bits} active bits "
          f"of 2048, noise {args.noise:.0%}")
    print(f"parameters: SP 2048 cols / {cfg.sp_numActiveColumns} active, potentialRadius {cfg.sp_potentialRadius}; "
          f"boostStrength {cfg.sp_boostStrength}; TM {cfg.tm_cellsPerColumn} cells/col, activationThreshold {cfg.tm_activationThreshold}, learning on")
    print(f"SP step          mean {ms(t_sp):.3f} ms  median {med(t_sp):.3f} ms")
    print(f"TM step          mean {ms(t_tm):.3f} ms  median {med(t_tm):.3f} ms")
    print(f"SP+TM step       mean {ms(sptm):.3f} ms  median {med(sptm):.3f} ms  p95 {1e3 * np.percentile(sptm, 95):.3f} ms")
    print(f"descriptor+LVC   mean {ms(t_rest):.3f} ms")
    print(f"ratio SP+TM / htm.core ({HTM_CORE_MS} ms): {ms(sptm) / HTM_CORE_MS:.2f} (mean), "
          f"{med(sptm) / HTM_CORE_MS:.2f} (median)")
    print(f"final state: {tmem.num_segments} segments, {tmem.num_synapses} synapses, {len(h.lvc)} LVCs, "
          f"mean anomaly last 500 steps {anomalies[-500:].mean():.2f}")
    if args.pipeline_frames > 0:
        pipeline_cost(args)
    return 0


def pipeline_cost(args: argparse.Namespace) -> None:
    """Default chain per frame, sequence memory on vs off, same stream, same run."""
    frames = make_stream(args.pipeline_frames, args.pipeline_places, args.hold, args.pipeline_bits, args.noise,
                         args.seed + 1)
    tail = min(1000, len(frames))
    res = {}
    from services.htm.chains import CHAINS, chain_config
    runs = [("default configuration", HtmConfig())]
    runs += [(f"chain {c}", chain_config(HtmConfig(), c)) for c in CHAINS]
    runs += [("chain sdr_seqmem, sequence memory off", chain_config(HtmConfig(), "sdr_seqmem").model_copy(
        update={"sv_seqmem_length": 0}))]
    for name, cfg in runs:
        warm = NeocortexHtm(cfg)
        for f in frames[:5]:
            warm.step(f)
        h = NeocortexHtm(cfg)
        t = np.empty(len(frames))
        for i, f in enumerate(tqdm(frames, desc=name, file=sys.stderr, mininterval=1.0, leave=False)):
            t0 = time.perf_counter()
            h.step(f)
            t[i] = time.perf_counter() - t0
        res[name] = 1e3 * float(np.mean(t[-tail:]))
        extra = "" if h.tm is None else f", TM {h.tm.num_segments} segments / {h.tm.num_synapses} synapses"
        print(f"{name:40s} mean {res[name]:.3f} ms per frame over the last {tail} frames "
              f"({len(frames)} frames stored, {len(h.lvc)} LVCs{extra})")


if __name__ == "__main__":
    raise SystemExit(main())
