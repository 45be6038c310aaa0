"""The typed results of the evaluation cores: the dicts that :func:`eval.run_eval.evaluate_run`,
:func:`eval.summary.summarize_run`, :func:`eval.vpr.evaluate_image_sets` and
:func:`eval.vpr.evaluate_mission` return, and that the report, ``poseidon compare``, the run
summary, the demo and the benchmarks read.

Each is a :class:`typing.TypedDict`: still a plain ``dict`` (``json.dumps`` and ``r["key"]``
work as before; the ``--json`` keys are these keys), described here key by key with its unit.
``None`` is JSON ``null``: a figure that cannot be computed (no ground truth, no map, a zero
denominator).  Positions are NED metres.  How each figure is defined: the module named on
each class.

The annotations are evaluated (no ``from __future__ import annotations``) so that
``NotRequired`` shows in each class's ``__optional_keys__`` at run time.
"""
from typing import NotRequired, TypedDict

__all__ = [
    "RunEvaluation", "LoopClosures", "LoopClosureRow", "MapAndDeadReckoning", "AteFigures", "AteBlock",
    "RpeFigures", "RpeBlock", "StabilityProxies", "ProxyRatios", "FrontEnd", "DeadReckoningErrors",
    "SessionsBlock", "SessionLinkRow", "CrossLoopClosures", "LatencyBlock", "LatencyStageFigures",
    "MeanStd", "RelationFigures", "RelationErrors", "RelationsBlock", "RunSummary", "BackEnd", "LoopClosureCounts", "AuditFigures",
    "MatcherMetrics", "SdrOverlap", "Seconds", "RunLengthStats", "LvcRevisitScores", "LvcScores", "ModalityScores", "ImageSetChain",
    "ImageSetHtm", "ImageSetResult", "MissionScores", "MissionResult",
]


# --------------------------------------------------------------------------- poseidon eval


class LoopClosureRow(TypedDict):
    """One accepted loop closure of the final map (Tables 5.2-5.3; :mod:`eval.run_eval`)."""

    event_seq: int | None          # header seq of the experience_event at the current node's stamp (None: none)
    current_exp: int               # the newer end's node id
    matched_exp: int               # the older end's node id
    d_gt_m: float | None           # true distance between the two ends (m; None: no truth at an end)
    current_gt: list[float | None] | None   # true NED position of the current node (m)
    matched_gt: list[float | None] | None   # true NED position of the matched node (m)
    label: str | None              # "TP" (d_gt_m <= far_m), "FP", or None without truth


class LoopClosures(TypedDict):
    """The ``loop_closures`` block (:func:`eval.run_eval.loop_closure_table`): counts of the
    final map's loop-closure links, precision (true / labelled) and the recall over revisit
    opportunities (shares in [0, 1]; None when the denominator is 0)."""

    accepted: int
    true: int
    false: int
    unlabelled: int
    precision: float | None
    recall: float | None           # recalled / opportunities
    opportunities: int             # experiences with an older one (>= min_experience_age) within far_m
    recalled: int                  # opportunities that are the current end of a TP closure
    passes: int                    # runs of opportunities with consecutive node ids
    passes_closed: int             # passes holding the current end of a TP closure
    pass_recall: float | None      # passes_closed / passes
    min_experience_age: int        # the rule used (experiences)
    table: list[LoopClosureRow]


class MapAndDeadReckoning(TypedDict):
    """One figure of the map and of the dead reckoning (``ate_rmse_m``: m; ``drift_pct``: % of
    the true distance travelled); None when not computable."""

    map: float | None
    dead_reckoning: float | None


class AteFigures(TypedDict):
    """Absolute trajectory error after rigid alignment (:func:`eval.trajectory.ate`)."""

    rmse_m: float | None
    mean_m: float | None
    max_m: float | None
    final_m: float | None
    n: int                         # samples


class AteBlock(TypedDict):
    """The ``ate`` block: at which stamps (``map_nodes`` | ``truth_pose``; None: no truth) and
    the figures of the map and the dead reckoning (None: not computable)."""

    stamps: str | None
    map: AteFigures | None
    dead_reckoning: AteFigures | None


class RpeFigures(TypedDict):
    """Relative position error over ``delta_s`` (:func:`eval.trajectory.rpe`)."""

    rmse_m: float | None
    mean_m: float | None
    n: int                         # pairs of stamps
    delta_s: float                 # the interval (s)


class RpeBlock(TypedDict):
    """The ``rpe`` block: the interval (s) and the figures of the map and the dead reckoning."""

    delta_s: float
    map: RpeFigures | None
    dead_reckoning: RpeFigures | None


