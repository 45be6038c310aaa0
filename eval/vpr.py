"""``poseidon vpr``: visual place recognition figures of the neocortical front-end.

The figures are computed here (:func:`evaluate_image_sets`, :func:`evaluate_mission`); the command
line (arguments, the printed table) is :mod:`eval.cli.vpr`.

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

Embedding standardisation (``encoder.embedding_norm.mode``, :mod:`services.encoder.standardize`)
on image sets: ``running`` is estimated in memory on the reference sequence in order (as
the node would), the queries use the statistics as they stand; ``fixed`` is fitted on the
reference set (``--save-norm FILE`` writes the camera statistics, e.g. for a deployment
with ``embedding_norm: fixed``); ``none`` hashes the raw y (Eq. 4.2 exactly).

``--mission FILE.mcap``: one recording (``poseidon sim --minutes M --seed S --out F.mcap``,
or ``poseidon transform``) with ``camera/image_raw``, ``truth/revisits`` and ``truth/pose``.
The camera and the ``encoder.sonar.topic`` stream go through :class:`EncoderNode` in event
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
  S* - S_2 (z units) with the sequence memory on (``htm.seqmem.length`` > 0), else R.
  A query that no rule accepted predicts the frame j* where the sequence memory's best
  diagonal ended, scored by its margin below the gate: the precision-recall curve
  sweeps the decision threshold, as every other matcher's curve sweeps its own score, and the
  configured gates are one point on it (``htm_query_matched`` counts the accepted queries;
  without the sequence memory a rejected query predicts nothing).  On ``--mission`` the same
  rule picks among the eligible earlier frames (a rejected frame there gets a new id and
  predicts nothing), and the frames' dead-reckoned positions for the dead-reckoning gate
  (``htm.dr_gate.enabled``, :mod:`services.htm.geometry`) come from the mission's own DVL, IMU and
  depth through the ``robot_state`` node, as in a run.  Image sets have no positions: the
  gate checks nothing there.
* ``htm_lvc_accepted`` -- (image sets) ``htm_lvc`` with the accepted queries only: the
  decisions at the configured gates, ranked by their confidence (the curve that stops at the
  accepted share of the queries).
* ``htm_descriptor`` -- R(D_q, D_r) (Eq. 4.7) between the TM descriptors of every query
  and reference frame: the HTM's similarity without the LVC decision.
* ``sdr_seqmem``, ``no_tm``, ``no_dr_gate``, ``no_seqmem``, ``sp_tm``, ``sdr_seqmem_f1``,
  ``sdr_seqmem_cal``, ``new_places`` -- ``htm_lvc`` of the named chains of :mod:`services.htm.chains` (the
  configured ``htm`` section with the chain's overrides; the module says what each changes),
  run on the same SDRs in the same run, printed beside the default (``--no-chains`` skips
  them): ``sdr_seqmem`` is the default without the SP + TM and the dead-reckoning gate (fused
  SDR, sequence memory, no SP, no TM), ``no_tm`` / ``no_dr_gate`` / ``no_seqmem`` the default
  without one part, ``sp_tm`` the SP's columns as the descriptor, ``new_places`` the default
  keeping only the frames that are no revisit of an older place.

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
                  "htm_lvc": {...}, "htm_lvc_accepted": {...}, "htm_descriptor": {...}},
     "n_ref": .., "n_query": .., "n_query_with_gt": .., "weights": "seeded" | "<path>",
     "backbone": "shufflenetv2", "embedding_dim": .., "embedding_norm": "none|running|fixed",
     "sdr_bits": .., "sdr_length": .., "ground_truth": "file name +-N" | "<gt file>",
     "sdr_overlap": {"same_place": .., "different_place": ..},   # mean |A_q & A_r| / 2k (random: s = 0.25)
     "n_lvc": .., "htm_query_matched": .., "decisions": {"gate": .., "tm": .., "seqmem": .., "prior": .., "new": ..},
     "chains": {"sdr_seqmem": {"n_lvc": .., "htm_query_matched": .., "decisions": {..}}, "no_tm": {...},
                "no_dr_gate": {...}, "no_seqmem": {...}, "sp_tm": {...}, "sdr_seqmem_f1": {...},
                "sdr_seqmem_cal": {...}, "new_places": {...}},
     "seconds": {"embed": .., "htm": ..}}   # htm: the default and the chains

and with ``--mission``::

    {"mission": "<file>", "backbone": .., "embedding_norm": .., "n_frames": .., "n_revisit_frames": ..,
     "min_gap_m": .., "sdr_overlap": {"same_place": .., "different_place": ..} (camera SDRs, candidate pairs),
     "fused_bits_mean": .., "encoder_counters": {..},
     "lvc_recall": .., "lvc_precision": .., "n_claimed_revisits": .., "n_correct_claims": ..,
     "n_lvc": .., "tm_anomaly_mean": .., "sp_columns_used": ..,   # the last 7 without --no-htm
     "lvc_pair_precision": .., "lvc_pair_recall": ..,   # frame pairs with the same id (eval.frontend.lvc_pair_metrics)
     "decisions": {"gate": .., "tm": .., "seqmem": .., "prior": .., "new": ..}, "tm_decision_share": ..,
     "frames_stored": ..,   # frames the sequence memory holds at the end (htm.seqmem.store; 0 without it)
     "chains": {"sdr_seqmem": {<the LVC figures above>}, "no_tm": {...}, "no_dr_gate": {...},
                "no_seqmem": {...}, "sp_tm": {...}, "sdr_seqmem_f1": {...}, "sdr_seqmem_cal": {...},
                "new_places": {...}},   # without --no-htm / --no-chains
     "dr_positions": .., # frames with a dead-reckoned position (robot_state over the mission)
     "lvc_run_length": {"median": .., "mean": .., "frames_in_runs_ge3": ..},  # runs of identical consecutive ids
     "modalities": {"fused_<fusion_mode>": {...}, "camera": {...}, "sonar": {...}},  # without --no-htm
     "matchers": {"cnn_cosine", "seq_cosine", "patchnorm_sad", "cnn_cosine_standardized", "lsbh_overlap",
                  "lsbh_fused_overlap", "htm_lvc", "htm_descriptor", "sdr_seqmem", "no_tm", "no_dr_gate",
                  "no_seqmem", "sp_tm", "sdr_seqmem_f1", "sdr_seqmem_cal", "new_places": {...}},
     "seconds": {"embed": .., "htm": ..}, "weights": .., "embedding_dim": ..}

Progress goes to stderr.  Returns 0, or 2 on bad arguments / inputs (message on stderr).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from eval.baselines import SEQ_LENGTH, patch_normalise, sad_similarity, sequence_similarity
from eval.results import ImageSetChain, ImageSetHtm, ImageSetResult, MissionResult
from eval.vpr_htm import (
    DECISION_KINDS,
    HtmPass,
    decision_kind,
    htm_similarities,
    image_set_standardizer,
    match_confidence,
    run_htm,
    run_length_stats,
)
from eval.vpr_metrics import (
    IMAGE_SUFFIXES,
    VprInputError,
    best_matches,
    cosine_similarity,
    ground_truth_by_name,
    ground_truth_from_file,
    load_sequence,
    overlap_similarity,
    overlap_stats,
    pr_curve,
    vpr_metrics,
)
from eval.vpr_mission import (
    MissionStreams,
    encode_mission,
    lvc_revisit_scores,
    mission_htm,
    run_mission,
    score_mission,
)

if TYPE_CHECKING:
    from services.encoder.config import EncoderConfig
    from services.encoder.encoder import MultimodalEncoder
    from services.encoder.standardize import EmbeddingStandardizer
    from system.config import PoseidonConfig

__all__ = ["evaluate_image_sets", "evaluate_mission", "input_errors", "pr_curve", "vpr_metrics", "best_matches", "load_sequence", "ground_truth_by_name",
           "ground_truth_from_file", "overlap_similarity", "cosine_similarity",
           # the building blocks live in eval.vpr_metrics, eval.vpr_htm and eval.vpr_mission; these names
           # stay importable from here
           "IMAGE_SUFFIXES", "VprInputError", "overlap_stats", "run_htm", "match_confidence", "htm_similarities",
           "image_set_standardizer", "DECISION_KINDS", "decision_kind", "run_length_stats", "MissionStreams",
           "run_mission", "encode_mission", "mission_htm", "score_mission", "lvc_revisit_scores"]


def input_errors() -> tuple[type[Exception], ...]:
    """The errors that mean bad input (configuration, folders, weights, statistics): ``poseidon vpr``
    reports them with exit code 2."""
    from common.config import ConfigError
    from services.encoder.backbones import WeightsError
    from services.encoder.lsbh import LsbhError
    from services.encoder.standardize import StandardizerError

    return (ConfigError, VprInputError, WeightsError, LsbhError, StandardizerError)


def evaluate_mission(mission: str | Path, cfg: PoseidonConfig, enc_cfg: EncoderConfig, min_gap_m: float | None = None,
                     htm: bool = True, chains: tuple[str, ...] = ()) -> MissionResult:
    """The figures of one recording: :class:`eval.results.MissionResult` (each key with its unit
    there; the ``--mission`` JSON of the module docstring), :func:`run_mission` with the mission,
    backbone and embedding standardisation named first.

    :param min_gap_m: travel before an earlier frame is a revisit candidate (m; None: the recording's)
    :param htm: run the HTM (the LVC figures, ``modalities``); ``chains``: the named chains beside it
    :raises: one of :func:`input_errors` on bad input
    """
    scores = run_mission(mission, cfg, enc_cfg, min_gap_m, htm, chains)
    named: MissionResult = {"mission": str(mission), "backbone": enc_cfg.cnn_backbone,
                            "embedding_norm": enc_cfg.embedding_norm.mode, **scores}
    return named


@dataclass
class _ImageSets:
    """The two image folders of a run, their ground truth and what the encoder made of them."""

    ref_names: list[str]
    ref_imgs: list[np.ndarray]
    q_names: list[str]
    q_imgs: list[np.ndarray]
    gt: list[list[int]]
    gt_desc: str
    encoder: MultimodalEncoder
    standardizer: EmbeddingStandardizer | None
    y_ref: list[np.ndarray]
    y_q: list[np.ndarray]
    z_ref: list[np.ndarray]
    z_q: list[np.ndarray]
    s_ref: list[np.ndarray]
    s_q: list[np.ndarray]
    t_embed: float


def _encode_image_sets(ref: str | Path, query: str | Path, enc_cfg: EncoderConfig, limit: int = 0,
                       gt_file: str | Path = "", tolerance: int = 0, save_norm: str | Path | None = None
                       ) -> _ImageSets:
    """Read both folders and the ground truth; embed, standardise and hash every frame."""
    from services.encoder.encoder import MultimodalEncoder

    ref_names, ref_imgs = load_sequence(ref, limit)
    q_names, q_imgs = load_sequence(query, limit)
    if gt_file:
        gt = ground_truth_from_file(gt_file, len(q_names), len(ref_names))
        gt_desc = str(gt_file)
    else:
        gt = ground_truth_by_name(q_names, ref_names, tolerance)
        gt_desc = f"file name +-{tolerance}"
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
    z_ref = encoder.standardize_sequence("camera", y_ref)   # the reference as the encoder node sees it
    z_q = [encoder.standardize("camera", y, update=False) for y in y_q]
    s_ref = [encoder.lsbh("camera").encode(z) for z in z_ref]
    s_q = [encoder.lsbh("camera").encode(z) for z in z_q]
    if save_norm and st is not None:
        st.save(Path(save_norm))
    t_embed = time.perf_counter() - t0
    return _ImageSets(ref_names, ref_imgs, q_names, q_imgs, gt, gt_desc, encoder, st, y_ref, y_q, z_ref, z_q,
                      s_ref, s_q, t_embed)


def _image_set_similarities(sets: _ImageSets) -> dict[str, np.ndarray]:
    """The matchers without the HTM (see the module doc), query x reference."""
    cos = cosine_similarity(np.stack(sets.y_q), np.stack(sets.y_ref))
    sims = {
        "cnn_cosine": cos,
        "seq_cosine": sequence_similarity(cos, SEQ_LENGTH),
        "patchnorm_sad": sad_similarity(np.stack([patch_normalise(im) for im in sets.q_imgs]),
                                        np.stack([patch_normalise(im) for im in sets.ref_imgs])),
        "lsbh_overlap": overlap_similarity(sets.s_q, sets.s_ref),
    }
    if sets.standardizer is not None:
        sims["cnn_cosine_standardized"] = cosine_similarity(np.stack(sets.z_q), np.stack(sets.z_ref))
    return sims


def _image_set_htm(cfg: PoseidonConfig, sets: _ImageSets, length: int, chains: tuple[str, ...],
                   sims: dict[str, np.ndarray], query_learning: bool = False) -> ImageSetHtm:
    """The default HTM and the named chains over the SDRs: adds their matchers to ``sims``,
    returns their JSON figures (``n_lvc``, ``htm_query_matched``, ``decisions``, ``chains``)."""
    from services.htm.chains import chain_config

    default = run_htm(cfg.htm, sets.s_ref, sets.s_q, length, query_learning)
    sims["htm_lvc"], sims["htm_descriptor"] = htm_similarities(default.ref, default.query)
    accepted = sims["htm_lvc"].copy()
    accepted[[i for i, o in enumerate(default.query) if o[0] < 0]] = -np.inf
    sims["htm_lvc_accepted"] = accepted
    per_chain: dict[str, ImageSetChain] = {}
    for cname in chains:
        c = run_htm(chain_config(cfg.htm, cname), sets.s_ref, sets.s_q, length, query_learning)
        sims[cname] = htm_similarities(c.ref, c.query)[0]
        per_chain[cname] = _chain_figures(c)
    return {**_chain_figures(default), "chains": per_chain}


def _chain_figures(p: HtmPass) -> ImageSetChain:
    """LVC ids, accepted queries and decisions per rule of one HTM pass over image sets."""
    return {"n_lvc": len(p.htm.lvc), "htm_query_matched": sum(1 for o in p.query if o[0] >= 0),
            "decisions": p.query_decisions}


def evaluate_image_sets(ref: str | Path, query: str | Path, cfg: PoseidonConfig, enc_cfg: EncoderConfig, *,
                        limit: int = 0, gt_file: str | Path = "", tolerance: int = 0,
                        save_norm: str | Path | None = None, htm: bool = True, chains: tuple[str, ...] = (),
                        query_learning: bool = False) -> ImageSetResult:
    """The figures of the ``query`` folder against the ``ref`` folder: :class:`eval.results.ImageSetResult`
    (each key with its unit there; the image-set JSON of the module docstring; ``matchers``: per
    matcher its :func:`vpr_metrics`).

    :param limit: first N frames of each folder (0: all)
    :param gt_file: VPR-Bench ground truth .npy ("": same file name, ``tolerance`` frames either side)
    :param save_norm: write the camera embedding statistics here
    :param htm: run the HTM matchers; ``chains``: the named chains beside the default
    :param query_learning: HTM learning stays on during the query pass
    :raises: one of :func:`input_errors` on bad input
    """
    sets = _encode_image_sets(ref, query, enc_cfg, limit, gt_file, tolerance, save_norm)
    length = enc_cfg.sp_columns
    sims = _image_set_similarities(sets)
    htm_figures: ImageSetHtm | None = None
    t_htm = 0.0
    if htm:
        t1 = time.perf_counter()
        htm_figures = _image_set_htm(cfg, sets, length, chains, sims, query_learning)
        t_htm = time.perf_counter() - t1
    gt, encoder = sets.gt, sets.encoder
    metrics = {name: vpr_metrics(s, gt) for name, s in sims.items()}
    result: ImageSetResult = {
        "matchers": metrics,
        "n_ref": len(sets.ref_names), "n_query": len(sets.q_names), "n_query_with_gt": sum(1 for g in gt if g),
        "weights": encoder.weights, "backbone": enc_cfg.cnn_backbone, "embedding_dim": encoder.dim,
        "embedding_norm": enc_cfg.embedding_norm.mode,
        "sdr_bits": 2 * encoder.lsbh("camera").k, "sdr_length": length, "ground_truth": sets.gt_desc,
        "sdr_overlap": overlap_stats(sims["lsbh_overlap"], gt),
        "seconds": {"embed": round(sets.t_embed, 2), "htm": round(t_htm, 2)},
    }
    if htm_figures is not None:
        result["n_lvc"], result["htm_query_matched"] = htm_figures["n_lvc"], htm_figures["htm_query_matched"]
        result["decisions"], result["chains"] = htm_figures["decisions"], htm_figures["chains"]
    return result
