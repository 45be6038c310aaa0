"""poseidon audit: event-evidence association and per-key sequence gaps on known inputs."""
import json

import pytest

from eval.audit import association, audit_run, main, sequence_gaps
from tests.eval import handmade as hm


def test_sequence_gaps():
    assert sequence_gaps([0, 1, 2, 3]) == {"messages": 4, "first_seq": 0, "last_seq": 3, "gaps": 0, "missing": 0,
                                           "duplicates": 0, "out_of_order": 0}
    g = sequence_gaps([5, 6, 9, 10, 10, 8, 20])
    # distinct 5 6 8 9 10 20: jumps 6->8 (7 missing) and 10->20 (11..19 missing)
    assert (g["gaps"], g["missing"], g["duplicates"], g["out_of_order"]) == (2, 10, 1, 1)
    assert sequence_gaps([])["first_seq"] is None


def test_association_counts():
    ev = [(0, 100), (1, 200), (2, 300), (3, 400)]
    im = [(0, 100, 100), (1, 200, 200 + 10**9), (1, 200, 200), (9, 999, 999)]
    a = association(ev, im, slop_s=0.75)
    # (0) associated; (1) joined but 1 s late; a duplicate of (1); (9) has no event; events 2, 3 lack images
    assert (a["associated"], a["late_images"], a["duplicate_images"], a["missing_events"], a["missing_images"]) == \
        (1, 1, 1, 1, 2)
    assert a["precision"] == 0.25 and a["recall"] == 0.25 and a["f1"] == pytest.approx(0.25)
    assert a["dt_mean_s"] == pytest.approx(0.5) and a["dt_max_s"] == pytest.approx(1.0)
    perfect = association(ev, [(s, t, t - 10**7) for s, t in ev], 0.75)
    assert perfect["f1"] == 1.0 and perfect["dt_max_s"] == pytest.approx(0.01)
    assert association([], [], 0.75)["f1"] is None
    assert association(ev, [], 0.75)["f1"] is None and association(ev, [], 0.75)["recall"] == 0.0


@pytest.fixture(scope="module")
def run_path(tmp_path_factory):
    return hm.write_run(tmp_path_factory.mktemp("hm") / "run.mcap")


def test_audit_hand_made_run(run_path):
    a = audit_run(run_path)
    assert a["slop_s"] == 0.75  # expmap.image.sync_slop of the recorded configuration
    # 20 events; images for all but event 5, event 7's is 1 s late, one orphan image
    assert (a["events"], a["images"], a["associated"]) == (20, 20, 18)
    assert (a["precision"], a["recall"], a["f1"]) == (0.9, 0.9, 0.9)
    assert (a["missing_images"], a["missing_events"], a["late_images"]) == (1, 1, 1)
    assert a["dt_mean_s"] == pytest.approx((18 * 0.1 + 1.0) / 19, abs=1e-6)
    assert a["dt_max_s"] == pytest.approx(1.0)
    # truth/pose seq jumps by 3 after sample 99
    tp = a["keys"]["truth/pose"]
    assert (tp["messages"], tp["gaps"], tp["missing"]) == (801, 1, 3)
    assert a["keys"]["Odometry"]["gaps"] == 0
    assert "truth/pose" in a["keys_with_gaps"] and "Odometry" not in a["keys_with_gaps"]
    assert audit_run(run_path, slop_s=2.0)["f1"] == pytest.approx(2 * 0.95 * 0.95 / 1.9)


def test_audit_cli(run_path, capsys, tmp_path):
    assert main([str(run_path), "--json"]) == 0
    a = json.loads(capsys.readouterr().out)
    for k in ("precision", "recall", "f1", "missing_events", "missing_images", "dt_mean_s", "dt_max_s", "keys",
              "messages_missing", "keys_with_gaps"):
        assert k in a
    assert main([str(run_path)]) == 0
    assert "F1 0.900" in capsys.readouterr().out
    assert main([str(tmp_path / "absent.mcap")]) == 2
    assert "absent.mcap" in capsys.readouterr().err
