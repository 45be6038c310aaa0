"""The built-in subcommands of ``poseidon`` (``run``, ``demo``, ``info``, ``service``,
``bridge``, ``hub``): what each does with its parsed arguments, and its exit code.

The commands, their flags and their exit codes are documented in :mod:`launcher.cli`, which
parses the command line and calls them.  Everything heavy (numpy, Zenoh, the services) is
imported inside the command that needs it: ``poseidon`` starts fast, and :mod:`launcher.cli`
sets the BLAS thread counts before numpy is first imported.
"""
from __future__ import annotations

import argparse
import json
import logging
import resource
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from common.resume import Supervision
    from launcher.run import RunFailed
    from system.config import PoseidonConfig
    from system.services import WorkerSpec

__all__ = ["cmd_run", "cmd_demo", "cmd_info", "cmd_service", "cmd_bridge", "cmd_hub", "print_run", "EXIT_ABORTED"]

log = logging.getLogger("poseidon")

#: exit code of ``poseidon service`` stopped by an abort of the run (another service failed)
EXIT_ABORTED = 4


def _load_config(args: argparse.Namespace) -> Any:
    from system.config import load_config
    return load_config(args.config, args.set)


def print_run(result: dict[str, Any], as_json: bool, config: Any) -> None:
    """Print the result of ``run``/``demo`` with its ``evaluation`` (:mod:`eval.summary`) added:
    the ``--json`` document (:mod:`launcher.cli`), or a readable summary."""
    from eval.summary import format_summary, summarize_run
    from launcher.inputs import format_inputs
    from launcher.logs import log_file
    from launcher.places import format_places, places_summary
    result["evaluation"] = summarize_run(result["output"], config)
    result["places"] = places_summary(result["output"])
    log_path = log_file()
    result["log"] = str(log_path) if log_path is not None else None
    if as_json:
        print(json.dumps(result, indent=2))
        for r in (result.get("inputs") or {}).values():  # what the user must act on, also with --json
            if r.get("hint"):
                print(f"poseidon run: {r['hint']}", file=sys.stderr)
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
        if "peak_rss_mb" in st:
            extra.append(f"peak memory {st['peak_rss_mb']:.0f} MB")
        if st.get("real_time_factor"):
            extra.append(f"{st['real_time_factor']:.1f}x real time")
        if st.get("dropped"):
            extra.append(f"dropped (queue full, oldest first) {st['dropped']}")
        if st.get("late"):
            extra.append(f"late {st['late']}")
        if st.get("behind_ms"):
            extra.append(f"published behind its schedule by p99 {st['behind_ms']['p99']:.1f} ms, "
                         f"max {st['behind_ms']['max']:.1f} ms" + ("" if st.get("complete") else " (stopped early)"))
        if st.get("outages"):
            extra.append(f"link outages {st['outages']}: delivered late {st.get('delivered_late') or {}}, "
                         f"sent again {st.get('resent') or {}}, dropped (outage buffer full) "
                         f"{st.get('dropped_outage') or {}}")
        if st.get("missing"):
            extra.append(f"missing (never arrived) {st['missing']}")
        if st.get("raw"):
            extra.append(f"carried raw {st['raw']}")
        print(f"  [{name}] " + "; ".join(extra) if extra else f"  [{name}] ok")
        for stage, lat in (st.get("latency") or {}).items():
            if lat.get("n"):
                print(f"    latency arrival -> {stage:<9} p50 {lat['p50_ms']:8.1f} ms  p95 {lat['p95_ms']:8.1f} ms  "
                      f"p99 {lat['p99_ms']:8.1f} ms  (n {lat['n']})")
    for line in format_inputs(result.get("inputs") or {}):
        print(line)
    for line in format_summary(result["evaluation"]):
        print(line)
    for line in format_places(result["places"]):
        print(line)
    if log_path is not None:
        print(f"log: {log_path}")


