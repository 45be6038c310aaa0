"""The experience map's configuration section (``expmap:``, Eq. 4.20): loop closure, corrections, experience images, sonar sweeps, sessions, the laser preset's scan graph (``expmap.scan_graph``) and the camera's odometry scale (``expmap.visual_scale``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import ConfigSection

__all__ = ["ScanGraphConfig", "VisualScaleConfig", "LoopsConfig", "CorrectionsConfig", "ExperienceImageConfig",
           "ScanConfig", "SessionsConfig", "ExpMapConfig"]


class ScanGraphConfig(ConfigSection):
    """Planar experience map of a range sensor (``expmap.graph: scan_graph``;
    services/expmap/scan_graph.py documents every rule)."""

    sensor_offset: list[float] | None = Field(None, min_length=3, max_length=3,
                                              description="the range sensor's pose on the robot: x m forward, y m "
                                              "left, yaw deg; null: the input recording's own (a CARMEN import's "
                                              "laser_offsets metadata), else 0 0 0 (launcher/run.py) [m, m, deg]")
    max_range_m: float = Field(20.0, gt=0, description="returns farther than this are not used [m]")
    min_range_m: float = Field(0.05, ge=0, description="returns nearer than this are not used [m]")
    voxel_m: float = Field(0.05, gt=0, description="one scan point per square of this size [m]")
    min_points: int = Field(30, ge=3, description="fewest points a scan or local map needs to be registered "
                            "[points]")
    local_map_experiences: int = Field(10, ge=1, description="previous experiences whose scans form the chain "
                                       "registration's local map [experiences]")
    chain_window_m: float = Field(0.3, gt=0, description="chain registration search window around the odometry "
                                  "[m]")
    chain_window_deg: float = Field(6.0, ge=0, description="chain registration heading window [deg]")
    chain_coarse_cell_m: float = Field(0.05, gt=0, description="coarse grid of the chain registration [m]")
    chain_coarse_yaw_step_deg: float = Field(1.0, gt=0, description="heading step of the chain registration's "
                                             "coarse search [deg]")
    chain_prior_sigma_m: float = Field(0.2, ge=0, description="odometry prior of the chain registration (0: none) "
                                       "[m]")
    chain_prior_sigma_deg: float = Field(4.0, ge=0, description="odometry prior of the chain registration [deg]")
    chain_min_score: float = Field(0.3, ge=0, le=1, description="a chain registration scoring less keeps the "
                                   "odometry increment [score]")
    chain_max_spread_m: float = Field(0.0, ge=0, description="a chain registration whose near-best translations "
                                      "spread more keeps the odometry's translation and its heading only (0: off) "
                                      "[m]")
    fine_cell_m: float = Field(0.025, gt=0, description="fine grid of every registration [m]")
    fine_sigma_m: float = Field(0.05, gt=0, description="likelihood-field sigma of the fine grid [m]")
    fine_yaw_step_deg: float = Field(0.25, gt=0, description="heading step of the fine search [deg]")
    odometry_at_stamps: bool = Field(True, description="place each scan, and each experience's frame, at the "
                                     "odometry interpolated to its own stamp (an experience waits for the next "
                                     "Odometry); false: at the newest Odometry before it (services/expmap/laser_input.py)")
    scan_poses: bool = Field(True, description="register every scan against the newest experience's local map and "
                             "publish its pose in that experience's frame (scan_pose); the map-corrected trajectory "
                             "takes its heading between experiences from them (services/expmap/scan_poses.py)")
    scan_pose_window_m: float = Field(0.2, gt=0, description="scan pose search window around the odometry [m]")
    scan_pose_window_deg: float = Field(4.0, ge=0, description="scan pose heading window around the odometry [deg]")
    scan_pose_prior_sigma_m: float = Field(0.05, ge=0, description="odometry prior of a scan pose (0: none) [m]")
    scan_pose_prior_sigma_deg: float = Field(20.0, ge=0, description="odometry prior of a scan pose (0: none) [deg]")
    scan_sigma_m: float = Field(0.05, gt=0, description="std of a registered edge's translation [m]")
    scan_sigma_deg: float = Field(1.0, gt=0, description="std of a registered edge's heading [deg]")
    odom_sigma_m: float = Field(0.1, gt=0, description="std of an odometry edge's translation [m]")
    odom_sigma_deg: float = Field(3.0, gt=0, description="std of an odometry edge's heading [deg]")
    loop_every: int = Field(1, ge=1, description="loop search on every k-th experience [experiences]")
    loop_min_route_m: float = Field(10.0, ge=0, description="a loop candidate is at least this far back along the "
                                    "odometry route [m]")
    loop_radius_m: float = Field(0.5, gt=0, description="loop search radius right after a closure [m]")
    loop_radius_growth: float = Field(0.03, ge=0, description="loop search radius growth per metre travelled "
                                      "since [m/m]")
    loop_radius_max_m: float = Field(4.0, gt=0, description="largest loop search radius [m]")
    loop_max_heading_diff_deg: float = Field(60.0, gt=0, le=180, description="a geometric loop candidate faces "
                                             "within this of the current experience [deg]")
    loop_lvc_radius_m: float = Field(8.0, ge=0, description="an experience of the same LVC id is tried up to this "
                                     "far in the map (appearance proposes, geometry verifies) [m]")
    loop_window_deg: float = Field(8.0, ge=0, description="loop registration heading window after a closure [deg]")
    loop_window_growth_deg_per_m: float = Field(0.1, ge=0, description="growth of that window per metre "
                                                "travelled since [deg/m]")
    loop_window_max_deg: float = Field(20.0, ge=0, description="largest loop registration heading window [deg]")
    loop_coarse_cell_m: float = Field(0.15, gt=0, description="coarse grid of the loop registration [m]")
    loop_coarse_yaw_step_deg: float = Field(1.0, gt=0, description="heading step of the loop registration's "
                                            "coarse search [deg]")
    loop_query_experiences: int = Field(4, ge=0, description="predecessors of the current experience in the query "
                                        "[experiences]")
    loop_reference_experiences: int = Field(6, ge=0, description="experiences either side of the candidate in the "
                                            "reference [experiences]")
    loop_query_voxel_m: float = Field(0.1, gt=0, description="query points thinned to one per square of this size "
                                      "[m]")
    loop_coarse_voxel_m: float = Field(0.25, ge=0, description="... and for the coarse search to one per square of "
                                       "this size (0: as the fine search) [m]")
    loop_min_score: float = Field(0.5, ge=0, le=1, description="fine score a loop registration needs [score]")
    loop_max_spread_m: float = Field(0.3, gt=0, description="largest principal std of the near-best coarse "
                                     "translations: a corridor's slide is not a loop [m]")
    loop_max_second_ratio: float = Field(0.9, gt=0, description="reject a loop registration whose best score "
                                         "more than 0.5 m from the best pose reaches this fraction of the best "
                                         "(repeated structure) [fraction]")
    loop_max_free_space: float = Field(0.05, ge=0, le=1, description="reject a loop registration that puts more "
                                       "than this fraction of the query's points where a reference scan saw "
                                       "through [fraction]")
    loop_free_space_margin_m: float = Field(0.3, ge=0, description="a point counts as seen through when the "
                                            "reference return on its bearing is this much farther [m]")
    loop_confirm_within: int = Field(10, ge=1, description="a verified loop waits this many experiences for a "
                                     "confirming one [experiences]")
    loop_confirm_m: float = Field(0.1, gt=0, description="two loop measurements agree within this translation [m]")
    loop_confirm_deg: float = Field(1.0, gt=0, description="... and this heading [deg]")
    relax_threshold_m: float = Field(0.02, ge=0, description="relax when a new loop edge's translation residual "
                                     "exceeds this [m]")
    relax_threshold_deg: float = Field(0.3, ge=0, description="... or its heading residual this [deg]")
    relax_iterations: int = Field(10, ge=1, description="Gauss-Newton iterations per relaxation [iterations]")
    loop_max_residual: float = Field(3.0, ge=0, description="take back a closure whose loop edges keep a larger "
                                     "Mahalanobis residual after relaxation (0: off) [sigma]")
    huber: float = Field(3.0, ge=0, description="Huber threshold on an edge's Mahalanobis residual (0: off) [sigma]")
    optimizer: Literal["gauss_newton", "gtsam_lm"] = Field(
        "gauss_newton", description="solver of the relaxation: gauss_newton (ours, services/expmap/pose_graph.py) or "
        "gtsam_lm (GTSAM's Levenberg-Marquardt on Pose2 between factors, the same objective; "
        "services/expmap/gtsam_graph.py; docs/DECISIONS.md 'Pose-graph optimiser: ours and GTSAM')")


class VisualScaleConfig(ConfigSection):
    """The odometry's scale measured by the downward camera (``expmap.visual_scale``;
    services/expmap/visual_scale.py documents the measurement)."""

    enabled: bool = Field(True, description="scale the map's odometry edges by the camera's measure of the "
                          "odometry's horizontal scale (needs expmap.image.topic and the DVL's altitude; on ten "
                          "held-out sim worlds mission 1's map ATE 0.14 m mean against 0.20 m without, at ~12 % "
                          "more CPU in all: docs/DECISIONS.md; false: the odometry as it comes)")
    dvl_topic: str = Field("dvl_linkquest", description="LinkquestDvl key whose altitude over the floor gives the "
                           "camera's height")
    focal_px: float = Field(405.64, gt=0, description="the camera's focal length (the Cala Viuda camera's fx) [px]")
    camera_height_m: float = Field(0.2, description="the camera's offset below the DVL (body z): the camera's "
                                   "height over the floor is the altitude minus this [m]")
    min_clearance_m: float = Field(0.3, gt=0, description="pairs where the camera is nearer the floor are not "
                                   "measured [m]")
    altitude_max_age_s: float = Field(2.0, gt=0, description="an altitude older than this is not used [s]")
    pair_every: int = Field(4, ge=1, description="measure one consecutive frame pair in this many (each measured "
                            "pair costs two frames' FFTs; 4 with downsample 2: a fifth of the CPU of 2 at full "
                            "resolution, held-out map ATE in docs/DECISIONS.md) [pairs]")
    downsample: int = Field(2, ge=1, le=8, description="frames are reduced to means of downsample x downsample "
                            "pixel blocks before the shift is measured (its filters scaled alike; 1: full "
                            "resolution) [pixels]")
    min_step_m: float = Field(0.02, gt=0, description="pairs over which the odometry moved less are not used [m]")
    inlier_band: float = Field(0.1, gt=0, lt=1, description="a pair counts when its camera/odometry ratio is within "
                               "this fraction of the median ratio of every pair so far [fraction]")
    min_pairs: int = Field(200, ge=1, description="inlier pairs needed before the estimate is used [pairs]")
    update_step: float = Field(0.001, gt=0, description="the map's odometry scale follows the estimate when it moved "
                               "by more than this fraction [fraction]")
    max_deviation: float = Field(0.03, gt=0, lt=1, description="an estimate further than this fraction from 1 is not "
                                 "applied (the map keeps the odometry's own scale): a DVL is off by 1-2 %, so the "
                                 "camera is the one wrong (zoomed or edited frames, a wrong altitude); counted as "
                                 "visual_scale_implausible [fraction]")


class LoopsConfig(ConfigSection):
    """Loop closure of the experience map (Table 4.1; services/expmap/graph.py, services/expmap/loop_policy.py)."""

    confirmations: int = Field(2, ge=1, description="consecutive events that must confirm a loop before it is "
                               "closed [events]")
    confirmation_gap: int = Field(10, ge=0, description="consecutive events confirm a loop when their matched "
                                  "nodes are at most this many experiences apart on the old route [experiences]")
    edge_weight: float = Field(1.0, gt=0, description="w of a loop-closure edge in Eq. 4.20 (odometry edges: 1)")
    place_radius_m: float = Field(0.0, ge=0, description="a loop closure pulls the two experiences to within "
                                  "this distance instead of onto each other; 0: zero-displacement loop edge "
                                  "(services/expmap/graph.py ExperienceMap.loop_delta) [m]")
    scan_matching: bool = Field(True, description="measure a loop edge's displacement by registering the sonar "
                                "sweeps kept with the two experiences (services/expmap/scans.py, expmap.scan); "
                                "false: the dissertation's zero-displacement loop edge")


class CorrectionsConfig(ConfigSection):
    """When a loop closure corrects the map, and how fast the map moves toward the corrected
    positions (Eq. 4.20; services/expmap/relaxation.py)."""

    min_route_len: float = Field(250, ge=0, description="a loop is closed only when the route between its two "
                                 "experiences is at least this long, counted along the current graph "
                                 "[experiences]")
    max_norm: float = Field(20.0, gt=0, description="a correction moving a node farther than this is scaled down "
                            "uniformly to it [m]")
    max_step: float = Field(0.05, gt=0, description="no node moves more than this per relaxation iteration [m]")
    min_interval_sec: float = Field(15.0, ge=0, description="event time that must pass between two corrections "
                                    "[s]")
    iterations_per_event: int = Field(10, ge=1, description="relaxation iterations per accepted event, each "
                                      "moving a node by at most max_step [iterations]")
    optimizer: Literal["series_reduction", "gtsam_lm"] = Field(
        "series_reduction", description="solver of Eq. 4.20's optimum: series_reduction (ours, exact, "
        "services/expmap/relaxation.py) or gtsam_lm (GTSAM's Levenberg-Marquardt on Point3 between factors over "
        "every node, the same objective; services/expmap/gtsam_graph.py)")


class ExperienceImageConfig(ConfigSection):
    """The camera frame published with each experience (``experience_image``; services/expmap/node.py)."""

    topic: str = Field("camera/image_raw", description="camera key of the experience images (and of "
                       "expmap.visual_scale)")
    transport: Literal["raw"] = Field("raw", description="image transport of the camera key")
    publish_experience: bool = Field(True, description="publish the camera frame nearest each experience event "
                                     "as experience_image")
    buffer_size: int = Field(400, ge=1, description="at most this many events wait for their image [events]")
    sync_slop: float = Field(0.75, ge=0, description="an image belongs to an event when their stamps are at most "
                             "min(sync.sync_stale_sec, this) apart [s]")


class ScanConfig(ConfigSection):
    """The imaging-sonar sweeps kept with the experiences and their registration (services/expmap/scans.py)."""

    topic: str = Field("sonar_micron", description="horizontal imaging sonar (RangeImageBeam) whose sweeps are "
                       "kept with the experiences")
    sweep_deg: float = Field(360.0, gt=0, le=720, description="head travel of the sweep kept per experience [deg]")
    min_range_m: float = Field(1.0, ge=0, description="echoes nearer than this are the transducer ring-down [m]")
    echo_threshold: float = Field(80.0, ge=0, description="a beam's strongest bin must reach this intensity to "
                                  "count as a wall echo [beam_data units]")
    cell_m: float = Field(0.1, gt=0, description="grid cell of the sweep registration [m]")
    search_radius_m: float = Field(4.0, gt=0, description="registration search around both hypotheses (same "
                                   "place; current map separation) [m]")
    max_rotation_deg: float = Field(2.0, ge=0, description="heading disagreement searched between two sweeps "
                                    "[deg]")
    rotation_step_deg: float = Field(1.0, gt=0, description="rotation step of that search [deg]")
    min_points: int = Field(50, ge=3, description="fewest wall echoes a sweep needs to be registered [points]")
    min_inlier_fraction: float = Field(0.65, ge=0, le=1, description="fraction of aligned points within 2 cells "
                                       "of the stored sweep for a trusted registration (true closures of the "
                                       "seed-1234 missions: 0.76-1.00; sweeps of different rooms: 0.2-0.56) "
                                       "[fraction]")
    reject_inconsistent: bool = Field(True, description="reject a loop closure whose two sweeps do not fit "
                                      "(fewer than min_inlier_fraction inliers): geometric verification")
    ambiguity_margin_m: float = Field(0.01, ge=0, description="translations whose cost is within this of the "
                                      "best are near-best [m]")
    max_ambiguity_m: float = Field(0.3, gt=0, description="a principal axis along which the near-best "
                                   "translations spread more (std) is left to the map [m]")


class SessionsConfig(ConfigSection):
    """Maps of several sessions: a continued map or a kidnapped vehicle, linked by a verified place
    (services/expmap/session_link.py)."""

    begin_on_load: bool = Field(False, description="a map loaded from expmap.map_path begins a new session: the "
                                "run's experiences sit in its own odometry frame, unlinked to the loaded ones "
                                "until a recognised place is verified by the sonar sweeps (poseidon run --map-dir "
                                "sets it; false: continue the loaded map in the same odometry frame)")
    jump_m: float = Field(0.0, ge=0, description="an odometry jump between consecutive events longer than this "
                          "begins a new session (a kidnapped vehicle, recovered by a verified link); 0: never (the "
                          "default: maps fed by hand take long steps; a hovering vehicle's events are < 1 m apart, "
                          "so e.g. 5 suits the sim) [m]")
    link_min_inliers: float = Field(0.75, ge=0, le=1, description="a session link needs a sweep registration "
                                    "trusted along both axes with at least this inlier fraction (above "
                                    "expmap.scan.min_inlier_fraction: a link moves a whole session) [fraction]")
    link_rotate: bool = Field(True, description="a session link turns the newer session by the registration's "
                              "rotation as well as moving it (false: translation only, the frames' headings taken "
                              "as equal)")
    link_max_rotation_deg: float = Field(2.0, ge=0, description="heading disagreement searched by a session "
                                         "link's registration (the frames share the AHRS heading, so a few degrees; "
                                         "loop closures keep expmap.scan.max_rotation_deg) [deg]")
    link_rotation_step_deg: float = Field(0.25, gt=0, description="rotation step of that search: the link's "
                                          "rotation turns the whole session about the link point, so finer than "
                                          "expmap.scan.rotation_step_deg [deg]")
    backfill_radius_m: float = Field(2.0, ge=0, description="after a session link, each experience the linked "
                                     "component made before the link is tried against the nearest experience of "
                                     "the older component within this horizontal distance (in the linked frame): "
                                     "a loop edge when their sweeps register as strictly as a link's "
                                     "(services/expmap/session_link.py); 0: off [m]")
    backfill_spacing_m: float = Field(1.0, gt=0, description="at most one such try per this much horizontal "
                                      "distance along the linked component's path [m]")
    backfill_search_m: float = Field(1.0, gt=0, description="registration search of a backfill try around the "
                                     "two experiences' separation in the linked frame [m]")


class ExpMapConfig(ConfigSection):
    """The experience map (Section 4.2.4): experiences, loop closure, relaxation, sessions."""

    match_threshold: float = Field(0.98, ge=0, description="score lv_factor * [same LVC] + pc_factor * proximity "
                                   "an old experience needs to match the new one (Table 4.1)")
    lv_factor: float = Field(0.5, ge=0, description="weight of the same-LVC term of the match score (Table 4.1)")
    pc_factor: float = Field(0.5, ge=0, description="weight of the pose-cell proximity term of the match score "
                             "(Table 4.1)")
    min_experience_age: int = Field(200, ge=0, description="an experience matches only experiences at least this "
                                    "many events older [events]")
    pc_proximity_sigma_cells: float = Field(100.0, gt=0, description="pose-cell proximity exp(-d^2/2s^2) of the "
                                            "wrap-aware centroid distance d (100: proximity > 0.99 anywhere on the "
                                            "(15,15,15,8) lattice, so a same-LVC node matches and the sonar "
                                            "registration verifies the geometry; 3.5: within 1 cell) [cells]")
    map_publish_every: int = Field(100, ge=0, description="publish the map every max(N, nodes/10) events (0: only "
                                   "after loop closures, settled relaxations and at the end) [events]")
    map_correction_divisor: int = Field(20, ge=0, description="a map owed to a loop closure or a settled "
                                        "correction waits until nodes/N events have passed since the last map "
                                        "(0: at once): the maps' cost per mission hour stays flat")
    dead_reckoning_period_sec: float = Field(0.0, ge=0, description="dead_reckoning decimation in event time "
                                             "(0: one PoseStamped per Odometry) [s]")
    map_path: str = Field("", description="load the experience map from here at start and save it at the end "
                          "(npz; empty: off)")
    graph: Literal["experience_map", "scan_graph"] = Field(
        "experience_map", description="experience_map: Eq. 4.20 over positions, loops from LVC matches "
        "(services/expmap/graph.py); scan_graph: planar pose graph of registered range scans "
        "(services/expmap/scan_graph.py, the laser preset)")
    loops: LoopsConfig = Field(default_factory=LoopsConfig)
    corrections: CorrectionsConfig = Field(default_factory=CorrectionsConfig)
    image: ExperienceImageConfig = Field(default_factory=ExperienceImageConfig)
    scan: ScanConfig = Field(default_factory=ScanConfig)
    sessions: SessionsConfig = Field(default_factory=SessionsConfig)
    scan_graph: ScanGraphConfig = Field(default_factory=ScanGraphConfig)
    visual_scale: VisualScaleConfig = Field(default_factory=VisualScaleConfig)