class ProxyRatios(TypedDict):
    """MAP value / reference value (ODOM or GT) of each proxy; None for a zero reference."""

    span_norm_map_odom: float | None
    volume_map_odom: float | None
    end_displacement_map_odom: float | None
    span_norm_map_gt: float | None
    volume_map_gt: float | None
    end_displacement_map_gt: float | None


class StabilityProxies(TypedDict):
    """Table 5.4's stability proxies (:func:`eval.run_eval.stability_proxies`); each figure per
    source ``map``, ``odom``, ``gt`` (a source present only when given)."""

    samples: int
    span_norm_m: dict[str, float | None]        # bounding-box diagonal (m)
    volume_m3: dict[str, float | None]          # bounding-box volume (m^3)
    end_displacement_m: dict[str, float | None]  # |last - first position| (m)
    ratios: ProxyRatios


class FrontEnd(TypedDict):
    """The ``front_end`` block (:func:`eval.run_eval.front_end_metrics`).  The revisit keys
    need ``truth/revisits``, the false-association keys ``truth/pose``."""

    frames: int                    # local_view_cells messages
    lvc_ids: int                   # distinct LVC ids
    new_id_fraction: float         # share of frames that created an id
    frame_matching: str            # "stamp" | "order": how LVC messages met camera-frame indices
    revisit_frames: NotRequired[int]
    revisit_recall: NotRequired[float | None]     # per-frame revisit recall (share)
    claimed_revisits: NotRequired[int]
    revisit_precision: NotRequired[float | None]  # per-frame revisit precision (share)
    min_gap_m: NotRequired[float | None]          # travel before a re-used id claims a revisit (m)
    matched_frames: NotRequired[int]
    false_association_rate: NotRequired[float | None]   # share of matches joining places > far_m apart


class DeadReckoningErrors(TypedDict):
    """The whole ``Odometry`` stream against ``truth/pose``, start-anchored, no rotation
    (:func:`eval.trajectory.anchored_errors`)."""

    ate_rmse_m: float | None
    final_error_m: float | None
    final_drift_pct: float | None  # final error / true distance travelled (%)
    max_error_m: float | None
    truth_distance_m: float | None


class CrossLoopClosures(TypedDict):
    """Loop closures between a loaded node and one of this run (:mod:`eval.sessions`)."""

    accepted: int
    true: int
    false: int
    unlabelled: int


class SessionLinkRow(TypedDict):
    """One session link of the final map (:mod:`eval.sessions`)."""

    session: int
    to_session: int
    source: int                    # node ids
    target: int
    stamp_s: float | None          # mission time of the link (s)
    error_m: float | None          # position error of the link's displacement (m)
    rotation_error_deg: float | None
    false: bool | None             # off by more than link_far_m or link_far_deg (None: no truth)
    time_to_link_s: float | None   # from first entering a mapped place to the link (s)
    inlier_fraction: float | None


class SessionsBlock(TypedDict):
    """The ``sessions`` block (:func:`eval.sessions.sessions_block`, which defines every key):
    counts, the ATE (m) of this run's nodes in the prior map's frame and of the dead reckoning
    placed at the first link (by the truth or by the link), node counts ``*_n``."""

    count: int
    loaded_nodes: int
    unlinked_nodes: int
    links: int
    false_links: int
    time_to_link_s: float | None
    link_error_m: float | None
    ate_prior_frame_m: float | None
    ate_prior_frame_n: int
    dr_ate_at_link_m: float | None
    dr_ate_at_link_n: int
    ate_prior_frame_after_link_m: float | None
    dr_ate_at_link_after_m: float | None
    dr_ate_by_link_m: float | None
    dr_ate_by_link_after_m: float | None
    cross_loop_closures: CrossLoopClosures
    table: list[SessionLinkRow]


class LatencyStageFigures(TypedDict):
    """One stage of a live run's latency (:class:`common.messages.LatencyStage`; ms)."""

    n: int
    unmatched: int
    p50_ms: float | None
    p95_ms: float | None
    p99_ms: float | None
    max_ms: float | None


class LatencyBlock(TypedDict):
    """The ``latency`` block of a live run: who measured it, the live player's pace (x real
    time, 0 for a sensor source) and the figures per stage."""

    source: str
    rate: float
    stages: dict[str, LatencyStageFigures]


class MeanStd(TypedDict):
    """Mean and standard deviation over the relations used (None: none used)."""

    mean: float | None
    std: float | None


