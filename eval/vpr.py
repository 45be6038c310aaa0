"""``poseidon vpr``: visual place recognition figures of the neocortical front-end.

Usage::

    poseidon vpr --ref DIR --query DIR [--gt FILE] [--tolerance N] [--weights PATH]
                 [--backbone shufflenetv2|alexnet_conv3] [--limit N] [--config FILE]
                 [--set key=value ...] [--no-htm] [--no-chains] [--htm-query-learning] [--save-norm FILE] [--json]
    poseidon vpr --mission FILE.mcap [--min-gap-m M] [--weights PATH] [--backbone ...]
                 [--config FILE] [--set key=value ...] [--no-htm] [--no-chains] [--json]

Both folders are image sequences (``.png`` / ``.jpg`` / ``.jpeg``, sorted by file name,
read with PIL as RGB); ``--limit N`` keeps the first N of each.  Ground truth: with
``--gt FILE`` the VPR-Bench format (``np.load(allow_pickle=True)``: rows ``[query index,
list of matching reference indices]``, indices into the sorted full folders); without it,
the reference frame with the query's file name is the match, and ``--tolerance N`` also
accepts the N neighbours on either side of it (Nordland: same name = same place).

Embedding standardisation (``encoder.embedding_norm``, :mod:`services.encoder.standardize`)
on image sets: ``running`` is estimated in memory on the reference sequence in order (as
the node would), the queries use the statistics as they stand; ``fixed`` is fitted on the
reference set (``--save-norm FILE`` writes the camera statistics, e.g. for a deployment
with ``embedding_norm: fixed``); ``none`` hashes the raw y (Eq. 4.2 exactly).

``--mission FILE.mcap``: one recording (``poseidon sim --minutes M --seed S --out F.mcap``,
or ``poseidon transform``) with ``camera/image_raw``, ``truth/revisits`` and ``truth/pose``.
The camera and the ``encoder.sonar_topic`` stream go through :class:`EncoderNode` in event
order (fused SDR = camera OR sonar, running statistics from the mission itself, in memory),
then :class:`NeocortexHtm` steps over the fused SDRs once, *storing* LVCs as online.  Each
frame i is compared with the earlier frames j that are at least ``--min-gap-m`` (default:
the recording's ``revisit_min_gap_m``, 10 m) back along the true track (nearer frames
trivially look alike and are never revisits); its ground truth is ``truth/revisits``.
Frames without a revisit that predict one count as false positives.  The modality table:
the fused code (``encoder.fusion_mode``: union = OR, and = AND) and, from the same encoder
pass, the camera-only and sonar-only SDR streams (a frame without a fresh sonar SDR feeds an
empty SDR) each run through their own :class:`NeocortexHtm`; ``modalities`` gives per stream
the LVC figures below plus ``lvc_run_length`` and ``htm_lvc`` (the matcher's metrics); the
top-level LVC figures and the ``htm_*`` matchers are those of the fused code.  Extra matcher
``lsbh_fused_overlap`` (fused camera+sonar SDR overlap).  LVC-id figures: ``lvc_recall`` =
fraction of revisit frames whose LVC id equals the id of one of their true earlier frames;
a frame *claims* a revisit when its id was given to a candidate earlier frame (>= the
gap back), ``lvc_precision`` = fraction of claims whose id is that of a true earlier frame
(the *per-frame* revisit recall / precision of :func:`eval.frontend.lvc_revisit_metrics`, the
figures of the run summary and ``poseidon eval`` too); ``lvc_pair_precision`` /
``lvc_pair_recall`` are the *frame-pair* measure of "same LVC id"
(:func:`eval.frontend.lvc_pair_metrics`), a different quantity.

Matchers (each gives an n_query x n_ref similarity; the best reference of a query is its
argmax, correct iff it is in the query's ground truth):

* ``cnn_cosine`` -- cosine of the raw embeddings y (Eq. 4.1), no hashing.
* ``seq_cosine`` -- baseline: SeqSLAM-style sequence matching on the cosines of ``cnn_cosine``
  (difference matrix normalised per reference, best straight line of 10 frames;
  :mod:`eval.baselines`).
* ``patchnorm_sad`` -- baseline: sum of absolute differences of patch-normalised 32x16 grey
  images (:mod:`eval.baselines`).
* ``lsbh_overlap`` -- |A_q intersect A_r| / 2k of the camera LSBH SDRs (Eqs. 4.2, 4.6).
* ``htm_lvc`` -- the full pipeline: camera SDR (the fused SDR: these image sets have no
  sonar) -> SP -> TM -> descriptor D_t -> LVC id (Eqs. 4.4-4.10, :mod:`services.htm`).  The
  reference sequence builds the LVC map (learning as ``htm.learning``); after a reset of the
  temporal context the query sequence only queries that map (no new LVCs; HTM learning off
  unless ``--htm-query-learning``; the reset also starts a new traversal of the sequence
  memory).  A query whose LVC match is accepted (Eq. 4.9, the sequence memory or the
  place-sequence prior) predicts the reference frame with that LVC id whose descriptor
  overlaps D_q most (Eq. 4.7) -- or, when the id is that of the stored frame j* where the
  sequence memory's best diagonal ended, j* itself; its score is the sequence margin
  S* - S_2 (z units) with the sequence memory on (``htm.sv_seqmem_length`` > 0), else R.
  A rejected query predicts nothing (it only lowers recall).  On ``--mission`` the same
  rule picks among the eligible earlier frames.
* ``htm_descriptor`` -- R(D_q, D_r) (Eq. 4.7) between the TM descriptors of every query
  and reference frame: the HTM's similarity without the LVC decision.
* ``sdr_seqmem``, ``sp_tm`` -- ``htm_lvc`` of the named chains of :mod:`services.htm.chains`
  (the configured ``htm`` section with the chain's overrides), run on the same SDRs in the
  same run, printed beside the default (``--no-chains`` skips them): ``sdr_seqmem`` is the
  fused-SDR chain with the sequence memory (no SP, no TM), ``sp_tm`` the spatial pooler +
  temporal memory chain (the TM's predictions decide revisits, :mod:`services.htm.tm_match`),
  ``sdr_seqmem_f1`` / ``sdr_seqmem_cal`` the fused-SDR chain whose sequence match also checks
  the frame's own F1 with the matched frame against a constant / a self-calibrated level
  (:mod:`services.htm.calibrate`) and may override an Eq. 4.9 match to a recent id.

Decisions (``decisions``: counts per rule of how a frame got its id, :func:`decision_kind`):
``gate`` Eq. 4.9 on l*, ``tm`` the TM's predictions, ``seqmem`` the sequence memory,
``prior`` the place-sequence prior, ``new`` Eq. 4.10 (or no id on a query-only step);
``tm_decision_share`` = tm / (all but new).

Per matcher, with queries ranked by score (thresholds at every distinct score):
precision = correct / predicted, recall = correct / queries having a ground-truth match.
``auc`` = area under that precision-recall curve (step-wise: sum of recall increments
times precision, i.e. average precision); ``recall_at_p100`` = the largest recall with
precision exactly 1 (0 if the best-scored query is wrong); ``best_f1`` = max 2PR/(P+R).

``--json`` prints one object (image sets)::

    {"matchers": {"cnn_cosine": {"auc": .., "recall_at_p100": .., "best_f1": .., "n_predicted": ..},
                  "seq_cosine": {...}, "patchnorm_sad": {...}, "lsbh_overlap": {...}, "cnn_cosine_standardized": {...} (embedding_norm not none),
                  "htm_lvc": {...}, "htm_descriptor": {...}},
     "n_ref": .., "n_query": .., "n_query_with_gt": .., "weights": "seeded" | "<path>",
     "backbone": "shufflenetv2", "embedding_dim": .., "embedding_norm": "none|running|fixed",
     "sdr_bits": .., "sdr_length": .., "ground_truth": "file name +-N" | "<gt file>",
     "sdr_overlap": {"same_place": .., "different_place": ..},   # mean |A_q & A_r| / 2k (random: s = 0.25)
     "n_lvc": .., "htm_query_matched": .., "decisions": {"gate": .., "tm": .., "seqmem": .., "prior": .., "new": ..},
     "chains": {"sdr_seqmem": {"n_lvc": .., "htm_query_matched": .., "decisions": {..}}, "sp_tm": {...},
                "sdr_seqmem_f1": {...}, "sdr_seqmem_cal": {...}},
     "seconds": {"embed": .., "htm": ..}}   # htm: the default and the chains

and with ``--mission``::

    {"mission": "<file>", "backbone": .., "embedding_norm": .., "n_frames": .., "n_revisit_frames": ..,
     "min_gap_m": .., "sdr_overlap": {"same_place": .., "different_place": ..} (camera SDRs, candidate pairs),
     "fused_bits_mean": .., "encoder_counters": {..},
     "lvc_recall": .., "lvc_precision": .., "n_claimed_revisits": .., "n_correct_claims": ..,
     "n_lvc": .., "tm_anomaly_mean": .., "sp_columns_used": ..,   # the last 7 without --no-htm
     "lvc_pair_precision": .., "lvc_pair_recall": ..,   # frame pairs with the same id (eval.frontend.lvc_pair_metrics)
     "decisions": {"gate": .., "tm": .., "seqmem": .., "prior": .., "new": ..}, "tm_decision_share": ..,
     "chains": {"sdr_seqmem": {<the LVC figures above>}, "sp_tm": {...}, "sdr_seqmem_f1": {...},
                "sdr_seqmem_cal": {...}},   # without --no-htm / --no-chains
     "lvc_run_length": {"median": .., "mean": .., "frames_in_runs_ge3": ..},  # runs of identical consecutive ids
     "modalities": {"fused_<fusion_mode>": {...}, "camera": {...}, "sonar": {...}},  # without --no-htm
     "matchers": {"cnn_cosine", "seq_cosine", "patchnorm_sad", "cnn_cosine_standardized", "lsbh_overlap",
                  "lsbh_fused_overlap", "htm_lvc", "htm_descriptor", "sdr_seqmem", "sp_tm", "sdr_seqmem_f1",
                  "sdr_seqmem_cal": {...}},
     "seconds": {"embed": .., "htm": ..}, "weights": .., "embedding_dim": ..}

Progress goes to stderr.  Returns 0, or 2 on bad arguments / inputs (message on stderr).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.baselines import SEQ_LENGTH, patch_normalise, sad_similarity, sequence_similarity

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
        ref_out.append(_htm_row(htm, r))
    htm.reset_sequence()
    learn = cfg.learning and query_learning
    htm.query_decisions = {k: 0 for k in DECISION_KINDS}
    for bits in tqdm(query_sdrs, desc="htm query", file=sys.stderr, leave=False):
        r = htm.step(np.asarray(bits, dtype=np.uint32), learn=learn, store=False)
        q_out.append(_htm_row(htm, r))
        htm.query_decisions[decision_kind(r)] += 1
    return ref_out, q_out, htm


def match_confidence(htm, r) -> float:
    """The score a query's LVC match is ranked by: with the sequence memory
    (``htm.sv_seqmem_length`` > 0) the sequence margin S* - S_2 at the predicted frame, else R."""
    return float(r.seq_margin) if htm.seqmem is not None else float(r.rate)


def _htm_row(htm, r) -> tuple[int, float, np.ndarray, int]:
    """(LVC id, confidence, D_t, memory frame the id was read from or -1) of one step."""
    frame = int(r.frame) if (htm.seqmem is not None and r.frame >= 0 and r.lvc_id >= 0
                             and int(htm.seqmem.ids[r.frame]) == r.lvc_id) else -1
    return int(r.lvc_id), match_confidence(htm, r), np.asarray(htm.last_descriptor, dtype=np.int64).copy(), frame


def htm_similarities(ref_out, query_out) -> tuple[np.ndarray, np.ndarray]:
    """(htm_lvc, htm_descriptor) similarity matrices from the HTM outputs (see module doc)."""
    d_ref = [o[2] for o in ref_out]
    d_q = [o[2] for o in query_out]
    desc = overlap_similarity(d_q, d_ref).astype(np.float64)
    ref_ids = np.array([o[0] for o in ref_out])
    lvc = np.full(desc.shape, -np.inf)
    for qi, (lid, score, _, frame) in enumerate(query_out):
        if 0 <= frame < len(ref_out):   # the sequence match names the reference frame itself
            lvc[qi, frame] = score
            continue
        same = np.flatnonzero(ref_ids == lid)
        if same.size:
            best = same[np.argmax(desc[qi, same])]
            lvc[qi, best] = score
    return lvc, desc


# --------------------------------------------------------------------------- standardisation


def image_set_standardizer(enc_cfg, dim: int, y_ref: Sequence[np.ndarray]):
    """The camera standardiser of an image-set run, or None for ``embedding_norm`` none.

    ``running``: in memory (nothing read from or written to ``embedding_norm_path``),
    estimated on the reference sequence in order exactly as the encoder node does (each frame
    standardised with the frames before it until the warm-up ends); the queries are then
    standardised with the statistics as they stand, without updating them (like the HTM
    query pass).  ``fixed``: fitted on the whole reference set.
    """
    from services.encoder.standardize import EmbeddingStandardizer

    mode = enc_cfg.embedding_norm
    if mode == "none":
        return None
    if mode == "fixed":
        return EmbeddingStandardizer.fitted(np.stack(y_ref), enc_cfg.embedding_norm_scale)
    return EmbeddingStandardizer(dim, "running", enc_cfg.embedding_norm_warmup, enc_cfg.embedding_norm_rate,
                                 enc_cfg.embedding_norm_scale, None)


def overlap_stats(sim: np.ndarray, gt: Sequence[Sequence[int]], eligible: np.ndarray | None = None) -> dict:
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


def _travelled(stamps: np.ndarray, pose_stamps: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Distance travelled (m) along the true trajectory at each of ``stamps``."""
    seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))]
    return np.interp(stamps.astype(np.float64), pose_stamps.astype(np.float64), seg)


