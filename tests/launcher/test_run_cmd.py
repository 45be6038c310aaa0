"""``poseidon run``'s printing of the run summary (launcher/run_cmd.py)."""
import json

from launcher.run_cmd import print_run
from tests.eval import handmade as hm


def test_poseidon_run_json_carries_the_evaluation(tmp_path, capsys):
    """`poseidon run --json` / `demo --json`: the "evaluation" block comes from eval.summary."""
    path = hm.write_run(tmp_path / "hm.mcap")
    result = {"output": str(path), "mode": "embedded", "wall_s": 1.0, "services": {},
              "recording": {"counts": {}, "duration_s": 80.0}}
    print_run(result, True, hm.config())
    ev = json.loads(capsys.readouterr().out)["evaluation"]
    assert set(ev) == {"front_end", "dead_reckoning", "back_end"}
    assert ev["front_end"]["revisit_recall"] == 0.5 and ev["back_end"]["loop_closures"]["true"] == 2
    print_run(dict(result), False, hm.config())
    assert "back-end: 20 events" in capsys.readouterr().out


def test_input_hints_go_to_stderr_also_with_json(tmp_path, capsys):
    path = hm.write_run(tmp_path / "hm.mcap")
    result = {"output": str(path), "mode": "embedded", "wall_s": 1.0, "services": {},
              "recording": {"counts": {}, "duration_s": 80.0},
              "inputs": {"htm": {"received": {}, "missing": ["embedding"], "hint": "htm: no input on embedding"}}}
    print_run(result, True, hm.config())
    out = capsys.readouterr()
    assert json.loads(out.out)["inputs"]["htm"]["missing"] == ["embedding"]
    assert "poseidon run: htm: no input on embedding" in out.err
