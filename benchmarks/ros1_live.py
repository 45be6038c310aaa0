"""One live run of a ROS 1 bag through ``poseidon run --live ros1``, for the benchmarks that play
the demo mission into ROS (``bench_recovery.py``, ``bench_live_ros1.py``).

:func:`demo_bag` makes (or reuses) the demo mission and its ROS 1 bag; :func:`live_run` starts
the run against a private ``roscore``, waits until the bridge is up, plays the bag with
``rosbag play -r RATE`` (optionally SIGKILLing services at given wall times), stops the run
with SIGINT once the bag has played and returns its ``--json`` result.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from launcher.children import child_pid  # noqa: E402
from launcher.demo import ensure_mission  # noqa: E402
from products.rosbag import export_rosbag  # noqa: E402
from tests.bridge_ros1.ros1 import ROS_PY, Roscore  # noqa: E402

CLI = [sys.executable, "-m", "launcher.cli"]
#: rosbag waits this long after advertising, so that the subscribed bridge has connected first [s]
PLAY_DELAY_S = 5.0

__all__ = ["CLI", "Roscore", "demo_bag", "live_run"]


def demo_bag(cache: Path, seed: int) -> tuple[Path, Path]:
    """The demo mission for ``seed`` and its ROS 1 bag (``poseidon export --ros1``), made or reused in ``cache``."""
    if ROS_PY not in sys.path:
        sys.path.append(ROS_PY)
    cache.mkdir(parents=True, exist_ok=True)
    mission, _cached = ensure_mission(cache, seed)
    bag = cache / f"{mission.stem}.bag"
    if not bag.exists():
        export_rosbag(mission, bag, ros2=False)
    return mission, bag


def _wait_bridge(uri: str, timeout_s: float = 180.0) -> None:
    """Until the bridge advertised its outputs on the master (it is up and subscribed)."""
    import rosgraph
    master = rosgraph.Master("/poseidon_bench", master_uri=uri)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pubs, _s, _v = master.getSystemState()
        if any(t == "/poseidon/odom" for t, _n in pubs):
            return
        time.sleep(0.2)
    raise TimeoutError("the bridge did not come up")


def live_run(core: Roscore, bag: Path, out: Path, rate: float, kills: list[tuple[str, float]] = (),
             settings: list[str] = ()) -> dict[str, Any]:
    """One live run of ``bag`` played at ``rate``; ``kills``: (service, wall seconds after the
    first message); ``settings``: ``--set`` values.  Returns the run's ``--json`` result (its
    stderr is kept beside ``out`` as ``.err``); RuntimeError naming the failure otherwise."""
    err = open(out.with_suffix(".err"), "w")
    cmd = CLI + ["run", "--live", "ros1", "--out", str(out), "--json"]
    for s in settings:
        cmd += ["--set", s]
    run = subprocess.Popen(cmd, cwd=REPO, env=core.env, stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        _wait_bridge(core.uri)
        play = subprocess.Popen(["rosbag", "play", "-q", "-d", str(PLAY_DELAY_S), "--queue", "100000", "-r",
                                 repr(rate), str(bag)], env=core.env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        t0 = time.monotonic() + PLAY_DELAY_S
        for name, at_s in sorted(kills, key=lambda k: k[1]):
            time.sleep(max(0.0, t0 + at_s - time.monotonic()))
            pid = child_pid(run.pid, name)
            if pid is None:
                raise RuntimeError(f"{name} is not running at {at_s:.1f} s")
            os.kill(pid, signal.SIGKILL)
            print(f"  killed {name} at {at_s:.1f} s", file=sys.stderr)
        _o, play_err = play.communicate()
        if play.returncode != 0:
            raise RuntimeError(f"rosbag play failed: {play_err[-2000:]}")
        time.sleep(3.0)
        run.send_signal(signal.SIGINT)
        stdout, _ = run.communicate(timeout=600)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        err.close()
    if run.returncode != 0:
        raise RuntimeError(f"live run failed ({run.returncode}): {out.with_suffix('.err').read_text()[-3000:]}")
    result: dict[str, Any] = json.loads(stdout)
    return result
