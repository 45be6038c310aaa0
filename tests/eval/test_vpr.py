"""poseidon vpr: metrics on synthetic similarity matrices, ground truth readers, main() on real frames."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image as PILImage

from eval.cli.vpr import main
from eval.vpr import ground_truth_by_name, ground_truth_from_file, overlap_similarity, pr_curve, vpr_metrics

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def test_metrics_known_curve():
    # 4 queries; best-match scores 0.9 0.8 0.7 0.6; correct T F T T
    sim = np.array([[0.9, 0.1, 0.0, 0.0],
                    [0.0, 0.0, 0.8, 0.0],   # wrong: predicts ref 2, truth is ref 1
                    [0.0, 0.0, 0.7, 0.2],
                    [0.1, 0.0, 0.0, 0.6]])
    gt = [[0], [1], [2], [3]]
    m = vpr_metrics(sim, gt)
    # P = 1, 1/2, 2/3, 3/4 at R = 1/4, 1/4, 2/4, 3/4
    assert m["auc"] == pytest.approx(0.25 * 1 + 0.25 * 2 / 3 + 0.25 * 3 / 4)
    assert m["recall_at_p100"] == pytest.approx(0.25)
    assert m["best_f1"] == pytest.approx(0.75)
    perfect = vpr_metrics(np.eye(4), gt)
    assert perfect == {"auc": 1.0, "recall_at_p100": 1.0, "best_f1": 1.0, "n_predicted": 4}


def test_metrics_ties_no_prediction_and_missing_gt():
    # equal scores are accepted together: one wrong among tied -> no recall at precision 1
    p, r = pr_curve(np.array([0.5, 0.5, 0.5]), np.array([True, False, True]), 3)
    assert p.tolist() == pytest.approx([2 / 3]) and r.tolist() == pytest.approx([2 / 3])
    sim = np.array([[0.9, 0.0], [-np.inf, -np.inf], [0.0, 0.4]])
    m = vpr_metrics(sim, [[0], [1], []])  # query 1 predicts nothing, query 2 has no truth
    # ranked: q0 correct (P=1, R=1/2), q2 wrong (P=1/2, R=1/2)
    assert m["n_predicted"] == 2
    assert m["auc"] == pytest.approx(0.5) and m["recall_at_p100"] == pytest.approx(0.5)
    assert m["best_f1"] == pytest.approx(2 * 0.5 / 1.5)


def test_overlap_similarity_eq_4_7():
    q = [np.array([1, 5, 9, 80000]), np.array([2])]
    r = [np.array([1, 5, 7]), np.array([2, 80000])]
    s = overlap_similarity(q, r)
    np.testing.assert_allclose(s, [[0.5, 0.25], [0.0, 1.0]])


def test_ground_truth_readers(tmp_path):
    assert ground_truth_by_name(["b", "c", "x"], ["a", "b", "c", "d"], 1) == [[0, 1, 2], [1, 2, 3], []]
    arr = np.empty((2, 2), dtype=object)
    arr[0, 0], arr[0, 1] = 0, [0, 1, 5]
    arr[1, 0], arr[1, 1] = 1, [1]
    f = tmp_path / "gt.npy"
    np.save(f, arr, allow_pickle=True)
    assert ground_truth_from_file(f, 3, 4) == [[0, 1], [1], []]


def _write_seq(folder: Path, seeds: list[int], names: list[str]) -> None:
    folder.mkdir()
    for s, n in zip(seeds, names):
        img = np.random.default_rng(s).integers(0, 256, (24, 32, 3), dtype=np.uint8)
        PILImage.fromarray(img).save(folder / n)


def test_main_synthetic_json(tmp_path, capsys):
    names = [f"{i:03d}.png" for i in range(6)]
    _write_seq(tmp_path / "ref", list(range(6)), names)
    _write_seq(tmp_path / "query", list(range(6)), names)  # identical images: cosine finds each one
    common = ["--ref", str(tmp_path / "ref"), "--query", str(tmp_path / "query"), "--json",
              "--set", f"encoder.lsbh.matrix_path={tmp_path}/p_{{backbone}}_{{modality}}.npy",
              "--set", "encoder.torch_threads=1"]
    # fixed: statistics fitted on the reference set, written with --save-norm
    assert main(common + ["--set", "encoder.embedding_norm.mode=fixed", "--no-htm",
                          "--save-norm", str(tmp_path / "norm.npz")]) == 0
    fixed = json.loads(capsys.readouterr().out)
    assert fixed["embedding_norm"] == "fixed" and (tmp_path / "norm.npz").exists()
    assert fixed["matchers"]["lsbh_overlap"]["auc"] == pytest.approx(1.0)
    assert fixed["matchers"]["cnn_cosine_standardized"]["auc"] == pytest.approx(1.0)
    assert fixed["sdr_overlap"]["same_place"] == 1.0 and fixed["sdr_overlap"]["different_place"] < 0.5
    rc = main(common + ["--set", "encoder.embedding_norm.mode=none", "--set", "encoder.untrained=true"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_ref"] == out["n_query"] == 6 and out["weights"] == "seeded"
    chains = {"sdr_seqmem", "no_tm", "no_dr_gate", "no_seqmem", "sp_tm", "sdr_seqmem_f1", "sdr_seqmem_cal",
              "new_places"}
    assert set(out["matchers"]) == {"cnn_cosine", "seq_cosine", "patchnorm_sad", "lsbh_overlap", "htm_lvc",
                                    "htm_lvc_accepted", "htm_descriptor"} | chains
    # the named chains run beside the default, with how each query got its id
    assert set(out["chains"]) == chains
    for c in list(out["chains"].values()) + [out]:
        assert set(c["decisions"]) == {"gate", "tm", "seqmem", "prior", "new"}
        assert sum(c["decisions"].values()) == 6
    # an image set has no dead-reckoned positions: the gate checks nothing, the default scores as no_dr_gate
    assert out["matchers"]["no_dr_gate"] == out["matchers"]["htm_lvc"]
    # the threshold sweep ranks every query; the accepted-only curve predicts the accepted ones
    assert out["matchers"]["htm_lvc_accepted"]["n_predicted"] == out["htm_query_matched"]
    assert out["matchers"]["htm_lvc"]["n_predicted"] >= out["htm_query_matched"]
    assert out["matchers"]["patchnorm_sad"]["auc"] == pytest.approx(1.0)  # identical images
    assert out["embedding_norm"] == "none"
    assert out["matchers"]["cnn_cosine"]["auc"] == pytest.approx(1.0)
    assert out["matchers"]["lsbh_overlap"]["auc"] == pytest.approx(1.0)
    for m in out["matchers"].values():
        assert 0.0 <= m["auc"] <= 1.0 and 0.0 <= m["best_f1"] <= 1.0


def test_main_bad_inputs(tmp_path, capsys):
    assert main(["--ref", str(tmp_path / "none"), "--query", str(tmp_path), "--no-htm"]) == 2
    assert "image folder not found" in capsys.readouterr().err
    (tmp_path / "q").mkdir()
    PILImage.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "q" / "a.png")
    assert main(["--ref", str(tmp_path / "q"), "--query", str(tmp_path / "q"), "--weights",
                 str(tmp_path / "missing.pth"), "--no-htm"]) == 2
    assert "missing.pth" in capsys.readouterr().err


def test_main_on_nordland_frames(tmp_path, capsys):
    summer, winter = DATA / "nordland_trimmed" / "summer", DATA / "nordland_trimmed" / "winter"
    if not (summer.is_dir() and winter.is_dir()):
        pytest.skip(f"Nordland data not found under {DATA / 'nordland_trimmed'}")
    rc = main(["--ref", str(summer), "--query", str(winter), "--limit", "12", "--tolerance", "1", "--json",
               "--backbone", "alexnet_conv3", "--set", "encoder.untrained=true",
               "--set", f"encoder.lsbh.matrix_path={tmp_path}/p_{{backbone}}_{{modality}}.npy",
               "--set", "encoder.torch_threads=1"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_query"] == 12 and out["n_query_with_gt"] == 12 and out["backbone"] == "alexnet_conv3"
    assert out["embedding_dim"] == 384 * 16 and out["ground_truth"] == "file name +-1"
    assert all(m["n_predicted"] <= 12 for m in out["matchers"].values())


def test_lvc_revisit_scores_definition():
    from eval.vpr import lvc_revisit_scores
    # frames 0..5; frame 4 revisits frame 0, frame 5 revisits frame 1; candidates: >= 3 frames back
    gt = [[], [], [], [], [0], [1]]
    idx = np.arange(6)
    eligible = idx[None, :] <= idx[:, None] - 3
    ids = np.array([0, 1, 2, 1, 0, 2])
    s = lvc_revisit_scores(ids, gt, eligible)
    # frame 4 finds frame 0's id (correct); frame 5 has id 2 = frame 2's (a claimed, wrong revisit);
    # frame 3's id 1 equals frame 1's, but frame 1 is only 2 frames back: no claim
    assert s["lvc_recall"] == pytest.approx(0.5) and s["n_revisit_frames"] == 2
    assert s["n_claimed_revisits"] == 2 and s["n_correct_claims"] == 1 and s["lvc_precision"] == pytest.approx(0.5)


@pytest.fixture(scope="module")
def short_mission(tmp_path_factory):
    from dataclasses import replace
    sim = pytest.importorskip("missions.sim.mission")
    p = sim.SimParams(minutes=2.0, seed=3, speed_m_s=1.0)  # approach + more than one loop of area 1
    p = replace(p, camera=replace(p.camera, rate_hz=1.0), micron_rate_hz=10.0, seaking_rate_hz=5.0)
    path = tmp_path_factory.mktemp("mission") / "m.mcap"
    sim.generate(path, p, progress=False)
    return path


def test_main_mission_json(short_mission, tmp_path, capsys):
    args = ["--mission", str(short_mission), "--json", "--set", "encoder.pool_grid=1",
            "--set", f"encoder.lsbh.matrix_path={tmp_path}/p_{{backbone}}_{{modality}}.npy",
            "--set", "encoder.embedding_norm.warmup=20"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_frames"] == 119 and out["n_revisit_frames"] > 10 and out["min_gap_m"] == 10.0
    chains = {"sdr_seqmem", "no_tm", "no_dr_gate", "no_seqmem", "sp_tm", "sdr_seqmem_f1", "sdr_seqmem_cal",
              "new_places"}
    assert set(out["matchers"]) == {"cnn_cosine", "seq_cosine", "patchnorm_sad", "cnn_cosine_standardized",
                                    "lsbh_overlap", "lsbh_fused_overlap", "htm_lvc", "htm_descriptor"} | chains
    # the named chains beside the default: the same LVC figures, SP columns and the TM's share of decisions
    assert set(out["chains"]) == chains
    # the default runs the SP and the TM; the fused-SDR chain sdr_seqmem does not
    assert out["sp_columns_used"] > 0 and out["chains"]["sp_tm"]["sp_columns_used"] > 0
    assert out["chains"]["sdr_seqmem"]["sp_columns_used"] == 0 and out["chains"]["no_tm"]["sp_columns_used"] == 0
    # the mission's own navigation gives every frame after the first Odometry a position
    assert out["dr_positions"] >= 110
    for c in list(out["chains"].values()) + [out]:
        assert sum(c["decisions"].values()) == 119 and 0 <= c["tm_decision_share"] <= 1
        assert 0 <= c["lvc_pair_precision"] <= 1 and 0 <= c["lvc_pair_recall"] <= 1
    # the modality table: the fused code and each single modality through its own HTM, same run
    assert set(out["modalities"]) == {"fused_union", "camera", "sonar"}
    for m in out["modalities"].values():
        assert 0 <= m["lvc_recall"] <= 1 and m["n_lvc"] >= 1 and m["lvc_run_length"]["median"] >= 1
        assert 0 <= m["htm_lvc"]["auc"] <= 1
    assert out["lvc_recall"] == out["modalities"]["fused_union"]["lvc_recall"]
    for m in out["matchers"].values():
        assert m["n_predicted"] <= out["n_frames"] and 0 <= m["auc"] <= 1
    assert 0 <= out["lvc_recall"] <= 1 and 0 <= out["lvc_precision"] <= 1 and out["n_lvc"] >= 1
    assert out["encoder_counters"]["outputs"] == 119 and out["fused_bits_mean"] > 2 * 256
    assert main(args) == 0  # deterministic
    assert json.loads(capsys.readouterr().out)["matchers"] == out["matchers"]
    assert main(args + ["--set", "encoder.fusion_mode=and", "--no-htm"]) == 0
    anded = json.loads(capsys.readouterr().out)
    assert anded["fused_bits_mean"] < out["fused_bits_mean"]  # AND keeps fewer bits than OR
    assert main(["--mission", str(tmp_path / "none.mcap"), "--no-htm"]) == 2
    assert "no such recording" in capsys.readouterr().err
    assert main(["--mission", str(short_mission), "--ref", str(tmp_path)]) == 2


def test_main_mission_transformed_recording(short_mission, tmp_path, capsys):
    """A `poseidon transform` output: the revisit gap comes from the source's metadata record."""
    from missions.transform import transform
    out = tmp_path / "t.mcap"
    transform(short_mission, out, [(0.0, 10.0), (10.0, 30.0), (30.0, 35.0), (35.0, 50.0), (50.0, 55.0)], seed=1)
    assert main(["--mission", str(out), "--json", "--no-htm", "--set", "encoder.pool_grid=1",
                 "--set", f"encoder.lsbh.matrix_path={tmp_path}/p_{{backbone}}_{{modality}}.npy"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["min_gap_m"] == 10.0 and res["n_revisit_frames"] > 20 and "htm_lvc" not in res["matchers"]
    # copies of a loop are the same place: the raw LSBH overlap finds many of them
    assert res["matchers"]["lsbh_overlap"]["best_f1"] > 0.45  # measured 0.60
