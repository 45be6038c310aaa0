"""Fusion of the modality SDRs present at time t (Eq. 4.3).

``union`` (default): bitwise OR over the modalities present, s_fused = OR_{m in M_t} s^(m).
``and``: bitwise AND over the modalities present (ablation the dissertation leaves as
future work); with one modality present it is that modality's SDR.
``camera`` / ``sonar``: that modality only (single-modality ablation); empty when absent.

A missing modality is simply not in ``sdrs`` (or maps to None): never an error.  SDRs are
sorted uint32 arrays of active bit indices; so is the result.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["FUSION_MODES", "fuse"]

FUSION_MODES = ("union", "and", "camera", "sonar")


def fuse(sdrs: Mapping[str, np.ndarray | None], mode: str = "union") -> np.ndarray:
    """Fused active bits of the SDRs in ``sdrs`` (modality -> active bits) under ``mode``."""
    present = [np.asarray(v, dtype=np.uint32) for _, v in sorted(sdrs.items()) if v is not None]
    if mode == "union":
        if not present:
            return np.zeros(0, dtype=np.uint32)
        bits = np.concatenate(present)  # a new array: sorted in place, then each bit once
        bits.sort()
        return bits[np.concatenate(([True], bits[1:] != bits[:-1]))] if bits.size else bits
    if mode == "and":
        if not present:
            return np.zeros(0, dtype=np.uint32)
        out = np.unique(present[0])
        for v in present[1:]:
            out = np.intersect1d(out, v, assume_unique=False)
        return out.astype(np.uint32)
    if mode in ("camera", "sonar"):
        sdr = sdrs.get(mode)
        return np.zeros(0, dtype=np.uint32) if sdr is None else np.unique(np.asarray(sdr, dtype=np.uint32))
    raise ValueError(f"encoder.fusion_mode: unknown mode {mode!r}; known: {FUSION_MODES}")
