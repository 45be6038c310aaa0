"""The neocortex's configuration section (``htm:``): spatial pooler, temporal memory, LVC matching (Eqs. 4.4-4.10), sequence memory.

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from common.config import ConfigSection, check

__all__ = ["HtmConfig"]


class HtmConfig(ConfigSection):
    sp_enable: bool = True
    sp_columns: int = Field(4096, ge=16, description="Table 4.1: 2048; 4096 (ours, issue 17): the SP keeps the place")
    sp_numActiveColumns: int = Field(800, ge=1, description="Table 4.1: 20; 800 (ours, issue 17)")
    sp_potentialRadius: int = Field(2048, ge=1, description="Table 4.1: 600; 2048 (ours, issue 17): the whole input")
    sp_potentialPct: float = Field(0.5, gt=0, le=1)
    sp_synPermActiveInc: float = Field(0.006, ge=0)
    sp_synPermInactiveDec: float = Field(0.008, ge=0)
    sp_synPermConnected: float = Field(0.1, gt=0, lt=1)
    sp_boostStrength: float = Field(0.0, ge=0, description="not given by the dissertation; 0 (issue 17): the "
                                    "standardised overlaps replace boosting (2 spreads the dense union with BAMI)")
    sp_dutyCyclePeriod: int = Field(1000, ge=1)
    tm_cellsPerColumn: int = Field(16, ge=1, description="Table 4.1: 40; 16 (ours, issue 17)")
    tm_activationThreshold: int = Field(4, ge=1, description="Table 4.1: 5; 4 (ours, issue 17)")
    tm_minThreshold: int = Field(3, ge=1)
    tm_initialPermanence: float = Field(0.55, ge=0, le=1)
    tm_connectedPermanence: float = Field(0.5, ge=0, le=1)
    tm_maxNewSynapseCount: int = Field(16, ge=1, description="Table 4.1: 20; 16 (ours, issue 17)")
    tm_permanenceIncrement: float = Field(0.008, ge=0)
    tm_permanenceDecrement: float = Field(0.012, ge=0)
    tm_predictedSegmentDecrement: float = Field(0.0, ge=0)
    tm_maxSegmentsPerCell: int = Field(255, ge=1)
    tm_maxSynapsesPerSegment: int = Field(255, ge=1)
    tm_maxSynapses: int = Field(1_048_576, ge=0, description="synapse budget of the whole TM (ours, issue 21; 0: none, the "
                                "dissertation's per-cell and per-segment caps only): beyond it the least recently used "
                                "segments are evicted, so a step's cost stays flat over hours (services/htm/"
                                "temporal_memory.py)")
    learning: bool = True
    seed: int = 42
    sv_descriptor_source: Literal["tm", "sp", "sdr"] = Field(
        "sdr", description="Table 4.1: tm. sdr (ours, issue 8): with pretrained embeddings the SP keeps too little "
        "of the place (20 of 2048 columns), the fused SDR itself is the descriptor; tm: the dissertation's chain")
    sv_tm_window: int = Field(7, ge=1)
    sv_tm_topk: int = Field(15, ge=1)
    sv_tm_match_threshold: float = Field(0.30, ge=0, le=1)
    interval_mode: bool = Field(False, description="Table 4.1: true; false (ours, issue 8): the union of "
                                "consecutive SDRs blurred places on the sim mission")
    theta_alpha: float = Field(0.65, ge=0, le=1)
    theta_rho: int = Field(3, ge=1)
    sv_match_threshold: float = Field(0.72, ge=0, le=1, description="Table 4.1: 0.38; 0.72 (ours, issue 8): "
                                      "the sdr descriptor of another place overlaps by ~0.5-0.6")
    sv_min_intersection: int = Field(12, ge=0)
    sv_require_multimodal: bool = False
    sv_min_img_score: float = Field(0.45, ge=0, le=1)
    sv_min_sonar_score: float = Field(0.35, ge=0, le=1)
    sv_enable_f1_gate: bool = True
    min_f1: float = Field(0.72, ge=0, le=1, description="Table 4.1: 0.55; 0.72 with the sdr descriptor (issue 8)")
    sv_use_iou_tiebreak: bool = True
    max_bits: int = Field(0, ge=0, description="cap on descriptor bits after interval union (0: sv_tm_topk)")
    state_path: str = Field("", description="load SP/TM/LVC state from here at start and save at end (empty: off)")
    # --- added for the HTM service (issue 4); see services/htm/
    input_size: int = Field(2048, ge=16, description="length L of the fused SDR (= encoder.sp_columns)")
    sp_minPctOverlapDutyCycle: float = Field(0.001, ge=0, le=1, description="BAMI weak-column bump threshold")
    sv_tm_bits: Literal["cells", "columns"] = Field("columns", description="bit space of the tm descriptor: "
                                                     "winner cell indices, or their columns")
    sp_learn_steps: int = Field(100, ge=0, description="SP learns during the first N learning steps, then its "
                                "synapses and boost factors are frozen (0: always learns)")
    # --- added for the place-sequence prior (issue 8); see services/htm/pipeline.py
    sv_seq_match_threshold: float = Field(0.68, ge=0, le=1, description="R and F1 gate for an LVC predicted by the "
                                          "place sequence (a learned successor of the previous frame's id); 0: off")
    sv_seq_hops: int = Field(2, ge=1, description="successor steps a predicted LVC may be ahead of the previous id")
    # --- added for the sequence memory (issue 8); see services/htm/sequence.py
    sv_seqmem_length: int = Field(40, ge=0, description="frames K of the sequence score of the LVC decision "
                                  "(SeqSLAM-like diagonals over the stored frames); 0: off")
    sv_seqmem_velocities: list[float] = Field(default_factory=lambda: [1.0], min_length=1,
                                              description="diagonal slopes: stored frames per current frame")
    sv_seqmem_exclude: int = Field(50, ge=0, description="frames of the current traversal stored this few steps "
                                   "ago are no sequence candidates (neighbours in time look alike)")
    sv_seqmem_threshold: float = Field(1.5, description="sequence score S* (z units) a sequence match needs")
    sv_seqmem_margin: float = Field(1.75, ge=0, description="S* minus the best score ending more than K frames "
                                    "away (z units) a sequence match needs")
    sv_seqmem_store: Literal["every_frame", "new_places"] = Field(
        "every_frame", description="which frames the sequence memory (and the TM frame index) keeps: every_frame, or "
        "new_places -- not a frame whose id is a revisit of a place created before the current traversal's last "
        "sv_seqmem_exclude frames (the memory then grows with the places seen, not with the time spent; "
        "services/htm/pipeline.py)")
    sv_seqmem_every_frame_limit: int = Field(6000, ge=0, description="every_frame keeps every frame until the memory "
                                             "holds this many, then new places only (the new_places rule), so a "
                                             "mission of hours costs per frame what its first ones did (0: no limit; "
                                             "ours, issue 21)")
    sv_tm_decide: bool = Field(True, description="run the SP and a TM over its columns beside the descriptor and "
                               "let its predictions decide a revisit (services/htm/tm_match.py)")
    sp_overlap_norm_steps: int = Field(1000, ge=0, description="> 0: global inhibition ranks each column's overlap "
                                       "standardised by its own mean and deviation over the first N learning steps "
                                       "(then frozen), in place of BAMI boosting and permanence learning (0: BAMI)")
    tm_input_columns: int = Field(20, ge=0, description="the TM sees the N most strongly driven of the SP's active "
                                  "columns (boosted overlap, ties to the lower index; 0: all): its cost grows with "
                                  "the square of its active columns")
    sv_tm_share: float = Field(0.15, ge=0, le=1, description="share of a frame's active columns the TM must have "
                               "predicted in the context of one stored frame for a TM decision")
    sv_seqmem_override: bool = Field(False, description="a sequence match (or TM decision) overrides an Eq. 4.9 "
                                     "match whose LVC was created by a recent frame of the current traversal "
                                     "(no sequence candidate): the revisit is taken over the pass's own new id")
    sv_seqmem_min_f1: float = Field(0.0, ge=0, le=1, description="a sequence match also needs the frame's own F1 "
                                    "with the stored frame j* where the diagonal ends >= this (0: off)")
    sv_seqmem_f1_quantile: float = Field(0.0, ge=0, le=1, description="self-calibrated F1 check (services/htm/"
                                         "calibrate.py): a sequence match needs F1(D_t, D_j*) >= this quantile of "
                                         "the F1 of the traversal's confident sequence matches so far (0: off)")
    sv_seqmem_confident_margin: float = Field(1.75, ge=0, description="margin S* - S_2 (z units) of a confident "
                                              "sequence match (the calibration sample; the gate until it is warm)")
    sv_seqmem_calib_warmup: int = Field(20, ge=1, description="confident matches the self-calibrated F1 check needs "
                                        "before it replaces the confident margin")
    sv_seqmem_column_norm: bool = Field(True, description="normalise each stored frame's similarity by its running "
                                        "mean/std over the current traversal before the per-frame z-score")
    # --- added for the dead-reckoning gate (issue 17); see services/htm/geometry.py
    sv_dr_gate: bool = Field(True, description="a revisit claim must be a plausible earlier visit by dead "
                             "reckoning (Eq. G.1): htm then also subscribes to Odometry; needs the sequence "
                             "memory, which keeps the stored frames (off with sv_seqmem_length 0)")
    sv_dr_gate_min_m: float = Field(2.0, ge=0, description="r_min of Eq. G.1 (m): the distance two frames of one "
                                    "place may be apart at zero path between them")
    sv_dr_gate_drift: float = Field(0.01, ge=0, description="drift of Eq. G.1: allowed dead-reckoning error per "
                                    "metre of path flown between the two frames")
    sv_dr_gate_min_path_m: float = Field(10.0, ge=0, description="s_min of Eq. G.1 (m): path flown since a stored "
                                         "frame before it can be revisited (the sim's truth uses the same 10 m)")
    sv_dr_gate_seqmem_threshold: float = Field(1.0, description="sv_seqmem_threshold for a sequence match the "
                                               "dead-reckoning gate checked (both frames have positions)")
    sv_dr_gate_seqmem_margin: float = Field(0.75, ge=0, description="sv_seqmem_margin for a sequence match the "
                                            "dead-reckoning gate checked (both frames have positions)")
    sv_dr_gate_jump_m: float = Field(2.0, gt=0, description="a position step between two camera frames longer "
                                     "than this (m) is an odometry discontinuity: positions stored before it "
                                     "are no longer compared")

    @model_validator(mode="after")
    def _consistent(self) -> HtmConfig:
        check(self.sp_numActiveColumns <= self.sp_columns,
               f"htm.sp_numActiveColumns ({self.sp_numActiveColumns}) must be <= htm.sp_columns ({self.sp_columns})")
        check(self.tm_minThreshold <= self.tm_activationThreshold,
               f"htm.tm_minThreshold ({self.tm_minThreshold}) must be <= htm.tm_activationThreshold "
               f"({self.tm_activationThreshold})")
        check(self.tm_maxNewSynapseCount <= self.tm_maxSynapsesPerSegment,
               f"htm.tm_maxNewSynapseCount ({self.tm_maxNewSynapseCount}) must be <= htm.tm_maxSynapsesPerSegment "
               f"({self.tm_maxSynapsesPerSegment})")
        check(all(v > 0 for v in self.sv_seqmem_velocities),
               f"htm.sv_seqmem_velocities {self.sv_seqmem_velocities} must all be > 0")
        return self