def lvc_revisit_scores(ids: np.ndarray, gt: Sequence[Sequence[int]], eligible: np.ndarray) -> dict:
    """LVC-id recall and precision on a mission (see the module doc, ``--mission``), by the one
    definition of :func:`eval.frontend.lvc_revisit_metrics`.  ``eligible[i]`` is a prefix of
    the earlier frames (those at least the revisit gap of travel back)."""
    from eval.frontend import lvc_pair_metrics, lvc_revisit_metrics
    before = np.asarray(eligible, bool).sum(axis=1)
    m = lvc_revisit_metrics(ids, gt, eligible_before=before)
    pm = lvc_pair_metrics(ids, gt, eligible_before=before)
    return {"lvc_recall": m["recall"] or 0.0, "lvc_precision": m["precision"] or 0.0,
            "n_revisit_frames": m["revisit_frames"], "n_claimed_revisits": m["claimed"],
            "n_correct_claims": m["correct_claims"],
            "lvc_pair_precision": pm["pair_precision"] or 0.0, "lvc_pair_recall": pm["pair_recall"] or 0.0}


@dataclass
class MissionStreams:
    """What the encoder made of one mission, per camera frame (input of :func:`score_mission`)."""

    y: np.ndarray                 # camera embeddings (n, d)
    z: np.ndarray                 # standardised camera embeddings (n, d)
    thumbs: np.ndarray            # patch-normalised 32x16 grey thumbnails (n, 512)
    sdrs: dict[str, list[np.ndarray]]  # "camera", "sonar" (empty when absent), "fused" active bits per frame
    gt: list[list[int]]
    eligible: np.ndarray          # (n, n) bool: j is a candidate earlier frame of i
    min_gap_m: float
    counters: dict
    weights: str
    dim: int
    fusion_mode: str
    seconds_embed: float


