"""The experience map's configuration section (``expmap:``, Eq. 4.20), with the laser preset's scan graph (``expmap.scan_graph``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import ConfigSection

__all__ = ["ScanGraphConfig", "VisualScaleConfig", "ExpMapConfig"]


class ScanGraphConfig(ConfigSection):
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


class VisualScaleConfig(ConfigSection):
    """The odometry's scale measured by the downward camera (``expmap.visual_scale``;
    services/expmap/visual_scale.py documents the measurement)."""

    enabled: bool = Field(True, description="scale the map's odometry edges by the camera's measure of the "
                          "odometry's horizontal scale (needs expmap.image_topic and the DVL's altitude; on ten "
                          "held-out sim worlds mission 1's map ATE 0.14 m mean against 0.20 m without, at ~12 % "
                          "more CPU in all: docs/DECISIONS.md, issue 20 round 9; false: the odometry as it comes)")
    dvl_topic: str = Field("dvl_linkquest", description="LinkquestDvl key whose altitude (m over the floor) gives the "
                           "camera's height")
    focal_px: float = Field(405.64, gt=0, description="the camera's focal length (px; the Cala Viuda camera's fx)")
    camera_height_m: float = Field(0.2, description="the camera's offset below the DVL (m, body z): the camera's "
                                   "height over the floor is the altitude minus this")
    min_clearance_m: float = Field(0.3, gt=0, description="pairs where the camera is nearer the floor (m) are not "
                                   "measured")
    altitude_max_age_s: float = Field(2.0, gt=0, description="an altitude older than this (s) is not used")
    pair_every: int = Field(2, ge=1, description="measure one consecutive frame pair in this many (each measured "
                            "pair costs two frames' FFTs)")
    min_step_m: float = Field(0.02, gt=0, description="pairs over which the odometry moved less (m) are not used")
    inlier_band: float = Field(0.1, gt=0, lt=1, description="a pair counts when its camera/odometry ratio is within "
                               "this fraction of the median ratio of every pair so far")
    min_pairs: int = Field(200, ge=1, description="inlier pairs needed before the estimate is used")
    update_step: float = Field(0.001, gt=0, description="the map's odometry scale follows the estimate when it moved "
                               "by more than this fraction")
    max_deviation: float = Field(0.03, gt=0, lt=1, description="an estimate further than this fraction from 1 is not "
                                 "applied (the map keeps the odometry's own scale): a DVL is off by 1-2 %, so the "
                                 "camera is the one wrong (zoomed or edited frames, a wrong altitude); counted as "
                                 "visual_scale_implausible")


class ExpMapConfig(ConfigSection):
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
    map_correction_divisor: int = Field(20, ge=0, description="a map owed to a loop closure or a settled "
                                        "correction waits until nodes/N events have passed since the last map "
                                        "(0: at once): the maps' cost per mission hour stays flat (issue 21)")
    dead_reckoning_period_sec: float = Field(0.0, ge=0, description="dead_reckoning decimation in event time "
                                             "(0: one PoseStamped per Odometry)")
    map_path: str = Field("", description="load the experience map from here at start and save it at the end "
                          "(npz; empty: off)")
    # --- added for sessions (issue 20); see services/expmap/session_link.py
    map_sessions: bool = Field(False, description="a map loaded from map_path begins a new session: the run's "
                               "experiences sit in its own odometry frame, unlinked to the loaded ones until a "
                               "recognised place is verified by the sonar sweeps (poseidon run --map-dir sets it; "
                               "false: continue the loaded map in the same odometry frame)")
    session_jump_m: float = Field(0.0, ge=0, description="an odometry jump between consecutive events longer than "
                                  "this (m) begins a new session (a kidnapped vehicle, recovered by a verified link); "
                                  "0: never (the default: maps fed by hand take long steps; a hovering vehicle's "
                                  "events are < 1 m apart, so e.g. 5 suits the sim)")
    session_link_min_inliers: float = Field(0.75, ge=0, le=1, description="a session link needs a sweep "
                                            "registration trusted along both axes with at least this inlier "
                                            "fraction (above scan_min_inlier_fraction: a link moves a whole "
                                            "session)")
    session_link_rotate: bool = Field(True, description="a session link turns the newer session by the "
                                      "registration's rotation as well as moving it (false: translation only, "
                                      "the frames' headings taken as equal)")
    session_link_max_rotation_deg: float = Field(2.0, ge=0, description="heading disagreement searched by a "
                                                 "session link's registration (deg; the frames share the "
                                                 "AHRS heading, so a few degrees; loop closures keep "
                                                 "scan_max_rotation_deg)")
    session_link_rotation_step_deg: float = Field(0.25, gt=0, description="rotation step of that search (deg): "
                                                  "the link's rotation turns the whole session about the link "
                                                  "point, so finer than scan_rotation_step_deg")
    session_backfill_radius_m: float = Field(2.0, ge=0, description="after a session link, each experience the "
                                             "linked component made before the link is tried against the nearest "
                                             "experience of the older component within this horizontal distance "
                                             "(m, in the linked frame): a loop edge when their sweeps register as "
                                             "strictly as a link's (services/expmap/session_link.py); 0: off")
    session_backfill_spacing_m: float = Field(1.0, gt=0, description="at most one such try per this much "
                                              "horizontal distance along the linked component's path (m)")
    session_backfill_search_m: float = Field(1.0, gt=0, description="registration search of a backfill try around "
                                             "the two experiences' separation in the linked frame (m)")
    graph: Literal["experience_map", "scan_graph"] = Field(
        "experience_map", description="experience_map: Eq. 4.20 over positions, loops from LVC matches "
        "(services/expmap/graph.py); scan_graph: planar pose graph of registered range scans "
        "(services/expmap/scan_graph.py, the laser preset)")
    scan_graph: ScanGraphConfig = Field(default_factory=ScanGraphConfig)
    visual_scale: VisualScaleConfig = Field(default_factory=VisualScaleConfig)
