"""``poseidon run --live ros1 --out RUN.mcap [--services a,b] [--duration S]`` and
``poseidon run --live mcap --input REC.mcap [--rate R] --out RUN.mcap [...]``: the services on
a live source instead of a recording replayed at their pace.

The launcher opens a hub (a Zenoh router on a free loopback port) and starts, each in its own
process (and its own session: Ctrl-C reaches only the launcher): the recorder, the services
(``--live``: bounded input queues, :class:`common.worker.DropOldestQueue`) and, once those are
alive, the source: ``ros1`` -- the ROS 1 bridge (:mod:`services.bridge_ros1.bridge`) against
the master of ``ROS_MASTER_URI`` / ``bridge_ros1.master_uri``; ``mcap`` -- the live player
(:mod:`services.player.live`), which plays a recording by the wall clock at ``--rate`` x real
time (default 1) as a vehicle's sensors would: a live run without ROS, on any recording.
Sources never wait: they publish every message at once, with wall-clock watermarks on every
source key (the rule: :mod:`common.live`), so a silent sensor does not stall the services.

It ends on SIGINT/SIGTERM, after ``--duration`` seconds or (``mcap``) at the end of the
recording: the source sends end-of-stream on every source key; the services then finish
their inputs and end their outputs, and the recorder closes a complete file when every
expected key has ended (``live.stop_timeout_s`` at most).  As for a replay, the recording is
written to ``<out stem>.partial.mcap`` and moved onto ``--out`` only when the run succeeded; it
replays through ``poseidon run --input`` like any other recording.  Live runs are not
supervised (a live source cannot replay what a restarted service missed): a process that
fails ends the run (:class:`launcher.run.RunFailed`, exit 3).

Latency goes into the recording: once the services' outputs ended, the source publishes its
:class:`common.messages.LatencyReport` on ``live/latency`` (the recorder awaits that key), so
``poseidon eval RUN.mcap`` reports it (``latency``) long after the run.  A replay never
republishes it (:func:`launcher.run.plan_run`).

The run summary (``--json``) is that of ``poseidon run`` (``mode``: ``"live"``), with per service
``dropped`` (data frames dropped per input key by the bounded queue) and the source's counters
under ``services.bridge_ros1`` / ``services.live_player``: ``published``/``late`` per key,
``watermarks``; the bridge's ``received``/``raw``/``to_ros`` and outage counters
``delivered_late``/``resent``/``dropped_outage``/``outages`` (per key, the rule in
:mod:`common.live`; the recorder's ``missing``: frames per key that never arrived); the live
player's ``input``, ``rate``, ``complete`` and ``behind_ms`` (``p99``/``max``: how late it
published against its schedule); and ``latency`` -- per stage (``lvc``, ``event``, ``map``,
``odometry``, ``dead_reckoning``) ``n``, ``p50_ms``, ``p95_ms``, ``p99_ms``, ``max_ms``,
``unmatched``: the wall time from a sensor message's arrival at the source to the output it
caused (matched by stamp) arriving back at the source.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml

from common.bus import Bus, open_hub
from common.live import LATENCY_KEY
from common.mcap_io import code_revision
from launcher.children import die_with_launcher
from launcher.inputs import input_report
from launcher.run import (
    RunFailed,
    RunPlan,
    RunResult,
    _free_port,
    _log_args,
    _monitor,
    _stats_file,
    _stop_all,
    _summarise,
    plan_run,
)
from services.player.player import SOURCE_KEYS
from system.config import PoseidonConfig
from system.services import BRIDGE_ROS1, LIVE_PLAYER, RECORDER, available_services, node_io

__all__ = ["plan_live", "run_live", "LIVE_SOURCES"]

log = logging.getLogger(__name__)

#: ``--live`` sources: name -> the worker that is the source
LIVE_SOURCES = {"ros1": BRIDGE_ROS1, "mcap": LIVE_PLAYER}


def plan_live(config: PoseidonConfig, services: list[str] | None = None) -> RunPlan:
    """Which services run; the source keys the bridge announces (its configured topics' keys and
    every sensor key a service reads that no service produces); what the recorder awaits."""
    names = list(services) if services is not None else list(config.services or available_services(config))
    io = {n: node_io(n, config) for n in names}
    produced = {k for _i, outs in io.values() for k in outs}
    routed = {r.key for r in config.bridge_ros1.topics.values() if r.key}
    needed = {k for ins, _o in io.values() for k in ins if k not in produced}
    unknown = sorted(k for k in needed if k not in routed and k not in SOURCE_KEYS)
    if unknown:
        raise ValueError(f"live run: services {names} read {unknown}, which no service produces and no "
                         f"bridge_ros1.topics route maps to (add a route 'ROS topic: {{key: ...}}')")
    source_keys = sorted((routed | needed) - produced)
    return RunPlan(names, source_keys, sorted(set(source_keys) | produced | {LATENCY_KEY}), io)


def plan_live_mcap(config: PoseidonConfig, input_path: str | Path, services: list[str] | None = None) -> RunPlan:
    """The plan of a replay (:func:`launcher.run.plan_run`: the recording's keys no service
    produces), whose recorder also awaits the live player's latency report."""
    plan = plan_run(config, input_path, services)
    plan.expect = sorted({*plan.expect, LATENCY_KEY})
    return plan


def _metadata(config: PoseidonConfig, source: str, services: list[str], input_path: Path | None,
              rate: float) -> dict[str, Any]:
    return {"tool": "poseidon run --live", "mode": "live", "source": source, "services": services,
            "code_revision": code_revision(), "input": f"live:{source}" + (f":{input_path}" if input_path else ""),
            "input_sha256": "", "rate": rate if input_path else None, "config": config.model_dump(mode="json")}


