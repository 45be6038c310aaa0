"""``poseidon run``: replay a recording through every service and record the run.

Distributed (default): the launcher opens the hub (a Zenoh router on a free loopback
port) and starts the recorder, each algorithm service and the player as separate
processes (``poseidon service NAME --connect tcp/127.0.0.1:PORT``).  Embedded
(``--embedded``): the same pieces as threads on one Zenoh session in this process.

The player publishes the input keys a started service reads (and the ground truth), the
recorder copies the others from the input (``player.replay`` copied: :func:`plan_run`).  Every
process starts at once, while a thread of the launcher computes the input's SHA-256 (from before
the planning on; ~0.8 CPU s per GB) and hands it to the recorder, which writes it into the
recording's metadata (``input_sha256``) at the end (:mod:`services.recorder.recorder`): no start
waits for it.  The player waits until the
recorder and every service are alive; the run ends when every process has finished (the recorder
has seen end-of-stream on every expected key).  If any
service fails, the others are stopped, what was recorded is kept, and :class:`RunFailed`
names the service.

Supervision (distributed runs, ``supervise.max_restarts`` > 0, the default): a service
(player and recorder included) that dies -- a non-zero exit or a signal, but not exit 4,
"stopped by an abort" -- is started again with ``--resume`` after ``n x
supervise.restart_backoff_s`` (restart n), each restart logged with the service, its exit
code or signal and the attempt; it resumes from its last checkpoint in the run's state
folder (``supervise.state_dir``, default ``<out stem>.state`` next to the output, emptied at
the start of a run and removed after a successful one) and its publishers replay what it
had not checkpointed (:mod:`common.resume`), so the recorded streams equal an uninterrupted
run's.  When a service has used its ``max_restarts`` the run fails as without supervision
(:class:`RunFailed` naming it, exit 3).  Embedded runs are not supervised.

Every service process logs to its console at the launcher's level and appends to the run's
log file (:mod:`launcher.logs`).

Children die with the launcher, even when it is killed with SIGKILL: each is started with
``prctl(PR_SET_PDEATHSIG, SIGTERM)`` (Linux), so no service is left running as an orphan.

Safe outputs: ``--out`` may not be the input (same resolved path or same file).  The run
records into ``<out stem>.partial.mcap`` in the same folder, after the configuration and
the input have been checked, and moves it onto ``--out`` only when the run succeeded; an
existing ``--out`` is never touched before that.  On failure the partial recording stays
under its ``.partial.mcap`` name (:attr:`RunFailed.partial`): nothing recorded is lost.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from common.bus import Bus, open_local_session
from common.live import HEALTH_KEY, LATENCY_KEY
from common.mcap_io import DigestCache, FileDigest, RecordingError, code_revision, recording_keys, recording_summary
from common.resume import Supervision
from common.sessions import open_hub_in_background
from common.worker import Worker
from launcher.children import child_env, describe_exit, stop_all
from launcher.inputs import input_report
from services.player.player import SOURCE_KEYS, TRUTH_KEYS, replayed_keys
from system.calibration import calibrate_from_input
from system.config import PoseidonConfig
from system.services import WorkerSpec, available_services, build_node, build_worker, node_io

__all__ = ["RunFailed", "ServiceStartError", "build_checked", "output_paths", "RunPlan", "RunResult", "plan_run", "calibrate_from_input", "run_distributed", "run_embedded", "node_io"]

log = logging.getLogger(__name__)


class RunFailed(RuntimeError):
    """A service failed; ``service`` names it, ``partial`` is the recording kept so far."""

    def __init__(self, service: str, detail: str, partial: str = ""):
        super().__init__(f"service {service!r} failed: {detail}")
        self.service = service
        self.partial = partial


class ServiceStartError(ValueError):
    """A service could not be built from the configuration (names the service)."""


def build_checked(name: str, config: PoseidonConfig) -> Any:
    """Build service ``name``'s node; any failure becomes a ServiceStartError naming it."""
    try:
        return build_node(name, config)
    except KeyError:
        raise
    except Exception as exc:
        raise ServiceStartError(f"service {name!r} cannot start with this configuration: "
                                f"{type(exc).__name__}: {exc}") from exc