class RelationFigures(TypedDict):
    """A trajectory's error against the Freiburg relations (:func:`eval.relations.relation_summary`):
    translation error (m), rotation error (deg), squared translation error (m^2)."""

    count: int                     # relations used
    outside: int                   # relations outside the trajectory's span
    trans_abs_m: MeanStd
    rot_abs_deg: MeanStd
    trans_sq_m2: MeanStd


class RelationErrors(RelationFigures):
    """:class:`RelationFigures` of a named trajectory (``relations`` / ``relations_odometry``)."""

    source: str                    # map_corrected | wheel_odometry | Odometry


class RelationsBlock(TypedDict):
    """The ``relations*`` keys of :class:`RunEvaluation` (:func:`eval.run_eval.relations_block`):
    the relations file, how many relations it holds, the errors of the map-corrected trajectory
    (None without a ``map`` message or ``Odometry``) and of the raw odometry (None without any)."""

    relations_file: str
    relations_in_file: int
    relations: RelationErrors | None
    relations_odometry: RelationErrors | None


class RunEvaluation(TypedDict):
    """:func:`eval.run_eval.evaluate_run` (``poseidon eval --json``; every key defined in
    :mod:`eval.run_eval`).  The ``relations*`` keys only with ``--relations``."""

    recording: str
    config_source: str             # recording | given | defaults
    duration_s: float | None       # first to last message (s)
    ground_truth: bool             # the run carries truth/pose
    far_m: float                   # d_gt threshold of a true loop closure (m)
    events: int
    events_per_s: float | None
    map_messages: int
    nodes: int
    edges: int
    mean_degree: float | None
    loop_closures: LoopClosures
    ate_rmse_m: MapAndDeadReckoning
    ate: AteBlock
    rpe: RpeBlock
    drift_pct: MapAndDeadReckoning
    truth_distance_m: float | None  # true distance between the first and last ATE stamp (m)
    proxies: StabilityProxies | None
    vpr_ok_ratio: float | None     # share of emissions passing the VPR window (Eqs. 4.11-4.12)
    front_end: FrontEnd | None
    dead_reckoning: DeadReckoningErrors | None
    sessions: SessionsBlock
    latency: LatencyBlock | None
    relations_file: NotRequired[str]
    relations_in_file: NotRequired[int]
    relations: NotRequired[RelationErrors | None]            # the map-corrected trajectory
    relations_odometry: NotRequired[RelationErrors | None]   # the raw odometry


# --------------------------------------------------------------------------- run summary


class LoopClosureCounts(TypedDict):
    """The summary's loop-closure figures (a part of :class:`LoopClosures`)."""

    accepted: int
    true: int
    false: int
    recall: float | None
    pass_recall: float | None


class AuditFigures(TypedDict):
    """The summary's audit figures (:func:`eval.audit.audit_run`): event-evidence F1, events
    without image, images without event, largest event interval (s)."""

    f1: float | None
    missing_events: int
    missing_images: int
    dt_max_s: float | None


class BackEnd(TypedDict):
    """The summary's back-end block (figures of :class:`RunEvaluation` and the audit)."""

    events: int
    events_per_s: float | None
    nodes: int
    edges: int
    mean_degree: float | None
    loop_closures: LoopClosureCounts
    ate_rmse_m: MapAndDeadReckoning
    drift_pct: MapAndDeadReckoning
    audit: AuditFigures


class RunSummary(TypedDict, total=False):
    """:func:`eval.summary.summarize_run` (the ``"evaluation"`` block of ``poseidon run --json``):
    each block only when the run has its inputs."""

    front_end: FrontEnd
    dead_reckoning: DeadReckoningErrors
    back_end: BackEnd


# --------------------------------------------------------------------------- poseidon vpr


class MatcherMetrics(TypedDict):
    """One matcher's precision-recall figures (:func:`eval.vpr_metrics.vpr_metrics`; shares)."""

    auc: float                     # area under the precision-recall curve (average precision)
    recall_at_p100: float          # largest recall at precision 1
    best_f1: float
    n_predicted: int               # queries with a prediction


class SdrOverlap(TypedDict):
    """Mean SDR overlap |A_q & A_r| / |A_q| of same-place and different-place pairs (None: no pair)."""

    same_place: float | None
    different_place: float | None


class Seconds(TypedDict):
    """Wall time (s) of the embedding and of the HTM passes (the default and the chains)."""

    embed: float
    htm: float


class RunLengthStats(TypedDict):
    """Runs of identical consecutive LVC ids (:func:`eval.vpr_htm.run_length_stats`): median and
    mean length (frames), share of frames in runs of >= 3."""

    median: float
    mean: float
    frames_in_runs_ge3: float


