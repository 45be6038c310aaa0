"""The ``poseidon`` command.

Subcommands:

- ``run --input REC.mcap --out RUN.mcap [--map-dir DIR] [--config FILE] [--set key=value ...] [--embedded]
  [--services a,b] [--rate R] [--timeout S] [--json]``: replay a recording through every
  built service and record the run (:mod:`launcher.run`).  ``run --live ros1 --out RUN.mcap
  [--services a,b] [--duration S]``: the same on a live source (:mod:`launcher.live`, which
  documents the summary's live keys: ``dropped``, the bridge's ``latency``).  Exit code 0 on success, 2 on
  bad configuration/input, 3 when a service failed (its name is printed).
- ``demo [--seed S] [--out DIR] [--baselines] [--embedded] [--timeout S] [--json]``: the main
  job on a fresh machine (:mod:`launcher.demo`): a transformed simulated cave mission through
  every service with the VPR Guard ON and OFF, a summary with the method's checks, an HTML report.
- ``service NAME --connect ENDPOINT [...]``: run one service (player, recorder or an
  algorithm service, built by :func:`launcher.services.build_worker` as the embedded run
  builds them) anywhere, connected to a hub or router.  Exit 0 when its inputs
  ended, 1 when it failed, 2 on bad configuration, 4 when the run was aborted because
  another service died (see :mod:`common.bus`).
- ``bridge ros1 [--connect ENDPOINT] [--duration S] [--announce a,b] [--json]``: the ROS 1 bridge
  (:mod:`services.bridge_ros1.bridge`) on a hub: sensor topics of the ROS master
  (``ROS_MASTER_URI`` or ``bridge_ros1.master_uri``) onto the bus, our outputs back to ROS,
  until SIGINT/SIGTERM or ``--duration``; prints its counters (``BridgeStats``).  Exit 2 when
  rospy or the master is unavailable.
- ``hub [--listen ENDPOINT] [--zenoh-config FILE]``: a hub (Zenoh router) for services on
  several hosts.
- ``info REC.mcap [--json] [--recover FIXED.mcap]``: keys, message counts, time span and
  metadata of a recording; exit 1 when it is damaged or unfinished (a killed recorder),
  2 when it is not a readable MCAP recording.  ``--recover`` rewrites every intact message
  into a complete file any standard MCAP reader opens.  ``--json`` keys: ``counts``,
  ``types``, ``start_ns``, ``end_ns``, ``duration_s``, ``metadata`` (record name -> field
  names), ``complete`` (bool), ``damage`` (where it stops being readable, "" if complete),
  ``recovered`` (``{"path", "messages"}`` with ``--recover``).
- ``sim``, ``transform``, ``import``, ``export``, ``vpr``, ``deadreckon``, ``eval``, ``audit``, ``compare``, ``report``,
  ``path``: see their own ``--help``.

``--json`` output of ``run`` and ``demo``: ``{"output", "mode", "wall_s", "services":
{name: {...per-service counters...}}, "recording": {"counts": {key: n}, "duration_s"},
"restarts": {name: number of supervised restarts},
"evaluation": {"front_end": {...}, "dead_reckoning": {...}, "back_end": {...}}}`` (``demo`` adds
``"mission"``: the simulated input file; the evaluation keys are documented in
:mod:`eval.summary`, present when the run has LVC ids / ground truth / a map).
"""
from __future__ import annotations

import os

# One BLAS thread per process, set before numpy loads (an explicit setting of the user wins).
# Each service is one process and the run's parallelism is across processes; a 2-thread
# OpenBLAS makes the LSBH projection (1792 x 1024 float32 matvec) cost 1.06 ms instead of
# 0.13 ms on an idle machine and ~12 ms when every core is busy (threads spin on each other).
for _blas in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas, "1")

import argparse
import importlib
import json
import logging
import resource
import signal
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the commands import what they use when they run (a fast start for every command)
    from common.resume import Supervision
    from launcher.config import PoseidonConfig
    from launcher.services import WorkerSpec

__all__ = ["main"]

log = logging.getLogger("poseidon")

#: exit code of ``poseidon service`` stopped by an abort of the run (another service failed)
EXIT_ABORTED = 4

