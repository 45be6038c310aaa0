"""eval.rundata.load_run: the one run model, on the hand-made run whose content is known."""
from pathlib import Path

import numpy as np
import pytest

from common.mcap_io import RecordingError, RecordingWriter
from common.messages import Header, Odometry, PoseStamped
from eval.rundata import load_run
from tests.eval import handmade as hm


@pytest.fixture(scope="module")
def run_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return hm.write_run(tmp_path_factory.mktemp("rundata") / "run.mcap")


def test_one_pass_holds_what_eval_and_the_report_need(run_path: Path) -> None:
    run = load_run(run_path)
    assert run.config_source == "recording" and run.config.expmap.min_experience_age == 5
    assert run.metadata["config"]["expmap"]["min_experience_age"] == 5  # JSON values decoded
    # truth is NED as recorded; Odometry is taken from the published ENU frame back to NED
    assert run.truth is not None and run.truth.source == "truth/pose" and len(run.truth) == 801
    np.testing.assert_allclose(run.truth.p[0], hm.truth(0.0), atol=1e-9)
    assert run.odometry is not None and run.odometry.source == "Odometry"
    np.testing.assert_allclose(run.odometry.p[0], hm.truth(0.0) + [0.0, hm.D, 0.0], atol=1e-9)
    # the published poses are kept as published (ENU) for the relation error
    assert run.odometry_poses is not None
    np.testing.assert_allclose(run.odometry_poses.positions[0], hm.enu(hm.truth(0.0) + [0.0, hm.D, 0.0]), atol=1e-9)
    assert run.final_map is not None and len(run.final_map.nodes) == 20 and run.map_messages >= 1
    assert len(run.events) == 20 and len(run.images) == 20  # 19 evidence images + the orphan
    assert run.counts["truth/pose"] == 801 and run.duration_s == pytest.approx(80.0)
    assert run.dead_reckoning is None and run.sdrs == []


def test_keys_limit_the_pass(run_path: Path) -> None:
    run = load_run(run_path, keys=("Odometry", "map"))
    assert set(run.counts) == {"Odometry", "map"}
    assert run.truth is None and not run.events and run.odometry_poses is not None and run.final_map is not None
    assert run.config_source == "recording"  # the configuration still comes from the metadata


def test_dead_reckoning_is_read_and_a_wrongly_typed_pose_key_is_named(tmp_path: Path) -> None:
    rec = tmp_path / "dr.mcap"
    with RecordingWriter(rec) as w:
        for i in range(3):
            w.write("dead_reckoning", PoseStamped(header=Header(seq=i, stamp=hm.T0 + i * hm.NS),
                                                  position=[float(i), 2.0, -1.0]))
    run = load_run(rec)
    assert run.config_source == "defaults" and run.metadata == {}
    assert run.dead_reckoning is not None and run.dead_reckoning.source == "dead_reckoning"
    # published ENU (x east, y north, z up) -> NED
    np.testing.assert_allclose(run.dead_reckoning.p[1], [2.0, 1.0, 1.0])
    bad = tmp_path / "bad.mcap"
    with RecordingWriter(bad) as w:
        w.write("Odometry", PoseStamped(header=Header(seq=0, stamp=hm.T0), position=[0.0, 0.0, 0.0]))
        w.write("truth/pose", Odometry(header=Header(seq=0, stamp=hm.T0), position=[0.0, 0.0, 0.0],
                                       orientation=[0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(RecordingError, match=r"bad.mcap: key 'Odometry' carries poseidon_msgs/PoseStamped"):
        load_run(bad)
