"""``poseidon vpr`` building blocks: the precision-recall metrics, the similarity matrices and
the image-set inputs (folders, ground truth).  :mod:`eval.vpr` states the definitions."""
from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.results import MatcherMetrics, SdrOverlap

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class VprInputError(ValueError):
    """Bad folders, ground truth or options; the message names the path."""


# --------------------------------------------------------------------------- metrics


def best_matches(similarity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per query (row): index of the best reference (first on ties) and its score.

    Rows that are all ``-inf`` (no prediction) get index -1 and score ``-inf``.
    """
    s = np.asarray(similarity, dtype=np.float64)
    idx = np.argmax(s, axis=1)
    score = s[np.arange(s.shape[0]), idx]
    idx = np.where(np.isneginf(score), -1, idx)
    return idx, score


def pr_curve(scores: np.ndarray, correct: np.ndarray, n_positive: int) -> tuple[np.ndarray, np.ndarray]:
    """Precision and recall at every distinct score threshold, highest threshold first.

    ``scores`` per query (``-inf``: no prediction), ``correct`` whether its prediction is in
    the ground truth, ``n_positive`` the number of queries that have a ground-truth match.
    """
    scores = np.asarray(scores, dtype=np.float64)
    correct = np.asarray(correct, dtype=bool)
    keep = ~np.isneginf(scores)
    scores, correct = scores[keep], correct[keep]
    if scores.size == 0 or n_positive <= 0:
        return np.zeros(0), np.zeros(0)
    order = np.argsort(-scores, kind="stable")
    s, c = scores[order], correct[order]
    tp = np.cumsum(c)
    n = np.arange(1, s.size + 1)
    last_of_group = np.r_[s[1:] != s[:-1], True]  # ties are accepted together
    precision = tp[last_of_group] / n[last_of_group]
    recall = tp[last_of_group] / n_positive
    return precision, recall


def vpr_metrics(similarity: np.ndarray, gt: Sequence[Sequence[int]]) -> MatcherMetrics:
    """AUC of the precision-recall curve, recall at precision 1 and best F1 (see module doc)."""
    sim = np.asarray(similarity)
    if sim.ndim != 2 or sim.shape[0] != len(gt):
        raise VprInputError(f"similarity shape {sim.shape} does not match {len(gt)} ground-truth rows")
    idx, score = best_matches(sim)
    correct = np.array([i >= 0 and int(i) in set(g) for i, g in zip(idx, gt)], dtype=bool)
    n_pos = int(sum(1 for g in gt if len(g) > 0))
    precision, recall = pr_curve(score, correct, n_pos)
    if precision.size == 0:
        return {"auc": 0.0, "recall_at_p100": 0.0, "best_f1": 0.0, "n_predicted": 0}
    auc = float(np.sum(np.diff(np.r_[0.0, recall]) * precision))
    perfect = recall[precision >= 1.0]
    r_p100 = float(perfect.max()) if perfect.size else 0.0
    denom = precision + recall
    f1 = np.where(denom > 0, 2 * precision * recall / np.where(denom > 0, denom, 1), 0.0)
    return {"auc": auc, "recall_at_p100": r_p100, "best_f1": float(f1.max()),
            "n_predicted": int((~np.isneginf(score)).sum())}


def cosine_similarity(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Cosine between rows of q (n_q x d) and r (n_r x d)."""
    qn = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    rn = r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-12)
    cos: np.ndarray = qn @ rn.T
    return cos


def _dense(sets: Sequence[np.ndarray], used: np.ndarray) -> np.ndarray:
    m = np.zeros((len(sets), used.size), dtype=np.float32)
    for i, a in enumerate(sets):
        m[i, np.searchsorted(used, np.asarray(a, dtype=np.int64))] = 1.0
    return m


