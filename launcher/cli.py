"""The ``poseidon`` command.

Subcommands:

- ``run --input REC.mcap --out RUN.mcap [--map-dir DIR] [--config FILE] [--set key=value ...] [--embedded]
  [--services a,b] [--rate R] [--timeout S] [--json]``: replay a recording through every
  built service and record the run (:mod:`launcher.run`).  ``run --live ros1 --out RUN.mcap
  [--services a,b] [--duration S]`` and ``run --live mcap --input REC.mcap [--rate R] ...``: the
  same on a live source (:mod:`launcher.live`, which documents the summary's live keys:
  ``dropped``, the source's ``latency``).  Exit code 0 on success, 2 on
  bad configuration/input, 3 when a service failed (its name is printed).
- ``demo [--seed S] [--out DIR] [--baselines] [--embedded] [--timeout S] [--json]``: the main
  job on a fresh machine (:mod:`launcher.demo`): a transformed simulated cave mission through
  every service with the VPR Guard ON and OFF, a summary with the method's checks, an HTML report.
- ``service NAME --connect ENDPOINT [...]``: run one service (player, recorder or an
  algorithm service, built by :func:`system.services.build_worker` as the embedded run
  builds them) anywhere, connected to a hub or router.  Exit 0 when its inputs
  ended, 1 when it failed, 2 on bad configuration, 4 when the run was aborted because
  another service died (see :mod:`common.bus`).
- ``bridge ros1 [--connect ENDPOINT] [--duration S] [--announce a,b] [--read a,b] [--json]``: the ROS 1 bridge
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
  ``recovered`` (``{"path", "messages"}`` with ``--recover``), ``digests`` (with ``--digests``: key ->
  ``{"messages", "sha256"}``, :func:`common.mcap_io.key_digests`).
- ``config --explain KEY`` / ``config --show [--config FILE] [--set ...]``: what a configuration
  key is (description, type, default, unit, range; a section's fields; a renamed key's new
  name), or the effective configuration as YAML (:mod:`launcher.config_cmd`).  Exit 2 for an
  unknown key (the closest keys are named) or a bad configuration.
- ``view [RUN.mcap] [--connect ENDPOINT] [--listen [HOST:]PORT] [--foxglove PORT]``: a read-only web
  page of a running deployment (or of a finished run, with a time slider), optionally the same
  streams for the Foxglove app (:mod:`services.viewer`).  Exit 2 when no hub answers at the
  address, the recording holds no map, or the address cannot be served.
- ``sim``, ``transform``, ``import``, ``export``, ``vpr``, ``deadreckon``, ``eval``, ``audit``, ``compare``, ``report``,
  ``path``: see their own ``--help``.

``--json`` output of ``run`` and ``demo``: ``{"output", "mode", "wall_s", "services":
{name: {...per-service counters...}}, "recording": {"counts": {key: n}, "duration_s"},
"restarts": {name: number of supervised restarts},
"evaluation": {"front_end": {...}, "dead_reckoning": {...}, "back_end": {...}},
"inputs": {name: {"received": {key: n}, "missing": [key], "hint": str}}, "places": {...}, "log": path}``
(``demo`` adds ``"mission"``: the simulated input file; the evaluation keys are documented in
:mod:`eval.summary`, present when the run has LVC ids / ground truth / a map; ``inputs``: per
algorithm service the messages it received on each input key, the inputs that got nothing and,
then, a one-line ``hint`` naming the recording's unread keys and the ``poseidon import --topic
TOPIC=KEY`` mapping (and setting) that feeds them to it (:mod:`launcher.inputs`; also printed at
the end of the run); ``places`` (with ``local_view_cells``, else null): ``{"frames", "places",
"revisits": [[frame, first frame of its place, LVC id]], "names": frame file names}``
(:mod:`launcher.places`); ``log``: the run's log file).  Among an algorithm service's counters
(:class:`common.runtime.RunnerStats`): ``cpu_s`` and ``peak_rss_mb`` (its process, every
thread; distributed runs), ``startup_cpu_s``, ``node_cpu_s`` and ``frame_path_cpu_s`` (where
that CPU went: :mod:`common.runtime`), ``busy_s`` (wall seconds inside the node and publishing).
The player's: ``published`` (data frames per key) and ``samples`` (the bus samples that carried
them: fewer when a replay at full speed bundles them, ``player.bundle_frames``).

Console and log (:mod:`launcher.logs`): the console shows warnings, errors, progress bars and
results; ``--verbose`` adds the services' INFO messages, ``--log-level LEVEL`` sets its level
outright.  ``run`` writes every service's full log to ``RUN.log`` beside ``RUN.mcap``, ``demo``
to ``OUT/demo.log``; the last line of their output names it.

This module parses the command line and delegates; the built-in commands are
:mod:`launcher.run_cmd` (``run``; its summary: :mod:`launcher.run_report`), :mod:`launcher.demo`,
:mod:`launcher.service_cmd` (``service``, ``bridge``), :mod:`launcher.hub_cmd`, :mod:`launcher.info`
and :mod:`launcher.config_cmd`.
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
import logging
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from launcher.config_cmd import add_arguments as config_arguments
from launcher.config_cmd import cmd_config
from launcher.hub_cmd import cmd_hub
from launcher.info import cmd_info
from launcher.run_cmd import cmd_run
from launcher.service_cmd import cmd_bridge, cmd_service

__all__ = ["main"]

#: subcommands implemented by other parts of the tree: name -> "module:function(argv) -> int"
DELEGATED = {
    "sim": "missions.sim.cli:main",
    "transform": "missions.transform:main",
    "import": "missions.importers.cli:main",
    "vpr": "eval.cli.vpr:main",
    "deadreckon": "eval.deadreckon:main",
    "eval": "eval.cli.run_eval:main",
    "audit": "eval.audit:main",
    "compare": "eval.compare:main",
    "report": "eval.report.cli:main",
    "path": "services.expmap.path:main",
    "export": "products.cli:main",
    "certs": "launcher.certs:main",
    "acl": "launcher.acl:main",
}


def _log_file_of(args: argparse.Namespace) -> tuple[Path | None, bool]:
    """The log file of a command (:mod:`launcher.logs`) and whether it is appended to: ``run``
    beside its output, ``demo`` in its folder, a service process wherever its launcher logs."""
    if args.command == "run":
        return Path(args.out).with_suffix(".log"), False
    if args.command == "demo":
        return Path(args.out) / "demo.log", False
    if args.command == "service" and args.log_file:
        return Path(args.log_file), True
    return None, False


def _setup_logging(args: argparse.Namespace) -> None:
    from launcher import logs
    file, append = _log_file_of(args)
    name = args.name if args.command == "service" else args.command
    try:
        level = logs.console_level_of(getattr(args, "log_level", None), getattr(args, "verbose", False))
    except ValueError as exc:
        print(f"poseidon {args.command}: --log-level: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    logs.setup(level, file, service=name, append=append)


def _add_log_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--verbose", "-v", action="store_true",
                   help="also the services' INFO messages on the console (they are always in the log file)")
    p.add_argument("--log-level", default=None, help="the console's logging level outright (DEBUG, INFO, WARNING; "
                   "default WARNING, INFO with --verbose)")


def _add_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="YAML configuration (defaults: deploy/poseidon.yaml values)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one field, e.g. --set vpr_guard.vpr_window=30 (repeatable)")
    _add_log_args(p)


def _add_secure_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tls-dir", help="secured profile: folder written by 'poseidon certs' (ca.pem, HOST.pem, ...)")
    p.add_argument("--tls-host", help="secured profile: this computer's name in --tls-dir (HOST.pem/HOST.key)")
    p.add_argument("--zenoh-user", help="secured profile: user name (the service's name)")
    p.add_argument("--zenoh-password-file", help="secured profile: file holding the user's password")


def _delegate(name: str) -> Callable[[list[str]], int]:
    module, func = DELEGATED[name].split(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and module.startswith(exc.name):
            raise SystemExit(f"poseidon {name}: not available in this build ({module} missing)") from None
        raise
    command: Callable[[list[str]], int] = getattr(mod, func)
    return command


def _add_run_command(sub: Any) -> None:
    """``poseidon run``: replay a recording (or a live source) through the services."""
    p = sub.add_parser("run", help="replay a recording through the services and record the run")
    p.add_argument("--input", help="input recording (MCAP); or --live")
    p.add_argument("--live", choices=["ros1", "mcap"], help="a live source: ros1 = the ROS 1 bridge on "
                   "ROS_MASTER_URI; mcap = --input played by the wall clock at --rate (default 1) like live "
                   "sensors (launcher/live.py); ends on Ctrl-C/SIGTERM, --duration or (mcap) the input's end")
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
    p.add_argument("--view", metavar="[HOST:]PORT", help="serve the live view of the run on this address "
                   "(poseidon view beside the run; loopback when no HOST)")
    p.add_argument("--foxglove", type=int, metavar="PORT", help="serve the run's streams to the Foxglove app "
                   "(WebSocket) on this port")
    _add_config_args(p)
    p.set_defaults(func=cmd_run)


def _add_demo_command(sub: Any) -> None:
    """``poseidon demo``: the main job on a fresh machine (:mod:`launcher.demo`)."""
    p = sub.add_parser("demo", help="simulate and transform a cave mission, run it with the VPR Guard ON and OFF, "
                       "write the report")
    from launcher.demo import add_arguments as demo_arguments
    from launcher.demo import cmd_demo
    demo_arguments(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_demo)


def _add_service_command(sub: Any) -> None:
    """``poseidon service NAME``: one service connected to a hub/router."""
    p = sub.add_parser("service", help="run one service connected to a hub/router")
    p.add_argument("name", help="player, recorder, bridge_ros1 (live ROS 1 source), live_player (a recording "
                   "played live), encoder, htm, robot_state, posecells, "
                   "expmap, ratslam_lv (RatSLAM front-end)")
    p.add_argument("--connect", help="Zenoh endpoint of the hub/router, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--mode", default="client", choices=["client", "peer"], help="Zenoh session mode")
    p.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file (deploy/*.json5)")
    p.add_argument("--namespace", help="vehicle namespace (default from configuration)")
    p.add_argument("--stats", help="write the service's final counters here (JSON) instead of stdout")
    p.add_argument("--input", help="player, live_player: recording to publish")
    p.add_argument("--rate", type=float, help="player, live_player: replay speed")
    p.add_argument("--keys", help="player, live_player: comma-separated keys to publish")
    p.add_argument("--wait-for", help="player: comma-separated services to wait for")
    p.add_argument("--announce", help="bridge_ros1: comma-separated source keys kept alive while silent")
    p.add_argument("--read", help="bridge_ros1: comma-separated keys the run's services read; only their topics, "
                   "bridge_ros1.keep_keys and the grid's returns are bridged (unless bridge_ros1.bridge_unread)")
    p.add_argument("--live", action="store_true", help="a service of a live run: bounded input queue (live.*)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--out", help="recorder: output MCAP")
    p.add_argument("--expect", help="recorder: keys whose end-of-stream ends the recording")
    p.add_argument("--metadata", help="recorder: JSON file with the run's metadata record")
    p.add_argument("--copy-from", help="recorder: input recording whose --copy-keys it copies into its output "
                   "(player.replay copied)")
    p.add_argument("--input-digest", metavar="FILE", help="recorder: file where the launcher writes the input's "
                   "SHA-256; the recorder writes it into the metadata record's input_sha256 at the end")
    p.add_argument("--copy-keys", help="recorder: comma-separated keys of --copy-from to copy")
    p.add_argument("--supervise", metavar="FILE", help="supervised run: checkpoints, replays (written by the "
                   "launcher, see common/resume.py)")
    p.add_argument("--resume", action="store_true", help="with --supervise: this is a restart, resume from the "
                   "last checkpoint")
    p.add_argument("--log-file", help="also log to this file from DEBUG, appending (a run's log: the launcher "
                   "passes its own)")
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
    p.add_argument("--read", help="comma-separated keys the services on the bus read: only their topics, "
                   "bridge_ros1.keep_keys and the grid's returns are bridged (unless bridge_ros1.bridge_unread; "
                   "default: every topic)")
    p.add_argument("--json", action="store_true", help="print the counters indented")
    _add_config_args(p)
    p.set_defaults(func=cmd_bridge)


def _add_hub_command(sub: Any) -> None:
    """``poseidon hub``: a hub (Zenoh router)."""
    p = sub.add_parser("hub", help="run a hub (Zenoh router) for services on several hosts")
    p.add_argument("--listen", default="tcp/127.0.0.1:7447", help="endpoint to listen on")
    p.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file (deploy/zenoh/*.json5)")
    _add_log_args(p)
    _add_secure_args(p)
    p.set_defaults(func=cmd_hub)


def _add_info_command(sub: Any) -> None:
    """``poseidon info``: the summary of a recording."""
    p = sub.add_parser("info", help="summarise a recording (exit 1 if damaged, 2 if unreadable)")
    p.add_argument("recording")
    p.add_argument("--json", action="store_true")
    p.add_argument("--recover", metavar="FIXED.mcap",
                   help="write every intact message of a damaged recording (e.g. a killed recorder's) to a complete file")
    p.add_argument("--digests", action="store_true",
                   help="also the sha256 of each key's stream (stamps, sequence numbers, payloads): two runs with "
                        "equal digests on a key published the same bytes on it")
    _add_log_args(p)
    p.set_defaults(func=cmd_info)


def _add_config_command(sub: Any) -> None:
    """``poseidon config``: explain a key, or show the effective configuration (:mod:`launcher.config_cmd`)."""
    p = sub.add_parser("config", help="explain a configuration key (--explain KEY) or print the effective "
                       "configuration (--show)")
    config_arguments(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_config)


def _add_view_command(sub: Any) -> None:
    """``poseidon view``: the live page over a deployment or a finished run (:mod:`services.viewer`)."""
    p = sub.add_parser("view", help="serve a live web view of a running deployment, or of a finished run's "
                       "recording with a time slider")
    p.add_argument("recording", nargs="?", help="a run's recording (MCAP) to view instead of a live deployment")
    p.add_argument("--connect", help="Zenoh endpoint of the deployment's hub (default: bus.connect)")
    p.add_argument("--listen", help="[HOST:]PORT of the page (default: view.listen, loopback)")
    p.add_argument("--foxglove", type=int, metavar="PORT", help="also serve the streams to the Foxglove app "
                   "(WebSocket) on this port, on the page's host")
    p.add_argument("--namespace", help="vehicle namespace (default from configuration)")
    p.add_argument("--io", metavar="FILE", help="each service's input and output keys, JSON {name: [[inputs], "
                   "[outputs]]} (poseidon run --view writes it; default: read from the services' configuration)")
    p.add_argument("--ready-file", metavar="FILE", help="write the page's address into FILE once the view is "
                   "subscribed and serves the page (poseidon run --view waits for it)")
    p.add_argument("--final-recording", metavar="FILE", help="on SIGUSR1, show the final state of the finished "
                   "run's recording FILE instead of the live one (poseidon run --view sends it once the run's "
                   "recording is complete: what the view dropped while the run went on is then shown too)")
    _add_secure_args(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_view)


def cmd_view(args: argparse.Namespace) -> int:
    """``poseidon view``: serve until SIGINT/SIGTERM; exit 2 naming a bad input (no hub at the
    address, a recording without a map, a bad configuration)."""
    import signal
    import threading

    from common.config import ConfigError
    from services.viewer.app import ViewError, lower_niceness, read_io, ready_file, serve_live, serve_recording
    from system.config import load_config
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    final = None
    if args.final_recording is not None:
        final_asked = threading.Event()
        final = (final_asked, Path(args.final_recording))
        signal.signal(signal.SIGUSR1, lambda *_: final_asked.set())
    try:
        config = load_config(args.config, args.set)
        if args.recording is not None:
            if args.connect or args.foxglove is not None or args.io is not None or final is not None:
                raise ValueError("a recording is viewed on its own: --connect, --foxglove, --io and "
                                 "--final-recording are for a live deployment")
            serve_recording(args.recording, config.view, stop, args.listen,
                            ready=ready_file(args.ready_file) if args.ready_file else None)
            return 0
        lower_niceness(config.view.nice)  # before the imports of the services' keys, too
        if args.io is not None:
            io = read_io(args.io)
        else:
            from system.services import available_services, node_io
            io = {n: node_io(n, config) for n in config.services or available_services(config)}
        serve_live(config.view, args.namespace or config.bus.namespace, args.connect or config.bus.connect[0], stop,
                   io, args.listen, args.foxglove, ready=ready_file(args.ready_file) if args.ready_file else None,
                   final=final,
                   tls_dir=args.tls_dir, tls_host=args.tls_host, user=args.zenoh_user,
                   password_file=args.zenoh_password_file)
    except (ConfigError, ViewError, ValueError, KeyError, FileNotFoundError) as exc:
        print(f"poseidon view: {exc}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="poseidon", description="PoseidonSLAM: underwater SLAM services")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_run_command(sub)
    _add_demo_command(sub)
    _add_service_command(sub)
    _add_bridge_command(sub)
    _add_hub_command(sub)
    _add_info_command(sub)
    _add_config_command(sub)
    _add_view_command(sub)

    for name in DELEGATED:
        sub.add_parser(name, help=f"see 'poseidon {name} --help'", add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in DELEGATED:
        from launcher import logs
        logs.setup(logs.console_level_of(None, False), service=argv[0])
        return int(_delegate(argv[0])(argv[1:]) or 0)
    args = build_parser().parse_args(argv)
    _setup_logging(args)
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
    """The ``poseidon`` console script (and ``python -m launcher.cli``): a child of a launcher binds
    itself to it (:func:`launcher.children.adopt_launcher`, before any thread starts), ``SIGUSR1``
    prints every thread's stack, then :func:`main`, then leave without interpreter finalisation.

    Zenoh's Rust threads call into Python.  If the interpreter finalises while one of them
    waits for the GIL, CPython ends that thread with ``pthread_exit``; its forced unwind meets
    the Rust FFI boundary, which aborts the process ("FATAL: exception not rethrown", SIGABRT,
    exit -6) after a run that succeeded -- seen about once in a few hundred runs under load.
    Every command has closed its sessions, recordings and files when :func:`main` returns, so
    the process flushes logging and stdio and ends with ``os._exit`` (no finalisation, no abort).
    """
    import faulthandler
    import signal

    from launcher.children import adopt_launcher
    adopt_launcher(" ".join(sys.argv[1:3]) if sys.argv[1:2] == ["service"] else " ".join(sys.argv[1:2]))
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # `kill -USR1 PID`: every thread's stack
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
