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
online, each frame with a dead-reckoned position (place p on a loop of 2 m per place, so the
dead-reckoning gate checks every claim); printed: ms per frame over the last 1000 frames (when
the frame memory holds ~N frames)
for the default configuration (fused-SDR descriptor, SP + TM deciding, sequence memory,
dead-reckoning gate), each named chain of ``services/htm/chains.py`` (``sdr_seqmem``: the
fused-SDR chain without SP/TM; ``no_tm``, ``no_dr_gate``, ``no_seqmem``: the
default without one part; ``sp_tm``: SP columns as the descriptor) and ``sdr_seqmem`` without
the sequence memory, all in the same run.  The budget: the default <= 1 ms per frame
at 6000 stored frames.

Third part (``--seqmem-sizes``, default 1000,5000,20000; empty skips it): one
:meth:`SequenceMatcher.score` (the default configuration: K 40, velocity 1, exclude 50, 900
active bits) with that many frames stored, the running diagonal sums (``incremental``, the
default) beside the K-term sums recomputed every frame (the plain computation),
rounds interleaved, median ms per frame; and whether both gave the same ending frames.
``--seqmem-only`` runs only this part.  ``--mission RUN.mcap`` (with ``--seqmem-only``) also
replays a run's ``neocortex/sdr`` through the htm node (default configuration, no transport)
with each computation: process CPU seconds and whether the ``local_view_cells`` are the same.

Fourth part (``--revisits RUN.mcap``, only it runs): a run's ``neocortex/sdr`` and ``Odometry``
replayed ``--loops`` times through the htm node (default configuration, stamps shifted per loop:
a vehicle surveying the same cave again and again), once with ``htm.seqmem.store``
``every_frame`` (the baseline) and once with ``new_places``: process CPU ms per frame per loop,
the ratio of the last loop's to the first's, the frames each memory holds, and on how many
frames the two give the same LVC id.

    NUMBA_CACHE_DIR=/tmp/numba_cache .venv/bin/python benchmarks/bench_htm.py
    .venv/bin/python benchmarks/bench_htm.py --revisits runs/demo/run_on.mcap --loops 8
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout, not another install

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


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--places", type=int, default=100)
    ap.add_argument("--hold", type=int, default=3, help="frames per place")
    ap.add_argument("--bits", type=int, default=512, help="active bits of the fused SDR")
    ap.add_argument("--noise", type=float, default=0.05, help="fraction of bits replaced per frame")
    ap.add_argument("--boost", type=float, default=None, help="htm.sp.boost_strength (default: config)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pipeline-frames", type=int, default=6000,
                    help="frames for the default-chain timing (6000 = a 20-min mission at 5 Hz; 0: skip)")
    ap.add_argument("--pipeline-bits", type=int, default=900, help="active bits of the fused SDR in that part")
    ap.add_argument("--pipeline-places", type=int, default=1000, help="places of the stream in that part")
    ap.add_argument("--seqmem-sizes", default="1000,5000,20000", help="stored frames of the sequence-memory timing")
    ap.add_argument("--seqmem-only", action="store_true", help="only the sequence-memory timing")
    ap.add_argument("--mission", default="", help="a run recording: its neocortex/sdr through the htm node")
    ap.add_argument("--revisits", default="", metavar="RUN.mcap",
                    help="a run recording replayed --loops times through the htm node, every_frame vs new_places")
    ap.add_argument("--loops", type=int, default=8, help="replays of --revisits")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.revisits:
        revisit_cost(args.revisits, args.loops)
        return 0
    sizes = [int(x) for x in args.seqmem_sizes.split(",") if x]
    if args.seqmem_only:
        seqmem_cost(sizes, args.seed)
        if args.mission:
            seqmem_mission(args.mission)
        return 0

    stream = make_stream(args.steps, args.places, args.hold, args.bits, args.noise, args.seed)
    # the dissertation's SP + TM chain (services/htm/presets/dissertation.yaml: Table 4.1's SP and TM);
    # sp.learn_steps 0: the SP learns on every step (the learning step is what is timed)
    from system.config import load_config
    preset = Path(__file__).resolve().parents[1] / "services/htm/presets/dissertation.yaml"
    update: dict = {"sp.learn_steps": 0} if args.boost is None else {"sp.learn_steps": 0, "sp.boost_strength": args.boost}
    cfg = load_config(preset).htm.updated(update)
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
    print(f"parameters: SP 2048 cols / {cfg.sp.num_active_columns} active, potentialRadius {cfg.sp.potential_radius}; "
          f"boostStrength {cfg.sp.boost_strength}; TM {cfg.tm.cells_per_column} cells/col, activationThreshold {cfg.tm.activation_threshold}, learning on")
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
    if sizes:
        seqmem_cost(sizes, args.seed)
    return 0


