"""Synthetic places for the sequence-memory and dead-reckoning-gate tests: random SDR bit sets
of a 2048-bit space, and the same place seen with another appearance."""
from __future__ import annotations

import numpy as np

L = 2048


def place(rng: np.random.Generator, bits: int = 300) -> np.ndarray:
    """A random place: ``bits`` sorted bit indices of L."""
    return np.sort(rng.choice(L, bits, replace=False)).astype(np.int64)


def other_appearance(place_bits: np.ndarray, keep: float, rng: np.random.Generator) -> np.ndarray:
    """The same place seen differently: only ``keep`` of its bits, the rest random elsewhere."""
    kept = rng.choice(place_bits, int(round(place_bits.size * keep)), replace=False)
    others = rng.choice(np.setdiff1d(np.arange(L), place_bits), place_bits.size - kept.size, replace=False)
    return np.sort(np.concatenate([kept, others])).astype(np.int64)
