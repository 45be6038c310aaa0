"""The neocortex's configuration section (``htm:``): spatial pooler, temporal memory, descriptor, LVC matching (Eqs. 4.4-4.10), sequence memory, dead-reckoning gate.

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field. Where a default differs from Table 4.1 of the
dissertation the description says so ("ours"); docs/DECISIONS.md says why.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from common.config import ConfigSection, check

__all__ = ["HtmConfig", "SpatialPoolerConfig", "TemporalMemoryConfig", "DescriptorConfig", "LvcConfig",
           "SequenceMemoryConfig", "DeadReckoningGateConfig"]


class SpatialPoolerConfig(ConfigSection):
    """The spatial pooler over the fused SDR (services/htm/spatial_pooler.py)."""

    enabled: bool = Field(True, description="run the spatial pooler; false: the fused SDR itself feeds the TM")
    columns: int = Field(4096, ge=16, description="columns of the SP (Table 4.1: 2048; ours: 4096, the SP keeps "
                         "the place) [columns]")
    num_active_columns: int = Field(800, ge=1, description="columns active per step after global inhibition "
                                    "(Table 4.1: 20; ours: 800) [columns]")
    potential_radius: int = Field(2048, ge=1, description="input bits a column may connect to around its centre "
                                  "(Table 4.1: 600; ours: 2048, the whole input) [bits]")
    potential_pct: float = Field(0.5, gt=0, le=1, description="fraction of a column's potential pool given a "
                                 "potential synapse [fraction]")
    syn_perm_active_inc: float = Field(0.006, ge=0, description="permanence increment of a synapse on an active "
                                       "input of a learning column [permanence]")
    syn_perm_inactive_dec: float = Field(0.008, ge=0, description="permanence decrement of a synapse on an "
                                         "inactive input of a learning column [permanence]")
    syn_perm_connected: float = Field(0.1, gt=0, lt=1, description="permanence from which a synapse is "
                                      "connected [permanence]")
    boost_strength: float = Field(0.0, ge=0, description="strength of BAMI boosting (not given by the "
                                  "dissertation; ours: 0, the standardised overlaps replace boosting, 2 spreads "
                                  "the dense union)")
    duty_cycle_period: int = Field(1000, ge=1, description="period of the duty-cycle moving averages of "
                                   "boosting [steps]")
    min_pct_overlap_duty_cycle: float = Field(0.001, ge=0, le=1, description="BAMI weak-column bump threshold: "
                                              "a column whose overlap duty cycle is below this fraction of its "
                                              "neighbours' largest gets its permanences bumped [fraction]")
    learn_steps: int = Field(100, ge=0, description="the SP learns during the first N learning steps, then its "
                             "synapses and boost factors are frozen (0: always learns) [steps]")
    overlap_norm_steps: int = Field(1000, ge=0, description="> 0: global inhibition ranks each column's overlap "
                                    "standardised by its own mean and deviation over the first N learning steps "
                                    "(then frozen), in place of BAMI boosting and permanence learning (0: BAMI) "
                                    "[steps]")

    @model_validator(mode="after")
    def _consistent(self) -> SpatialPoolerConfig:
        check(self.num_active_columns <= self.columns,
              f"htm.sp.num_active_columns ({self.num_active_columns}) must be <= htm.sp.columns ({self.columns})")
        return self


class TemporalMemoryConfig(ConfigSection):
    """The temporal memory over the SP's columns, and its decisions (services/htm/temporal_memory.py,
    services/htm/tm_match.py)."""

    cells_per_column: int = Field(16, ge=1, description="cells per column (Table 4.1: 40; ours: 16) [cells]")
    activation_threshold: int = Field(4, ge=1, description="active connected synapses that make a segment active "
                                      "(Table 4.1: 5; ours: 4) [synapses]")
    min_threshold: int = Field(3, ge=1, description="active potential synapses that make a segment matching "
                               "[synapses]")
    initial_permanence: float = Field(0.55, ge=0, le=1, description="permanence of a newly grown synapse "
                                      "[permanence]")
    connected_permanence: float = Field(0.5, ge=0, le=1, description="permanence from which a synapse is "
                                        "connected [permanence]")
    max_new_synapse_count: int = Field(16, ge=1, description="synapses grown on a learning segment per step "
                                       "(Table 4.1: 20; ours: 16) [synapses]")
    permanence_increment: float = Field(0.008, ge=0, description="permanence increment of a correctly active "
                                        "synapse [permanence]")
    permanence_decrement: float = Field(0.012, ge=0, description="permanence decrement of an inactive synapse of "
                                        "a learning segment [permanence]")
    predicted_segment_decrement: float = Field(0.0, ge=0, description="punishment of a segment that predicted a "
                                               "column that did not become active (0: none) [permanence]")
    max_segments_per_cell: int = Field(255, ge=1, description="segments a cell may hold [segments]")
    max_synapses_per_segment: int = Field(255, ge=1, description="synapses a segment may hold [synapses]")
    max_synapses: int = Field(1_048_576, ge=0, description="synapse budget of the whole TM (ours; 0: none, the "
                              "dissertation's per-cell and per-segment caps only): beyond it the least recently "
                              "used segments are evicted, so a step's cost stays flat over hours "
                              "(services/htm/temporal_memory.py) [synapses]")
    input_columns: int = Field(20, ge=0, description="the TM sees the N most strongly driven of the SP's active "
                               "columns (boosted overlap, ties to the lower index; 0: all): its cost grows with "
                               "the square of its active columns [columns]")
    decide: bool = Field(True, description="run the SP and a TM over its columns beside the descriptor and let "
                         "its predictions decide a revisit (services/htm/tm_match.py)")
    decide_share: float = Field(0.15, ge=0, le=1, description="share of a frame's active columns the TM must "
                                "have predicted in the context of one stored frame for a TM decision [fraction]")

    @model_validator(mode="after")
    def _consistent(self) -> TemporalMemoryConfig:
        check(self.min_threshold <= self.activation_threshold,
              f"htm.tm.min_threshold ({self.min_threshold}) must be <= htm.tm.activation_threshold "
              f"({self.activation_threshold})")
        check(self.max_new_synapse_count <= self.max_synapses_per_segment,
              f"htm.tm.max_new_synapse_count ({self.max_new_synapse_count}) must be <= "
              f"htm.tm.max_synapses_per_segment ({self.max_synapses_per_segment})")
        return self


class DescriptorConfig(ConfigSection):
    """The matching descriptor D_t of a frame (Eqs. 4.4-4.5, services/htm/descriptor.py)."""

    source: Literal["tm", "sp", "sdr"] = Field(
        "sdr", description="what the descriptor is made of. Table 4.1: tm (the dissertation's chain: pooled TM "
        "winners); ours: sdr, the fused SDR itself (with pretrained embeddings the SP keeps too little of the "
        "place, 20 of 2048 columns); sp: the SP's active columns")
    tm_window: int = Field(7, ge=1, description="tm descriptor: steps whose winners are pooled (Eq. 4.4) [steps]")
    tm_topk: int = Field(15, ge=1, description="tm descriptor: most frequent pooled bits kept (Eq. 4.4) [bits]")
    tm_bits: Literal["cells", "columns"] = Field("columns", description="bit space of the tm descriptor: winner "
                                                 "cell indices, or their columns")
    interval_mode: bool = Field(False, description="union of consecutive similar descriptors (Eq. 4.5; Table 4.1: "
                                "true; ours: false, the union blurred places on the sim mission)")
    theta_alpha: float = Field(0.65, ge=0, le=1, description="interval union: overlap |A_t & A_t-1| / |A_t| that "
                               "continues the run (Eq. 4.5) [fraction]")
    theta_rho: int = Field(3, ge=1, description="interval union: longest run of unioned steps (Eq. 4.5) [steps]")
    max_bits: int = Field(0, ge=0, description="cap on descriptor bits after the interval union (0: tm_topk for "
                          "the tm descriptor, no cap otherwise) [bits]")


class LvcConfig(ConfigSection):
    """Matching a descriptor against the local view cells (Eqs. 4.6-4.10, services/htm/lvc.py) and the
    place-sequence prior (services/htm/pipeline.py)."""

    match_threshold: float = Field(0.72, ge=0, le=1, description="R an LVC match needs, sp and sdr descriptors "
                                   "(Eq. 4.9; Table 4.1: 0.38; ours: 0.72, the sdr descriptor of another place "
                                   "overlaps by ~0.5-0.6) [fraction]")
    tm_match_threshold: float = Field(0.30, ge=0, le=1, description="R an LVC match needs, tm descriptor "
                                      "(Eq. 4.9) [fraction]")
    min_intersection: int = Field(12, ge=0, description="bits an LVC match must share with the descriptor "
                                  "(Eq. 4.6) [bits]")
    f1_gate: bool = Field(True, description="an LVC match also needs F1 >= min_f1 (Eq. 4.10)")
    min_f1: float = Field(0.72, ge=0, le=1, description="F1 the F1 gate needs (Table 4.1: 0.55; ours: 0.72 with "
                          "the sdr descriptor) [fraction]")
    iou_tiebreak: bool = Field(True, description="among LVCs of equal R, the one of highest IoU wins")
    require_multimodal: bool = Field(False, description="a match must also hold per modality: the frame's camera "
                                     "and sonar SDRs against the LVC's prototypes (Table 4.1; services/htm/"
                                     "multimodal.py)")
    min_camera_score: float = Field(0.45, ge=0, le=1, description="require_multimodal: overlap the camera SDR "
                                    "needs with the LVC's camera prototype [fraction]")
    min_sonar_score: float = Field(0.35, ge=0, le=1, description="require_multimodal: overlap the sonar SDR needs "
                                   "with the LVC's sonar prototype [fraction]")
    successor_threshold: float = Field(0.68, ge=0, le=1, description="R and F1 gate for an LVC predicted by the "
                                       "place sequence (a learned successor of the previous frame's id); 0: off "
                                       "[fraction]")
    successor_hops: int = Field(2, ge=1, description="successor steps a predicted LVC may be ahead of the "
                                "previous id [steps]")


class SequenceMemoryConfig(ConfigSection):
    """The sequence memory of the LVC decision: SeqSLAM-like diagonals over the stored frames
    (services/htm/sequence.py, services/htm/calibrate.py)."""

    length: int = Field(40, ge=0, description="frames K of the sequence score; 0: no sequence memory [frames]")
    velocities: list[float] = Field(default_factory=lambda: [1.0], min_length=1,
                                    description="diagonal slopes: stored frames per current frame, each > 0")
    exclude: int = Field(50, ge=0, description="frames of the current traversal stored this few steps ago are no "
                         "sequence candidates (neighbours in time look alike) [frames]")
    threshold: float = Field(1.5, description="sequence score S* a sequence match needs [z]")
    margin: float = Field(1.75, ge=0, description="S* minus the best score ending more than K frames away a "
                          "sequence match needs [z]")
    store: Literal["every_frame", "new_places"] = Field(
        "every_frame", description="which frames the sequence memory (and the TM frame index) keeps: every_frame, "
        "or new_places -- not a frame whose id is a revisit of a place created before the current traversal's "
        "last exclude frames (the memory then grows with the places seen, not with the time spent; "
        "services/htm/pipeline.py)")
    every_frame_limit: int = Field(6000, ge=0, description="every_frame keeps every frame until the memory holds "
                                   "this many, then new places only (the new_places rule), so a mission of hours "
                                   "costs per frame what its first ones did (0: no limit) [frames]")
    override: bool = Field(False, description="a sequence match (or TM decision) overrides an Eq. 4.9 match whose "
                           "LVC was created by a recent frame of the current traversal (no sequence candidate): "
                           "the revisit is taken over the pass's own new id")
    min_f1: float = Field(0.0, ge=0, le=1, description="a sequence match also needs the frame's own F1 with the "
                          "stored frame j* where the diagonal ends >= this (0: off) [fraction]")
    f1_quantile: float = Field(0.0, ge=0, le=1, description="self-calibrated F1 check (services/htm/calibrate.py): "
                               "a sequence match needs F1(D_t, D_j*) >= this quantile of the F1 of the traversal's "
                               "confident sequence matches so far (0: off) [quantile]")
    confident_margin: float = Field(1.75, ge=0, description="margin S* - S_2 of a confident sequence match (the "
                                    "calibration sample; the gate until it is warm) [z]")
    calib_warmup: int = Field(20, ge=1, description="confident matches the self-calibrated F1 check needs before "
                              "it replaces the confident margin [matches]")
    column_norm: bool = Field(True, description="normalise each stored frame's similarity by its running mean/std "
                              "over the current traversal before the per-frame z-score")

    @model_validator(mode="after")
    def _consistent(self) -> SequenceMemoryConfig:
        check(all(v > 0 for v in self.velocities), f"htm.seqmem.velocities {self.velocities} must all be > 0")
        return self


class DeadReckoningGateConfig(ConfigSection):
    """A revisit claim must be a plausible earlier visit by dead reckoning (Eq. G.1,
    services/htm/geometry.py)."""

    enabled: bool = Field(True, description="check every revisit claim against the dead-reckoned positions: htm "
                          "then also subscribes to Odometry; needs the sequence memory, which keeps the stored "
                          "frames (off with seqmem.length 0)")
    min_m: float = Field(2.0, ge=0, description="r_min of Eq. G.1: the distance two frames of one place may be "
                         "apart at zero path between them [m]")
    drift: float = Field(0.01, ge=0, description="drift of Eq. G.1: allowed dead-reckoning error per metre of "
                         "path flown between the two frames [m/m]")
    min_path_m: float = Field(10.0, ge=0, description="s_min of Eq. G.1: path flown since a stored frame before "
                              "it can be revisited (the sim's truth uses the same 10 m) [m]")
    seqmem_threshold: float = Field(1.0, description="seqmem.threshold for a sequence match the gate checked "
                                    "(both frames have positions) [z]")
    seqmem_margin: float = Field(0.75, ge=0, description="seqmem.margin for a sequence match the gate checked "
                                 "(both frames have positions) [z]")
    jump_m: float = Field(2.0, gt=0, description="a position step between two camera frames longer than this is "
                          "an odometry discontinuity: positions stored before it are no longer compared [m]")


class HtmConfig(ConfigSection):
    """The neocortical front-end: fused SDR -> local view cells (services/htm)."""

    input_size: int = Field(2048, ge=16, description="length L of the fused SDR (= encoder.sp_columns) [bits]")
    learning: bool = Field(True, description="the SP, the TM and the LVCs learn; false: recognition only")
    seed: int = Field(42, description="seed of the SP's and the TM's initialisation and of the descriptor's "
                      "tie-break order")
    state_path: str = Field("", description="load SP/TM/LVC state from here at start and save at end (empty: off)")
    sp: SpatialPoolerConfig = Field(default_factory=SpatialPoolerConfig)
    tm: TemporalMemoryConfig = Field(default_factory=TemporalMemoryConfig)
    descriptor: DescriptorConfig = Field(default_factory=DescriptorConfig)
    lvc: LvcConfig = Field(default_factory=LvcConfig)
    seqmem: SequenceMemoryConfig = Field(default_factory=SequenceMemoryConfig)
    dr_gate: DeadReckoningGateConfig = Field(default_factory=DeadReckoningGateConfig)
