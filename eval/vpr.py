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
  A query that no rule accepted predicts the frame j* where the sequence memory's best
  diagonal ended, scored by its margin below the gate: the precision-recall curve
  sweeps the decision threshold, as every other matcher's curve sweeps its own score, and the
  configured gates are one point on it (``htm_query_matched`` counts the accepted queries;
  without the sequence memory a rejected query predicts nothing).  On ``--mission`` the same
  rule picks among the eligible earlier frames (a rejected frame there gets a new id and
  predicts nothing), and the frames' dead-reckoned positions for the dead-reckoning gate
  (``htm.sv_dr_gate``, :mod:`services.htm.geometry`) come from the mission's own DVL, IMU and
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
     "frames_stored": ..,   # frames the sequence memory holds at the end (htm.sv_seqmem_store; 0 without it)
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

import argparse
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from eval.baselines import SEQ_LENGTH, patch_normalise, sad_similarity, sequence_similarity
from eval.vpr_htm import (
    DECISION_KINDS,
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

__all__ = ["main", "pr_curve", "vpr_metrics", "best_matches", "load_sequence", "ground_truth_by_name",
           "ground_truth_from_file", "overlap_similarity", "cosine_similarity",
           # the building blocks live in eval.vpr_metrics, eval.vpr_htm and eval.vpr_mission; these names
           # stay importable from here
           "IMAGE_SUFFIXES", "VprInputError", "overlap_stats", "run_htm", "match_confidence", "htm_similarities",
           "image_set_standardizer", "DECISION_KINDS", "decision_kind", "run_length_stats", "MissionStreams",
           "run_mission", "encode_mission", "mission_htm", "score_mission", "lvc_revisit_scores"]

log = logging.getLogger(__name__)




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
                    help="do not run the named chains (services/htm/chains.py: sdr_seqmem, no_tm, no_dr_gate, no_seqmem, sp_tm, sdr_seqmem_f1, "
                         "sdr_seqmem_cal, new_places) beside the default")
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


def _errors() -> tuple[type[Exception], ...]:
    """The input errors ``poseidon vpr`` reports as exit code 2."""
    from common.config import ConfigError
    from services.encoder.backbones import WeightsError
    from services.encoder.lsbh import LsbhError
    from services.encoder.standardize import StandardizerError

    return (ConfigError, VprInputError, WeightsError, LsbhError, StandardizerError)