def _run_live(args: argparse.Namespace) -> int:
    """``run --live SOURCE``: stop on SIGINT/SIGTERM or ``--duration`` (:mod:`launcher.live`)."""
    import threading

    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.live import run_live
    from launcher.run import RunFailed
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        config = _load_config(args)
        services = _services_arg(args)
        result = run_live(config, args.live, args.out, services=services, duration_s=args.duration, stop=stop,
                          input_path=args.input if args.live == "mcap" else None,
                          rate=1.0 if args.rate is None else args.rate)
    except (ConfigError, RecordingError, ValueError, KeyError, TimeoutError, FileNotFoundError) as exc:
        print(f"poseidon run: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        return _report_run_failed(args, exc)
    print_run(result.as_dict(), args.json, config)
    return 0


def _services_arg(args: argparse.Namespace) -> list[str] | None:
    """``--services a,b`` as a list (``none`` or empty: no services); None when not given (all)."""
    return [s for s in args.services.split(",") if s and s != "none"] if args.services is not None else None


def _report_run_failed(args: argparse.Namespace, exc: RunFailed) -> int:
    """Exit 3 naming the failed service and where the partial recording is."""
    from launcher.logs import log_file
    print(f"poseidon run: {exc}; what was recorded so far is in {exc.partial} ({args.out} left as it was); "
          f"the log: {log_file()}", file=sys.stderr)
    return 3


def cmd_run(args: argparse.Namespace) -> int:
    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.run import RunFailed, run_distributed, run_embedded
    if (args.live in (None, "mcap")) != (args.input is not None):
        print("poseidon run: give --input REC.mcap (a replay, or with --live mcap) or --live ros1", file=sys.stderr)
        return 2
    if args.live is not None:
        if args.embedded or (args.rate is not None and args.live != "mcap"):
            print(f"poseidon run: --embedded{'' if args.live == 'mcap' else ' and --rate'} do not apply to "
                  f"--live {args.live}", file=sys.stderr)
            return 2
        return _run_live(args)
    try:
        config = _load_config(args)
        if args.rate is not None:
            config.player.rate = args.rate
        if args.map_dir:
            from launcher.run import use_map_dir
            use_map_dir(config, args.map_dir)
        services = _services_arg(args)
        runner = run_embedded if args.embedded else run_distributed
        result = runner(config, args.input, args.out, services=services, timeout_s=args.timeout,
                        progress=not args.json)
    except (ConfigError, RecordingError, ValueError, KeyError, FileNotFoundError) as exc:
        print(f"poseidon run: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        return _report_run_failed(args, exc)
    print_run(result.as_dict(), args.json, config)
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
        key_digests,
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
        if getattr(args, "digests", False):
            summary["digests"] = key_digests(args.recording)
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
        for k, d in summary.get("digests", {}).items():
            print(f"  sha256 {k:<24} {d['sha256']}")
    if recovered is not None:
        print(f"poseidon info: {recovered} messages written to {args.recover} (a complete recording)", file=sys.stderr)
        return 0
    if not status["complete"]:
        print(f"poseidon info: damaged or unfinished recording: {status['error']}; the messages listed are intact; "
              f"'poseidon info {args.recording} --recover FIXED.mcap' writes them to a complete file",
              file=sys.stderr)
        return 1
    return 0


class _Signals:
    """SIGTERM/SIGINT for a service process: the first stops what is registered (:meth:`on_stop`;
    the worker ends its streams and leaves); a second one exits at once, exit code
    ``EXIT_ABORTED``, after flushing stdout/stderr (a process stuck on an unreachable hub does
    not need SIGKILL); a repeat within ``DUPLICATE_S`` of the first is ignored.

    The signals are acted on by a watcher thread, not by a Python handler in the main thread: the
    C-level handler writes each signal's number to a pipe (:func:`signal.set_wakeup_fd`) the watcher
    reads, so a main thread held in native code (a Zenoh call on a hub that went away) cannot keep
    a stop from being seen or the second signal from exiting.  ``SIGUSR1`` prints every thread's
    Python stack to stderr (:mod:`faulthandler`); a process still running ``OVERRUN_S`` after
    its first stop signal does so by itself, once, and keeps going."""

    #: a repeat within this many seconds of the first signal is the same event delivered twice:
    #: the kernel sends the parent-death signal (launcher/run.py) again each time the orphan is
    #: re-parented, so a launcher killed by SIGKILL can deliver two SIGTERMs at once, and the
    #: recorder must still close its file
    DUPLICATE_S = 1.0
    #: seconds after the first stop signal after which the thread stacks are printed (diagnosis
    #: of a stop that hangs: the longest legitimate one, a bridge forwarding the services' last
    #: outputs, is bounded by 60 s)
    OVERRUN_S = 75.0

    def __init__(self, what: str):
        import faulthandler
        import os
        import threading
        self.what = what
        self.stopped = threading.Event()
        self.signum = 0
        self._first_at = 0.0
        self._callbacks: list[Any] = []
        faulthandler.register(signal.SIGUSR1, all_threads=True)
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, self._noop)  # a Python handler must exist for the wakeup fd to be written
        threading.Thread(target=self._watch, args=(read_fd,), name="signals", daemon=True).start()

    @staticmethod
    def _noop(_signum: int, _frame: Any) -> None:
        """The signal is handled by :meth:`_watch`."""

    def _watch(self, read_fd: int) -> None:
        import os
        while True:
            for signum in os.read(read_fd, 64):
                if signum in (signal.SIGTERM, signal.SIGINT):
                    self._on_signal(signum)

    def on_stop(self, callback: Any) -> None:
        self._callbacks.append(callback)
        if self.stopped.is_set():
            callback()

    def _on_signal(self, signum: int) -> None:
        if self.stopped.is_set() and time.monotonic() - self._first_at < self.DUPLICATE_S:
            log.debug("%s: signal %d again within %.1f s: the same stop", self.what, signum, self.DUPLICATE_S)
            return
        if self.stopped.is_set():
            print(f"{self.what}: second signal {signum}: exiting now", file=sys.stderr)
            sys.stdout.flush()
            sys.stderr.flush()
            import os
            os._exit(EXIT_ABORTED)
        import faulthandler
        print(f"{self.what}: signal {signum}, stopping (a second signal exits at once)", file=sys.stderr, flush=True)
        self._first_at = time.monotonic()
        self.signum = signum
        self.stopped.set()
        faulthandler.dump_traceback_later(self.OVERRUN_S, exit=False)
        for cb in self._callbacks:
            cb()


def _join_bus(what: str, signals: _Signals, timeout_s: float, namespace: str, connect: list[str],
              **kwargs: Any) -> Any:
    """Open the process's :class:`common.bus.Bus` (a client session waits for its hub) in a
    helper thread: None, with the reason on stderr, when the hub was not reached within
    ``timeout_s`` (``bus.startup_timeout_s``) or a signal came first.  Errors opening it are raised."""
    import threading

    from common.bus import Bus
    box: dict[str, Any] = {}

    def opener() -> None:
        try:
            box["bus"] = Bus(namespace, connect=connect, **kwargs)
        except BaseException as exc:  # handed to the main thread
            box["error"] = exc
        finally:
            done.set()

    done = threading.Event()
    threading.Thread(target=opener, name="join-bus", daemon=True).start()
    deadline = time.monotonic() + timeout_s
    said = False
    while not done.wait(0.1):
        if not said and time.monotonic() > deadline - timeout_s + 1.0:
            said = True
            print(f"{what}: waiting for the hub {connect} (at most {timeout_s:.0f} s)", file=sys.stderr, flush=True)
        if signals.stopped.is_set():
            print(f"{what}: stopped by signal {signals.signum} before reaching the hub {connect}", file=sys.stderr)
            return None
        if time.monotonic() > deadline:
            print(f"{what}: hub {connect} not reached within {timeout_s:.0f} s (bus.startup_timeout_s); "
                  "giving up", file=sys.stderr)
            return None
    if "error" in box:
        raise box["error"]
    return box["bus"]


def zenoh_error() -> type[Exception]:
    import zenoh
    return zenoh.ZError  # type: ignore[no-any-return]


def _worker_spec(args: argparse.Namespace, config: PoseidonConfig, supervision: Supervision | None) -> WorkerSpec:
    """What ``poseidon service NAME``'s flags say about the worker (the recorder's
    ``--metadata`` file is read here)."""
    from system.services import RECORDER, WorkerSpec
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
    from common.config import ConfigError
    from system.services import PLAYER, RECORDER, build_worker
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
    what = f"poseidon service {args.name}"
    signals = _Signals(what)
    try:
        bus = _join_bus(what, signals, config.bus.startup_timeout_s, namespace, connect, mode=args.mode,
                        config_file=args.zenoh_config, **_secure_args(args))
    except (OSError, ValueError, zenoh_error()) as exc:
        print(f"{what}: cannot join the bus: {exc}", file=sys.stderr)
        return 2
    if bus is None:
        return 0 if signals.stopped.is_set() else 2
    try:
        worker = build_worker(args.name, config, bus, _worker_spec(args, config, supervision))
        signals.on_stop(worker.stop)
        stats = worker.run().as_dict()
    except Exception:  # the service's own failure: logged with its traceback, exit 1
        log.exception("service %s failed", args.name)
        return 1
    finally:
        bus.close()
    # the process's CPU seconds (user + system, every thread: Zenoh's included), for the
    # per-service cost of a distributed run
    usage = resource.getrusage(resource.RUSAGE_SELF)
    stats["cpu_s"] = round(usage.ru_utime + usage.ru_stime, 3)
    stats["peak_rss_mb"] = round(usage.ru_maxrss / 1024.0, 1)   # Linux: KiB; the process's peak resident memory
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

    from common.config import ConfigError
    from services.bridge_ros1.ros_io import RosUnavailable
    from system.services import BRIDGE_ROS1, WorkerSpec, build_worker
    try:
        config = _load_config(args)
    except ConfigError as exc:
        print(f"poseidon bridge {args.kind}: {exc}", file=sys.stderr)
        return 2
    connect = [args.connect] if args.connect else config.bus.connect
    what = f"poseidon bridge {args.kind}"
    signals = _Signals(what)
    bus = _join_bus(what, signals, config.bus.startup_timeout_s, args.namespace or config.bus.namespace, connect)
    if bus is None:
        return 0 if signals.stopped.is_set() else 2
    spec = WorkerSpec(announce=[k for k in (args.announce or "").split(",") if k], drain=False)
    worker = build_worker(BRIDGE_ROS1, config, bus, spec)
    signals.on_stop(worker.stop)
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


def _secure_args(args: argparse.Namespace) -> dict[str, str | None]:
    return {"tls_dir": args.tls_dir, "tls_host": args.tls_host, "user": args.zenoh_user,
            "password_file": args.zenoh_password_file}
