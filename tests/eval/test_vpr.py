"""poseidon vpr's figures (eval/vpr.py and its building blocks): metrics on synthetic similarity
matrices, the ground truth readers, the LVC revisit scores (the command line: tests/eval/cli/test_vpr.py)."""
from __future__ import annotations

import numpy as np
import pytest

from eval.vpr import ground_truth_by_name, ground_truth_from_file, overlap_similarity, pr_curve, vpr_metrics


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
