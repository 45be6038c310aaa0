"""``poseidon run --live ros1 --out RUN.mcap [--services a,b] [--duration S]`` and
``poseidon run --live mcap --input REC.mcap [--rate R] --out RUN.mcap [...]``: the services on
a live source instead of a recording replayed at their pace.

The launcher starts a hub (``poseidon hub``, a Zenoh router on a free loopback port, in its own
process) and, each in its own process (and its own session: Ctrl-C reaches only the launcher):
the recorder, the services
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
replays through ``poseidon run --input`` like any other recording.

Supervised (``supervise.max_restarts`` > 0, the default): a service, the recorder or the hub
that dies is started again (``--resume`` after ``n x supervise.restart_backoff_s``); it resumes
from its checkpoint and catches up from what the source keeps for it (``live.retain_s``,
``live.retain_mb``: :meth:`common.live.LiveSource.serve_replays`) and its upstream services
keep (:mod:`common.resume`), then follows the live stream again.  The source is not restarted:
its failure ends the run (:class:`launcher.run.RunFailed`, exit 3).  A process that used its
restarts ends the run cleanly: its outputs get end-of-stream from the launcher, the source is
stopped, the others finish, exit 3 naming it, the partial recording complete.  Health
(:mod:`launcher.health`) goes on ``live/health`` every ``supervise.health_interval_s`` and into
the summary (``health``, ``recoveries``).  What survives which fault: docs/DEPLOY.md.

Latency goes into the recording: once the services' outputs ended, the source publishes its
:class:`common.messages.LatencyReport` on ``live/latency`` (the recorder awaits that key), so
``poseidon eval RUN.mcap`` reports it (``latency``) long after the run.  A replay never
republishes it (:func:`launcher.run.plan_run`).

The run summary (``--json``) is that of ``poseidon run`` (``mode``: ``"live"``; ``restarts`` per
process; ``health``: per process ``alive``, ``restarts``, ``lag_s``, ``checkpoint_age_s`` at the end;
``recoveries``: per restart ``service``, ``cause``, ``restarted_s``, ``resumed_s``, ``caught_up_s``,
wall seconds from the death), with per service
``dropped`` (data frames dropped per input key by the bounded queue) and the source's counters
under ``services.bridge_ros1`` / ``services.live_player``: ``published``/``late`` per key,
``watermarks``; the bridge's ``received``/``raw``/``to_ros`` and outage counters
``delivered_late``/``resent``/``dropped_outage``/``outages`` (per key, the rule in
:mod:`common.live`; the recorder's ``missing``: frames per key that never arrived); the live
player's ``input``, ``rate``, ``complete`` and ``behind_ms`` (``p99``/``max``: how late it
published against its schedule); the source's ``retention`` (supervised: the bound ``retain_s``,
``retain_mb``, the most kept at once ``peak_mb``, ``replays`` answered, ``short``: frames per key
asked for that were no longer kept), the live player's ``outages``/``delivered_late`` per key (a
restarted hub: the outage rule of :mod:`common.live`); and ``latency`` -- per stage (``lvc``, ``event``, ``map``,
``odometry``, ``dead_reckoning``) ``n``, ``p50_ms``, ``p95_ms``, ``p99_ms``, ``max_ms``,
``unmatched``: the wall time from a sensor message's arrival at the source to the output it
caused (matched by stamp) arriving back at the source.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from common.bus import Bus
from common.codec import encode_frame
from common.live import HEALTH_KEY, LATENCY_KEY
from common.mcap_io import code_revision
from common.ordering import END_OF_TIME
from launcher.children import child_env, describe_exit, stop_all
from launcher.health import Recovery, ServiceHealth, checkpoint_ages, diagnostics, snapshot
from launcher.inputs import input_report
from launcher.run import (
    RunFailed,
    RunPlan,
    RunResult,
    _free_port,
    _log_args,
    _stats_file,
    _summarise,
    plan_run,
    state_dir_of,
    supervision_plan,
)
from services.player.player import SOURCE_KEYS
from system.config import PoseidonConfig
from system.services import BRIDGE_ROS1, LIVE_PLAYER, RECORDER, available_services, node_io

__all__ = ["plan_live", "run_live", "LIVE_SOURCES", "HUB"]

log = logging.getLogger(__name__)

#: ``--live`` sources: name -> the worker that is the source
LIVE_SOURCES = {"ros1": BRIDGE_ROS1, "mcap": LIVE_PLAYER}
#: the hub's process name in a live run (restarts, health)
HUB = "hub"


def plan_live(config: PoseidonConfig, services: list[str] | None = None) -> RunPlan:
    """Which services run; the keys the bridge bridges (``read``: every sensor key a service reads
    that no service produces; None, every topic, with ``bridge_ros1.bridge_unread`` or when no
    service reads one); the source keys it announces (those, or with every topic its configured
    topics' keys too); what the recorder awaits."""
    names = list(services) if services is not None else list(config.services or available_services(config))
    io = {n: node_io(n, config) for n in names}
    produced = {k for _i, outs in io.values() for k in outs}
    routed = {r.key for r in config.bridge_ros1.topics.values() if r.key}
    needed = {k for ins, _o in io.values() for k in ins if k not in produced}
    unknown = sorted(k for k in needed if k not in routed and k not in SOURCE_KEYS)
    if unknown:
        raise ValueError(f"live run: services {names} read {unknown}, which no service produces and no "
                         f"bridge_ros1.topics route maps to (add a route 'ROS topic: {{key: ...}}')")
    read = None if config.bridge_ros1.bridge_unread or not needed else sorted(needed)
    source_keys = sorted((routed | needed) - produced) if read is None else read
    return RunPlan(names, source_keys, sorted(set(source_keys) | produced | {LATENCY_KEY}), io, read=read)


def plan_live_mcap(config: PoseidonConfig, input_path: str | Path, services: list[str] | None = None) -> RunPlan:
    """The plan of a replay (:func:`launcher.run.plan_run`: the recording's keys no service
    produces), whose recorder also awaits the live player's latency report."""
    plan = plan_run(config, input_path, services, live=True)
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
              rate: float, supervise: list[str]) -> dict[str, list[str]]:
    """The command line of every process of the run (its configuration and metadata in ``tmp``;
    ``supervise``: the supervision arguments of the recorder, the services and the source)."""
    common = ["--connect", endpoint, "--config", str(tmp / "config.yaml"), *_log_args()]
    base = [sys.executable, "-m", "launcher.cli"]
    cmds = {HUB: base + ["hub", "--listen", endpoint],
            RECORDER: base + ["service", RECORDER, *common, *supervise, "--out", str(partial),
                              "--expect", ",".join(plan.expect), "--metadata", str(tmp / "metadata.json"),
                              "--stats", str(_stats_file(tmp, RECORDER))]}
    for name in plan.services:
        cmds[name] = base + ["service", name, *common, *supervise, "--live", "--stats", str(_stats_file(tmp, name))]
    cmds[source] = base + ["service", source, *common, *supervise, "--announce", ",".join(plan.player_keys),
                           "--stats", str(_stats_file(tmp, source))]
    if inp is None and plan.read is not None:
        cmds[source] += ["--read", ",".join(plan.read)]
    if inp is not None:
        cmds[source] += ["--input", str(inp), "--rate", repr(rate), "--keys", ",".join(plan.player_keys)]
    return cmds