#: subcommands implemented by other parts of the tree: name -> "module:function(argv) -> int"
DELEGATED = {
    "sim": "missions.sim.cli:main",
    "transform": "missions.transform:main",
    "import": "missions.importers.cli:main",
    "vpr": "eval.vpr:main",
    "deadreckon": "eval.deadreckon:main",
    "eval": "eval.run_eval:main",
    "audit": "eval.audit:main",
    "compare": "eval.compare:main",
    "report": "eval.report.cli:main",
    "path": "services.expmap.path:main",
    "export": "missions.export.cli:main",
    "certs": "launcher.certs:main",
    "acl": "launcher.acl:main",
}


def _setup_logging(level: str) -> None:
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:  # Zenoh's own errors (TLS handshakes, refused authentication) on stderr; RUST_LOG overrides
        import zenoh
        zenoh.init_log_from_env_or("error")
    except (ImportError, AttributeError):
        pass


def _load_config(args: argparse.Namespace) -> Any:
    from launcher.config import load_config
    return load_config(args.config, args.set)


def _add_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="YAML configuration (defaults: deploy/poseidon.yaml values)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one field, e.g. --set vpr_guard.vpr_window=30 (repeatable)")
    p.add_argument("--log-level", default="INFO")


def _print_run(result: dict[str, Any], as_json: bool, config: Any) -> None:
    from eval.summary import format_summary, summarize_run
    result["evaluation"] = summarize_run(result["output"], config)
    if as_json:
        print(json.dumps(result, indent=2))
        return
    rec = result["recording"]
    print(f"run finished ({result['mode']}) in {result['wall_s']:.1f} s wall; "
          f"{rec['duration_s']:.1f} s of mission -> {result['output']}")
    print("recorded messages per key:")
    for key, n in sorted(rec["counts"].items()):
        print(f"  {key:<24} {n:>8}")
    for name, st in result["services"].items():
        extra = []
        if st.get("invalid"):
            extra.append(f"invalid {st['invalid']}")
        if st.get("counters"):
            extra.append(", ".join(f"{k} {v}" for k, v in sorted(st["counters"].items())))
        if "busy_s" in st:
            extra.append(f"busy {st['busy_s']:.2f} s")
        if "cpu_s" in st:
            extra.append(f"process CPU {st['cpu_s']:.2f} s")
        if st.get("real_time_factor"):
            extra.append(f"{st['real_time_factor']:.1f}x real time")
        if st.get("dropped"):
            extra.append(f"dropped (queue full, oldest first) {st['dropped']}")
        if st.get("late"):
            extra.append(f"late {st['late']}")
        if st.get("raw"):
            extra.append(f"carried raw {st['raw']}")
        print(f"  [{name}] " + "; ".join(extra) if extra else f"  [{name}] ok")
        for stage, lat in (st.get("latency") or {}).items():
            if lat.get("n"):
                print(f"    latency arrival -> {stage:<9} p50 {lat['p50_ms']:8.1f} ms  p95 {lat['p95_ms']:8.1f} ms  "
                      f"p99 {lat['p99_ms']:8.1f} ms  (n {lat['n']})")
    for line in format_summary(result["evaluation"]):
        print(line)