def overlap_similarity(q: Sequence[np.ndarray], r: Sequence[np.ndarray]) -> np.ndarray:
    """R(A_q, A_r) = |A_q intersect A_r| / |A_q| (Eq. 4.7) for every pair; 0 for an empty A_q.

    Only the bits used by some set get a column, so a descriptor space of 2048 x 40 cells
    costs no more than the bits actually active.
    """
    parts = [np.asarray(a, dtype=np.int64) for a in list(q) + list(r)]
    used = np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
    inter = _dense(q, used) @ _dense(r, used).T
    size = np.array([max(len(np.unique(a)), 1) for a in q], dtype=np.float32)[:, None]
    overlap: np.ndarray = inter / size
    return overlap


# --------------------------------------------------------------------------- inputs


def load_sequence(folder: str | Path, limit: int = 0) -> tuple[list[str], list[np.ndarray]]:
    """File names (sorted) and RGB uint8 images of an image folder; first ``limit`` if > 0."""
    from PIL import Image as PILImage
    from PIL import UnidentifiedImageError

    d = Path(folder)
    if not d.is_dir():
        raise VprInputError(f"image folder not found: {d}")
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise VprInputError(f"no .png/.jpg images in {d}")
    if limit > 0:
        files = files[:limit]
    images = []
    for p in tqdm(files, desc=f"read {d.name}", file=sys.stderr, leave=False):
        try:
            with PILImage.open(p) as im:
                images.append(np.asarray(im.convert("RGB")))
        except (OSError, UnidentifiedImageError) as exc:
            raise VprInputError(f"cannot read image {p}: {exc}") from exc
    return [p.name for p in files], images


def ground_truth_by_name(query_names: Sequence[str], ref_names: Sequence[str], tolerance: int = 0) -> list[list[int]]:
    """Query i matches the reference with the same file name and its ``tolerance`` neighbours."""
    pos = {n: i for i, n in enumerate(ref_names)}
    gt = []
    for n in query_names:
        j = pos.get(n)
        gt.append([] if j is None else list(range(max(0, j - tolerance), min(len(ref_names), j + tolerance + 1))))
    if not any(gt):
        raise VprInputError("no query file name appears among the reference file names; pass --gt FILE")
    return gt


def ground_truth_from_file(path: str | Path, n_query: int, n_ref: int) -> list[list[int]]:
    """VPR-Bench ground truth: rows [query index, list of reference indices] (object array)."""
    p = Path(path)
    if not p.is_file():
        raise VprInputError(f"ground-truth file not found: {p}")
    try:
        arr = np.load(p, allow_pickle=True)
    except (OSError, ValueError) as exc:
        raise VprInputError(f"ground-truth file {p} is not a readable .npy: {exc}") from exc
    gt: list[list[int]] = [[] for _ in range(n_query)]
    for row_no, row in enumerate(arr):
        try:
            q, refs = int(row[0]), [int(r) for r in np.atleast_1d(row[1])]
        except (TypeError, ValueError, IndexError) as exc:
            raise VprInputError(f"ground-truth file {p} row {row_no}: expected [query index, [ref indices]], "
                                f"got {row!r}") from exc
        if q < n_query:  # rows beyond --limit are dropped
            gt[q] = [r for r in refs if r < n_ref]
    return gt



def overlap_stats(sim: np.ndarray, gt: Sequence[Sequence[int]], eligible: np.ndarray | None = None) -> SdrOverlap:
    """Mean SDR overlap |A_q & A_r| / |A_q| of same-place (ground truth) and different-place pairs.

    Independent LSBH SDRs overlap by s = 0.25 on average; ``eligible`` restricts the pairs.
    """
    same = np.zeros(sim.shape, bool)
    for i, g in enumerate(gt):
        same[i, list(g)] = True
    elig = np.ones(sim.shape, bool) if eligible is None else eligible
    a, b = sim[same & elig], sim[~same & elig]
    return {"same_place": round(float(a.mean()), 4) if a.size else None,
            "different_place": round(float(b.mean()), 4) if b.size else None}


# --------------------------------------------------------------------------- MCAP mission