def _load_configs(args: argparse.Namespace) -> tuple[PoseidonConfig, EncoderConfig]:
    """The run configuration and its encoder section with the command line's overrides."""
    from system.config import load_config

    cfg = load_config(args.config, args.overrides)
    enc_cfg = cfg.encoder
    upd: dict[str, Any] = {}
    if args.weights is not None:
        upd["weights_path"] = args.weights
    if args.backbone is not None:
        upd["cnn_backbone"] = args.backbone
    if enc_cfg.embedding_norm != "fixed":
        upd["embedding_norm_path"] = ""  # running statistics start fresh, in memory, every run
    return cfg, enc_cfg.model_copy(update=upd)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``poseidon vpr`` (see the module docstring)."""
    args = _parser().parse_args(argv)
    errors = _errors()
    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(levelname)s %(message)s")
    if args.mission is None and (args.ref is None or args.query is None):
        print("poseidon vpr: give --ref DIR and --query DIR, or --mission FILE.mcap", file=sys.stderr)
        return 2
    if args.mission is not None and (args.ref is not None or args.query is not None):
        print("poseidon vpr: --mission excludes --ref/--query", file=sys.stderr)
        return 2
    from services.htm.chains import CHAINS
    chains = () if (args.no_htm or args.no_chains) else tuple(CHAINS)
    try:
        cfg, enc_cfg = _load_configs(args)
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    if args.mission is not None:
        return _main_mission(args, cfg, enc_cfg, chains, errors)
    return _main_image_sets(args, cfg, enc_cfg, chains, errors)


def _main_mission(args: argparse.Namespace, cfg: PoseidonConfig, enc_cfg: EncoderConfig,
                  chains: tuple[str, ...], errors: tuple[type[Exception], ...]) -> int:
    """``poseidon vpr --mission``: figures of one recording, printed as a table or JSON."""
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


def _encode_image_sets(args: argparse.Namespace, enc_cfg: EncoderConfig) -> _ImageSets:
    """Read both folders and the ground truth; embed, standardise and hash every frame."""
    from services.encoder.encoder import MultimodalEncoder

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
    z_ref = encoder.standardize_sequence("camera", y_ref)   # the reference as the encoder node sees it
    z_q = [encoder.standardize("camera", y, update=False) for y in y_q]
    s_ref = [encoder.lsbh("camera").encode(z) for z in z_ref]
    s_q = [encoder.lsbh("camera").encode(z) for z in z_q]
    if args.save_norm and st is not None:
        st.save(Path(args.save_norm))
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


def _image_set_htm(args: argparse.Namespace, cfg: PoseidonConfig, sets: _ImageSets, length: int,
                   chains: tuple[str, ...], sims: dict[str, np.ndarray]) -> dict[str, Any]:
    """The default HTM and the named chains over the SDRs: adds their matchers to ``sims``,
    returns their JSON figures (``n_lvc``, ``htm_query_matched``, ``decisions``, ``chains``)."""
    ref_out, q_out, htm = run_htm(cfg.htm, sets.s_ref, sets.s_q, length, args.htm_query_learning)
    sims["htm_lvc"], sims["htm_descriptor"] = htm_similarities(ref_out, q_out)
    accepted = sims["htm_lvc"].copy()
    accepted[[i for i, o in enumerate(q_out) if o[0] < 0]] = -np.inf
    sims["htm_lvc_accepted"] = accepted
    result: dict[str, Any] = {}
    result["n_lvc"] = len(htm.lvc)
    result["htm_query_matched"] = sum(1 for o in q_out if o[0] >= 0)
    result["decisions"] = htm.query_decisions
    from services.htm.chains import chain_config
    result["chains"] = {}
    for cname in chains:
        c_ref, c_q, c_htm = run_htm(chain_config(cfg.htm, cname), sets.s_ref, sets.s_q, length,
                                    args.htm_query_learning)
        sims[cname] = htm_similarities(c_ref, c_q)[0]
        result["chains"][cname] = {"n_lvc": len(c_htm.lvc), "htm_query_matched": sum(1 for o in c_q if o[0] >= 0),
                                   "decisions": c_htm.query_decisions}
    return result


def _main_image_sets(args: argparse.Namespace, cfg: PoseidonConfig, enc_cfg: EncoderConfig,
                     chains: tuple[str, ...], errors: tuple[type[Exception], ...]) -> int:
    """``poseidon vpr --ref DIR --query DIR``: figures of the query folder against the reference."""
    try:
        sets = _encode_image_sets(args, enc_cfg)
    except errors as exc:
        print(f"poseidon vpr: {exc}", file=sys.stderr)
        return 2
    length = enc_cfg.sp_columns
    sims = _image_set_similarities(sets)
    result: dict[str, Any] = {}
    t_htm = 0.0
    if not args.no_htm:
        t1 = time.perf_counter()
        result = _image_set_htm(args, cfg, sets, length, chains, sims)
        t_htm = time.perf_counter() - t1
    gt, encoder = sets.gt, sets.encoder
    metrics = {name: vpr_metrics(s, gt) for name, s in sims.items()}
    result = {
        "matchers": metrics,
        "n_ref": len(sets.ref_names), "n_query": len(sets.q_names), "n_query_with_gt": sum(1 for g in gt if g),
        "weights": encoder.weights, "backbone": enc_cfg.cnn_backbone, "embedding_dim": encoder.dim,
        "embedding_norm": enc_cfg.embedding_norm,
        "sdr_bits": 2 * encoder.lsbh("camera").k, "sdr_length": length, "ground_truth": sets.gt_desc,
        "sdr_overlap": overlap_stats(sims["lsbh_overlap"], gt),
        **result,
        "seconds": {"embed": round(sets.t_embed, 2), "htm": round(t_htm, 2)},
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        _print_table(f"VPR {args.query} vs {args.ref}: {result['n_query']} queries, {result['n_ref']} references, "
                     f"backbone {result['backbone']} ({result['weights']} weights), ground truth {sets.gt_desc}, "
                     f"embedding_norm {enc_cfg.embedding_norm}", metrics)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
