"""``poseidon eval``'s sessions block (eval/sessions.py): link error, false links, time to
link and the ATE in the prior map's frame, on a hand-made two-mission map."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from common.messages import ExperienceMap, ExperienceNode, Header, MapSessions, SessionLinkInfo
from eval.results import SessionsBlock
from eval.rundata import RunData
from eval.sessions import sessions_block
from eval.trajectory import Trajectory
from system.config import PoseidonConfig
from tests.eval.shapes import assert_shape

SEC = 1_000_000_000


def enu(p: np.ndarray) -> list[float]:
    return [float(p[1]), float(p[0]), float(-p[2])]


def run_of(truth: np.ndarray, stamps: np.ndarray) -> RunData:
    run = RunData(path=Path("hand.mcap"), config=PoseidonConfig(), config_source="defaults")
    run.truth = Trajectory(stamps, truth, source="truth/pose")
    run.truth_yaw = np.zeros(len(stamps))
    run.start_ns = int(stamps[0])
    return run


def two_missions(delta_error_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 map_offset_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[RunData, RunData]:
    """Prior mission: 10 nodes along north at east 0; this mission: 10 nodes along north at
    east 0.5, same stamps (both missions start at the same time), linked 3 -> 13."""
    ts = np.arange(40) * SEC // 4
    prior = run_of(np.c_[ts / SEC, np.zeros(40), np.full(40, 5.0)], ts)
    run = run_of(np.c_[ts / SEC, np.full(40, 0.5), np.full(40, 5.0)], ts)
    nodes = []
    for i in range(20):
        k = i % 10
        g = np.array([float(k), 0.0 if i < 10 else 0.5, 5.0])
        if i >= 10:
            g = g + np.asarray(map_offset_ned)
        nodes.append(ExperienceNode(id=i, lvc_id=i, position=enu(g), yaw=math.pi / 2, stamp=k * SEC))
    run.final_map = ExperienceMap(header=Header(seq=0, stamp=9 * SEC, frame_id="map"), nodes=nodes, links=[])
    d = np.array([0.0, 0.5, 0.0]) + np.asarray(delta_error_ned)
    run.final_sessions = MapSessions(
        header=Header(seq=0, stamp=9 * SEC, frame_id="map"), node_session=[0] * 10 + [1] * 10, loaded_nodes=10,
        links=[SessionLinkInfo(session=1, to_session=0, source=3, target=13, stamp=3 * SEC, delta=enu(d),
                               shift=[0.0, 0.0, 0.0], rotation_deg=0.0, inlier_fraction=0.9)])
    return run, prior


def test_a_correct_link_and_the_map_in_the_prior_frame() -> None:
    run, prior = two_missions()
    s = sessions_block(run, prior)
    assert_shape(s, SessionsBlock)
    assert (s["count"], s["links"], s["false_links"], s["loaded_nodes"], s["unlinked_nodes"]) == (2, 1, 0, 10, 0)
    assert s["link_error_m"] < 1e-6 and s["table"][0]["rotation_error_deg"] < 1e-6
    assert s["ate_prior_frame_m"] < 1e-6 and s["ate_prior_frame_n"] == 10
    # this mission is within 2 m of the prior nodes from its start: entered at 0 s, linked at 3 s
    assert s["time_to_link_s"] == 3.0


def test_a_link_off_by_more_than_2_m_is_false_and_the_offset_shows_in_the_prior_frame_ate() -> None:
    run, prior = two_missions(delta_error_ned=(0.0, 2.5, 0.0), map_offset_ned=(0.0, 2.5, 0.0))
    s = sessions_block(run, prior)
    assert s["false_links"] == 1 and abs(s["link_error_m"] - 2.5) < 1e-6 and s["table"][0]["false"]
    assert abs(s["ate_prior_frame_m"] - 2.5) < 1e-6


def test_without_the_prior_recording_the_loaded_ends_have_no_truth() -> None:
    run, _ = two_missions()
    s = sessions_block(run, None)
    assert s["links"] == 1 and s["link_error_m"] is None and s["table"][0]["false"] is None
    assert s["ate_prior_frame_m"] is None


def test_a_single_session_map() -> None:
    run, _ = two_missions()
    run.final_sessions = None
    s = sessions_block(run)
    assert (s["count"], s["links"], s["time_to_link_s"]) == (1, 0, None)


def test_loop_closures_with_a_loaded_end_are_judged_here() -> None:
    from common.messages import ExperienceLink
    run, prior = two_missions()
    assert run.final_map is not None
    run.final_map.links = [ExperienceLink(source=3, target=13, delta=[0.0, 0.0, 0.0], duration_s=0.0, weight=1.0,
                                          loop_closure=True),                     # the session link itself
                           ExperienceLink(source=5, target=15, delta=[0.0, 0.0, 0.0], duration_s=0.0, weight=1.0,
                                          loop_closure=True),                     # 0.5 m apart: true
                           ExperienceLink(source=0, target=19, delta=[0.0, 0.0, 0.0], duration_s=0.0, weight=1.0,
                                          loop_closure=True),                     # 9 m apart: false
                           ExperienceLink(source=1, target=8, delta=[0.0, 0.0, 0.0], duration_s=0.0, weight=1.0,
                                          loop_closure=True)]                     # the prior map's own: not counted
    s = sessions_block(run, prior)
    assert s["cross_loop_closures"] == {"accepted": 2, "true": 1, "false": 1, "unlabelled": 0}


def _with_dr(run: RunData, turn_deg: float, yaw_bias_deg: float) -> RunData:
    """This mission's dead reckoning: its truth turned by ``turn_deg`` about the start and
    shifted, reporting a heading off by ``yaw_bias_deg`` from its own track (published ENU)."""
    from common.geometry import quaternion_of_yaw
    from eval.trajectory import PoseSeries
    assert run.truth is not None
    t = np.asarray(run.truth.t, np.int64)
    a = math.radians(turn_deg)
    R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    p_ned = run.truth.positions_at(t) @ R.T + np.array([7.0, -3.0, 0.0])
    psi = a + math.radians(yaw_bias_deg)            # NED heading (truth: north, 0)
    run.odometry_poses = PoseSeries(t, np.array([enu(p) for p in p_ned]),
                                    np.array([quaternion_of_yaw(math.pi / 2 - psi)] * len(t)))
    return run


def test_dead_reckoning_aligned_at_the_link() -> None:
    """``dr_ate_at_link_m``: the dead reckoning's pose at the link put on the truth; a rigidly
    displaced dead reckoning is then exact, a heading error at the link turns it about there."""
    run, prior = two_missions()
    s = sessions_block(_with_dr(run, 10.0, 0.0), prior)
    assert s["dr_ate_at_link_n"] == 10 and s["dr_ate_at_link_m"] < 1e-6
    run, prior = two_missions()
    s = sessions_block(_with_dr(run, 10.0, 5.0), prior)
    k = np.arange(10) - 3.0                          # metres along the track from the link node
    want = math.sqrt(float(np.mean((2 * np.abs(k) * math.sin(math.radians(2.5))) ** 2)))
    assert abs(s["dr_ate_at_link_m"] - want) < 1e-3
    after = math.sqrt(float(np.mean((2 * np.abs(k[3:]) * math.sin(math.radians(2.5))) ** 2)))
    assert abs(s["dr_ate_at_link_after_m"] - after) < 1e-3 and s["ate_prior_frame_after_link_m"] < 1e-6
    run, prior = two_missions()                      # no odometry recorded: not computable
    assert sessions_block(run, prior)["dr_ate_at_link_m"] is None


def test_dead_reckoning_placed_by_the_link_carries_the_maps_error_at_the_link() -> None:
    """``dr_ate_by_link_m``: the dead reckoning's pose at the link put on the link node's pose in
    the final map, not on the truth.  A map whose new session sits 0.4 m east of the truth moves
    that dead reckoning 0.4 m too (the truth-anchored one stays exact); a heading error of the
    dead reckoning turns it about the link node, as for ``dr_ate_at_link_m``."""
    run, prior = two_missions(map_offset_ned=(0.0, 0.4, 0.0))
    s = sessions_block(_with_dr(run, 10.0, 0.0), prior)
    assert s["dr_ate_at_link_m"] < 1e-6
    assert abs(s["dr_ate_by_link_m"] - 0.4) < 1e-6 and abs(s["dr_ate_by_link_after_m"] - 0.4) < 1e-6
    assert abs(s["ate_prior_frame_m"] - 0.4) < 1e-6
    run, prior = two_missions()
    s = sessions_block(_with_dr(run, 10.0, 5.0), prior)
    assert abs(s["dr_ate_by_link_m"] - s["dr_ate_at_link_m"]) < 1e-6 and s["dr_ate_by_link_m"] > 0.1
    run, prior = two_missions()
    assert sessions_block(_with_dr(run, 10.0, 0.0), None)["dr_ate_by_link_m"] is None   # no prior: no map frame


def test_a_kidnapped_vehicle_enters_a_mapped_place_when_it_comes_back_not_where_it_jumped() -> None:
    """One mission, no map loaded: 20 experiences north along east 0 (session 0), a jump begins
    session 1 at experience 20, the vehicle goes on north to 29 m, then back south at 1.5 m/s and
    is linked at 40 s.  The place of the jump (1 m from experience 19, just made) is no mapped
    place; the first is 2 m from experience 19 on the way back (x = 21 m at 35.33 s, the next
    truth sample 35.5 s), 19 experiences after it was made."""
    ts = np.arange(200) * SEC // 4  # 0 .. 49.75 s
    t = ts / SEC
    x = np.where(t < 30, t, 29.0 - 1.5 * (t - 30))
    run = run_of(np.c_[x, np.zeros(200), np.full(200, 5.0)], ts)
    run.config.expmap.min_experience_age = 5
    nodes = [ExperienceNode(id=i, lvc_id=i, position=enu(np.array([x[4 * i], 0.0, 5.0])), yaw=math.pi / 2,
                            stamp=i * SEC) for i in range(50)]
    run.final_map = ExperienceMap(header=Header(seq=0, stamp=49 * SEC, frame_id="map"), nodes=nodes, links=[])
    run.final_sessions = MapSessions(
        header=Header(seq=0, stamp=49 * SEC, frame_id="map"), node_session=[0] * 20 + [1] * 30, loaded_nodes=0,
        links=[SessionLinkInfo(session=1, to_session=0, source=14, target=40, stamp=40 * SEC, delta=[0.0, 0.0, 0.0],
                               shift=[0.0, 0.0, 0.0], rotation_deg=0.0, inlier_fraction=0.9)])
    s = sessions_block(run)
    assert (s["count"], s["links"], s["false_links"]) == (2, 1, 0)
    assert s["time_to_link_s"] == 4.5  # 40 - 35.5; counted from the jump it would be 20 s
    run.config.expmap.min_experience_age = 0  # every older experience counts: the jump itself is "entering"
    assert sessions_block(run)["time_to_link_s"] == 20.0