def _run_live(args: argparse.Namespace) -> int:
    """``run --live SOURCE``: stop on SIGINT/SIGTERM or ``--duration`` (:mod:`launcher.live`)."""
    import threading

    from common.config import ConfigError
    from launcher.live import run_live
    from launcher.run import RunFailed
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        config = _load_config(args)
        services = [s for s in args.services.split(",") if s and s != "none"] if args.services is not None else None
        result = run_live(config, args.live, args.out, services=services, duration_s=args.duration, stop=stop)
    except (ConfigError, ValueError, KeyError, TimeoutError) as exc:
        print(f"poseidon run: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"poseidon run: {exc}; what was recorded so far is in {exc.partial} ({args.out} left as it was)",
              file=sys.stderr)
        return 3
    _print_run(result.as_dict(), args.json, config)
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.run import RunFailed, run_distributed, run_embedded
    if (args.live is None) == (args.input is None):
        print("poseidon run: give exactly one of --input REC.mcap and --live SOURCE", file=sys.stderr)
        return 2
    if args.live is not None:
        if args.embedded or args.rate is not None:
            print("poseidon run: --embedded and --rate do not apply to --live", file=sys.stderr)
            return 2
        return _run_live(args)
    try:
        config = _load_config(args)
        if args.rate is not None:
            config.player.rate = args.rate
        if args.map_dir:
            from launcher.run import use_map_dir
            use_map_dir(config, args.map_dir)
        services = [s for s in args.services.split(",") if s and s != "none"] if args.services is not None else None
        runner = run_embedded if args.embedded else run_distributed
        result = runner(config, args.input, args.out, services=services, timeout_s=args.timeout,
                        progress=not args.json)
    except (ConfigError, RecordingError, ValueError, KeyError, FileNotFoundError) as exc:
        print(f"poseidon run: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"poseidon run: {exc}; what was recorded so far is in {exc.partial} ({args.out} left as it was)",
              file=sys.stderr)
        return 3
    _print_run(result.as_dict(), args.json, config)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from common.config import ConfigError
    from launcher.demo import run_demo
    from launcher.run import RunFailed
    try:
        config = _load_config(args)
        return run_demo(config, Path(args.out), seed=args.seed, baselines=args.baselines, embedded=args.embedded,
                        timeout_s=args.timeout, as_json=args.json)
    except ConfigError as exc:
        print(f"poseidon demo: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        print(f"poseidon demo: {exc}; what was recorded so far is in {exc.partial}", file=sys.stderr)
        return 3
    except RuntimeError as exc:  # the simulation or the report failed; their own messages precede this
        print(f"poseidon demo: {exc}", file=sys.stderr)
        return 3


def cmd_info(args: argparse.Namespace) -> int:
    """Exit 0: a complete recording (or recovered with --recover); 1: damaged (what is readable
    is listed, with how to recover it); 2: not a readable MCAP recording."""
    from common.mcap_io import (
        RecordingError,
        read_metadata,
        recording_keys,
        recording_status,
        recording_summary,
        recover_recording,
    )
    try:
        status = recording_status(args.recording)
        summary = recording_summary(args.recording)
        summary["types"] = recording_keys(args.recording)
        meta = read_metadata(args.recording)
        recovered = None
        if args.recover:
            recovered = recover_recording(args.recording, args.recover)
    except RecordingError as exc:
        print(f"poseidon info: {exc}", file=sys.stderr)
        return 2
    summary["metadata"] = {name: sorted(rec) for name, rec in meta.items()}
    summary["complete"] = status["complete"]
    summary["damage"] = status["error"]
    if recovered is not None:
        summary["recovered"] = {"path": args.recover, "messages": recovered}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{args.recording}: {summary['duration_s']:.1f} s")
        for k, n in sorted(summary["counts"].items()):
            print(f"  {k:<24} {n:>8}  {summary['types'].get(k, '')}")
        for name, fields in summary["metadata"].items():
            print(f"  metadata {name}: {', '.join(fields)}")
    if recovered is not None:
        print(f"poseidon info: {recovered} messages written to {args.recover} (a complete recording)", file=sys.stderr)
        return 0
    if not status["complete"]:
        print(f"poseidon info: damaged or unfinished recording: {status['error']}; the messages listed are intact; "
              f"'poseidon info {args.recording} --recover FIXED.mcap' writes them to a complete file",
              file=sys.stderr)
        return 1
    return 0


def _worker_spec(args: argparse.Namespace, config: PoseidonConfig, supervision: Supervision | None) -> WorkerSpec:
    """What ``poseidon service NAME``'s flags say about the worker (the recorder's
    ``--metadata`` file is read here)."""
    from launcher.services import RECORDER, WorkerSpec
    spec = WorkerSpec(supervision=supervision, drain=True, input=args.input, rate=args.rate,
                      keys=args.keys.split(",") if args.keys else None,
                      announce=[k for k in (args.announce or "").split(",") if k], live=args.live,
                      wait_for=[w for w in (args.wait_for or "").split(",") if w], progress=not args.no_progress,
                      out=args.out, expect=[k for k in (args.expect or "").split(",") if k] or None)
    if args.name == RECORDER:
        spec.metadata = json.loads(Path(args.metadata).read_text()) if args.metadata else {
            "tool": "poseidon service recorder", "config": config.model_dump(mode="json")}
    return spec


def cmd_service(args: argparse.Namespace) -> int:
    from common.bus import Bus
    from common.config import ConfigError
    from launcher.services import PLAYER, RECORDER, build_worker
    try:
        config = _load_config(args)
    except ConfigError as exc:
        print(f"poseidon service {args.name}: {exc}", file=sys.stderr)
        return 2
    namespace = args.namespace or config.bus.namespace
    connect = [args.connect] if args.connect else config.bus.connect
    supervision = None
    if args.supervise:
        from common.resume import Supervision
        try:
            supervision = Supervision.from_file(args.supervise, resume=args.resume)
        except ValueError as exc:
            print(f"poseidon service {args.name}: {exc}", file=sys.stderr)
            return 2
    if args.name == PLAYER and not args.input:
        print("poseidon service player: --input REC.mcap is required", file=sys.stderr)
        return 2
    if args.name == RECORDER and not args.out:
        print("poseidon service recorder: --out RUN.mcap is required", file=sys.stderr)
        return 2
    try:
        bus = Bus(namespace, connect=connect, mode=args.mode, config_file=args.zenoh_config, **_secure_args(args))
    except (OSError, ValueError) as exc:
        print(f"poseidon service {args.name}: cannot join the bus: {exc}", file=sys.stderr)
        return 2
    stoppable: list[Any] = []

    def on_signal(signum: int, _frame: Any) -> None:
        log.warning("%s: signal %d, stopping", args.name, signum)
        for obj in stoppable:
            obj.stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        worker = build_worker(args.name, config, bus, _worker_spec(args, config, supervision))
        stoppable.append(worker)
        stats = worker.run().as_dict()
    except Exception:  # the service's own failure: logged with its traceback, exit 1
        log.exception("service %s failed", args.name)
        return 1
    finally:
        bus.close()
    # the process's CPU seconds (user + system, every thread: Zenoh's included), for the
    # per-service cost of a distributed run (issue 21)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    stats["cpu_s"] = round(usage.ru_utime + usage.ru_stime, 3)
    if args.stats:
        Path(args.stats).write_text(json.dumps(stats))
    else:
        print(json.dumps(stats))
    if stats.get("aborted"):
        print(f"poseidon service {args.name}: run aborted: {stats['aborted']}", file=sys.stderr)
        return EXIT_ABORTED
    return 0


def cmd_bridge(args: argparse.Namespace) -> int:
    """``poseidon bridge ros1``: the bridge in this process, on a hub, until a signal or ``--duration``."""
    import threading

    from common.bus import Bus
    from common.config import ConfigError
    from launcher.services import BRIDGE_ROS1, WorkerSpec, build_worker
    from services.bridge_ros1.ros_io import RosUnavailable
    try:
        config = _load_config(args)
    except ConfigError as exc:
        print(f"poseidon bridge {args.kind}: {exc}", file=sys.stderr)
        return 2
    connect = [args.connect] if args.connect else config.bus.connect
    bus = Bus(args.namespace or config.bus.namespace, connect=connect)
    spec = WorkerSpec(announce=[k for k in (args.announce or "").split(",") if k], drain=False)
    worker = build_worker(BRIDGE_ROS1, config, bus, spec)
    signal.signal(signal.SIGTERM, lambda *_: worker.stop())
    signal.signal(signal.SIGINT, lambda *_: worker.stop())
    timer = threading.Timer(args.duration, worker.stop) if args.duration else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    try:
        stats = worker.run().as_dict()
    except RosUnavailable as exc:
        print(f"poseidon bridge {args.kind}: {exc}", file=sys.stderr)
        return 2
    finally:
        if timer is not None:
            timer.cancel()
        bus.close()
    print(json.dumps(stats, indent=2 if args.json else None))
    return 0


def cmd_hub(args: argparse.Namespace) -> int:
    """Run a hub (Zenoh router) until interrupted: the meeting point of services on other hosts."""
    import threading

    from common.bus import open_hub
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    hub = open_hub(args.listen, config_file=args.zenoh_config, **_secure_args(args))
    print(f"hub listening on {args.listen}", file=sys.stderr)
    try:
        stop.wait()
    finally:
        hub.close()
    return 0


def _add_secure_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tls-dir", help="secured profile: folder written by 'poseidon certs' (ca.pem, HOST.pem, ...)")
    p.add_argument("--tls-host", help="secured profile: this computer's name in --tls-dir (HOST.pem/HOST.key)")
    p.add_argument("--zenoh-user", help="secured profile: user name (the service's name)")
    p.add_argument("--zenoh-password-file", help="secured profile: file holding the user's password")


def _secure_args(args: argparse.Namespace) -> dict[str, str | None]:
    return {"tls_dir": args.tls_dir, "tls_host": args.tls_host, "user": args.zenoh_user,
            "password_file": args.zenoh_password_file}


def _delegate(name: str) -> Callable[[list[str]], int]:
    module, func = DELEGATED[name].split(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and module.startswith(exc.name):
            raise SystemExit(f"poseidon {name}: not available in this build ({module} missing)") from None
        raise
    return getattr(mod, func)


def _add_run_command(sub: Any) -> None:
    """``poseidon run``: replay a recording (or a live source) through the services."""
    p = sub.add_parser("run", help="replay a recording through the services and record the run")
    p.add_argument("--input", help="input recording (MCAP); or --live")
    p.add_argument("--live", choices=["ros1"], help="a live source instead of --input: ros1 = the ROS 1 bridge "
                   "on ROS_MASTER_URI (launcher/live.py); ends on Ctrl-C/SIGTERM or --duration")
    p.add_argument("--duration", type=float, help="--live: stop after this many seconds")
    p.add_argument("--out", required=True, help="output recording of the run (MCAP)")
    p.add_argument("--embedded", action="store_true", help="all services in this process")
    p.add_argument("--services", help="comma-separated algorithm services (default: every built one)")
    p.add_argument("--rate", type=float, help="replay speed: 1 real time, N x, 0 as fast as possible")
    p.add_argument("--timeout", type=float, help="fail if the run takes longer (s)")
    p.add_argument("--json", action="store_true", help="print the run summary as JSON")
    p.add_argument("--map-dir", help="load the map (LVC/HTM state, pose cells, experience map, embedding "
                   "statistics) from this folder when there, begin a new session in it, save the merged map "
                   "there at the end")
    _add_config_args(p)
    p.set_defaults(func=cmd_run)


def _add_demo_command(sub: Any) -> None:
    """``poseidon demo``: the main job on a fresh machine (:mod:`launcher.demo`)."""
    p = sub.add_parser("demo", help="simulate and transform a cave mission, run it with the VPR Guard ON and OFF, "
                       "write the report")
    from launcher.demo import add_arguments as demo_arguments
    demo_arguments(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_demo)


def _add_service_command(sub: Any) -> None:
    """``poseidon service NAME``: one service connected to a hub/router."""
    p = sub.add_parser("service", help="run one service connected to a hub/router")
    p.add_argument("name", help="player, recorder, bridge_ros1 (live ROS 1 source), encoder, htm, robot_state, posecells, "
                   "expmap, ratslam_lv (RatSLAM front-end)")
    p.add_argument("--connect", help="Zenoh endpoint of the hub/router, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--mode", default="client", choices=["client", "peer"], help="Zenoh session mode")
    p.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file (deploy/*.json5)")
    p.add_argument("--namespace", help="vehicle namespace (default from configuration)")
    p.add_argument("--stats", help="write the service's final counters here (JSON) instead of stdout")
    p.add_argument("--input", help="player: recording to publish")
    p.add_argument("--rate", type=float, help="player: replay speed")
    p.add_argument("--keys", help="player: comma-separated keys to publish")
    p.add_argument("--wait-for", help="player: comma-separated services to wait for")
    p.add_argument("--announce", help="bridge_ros1: comma-separated source keys kept alive while silent")
    p.add_argument("--live", action="store_true", help="a service of a live run: bounded input queue (live.*)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--out", help="recorder: output MCAP")
    p.add_argument("--expect", help="recorder: keys whose end-of-stream ends the recording")
    p.add_argument("--metadata", help="recorder: JSON file with the run's metadata record")
    p.add_argument("--supervise", metavar="FILE", help="supervised run: checkpoints, replays (written by the "
                   "launcher, see common/resume.py)")
    p.add_argument("--resume", action="store_true", help="with --supervise: this is a restart, resume from the "
                   "last checkpoint")
    _add_secure_args(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_service)


def _add_bridge_command(sub: Any) -> None:
    """``poseidon bridge ros1``: the ROS 1 bridge."""
    p = sub.add_parser("bridge", help="bridge a robot middleware to the bus (ROS 1: sensor topics in, our outputs out)")
    p.add_argument("kind", choices=["ros1"], help="the middleware")
    p.add_argument("--connect", help="Zenoh endpoint of the hub/router (default: bus.connect)")
    p.add_argument("--namespace", help="vehicle namespace (default from configuration)")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: at SIGINT/SIGTERM)")
    p.add_argument("--announce", help="comma-separated source keys kept alive with watermarks even while silent")
    p.add_argument("--json", action="store_true", help="print the counters indented")
    _add_config_args(p)
    p.set_defaults(func=cmd_bridge)


def _add_hub_command(sub: Any) -> None:
    """``poseidon hub``: a hub (Zenoh router)."""
    p = sub.add_parser("hub", help="run a hub (Zenoh router) for services on several hosts")
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="endpoint to listen on")
    p.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file (deploy/zenoh/*.json5)")
    p.add_argument("--log-level", default="INFO")
    _add_secure_args(p)
    p.set_defaults(func=cmd_hub)


def _add_info_command(sub: Any) -> None:
    """``poseidon info``: the summary of a recording."""
    p = sub.add_parser("info", help="summarise a recording (exit 1 if damaged, 2 if unreadable)")
    p.add_argument("recording")
    p.add_argument("--json", action="store_true")
    p.add_argument("--recover", metavar="FIXED.mcap",
                   help="write every intact message of a damaged recording (e.g. a killed recorder's) to a complete file")
    p.add_argument("--log-level", default="WARNING")
    p.set_defaults(func=cmd_info)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="poseidon", description="PoseidonSLAM: underwater SLAM services")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_run_command(sub)
    _add_demo_command(sub)
    _add_service_command(sub)
    _add_bridge_command(sub)
    _add_hub_command(sub)
    _add_info_command(sub)

    for name in DELEGATED:
        sub.add_parser(name, help=f"see 'poseidon {name} --help'", add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in DELEGATED:
        _setup_logging("INFO")
        return int(_delegate(argv[0])(argv[1:]) or 0)
    args = build_parser().parse_args(argv)
    _setup_logging(args.log_level)
    return int(args.func(args) or 0)


def _main_profiled() -> int:
    """:func:`main` under :mod:`cProfile` (developer aid): with ``POSEIDON_PROFILE_DIR=DIR`` set,
    each ``poseidon`` process (every service of a distributed run is one) writes
    ``DIR/<command>[-<service>]-<pid>.prof`` for ``python -m pstats``.  Only the main thread is
    profiled -- where every service decodes and processes its inputs -- and timed by that
    thread's CPU clock (waiting for input costs nothing)."""
    import cProfile
    import time
    out = Path(os.environ["POSEIDON_PROFILE_DIR"])
    out.mkdir(parents=True, exist_ok=True)
    argv = sys.argv[1:]
    tag = "-".join(argv[:2]) if argv[:1] == ["service"] else (argv[0] if argv else "poseidon")
    prof = cProfile.Profile(time.thread_time)
    try:
        return int(prof.runcall(main) or 0)
    finally:
        prof.dump_stats(str(out / f"{tag}-{os.getpid()}.prof"))


def isolate_stdout() -> None:
    """Native code (Zenoh's Rust logging, e.g. "timer overrun" under load) writes to file
    descriptor 1, which would corrupt a ``--json`` document on stdout.  Point descriptor 1 at
    stderr and keep :data:`sys.stdout` on a duplicate of the original: the command's own
    output stays alone on stdout, everything else goes to stderr."""
    try:
        saved = os.dup(1)
    except OSError:  # started without a stdout (fd 1 closed): nothing to keep apart
        return
    sys.stdout.flush()
    os.dup2(2, 1)
    sys.stdout = os.fdopen(saved, "w", buffering=1 if sys.stdout.line_buffering else -1,
                           encoding=sys.stdout.encoding, errors=sys.stdout.errors)


def entry() -> None:
    """The ``poseidon`` console script (and ``python -m launcher.cli``): :func:`main`, then leave
    without interpreter finalisation.

    Zenoh's Rust threads call into Python.  If the interpreter finalises while one of them
    waits for the GIL, CPython ends that thread with ``pthread_exit``; its forced unwind meets
    the Rust FFI boundary, which aborts the process ("FATAL: exception not rethrown", SIGABRT,
    exit -6) after a run that succeeded -- seen about once in a few hundred runs under load.
    Every command has closed its sessions, recordings and files when :func:`main` returns, so
    the process flushes logging and stdio and ends with ``os._exit`` (no finalisation, no abort).
    """
    isolate_stdout()
    try:
        code = _main_profiled() if os.environ.get("POSEIDON_PROFILE_DIR") else main()
    except SystemExit as exc:          # argparse errors (2), explicit exits
        if exc.code is None or isinstance(exc.code, int):
            code = exc.code or 0
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except KeyboardInterrupt:
        code = 130
    except BaseException:              # noqa: BLE001 - reported in full, then the same exit as Python's
        traceback.print_exc()
        code = 1
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe or stream: the output is lost, so not a success
            code = code or 1
    os._exit(code)


if __name__ == "__main__":
    entry()
