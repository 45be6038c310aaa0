"""NeocortexHtm: fused SDR -> SP -> TM -> descriptor D_t -> LVC id (Section 4.2.2, Fig. 4.2).

``NeocortexHtm(cfg).step(active)`` takes the sorted active indices of one fused SDR
(Eq. 4.3; ``cfg.input_size`` bits) and returns an :class:`LvcResult` (id, R, is_new, I).
``describe(active)`` returns D_t only (e.g. to build a similarity matrix with
:func:`descriptor_similarity`), ``step(active, store=False)`` matches without creating ids,
``reset_sequence()`` forgets the temporal context between two sequences.
``descriptor.source`` picks what D_t is built from: ``tm`` TM winner cells (default),
``sp`` SP active columns, ``sdr`` the fused SDR itself (SP/TM are then not run). In ``tm``
mode ``descriptor.tm_bits`` chooses the bit space: ``cells`` (winner cell indices, the dissertation's
reading) or ``columns`` (the winners' columns, default: the same pooling over the window,
but a place seen in another temporal context keeps its bits).
``sp.learn_steps`` N > 0 lets the SP learn (permanences, duty cycles, boost factors) during
its first N learning steps only and then freezes it, so a place maps to the same columns for
the rest of the mission (a continually learning SP moves the columns of places seen once and
the stored prototypes stop matching); the TM keeps learning.
``lvc.require_multimodal`` (Table 4.1) adds a per-modality check to an accepted match: the
camera (sonar) SDR of the frame must overlap the camera (sonar) SDR of the frame that
created the matched LVC by R = |A & B| / |A| >= ``lvc.min_camera_score`` (``lvc.min_sonar_score``),
for every modality present in both; otherwise Eq. 4.10 creates a new id.  A modality
missing on either side is not checked.  Pass the per-modality SDRs to ``step`` as
``modalities={"camera": ..., "sonar": ...}``.
Place-sequence prior (``lvc.successor_threshold`` > 0, ours): the ids of consecutive
frames teach a successor graph (id a then id b != a: b is a successor of a).  When the best
prototype l* fails Eq. 4.9, the prototypes up to ``lvc.successor_hops`` successors ahead of the
previous frame's id are tried with the gate ``lvc.successor_threshold`` (on R and F1, with
I >= I_min): a revisit that has locked onto an earlier stretch keeps following it through
frames that alone would be too weak, as a sequence memory over places.  Query-only steps
(``store=False``) use the graph without adding to it.
Sequence memory (``seqmem.length`` K > 0, ours; :mod:`services.htm.sequence`):
every frame's D_t is kept with the id it was given, and each frame scores the SeqSLAM-like
diagonals of its last K frames against that memory (causal).  The decision of a frame is:
l* when it passes Eq. 4.9 (+ F1 gate); else the id of the stored frame j* where the best
diagonal ends, when its score S* >= ``seqmem.threshold`` and S* minus the best score
ending more than K frames away >= ``seqmem.margin`` (so a revisit whose frames each look
different -- Nordland winter vs summer -- is recognised by their order); else the
place-sequence prior; else Eq. 4.10.  ``LvcResult.by_sequence/frame/seq_score/seq_margin``
report it.  ``seqmem.store`` ``new_places`` (or ``every_frame`` once the memory holds
``seqmem.every_frame_limit`` frames) keeps a revisit of a place older than the last ``seqmem.exclude``
frames out of the memory and the TM frame index (``frames_not_stored``): they grow with the places seen.
TM decision (``tm.decide``, ours; :mod:`services.htm.tm_match`): with
``descriptor.source`` ``sp`` (or ``sdr``) the SP and a TM over the ``tm.input_columns`` most
strongly driven SP columns run beside the descriptor; the cells the TM predicted correctly
vote for the stored frames where they won, and when the best frame's votes are >=
``tm.decide_share`` of the TM's columns its id is taken (after Eq. 4.9, before the sequence
match; ``LvcResult.by_tm/tm_frame/tm_share``).  ``sp.overlap_norm_steps`` N > 0: the SP ranks
standardised overlaps (:mod:`services.htm.spatial_pooler`); named chains: :mod:`services.htm.chains`.
Sequence-match checks (ours; off by default, used by the ``sdr_seqmem_f1`` /
``sdr_seqmem_cal`` chains): ``seqmem.override`` -- an Eq. 4.9 match whose l* was created
by a frame that is no sequence candidate (the current traversal's last ``seqmem.exclude``
frames: the pass's own new id, no revisit) yields to a sequence (or TM) decision, so a revisit
the sequence memory recognises a few frames late takes over the new ids its first frames made;
``seqmem.min_f1`` -- the sequence match (the margin gate above, which replaces nothing of
Eqs. 4.6-4.10) also needs the frame's own F1(D_t, D_j*) (the F1 of the Eq. 4.9 gate, at the
stored frame j* where the diagonal ends) >= a constant; ``seqmem.f1_quantile`` q > 0 -- the
self-calibrated form: F1(D_t, D_j*) >= the q-quantile of F1(D_t', D_j*') over the traversal's
*confident* sequence matches t' so far (margin >= ``seqmem.confident_margin``; until
``seqmem.calib_warmup`` of them the confident margin is required instead), read from the
traversal itself (:mod:`services.htm.calibrate`): a level shift of every F1 moves the threshold
with it.  The calibration sample restarts with ``reset_sequence()`` and is saved with the state.
``sp.enabled: false`` feeds the fused SDR to the TM (needs ``sp.columns == input_size``). ``save(path)`` / ``NeocortexHtm.load(path, cfg)`` persist the
whole state (SP, TM, descriptor history, LVC prototypes) to an ``.npz``; a loaded object
continues exactly as the saved one would have, but for the dead-reckoning gate's stored
positions, which a loaded map forgets (they are in the earlier run's odometry frame).
Dead-reckoning gate (``dr_gate.enabled``, ours): every revisit claim (l*, TM, sequence,
prior) must pass Eq. G.1 with the frame's position passed to ``step``; a sequence match it
checked decides at ``dr_gate.seqmem_threshold``/``seqmem_margin`` (:mod:`services.htm.geometry`).
"""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from common.config import RENAMED_KEYS
from services.htm.calibrate import RunningQuantile
from services.htm.config import HtmConfig
from services.htm.descriptor import DescriptorBuilder
from services.htm.geometry import DeadReckoningGate
from services.htm.lvc import LvcMatcher, LvcResult, overlap_scores
from services.htm.multimodal import ModalityPrototypes
from services.htm.sequence import SequenceMatcher, SequenceScore
from services.htm.spatial_pooler import SpatialPooler
from services.htm.temporal_memory import TemporalMemory
from services.htm.tm_match import TmFrameIndex

