"""The recordings a short simulated mission produces are byte-identical, key by key, to the
stored digests: a refactoring that changes no algorithm must not change one byte a service
publishes.  A change that is meant to alter outputs updates ``tests/data/recording_digests.json``
(``poseidon info RUN.mcap --digests --json``) in the same commit, so the diff shows which keys moved.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from common.mcap_io import key_digests
from launcher.cli import main as poseidon
from missions.sim.cli import main as sim_main

GOLDEN = Path(__file__).resolve().parent / "data" / "recording_digests.json"


@pytest.mark.slow
def test_a_one_minute_mission_publishes_the_stored_bytes_on_all_21_keys(tmp_path: Path) -> None:
    mission = tmp_path / "sim.mcap"
    assert sim_main(["--minutes", "1", "--seed", "23", "--out", str(mission), "--no-progress"]) == 0
    run = tmp_path / "run.mcap"
    assert poseidon(["run", "--embedded", "--input", str(mission), "--out", str(run), "--rate", "0"]) == 0
    expected = json.loads(GOLDEN.read_text())
    got = key_digests(run)
    assert len(expected) == 21
    assert sorted(got) == sorted(expected), "keys differ"
    moved = [f"{k}: {got[k]['messages']} messages (stored {expected[k]['messages']})"
             for k in expected if got[k] != expected[k]]
    assert not moved, "streams differ from tests/data/recording_digests.json:\n" + "\n".join(moved)
