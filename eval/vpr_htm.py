"""``poseidon vpr`` HTM matchers: :class:`services.htm.pipeline.NeocortexHtm` over the reference
then the query SDRs of an image-set run, the ``htm_lvc`` / ``htm_descriptor`` similarities,
how each frame got its id, and the camera standardiser of an image-set run
(:mod:`eval.vpr` states the definitions)."""
from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from tqdm import tqdm

from eval.results import RunLengthStats
from eval.vpr_metrics import overlap_similarity

if TYPE_CHECKING:
    from services.encoder.config import EncoderConfig
    from services.encoder.standardize import EmbeddingStandardizer
    from services.htm.config import HtmConfig
    from services.htm.lvc import LvcResult
    from services.htm.pipeline import NeocortexHtm

#: one HTM step of an evaluation: (LVC id, confidence, descriptor D_t, memory frame or -1); see :func:`_htm_row`
HtmRow = tuple[int, float, np.ndarray, int]


class HtmPass(NamedTuple):
    """The rows of the reference and the query pass (:func:`run_htm`), the HTM after them and
    the query frames per decision rule (:data:`DECISION_KINDS`)."""

    ref: list[HtmRow]
    query: list[HtmRow]
    htm: NeocortexHtm
    query_decisions: dict[str, int]


def run_htm(htm_cfg: HtmConfig, ref_sdrs: Sequence[np.ndarray], query_sdrs: Sequence[np.ndarray], length: int,
            query_learning: bool = False) -> HtmPass:
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
    ref_out: list[HtmRow] = []
    q_out: list[HtmRow] = []
    for bits in tqdm(ref_sdrs, desc="htm ref", file=sys.stderr, leave=False):
        r = htm.step(np.asarray(bits, dtype=np.uint32))
        ref_out.append(_htm_row(htm, r))
    htm.reset_sequence()
    learn = cfg.learning and query_learning
    decisions = {k: 0 for k in DECISION_KINDS}
    for bits in tqdm(query_sdrs, desc="htm query", file=sys.stderr, leave=False):
        r = htm.step(np.asarray(bits, dtype=np.uint32), learn=learn, store=False)
        q_out.append(_htm_row(htm, r))
        decisions[decision_kind(r)] += 1
    return HtmPass(ref_out, q_out, htm, decisions)


def match_confidence(htm: NeocortexHtm, r: LvcResult) -> float:
    """The score a query's LVC match is ranked by: with the sequence memory
    (``htm.seqmem.length`` > 0) the sequence margin S* - S_2 at the predicted frame, else R."""
    return float(r.seq_margin) if htm.seqmem is not None else float(r.rate)


def _htm_row(htm: NeocortexHtm, r: LvcResult) -> HtmRow:
    """(LVC id, confidence, D_t, memory frame the id was read from -- or, for a query without
    an id, the sequence memory's candidate -- or -1) of one step."""
    # a query no rule accepted (id -1) keeps the sequence memory's candidate j* and its margin: the
    # PR curve sweeps the decision threshold (eval.vpr, htm_lvc)
    frame = int(r.frame) if (htm.seqmem is not None and r.frame >= 0
                             and (r.lvc_id < 0 or int(htm.seqmem.ids[r.frame]) == r.lvc_id)) else -1
    return int(r.lvc_id), match_confidence(htm, r), np.asarray(htm.last_descriptor, dtype=np.int64).copy(), frame


def htm_similarities(ref_out: Sequence[HtmRow], query_out: Sequence[HtmRow]) -> tuple[np.ndarray, np.ndarray]:
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


def image_set_standardizer(enc_cfg: EncoderConfig, dim: int, y_ref: Sequence[np.ndarray]
                           ) -> EmbeddingStandardizer | None:
    """The camera standardiser of an image-set run, or None for ``embedding_norm`` none.

    ``running``: in memory (nothing read from or written to ``encoder.embedding_norm.path``),
    estimated on the reference sequence in order exactly as the encoder node does (the first
    frames, held until ``encoder.embedding_norm.hold`` are in, standardised with those statistics, then
    each frame with the frames before it until the warm-up ends:
    :meth:`MultimodalEncoder.standardize_sequence`); the queries are then
    standardised with the statistics as they stand, without updating them (like the HTM
    query pass).  ``fixed``: fitted on the whole reference set.
    """
    from services.encoder.standardize import EmbeddingStandardizer

    mode = enc_cfg.embedding_norm.mode
    if mode == "none":
        return None
    if mode == "fixed":
        return EmbeddingStandardizer.fitted(np.stack(y_ref), enc_cfg.embedding_norm.scale)
    return EmbeddingStandardizer(dim, "running", enc_cfg.embedding_norm.warmup, enc_cfg.embedding_norm.rate,
                                 enc_cfg.embedding_norm.scale, None)



DECISION_KINDS = ("gate", "tm", "seqmem", "prior", "new")


def decision_kind(r: LvcResult) -> str:
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


def run_length_stats(ids: np.ndarray) -> RunLengthStats:
    """Lengths of the runs of identical consecutive LVC ids: median, mean, and the share of frames
    in runs of >= 3 (what the VPR Guard needs: the same id >= 3 times within 26 frames)."""
    ids = np.asarray(ids)
    if ids.size == 0:
        return {"median": 0.0, "mean": 0.0, "frames_in_runs_ge3": 0.0}
    cuts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1], True])
    runs = np.diff(cuts)
    return {"median": float(np.median(runs)), "mean": round(float(runs.mean()), 2),
            "frames_in_runs_ge3": round(float(runs[runs >= 3].sum() / ids.size), 4)}
