"""``poseidon vpr``: visual place recognition figures of the neocortical front-end.

Usage::

    poseidon vpr --ref DIR --query DIR [--gt FILE] [--tolerance N] [--weights PATH]
                 [--backbone shufflenetv2|alexnet_conv3] [--limit N] [--config FILE]
                 [--set key=value ...] [--no-htm] [--htm-query-learning] [--json]

Both folders are image sequences (``.png`` / ``.jpg`` / ``.jpeg``, sorted by file name,
read with PIL as RGB); ``--limit N`` keeps the first N of each.  Ground truth: with
``--gt FILE`` the VPR-Bench format (``np.load(allow_pickle=True)``: rows ``[query index,
list of matching reference indices]``, indices into the sorted full folders); without it,
the reference frame with the query's file name is the match, and ``--tolerance N`` also
accepts the N neighbours on either side of it (Nordland: same name = same place).

Matchers (each gives an n_query x n_ref similarity; the best reference of a query is its
argmax, correct iff it is in the query's ground truth):

* ``cnn_cosine`` -- cosine of the raw embeddings y (Eq. 4.1), no hashing.
* ``lsbh_overlap`` -- |A_q intersect A_r| / 2k of the camera LSBH SDRs (Eqs. 4.2, 4.6).
* ``htm_lvc`` -- the full pipeline: camera SDR (the fused SDR: these image sets have no
  sonar) -> SP -> TM -> descriptor D_t -> LVC id (Eqs. 4.4-4.10, :mod:`services.htm`).  The
  reference sequence builds the LVC map (learning as ``htm.learning``); after a reset of the
  temporal context the query sequence only queries that map (no new LVCs; HTM learning off
  unless ``--htm-query-learning``).  A query whose LVC match is accepted (Eq. 4.9) predicts
  the reference frame with that LVC id whose descriptor overlaps D_q most (Eq. 4.7), with
  the match's R as score; a rejected query predicts nothing (it only lowers recall).
* ``htm_descriptor`` -- R(D_q, D_r) (Eq. 4.7) between the TM descriptors of every query
  and reference frame: the HTM's similarity without the LVC decision.

Per matcher, with queries ranked by score (thresholds at every distinct score):
precision = correct / predicted, recall = correct / queries having a ground-truth match.
``auc`` = area under that precision-recall curve (step-wise: sum of recall increments
times precision, i.e. average precision); ``recall_at_p100`` = the largest recall with
precision exactly 1 (0 if the best-scored query is wrong); ``best_f1`` = max 2PR/(P+R).

``--json`` prints one object::

    {"matchers": {"cnn_cosine": {"auc": .., "recall_at_p100": .., "best_f1": .., "n_predicted": ..},
                  "lsbh_overlap": {...}, "htm_lvc": {...}, "htm_descriptor": {...}},
     "n_ref": .., "n_query": .., "n_query_with_gt": .., "weights": "seeded" | "<path>",
     "backbone": "shufflenetv2", "embedding_dim": .., "sdr_bits": .., "sdr_length": ..,
     "n_lvc": .., "htm_query_matched": .., "ground_truth": "file name +-N" | "<gt file>", "seconds": {"embed": .., "htm": ..}}

Progress goes to stderr.  Returns 0, or 2 on bad arguments / inputs (message on stderr).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm import tqdm

__all__ = ["main", "pr_curve", "vpr_metrics", "best_matches", "load_sequence", "ground_truth_by_name",
           "ground_truth_from_file", "overlap_similarity", "cosine_similarity"]

log = logging.getLogger(__name__)

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


def vpr_metrics(similarity: np.ndarray, gt: Sequence[Sequence[int]]) -> dict[str, float]:
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
    return qn @ rn.T


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
    return inter / size


# --------------------------------------------------------------------------- inputs


def load_sequence(folder: str | Path, limit: int = 0) -> tuple[list[str], list[np.ndarray]]:
    """File names (sorted) and RGB uint8 images of an image folder; first ``limit`` if > 0."""
    from PIL import Image as PILImage, UnidentifiedImageError

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


# --------------------------------------------------------------------------- HTM matcher


def run_htm(htm_cfg, ref_sdrs: Sequence[np.ndarray], query_sdrs: Sequence[np.ndarray], length: int,
            query_learning: bool = False):
    """LVC ids, rates and descriptors D_t of the reference then the query sequence.

    :class:`services.htm.pipeline.NeocortexHtm` (``htm.input_size`` = L) runs over the
    reference sequence storing LVC prototypes (learning as ``htm.learning``); its temporal
    context is then reset (the jump to the first query frame is no real transition) and the
    query sequence only *queries* the reference map (``store=False``: id -1 when Eq. 4.9
    rejects), with learning off unless ``query_learning``.
    """
    from services.htm.pipeline import NeocortexHtm

    cfg = htm_cfg.model_copy(update={"input_size": length})
    htm = NeocortexHtm(cfg)
    ref_out, q_out = [], []
    for bits in tqdm(ref_sdrs, desc="htm ref", file=sys.stderr, leave=False):
        r = htm.step(np.asarray(bits, dtype=np.uint32))
        ref_out.append((int(r.lvc_id), float(r.rate), np.asarray(htm.last_descriptor, dtype=np.int64).copy()))
    htm.reset_sequence()
    learn = cfg.learning and query_learning
    for bits in tqdm(query_sdrs, desc="htm query", file=sys.stderr, leave=False):
        r = htm.step(np.asarray(bits, dtype=np.uint32), learn=learn, store=False)
        q_out.append((int(r.lvc_id), float(r.rate), np.asarray(htm.last_descriptor, dtype=np.int64).copy()))
    return ref_out, q_out, htm


def htm_similarities(ref_out, query_out) -> tuple[np.ndarray, np.ndarray]:
    """(htm_lvc, htm_descriptor) similarity matrices from the HTM outputs (see module doc)."""
    d_ref = [d for _, _, d in ref_out]
    d_q = [d for _, _, d in query_out]
    desc = overlap_similarity(d_q, d_ref).astype(np.float64)
    ref_ids = np.array([i for i, _, _ in ref_out])
    lvc = np.full(desc.shape, -np.inf)
    for qi, (lid, rate, _) in enumerate(query_out):
        same = np.flatnonzero(ref_ids == lid)
        if same.size:
            best = same[np.argmax(desc[qi, same])]
            lvc[qi, best] = rate
    return lvc, desc


# --------------------------------------------------------------------------- CLI


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="poseidon vpr", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", required=True, help="reference image folder")
    ap.add_argument("--query", required=True, help="query image folder")
    ap.add_argument("--gt", default="", help="VPR-Bench ground truth .npy (default: same file name)")
    ap.add_argument("--tolerance", type=int, default=0, help="same-name ground truth: +-N frames also match")
    ap.add_argument("--weights", default=None, help="torchvision state dict (default: encoder.weights_path)")
    ap.add_argument("--backbone", choices=["shufflenetv2", "alexnet_conv3"], default=None)
    ap.add_argument("--limit", type=int, default=0, help="first N frames of each folder (0: all)")
    ap.add_argument("--config", default=None, help="PoseidonSLAM YAML configuration")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--no-htm", action="store_true", help="skip the HTM matchers")
    ap.add_argument("--htm-query-learning", action="store_true",
                    help="keep HTM learning on during the query pass (default: off, fixed reference)")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``poseidon vpr`` (see the module docstring)."""
    args = _parser().parse_args(argv)
    from common.config import ConfigError, load_config

    from .backbones import WeightsError
    from .encoder import MultimodalEncoder
    from .lsbh import LsbhError

    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(levelname)s %(message)s")
    try:
        cfg = load_config(args.config, args.overrides)
        enc_cfg = cfg.encoder
        upd = {}
        if args.weights is not None:
            upd["weights_path"] = args.weights
        if args.backbone is not None:
            upd["cnn_backbone"] = args.backbone
        enc_cfg = enc_cfg.model_copy(update=upd)
        ref_names, ref_imgs = load_sequence(args.ref, args.limit)
        q_names, q_imgs = load_sequence(args.query, args.limit)
        if args.gt:
            gt = ground_truth_from_file(args.gt, len(q_names), len(ref_names))
            gt_desc = str(args.gt)
        else:
            gt = ground_truth_by_name(q_names, ref_names, args.tolerance)
            gt_desc = f"file name +-{args.tolerance}"
        t0 = time.perf_counter()
        encoder = MultimodalEncoder(enc_cfg)
        y_ref: list[np.ndarray] = []
        y_q: list[np.ndarray] = []
        for imgs, out, name in ((ref_imgs, y_ref, "ref"), (q_imgs, y_q, "query")):
            b = enc_cfg.batch_max
            for i in tqdm(range(0, len(imgs), b), desc=f"embed {name}", file=sys.stderr, leave=False):
                out.extend(encoder.encode_camera(imgs[i:i + b]))
        s_ref = encoder.sdr_batch("camera", y_ref)
        s_q = encoder.sdr_batch("camera", y_q)
        t_embed = time.perf_counter() - t0
    except (ConfigError, VprInputError, WeightsError, LsbhError) as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    length = enc_cfg.sp_columns
    sims = {
        "cnn_cosine": cosine_similarity(np.stack(y_q), np.stack(y_ref)),
        "lsbh_overlap": overlap_similarity(s_q, s_ref),
    }
    result: dict = {}
    t_htm = 0.0
    if not args.no_htm:
        t1 = time.perf_counter()
        ref_out, q_out, htm = run_htm(cfg.htm, s_ref, s_q, length, args.htm_query_learning)
        t_htm = time.perf_counter() - t1
        sims["htm_lvc"], sims["htm_descriptor"] = htm_similarities(ref_out, q_out)
        result["n_lvc"] = len(htm.lvc)
        result["htm_query_matched"] = sum(1 for i, _, _ in q_out if i >= 0)
    metrics = {name: vpr_metrics(s, gt) for name, s in sims.items()}
    result = {
        "matchers": metrics,
        "n_ref": len(ref_names), "n_query": len(q_names), "n_query_with_gt": sum(1 for g in gt if g),
        "weights": encoder.weights, "backbone": enc_cfg.cnn_backbone, "embedding_dim": encoder.dim,
        "sdr_bits": 2 * encoder.lsbh("camera").k, "sdr_length": length, "ground_truth": gt_desc,
        **result,
        "seconds": {"embed": round(t_embed, 2), "htm": round(t_htm, 2)},
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"VPR {args.query} vs {args.ref}: {result['n_query']} queries, {result['n_ref']} references, "
              f"backbone {result['backbone']} ({result['weights']} weights), ground truth {gt_desc}")
        print(f"{'matcher':16s} {'AUC':>7s} {'R@P100':>7s} {'bestF1':>7s}")
        for name, m in metrics.items():
            print(f"{name:16s} {m['auc']:7.3f} {m['recall_at_p100']:7.3f} {m['best_f1']:7.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