def _first_failure(procs: dict[str, subprocess.Popen[bytes]], first: str, wait_s: float = 10.0) -> tuple[str, str]:
    """A process ended during the live phase.  A failing source still ends its streams, so the
    others may end normally before it exits: wait (at most ``wait_s``) for a non-zero exit code
    and name that process; else ``first``."""
    deadline = time.monotonic() + wait_s
    while True:
        bad = [(n, p.returncode) for n, p in procs.items() if p.poll() not in (None, 0)]
        if bad:
            return bad[0][0], f"exited with code {bad[0][1]} before the end of the live run"
        if time.monotonic() > deadline or all(p.poll() is not None for p in procs.values()):
            return first, f"exited with code {procs[first].returncode} before the end of the live run"
        time.sleep(0.1)


def _commands(plan: RunPlan, source: str, tmp: Path, endpoint: str, partial: Path, inp: Path | None,
              rate: float) -> dict[str, list[str]]:
    """The command line of every process of the run (its configuration and metadata in ``tmp``)."""
    common = ["--connect", endpoint, "--config", str(tmp / "config.yaml"), *_log_args()]
    base = [sys.executable, "-m", "launcher.cli", "service"]
    cmds = {RECORDER: base + [RECORDER, *common, "--out", str(partial), "--expect", ",".join(plan.expect),
                              "--metadata", str(tmp / "metadata.json"), "--stats", str(_stats_file(tmp, RECORDER))]}
    for name in plan.services:
        cmds[name] = base + [name, *common, "--live", "--stats", str(_stats_file(tmp, name))]
    cmds[source] = base + [source, *common, "--announce", ",".join(plan.player_keys),
                           "--stats", str(_stats_file(tmp, source))]
    if inp is not None:
        cmds[source] += ["--input", str(inp), "--rate", repr(rate), "--keys", ",".join(plan.player_keys)]
    return cmds


def run_live(config: PoseidonConfig, source: str, out: str | Path, services: list[str] | None = None,
             duration_s: float | None = None, stop: threading.Event | None = None,
             input_path: str | Path | None = None, rate: float = 1.0) -> RunResult:
    """Run the services on the live ``source`` until ``stop`` is set or ``duration_s`` passed
    (``mcap``: or the end of ``input_path``, played at ``rate``; see the module notes); returns
    the run summary."""
    if source not in LIVE_SOURCES:
        raise ValueError(f"--live {source}: unknown live source (known: {', '.join(LIVE_SOURCES)})")
    if (source == "mcap") != (input_path is not None):
        raise ValueError("--live mcap plays --input REC.mcap; --live ros1 takes no --input")
    if not rate > 0:
        raise ValueError(f"--rate {rate}: a live source plays at > 0 x real time")
    out = Path(out)
    if out.suffix != ".mcap" or out.is_dir():
        raise ValueError(f"--out {out}: the output must be an .mcap file")
    partial = out.with_name(out.stem + ".partial.mcap")
    inp = Path(input_path) if input_path is not None else None
    plan = plan_live(config, services) if inp is None else plan_live_mcap(config, inp, services)
    stop = stop or threading.Event()
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    t0 = time.monotonic()
    hub = open_hub(endpoint)
    watcher = Bus(config.bus.namespace, connect=[endpoint])
    procs: dict[str, subprocess.Popen[bytes]] = {}
    bridge = LIVE_SOURCES[source]
    with tempfile.TemporaryDirectory(prefix="poseidon-live-") as tmp_dir:
        tmp = Path(tmp_dir)
        cfg_file = tmp / "config.yaml"
        cfg_file.write_text(yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
        (tmp / "metadata.json").write_text(json.dumps(_metadata(config, source, plan.services, inp, rate)))
        cmds = _commands(plan, bridge, tmp, endpoint, partial, inp, rate)
        env = dict(os.environ)
        env.setdefault("NUMBA_CACHE_DIR", str(Path(tempfile.gettempdir()) / "poseidon-numba-cache"))

        def start(name: str) -> None:
            procs[name] = subprocess.Popen(cmds[name], env=env, stdout=2, start_new_session=True,
                                           preexec_fn=die_with_launcher(os.getpid()))

        failed: tuple[str, str] | None = None
        try:
            for name in [RECORDER, *plan.services]:
                start(name)
            watcher.wait_alive([RECORDER, *plan.services], config.live.startup_timeout_s)
            start(bridge)  # the consumers are subscribed: nothing the source publishes is lost
            log.info("live run: %s -> %s (services %s); stop with Ctrl-C%s", source, out, ", ".join(plan.services),
                     f" or after {duration_s:.0f} s" if duration_s else "")
            deadline = None if duration_s is None else time.monotonic() + duration_s
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                dead = [n for n, p in procs.items() if p.poll() is not None]
                if inp is not None and dead and all(procs[n].returncode == 0 for n in dead):
                    break  # the live player played its recording to the end: the rest is ending
                if dead:  # before its time: blame the one that failed, not those that ended after it
                    failed = _first_failure(procs, dead[0])
                    break
                stop.wait(0.2)
            if failed is None:
                if procs[bridge].poll() is None:
                    procs[bridge].send_signal(signal.SIGTERM)  # the source ends its streams; the rest follows
                failed = _monitor(procs, config.live.stop_timeout_s)
        finally:
            _stop_all(procs)
            watcher.close()
            hub.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves close() unannotated
        if failed:
            raise RunFailed(failed[0], failed[1], str(partial))
        os.replace(partial, out)
        result = RunResult(str(out), "live", time.monotonic() - t0)
        for name in cmds:
            p = _stats_file(tmp, name)
            if p.exists():
                result.services[name] = json.loads(p.read_text())
    result.recording = _summarise(out)
    result.inputs = input_report(config, plan.io, result.services, inp)
    return result