def seqmem_mission(path: str) -> None:
    """A run's fused SDRs through the htm node with the running sums and with the K-term sums."""
    from common.mcap_io import read_messages
    from common.node import run_offline
    from services.htm.sequence import SequenceMatcher
    from system.config import PoseidonConfig
    from system.services import build_node

    msgs = [(m.key, m.message()) for m in read_messages(path, keys=["neocortex/sdr"])]
    cfg = PoseidonConfig.model_validate({"htm": {"state_path": ""}})
    cpu, ids = {}, {}
    for incremental in (False, True):
        node = build_node("htm", cfg)
        old = node.htm.seqmem  # type: ignore[attr-defined]
        node.htm.seqmem = SequenceMatcher(old.n_bits, old.length, old.velocities, old.exclude,  # type: ignore[attr-defined]
                                          old.column_norm, old.column_prior, incremental=incremental)
        t0 = time.process_time()
        out = run_offline(node, msgs)
        cpu[incremental] = time.process_time() - t0
        ids[incremental] = [m.most_active_cell for k, m in out if k == "local_view_cells"]  # type: ignore[attr-defined]
    same = sum(a == b for a, b in zip(ids[False], ids[True]))
    print(f"\nhtm node over {path} ({len(msgs)} frames): K-term sums {cpu[False]:.1f} s CPU, running sums "
          f"{cpu[True]:.1f} s ({cpu[True] / cpu[False]:.2f}x); LVC ids equal on {same}/{len(ids[False])} frames")


def revisit_cost(path: str, loops: int) -> None:
    """The fourth part of the module doc: per-loop CPU of the htm node, every_frame vs new_places."""
    from common.mcap_io import read_messages
    from common.messages import LocalViewCells, Message
    from system.config import PoseidonConfig
    from system.services import build_node

    recs = [(r.key, r.stamp, r.message()) for r in read_messages(path, keys=["neocortex/sdr", "Odometry"])]
    if not recs:
        raise SystemExit(f"bench_htm: {path} has no neocortex/sdr")
    frames = sum(k == "neocortex/sdr" for k, _, _ in recs)
    period = recs[-1][1] - recs[0][1] + 1_000_000_000
    ids: dict[str, list[int]] = {}
    for store in ("every_frame", "new_places"):
        node = build_node("htm", PoseidonConfig.model_validate({"htm": {"state_path": "", "seqmem": {"store": store}}}))
        node.warm_up()
        out: list[int] = ids.setdefault(store, [])

        def publish(key: str, msg: Message, out: list[int] = out) -> None:
            if isinstance(msg, LocalViewCells):
                out.append(msg.most_active_cell)
        node.publish = publish  # type: ignore[method-assign]
        per_loop = []
        for loop in range(loops):
            c = time.process_time()
            for k, st, m in recs:
                h = m.header.model_copy(update={"stamp": st + loop * period, "seq": m.header.seq + loop * 1_000_000})
                node.process(k, m.model_copy(update={"header": h}))
            per_loop.append(1e3 * (time.process_time() - c) / frames)
        core = node.htm  # type: ignore[attr-defined]
        print(f"{store:12s} ms per frame per loop: {' '.join(f'{v:.2f}' for v in per_loop)}; last / first "
              f"{per_loop[-1] / per_loop[0]:.2f}; memory {len(core.seqmem)} frames of {frames * loops}, "
              f"{len(core.lvc)} LVCs")
    a, b = np.array(ids["every_frame"]), np.array(ids["new_places"])
    print(f"{path}: {frames} frames x {loops} loops; same LVC id on {np.mean(a == b):.4f} of the frames "
          f"(loops after the first: {np.mean(a[frames:] == b[frames:]):.4f})")


