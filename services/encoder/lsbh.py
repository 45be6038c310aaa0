"""Locality-sensitive binary hashing (LSBH), Eq. 4.2 of the dissertation.

v = P_m^T y with a fixed projection P_m (d_m x L/2): Gaussian entries, columns scaled to
unit norm, generated from ``lsbh.seed`` (42) and a per-modality derived seed, persisted to
``lsbh.matrix_path`` (``{backbone}`` and ``{modality}`` substituted) and reloaded from there.

With p = L/2 and k = floor(s p): bit i (0 <= i < p) is 1 iff i is among the k largest
components of v; bit p + i is 1 iff i is among the k smallest.  Exactly 2k bits are set
whatever the input: ties at the k-th value are broken deterministically towards the lower
index (the selection is ``np.partition`` for the k-th value, then strict comparison plus
the first tied indices) -- never ``v >= threshold``, which sets extra bits on ties.
"""
from __future__ import annotations

import logging
import os
import zlib
from pathlib import Path

import numpy as np

__all__ = ["LsbhError", "lsbh_k", "lsbh_bits", "lsbh_bits_batch", "make_projection", "modality_seed",
           "projection_path", "load_or_create_projection", "LsbhEncoder"]

log = logging.getLogger(__name__)


class LsbhError(ValueError):
    """A projection file that does not fit, or an input LSBH cannot hash."""


def lsbh_k(length: int, s: float) -> int:
    """k = floor(s L/2): bits per half (Eq. 4.2)."""
    if length < 2 or length % 2:
        raise LsbhError(f"SDR length L must be even and >= 2, got {length}")
    if not 0.0 < s < 1.0:
        raise LsbhError(f"encoder.lsbh.s must be in (0, 1), got {s}")
    k = int(np.floor(s * (length // 2)))
    if k < 1:
        raise LsbhError(f"k = floor({s} * {length // 2}) = 0: no bit would be set")
    return k


def _select(v: np.ndarray, k: int, largest: bool) -> np.ndarray:
    """Indices of the k largest (or smallest) of v; ties at the cut-off: lowest index first."""
    p = v.size
    if largest:
        kth = np.partition(v, p - k)[p - k]
        strict = np.flatnonzero(v > kth)
    else:
        kth = np.partition(v, k - 1)[k - 1]
        strict = np.flatnonzero(v < kth)
    tied = np.flatnonzero(v == kth)
    return np.concatenate([strict, tied[: k - strict.size]])


def lsbh_bits(v: np.ndarray, k: int) -> np.ndarray:
    """Active bits (sorted uint32, 0-based, exactly 2k) of the SDR of responses v (Eq. 4.2)."""
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    p = v.size
    if not 1 <= k <= p:
        raise LsbhError(f"k={k} must be in [1, {p}] for {p} responses")
    if not np.all(np.isfinite(v)):
        raise LsbhError(f"LSBH responses contain {int((~np.isfinite(v)).sum())} non-finite values")
    top = _select(v, k, largest=True)
    bottom = _select(v, k, largest=False)
    return np.sort(np.concatenate([top, bottom + p])).astype(np.uint32)


def lsbh_bits_batch(v: np.ndarray, k: int) -> list[np.ndarray]:
    """:func:`lsbh_bits` for each row of an (N, p) response matrix."""
    v = np.atleast_2d(np.asarray(v))
    return [lsbh_bits(row, k) for row in v]


_MODALITY_IDS = {"camera": 0, "sonar": 1}


def modality_seed(seed: int, modality: str) -> np.random.SeedSequence:
    """Seed sequence of modality ``modality``: (``seed``, modality id), camera 0, sonar 1, other: crc32."""
    mid = _MODALITY_IDS.get(modality, zlib.crc32(modality.encode()) & 0x7FFFFFFF)
    return np.random.SeedSequence(entropy=int(seed), spawn_key=(mid,))


def make_projection(d: int, half: int, seed: int, modality: str) -> np.ndarray:
    """P_m (d x L/2): standard Gaussian entries, each column scaled to unit L2 norm, float32."""
    if d < 1 or half < 1:
        raise LsbhError(f"projection shape must be positive, got {d} x {half}")
    rng = np.random.default_rng(modality_seed(seed, modality))
    p = rng.standard_normal((d, half))
    p /= np.linalg.norm(p, axis=0, keepdims=True)
    return p.astype(np.float32)


def projection_path(template: str, backbone: str, modality: str) -> Path:
    """``lsbh.matrix_path`` with ``{backbone}`` and ``{modality}`` substituted."""
    try:
        return Path(template.format(backbone=backbone, modality=modality))
    except (KeyError, IndexError) as exc:
        raise LsbhError(f"encoder.lsbh.matrix_path {template!r}: only {{backbone}} and {{modality}} "
                        f"may be substituted ({exc})") from None


def load_or_create_projection(path: Path | None, d: int, half: int, seed: int, modality: str) -> np.ndarray:
    """Load P_m from ``path`` if it exists (shape must be (d, half)), else create and save it.

    ``path`` None: generate in memory only.
    """
    if path is not None and path.exists():
        try:
            p = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise LsbhError(f"LSBH projection {path} is not a readable .npy array: {exc}") from exc
        if p.shape != (d, half):
            raise LsbhError(f"LSBH projection {path} has shape {p.shape}, the encoder needs ({d}, {half}) "
                            f"(d_m x L/2 for modality {modality!r}); delete it or point "
                            f"encoder.lsbh.matrix_path elsewhere")
        if not np.all(np.isfinite(p)):
            raise LsbhError(f"LSBH projection {path} contains non-finite values")
        log.debug("encoder: LSBH projection for %s loaded from %s", modality, path)
        return np.ascontiguousarray(p, dtype=np.float32)
    p = make_projection(d, half, seed, modality)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.npy")  # processes making it at once: one file each
        np.save(tmp, p, allow_pickle=False)
        tmp.replace(path)
        log.debug("encoder: LSBH projection for %s (%d x %d, seed %d) saved to %s", modality, d, half, seed, path)
    return p


class LsbhEncoder:
    """One modality's LSBH: embedding y (d_m) -> sorted active bits of an L-bit SDR (Eq. 4.2)."""

    def __init__(self, projection: np.ndarray, length: int, s: float):
        self.length = int(length)
        self.k = lsbh_k(self.length, s)
        if projection.ndim != 2 or projection.shape[1] != self.length // 2:
            raise LsbhError(f"projection shape {projection.shape} does not have L/2 = {self.length // 2} columns")
        self.projection = projection

    @property
    def dim(self) -> int:
        return int(self.projection.shape[0])

    def responses(self, y: np.ndarray) -> np.ndarray:
        """v = P^T y for one embedding (d,) or a batch (N, d)."""
        y = np.asarray(y, dtype=np.float32)
        if y.shape[-1] != self.dim:
            raise LsbhError(f"embedding has {y.shape[-1]} dimensions, the LSBH projection expects {self.dim}")
        out: np.ndarray = y @ self.projection
        return out

    def encode(self, y: np.ndarray) -> np.ndarray:
        """Sorted uint32 active bits (exactly 2k) of one embedding."""
        return lsbh_bits(self.responses(np.asarray(y).reshape(-1)), self.k)

    def encode_batch(self, y: np.ndarray) -> list[np.ndarray]:
        return lsbh_bits_batch(self.responses(np.atleast_2d(y)), self.k)