def output_paths(input_path: str | Path, out: str | Path) -> tuple[Path, Path]:
    """``(final, partial)`` paths of a run's recording; ValueError if ``out`` is the input."""
    input_path, out = Path(input_path), Path(out)
    if out.suffix != ".mcap":
        raise ValueError(f"--out {out}: the output must be an .mcap file")
    if out.is_dir():
        raise ValueError(f"--out {out} is a directory")
    partial = out.with_name(out.stem + ".partial.mcap")
    for candidate in (out, partial):
        same = candidate.resolve() == input_path.resolve()
        if not same and candidate.exists() and input_path.exists():
            same = os.path.samefile(candidate, input_path)
        if same:
            raise ValueError(f"--out {out} would overwrite the input recording {input_path}; choose another file")
    return out, partial


def _publish_output(partial: Path, out: Path) -> None:
    """Move the finished recording into place (atomic within the folder)."""
    os.replace(partial, out)


@dataclass
class RunPlan:
    """``copy_keys``: the input keys the recorder copies from the input itself (``player.replay``
    copied); the player publishes ``player_keys``, the recorder awaits the end of ``expect``;
    ``read``: a live ROS 1 run's keys its services read, the bridge's ``--read`` (None: every topic
    is bridged)."""

    services: list[str]
    player_keys: list[str]
    expect: list[str]
    io: dict[str, tuple[tuple[str, ...], tuple[str, ...]]]
    copy_keys: list[str] = field(default_factory=list)
    read: list[str] | None = None


def plan_run(config: PoseidonConfig, input_path: str | Path, services: list[str] | None = None,
             live: bool = False) -> RunPlan:
    """Decide which services run, what the player publishes, what the recorder copies from the
    input (a replay's ``player.replay`` copied; ``live``: a live run replays every key instead)
    and what it awaits.  When no started service reads any of the input's keys (``--services
    none``: player and recorder alone), every key goes over the bus whatever ``player.replay``
    says: the run is a test of the transport, and nothing would otherwise keep the recorder
    waiting for the player."""
    known = available_services(config)
    names = list(services) if services is not None else list(config.services or known)
    unknown = set(config.bus.replay_favoured) - set(known) - {"player", "recorder"}
    if unknown:
        raise ValueError(f"bus.replay_favoured: {sorted(unknown)} name no service (services: "
                         f"{sorted(known)}, player, recorder)")
    io = {n: node_io(n, config) for n in names}
    produced = {k: n for n, (_i, outs) in io.items() for k in outs}
    rec_keys = list(recording_keys(input_path))
    if not rec_keys:
        raise RecordingError(f"{input_path}: no readable messages (not an MCAP recording, or damaged from its start)")
    inputs = sorted(k for k in rec_keys if k not in produced and k not in (LATENCY_KEY, HEALTH_KEY))  # not inputs
    replay = "all" if live and config.player.replay == "copied" else config.player.replay
    read = {k for ins, _o in io.values() for k in ins}
    if not names or not read & set(inputs) - set(TRUTH_KEYS):
        replay = "all"  # nothing started reads the input: a transport run, every key over the bus
    player_keys = replayed_keys(config.player.model_copy(update={"replay": replay}), inputs, read)
    copy_keys = [k for k in inputs if k not in player_keys and (not config.player.keys or k in config.player.keys)
                 and replay == "copied"]
    for n, (ins, _o) in io.items():
        for k in ins:
            if k not in produced and k not in player_keys and k not in SOURCE_KEYS:
                raise ValueError(f"service {n!r} needs key {k!r}, which neither the recording nor any started "
                                 f"service produces (services: {names})")
    expect = sorted(set(player_keys) | set(produced))
    return RunPlan(names, player_keys, expect, io, copy_keys)


@dataclass
class RunResult:
    output: str
    mode: str
    wall_s: float
    services: dict[str, dict[str, Any]] = field(default_factory=dict)
    recording: dict[str, Any] = field(default_factory=dict)
    restarts: dict[str, int] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)
    health: dict[str, Any] = field(default_factory=dict)        # live runs: launcher/health.py
    recoveries: list[dict[str, Any]] = field(default_factory=list)  # live runs: one per restart

    def as_dict(self) -> dict[str, Any]:
        live = {"health": self.health, "recoveries": self.recoveries} if self.mode == "live" else {}
        return {"output": self.output, "mode": self.mode, "wall_s": round(self.wall_s, 3), "services": self.services,
                "recording": self.recording, "restarts": self.restarts, "inputs": self.inputs, **live}


def run_metadata(config: PoseidonConfig, input_path: str | Path, mode: str, services: list[str]) -> dict[str, Any]:
    """The ``poseidon`` metadata record of a replay; the recorder adds ``input_sha256``."""
    return {"tool": "poseidon run", "mode": mode, "services": services, "code_revision": code_revision(),
            "input": str(input_path), "input_sha256": "", "config": config.model_dump(mode="json")}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _summarise(out: Path) -> dict[str, Any]:
    summary = recording_summary(out)
    return {"counts": summary["counts"], "duration_s": round(summary["duration_s"], 3)}


