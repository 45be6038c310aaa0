"""eval.frontend: LVC revisit recall/precision, false associations and the VPR window ok_ratio."""
import numpy as np
import pytest

from eval.frontend import frame_indices, lvc_false_associations, lvc_revisit_metrics, vpr_window_ok_ratio


def test_lvc_revisit_recall_and_precision():
    # frames 0..5; frame 4 revisits frame 0, frame 5 revisits frame 1
    ids = [10, 11, 12, 10, 10, 13]
    same = [[], [], [], [], [0], [1]]
    r = lvc_revisit_metrics(ids, same)
    # recall: frame 4 has frame 0's id (hit), frame 5 has a new id (miss)
    assert (r["revisit_frames"], r["recalled"], r["recall"]) == (2, 1, 0.5)
    # claims without distances: frames 3 and 4 re-use id 10; only frame 4's is true
    assert (r["claimed"], r["correct_claims"], r["precision"]) == (2, 1, 0.5)
    # with a 10 m gap, frame 3 (3 m after frame 0) cannot claim; frame 4 (20 m after) can
    r = lvc_revisit_metrics(ids, same, travelled_m=[0, 1, 2, 3, 20, 21], min_gap_m=10.0)
    assert (r["claimed"], r["correct_claims"], r["precision"]) == (1, 1, 1.0)
    # negative ids are "no id"; truth indices outside [0, i) are ignored
    r = lvc_revisit_metrics([-1, -1, 5], [[], [], [0, 7]])
    assert (r["revisit_frames"], r["recalled"], r["claimed"], r["precision"]) == (1, 0, 0, None)
    assert lvc_revisit_metrics([], [])["recall"] is None
    with pytest.raises(ValueError, match="ground-truth rows"):
        lvc_revisit_metrics([1, 2], [[]])


def test_false_associations():
    ids = [0, 1, 0, 0, 2]
    is_new = [True, True, False, False, True]
    pos = np.array([[0, 0, 0], [10, 0, 0], [20, 0, 0], [3, 0, 0], [np.nan] * 3])
    r = lvc_false_associations(ids, is_new, pos, far_m=5.0)
    # frame 2 joins id 0 (created 20 m away: false), frame 3 joins it 3 m away (fine)
    assert r == {"matched_frames": 2, "false_associations": 1, "false_association_rate": 0.5}
    assert lvc_false_associations(ids, is_new, None)["false_association_rate"] is None


def test_vpr_window_ok_ratio_counts_eq_4_11_gate():
    # window 3, r 2: gates 0,1,0,1,0,1
    assert vpr_window_ok_ratio([1, 1, 2, 1, 3, 3], window=3, min_rep=2) == pytest.approx(0.5)
    # Section 4.2.3's example: id 12 four times within the last 26 emissions passes r = 3
    stream = [12, 5, 12, 7, 12, 9, 12]
    assert vpr_window_ok_ratio(stream, 26, 3) == pytest.approx(2 / 7)  # the 3rd and 4th 12
    assert vpr_window_ok_ratio([4, 4, 4], 1, 1) == 1.0
    assert vpr_window_ok_ratio([], 26, 3) is None
    with pytest.raises(ValueError):
        vpr_window_ok_ratio([1], 0, 1)


def test_frame_indices_by_stamp_or_order():
    assert frame_indices([10, 30], {10: 0, 20: 1, 30: 2}) == ([0, 2], "stamp")
    assert frame_indices([10, 40], {10: 0}) == ([0, 1], "order")


def test_pair_metrics_count_pairs_not_frames():
    from eval.frontend import lvc_pair_metrics, lvc_revisit_metrics
    # frames 0,1 one place (id 0), frame 2 another (id 1), frames 3,4 revisit the first place;
    # frame 3 gets id 0 (right), frame 4 gets id 1 (wrong: place of frame 2)
    ids = [0, 0, 1, 0, 1]
    same = [[], [0], [], [0, 1], [0, 1, 3]]
    m = lvc_pair_metrics(ids, same)
    # true pairs: (1,0) (3,0) (3,1) (4,0) (4,1) (4,3) = 6; called: (1,0) (3,0) (3,1) (4,2) = 4; correct 3
    assert (m["true_pairs"], m["called_pairs"], m["correct_pairs"]) == (6, 4, 3)
    assert m["pair_precision"] == 0.75 and m["pair_recall"] == 0.5
    f = lvc_revisit_metrics(ids, same)
    # per frame: revisit frames 1, 3, 4; recalled 1, 3; claims 1, 3, 4 (4's id exists earlier) -> 2 of 3
    assert (f["recalled"], f["claimed"], f["correct_claims"]) == (2, 3, 2)
    # only eligible pairs count
    assert lvc_pair_metrics(ids, same, eligible_before=[0, 0, 0, 0, 0])["called_pairs"] == 0