def run_mission(path: str | Path, cfg, enc_cfg, min_gap_m: float | None, use_htm: bool,
                chains: Sequence[str] = ()) -> dict:
    """The front-end (EncoderNode, then NeocortexHtm storing LVCs online) over one MCAP mission.

    Returns the figures of the ``--mission`` JSON (see the module doc); ``chains`` names the
    chains of :mod:`services.htm.chains` also run on the fused stream.
    """
    return score_mission(encode_mission(path, cfg, enc_cfg, min_gap_m), cfg, enc_cfg, use_htm, chains)


def encode_mission(path: str | Path, cfg, enc_cfg, min_gap_m: float | None) -> MissionStreams:
    """Camera and sonar of one MCAP mission through :class:`EncoderNode`, in event order."""
    from common.codec import DecodeError
    from common.mcap_io import RecordingError, read_messages, read_metadata, recording_keys
    from services.encoder.encoder import MultimodalEncoder, image_to_rgb
    from services.encoder.node import EncoderNode

    path = Path(path)
    try:
        keys = recording_keys(path)
    except RecordingError as exc:
        raise VprInputError(str(exc)) from None
    for k in ("camera/image_raw", "truth/revisits", "truth/pose"):
        if k not in keys:
            raise VprInputError(f"{path}: no {k!r} channel (needed by --mission; a `poseidon sim` recording has it)")
    if min_gap_m is None:
        meta = read_metadata(path).get("poseidon", {})
        try:
            if "params" not in meta and "source_metadata" in meta:  # poseidon transform: the source's record
                meta = json.loads(meta["source_metadata"])
            params = meta["params"]
            min_gap_m = float((json.loads(params) if isinstance(params, str) else params)["revisit_min_gap_m"])
        except (KeyError, ValueError, TypeError) as exc:
            raise VprInputError(f"{path}: no params.revisit_min_gap_m in the 'poseidon' metadata ({exc}); "
                                f"pass --min-gap-m") from None
    sonar_key = enc_cfg.sonar_topic

    class _Recorder(MultimodalEncoder):
        def __init__(self, c) -> None:
            super().__init__(c)
            self.camera: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

        def sdr(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray:
            z = self.standardize(modality, embedding, update)
            bits = self.lsbh(modality).encode(z)
            if modality == "camera":
                self.camera.append((np.asarray(embedding, np.float32), z.astype(np.float32), bits))
            return bits

    run_cfg = cfg.model_copy(update={"encoder": enc_cfg})
    encoder = _Recorder(enc_cfg)
    node = EncoderNode(run_cfg, encoder)
    frames: list[tuple[int, np.ndarray]] = []  # (stamp, fused bits) per camera frame
    mod_bits: dict[str, list[np.ndarray]] = {"camera": [], "sonar": []}
    thumbs: list[np.ndarray] = []
    truth: dict[int, np.ndarray] = {}
    pose_t, pose_p = [], []
    cam_stamps: list[int] = []
    wanted = ["camera/image_raw", sonar_key, "truth/revisits", "truth/pose"]
    t0 = time.perf_counter()
    bar = tqdm(desc="mission frames", unit="frame", file=sys.stderr, leave=False)
    try:
        for rec in read_messages(path, keys=wanted):
            msg = rec.message()
            if rec.key == "truth/revisits":
                truth[int(msg.frame_index)] = np.asarray(msg.same_place, np.int64)
            elif rec.key == "truth/pose":
                pose_t.append(msg.header.stamp)
                pose_p.append(msg.position)
            else:
                if rec.key == "camera/image_raw":
                    cam_stamps.append(msg.header.stamp)
                    thumbs.append(patch_normalise(image_to_rgb(msg)))
                    bar.update(1)
                node.process(rec.key, msg)
                for _, out in node.take_outbox():
                    present = {m.modality: np.asarray(m.active, np.uint32) for m in out.modalities}
                    if "camera" in present:
                        frames.append((out.header.stamp, np.asarray(out.fused.active, np.uint32)))
                        for m in mod_bits:
                            mod_bits[m].append(present.get(m, np.zeros(0, np.uint32)))
    except (RecordingError, DecodeError) as exc:
        raise VprInputError(f"{path}: {exc}") from None
    finally:
        bar.close()
    node.finish()
    t_embed = time.perf_counter() - t0
    n = len(cam_stamps)
    if len(frames) != n or len(encoder.camera) != n:
        raise VprInputError(f"{path}: {n} camera frames but {len(frames)} camera-clocked SDRs")
    gt = [[int(j) for j in truth.get(i, []) if 0 <= j < i] for i in range(n)]
    dist = _travelled(np.asarray(cam_stamps), np.asarray(pose_t), np.asarray(pose_p, np.float64))
    idx = np.arange(n)
    eligible = (idx[None, :] < idx[:, None]) & (dist[:, None] - dist[None, :] >= min_gap_m)

    return MissionStreams(
        y=np.stack([c[0] for c in encoder.camera]), z=np.stack([c[1] for c in encoder.camera]),
        thumbs=np.stack(thumbs), sdrs={**mod_bits, "fused": [f[1] for f in frames]}, gt=gt, eligible=eligible,
        min_gap_m=float(min_gap_m), counters=dict(node.counters), weights=encoder.weights, dim=encoder.dim,
        fusion_mode=enc_cfg.fusion_mode, seconds_embed=t_embed)


def mission_htm(htm_cfg, length: int, bits: Sequence[np.ndarray], gt: Sequence[Sequence[int]],
                eligible: np.ndarray) -> dict:
    """One NeocortexHtm storing LVCs online over one SDR stream: LVC scores and similarity matrices."""
    from services.htm.pipeline import NeocortexHtm

    htm = NeocortexHtm(htm_cfg.model_copy(update={"input_size": length}))
    out = []
    cols_used: set[int] = set()
    kinds = {k: 0 for k in DECISION_KINDS}
    for b in tqdm(bits, desc="htm", file=sys.stderr, leave=False):
        r = htm.step(np.asarray(b, np.uint32))
        cols_used.update(htm.last_columns.tolist())
        out.append((*_htm_row(htm, r), float(r.anomaly)))
        kinds[decision_kind(r)] += 1
    n = len(out)
    ids = np.array([o[0] for o in out])
    desc = overlap_similarity([o[2] for o in out], [o[2] for o in out]).astype(np.float64)
    lvc = np.full(desc.shape, -np.inf)
    for i in range(n):
        frame = out[i][3]   # the memory index is the frame index: every frame is stored in order
        if 0 <= frame < n and eligible[i, frame]:
            lvc[i, frame] = out[i][1]
            continue
        same = np.flatnonzero(eligible[i] & (ids == ids[i]))
        if same.size:
            lvc[i, same[np.argmax(desc[i, same])]] = out[i][1]
    res = lvc_revisit_scores(ids, gt, eligible)
    res.update({"n_lvc": len(htm.lvc), "lvc_run_length": run_length_stats(ids),
                "tm_anomaly_mean": round(float(np.mean([o[4] for o in out])), 4) if out else 0.0,
                "sp_columns_used": len(cols_used), "decisions": kinds,
                "tm_decision_share": round(kinds["tm"] / max(n - kinds["new"], 1), 4)})
    return {"scores": res, "htm_lvc": lvc, "htm_descriptor": np.where(eligible, desc, -np.inf), "ids": ids}


DECISION_KINDS = ("gate", "tm", "seqmem", "prior", "new")


def decision_kind(r) -> str:
    """Which rule gave a frame its id: ``gate`` (Eq. 4.9 on l*), ``tm`` (the TM's predictions,
    :mod:`services.htm.tm_match`), ``seqmem`` (the sequence memory's diagonal), ``prior`` (the
    place-sequence prior), ``new`` (Eq. 4.10, or no id on a query-only step)."""
    if r.is_new or r.lvc_id < 0:
        return "new"
    if r.by_tm:
        return "tm"
    if r.by_sequence:
        return "seqmem"
    return "prior" if r.by_prior else "gate"


def run_length_stats(ids: np.ndarray) -> dict:
    """Lengths of the runs of identical consecutive LVC ids: median, mean, and the share of frames
    in runs of >= 3 (what the VPR Guard needs: the same id >= 3 times within 26 frames)."""
    ids = np.asarray(ids)
    if ids.size == 0:
        return {"median": 0.0, "mean": 0.0, "frames_in_runs_ge3": 0.0}
    cuts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1], True])
    runs = np.diff(cuts)
    return {"median": float(np.median(runs)), "mean": round(float(runs.mean()), 2),
            "frames_in_runs_ge3": round(float(runs[runs >= 3].sum() / ids.size), 4)}