def _wait_listening(endpoint: str, proc: subprocess.Popen[bytes], timeout_s: float = 30.0) -> str:
    """Wait until the hub process accepts TCP connections on ``endpoint`` (``tcp/HOST:PORT``);
    '' when it does, else what went wrong."""
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return f"exited with code {proc.returncode} before listening on {endpoint}"
        try:
            with socket.create_connection((host, int(port)), timeout=0.5):
                return ""
        except OSError:
            time.sleep(0.05)
    return f"not listening on {endpoint} after {timeout_s:.0f} s"


class _Supervisor:
    """The processes of a live run: started, restarted (supervised), followed for health.

    ``restartable``: the processes started again when they die (the services, the recorder and
    the hub; never the source, which holds what the others catch up from)."""

    def __init__(self, config: PoseidonConfig, cmds: dict[str, list[str]], source: str, state_dir: Path | None,
                 endpoint: str):
        self.config = config
        self.cmds = cmds
        self.source = source
        self.state_dir = state_dir
        self.endpoint = endpoint
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.restarts: dict[str, int] = {}
        self.recoveries: list[Recovery] = []
        self.max_restarts = config.supervise.max_restarts if state_dir is not None else 0
        self.env = dict(os.environ)
        self.env.setdefault("NUMBA_CACHE_DIR", str(Path(tempfile.gettempdir()) / "poseidon-numba-cache"))
        self.env.setdefault("PYTHONFAULTHANDLER", "1")
        self.given_up: tuple[str, str] | None = None
        self.health: dict[str, ServiceHealth] = {}
        self._pending: dict[str, float] = {}  # name -> monotonic time of its restart (backoff)
        self._ended: set[str] = set()  # processes that ended normally (exit 0)

    def start(self, name: str, resume: bool = False) -> None:
        cmd = self.cmds[name] + (["--resume"] if resume and name != HUB else [])
        self.procs[name] = subprocess.Popen(cmd, env=child_env(self.env), stdout=2, start_new_session=True)

    def check(self, now: float, progress: Callable[[str], int]) -> list[str]:
        """Handle the processes that ended since the last call: a restartable one that failed is
        restarted after its backoff (or given up: :attr:`given_up`); returns the names of the
        non-restartable ones that ended (exit code in ``procs``)."""
        ended = []
        for name, due in list(self._pending.items()):
            if now >= due:
                del self._pending[name]
                self.start(name, resume=True)
                rec = next(r for r in reversed(self.recoveries) if r.service == name)
                rec.restarted_s = time.monotonic() - rec.died
                rec.progress_at_restart = progress(name)
        for name, p in self.procs.items():
            rc = p.poll()
            if rc is None or name in self._pending or name in self._ended:
                continue
            if rc == 0 or name == self.source or self.given_up is not None:
                self._ended.add(name)
                ended.append(name)
                continue
            n = self.restarts.get(name, 0)
            if n >= self.max_restarts:
                self._ended.add(name)
                detail = describe_exit(rc) + (f" after {n} restart(s) (supervise.max_restarts)" if n else "")
                log.error("supervise: %s %s; ending the run", name, detail)
                self.given_up = (name, detail)
                ended.append(name)
                continue
            self.restarts[name] = n + 1
            delay = self.config.supervise.restart_backoff_s * (n + 1)
            log.warning("supervise: %s died (%s); restart %d of %d in %.1f s, resuming from its last checkpoint",
                        name, describe_exit(rc), n + 1, self.max_restarts, delay)
            self.recoveries.append(Recovery(name, describe_exit(rc), now))
            self._pending[name] = now + delay
        return ended

    def running(self, name: str) -> bool:
        p = self.procs.get(name)
        return p is not None and p.poll() is None and name not in self._pending

    def done(self, names: list[str]) -> bool:
        """Every one of ``names`` ended for good (exit 0, given up, or the source)."""
        return all(n in self._ended for n in names)


