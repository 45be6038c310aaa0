"""``poseidon run --live mcap``: a recording played live (no ROS) through robot_state into a
complete recording that carries the run's latency on ``live/latency``; ``poseidon eval`` reads it
back; the recording replays through ``poseidon run --input`` to the same Odometry, byte for byte,
without the live report; the flags' contract."""
import json
import subprocess
import sys

import pytest

from common.mcap_io import read_messages
from tests.common.recordings import six_stream_recording
from tests.conftest import REPO

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]
CLI = [sys.executable, "-m", "launcher.cli"]


def _cli(*args, timeout=240):
    return subprocess.run(CLI + list(args), cwd=REPO, capture_output=True, text=True, timeout=timeout)


def test_a_recording_played_live_is_recorded_with_its_latency_and_replays_to_the_same_outputs(tmp_path):
    src = tmp_path / "mission.mcap"
    counts = six_stream_recording(src, 1500, image_every=50)  # ~6.4 s of event time
    out = tmp_path / "live.mcap"
    # a lateness bound of 2 s: a loaded 2-core machine can stall the player for more than the
    # default 200 ms, and a late frame would (rightly) make the live run differ from its replay
    proc = _cli("run", "--live", "mcap", "--input", str(src), "--rate", "2", "--services", "robot_state",
                "--out", str(out), "--json", "--set", "live.lateness_ms=2000")
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout)
    player = result["services"]["live_player"]
    assert result["mode"] == "live" and player["complete"] and player["rate"] == 2.0
    rec = result["recording"]["counts"]
    assert {k: rec[k] for k in counts} == counts  # every input recorded (nothing dropped at 2x)
    assert rec["live/latency"] == 1 and rec["Odometry"] > 0
    assert result["services"]["robot_state"]["dropped"] == {} and player["late"] == {}
    lat = player["latency"]["odometry"]
    assert lat["n"] == rec["Odometry"] and 0 < lat["p50_ms"] <= lat["p99_ms"] <= lat["max_ms"] < 5000

    ev = _cli("eval", str(out), "--json")
    assert ev.returncode == 0, ev.stderr[-2000:]
    recorded = json.loads(ev.stdout)["latency"]
    assert recorded["source"] == "live_player" and recorded["rate"] == 2.0
    assert recorded["stages"]["odometry"] == lat
    text = _cli("eval", str(out))
    assert "live latency       measured by live_player at 2x real time" in text.stdout

    replay = tmp_path / "replay.mcap"
    proc = _cli("run", "--input", str(out), "--services", "robot_state", "--out", str(replay), "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "live/latency" not in json.loads(proc.stdout)["recording"]["counts"]
    live = [m.payload for m in read_messages(out, keys=["Odometry"])]
    again = [m.payload for m in read_messages(replay, keys=["Odometry"])]
    assert len(live) == rec["Odometry"] and live == again  # live event time is replay event time
    assert json.loads(_cli("eval", str(replay), "--json").stdout)["latency"] is None


@pytest.mark.parametrize("args, message", [
    (["--live", "mcap"], "give --input REC.mcap"),
    (["--live", "ros1", "--input", "x.mcap"], "give --input REC.mcap"),
    (["--live", "ros1", "--rate", "2"], "--embedded and --rate do not apply to --live ros1"),
    (["--live", "mcap", "--input", "x.mcap", "--embedded"], "--embedded do not apply to --live mcap"),
])
def test_live_flags_that_do_not_fit_are_refused_naming_them(tmp_path, args, message):
    proc = _cli("run", *args, "--out", str(tmp_path / "o.mcap"), timeout=60)
    assert proc.returncode == 2 and message in proc.stderr


def test_a_live_run_of_a_missing_recording_fails_naming_it(tmp_path):
    proc = _cli("run", "--live", "mcap", "--input", str(tmp_path / "none.mcap"), "--out", str(tmp_path / "o.mcap"),
                timeout=60)
    assert proc.returncode == 2 and "none.mcap" in proc.stderr


def test_a_live_crash_loop_ends_the_run_naming_the_service_with_a_complete_recording_that_replays(tmp_path):
    """A service that dies at the same input every time (tests.common.nodes:Boom) uses its
    restarts; the run ends with exit 3 naming it, the other service finishes its inputs, and
    the partial recording is complete (its summary written) and replays.  A late or queue-dropped
    input would (rightly) make robot_state's live outputs differ from the replay's: the bounds are
    wide (on a loaded 2-core machine a stall of over 2 s once cost one Odometry)."""
    src = tmp_path / "mission.mcap"
    six_stream_recording(src, 1500, image_every=50)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text('{"service_classes": {"boom": "tests.common.nodes:Boom"}, '
                   '"supervise": {"max_restarts": 2, "restart_backoff_s": 0.05}, '
                   '"live": {"lateness_ms": 5000, "queue_frames": 1000000}}')
    out = tmp_path / "live.mcap"
    proc = _cli("run", "--live", "mcap", "--input", str(src), "--rate", "2", "--services", "boom,robot_state",
                "--config", str(cfg), "--out", str(out))
    assert proc.returncode == 3, proc.stderr[-3000:]
    assert "service 'boom' failed: exit code 1 after 2 restart(s) (supervise.max_restarts)" in proc.stderr
    assert "supervise: boom died (exit code 1); restart 2 of 2" in proc.stderr
    partial = tmp_path / "live.partial.mcap"
    assert not out.exists() and partial.exists()
    info = _cli("info", str(partial), "--json")
    assert info.returncode == 0, info.stderr[-2000:]  # a complete file: summary and every chunk readable
    odometry = [m.payload for m in read_messages(partial, keys=["Odometry"])]
    assert len(odometry) == counts_of(partial)["Odometry"] > 0  # robot_state's outputs are all kept
    replay = _cli("run", "--input", str(partial), "--services", "robot_state", "--out", str(tmp_path / "again.mcap"))
    assert replay.returncode == 0, replay.stderr[-3000:]
    again = [m.payload for m in read_messages(tmp_path / "again.mcap", keys=["Odometry"])]
    assert again == odometry, (len(again), len(odometry), proc.stdout[-3000:], proc.stderr[-3000:])


def counts_of(path):
    out: dict[str, int] = {}
    for m in read_messages(path):
        out[m.key] = out.get(m.key, 0) + 1
    return out