def score_mission(st: MissionStreams, cfg, enc_cfg, use_htm: bool, chains: Sequence[str] = ()) -> dict:
    """The ``--mission`` figures (see the module doc) from the encoded streams."""
    gt, eligible, n = st.gt, st.eligible, len(st.gt)

    def masked(sim: np.ndarray) -> np.ndarray:
        return np.where(eligible, sim, -np.inf)

    cam_bits, fused = st.sdrs["camera"], st.sdrs["fused"]
    lsbh_cam = overlap_similarity(cam_bits, cam_bits)
    cos = cosine_similarity(st.y, st.y)
    sims = {"cnn_cosine": masked(cos),
            "seq_cosine": sequence_similarity(masked(cos), SEQ_LENGTH),
            "patchnorm_sad": masked(sad_similarity(st.thumbs, st.thumbs)),
            "lsbh_overlap": masked(lsbh_cam),
            "lsbh_fused_overlap": masked(overlap_similarity(fused, fused))}
    if enc_cfg.embedding_norm != "none":
        sims["cnn_cosine_standardized"] = masked(cosine_similarity(st.z, st.z))
    result: dict = {"n_frames": n, "n_revisit_frames": sum(1 for g in gt if g), "min_gap_m": st.min_gap_m,
                    "sdr_overlap": overlap_stats(lsbh_cam, gt, eligible),
                    "fused_bits_mean": round(float(np.mean([f.size for f in fused])), 1),
                    "encoder_counters": st.counters}
    t_htm = 0.0
    if use_htm:
        t1 = time.perf_counter()
        streams = {f"fused_{st.fusion_mode}": fused}
        for m in ("camera", "sonar"):
            if st.fusion_mode != m:
                streams[m] = st.sdrs[m]
        per: dict[str, dict] = {}
        for name, bits in streams.items():
            h = mission_htm(cfg.htm, enc_cfg.sp_columns, bits, gt, eligible)
            per[name] = {**h["scores"], "htm_lvc": vpr_metrics(h["htm_lvc"], gt)}
            if name.startswith("fused"):
                sims["htm_lvc"], sims["htm_descriptor"] = h["htm_lvc"], h["htm_descriptor"]
                result.update(h["scores"])
        result["modalities"] = per
        if chains:
            from services.htm.chains import chain_config
            result["chains"] = {}
            for cname in chains:
                h = mission_htm(chain_config(cfg.htm, cname), enc_cfg.sp_columns, fused, gt, eligible)
                sims[cname] = h["htm_lvc"]
                result["chains"][cname] = h["scores"]
        t_htm = time.perf_counter() - t1
    result["matchers"] = {name: vpr_metrics(s, gt) for name, s in sims.items()}
    result["seconds"] = {"embed": round(st.seconds_embed, 2), "htm": round(t_htm, 2)}
    result["weights"] = st.weights
    result["embedding_dim"] = st.dim
    return result


