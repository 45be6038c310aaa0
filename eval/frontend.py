"""Front-end figures on the LVC id stream, each defined once.

- :func:`lvc_revisit_metrics` -- LVC-id revisit recall and precision against the revisit
  ground truth (``truth/revisits``): frame i is a *revisit frame* when its truth lists
  earlier frames of the same place; it is *recalled* when its LVC id equals the id of one
  of those frames.  Frame i *claims* a revisit when its id (>= 0) was already given to an
  *eligible* earlier frame j (j < i and at least ``min_gap_m`` travelled between them in
  truth; all earlier frames when no distances are given); a claim is *correct* when the id
  is that of one of its true earlier frames.  recall = recalled / revisit frames,
  precision = correct claims / claims (None when the denominator is 0).
  These are the *per-frame* revisit precision and recall ("does the id of this frame point
  to an earlier visit of this place?"): the front-end figures of ``poseidon vpr --mission``
  (``lvc_precision`` / ``lvc_recall``), the run summary and ``poseidon eval``.
- :func:`lvc_pair_metrics` -- the *frame-pair* precision and recall of "same LVC id": over
  the eligible pairs (j < i, ``eligible_before``), a pair is *called* the same place when
  both frames carry the same id; pair precision = true called pairs / called pairs, pair
  recall = true called pairs / true pairs (``truth/revisits``).  A different measure with a
  different name: one revisit frame whose id is right is one correct claim per frame but
  only as many true pairs as the id has frames among the place's earlier frames, and a
  long-lived id (a place seen for many frames) calls many pairs; the report's
  precision-recall star ("same LVC id") is of this kind.
- :func:`lvc_false_associations` -- frames matched to an existing id (``is_new`` false)
  whose id was created (first ``is_new`` frame of that id) more than ``far_m`` away in
  truth: the dissertation's loop-closure false-positive distance (5 m) applied to ids.
- :func:`vpr_window_ok_ratio` -- Table 5.4's "VPR window ok_ratio": the fraction of LVC
  emissions whose id repeats at least ``min_rep`` times in the last ``window`` emissions
  (itself included), i.e. the VPR Guard gate g_t of Eqs. 4.11-4.12 recomputed on the
  recorded ``local_view_cells`` stream (independent of whether the guard was ON).
"""
from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["lvc_revisit_metrics", "lvc_pair_metrics", "lvc_false_associations", "vpr_window_ok_ratio", "frame_indices"]


def lvc_revisit_metrics(ids: Sequence[int] | np.ndarray, same_place: Sequence[Sequence[int]],
                        travelled_m: Sequence[float] | np.ndarray | None = None,
                        min_gap_m: float = 0.0, eligible_before: np.ndarray | None = None) -> dict[str, Any]:
    """LVC-id recall and precision (module docstring).

    ``ids[i]``: LVC id of frame i (negative: none); ``same_place[i]``: indices of earlier
    frames that show the same place (indices outside ``[0, i)`` are ignored);
    ``travelled_m[i]``: true distance travelled at frame i (non-decreasing);
    ``eligible_before[i]``: alternatively, frames ``[0, eligible_before[i])`` are far enough
    back to be claimed (what ``travelled_m``/``min_gap_m`` compute).

    Returns ``{"revisit_frames", "recalled", "recall", "claimed", "correct_claims",
    "precision"}``.
    """
    ids = np.asarray(ids, dtype=np.int64)
    n = len(ids)
    if len(same_place) != n:
        raise ValueError(f"lvc_revisit_metrics: {n} ids but {len(same_place)} ground-truth rows")
    truth_ids: list[set[int]] = []
    for i in range(n):
        js = [int(j) for j in same_place[i] if 0 <= int(j) < i]
        truth_ids.append({int(ids[j]) for j in js if ids[j] >= 0})
    revisit = [i for i in range(n) if any(0 <= int(j) < i for j in same_place[i])]
    recalled = sum(1 for i in revisit if ids[i] >= 0 and int(ids[i]) in truth_ids[i])
    if eligible_before is not None:
        limit = np.minimum(np.asarray(eligible_before, dtype=np.int64), np.arange(n))
    elif travelled_m is None:
        limit = np.arange(n)  # frames [0, i) are eligible
    else:
        d = np.asarray(travelled_m, dtype=float)
        if len(d) != n:
            raise ValueError(f"lvc_revisit_metrics: {n} ids but {len(d)} travelled distances")
        limit = np.minimum(np.searchsorted(d, d - min_gap_m, side="right"), np.arange(n))
    first: dict[int, int] = {}
    claimed = correct = 0
    for i in range(n):
        lid = int(ids[i])
        if lid < 0:
            continue
        j = first.setdefault(lid, i)
        if j < limit[i]:
            claimed += 1
            correct += int(lid in truth_ids[i])
    return {"revisit_frames": len(revisit), "recalled": recalled,
            "recall": recalled / len(revisit) if revisit else None,
            "claimed": claimed, "correct_claims": correct, "precision": correct / claimed if claimed else None}


