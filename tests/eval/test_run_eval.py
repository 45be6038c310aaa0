"""poseidon eval on the hand-made run (tests/eval/handmade.py): every figure known by construction."""
import math

import numpy as np
import pytest

from eval.run_eval import evaluate_run, stability_proxies
from tests.eval import handmade as hm

SLOPE = math.sqrt(1.01)  # path length per metre of x (depth z = 5 + x/10)


@pytest.fixture(scope="module")
def run_path(tmp_path_factory):
    return hm.write_run(tmp_path_factory.mktemp("hm") / "run.mcap")


@pytest.fixture(scope="module")
def result(run_path):
    return evaluate_run(run_path)


def test_graph_and_event_density(result):
    assert result["config_source"] == "recording"
    assert result["ground_truth"] is True
    assert result["duration_s"] == 80.0
    assert result["events"] == 20 and result["events_per_s"] == pytest.approx(20 / 80)
    assert (result["nodes"], result["edges"]) == (20, 19 + len(hm.LOOPS))
    assert result["mean_degree"] == pytest.approx(2 * 22 / 20)
    assert result["map_messages"] == 20


def test_loop_closures_labelled_by_ground_truth_distance(result):
    lc = result["loop_closures"]
    assert (lc["accepted"], lc["true"], lc["false"], lc["unlabelled"]) == (3, 2, 1, 0)
    rows = {(r["current_exp"], r["matched_exp"]): r for r in lc["table"]}
    assert rows[(19, 0)]["label"] == "TP" and rows[(19, 0)]["d_gt_m"] == pytest.approx(0.0)
    fp = rows[(15, 2)]
    # node 15 at t = 62 s (x = 18), node 2 at t = 10 s (x = 10); depth 5 + x/10
    assert fp["label"] == "FP" and fp["d_gt_m"] == pytest.approx(8 * SLOPE, abs=1e-5)
    assert fp["current_gt"] == pytest.approx([18.0, 0.0, 6.8]) and fp["matched_gt"] == pytest.approx([10.0, 0.0, 6.0])
    assert fp["event_seq"] == 15
    assert lc["precision"] == pytest.approx(2 / 3, abs=1e-6)


def test_loop_closure_recall_against_revisit_opportunities(result):
    lc = result["loop_closures"]
    # back-leg node k (x = 78 - 4k) meets out-leg node 19 - k, which is >= 5 events older for k >= 12
    assert lc["min_experience_age"] == 5
    assert lc["opportunities"] == 8 and lc["recalled"] == 2 and lc["recall"] == pytest.approx(0.25)
    assert (lc["passes"], lc["passes_closed"], lc["pass_recall"]) == (1, 1, 1.0)


def test_time_aligned_ate_drift_and_rpe(result):
    assert result["ate"]["stamps"] == "map_nodes"
    assert result["ate_rmse_m"]["map"] == pytest.approx(hm.E, abs=1e-6)
    assert result["ate_rmse_m"]["dead_reckoning"] == pytest.approx(hm.D, abs=1e-6)
    assert result["ate"]["map"]["n"] == 20
    # nodes t = 2..78 s: 38 m out, 38 m back; start-anchored final error 2E (map), 2D (dead reckoning)
    dist = 76 * SLOPE
    assert result["truth_distance_m"] == pytest.approx(dist, abs=1e-5)
    assert result["drift_pct"]["map"] == pytest.approx(100 * 2 * hm.E / dist, abs=1e-5)
    assert result["drift_pct"]["dead_reckoning"] == pytest.approx(100 * 2 * hm.D / dist, abs=1e-5)
    # RPE over 10 s: node pairs (k, k+3), 12 s apart; the 3 pairs straddling the turn (k = 7, 8, 9)
    # see the offset flip (2E), the other 14 none
    for name, off in (("map", hm.E), ("dead_reckoning", hm.D)):
        rp = result["rpe"][name]
        assert rp["n"] == 17
        assert rp["rmse_m"] == pytest.approx(2 * off * math.sqrt(3 / 17), abs=1e-5)
        assert rp["mean_m"] == pytest.approx(2 * off * 3 / 17, abs=1e-5)


def test_stability_proxies(result):
    p = result["proxies"]
    assert p["samples"] == 20
    # extents (NED): x 36 m for all; y 2E (map), 2D (odom), 0 (gt); z 3.6 m
    assert p["volume_m3"] == pytest.approx({"map": 36 * 2 * hm.E * 3.6, "odom": 36 * 2 * hm.D * 3.6, "gt": 0.0})
    assert p["span_norm_m"]["map"] == pytest.approx(math.sqrt(36 ** 2 + (2 * hm.E) ** 2 + 3.6 ** 2), abs=1e-5)
    assert p["end_displacement_m"] == pytest.approx({"map": 2 * hm.E, "odom": 2 * hm.D, "gt": 0.0})
    q = p["ratios"]
    assert q["volume_map_odom"] == pytest.approx(hm.E / hm.D)
    assert q["end_displacement_map_odom"] == pytest.approx(hm.E / hm.D)
    assert q["volume_map_gt"] is None and q["end_displacement_map_gt"] is None  # zero reference
    assert q["span_norm_map_gt"] == pytest.approx(p["span_norm_m"]["map"] / p["span_norm_m"]["gt"], abs=1e-5)


