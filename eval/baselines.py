"""Place-recognition baselines printed beside the front-end in every ``poseidon vpr`` output.

* ``seq_cosine`` (:func:`sequence_similarity`) -- SeqSLAM-style sequence matching (Milford &
  Wyeth 2012) on the same embeddings as ``cnn_cosine``: difference matrix D = 1 - cosine,
  normalised per reference (each column to zero mean and unit standard deviation over the
  queries it can be compared with), then for query q and reference r the mean of the
  normalised differences along the straight line of the last ``length`` (10) frames,
  (q - k, r - k) for k = 0 .. length-1; similarity = minus that mean.  Points of the line
  before the start of a sequence or on a masked pair count as 0 (the per-reference mean), so
  a short line near a sequence start cannot outscore a full one by a single frame.  A trailing window, so a query only uses frames seen up to it (as online).
* ``patchnorm_sad`` (:func:`patch_normalise`, :func:`sad_similarity`) -- the image-level
  baseline of SeqSLAM: grey images resized to 32 x 16 pixels (W x H), normalised per 8 x 8
  patch (zero mean, unit standard deviation; a flat patch becomes 0), compared by the sum of
  absolute differences (similarity = minus the mean absolute difference per pixel).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["sequence_similarity", "patch_normalise", "sad_similarity", "SEQ_LENGTH", "PATCH_SIZE", "THUMB_WH"]

SEQ_LENGTH = 10
THUMB_WH = (32, 16)
PATCH_SIZE = 8


def sequence_similarity(similarity: np.ndarray, length: int = SEQ_LENGTH) -> np.ndarray:
    """SeqSLAM straight-line score of every (query, reference) pair (see the module doc).

    ``similarity`` is n_q x n_r; entries that are ``-inf`` (pairs that may not be compared,
    e.g. too close in time on a single mission) are left out of the normalisation and of
    the line sums, and stay ``-inf`` in the result.
    """
    s = np.asarray(similarity, dtype=np.float64)
    if s.ndim != 2:
        raise ValueError(f"similarity must be 2-D, got shape {s.shape}")
    if length < 1:
        raise ValueError(f"sequence length must be >= 1, got {length}")
    ok = np.isfinite(s)
    d = np.where(ok, 1.0 - s, 0.0)
    n = ok.sum(axis=0)
    mean = d.sum(axis=0) / np.maximum(n, 1)
    var = (np.where(ok, (d - mean) ** 2, 0.0)).sum(axis=0) / np.maximum(n, 1)
    dn = np.where(ok, (d - mean) / np.maximum(np.sqrt(var), 1e-9), 0.0)
    acc = np.zeros_like(dn)
    nq, nr = dn.shape
    for k in range(min(length, nq, nr)):
        acc[k:, k:] += dn[: nq - k, : nr - k]
    return np.where(ok, -acc / length, -np.inf)


def patch_normalise(image: np.ndarray, size: tuple[int, int] = THUMB_WH, patch: int = PATCH_SIZE) -> np.ndarray:
    """Grey ``size`` (W, H) thumbnail of an (H, W, 3) / (H, W) image, normalised per patch; float32, flat."""
    from PIL import Image as PILImage

    a = np.asarray(image)
    if a.ndim == 3:
        a = a[:, :, :3].astype(np.float32).mean(axis=2)
    elif a.ndim != 2:
        raise ValueError(f"image must be (H, W) or (H, W, C), got shape {a.shape}")
    a = a.astype(np.float32)
    w, h = size
    if w % patch or h % patch:
        raise ValueError(f"thumbnail {w}x{h} is not a whole number of {patch}x{patch} patches")
    g = np.asarray(PILImage.fromarray(a, mode="F").resize((w, h), PILImage.Resampling.BILINEAR), dtype=np.float32)
    p = g.reshape(h // patch, patch, w // patch, patch).transpose(0, 2, 1, 3).reshape(-1, patch * patch)
    mu = p.mean(axis=1, keepdims=True)
    sd = p.std(axis=1, keepdims=True)
    p = np.where(sd > 1e-6, (p - mu) / np.maximum(sd, 1e-6), 0.0)
    return p.reshape(-1).astype(np.float32)


@njit(cache=True, parallel=False)
def _sad(q: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
    n = q.shape[1]
    for i in prange(q.shape[0]):
        for j in range(r.shape[0]):
            acc = 0.0
            for k in range(n):
                acc += abs(q[i, k] - r[j, k])
            out[i, j] = -acc / n


def sad_similarity(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Minus the mean absolute difference between every row of ``q`` and of ``r`` (n_q x n_r)."""
    q = np.ascontiguousarray(q, dtype=np.float32)
    r = np.ascontiguousarray(r, dtype=np.float32)
    if q.ndim != 2 or r.ndim != 2 or q.shape[1] != r.shape[1]:
        raise ValueError(f"SAD needs two (n, d) arrays with the same d, got {q.shape} and {r.shape}")
    out = np.empty((q.shape[0], r.shape[0]), np.float32)
    _sad(q, r, out)
    return out
