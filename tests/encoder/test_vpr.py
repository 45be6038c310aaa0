"""poseidon vpr: metrics on synthetic similarity matrices, ground truth readers, main() on real frames."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image as PILImage

from services.encoder.vpr import (ground_truth_by_name, ground_truth_from_file, main, overlap_similarity, pr_curve,
                                  vpr_metrics)

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
    rc = main(["--ref", str(tmp_path / "ref"), "--query", str(tmp_path / "query"), "--json",
               "--set", f"encoder.lsbh_matrix_path={tmp_path}/p_{{backbone}}_{{modality}}.npy",
               "--set", "encoder.torch_threads=1"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_ref"] == out["n_query"] == 6 and out["weights"] == "seeded"
    assert set(out["matchers"]) == {"cnn_cosine", "lsbh_overlap", "htm_lvc", "htm_descriptor"}
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
               "--backbone", "alexnet_conv3",
               "--set", f"encoder.lsbh_matrix_path={tmp_path}/p_{{backbone}}_{{modality}}.npy",
               "--set", "encoder.torch_threads=1"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_query"] == 12 and out["n_query_with_gt"] == 12 and out["backbone"] == "alexnet_conv3"
    assert out["embedding_dim"] == 384 * 16 and out["ground_truth"] == "file name +-1"
    assert all(m["n_predicted"] <= 12 for m in out["matchers"].values())
