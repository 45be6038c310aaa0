"""poseidon eval's command line (eval/cli/run_eval.py) on the hand-made run (tests/eval/handmade.py)."""
import json

import pytest

from eval.cli.run_eval import main
from launcher.cli import main as poseidon
from tests.eval import handmade as hm


@pytest.fixture(scope="module")
def run_path(tmp_path_factory):
    return hm.write_run(tmp_path_factory.mktemp("hm") / "run.mcap")


def test_cli_json_keys(run_path, capsys):
    assert main([str(run_path), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert {"accepted", "true", "false", "recall"} <= set(r["loop_closures"])
    assert set(r["ate_rmse_m"]) == {"map", "dead_reckoning"}
    for k in ("events_per_s", "nodes", "edges", "mean_degree", "proxies", "vpr_ok_ratio", "drift_pct", "rpe"):
        assert k in r
    # through the poseidon command, text output
    assert poseidon(["eval", str(run_path), "--far-m", "10"]) == 0
    out = capsys.readouterr().out
    assert "3 accepted: 3 true, 0 false (d_gt <= 10 m)" in out


def test_cli_bad_input(tmp_path, capsys):
    missing = tmp_path / "nope.mcap"
    assert main([str(missing)]) == 2
    assert str(missing) in capsys.readouterr().err


def test_loop_link_to_a_missing_node_is_an_error(tmp_path, capsys):
    from common.mcap_io import RecordingWriter
    from common.messages import ExperienceLink, ExperienceMap, ExperienceNode, Header
    path = tmp_path / "broken.mcap"
    with RecordingWriter(path) as w:
        w.write("map", ExperienceMap(header=Header(seq=0, stamp=1), nodes=[
            ExperienceNode(id=0, lvc_id=0, position=[0, 0, 0], yaw=0, stamp=1)],
            links=[ExperienceLink(source=0, target=7, delta=[0, 0, 0], duration_s=0, weight=1, loop_closure=True)]))
    assert main([str(path)]) == 2
    err = capsys.readouterr().err
    assert "broken.mcap" in err and "0->7" in err


def test_cli_config_override(run_path, capsys):
    # the recorded configuration says min_experience_age 5; --set replaces the whole configuration
    assert main([str(run_path), "--json", "--set", "expmap.min_experience_age=12"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["config_source"] == "given" and r["loop_closures"]["min_experience_age"] == 12
    # back-leg node k (x = 78 - 4k) has node 19 - k at 0 m and node 18 - k at 4.02 m; one of them is
    # >= 12 events older for k >= 15 (node 15: node 3, 4.02 m away)
    assert r["loop_closures"]["opportunities"] == 5
    assert main([str(run_path), "--set", "expmap.nonsense=1"]) == 2
    assert "nonsense" in capsys.readouterr().err
