"""Pose-cell attractor update (Eqs. 4.16-4.17) at (15, 15, 15, 8), ms per update; goal <= 0.5 ms.

Ours: :class:`services.posecells.network.PoseCellNetwork` (numba kernels that skip the zero
cells around the packet).  Baseline, measured in the same run: a straightforward numpy
implementation of the same update (separable wrapped Gaussian excitation with ``np.roll``
per kernel tap, ``max(0, E - phi)``, normalisation), checked to give the same activity.
Also timed: one full frame step (path integration + injection of two LVCs + update +
Hebbian learning, Eqs. 4.15-4.19) against the same numpy update plus the same extra work.

    NUMBA_CACHE_DIR=/tmp/numba_cache .venv/bin/python benchmarks/bench_posecells.py [--updates N]

Prints CPU ms per update / step (ours, numpy; best of 3 repetitions) and the ratio numpy / ours.
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from services.posecells.config import PoseCellsConfig
from services.posecells.network import PoseCellNetwork, gaussian_kernel


class NumpyPoseCells:
    """Reference update: dense numpy, the obvious way."""

    def __init__(self, cfg: PoseCellsConfig):
        self.dims = tuple(cfg.number_of_neurons)
        sig = (cfg.excitation_sigma_cells,) * 3 + (cfg.excitation_sigma_yaw_cells,)
        self.kernels = [gaussian_kernel(s, n) for s, n in zip(sig, self.dims)]
        self.phi = cfg.global_inhibition

    def update(self, p: np.ndarray) -> np.ndarray:
        for axis, (offsets, weights) in enumerate(self.kernels):
            q = np.zeros_like(p)
            for o, w in zip(offsets, weights):
                q += w * np.roll(p, int(o), axis=axis)
            p = q
        p = np.maximum(p - self.phi, 0.0)
        out: np.ndarray = p / p.sum()
        return out


def timed(fn: Callable[[], object], n: int) -> float:
    """Best of 3 repetitions of ``n`` calls, CPU ms per call of this process (both sides are
    single-threaded; CPU time is less distorted than wall time when other jobs share the cores)."""
    best = float("inf")
    for _ in range(3):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, (time.process_time() - t0) / n * 1e3)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--updates", type=int, default=300, help="updates per timing repetition")
    args = ap.parse_args()

    cfg = PoseCellsConfig()
    net = PoseCellNetwork(cfg)
    net.reset((7, 7, 7, 3))
    for _ in range(50):  # settle to the steady packet (and compile the kernels)
        net.update()
    ref = NumpyPoseCells(cfg)
    p0 = net.P.copy()
    # same result first
    net.update()
    expected = ref.update(p0)
    err = float(np.abs(net.P - expected).max())
    if err > 1e-12:
        raise SystemExit(f"numba and numpy updates differ by {err:.3g}")
    print(f"lattice {list(net.dims)}, active cells {int((net.activity > 0).sum())} of {net.size}, "
          f"max |numba - numpy| = {err:.1e}")

    state = net.activity.copy()

    def ours_update() -> None:
        net.activity[:] = state
        net.update()

    def numpy_update() -> None:
        ref.update(p0)

    t_ours = timed(ours_update, args.updates)
    t_np = timed(numpy_update, max(args.updates // 10, 5))
    print(f"update   ours {t_ours:8.3f} ms   numpy {t_np:8.3f} ms   ratio numpy / ours {t_np / t_ours:6.1f}x"
          f"   (goal <= 0.5 ms: {'met' if t_ours <= 0.5 else 'NOT met'})")

    for _ in range(5):
        net.step(active_lvcs=[1, 2])
    for _ in range(cfg.lvc_maturity_steps + 1):  # LVCs 1 and 2 absent: their associations mature
        net.step()
    net.activity[:] = state

    def ours_step() -> None:
        net.activity[:] = state
        net.step(forward=0.04, left=0.01, up=-0.003, dyaw=0.01, active_lvcs=[1, 2])

    def numpy_step() -> None:
        p = np.roll(p0, 1, axis=0)
        for lvc in (1, 2):
            b = net.beta[lvc]
            p.ravel()[b.cells] += cfg.lvc_injection_gain * b.values
        p = ref.update(p)
        np.flatnonzero(p >= cfg.beta_min_fraction * p.max())

    t_ours = timed(ours_step, args.updates)
    t_np = timed(numpy_step, max(args.updates // 10, 5))
    print(f"step     ours {t_ours:8.3f} ms   numpy {t_np:8.3f} ms   ratio numpy / ours {t_np / t_ours:6.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