class LvcRevisitScores(TypedDict):
    """LVC-id revisit figures on a mission (:func:`eval.vpr_mission.lvc_revisit_scores`; shares
    in [0, 1], 0 for a zero denominator; counts in frames)."""

    lvc_recall: float              # per-frame revisit recall
    lvc_precision: float           # per-frame revisit precision
    n_revisit_frames: int
    n_claimed_revisits: int
    n_correct_claims: int
    lvc_pair_precision: float      # frame pairs with the same id
    lvc_pair_recall: float


class LvcScores(LvcRevisitScores):
    """The LVC figures of one HTM over a mission's stream (:func:`eval.vpr_mission.mission_htm`):
    the revisit figures, then the HTM's own."""

    n_lvc: int                     # LVC ids created
    lvc_run_length: RunLengthStats
    tm_anomaly_mean: float
    sp_columns_used: int
    decisions: dict[str, int]      # frames per rule: gate, tm, seqmem, prior, new
    frames_stored: int             # frames the sequence memory holds at the end
    tm_decision_share: float       # tm / (all but new)


class ModalityScores(LvcScores):
    """One stream of the ``modalities`` table: its LVC figures and its ``htm_lvc`` matcher."""

    htm_lvc: MatcherMetrics


class ImageSetChain(TypedDict):
    """One chain's figures on image sets: LVC ids, accepted queries, decisions per rule."""

    n_lvc: int
    htm_query_matched: int
    decisions: dict[str, int]


class ImageSetHtm(ImageSetChain):
    """The HTM figures of an image-set run: the default's and, per named chain, the chain's."""

    chains: dict[str, ImageSetChain]


class ImageSetResult(TypedDict):
    """:func:`eval.vpr.evaluate_image_sets` (``poseidon vpr --ref --query --json``; defined in
    :mod:`eval.vpr`).  The HTM keys only without ``--no-htm``."""

    matchers: dict[str, MatcherMetrics]
    n_ref: int
    n_query: int
    n_query_with_gt: int
    weights: str                   # "seeded" | the weights file
    backbone: str
    embedding_dim: int
    embedding_norm: str            # none | running | fixed
    sdr_bits: int                  # active bits of a camera SDR (2k)
    sdr_length: int
    ground_truth: str              # "file name +-N" | the ground-truth file
    sdr_overlap: SdrOverlap
    n_lvc: NotRequired[int]
    htm_query_matched: NotRequired[int]
    decisions: NotRequired[dict[str, int]]
    chains: NotRequired[dict[str, ImageSetChain]]
    seconds: Seconds


class MissionScores(TypedDict):
    """The figures of one mission (:func:`eval.vpr_mission.score_mission`; defined in
    :mod:`eval.vpr`).  The LVC figures (those of :class:`LvcScores`, of the fused code),
    ``modalities`` and ``chains`` only without ``--no-htm``."""

    n_frames: int
    n_revisit_frames: int
    min_gap_m: float               # travel before an earlier frame is a candidate (m)
    dr_positions: int              # frames with a dead-reckoned position
    sdr_overlap: SdrOverlap        # camera SDRs, candidate pairs
    fused_bits_mean: float         # active bits of a fused SDR
    encoder_counters: dict[str, int]
    lvc_recall: NotRequired[float]
    lvc_precision: NotRequired[float]
    n_claimed_revisits: NotRequired[int]
    n_correct_claims: NotRequired[int]
    lvc_pair_precision: NotRequired[float]
    lvc_pair_recall: NotRequired[float]
    n_lvc: NotRequired[int]
    lvc_run_length: NotRequired[RunLengthStats]
    tm_anomaly_mean: NotRequired[float]
    sp_columns_used: NotRequired[int]
    decisions: NotRequired[dict[str, int]]
    frames_stored: NotRequired[int]
    tm_decision_share: NotRequired[float]
    modalities: NotRequired[dict[str, ModalityScores]]   # fused_<fusion_mode>, camera, sonar
    chains: NotRequired[dict[str, LvcScores]]
    matchers: dict[str, MatcherMetrics]
    seconds: Seconds
    weights: str
    embedding_dim: int


class MissionResult(MissionScores):
    """:func:`eval.vpr.evaluate_mission` (``poseidon vpr --mission --json``): the mission's
    figures (:class:`MissionScores`) with the recording, the backbone and the embedding
    standardisation (none | running | fixed) named first."""

    mission: str
    backbone: str
    embedding_norm: str