__all__ = ["NeocortexHtm", "LvcResult", "descriptor_similarity"]

STATE_VERSION = 1
T = TypeVar("T")
# configuration fields that change the shape or meaning of the saved state
_STRUCTURAL = ("input_size", "sp.enabled", "tm.decide", "sp.columns", "sp.potential_radius", "sp.potential_pct",
               "sp.overlap_norm_steps", "tm.cells_per_column", "tm.max_synapses_per_segment", "descriptor.source",
               "descriptor.tm_window", "descriptor.tm_bits", "descriptor.theta_rho", "seed")


def _need(part: T | None, what: str) -> T:
    """``part``, or a RuntimeError naming the setting that leaves it out."""
    if part is None:
        raise RuntimeError(f"NeocortexHtm: this configuration {what}")
    return part


def descriptor_similarity(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """I (Eq. 4.6), R = I/|a| (Eq. 4.7), IoU and F1 between two descriptors."""
    return overlap_scores(a, b)


class NeocortexHtm:
    """The HTM half of the neocortical front-end for one vehicle."""

    def __init__(self, cfg: HtmConfig):
        self.cfg = cfg
        self.mode = cfg.descriptor.source
        self.tm_decides = self.mode in ("sp", "sdr") and cfg.tm.decide and cfg.sp.enabled
        run_sp = cfg.sp.enabled and (self.mode in ("tm", "sp") or self.tm_decides)
        run_tm = self.mode == "tm" or self.tm_decides
        if self.mode == "sp" and not cfg.sp.enabled:
            raise ValueError("htm.descriptor.source 'sp' needs htm.sp.enabled true")
        if run_tm and not cfg.sp.enabled and cfg.sp.columns != cfg.input_size:
            raise ValueError(f"htm.sp.enabled false feeds the SDR to the TM: htm.sp.columns ({cfg.sp.columns}) "
                             f"must equal htm.input_size ({cfg.input_size})")
        self.sp = SpatialPooler(
            cfg.input_size, cfg.sp.columns, cfg.sp.num_active_columns, cfg.sp.potential_radius,
            cfg.sp.potential_pct, cfg.sp.syn_perm_active_inc, cfg.sp.syn_perm_inactive_dec,
            cfg.sp.syn_perm_connected, cfg.sp.boost_strength, cfg.sp.duty_cycle_period,
            cfg.sp.min_pct_overlap_duty_cycle, cfg.seed, cfg.sp.overlap_norm_steps) if run_sp else None
        self.tm = TemporalMemory(
            cfg.sp.columns, cfg.tm.cells_per_column, cfg.tm.activation_threshold, cfg.tm.min_threshold,
            cfg.tm.initial_permanence, cfg.tm.connected_permanence, cfg.tm.permanence_increment,
            cfg.tm.permanence_decrement, cfg.tm.predicted_segment_decrement, cfg.tm.max_new_synapse_count,
            cfg.tm.max_segments_per_cell, cfg.tm.max_synapses_per_segment, cfg.seed + 1, cfg.tm.max_synapses) if run_tm else None
        self.tm_columns = cfg.descriptor.tm_bits == "columns"
        n_tm_bits = cfg.sp.columns if self.tm_columns else cfg.sp.columns * cfg.tm.cells_per_column
        n_bits = {"tm": n_tm_bits, "sp": cfg.sp.columns, "sdr": cfg.input_size}[self.mode]
        self.descriptor = DescriptorBuilder(self.mode, n_bits, cfg.descriptor.tm_window, cfg.descriptor.tm_topk,
                                            cfg.descriptor.interval_mode, cfg.descriptor.theta_alpha, cfg.descriptor.theta_rho,
                                            cfg.descriptor.max_bits, cfg.seed + 2)
        tau_r = cfg.lvc.tm_match_threshold if self.mode == "tm" else cfg.lvc.match_threshold
        self.lvc = LvcMatcher(n_bits, cfg.lvc.min_intersection, tau_r, cfg.lvc.f1_gate,
                              cfg.lvc.min_f1, cfg.lvc.iou_tiebreak)
        self.multimodal = ModalityPrototypes({"camera": cfg.lvc.min_camera_score, "sonar": cfg.lvc.min_sonar_score}) \
            if cfg.lvc.require_multimodal else None
        self.seqmem = SequenceMatcher(n_bits, cfg.seqmem.length, cfg.seqmem.velocities, cfg.seqmem.exclude,
                                      cfg.seqmem.column_norm) if cfg.seqmem.length > 0 else None
        self.tm_index = TmFrameIndex(cfg.sp.columns * cfg.tm.cells_per_column) if self.tm_decides else None
        self.dr_gate = DeadReckoningGate(cfg.dr_gate.min_m, cfg.dr_gate.drift, cfg.dr_gate.jump_m,
                                         cfg.dr_gate.min_path_m) if cfg.dr_gate.enabled and self.seqmem is not None else None
        self.dr_rejections = 0               # claims the dead-reckoning gate turned down (gate / TM / prior)
        self.frames_not_stored = 0           # revisit frames seqmem.store=new_places kept out of the memory
        self.id_last_frame: dict[int, int] = {}   # LVC id -> its latest frame in the sequence memory
        self.frame_ids: list[int] = []       # LVC id of every frame stored in the TM frame index
        self.tm_traversal_start = 0
        self.last_tm_hits = np.zeros(0, np.int64)
        self.last_tm_columns = 0
        self.steps = 0
        self.seq_calib = RunningQuantile(cfg.seqmem.calib_warmup)  # own F1 of the confident sequence matches
        self.lvc_birth: list[int] = []       # memory index of the frame that created each LVC (with the sequence memory)
        self.successors: dict[int, set[int]] = {}
        self.last_id = -1
        self.last_columns = np.zeros(0, np.int32)
        self.last_descriptor = np.zeros(0, np.int64)
        self.last_anomaly = 0.0

    # ---- the optional parts, for the code paths that need them ----------------------
    def _need_sp(self) -> SpatialPooler:
        return _need(self.sp, "runs no spatial pooler (htm.sp.enabled)")

    def _need_tm(self) -> TemporalMemory:
        return _need(self.tm, "runs no temporal memory (htm.descriptor.source / htm.tm.decide)")

    def _need_tm_index(self) -> TmFrameIndex:
        return _need(self.tm_index, "keeps no TM frame index (htm.tm.decide)")

    def _need_seqmem(self) -> SequenceMatcher:
        return _need(self.seqmem, "has no sequence memory (htm.seqmem.length)")

    @property
    def n_bits(self) -> int:
        """Size of the descriptor bit space (cells, columns or SDR bits)."""
        return self.lvc.n_bits

    def _validate(self, active: np.ndarray) -> np.ndarray:
        a = np.asarray(active)
        if a.ndim != 1:
            raise ValueError(f"fused SDR 'active' must be 1-D, got shape {a.shape}")
        if a.size and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"fused SDR 'active' must hold integer indices, got {a.dtype}")
        a = a.astype(np.int64)
        if a.size and (a[0] < 0 or a[-1] >= self.cfg.input_size or np.any(np.diff(a) <= 0)):
            raise ValueError(f"fused SDR 'active' must be sorted unique indices in [0, {self.cfg.input_size})")
        return a

    def encode(self, active: np.ndarray, learn: bool | None = None) -> tuple[np.ndarray, float]:
        """SP/TM on one fused SDR; returns (descriptor source bits, TM anomaly).

        ``learn`` None uses ``htm.learning``.
        """
        a = self._validate(active)
        learn = self.cfg.learning if learn is None else bool(learn)
        if self.mode == "sdr" and not self.tm_decides:
            return a, 0.0
        if self.sp is not None:
            sp_learn = learn and (self.cfg.sp.learn_steps == 0 or self.sp.iteration_learn < self.cfg.sp.learn_steps
                                  or self.cfg.sp.overlap_norm_steps > 0)
            cols = self.sp.compute(a, sp_learn)
        else:
            cols = a.astype(np.int32)
        self.last_columns = cols
        if self.mode in ("sp", "sdr"):
            if self.tm_decides:
                tm = self._need_tm()
                predicted = tm.predictive_cells
                tm_cols = self._tm_input(cols)
                self.last_tm_columns = tm_cols.size
                tm.compute(tm_cols, learn)
                self.last_anomaly = float(tm.anomaly)
                self.last_tm_hits = np.intersect1d(tm.active_cells, predicted, assume_unique=True).astype(np.int64)
            return (a if self.mode == "sdr" else cols.astype(np.int64)), self.last_anomaly
        tm = self._need_tm()
        winners = tm.compute(cols, learn).astype(np.int64)
        self.last_anomaly = float(tm.anomaly)
        if self.tm_columns and (col := winners // tm.cpc).size:  # sorted cells: sorted columns, each once
            winners = col[np.concatenate(([True], col[1:] != col[:-1]))]
        return winners, float(tm.anomaly)

    def _tm_input(self, cols: np.ndarray) -> np.ndarray:
        """The ``tm.input_columns`` most strongly driven active columns (all when 0), sorted."""
        k = self.cfg.tm.input_columns
        if k <= 0 or cols.size <= k:
            return cols
        sp = self._need_sp()
        if sp.overlap_norm_steps > 0:
            drive = (sp.overlaps[cols] - sp.ov_mean[cols]) * sp.ov_isd[cols]
        else:
            drive = sp.overlaps[cols] * (sp.boost[cols] if sp.boost_strength > 0 else 1.0)
        order = np.lexsort((cols, -drive))
        return np.sort(cols[order[:k]])

    def describe(self, active: np.ndarray, learn: bool | None = None) -> np.ndarray:
        """D_t for one fused SDR (SP -> TM -> pooling -> Eq. 4.5 -> cap); the LVC store is untouched."""
        src, _ = self.encode(active, learn)
        d = self.descriptor.update(src)
        self.last_descriptor = d
        return d

    def step(self, active: np.ndarray, learn: bool | None = None, store: bool = True,
             modalities: dict[str, np.ndarray] | None = None,
             position: np.ndarray | list[float] | None = None) -> LvcResult:
        """One frame: fused SDR indices -> LVC id, R, is_new, I (Eqs. 4.3-4.10).  ``store`` False only
        queries (evaluation against a fixed reference map): the id is the accepted l* or -1, no
        prototype is created.  ``modalities`` (per-modality SDR indices): with ``lvc.require_multimodal``
        only; ``position`` (the frame's dead-reckoned position, m; None: unknown): ``dr_gate.enabled`` only."""
        d = self.describe(active, learn)
        anomaly = self.last_anomaly if self.tm is not None else 0.0
        self.steps += 1
        mm = self.multimodal
        veto = None if mm is None else (lambda lvc_id: mm.disagree(lvc_id, modalities))
        if self.dr_gate is not None:
            self.dr_gate.locate(position)
        seq = self.seqmem.score(d) if self.seqmem is not None else None
        tmv = self._tm_vote() if self.tm_index is not None else None
        res = self._decide(d, veto, seq, store, tmv)
        if self.cfg.seqmem.f1_quantile > 0 and seq is not None and seq.frame >= 0 \
                and seq.score >= self.cfg.seqmem.threshold \
                and seq.score - seq.second >= self.cfg.seqmem.confident_margin:
            self.seq_calib.add(seq.f1)
        if store:
            if mm is not None and res.is_new:
                mm.store(res.lvc_id, modalities)
            if self.last_id >= 0 and res.lvc_id != self.last_id:
                self.successors.setdefault(self.last_id, set()).add(res.lvc_id)
            lim, held = self.cfg.seqmem.every_frame_limit, len(self.frame_ids if self.seqmem is None else self.seqmem)
            keep = (self.cfg.seqmem.store == "every_frame" and not 0 < lim <= held) or res.is_new or self._recent(res.lvc_id)
            self.frames_not_stored += not keep
            if self.seqmem is not None and keep:
                if res.is_new:
                    self.lvc_birth.append(self.seqmem.size)
                self.id_last_frame[res.lvc_id] = self.seqmem.add(d, res.lvc_id)
                if self.dr_gate is not None:
                    self.dr_gate.add()
            if self.tm_index is not None and keep:
                self.tm_index.add(self._need_tm().winner_cells)
                self.frame_ids.append(res.lvc_id)
        self.last_id = res.lvc_id
        return replace(res, anomaly=anomaly)

    def _tm_vote(self) -> tuple[int, float]:
        """(stored frame j*, share) the TM's correctly predicted cells point at (:mod:`services.htm.tm_match`);
        candidates are the stored frames but the last ``seqmem.exclude`` of the current traversal."""
        idx = self._need_tm_index()
        nc = max(min(self.tm_traversal_start, idx.size), idx.size - self.cfg.seqmem.exclude, 0)
        j, votes = idx.vote(self.last_tm_hits, nc)
        return j, votes / max(self.last_tm_columns, 1)

    def _decide(self, d: np.ndarray, veto: Callable[[int], bool] | None, seq: SequenceScore | None, store: bool,
                tmv: tuple[int, float] | None = None) -> LvcResult:
        """Eq. 4.9 on l*, then the TM decision, then the sequence match, then the place-sequence
        prior, then Eq. 4.10 (``store``) or no id (-1)."""
        best, i = self.lvc.best(d)
        n = d.size
        rate = i / n if n else 0.0
        extra: dict[str, Any] = {} if seq is None else {"frame": seq.frame, "seq_score": seq.score,
                                         "seq_margin": seq.score - seq.second}
        if tmv is not None:
            extra.update(tm_frame=tmv[0], tm_share=tmv[1])
        gate = best >= 0 and self.lvc.accepts(i, n, self.lvc.prototype_size(best)) and not (veto and veto(best)) \
            and self._plausible_id(best, revisit=False)
        if gate and not (self.cfg.seqmem.override and self._recent(best)):
            return LvcResult(best, rate, False, i, best, rate, i, n, **extra)
        if tmv is not None and tmv[0] >= 0 and tmv[1] >= self.cfg.tm.decide_share and self._plausible_frame(tmv[0]):
            lid = self.frame_ids[tmv[0]]
            if lid >= 0 and not (veto and veto(lid)):
                it = int(np.intersect1d(d, self.lvc.prototype(lid), assume_unique=True).size)
                return LvcResult(lid, it / n if n else 0.0, False, it, best, rate, i, n, by_tm=True, **extra)
        sm = self._sequence_match(d, seq, veto)
        if sm is not None and not (gate and sm[0] == best):
            return LvcResult(sm[0], sm[1], False, sm[2], best, rate, i, n, by_sequence=True, **extra)
        if gate:
            return LvcResult(best, rate, False, i, best, rate, i, n, **extra)
        if self.cfg.lvc.successor_threshold > 0:
            pm = self._predicted_match(d, veto)
            if pm is not None:
                return LvcResult(pm[0], pm[1], False, pm[2], best, rate, i, n, by_prior=True, **extra)
        if store:
            new_id = self.lvc.add(d)
            return LvcResult(new_id, 1.0 if n else 0.0, True, 0, best, rate, i, n, **extra)
        return LvcResult(-1, 0.0, False, 0, best, rate, i, n, **extra)

    def _plausible_id(self, lvc_id: int, revisit: bool = True) -> bool:
        """Eq. G.1 for LVC ``lvc_id``: one of its stored frames passes (``revisit`` False: the distance only;
        True without the gate or a known position)."""
        if self.dr_gate is None or self.dr_gate.current is None:
            return True
        last = self.id_last_frame.get(lvc_id)
        if last is None:
            return True                  # no stored frame carries it
        # the id's latest frame first (the id carried on from the last frames: nearly always it)
        if self.dr_gate.plausible(last, revisit):
            return True
        mem = self._need_seqmem()
        frames = np.flatnonzero(mem.ids[:mem.size] == lvc_id)
        ok = self.dr_gate.any_plausible(frames, revisit)
        self.dr_rejections += not ok
        return ok

    def _plausible_frame(self, frame: int) -> bool:
        """Eq. G.1 for one stored frame (always True without the gate or a known position)."""
        if self.dr_gate is None or self.dr_gate.current is None:
            return True
        ok = self.dr_gate.plausible(frame)
        self.dr_rejections += not ok
        return ok

    def _recent(self, lvc_id: int) -> bool:
        """True when LVC ``lvc_id`` was created by a frame that is no sequence candidate (stored in the
        last ``seqmem.exclude`` steps of the current traversal): its match is no revisit."""
        return self.seqmem is not None and 0 <= lvc_id < len(self.lvc_birth) \
            and self.lvc_birth[lvc_id] >= self.seqmem.candidates()

    def _sequence_match(self, d: np.ndarray, seq: SequenceScore | None, veto: Callable[[int], bool] | None) -> tuple[int, float, int] | None:
        """(id, R, I) of the sequence match when S* and its margin pass the gates, else None."""
        cfg = self.cfg
        if seq is None or seq.frame < 0:
            return None
        checked = self.dr_gate is not None and self.dr_gate.checks(seq.frame)
        threshold = cfg.dr_gate.seqmem_threshold if checked else cfg.seqmem.threshold
        margin = cfg.dr_gate.seqmem_margin if checked else cfg.seqmem.margin
        if seq.score < threshold or seq.score - seq.second < margin or seq.f1 < cfg.seqmem.min_f1:
            return None
        if cfg.seqmem.f1_quantile > 0:
            q = self.seq_calib.quantile(cfg.seqmem.f1_quantile)
            if q is None:       # calibration not yet warm: the margin alone, at the confident level
                if seq.score - seq.second < cfg.seqmem.confident_margin:
                    return None
            elif seq.f1 < q:
                return None
        lid = int(self._need_seqmem().ids[seq.frame])
        if lid < 0 or (veto and veto(lid)) or not self._plausible_frame(seq.frame):
            return None
        i = int(np.intersect1d(d, self.lvc.prototype(lid), assume_unique=True).size)
        return lid, (i / d.size if d.size else 0.0), i

    def predicted_ids(self) -> list[int]:
        """LVC ids 1 .. ``lvc.successor_hops`` successor steps ahead of the previous frame's id (sorted)."""
        if self.last_id < 0:
            return []
        frontier: set[int] = {self.last_id}
        seen: set[int] = set()
        for _ in range(self.cfg.lvc.successor_hops):
            frontier = {b for a in frontier for b in self.successors.get(a, ())} - seen - {self.last_id}
            seen |= frontier
        return sorted(seen)

    def _predicted_match(self, d: np.ndarray, veto: Callable[[int], bool] | None) -> tuple[int, float, int] | None:
        """(id, R, I) of the best predicted prototype passing the sequence gate, or None."""
        n = d.size
        g = self.cfg.lvc.successor_threshold
        best = None
        for lid in self.predicted_ids():
            if not self._plausible_id(lid):
                continue
            proto = self.lvc.prototype(lid)
            i = int(np.intersect1d(d, proto, assume_unique=True).size)
            if n == 0 or i < self.cfg.lvc.min_intersection or i / n < g or 2.0 * i / (n + proto.size) < g:
                continue
            if (best is None or i > best[2]) and not (veto and veto(lid)):
                best = (lid, i / n, i)
        return best

    def reset_sequence(self) -> None:
        """Forget the temporal context (TM predictions, pooling window, interval run); keep learning."""
        if self.tm is not None:
            self.tm.reset()
        self.descriptor.reset()
        if self.seqmem is not None:
            self.seqmem.reset()
        self.seq_calib.reset()
        if self.tm_index is not None:
            self.tm_traversal_start = self.tm_index.size
        self.last_tm_hits = np.zeros(0, np.int64)
        self.last_id = -1

    # ---- persistence ------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the whole state to ``path`` (npz; written atomically)."""
        path = Path(path)
        arrays: dict[str, np.ndarray] = {}
        for prefix, part in (("sp", self.sp), ("tm", self.tm), ("desc", self.descriptor), ("lvc", self.lvc),
                             ("mm", self.multimodal), ("seqmem", self.seqmem), ("tmidx", self.tm_index),
                             ("seqcalib", self.seq_calib), ("drgate", self.dr_gate)):
            if part is not None:
                for k, v in part.state().items():
                    arrays[f"{prefix}.{k}"] = v
        pairs = sorted((a, b) for a, bs in self.successors.items() for b in bs)
        arrays["seq.pairs"] = np.array(pairs, np.int64).reshape(-1, 2)
        arrays["seq.last_id"] = np.array([self.last_id], np.int64)
        arrays["tmidx.frame_ids"] = np.array(self.frame_ids, np.int64)
        arrays["tmidx.traversal_start"] = np.array([self.tm_traversal_start], np.int64)
        meta = {"version": STATE_VERSION, "steps": self.steps, "frames_not_stored": self.frames_not_stored,
                "config": {k: self.cfg.get(k) for k in _STRUCTURAL}}
        arrays["meta_json"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        savez_arrays: dict[str, Any] = arrays   # numpy's stub types **kwds against allow_pickle too
        np.savez(tmp, **savez_arrays)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, cfg: HtmConfig) -> NeocortexHtm:
        """A NeocortexHtm with ``cfg`` and the state saved at ``path``."""
        obj = cls(cfg)
        obj.load_state(path)
        return obj

    def load_state(self, path: str | Path) -> None:
        path = Path(path)
        try:
            with np.load(path) as z:
                data = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise FileNotFoundError(f"HTM state file not found: {path}") from None
        if "meta_json" not in data:
            raise ValueError(f"{path}: not an HTM state file (no meta_json)")
        meta = json.loads(bytes(data["meta_json"]).decode())
        if meta.get("version") != STATE_VERSION:
            raise ValueError(f"{path}: HTM state version {meta.get('version')}, expected {STATE_VERSION}")
        for k, v in meta["config"].items():
            k = RENAMED_KEYS.get(f"htm.{k}", f"htm.{k}").removeprefix("htm.")   # a state file of an older version
            if self.cfg.get(k) != v:
                raise ValueError(f"{path}: saved with htm.{k}={v!r}, configuration has {self.cfg.get(k)!r}")
        for prefix, part in (("sp", self.sp), ("tm", self.tm), ("desc", self.descriptor), ("lvc", self.lvc),
                             ("mm", self.multimodal), ("seqmem", self.seqmem), ("tmidx", self.tm_index),
                             ("seqcalib", self.seq_calib), ("drgate", self.dr_gate)):
            if part is not None:
                pre = prefix + "."
                part.set_state({k[len(pre):]: v for k, v in data.items() if k.startswith(pre)})
        self.steps = int(meta["steps"])
        self.frames_not_stored = int(meta.get("frames_not_stored", 0))
        if self.dr_gate is not None:    # a state file is a map of an earlier run: another odometry frame
            self.dr_gate.forget_positions()
        self.lvc_birth = []
        self.id_last_frame = {}
        if self.seqmem is not None:     # the creating frame of each id: its first frame in the memory
            seen: set[int] = set()
            for j, lid in enumerate(self.seqmem.ids[:self.seqmem.size].tolist()):
                if lid >= 0 and lid not in seen:
                    seen.add(lid)
                    self.lvc_birth.append(j)
                self.id_last_frame[lid] = j
        self.successors = {}
        for a, b in data.get("seq.pairs", np.zeros((0, 2), np.int64)).tolist():
            self.successors.setdefault(int(a), set()).add(int(b))
        self.last_id = int(data["seq.last_id"][0]) if "seq.last_id" in data else -1
        self.frame_ids = [int(x) for x in data.get("tmidx.frame_ids", np.zeros(0, np.int64))]
        self.tm_traversal_start = int(data["tmidx.traversal_start"][0]) if "tmidx.traversal_start" in data else 0