def _hub_up(sv: _Supervisor, before_services: Callable[[], None] | None) -> str:
    """Wait until the hub listens, then call ``before_services``; '' when the hub is up, else
    what went wrong with it."""
    problem = _wait_listening(sv.endpoint, sv.procs[HUB])
    if not problem and before_services is not None:
        before_services()
    return problem


def _outputs_of(plan: RunPlan, service: str) -> tuple[str, ...]:
    return plan.io[service][1] if service in plan.io else ()


def run_live(config: PoseidonConfig, source: str, out: str | Path, services: list[str] | None = None,
             duration_s: float | None = None, stop: threading.Event | None = None,
             input_path: str | Path | None = None, rate: float = 1.0, hub_port: int | None = None,
             before_services: Callable[[], None] | None = None) -> RunResult:
    """Run the services on the live ``source`` until ``stop`` is set or ``duration_s`` passed
    (``mcap``: or the end of ``input_path``, played at ``rate``; see the module notes); the hub
    listens on loopback ``hub_port`` (default a free port); ``before_services`` is called once
    it listens, before any other process starts (``poseidon run --view``: until the view is
    ready, so its start-up is not inside the run's data); returns the run summary."""
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
    plan.expect = sorted({*plan.expect, HEALTH_KEY})
    stop = stop or threading.Event()
    state_dir = state_dir_of(config, out) if config.supervise.max_restarts > 0 else None
    endpoint = f"tcp/127.0.0.1:{hub_port or _free_port()}"
    t0 = time.monotonic()
    bridge = LIVE_SOURCES[source]
    with tempfile.TemporaryDirectory(prefix="poseidon-live-") as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "config.yaml").write_text(yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
        (tmp / "metadata.json").write_text(json.dumps(_metadata(config, source, plan.services, inp, rate)))
        supervise: list[str] = []
        if state_dir is not None:
            if state_dir.exists():  # checkpoints of an earlier run must never be resumed from
                shutil.rmtree(state_dir)
            state_dir.mkdir(parents=True)
            sup = supervision_plan(config, plan, state_dir)
            sup.live = True
            sup.retain_ns, sup.retain_bytes = int(config.live.retain_s * 1e9), int(config.live.retain_mb * 1e6)
            (tmp / "supervision.json").write_text(sup.to_json())
            supervise = ["--supervise", str(tmp / "supervision.json")]
        sv = _Supervisor(config, _commands(plan, bridge, tmp, endpoint, partial, inp, rate, supervise), bridge,
                         state_dir, endpoint)
        failed = _live_phases(config, plan, sv, bridge, stop, duration_s, before_services)
        if failed:
            raise RunFailed(failed[0], failed[1], str(partial))
        os.replace(partial, out)
        if state_dir is not None and not config.supervise.state_dir:
            shutil.rmtree(state_dir, ignore_errors=True)
        result = RunResult(str(out), "live", time.monotonic() - t0, restarts=dict(sv.restarts))
        for name in sv.cmds:
            p = _stats_file(tmp, name)
            if p.exists():
                result.services[name] = json.loads(p.read_text())
        result.health = dict(sv.health)
        result.recoveries = [r.as_dict() for r in sv.recoveries]
    result.recording = _summarise(out)
    result.inputs = input_report(config, plan.io, result.services, inp)
    return result


def _live_phases(config: PoseidonConfig, plan: RunPlan, sv: _Supervisor, bridge: str, stop: threading.Event,
                 duration_s: float | None, before_services: Callable[[], None] | None) -> tuple[str, str] | None:
    """Start the hub, the recorder, the services and then the source; supervise them through
    the live phase and the end (module notes); the failure to report, or None."""
    sup = config.supervise
    consumers = [RECORDER, *plan.services]
    everyone = [HUB, *consumers, bridge]
    failed: tuple[str, str] | None = None
    sv.start(HUB)
    watcher: Bus | None = None
    try:
        problem = _hub_up(sv, before_services)
        if problem:
            return HUB, problem
        watcher = Bus(config.bus.namespace, connect=[sv.endpoint])
        progress = watcher.watch_progress()
        health_pub = watcher.publisher(HEALTH_KEY)
        for name in consumers:
            sv.start(name)
        watcher.wait_alive(consumers, config.live.startup_timeout_s)
        sv.start(bridge)  # the consumers are subscribed: nothing the source publishes is lost
        log.info("live run: %s (services %s); stop with Ctrl-C%s", bridge, ", ".join(plan.services),
                 f" or after {duration_s:.0f} s" if duration_s else "")
        deadline = None if duration_s is None else time.monotonic() + duration_s
        seq = 0
        next_health = time.monotonic()
        stopping_at: float | None = None  # when the source was asked to end (or ended)
        health_ended = False
        while True:
            now = time.monotonic()
            ended = sv.check(now, progress.get)
            if bridge in ended:
                rc = sv.procs[bridge].returncode
                if rc != 0 and failed is None:
                    failed = _first_failure({n: sv.procs[n] for n in everyone if n in sv.procs}, bridge)
                stopping_at = stopping_at or now
            if sv.given_up is not None and failed is None:
                failed = sv.given_up
                # its consumers get its end-of-stream from here, so they finish and the recording closes
                for key in _outputs_of(plan, failed[0]):
                    watcher.publisher(key).send_eos()
                stopping_at = stopping_at or now
                if sv.running(bridge):
                    sv.procs[bridge].send_signal(signal.SIGTERM)
            if stopping_at is None and (stop.is_set() or (deadline is not None and now >= deadline)):
                stopping_at = now
                if sv.running(bridge):
                    sv.procs[bridge].send_signal(signal.SIGTERM)  # the source ends its streams; the rest follows
            if now >= next_health:
                sv.health = _health(sv, everyone, progress, now)
                if not health_ended:
                    msg = diagnostics(sv.health, _source_stamp(progress, bridge), seq, sup.caught_up_lag_s)
                    health_pub.send_raw(encode_frame(msg))
                    seq += 1
                next_health = now + sup.health_interval_s
            if not health_ended and (sv.done([bridge]) or all(
                    progress.get(n) == END_OF_TIME or (sv.given_up or ("",))[0] == n for n in plan.services)):
                # the recorder awaits it: the last sample went out once the services finished their inputs
                health_pub.send_eos()
                health_ended = True
            if sv.done(everyone[1:]):
                break
            stopping_at = stopping_at or (now if sv.done(consumers) else None)  # the source's stop_timeout_s
            if stopping_at is not None and now - stopping_at > config.live.stop_timeout_s:
                still = [n for n in everyone[1:] if n not in sv._ended]
                failed = failed or (still[0], f"did not finish within {config.live.stop_timeout_s:.0f} s after "
                                              f"the source ended (still running: {', '.join(still)})")
                break
            time.sleep(0.1)
        sv.health = _health(sv, everyone, progress, time.monotonic())  # the run's final state
        if failed is None:
            bad = [(n, sv.procs[n].returncode) for n in everyone[1:] if sv.procs[n].returncode not in (0, None)]
            if bad:
                failed = (bad[0][0], f"exited with code {bad[0][1]}")
    finally:
        stop_all({n: p for n, p in sv.procs.items() if n != HUB})
        if watcher is not None:
            watcher.close()
        stop_all({HUB: sv.procs[HUB]})
    return failed


def _source_stamp(progress: Any, source: str) -> int:
    stamp: int = progress.get(source)
    return stamp if stamp >= 0 else 0


def _health(sv: _Supervisor, names: list[str], progress: Any, now: float) -> dict[str, ServiceHealth]:
    """The health snapshot of the run's processes; follows the recoveries in progress."""
    prog = {n: progress.get(n) for n in names}
    src = prog.get(sv.source)
    alive = {n: sv.running(n) for n in names}
    snap = snapshot(names, alive, sv.restarts, {n: v for n, v in prog.items() if n != sv.source},
                    src if src is not None and src >= 0 else None,
                    checkpoint_ages(sv.state_dir, names, time.time()))
    snap[sv.source]["lag_s"] = 0.0
    for rec in sv.recoveries:
        rec.follow(now, prog.get(rec.service, -2), snap[rec.service]["lag_s"], sv.config.supervise.caught_up_lag_s)
    return snap