def test_stability_proxies_box():
    mp = np.array([[0, 0, 0], [2, 3, 4.0]])
    r = stability_proxies(mp, mp * 2, None)
    assert r["volume_m3"] == {"map": 24.0, "odom": 192.0}
    assert r["span_norm_m"]["map"] == pytest.approx(math.sqrt(29))
    assert r["ratios"]["volume_map_odom"] == pytest.approx(0.125)
    assert r["ratios"]["span_norm_map_gt"] is None


def test_front_end_figures(result):
    fe = result["front_end"]
    assert fe["frame_matching"] == "stamp"
    assert (fe["frames"], fe["lvc_ids"]) == (81, 55)
    assert fe["new_id_fraction"] == pytest.approx(55 / 81, abs=1e-4)
    # revisit frames 45..80; right ids on 45..62
    assert fe["revisit_frames"] == 36 and fe["revisit_recall"] == pytest.approx(0.5)
    # claims: 45..62 (right) and 63..70 (id 0, wrong)
    assert fe["claimed_revisits"] == 26 and fe["revisit_precision"] == pytest.approx(18 / 26, abs=1e-4)
    assert fe["matched_frames"] == 26 and fe["false_association_rate"] == pytest.approx(8 / 26, abs=1e-4)
    # window 3, r 2: only frames 64..70 (id 0 repeated) pass
    assert result["vpr_ok_ratio"] == pytest.approx(7 / 81, abs=1e-6)


def test_dead_reckoning_block(result):
    dr = result["dead_reckoning"]
    # whole stream: 401 samples on the way out with error 0, 400 back with error 2D
    assert dr["final_error_m"] == pytest.approx(2 * hm.D)
    assert dr["ate_rmse_m"] == pytest.approx(2 * hm.D * math.sqrt(400 / 801), abs=1e-4)


def test_config_defaults_without_metadata(tmp_path):
    r = evaluate_run(hm.write_run(tmp_path / "bare.mcap", with_metadata=False))
    assert r["config_source"] == "defaults"
    # default min_experience_age 200 > 20 nodes: no revisit opportunity
    assert r["loop_closures"]["opportunities"] == 0 and r["loop_closures"]["recall"] is None
    assert r["loop_closures"]["true"] == 2


def test_run_without_ground_truth(tmp_path):
    from common.mcap_io import RecordingWriter
    from common.messages import ExperienceLink, ExperienceMap, ExperienceNode, Header, Odometry
    path = tmp_path / "nogt.mcap"
    with RecordingWriter(path) as w:
        for k in range(3):
            w.write("Odometry", Odometry(header=Header(seq=k, stamp=k * hm.NS), position=[0.0, float(k), 0.0],
                                         orientation=hm.Q))
        nodes = [ExperienceNode(id=k, lvc_id=k, position=[0.0, float(k), 0.0], yaw=0.0, stamp=k * hm.NS)
                 for k in range(3)]
        links = [ExperienceLink(source=0, target=1, delta=[0, 1, 0], duration_s=1, weight=1),
                 ExperienceLink(source=1, target=2, delta=[0, 1, 0], duration_s=1, weight=1),
                 ExperienceLink(source=0, target=2, delta=[0, 0, 0], duration_s=0, weight=1, loop_closure=True)]
        w.write("map", ExperienceMap(header=Header(seq=0, stamp=2 * hm.NS), nodes=nodes, links=links))
    r = evaluate_run(path)
    assert r["ground_truth"] is False
    lc = r["loop_closures"]
    assert (lc["accepted"], lc["true"], lc["false"], lc["unlabelled"]) == (1, 0, 0, 1)
    assert lc["table"][0]["label"] is None and lc["table"][0]["d_gt_m"] is None
    assert r["ate_rmse_m"] == {"map": None, "dead_reckoning": None}
    # map and odometry agree exactly: ratios 1; no GT column
    assert r["proxies"]["ratios"]["span_norm_map_odom"] == pytest.approx(1.0)
    assert r["proxies"]["ratios"]["span_norm_map_gt"] is None
    assert r["events_per_s"] == 0.0 and r["front_end"] is None and r["dead_reckoning"] is None


def test_revisit_opportunities_grid_equals_brute_force():
    from eval.run_eval import _revisit_opportunities
    rng = np.random.default_rng(3)
    g = rng.uniform(-20, 20, size=(300, 3))
    known = rng.random(300) > 0.1
    ids = np.arange(300)
    for age in (0, 7, 50):
        brute = np.zeros(300, bool)
        for k in range(300):
            if known[k]:
                js = [j for j in range(300) if known[j] and j != k and ids[j] <= ids[k] - age]
                brute[k] = bool(js) and min(np.linalg.norm(g[js] - g[k], axis=1)) <= 5.0
        assert np.array_equal(_revisit_opportunities(ids, g, known, age, 5.0), brute)
        assert brute.any()
