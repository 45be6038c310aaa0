"""The typed results (eval/results.py) describe the dicts the evaluation cores return: every
key produced is declared, every required key is produced (on the hand-made run; the vpr
results in tests/eval/cli/test_vpr.py, the sessions and relations blocks beside their tests)."""
from __future__ import annotations

import json

import pytest

from common.messages import Header, LatencyReport, LatencyStage
from eval.results import FrontEnd, LatencyBlock, RunEvaluation, RunSummary
from eval.run_eval import evaluate_run, latency_block
from eval.rundata import load_run
from eval.summary import summarize_run
from tests.eval import handmade as hm
from tests.eval.shapes import assert_shape


@pytest.fixture(scope="module")
def run_path(tmp_path_factory):
    return hm.write_run(tmp_path_factory.mktemp("hm") / "run.mcap")


def test_evaluate_run_matches_run_evaluation(run_path):
    r = evaluate_run(run_path)
    assert_shape(r, RunEvaluation)
    assert r["front_end"] is not None and "revisit_recall" in r["front_end"] and "matched_frames" in r["front_end"]
    assert r["loop_closures"]["table"] and r["proxies"] is not None and r["dead_reckoning"] is not None
    assert json.loads(json.dumps(r)) == r   # still a plain, JSON-ready dict


def test_summarize_run_matches_run_summary(run_path):
    s = summarize_run(run_path)
    assert set(s) == {"front_end", "dead_reckoning", "back_end"}
    assert_shape(s, RunSummary)


def test_a_live_runs_latency_matches_latency_block(run_path):
    run = load_run(run_path)
    run.latency = LatencyReport(header=Header(seq=0, stamp=0), source="live_player", rate=2.0,
                                stages={"lvc": LatencyStage(n=3, unmatched=1, p50_ms=1.5, p95_ms=2.0, p99_ms=2.5,
                                                            max_ms=3.0)})
    block = latency_block(run)
    assert block is not None and block["stages"]["lvc"]["p95_ms"] == 2.0
    assert_shape(block, LatencyBlock)


def test_the_shape_check_names_missing_and_unknown_keys():
    good = {"frames": 3, "lvc_ids": 2, "new_id_fraction": 0.5, "frame_matching": "stamp"}
    assert_shape(good, FrontEnd)
    with pytest.raises(AssertionError, match="missing \\['frame_matching'\\]"):
        assert_shape({k: v for k, v in good.items() if k != "frame_matching"}, FrontEnd)
    with pytest.raises(AssertionError, match="unknown \\['extra'\\]"):
        assert_shape({**good, "extra": 1}, FrontEnd)