# --------------------------------------------------------------------------- CLI


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="poseidon vpr", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", default=None, help="reference image folder")
    ap.add_argument("--query", default=None, help="query image folder")
    ap.add_argument("--mission", default=None, metavar="FILE.mcap",
                    help="a recording with camera/image_raw, truth/revisits and truth/pose (instead of --ref/--query)")
    ap.add_argument("--min-gap-m", type=float, default=None,
                    help="--mission: earlier frames count as candidates only this far back along the track, m "
                         "(default: the recording's revisit_min_gap_m)")
    ap.add_argument("--gt", default="", help="VPR-Bench ground truth .npy (default: same file name)")
    ap.add_argument("--tolerance", type=int, default=0, help="same-name ground truth: +-N frames also match")
    ap.add_argument("--weights", default=None, help="torchvision state dict (default: encoder.weights_path)")
    ap.add_argument("--backbone", choices=["efficientnet_lite0", "shufflenetv2", "alexnet_conv3"], default=None)
    ap.add_argument("--limit", type=int, default=0, help="first N frames of each folder (0: all)")
    ap.add_argument("--config", default=None, help="PoseidonSLAM YAML configuration")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--no-htm", action="store_true", help="skip the HTM matchers")
    ap.add_argument("--no-chains", action="store_true",
                    help="do not run the named chains (services/htm/chains.py: sdr_seqmem, sp_tm, sdr_seqmem_f1, "
                         "sdr_seqmem_cal) beside the default")
    ap.add_argument("--htm-query-learning", action="store_true",
                    help="keep HTM learning on during the query pass (default: off, fixed reference)")
    ap.add_argument("--save-norm", default=None, metavar="FILE.npz",
                    help="write the camera embedding statistics of the run (embedding_norm running/fixed) here, "
                         "e.g. for encoder.embedding_norm fixed")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    return ap


