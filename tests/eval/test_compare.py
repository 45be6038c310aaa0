"""poseidon compare: Table 5.4, Tables 5.2-5.3 and our additions side by side."""
import json

import pytest

from eval.compare import ADDITIONS, TABLE_5_4, compare_runs, main
from launcher.cli import main as poseidon
from tests.eval import handmade as hm


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("cmp")
    return hm.write_run(d / "a.mcap"), hm.write_run(d / "b.mcap", with_metadata=False)


def test_compare_tables(runs):
    c = compare_runs(*runs, labels=("ON", "OFF"))
    assert list(c["table_5_4"]) == list(TABLE_5_4) and list(c["additions"]) == list(ADDITIONS)
    t = c["table_5_4"]
    assert t["event_density_per_s"] == {"label": "Event density (events/s)", "a": 0.25, "b": 0.25}
    assert t["nodes"]["a"] == 20 and t["edges"]["b"] == 22
    assert t["audit_f1"]["a"] == pytest.approx(0.9)
    assert t["dt_max_s"]["a"] == pytest.approx(1.0)
    # the configurations differ: window 3 / r 2 (a) against the defaults 26 / 3 (b)
    assert t["vpr_ok_ratio"]["a"] == pytest.approx(7 / 81, abs=1e-6)
    assert t["vpr_ok_ratio"]["b"] == pytest.approx(6 / 81, abs=1e-6)  # frames 65..70: id 0 three times
    assert t["volume_ratio_map_odom"]["a"] == pytest.approx(hm.E / hm.D)
    assert t["end_disp_ratio_map_gt"]["a"] is None
    ad = c["additions"]
    assert ad["ate_rmse_map_m"]["a"] == pytest.approx(hm.E) and ad["ate_rmse_dead_reckoning_m"]["b"] == pytest.approx(hm.D)
    assert ad["loop_closures_true"]["a"] == 2 and ad["loop_closures_false"]["a"] == 1
    assert ad["loop_closure_recall"]["a"] == pytest.approx(0.25) and ad["loop_closure_recall"]["b"] is None
    assert [r["label"] for r in c["loop_closures"]["a"]] == ["TP", "FP", "TP"]
    assert c["runs"]["a"] == {"recording": str(runs[0]), "label": "ON"}
    # the same from runs loaded once (as the report does)
    from eval.rundata import load_run
    assert compare_runs(load_run(runs[0]), load_run(runs[1]), labels=("ON", "OFF")) == c


def test_compare_cli_text_and_json(runs, capsys):
    assert main([str(runs[0]), str(runs[1]), "--labels", "Guard ON,Guard OFF"]) == 0
    out = capsys.readouterr().out
    assert "Table 5.4" in out and "Span norm ratio MAP/GT" in out and "Guard OFF" in out
    assert "Accepted loop closures, Guard ON" in out and " FP" in out
    assert poseidon(["compare", str(runs[0]), str(runs[1]), "--json"]) == 0
    c = json.loads(capsys.readouterr().out)
    assert set(c) == {"runs", "table_5_4", "additions", "loop_closures", "far_m"}
    assert main([str(runs[0]), str(runs[1]), "--labels", "only-one"]) == 2
