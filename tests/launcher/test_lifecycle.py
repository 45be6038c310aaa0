"""Children die with the launcher; a killed recorder's file is recovered
into one the standard MCAP reader opens; `info` fails on files that are not recordings; one
declaration of each service's keys."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from unittest import mock

import pytest
from mcap.reader import make_reader

from common.node import ServiceNode
from launcher.children import children
from launcher.run import node_io, plan_run
from system.config import load_config
from tests.common.recordings import six_stream_recording
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(180)
CLI = [sys.executable, "-m", "launcher.cli"]


def _standard_reader_count(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state not in ("Z", "X")


def test_children_die_with_a_launcher_killed_by_sigkill(tmp_path):
    src = tmp_path / "in.mcap"
    six_stream_recording(src, 3000, image_every=10)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text('{"service_classes": {"stall": "tests.common.nodes:Stall"}}')
    out = tmp_path / "run.mcap"
    launcher = subprocess.Popen(CLI + ["run", "--input", str(src), "--out", str(out), "--config", str(cfg),
                                       "--services", "stall", "--json"], cwd=REPO, stdout=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        kids: list[int] = []
        while time.monotonic() < deadline and len(kids) < 3:  # recorder, stall, player
            time.sleep(0.3)
            kids = children(launcher.pid)
        assert len(kids) == 3, kids
        while not (tmp_path / "run.partial.mcap").exists() and time.monotonic() < deadline:
            time.sleep(0.2)  # the recorder is up
        time.sleep(3.0)  # the run is under way (stall takes 0.2 s per depth message)
        launcher.send_signal(signal.SIGKILL)
        launcher.wait(timeout=10)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_running(k) for k in kids):
            time.sleep(0.2)
        assert not [k for k in kids if _running(k)], "orphans left running"
    finally:
        for k in kids:
            if _running(k):
                os.kill(k, signal.SIGKILL)
    # the recorder was stopped by SIGTERM: its partial file is a complete MCAP, nothing lost
    partial = tmp_path / "run.partial.mcap"
    assert not out.exists()
    assert _standard_reader_count(partial) > 0


@pytest.mark.parametrize("content", [b"", b"\x89MCAP0\r\n", bytes(range(256)) * 20])
def test_info_and_deadreckon_fail_on_files_that_are_not_recordings(tmp_path, content):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    for cmd in (["info", str(bad)], ["info", str(bad), "--json"], ["deadreckon", str(bad), "--json"]):
        proc = subprocess.run(CLI + cmd, cwd=REPO, capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, (cmd, proc.stdout, proc.stderr)
        assert "bad.mcap: not an MCAP recording" in proc.stderr


class _Configured(ServiceNode):
    name = "configured"
    outputs = ("configured/out",)

    @classmethod
    def io_keys(cls, config):
        return (config.encoder.sonar.topic, "depth_sensor"), cls.outputs

    def process(self, key, msg):
        pass


def test_one_declaration_of_keys_used_by_node_and_launcher(tmp_path):
    cfg = load_config(overrides=["encoder.sonar.topic=sonar_seaking"])
    assert node_io("encoder", cfg) == (("camera/image_raw", "sonar_seaking"), ("neocortex/sdr",))
    node = _Configured(cfg)
    assert (node.inputs, node.outputs) == _Configured.io_keys(cfg) == (("sonar_seaking", "depth_sensor"),
                                                                        ("configured/out",))
    # the launcher wires the configured key: a recording with sonar_seaking only plans without error
    import numpy as np

    from common.mcap_io import RecordingWriter
    from common.messages import Header, Image, RangeImageBeam
    rec = tmp_path / "seaking.mcap"
    with RecordingWriter(rec) as w:
        w.write("camera/image_raw", Image(header=Header(seq=0, stamp=1), height=1, width=1, encoding="mono8",
                                          data=np.zeros((1, 1), np.uint8)))
        w.write("sonar_seaking", RangeImageBeam(header=Header(seq=0, stamp=2), angle_grad=0, angle_rad=0, nbins=2,
                                                max_range=10, beam_data=np.zeros(2, np.int32)))
    plan = plan_run(cfg, rec, services=["encoder"])
    assert plan.io["encoder"][0] == ("camera/image_raw", "sonar_seaking")
    assert "sonar_seaking" in plan.player_keys


def test_service_killed_mid_run_is_named_and_the_recording_is_complete_so_far(tmp_path):
    """SIGKILL of a service mid-run without supervision (supervise.max_restarts 0): exit 3 naming
    it, every other process stops (abort), and the partial recording is closed with its summary
    (the standard reader opens it)."""
    src = tmp_path / "in.mcap"
    six_stream_recording(src, 3000, image_every=10)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text('{"service_classes": {"stall": "tests.common.nodes:Stall"}, "supervise": {"max_restarts": 0}}')
    out = tmp_path / "run.mcap"
    launcher = subprocess.Popen(CLI + ["run", "--input", str(src), "--out", str(out), "--config", str(cfg),
                                       "--services", "stall", "--json"], cwd=REPO, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
    try:
        stall = None
        deadline = time.monotonic() + 60
        while stall is None and time.monotonic() < deadline:
            time.sleep(0.3)
            for k in children(launcher.pid):
                try:
                    argv = Path(f"/proc/{k}/cmdline").read_bytes().decode(errors="replace").split("\0")
                except FileNotFoundError:   # a child that ended between the listing and the read
                    continue
                if "service" in argv and argv[argv.index("service") + 1] == "stall":
                    stall = k
        assert stall is not None
        partial = tmp_path / "run.partial.mcap"
        while not partial.exists() and time.monotonic() < deadline:  # the recorder is up
            time.sleep(0.2)
        time.sleep(3.0)  # the replay is under way (stall takes 0.2 s per depth message)
        os.kill(stall, signal.SIGKILL)
        _, err = launcher.communicate(timeout=60)
    finally:
        if launcher.poll() is None:
            launcher.kill()
    assert launcher.returncode == 3, err
    assert "service 'stall' failed: exited with code -9 (killed by signal 9)" in err
    partial = tmp_path / "run.partial.mcap"
    assert not out.exists()
    try:
        n = _standard_reader_count(partial)
    except Exception as exc:  # noqa: BLE001 - the launcher's log says why the file was not closed
        pytest.fail(f"the partial recording has no readable summary ({type(exc).__name__}: {exc}); "
                    f"launcher stderr:\n{err[-4000:]}")
    assert n > 0


def _probe(code: str) -> subprocess.CompletedProcess[str]:
    """``code`` run by a fresh interpreter in the repository (a signal probe: it may exit at once)."""
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=30)


def test_a_signal_delivered_twice_at_once_is_one_stop_and_a_later_one_exits():
    """The kernel delivers the parent-death SIGTERM again on each re-parenting of an orphan: two
    SIGTERMs at once must stop a service once (the recorder still closes its file); a second
    signal a while later exits at once with EXIT_ABORTED."""
    code = (
        "import os, signal, sys, time\n"
        "from launcher.service_cmd import _Signals, EXIT_ABORTED\n"
        "s = _Signals('probe'); stops = []\n"
        "s.on_stop(lambda: stops.append(1))\n"
        "os.kill(os.getpid(), signal.SIGTERM); os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(0.2); print('alive after two at once, stops', len(stops), flush=True)\n"
        "time.sleep(s.DUPLICATE_S + 0.2); os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(5); print('not reached', flush=True)\n")
    proc = _probe(code)
    assert "alive after two at once, stops 1" in proc.stdout
    assert "not reached" not in proc.stdout
    assert proc.returncode == 4, proc.stderr


def test_signals_are_seen_while_the_main_thread_is_held_in_native_code():
    """A main thread blocked inside native code (here a pthread mutex it already holds, the way a
    Zenoh call can hang on a hub that went away) never runs a Python signal handler: the stop must
    still be seen, SIGUSR1 must print the stacks, and the second SIGTERM must exit."""
    code = (
        "import ctypes, os, signal, threading\n"
        "from launcher.service_cmd import _Signals\n"
        "s = _Signals('probe'); s.on_stop(lambda: print('stop seen', flush=True))\n"
        "libc = ctypes.CDLL(None); mutex = ctypes.create_string_buffer(64)\n"
        "libc.pthread_mutex_lock(mutex)\n"
        "for delay, sig in ((0.5, signal.SIGTERM), (1.5, signal.SIGUSR1), (2.5, signal.SIGTERM)):\n"
        "    threading.Timer(delay, os.kill, (os.getpid(), sig)).start()\n"
        "libc.pthread_mutex_lock(mutex)\n"
        "print('not reached', flush=True)\n")
    proc = _probe(code)
    assert proc.stdout == "stop seen\n", (proc.stdout, proc.stderr)
    assert proc.returncode == 4, proc.stderr
    assert "signal 15, stopping" in proc.stderr and "second signal 15: exiting now" in proc.stderr
    assert "Current thread" in proc.stderr and "<module>" in proc.stderr  # faulthandler's dump on SIGUSR1


def test_player_replay_consumed_replays_what_services_read_and_the_truth(tmp_path):
    """player.replay copied (default): keys a started service subscribes to, plus truth/*, over the
    bus, the others copied by the recorder (a live run: every key over the bus); consumed: the same
    keys, nothing copied; all: every key."""
    import numpy as np

    from common.mcap_io import RecordingWriter
    from common.messages import Header, Image, RangeImageBeam
    from common.messages import Odometry as Odom
    rec = tmp_path / "m.mcap"
    beam = dict(angle_grad=0, angle_rad=0, nbins=2, max_range=10, beam_data=np.zeros(2, np.int32))
    with RecordingWriter(rec) as w:
        w.write("camera/image_raw", Image(header=Header(seq=0, stamp=1), height=1, width=1, encoding="mono8",
                                          data=np.zeros((1, 1), np.uint8)))
        w.write("sonar_micron", RangeImageBeam(header=Header(seq=0, stamp=2), **beam))
        w.write("sonar_seaking", RangeImageBeam(header=Header(seq=0, stamp=3), **beam))
        w.write("truth/pose", Odom(header=Header(seq=0, stamp=4), position=[0, 0, 0], orientation=[0, 0, 0, 1]))
    copied = plan_run(load_config(), rec, services=["encoder"])
    assert copied.player_keys == ["camera/image_raw", "sonar_micron", "truth/pose"]
    assert copied.copy_keys == ["sonar_seaking"] and "sonar_seaking" not in copied.expect
    live = plan_run(load_config(), rec, services=["encoder"], live=True)
    assert live.player_keys == ["camera/image_raw", "sonar_micron", "sonar_seaking", "truth/pose"]
    assert live.copy_keys == []
    alone = plan_run(load_config(), rec, services=[])  # player and recorder alone: a transport run
    assert alone.player_keys == live.player_keys and alone.copy_keys == []
    everything = plan_run(load_config(overrides=["player.replay=all"]), rec, services=["encoder"])
    assert everything.player_keys == ["camera/image_raw", "sonar_micron", "sonar_seaking", "truth/pose"]
    assert everything.copy_keys == []
    consumed = plan_run(load_config(overrides=["player.replay=consumed"]), rec, services=["encoder"])
    assert consumed.player_keys == ["camera/image_raw", "sonar_micron", "truth/pose"]
    assert "sonar_seaking" not in consumed.expect and consumed.copy_keys == []  # nor copies it
    narrowed = plan_run(load_config(overrides=["player.replay=consumed", "player.keys=[camera/image_raw]"]), rec,
                        services=["encoder"])
    assert narrowed.player_keys == ["camera/image_raw"]
    narrowed = plan_run(load_config(overrides=["player.keys=[camera/image_raw,sonar_seaking]"]), rec,
                        services=["encoder"])
    assert narrowed.player_keys == ["camera/image_raw"] and narrowed.copy_keys == ["sonar_seaking"]


def test_replay_children_run_under_sched_batch_die_with_the_launcher_and_a_refusal_is_reported():
    """bus.batch_scheduling: a child started with child_env takes SCHED_BATCH itself (and every
    thread it starts has it), binds its death to the launcher's, and does not pass either on to
    its own children; a refused SCHED_BATCH is said on its stderr, and it runs all the same."""
    from launcher.children import child_env

    if not hasattr(os, "SCHED_BATCH"):
        pytest.skip("this system has no SCHED_BATCH")
    probe = ("import ctypes, os, signal, sys, threading\n"
             "{patch}"
             "from launcher.children import adopt_launcher\n"
             "adopt_launcher('probe')\n"
             "sig = ctypes.c_int(0)\n"
             "ctypes.CDLL(None).prctl(2, ctypes.byref(sig), 0, 0, 0)  # PR_GET_PDEATHSIG\n"
             "t = threading.Thread(target=lambda: print(os.sched_getscheduler(0), sig.value,"
             " 'POSEIDON_LAUNCHER_PID' in os.environ)); t.start(); t.join()\n")
    refuse = "def _refuse(*a): raise PermissionError(1, 'not permitted')\nos.sched_setscheduler = _refuse\n"
    for batch, patch, policy in [(True, "", os.SCHED_BATCH), (False, "", os.SCHED_OTHER),
                                 (True, refuse, os.SCHED_OTHER)]:
        proc = subprocess.run([sys.executable, "-c", probe.format(patch=patch)], env=child_env(batch_scheduling=batch),
                              cwd=REPO, capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        got_policy, got_sig, passed_on = proc.stdout.split()
        assert int(got_policy) == policy  # a thread the child starts has the child's policy
        assert int(got_sig) == signal.SIGTERM and passed_on == "False"
        assert ("did not get SCHED_BATCH" in proc.stderr) is bool(patch), proc.stderr


def test_replay_children_but_the_favoured_run_nicer_and_a_bad_favoured_name_is_refused(tmp_path):
    """bus.replay_nice / bus.replay_favoured: a child started with child_env(nice=N) raises its own
    niceness by N before any thread (a thread it starts has it too) and does not pass the setting
    on; run_distributed gives every service but the favoured ones that niceness; a favoured name
    that is no service is refused, naming the field."""
    from launcher import run as run_mod
    from launcher.children import child_env

    probe = ("import os, threading\n"
             "from launcher.children import adopt_launcher\n"
             "adopt_launcher('probe')\n"
             "t = threading.Thread(target=lambda: print(os.nice(0), 'POSEIDON_NICE' in os.environ)); t.start(); t.join()\n")
    base = os.nice(0)
    for nice in (0, 5):
        proc = subprocess.run([sys.executable, "-c", probe], env=child_env(nice=nice), cwd=REPO,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        got, passed_on = proc.stdout.split()
        assert int(got) == min(base + nice, 19) and passed_on == "False"
    with pytest.raises(ValueError, match="nice must be >= 0"):
        child_env(nice=-1)

    started: dict[str, str] = {}
    real_popen = subprocess.Popen

    def record(cmd, env=None, **kw):  # noqa: ANN001, ANN202 - the launcher's Popen, recorded and run
        if "service" in cmd:
            started[cmd[cmd.index("service") + 1]] = env["POSEIDON_NICE"]
        return real_popen(cmd, env=env, **kw)

    mission = tmp_path / "m.mcap"
    six_stream_recording(mission, 200)
    cfg = load_config(overrides=["bus.replay_nice=7", "bus.replay_favoured=[recorder]"])
    with mock.patch.object(run_mod.subprocess, "Popen", side_effect=record):
        run_mod.run_distributed(cfg, mission, tmp_path / "run.mcap", services=[], progress=False)
    assert started == {"recorder": "0", "player": "7"}, started
    bad = load_config(overrides=["bus.replay_favoured=[encodr]"])
    with pytest.raises(ValueError, match=r"bus\.replay_favoured: \['encodr'\]"):
        run_mod.plan_run(bad, mission)


def test_the_launcher_starts_no_child_with_a_preexec_fn():
    """Code between fork and exec in the launcher, which has Zenoh threads running, can block on a
    lock one of them held at the fork, and the launcher with it (launcher/children.py)."""
    import ast
    for path in sorted((REPO / "launcher").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.keyword) and node.arg == "preexec_fn":
                pytest.fail(f"{path.name}:{node.value.lineno}: a child started with preexec_fn")


def test_a_live_run_stops_at_the_first_signal_and_exits_at_the_second():
    """``poseidon run --live``'s stop: the first SIGTERM sets it (the run ends its streams), a
    second one a while later exits at once with exit code 4 -- a launcher whose stop hangs does
    not need SIGKILL."""
    code = (
        "import os, signal, time\n"
        "from launcher.run_cmd import stop_on_signals\n"
        "stop = stop_on_signals('probe')\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "print('stop seen' if stop.wait(5) else 'stop missed', flush=True)\n"
        "time.sleep(1.3); os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(5); print('not reached', flush=True)\n")
    proc = _probe(code)
    assert proc.stdout == "stop seen\n", (proc.stdout, proc.stderr)
    assert proc.returncode == 4, proc.stderr