def _print_lvc(name: str, r: dict) -> None:
    d = r.get("decisions", {})
    print(f"{name:12s} LVC ids {r['n_lvc']}, per-frame revisit recall {r['lvc_recall']:.3f}, "
          f"precision {r['lvc_precision']:.3f}; SP columns used {r.get('sp_columns_used', 0)}; decisions "
          + ", ".join(f"{k} {v}" for k, v in d.items()) + f" (TM share {r.get('tm_decision_share', 0.0):.3f})")


def _print_table(title: str, metrics: dict) -> None:
    print(title)
    print(f"{'matcher':24s} {'AUC':>7s} {'R@P100':>7s} {'bestF1':>7s}")
    for name, m in metrics.items():
        print(f"{name:24s} {m['auc']:7.3f} {m['recall_at_p100']:7.3f} {m['best_f1']:7.3f}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``poseidon vpr`` (see the module docstring)."""
    args = _parser().parse_args(argv)
    from common.config import ConfigError, load_config
    from services.encoder.backbones import WeightsError
    from services.encoder.encoder import MultimodalEncoder
    from services.encoder.lsbh import LsbhError
    from services.encoder.standardize import StandardizerError

    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(levelname)s %(message)s")
    if args.mission is None and (args.ref is None or args.query is None):
        print("poseidon vpr: give --ref DIR and --query DIR, or --mission FILE.mcap", file=sys.stderr)
        return 2
    if args.mission is not None and (args.ref is not None or args.query is not None):
        print("poseidon vpr: --mission excludes --ref/--query", file=sys.stderr)
        return 2
    errors = (ConfigError, VprInputError, WeightsError, LsbhError, StandardizerError)
    from services.htm.chains import CHAINS
    chains = () if (args.no_htm or args.no_chains) else tuple(CHAINS)
    try:
        cfg = load_config(args.config, args.overrides)
        enc_cfg = cfg.encoder
        upd: dict = {}
        if args.weights is not None:
            upd["weights_path"] = args.weights
        if args.backbone is not None:
            upd["cnn_backbone"] = args.backbone
        if enc_cfg.embedding_norm != "fixed":
            upd["embedding_norm_path"] = ""  # running statistics start fresh, in memory, every run
        enc_cfg = enc_cfg.model_copy(update=upd)
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    if args.mission is not None:
        try:
            result = run_mission(args.mission, cfg, enc_cfg, args.min_gap_m, not args.no_htm, chains)
        except errors as exc:
            print(f"poseidon vpr: {exc}", file=sys.stderr)
            return 2
        result = {"mission": str(args.mission), "backbone": enc_cfg.cnn_backbone,
                  "embedding_norm": enc_cfg.embedding_norm, **result}
        if args.json:
            print(json.dumps(result, indent=2))
        else:
            _print_table(f"VPR on mission {args.mission}: {result['n_frames']} frames, {result['n_revisit_frames']} "
                         f"revisits, backbone {enc_cfg.cnn_backbone} ({result['weights']} weights), "
                         f"embedding_norm {enc_cfg.embedding_norm}", result["matchers"])
            if "lvc_recall" in result:
                _print_lvc("default", result)
                for cname, c in result.get("chains", {}).items():
                    _print_lvc(cname, c)
        return 0
    try:
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
        st = image_set_standardizer(enc_cfg, encoder.dim, y_ref)
        if st is not None:
            encoder.set_standardizer("camera", st)
        z_ref = [encoder.standardize("camera", y) for y in y_ref]
        z_q = [encoder.standardize("camera", y, update=False) for y in y_q]
        s_ref = [encoder.lsbh("camera").encode(z) for z in z_ref]
        s_q = [encoder.lsbh("camera").encode(z) for z in z_q]
        if args.save_norm and st is not None:
            st.save(Path(args.save_norm))
        t_embed = time.perf_counter() - t0
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    length = enc_cfg.sp_columns
    cos = cosine_similarity(np.stack(y_q), np.stack(y_ref))
    sims = {
        "cnn_cosine": cos,
        "seq_cosine": sequence_similarity(cos, SEQ_LENGTH),
        "patchnorm_sad": sad_similarity(np.stack([patch_normalise(im) for im in q_imgs]),
                                        np.stack([patch_normalise(im) for im in ref_imgs])),
        "lsbh_overlap": overlap_similarity(s_q, s_ref),
    }
    if st is not None:
        sims["cnn_cosine_standardized"] = cosine_similarity(np.stack(z_q), np.stack(z_ref))
    result: dict = {}
    t_htm = 0.0
    if not args.no_htm:
        t1 = time.perf_counter()
        ref_out, q_out, htm = run_htm(cfg.htm, s_ref, s_q, length, args.htm_query_learning)
        sims["htm_lvc"], sims["htm_descriptor"] = htm_similarities(ref_out, q_out)
        result["n_lvc"] = len(htm.lvc)
        result["htm_query_matched"] = sum(1 for o in q_out if o[0] >= 0)
        result["decisions"] = htm.query_decisions
        from services.htm.chains import chain_config
        result["chains"] = {}
        for cname in chains:
            c_ref, c_q, c_htm = run_htm(chain_config(cfg.htm, cname), s_ref, s_q, length, args.htm_query_learning)
            sims[cname] = htm_similarities(c_ref, c_q)[0]
            result["chains"][cname] = {"n_lvc": len(c_htm.lvc), "htm_query_matched": sum(1 for o in c_q if o[0] >= 0),
                                       "decisions": c_htm.query_decisions}
        t_htm = time.perf_counter() - t1
    metrics = {name: vpr_metrics(s, gt) for name, s in sims.items()}
    result = {
        "matchers": metrics,
        "n_ref": len(ref_names), "n_query": len(q_names), "n_query_with_gt": sum(1 for g in gt if g),
        "weights": encoder.weights, "backbone": enc_cfg.cnn_backbone, "embedding_dim": encoder.dim,
        "embedding_norm": enc_cfg.embedding_norm,
        "sdr_bits": 2 * encoder.lsbh("camera").k, "sdr_length": length, "ground_truth": gt_desc,
        "sdr_overlap": overlap_stats(sims["lsbh_overlap"], gt),
        **result,
        "seconds": {"embed": round(t_embed, 2), "htm": round(t_htm, 2)},
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_table(f"VPR {args.query} vs {args.ref}: {result['n_query']} queries, {result['n_ref']} references, "
                     f"backbone {result['backbone']} ({result['weights']} weights), ground truth {gt_desc}, "
                     f"embedding_norm {enc_cfg.embedding_norm}", metrics)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