def lvc_pair_metrics(ids: Sequence[int] | np.ndarray, same_place: Sequence[Sequence[int]],
                     eligible_before: np.ndarray | None = None) -> dict[str, Any]:
    """Frame-pair precision and recall of "same LVC id" (module docstring).

    Frames ``[0, eligible_before[i])`` (default: all earlier frames) are the pairs of frame i;
    a negative id calls no pair.  Returns ``{"true_pairs", "called_pairs", "correct_pairs",
    "pair_precision", "pair_recall"}`` (None when the denominator is 0).
    """
    ids = np.asarray(ids, dtype=np.int64)
    n = len(ids)
    if len(same_place) != n:
        raise ValueError(f"lvc_pair_metrics: {n} ids but {len(same_place)} ground-truth rows")
    limit = np.arange(n) if eligible_before is None else np.minimum(np.asarray(eligible_before, np.int64), np.arange(n))
    true_pairs = called = correct = 0
    for i in range(n):
        lim = int(limit[i])
        js = np.array([int(j) for j in same_place[i] if 0 <= int(j) < lim], np.int64)
        true_pairs += js.size
        if ids[i] < 0 or lim == 0:
            continue
        same = ids[:lim] == ids[i]
        called += int(same.sum())
        if js.size:
            correct += int(same[js].sum())
    return {"true_pairs": true_pairs, "called_pairs": called, "correct_pairs": correct,
            "pair_precision": correct / called if called else None,
            "pair_recall": correct / true_pairs if true_pairs else None}


def lvc_false_associations(ids: Sequence[int], is_new: Sequence[bool], positions: np.ndarray | None,
                           far_m: float = 5.0) -> dict[str, Any]:
    """Matched frames whose id was created more than ``far_m`` away (module docstring).

    ``positions[i]``: true position of frame i (NaN rows = unknown; such frames are
    skipped).  Returns ``{"matched_frames", "false_associations", "false_association_rate"}``.
    """
    created: dict[int, int] = {}
    for i, (lid, new) in enumerate(zip(ids, is_new)):
        if new:
            created.setdefault(int(lid), i)
    if positions is None:
        return {"matched_frames": 0, "false_associations": 0, "false_association_rate": None}
    pos = np.asarray(positions, dtype=float)
    matched = far = 0
    for i, (lid, new) in enumerate(zip(ids, is_new)):
        j = created.get(int(lid))
        if new or j is None or not (np.all(np.isfinite(pos[i])) and np.all(np.isfinite(pos[j]))):
            continue
        matched += 1
        far += int(np.linalg.norm(pos[i] - pos[j]) > far_m)
    return {"matched_frames": matched, "false_associations": far,
            "false_association_rate": far / matched if matched else None}


def vpr_window_ok_ratio(ids: Sequence[int], window: int, min_rep: int) -> float | None:
    """Fraction of emissions with C_t(l_t) >= r over the last ``window`` ids (Eqs. 4.11-4.12)."""
    if window < 1 or min_rep < 1:
        raise ValueError(f"vpr_window_ok_ratio: window {window} and min_rep {min_rep} must be >= 1")
    if not len(ids):
        return None
    last: deque[int] = deque(maxlen=window)
    counts: dict[int, int] = {}
    ok = 0
    for lid in ids:
        lid = int(lid)
        if len(last) == window:
            old = last[0]
            counts[old] -= 1
        last.append(lid)
        counts[lid] = counts.get(lid, 0) + 1
        ok += int(counts[lid] >= min_rep)
    return ok / len(ids)


def frame_indices(lvc_stamps: Sequence[int], revisit_stamps: dict[int, int]) -> tuple[list[int], str]:
    """Camera-frame index of each LVC message: by stamp through ``truth/revisits``
    (stamp -> frame_index) when every stamp is found, else by order.  Returns the indices
    and ``"stamp"`` or ``"order"``."""
    if lvc_stamps and all(s in revisit_stamps for s in lvc_stamps):
        return [revisit_stamps[s] for s in lvc_stamps], "stamp"
    return list(range(len(lvc_stamps))), "order"