def seqmem_cost(sizes: list[int], seed: int, rounds: int = 7, queries: int = 20) -> None:
    """Sequence-memory score per frame at N stored frames: running diagonal sums vs K-term sums."""
    from services.htm.sequence import SequenceMatcher

    cfg = HtmConfig()
    print(f"\nsequence memory, one score per frame (K {cfg.seqmem.length}, velocities {cfg.seqmem.velocities}, "
          f"exclude {cfg.seqmem.exclude}, 900 active bits), median of {rounds} interleaved rounds of {queries} frames")
    print(f"{'stored frames':>13s} {'K-term sums':>12s} {'running sums':>13s} {'ratio':>6s} {'same ends':>10s}")
    for n in sizes:
        frames = make_stream(n + cfg.seqmem.length + queries, max(n // 3, 1), 3, 900, 0.05, seed + 2)

        def make(incremental: bool) -> SequenceMatcher:
            return SequenceMatcher(2048, cfg.seqmem.length, cfg.seqmem.velocities, cfg.seqmem.exclude,
                                   cfg.seqmem.column_norm, incremental=incremental)

        full = make(False)
        for i, f in enumerate(frames[:n]):
            full.add(f.astype(np.int64), i)
        for f in frames[n:n + cfg.seqmem.length]:  # fill the history with rows of n candidates
            full.score(f.astype(np.int64))
        start = full.state()
        queries_ = [f.astype(np.int64) for f in frames[n + cfg.seqmem.length:]]
        times: dict[bool, list[float]] = {False: [], True: []}
        ends: dict[bool, list[int]] = {}
        for _ in range(rounds):
            for inc in (False, True):
                m = make(inc)
                m.set_state(start)  # the running sums are rebuilt from the history
                t0 = time.perf_counter()
                ends[inc] = [m.score(q).frame for q in queries_]
                times[inc].append((time.perf_counter() - t0) / len(queries_))
        a, b = (1e3 * float(np.median(times[k])) for k in (False, True))
        print(f"{n:13d} {a:9.3f} ms {b:10.3f} ms {b / a:5.2f}x {str(ends[False] == ends[True]):>10s}")


def pipeline_cost(args: argparse.Namespace) -> None:
    """Default chain per frame, sequence memory on vs off, same stream, same run."""
    frames = make_stream(args.pipeline_frames, args.pipeline_places, args.hold, args.pipeline_bits, args.noise,
                         args.seed + 1)
    tail = min(1000, len(frames))
    # dead-reckoned positions: place p sits on a loop of 2 m per place, so the second lap's
    # revisits are plausible and the dead-reckoning gate's checks run as on a mission
    place = (np.arange(len(frames)) // args.hold) % args.pipeline_places
    angle = 2 * np.pi * place / args.pipeline_places
    radius = 2.0 * args.pipeline_places / (2 * np.pi)
    positions = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(angle.shape, -5.0)], axis=1)
    res = {}
    from services.htm.chains import CHAINS, chain_config
    runs = [("default configuration", HtmConfig())]
    runs += [(f"chain {c}", chain_config(HtmConfig(), c)) for c in CHAINS]
    runs += [("chain sdr_seqmem, sequence memory off", chain_config(HtmConfig(), "sdr_seqmem").updated(
        {"seqmem.length": 0}))]
    for name, cfg in runs:
        warm = NeocortexHtm(cfg)
        for f in frames[:5]:
            warm.step(f)
        h = NeocortexHtm(cfg)
        t = np.empty(len(frames))
        for i, f in enumerate(tqdm(frames, desc=name, file=sys.stderr, mininterval=1.0, leave=False)):
            t0 = time.perf_counter()
            h.step(f, position=positions[i])
            t[i] = time.perf_counter() - t0
        res[name] = 1e3 * float(np.mean(t[-tail:]))
        extra = "" if h.tm is None else f", TM {h.tm.num_segments} segments / {h.tm.num_synapses} synapses"
        print(f"{name:40s} mean {res[name]:.3f} ms per frame over the last {tail} frames "
              f"({len(frames)} frames stored, {len(h.lvc)} LVCs{extra})")


if __name__ == "__main__":
    raise SystemExit(main())
