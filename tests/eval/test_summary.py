"""eval.summary judges LVC ids and dead reckoning against ground truth."""
import numpy as np
import pytest

from common.mcap_io import RecordingWriter
from common.messages import Header, LocalViewCells, Odometry, RevisitTruth
from eval.summary import format_summary, summarize_run
from system.config import PoseidonConfig


def _pose(i, x):
    return Odometry(header=Header(seq=i, stamp=i * 10**9), position=[x, 0.0, 0.0], orientation=[0, 0, 0, 1])


def test_revisit_recall_and_false_associations(tmp_path):
    # frames 0..3 at x = 0, 10, 20, 0 (frame 3 revisits frame 0); ids: 0, 1, 0 (wrong: 20 m away), 0 (right)
    xs = [0.0, 10.0, 20.0, 0.0]
    ids = [(0, True), (1, True), (0, False), (0, False)]
    path = tmp_path / "run.mcap"
    with RecordingWriter(path) as w:
        for i, x in enumerate(xs):
            w.write("truth/pose", _pose(i, x))
            w.write("local_view_cells", LocalViewCells(header=Header(seq=i, stamp=i * 10**9), most_active_cell=ids[i][0],
                                                       active_cells=[{"id": ids[i][0], "rate": 1.0}], is_new=ids[i][1],
                                                       intersection=0))
            w.write("truth/revisits", RevisitTruth(header=Header(seq=i, stamp=i * 10**9), frame_index=i,
                                                   same_place=np.array([0] if i == 3 else [], dtype=np.int32)))
            # dead reckoning 1 m short over 40 m (published frame: ENU via yxz, z sign -1)
            w.write("Odometry", Odometry(header=Header(seq=i, stamp=i * 10**9), position=[0.0, x * 0.975, 0.0],
                                         orientation=[0, 0, 0, 1]))
    s = summarize_run(path, PoseidonConfig())
    fe = s["front_end"]
    assert (fe["frames"], fe["lvc_ids"], fe["revisit_frames"], fe["revisit_recall"]) == (4, 2, 1, 1.0)
    assert fe["matched_frames"] == 2 and fe["false_association_rate"] == 0.5
    dr = s["dead_reckoning"]
    assert dr["truth_distance_m"] == pytest.approx(40.0)
    assert dr["max_error_m"] == pytest.approx(0.5)
    assert "per-frame revisit recall 100.0% of 1 frames" in format_summary(s)[0]
    assert "per-frame revisit precision" in format_summary(s)[0]


def test_back_end_block_on_a_run_with_a_map(tmp_path):
    from tests.eval import handmade as hm
    s = summarize_run(hm.write_run(tmp_path / "hm.mcap"))
    assert set(s) == {"front_end", "dead_reckoning", "back_end"}
    be = s["back_end"]
    assert (be["events"], be["nodes"], be["edges"]) == (20, 20, 22)
    assert be["loop_closures"] == {"accepted": 3, "true": 2, "false": 1, "recall": 0.25, "pass_recall": 1.0}
    assert be["ate_rmse_m"]["map"] == pytest.approx(hm.E) and be["ate_rmse_m"]["dead_reckoning"] == pytest.approx(hm.D)
    assert be["audit"]["f1"] == pytest.approx(0.9) and be["audit"]["missing_images"] == 1
    lines = format_summary(s)
    assert any(line.startswith("back-end: 20 events (0.250/s)") for line in lines)
    assert any("audit: event-evidence F1 0.900" in line for line in lines)


def test_no_back_end_block_without_events(tmp_path):
    path = tmp_path / "fe.mcap"
    with RecordingWriter(path) as w:
        w.write("truth/pose", _pose(0, 0.0))
    assert "back_end" not in summarize_run(path, PoseidonConfig())
