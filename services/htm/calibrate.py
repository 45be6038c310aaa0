"""Self-calibrated gates: a threshold read from the mission's own score distribution (ours).

A constant threshold on a similarity (the Eq. 4.9 gates, the sequence memory's F1 check) is
tuned on one data set; when another mission's whole score level is higher or lower (other
floor texture, other sonar returns, another season) the same constant admits too many false
matches or too few true ones.  A *self-calibrated* gate compares a frame's score with the
distribution of scores the same mission gives to pairs that are known not to be the same
place (the *null*), and accepts when the score exceeds a quantile of that null.  A constant
added to every score moves the null quantile by the same constant, so the decisions do not
change (``tests/htm/test_calibrate.py``).

:class:`RunningQuantile` keeps the null samples sorted (``bisect.insort``: exact, deterministic,
O(n) per insert, 8 bytes per sample) and answers ``quantile(q)`` (the lower empirical quantile:
the sample of rank floor(q (n - 1)), no interpolation), or None before ``warmup`` samples.
"""
from __future__ import annotations

import bisect

import numpy as np

__all__ = ["RunningQuantile"]


class RunningQuantile:
    """Exact running quantile of a stream of floats (see the module doc)."""

    def __init__(self, warmup: int = 50):
        self.warmup = int(warmup)
        self.values: list[float] = []

    def __len__(self) -> int:
        return len(self.values)

    def add(self, x: float) -> None:
        bisect.insort(self.values, float(x))

    def quantile(self, q: float) -> float | None:
        """The lower empirical q-quantile of the samples, or None with fewer than ``warmup`` samples."""
        n = len(self.values)
        if n == 0 or n < self.warmup:
            return None
        return self.values[int(np.floor(min(max(q, 0.0), 1.0) * (n - 1)))]

    def reset(self) -> None:
        self.values = []

    def state(self) -> dict[str, np.ndarray]:
        return {"values": np.array(self.values, np.float64)}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        self.values = [float(x) for x in st.get("values", np.zeros(0))]
