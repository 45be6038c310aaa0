"""Supervision and resume: SIGKILL of every process at once mid-run (after their first
checkpoints), and the recorded streams equal an uninterrupted run's message for message; the
checkpoint of every algorithm core round-trips (save, load into a fresh node, continue: the
same outputs as a node never interrupted).

One short simulated mission and one uninterrupted run are shared by the module; the kill test
is one more distributed run (~30 s on 2 cores)."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import services.encoder.node  # noqa: F401  (see below)
from common.codec import encode
from common.mcap_io import read_messages
from common.ordering import EventTimeMerger
from common.resume import load_checkpoint, save_checkpoint
from launcher.children import child_pid
from missions.sim.cli import main as sim_main
from system.config import load_config
from system.services import build_node
from tests.common.processes import finish
from tests.common.recordings import payloads_by_key
from tests.conftest import REPO

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow]
# services.encoder.node is imported up front: a kill test unpickles the service's first checkpoint
# mid-run, and the encoder's pulls in torch (~1.5 s on first import), about as long as what is left
# of the run after that checkpoint once the encoder is fast (encoder.runtime openvino)

CHECKPOINT_S = 3.0  # event time between checkpoints: several per run of the 24-s mission
SLAM_KEYS = ("neocortex/sdr", "local_view_cells", "Odometry", "ground_truth", "experience_event", "map",
             "experience_image", "dead_reckoning")


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("supervise")
    assert sim_main(["--minutes", "0.4", "--seed", "3", "--out", str(d / "cave.mcap")]) == 0
    return d


def _settings(work: Path) -> list[str]:
    return ["--set", f"encoder.lsbh.matrix_path={work}/lsbh_{{backbone}}_{{modality}}.npy",
            "--set", f"supervise.checkpoint_interval_s={CHECKPOINT_S}",
            "--set", f"supervise.recorder_checkpoint_interval_s={CHECKPOINT_S / 2}", "--set", "supervise.restart_backoff_s=0.1"]


def _launch(work: Path, out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "launcher.cli", "run", "--input", str(work / "cave.mcap"), "--out", str(out),
           "--json", *_settings(work)]
    return subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=open(out.with_suffix(".err"), "w"),
                            text=True)


@pytest.fixture(scope="module")
def uninterrupted(work):
    out = work / "uninterrupted.mcap"
    proc = _launch(work, out)
    stdout = finish(proc, 400, out.with_suffix(".err"), out.with_suffix(".log"))
    assert proc.returncode == 0, out.with_suffix(".err").read_text()[-3000:]
    result = json.loads(stdout)
    assert result["restarts"] == {}
    counts = result["recording"]["counts"]
    assert counts["experience_event"] > 0 and counts["map"] > 0 and counts["local_view_cells"] > 50
    for name in ("encoder", "htm", "robot_state", "posecells", "expmap", "recorder"):
        assert result["services"][name]["checkpoints"] >= 2, (name, result["services"][name])
    return out


VICTIMS = ["encoder", "htm", "robot_state", "posecells", "expmap", "recorder", "player"]


def test_sigkill_of_every_process_mid_run_resumes_to_the_uninterrupted_streams(work, uninterrupted, tmp_path):
    """Every service, the recorder and the player SIGKILLed in one run, each right after its first
    checkpoint (the player, which keeps none, after the recorder's), so that several are down at
    once; each restarts from its own checkpoint, the publishers answer the replays from what
    their checkpoints kept, and the recorded streams equal the uninterrupted run's."""
    out = tmp_path / "killed.mcap"
    proc = _launch(work, out)
    state = tmp_path / "killed.state"
    killed: list[str] = []
    try:
        deadline = time.monotonic() + 300
        while len(killed) < len(VICTIMS):
            assert proc.poll() is None, f"the run ended before every process was killed (killed: {killed})"
            assert time.monotonic() < deadline, f"not every process checkpointed within 300 s (killed: {killed})"
            for name in VICTIMS:
                ckpt = state / f"{'recorder' if name == 'player' else name}.ckpt"
                if name in killed or not ckpt.exists():
                    continue
                assert not load_checkpoint(ckpt).get("finished"), f"{name}: killed after its end, not mid-run"
                pid = child_pid(proc.pid, name)
                assert pid is not None, f"{name} not running"
                os.kill(pid, signal.SIGKILL)
                killed.append(name)
            time.sleep(0.02)
        stdout = finish(proc, 400, out.with_suffix(".err"), out.with_suffix(".log"))
    finally:
        if proc.poll() is None:
            proc.kill()
    err = out.with_suffix(".err").read_text()
    assert proc.returncode == 0, err[-3000:]
    for service in VICTIMS:
        assert f"supervise: service {service} died (killed by signal SIGKILL); restart 1 of 3" in err
        if service != "player":
            assert f"{service}: resumed" in err, err[-3000:]
    result = json.loads(stdout)
    assert result["restarts"] == {n: 1 for n in VICTIMS}
    expected, got = payloads_by_key(uninterrupted), payloads_by_key(out)
    assert set(got) == set(expected)
    for key in SLAM_KEYS:
        assert len(got[key]) == len(expected[key]), (key, len(got[key]), len(expected[key]))
        assert got[key] == expected[key], f"{key} differs from the uninterrupted run after every process was killed"
    for key in set(expected) - set(SLAM_KEYS):  # the replayed inputs, recorded once each
        assert got[key] == expected[key], key


@pytest.mark.parametrize("service", ["encoder", "htm", "robot_state", "posecells", "expmap"])
def test_checkpoint_round_trip_continues_like_an_uninterrupted_node(service, work, uninterrupted, tmp_path):
    """Save mid-stream, load into a node built afresh, continue: outputs byte for byte those of
    one node that ran through (also prints the checkpoint's cost and size)."""
    config = load_config(overrides=[f"encoder.lsbh.matrix_path={work}/lsbh_{{backbone}}_{{modality}}.npy"])
    first = build_node(service, config)
    merger = EventTimeMerger(list(first.inputs))
    for rec in read_messages(uninterrupted, keys=list(first.inputs)):
        msg = rec.message()
        merger.push(rec.key, msg.header.stamp, msg.header.seq, msg)
    for key in first.inputs:
        merger.end(key)
    ordered = [(key, msg) for key, _stamp, msg in merger.pop_ready()]
    assert len(ordered) > 100

    def drive(node, items, finish):
        out = []
        for key, msg in items:
            node.process(key, msg)
            out += node.take_outbox()
        if finish:
            node.finish()
            out += node.take_outbox()
        return [(k, encode(m)) for k, m in out]

    uninterrupted_node = build_node(service, config)
    reference = drive(uninterrupted_node, ordered, True)
    half = len(ordered) // 2
    before = drive(first, ordered[:half], False)
    t0 = time.perf_counter()
    size = save_checkpoint(tmp_path / "c.ckpt", {"node": first.checkpoint_state()})
    ms = (time.perf_counter() - t0) * 1e3
    resumed = build_node(service, config)
    resumed.restore_checkpoint(load_checkpoint(tmp_path / "c.ckpt")["node"])
    after = drive(resumed, ordered[half:], True)
    print(f"[checkpoint] {service}: {size.total / 1e6:.2f} MB, {ms:.1f} ms to save after {half} inputs")
    assert before + after == reference
    assert resumed.counters == uninterrupted_node.counters