def state_dir_of(config: PoseidonConfig, out: Path) -> Path:
    """The checkpoint folder of a supervised run writing ``out``."""
    return Path(config.supervise.state_dir) if config.supervise.state_dir else out.with_name(out.stem + ".state")


def supervision_plan(config: PoseidonConfig, plan: RunPlan, state_dir: Path) -> Supervision:
    """Who consumes which key (every recorded key: the recorder too), and the intervals."""
    consumers: dict[str, list[str]] = {}
    for key in plan.expect:
        consumers[key] = [n for n in plan.services if key in plan.io[n][0]] + ["recorder"]
    sup = config.supervise
    return Supervision(state_dir, consumers, int(round(sup.checkpoint_interval_s * 1e9)), sup.replay_retry_s,
                       sup.rejoin_timeout_s,
                       recorder_checkpoint_interval_ns=int(round(sup.recorder_checkpoint_interval_s * 1e9)))


def _log_args() -> list[str]:
    """The arguments that make a service process log like the launcher (:mod:`launcher.logs`):
    the same console level, appending to the run's log file."""
    from launcher.logs import child_args
    return child_args()


def _digest_file(tmp: Path) -> Path:
    return tmp / "input.sha256"


def _stats_file(tmp: Path, name: str) -> Path:
    return tmp / f"{name}.stats.json"


def _service_commands(plan: RunPlan, input_path: Path, partial: Path, tmp: Path, common: list[str],
                      progress: bool) -> dict[str, list[str]]:
    """``poseidon service`` command line of every process of a distributed run (recorder,
    services, player: the order they start in); ``common``: the arguments they all get;
    ``tmp`` holds the run's metadata file and receives each one's final counters."""
    base = [sys.executable, "-m", "launcher.cli", "service"]
    cmds = {"recorder": base + ["recorder", *common, "--out", str(partial), "--expect", ",".join(plan.expect),
                                "--metadata", str(tmp / "metadata.json"), "--input-digest", str(_digest_file(tmp)),
                                "--stats", str(_stats_file(tmp, "recorder"))]}
    if plan.copy_keys:
        cmds["recorder"] += ["--copy-from", str(input_path), "--copy-keys", ",".join(plan.copy_keys)]
    for name in plan.services:
        cmds[name] = base + [name, *common, "--stats", str(_stats_file(tmp, name))]
    cmds["player"] = base + ["player", *common, "--input", str(input_path), "--keys", ",".join(plan.player_keys),
                             "--wait-for", ",".join(["recorder", *plan.services]),
                             "--stats", str(_stats_file(tmp, "player"))]
    cmds["player"] += [] if progress else ["--no-progress"]
    return cmds


def _supervision_args(config: PoseidonConfig, plan: RunPlan, state_dir: Path | None, tmp: Path) -> list[str]:
    """The services' ``--supervise FILE`` (none unsupervised), with an empty state folder."""
    if state_dir is None:
        return []
    if state_dir.exists():  # checkpoints of an earlier run must never be resumed from
        shutil.rmtree(state_dir)
    state_dir.mkdir(parents=True)
    sup_file = tmp / "supervision.json"
    sup_file.write_text(supervision_plan(config, plan, state_dir).to_json())
    return ["--supervise", str(sup_file)]


def _prepare(config: PoseidonConfig, input_path: Path, services: list[str] | None,
             hub_port: int | None) -> tuple[RunPlan, str, Future[Any], FileDigest]:
    """The run's plan; meanwhile the hub opens (~0.5 s, mostly Zenoh's own start-up wait) and
    the input's digest starts (the recorder needs it at the end only)."""
    endpoint = f"tcp/127.0.0.1:{hub_port or _free_port()}"
    opening: Future[Any] = open_hub_in_background(endpoint)  # the hub, as the rest of this module holds it
    digest = FileDigest(input_path, cache=DigestCache.default())
    try:
        calibrate_from_input(config, input_path)
        plan = plan_run(config, input_path, services)
    except BaseException:
        digest.cancel()
        if opening.exception() is None:
            opening.result().close()
        raise
    return plan, endpoint, opening, digest


