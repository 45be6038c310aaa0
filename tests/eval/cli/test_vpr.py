"""poseidon vpr's command line (eval/cli/vpr.py): image sets, a mission, bad inputs; the JSON has
the keys of eval.results.ImageSetResult / MissionResult."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image as PILImage

from eval.cli.vpr import main
from eval.results import ImageSetResult, MissionResult
from tests.eval.shapes import assert_shape

DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data"


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
    assert_shape(fixed, ImageSetResult)
    assert fixed["embedding_norm"] == "fixed" and (tmp_path / "norm.npz").exists()
    assert fixed["matchers"]["lsbh_overlap"]["auc"] == pytest.approx(1.0)
    assert fixed["matchers"]["cnn_cosine_standardized"]["auc"] == pytest.approx(1.0)
    assert fixed["sdr_overlap"]["same_place"] == 1.0 and fixed["sdr_overlap"]["different_place"] < 0.5
    rc = main(common + ["--set", "encoder.embedding_norm.mode=none", "--set", "encoder.untrained=true"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert_shape(out, ImageSetResult)
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
    assert_shape(out, MissionResult)
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
    assert_shape(anded, MissionResult)
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