def run_distributed(config: PoseidonConfig, input_path: str | Path, out: str | Path,
                    services: list[str] | None = None, timeout_s: float | None = None,
                    progress: bool = True, hub_port: int | None = None,
                    before_services: Callable[[], None] | None = None) -> RunResult:
    """Each service in its own process, connected through a hub on loopback ``hub_port`` (default a
    free port); supervised when ``supervise.max_restarts`` > 0 (see the module notes); once the
    hub listens, ``before_services()`` returns before any process starts (``run --view``: the view)."""
    input_path, (out, partial) = Path(input_path), output_paths(input_path, out)
    plan, endpoint, opening, digest = _prepare(config, input_path, services, hub_port)
    max_restarts = config.supervise.max_restarts
    state_dir = state_dir_of(config, out) if max_restarts > 0 else None
    t0 = time.monotonic()
    hub = opening.result()
    procs: dict[str, subprocess.Popen[bytes]] = {}
    with tempfile.TemporaryDirectory(prefix="poseidon-run-") as tmp:
        cfg_file = Path(tmp) / "config.yaml"
        cfg_file.write_text(yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
        meta_file = Path(tmp) / "metadata.json"
        common = ["--connect", endpoint, "--config", str(cfg_file), *_log_args()]
        supervise_args = _supervision_args(config, plan, state_dir, Path(tmp))
        cmds = _service_commands(plan, input_path, partial, Path(tmp), [*common, *supervise_args], progress)
        env = dict(os.environ)
        env.setdefault("NUMBA_CACHE_DIR", str(Path(tempfile.gettempdir()) / "poseidon-numba-cache"))
        env.setdefault("PYTHONFAULTHANDLER", "1")  # a service killed by a fatal signal prints where it was
        restarts: dict[str, int] = {}
        batch, favoured = config.bus.batch_scheduling, set(config.bus.replay_favoured)

        def _start(name: str, cmd: list[str]) -> subprocess.Popen[bytes]:
            nice = 0 if name in favoured else config.bus.replay_nice
            return subprocess.Popen(cmd, env=child_env(env, batch, nice), stdout=2)

        def restart(name: str, rc: int) -> subprocess.Popen[bytes] | None:
            """Supervision: start ``name`` again (resuming) unless it used its restarts."""
            n = restarts.get(name, 0)
            if n >= max_restarts:
                if max_restarts:
                    log.error("supervise: service %s died (%s) and used its %d restarts (supervise.max_restarts)",
                              name, describe_exit(rc), max_restarts)
                return None
            restarts[name] = n + 1
            delay = config.supervise.restart_backoff_s * (n + 1)
            log.warning("supervise: service %s died (%s); restart %d of %d in %.1f s, resuming from its last "
                        "checkpoint", name, describe_exit(rc), n + 1, max_restarts, delay)
            time.sleep(delay)
            return _start(name, cmds[name] + ["--resume"])

        digest.publish_to(_digest_file(Path(tmp)))
        try:
            meta_file.write_text(json.dumps(run_metadata(config, input_path, "distributed", plan.services)))
            if before_services is not None:
                before_services()
            # a service's stdout goes to our stderr: our stdout carries only ``run --json``
            for name in cmds:
                procs[name] = _start(name, cmds[name])
            failed = _monitor(procs, timeout_s, restart if max_restarts > 0 else None, restarts)
        finally:
            digest.cancel()
            stop_all(procs)
            hub.close()
        if failed:
            name, detail = failed
            raise RunFailed(name, detail, str(partial))
        _publish_output(partial, out)
        if state_dir is not None and not config.supervise.state_dir:
            shutil.rmtree(state_dir, ignore_errors=True)
        result = RunResult(str(out), "distributed", time.monotonic() - t0, restarts=dict(restarts))
        for name in cmds:
            p = _stats_file(Path(tmp), name)
            if p.exists():
                result.services[name] = json.loads(p.read_text())
    result.recording = _summarise(out)
    result.inputs = input_report(config, plan.io, result.services, input_path)
    return result


#: exit code of a service stopped by the run's abort (``launcher.service_cmd.EXIT_ABORTED``)
_ABORTED = 4


def _monitor(procs: dict[str, subprocess.Popen[bytes]], timeout_s: float | None,
             restart: Any = None, restarts: dict[str, int] | None = None,
             blame_grace_s: float = 3.0) -> tuple[str, str] | None:
    """Wait for every process; the first failure (not a mere abort) is named.  ``restart(name,
    rc)`` (supervision) may return a new process for one that died instead."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    aborted_at: float | None = None
    while True:
        running = 0
        aborted = []
        for name, p in procs.items():
            rc = p.poll()
            if rc is None:
                running += 1
            elif rc == _ABORTED:
                aborted.append(name)
            elif rc != 0:
                if restart is not None:
                    again = restart(name, rc)
                    if again is not None:
                        procs[name] = again
                        running += 1
                        continue
                used = (restarts or {}).get(name, 0)
                return name, (f"exited with code {rc}" + (f" (killed by signal {-rc})" if rc < 0 else "")
                              + (f" after {used} restart(s)" if used else ""))
        if aborted:
            # stopped because another one failed: give the failing one time to show its exit code
            aborted_at = aborted_at or time.monotonic()
            if running == 0 or time.monotonic() - aborted_at > blame_grace_s:
                return aborted[0], "stopped by an abort of the run (see its log for the service that died)"
        if running == 0:
            return None
        if deadline is not None and time.monotonic() > deadline:
            still = [n for n, p in procs.items() if p.poll() is None]
            return still[0], f"did not finish within {timeout_s:.0f} s (still running: {', '.join(still)})"
        time.sleep(0.1)


def run_embedded(config: PoseidonConfig, input_path: str | Path, out: str | Path,
                 services: list[str] | None = None, timeout_s: float | None = None,
                 progress: bool = True) -> RunResult:
    """Every service as a thread on one Zenoh session in this process."""
    input_path, (out, partial) = Path(input_path), output_paths(input_path, out)
    calibrate_from_input(config, input_path)
    plan = plan_run(config, input_path, services)
    t0 = time.monotonic()
    digest = FileDigest(input_path, cache=DigestCache.default())  # for the recording's metadata, at its end
    # every node is built (and its configuration checked) before anything opens the output
    try:
        nodes = {n: build_checked(n, config) for n in plan.services}
    except BaseException:
        digest.cancel()
        raise
    session = open_local_session()
    bus = Bus(config.bus.namespace, session=session)
    errors: dict[str, BaseException] = {}
    results: dict[str, dict[str, Any]] = {}
    threads: list[threading.Thread] = []
    stoppable: list[Worker] = []
    try:
        # the recorder last: it opens the output, once everything else could be built
        specs = {**{n: WorkerSpec(node=node) for n, node in nodes.items()},
                 "player": WorkerSpec(input=input_path, keys=plan.player_keys, wait_for=["recorder", *plan.services],
                                      progress=progress),
                 "recorder": WorkerSpec(out=partial, expect=plan.expect,
                                        metadata=run_metadata(config, input_path, "embedded", plan.services),
                                        input_digest=digest.result,
                                        copy_from=input_path if plan.copy_keys else None, copy_keys=plan.copy_keys)}
        built: dict[str, Worker] = {}
        for name, spec in specs.items():
            built[name] = build_worker(name, config, bus, spec)
            stoppable.append(built[name])
        workers = {"recorder": built["recorder"], **{n: built[n] for n in nodes}, "player": built["player"]}

        def target(name: str, fn: Any) -> None:
            try:
                results[name] = fn().as_dict()
            except BaseException as exc:  # reported below with the service's name
                log.exception("service %s failed", name)
                errors[name] = exc

        threads = [threading.Thread(target=target, args=(n, w.run), name=f"poseidon-{n}", daemon=True)
                   for n, w in workers.items()]
        for t in threads:
            t.start()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while any(t.is_alive() for t in threads) and not errors:
            if deadline is not None and time.monotonic() > deadline:
                still = [t.name.removeprefix("poseidon-") for t in threads if t.is_alive()]
                errors[still[0]] = TimeoutError(f"did not finish within {timeout_s:.0f} s (still running: {still})")
                break
            time.sleep(0.05)
        for name, st in results.items():
            if st.get("aborted") and not errors:
                errors[name] = RuntimeError(f"aborted: {st['aborted']}")
    finally:
        digest.cancel()
        for obj in stoppable:
            obj.stop()
        for t in threads:
            t.join(timeout=10)
        still = [t.name for t in threads if t.is_alive()]
        if still:
            log.error("threads still running after the stop: %s", still)
        bus.close()
        session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves close() unannotated
    if errors:
        name, exc = next(iter(errors.items()))
        raise RunFailed(name, f"{type(exc).__name__}: {exc}", str(partial))
    _publish_output(partial, out)
    result = RunResult(str(out), "embedded", time.monotonic() - t0, services=results)
    result.recording = _summarise(out)
    result.inputs = input_report(config, plan.io, result.services, input_path)
    return result
