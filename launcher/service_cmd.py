"""``poseidon service NAME`` and ``poseidon bridge ros1``: one worker in its own process on a hub.

The process joins the bus (:func:`join_bus`, waiting at most ``bus.startup_timeout_s`` for the
hub), runs its worker (:func:`run_worker`) until its inputs end, a signal (:class:`_Signals`) or
``--duration``, and prints the worker's counters as JSON.  ``service`` exit codes: 0 when its
inputs ended (or a signal came before the hub was reached), 1 when the service failed, 2 on bad
configuration or an unreachable hub, :data:`EXIT_ABORTED` when the run was aborted because another
service died.  ``bridge``: 0, or 2 when rospy, the ROS master or the hub is unavailable.
"""
from __future__ import annotations

import argparse
import json
import logging
import resource
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

if TYPE_CHECKING:
    from common.bus import Bus
    from common.resume import Supervision
    from common.worker import Worker
    from system.config import PoseidonConfig
    from system.services import WorkerSpec

__all__ = ["EXIT_ABORTED", "ProcessUsage", "join_bus", "zenoh_error", "secure_args", "worker_spec",
           "run_worker", "process_usage", "cmd_service", "cmd_bridge"]

log = logging.getLogger("poseidon")

#: exit code of ``poseidon service`` stopped by an abort of the run (another service failed)
EXIT_ABORTED = 4


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
        self.what = what
        self.stopped = threading.Event()
        self.signum = 0
        self._first_at = 0.0
        self._callbacks: list[Callable[[], Any]] = []
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

    def on_stop(self, callback: Callable[[], Any]) -> None:
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


def join_bus(what: str, signals: _Signals, timeout_s: float, namespace: str, connect: list[str],
             **kwargs: Any) -> Bus | None:
    """Open the process's :class:`common.bus.Bus` (a client session waits for its hub) in a
    helper thread: None, with the reason on stderr, when the hub was not reached within
    ``timeout_s`` (``bus.startup_timeout_s``) or a signal came first.  Errors opening it are raised."""
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
    bus: Bus = box["bus"]
    return bus


def zenoh_error() -> type[Exception]:
    """Zenoh's error type (imported when needed: ``poseidon`` starts without Zenoh)."""
    import zenoh
    return zenoh.ZError


def secure_args(args: argparse.Namespace) -> dict[str, str | None]:
    """The secured profile's flags (``--tls-dir``, ...) as :class:`common.bus.Bus` keywords."""
    return {"tls_dir": args.tls_dir, "tls_host": args.tls_host, "user": args.zenoh_user,
            "password_file": args.zenoh_password_file}


def worker_spec(args: argparse.Namespace, config: PoseidonConfig, supervision: Supervision | None) -> WorkerSpec:
    """What ``poseidon service NAME``'s flags say about the worker (the recorder's
    ``--metadata`` file is read here)."""
    from system.services import RECORDER, WorkerSpec
    spec = WorkerSpec(supervision=supervision, drain=True, input=args.input, rate=args.rate,
                      keys=args.keys.split(",") if args.keys else None,
                      announce=[k for k in (args.announce or "").split(",") if k], live=args.live,
                      read=_key_list(args.read),
                      wait_for=[w for w in (args.wait_for or "").split(",") if w], progress=not args.no_progress,
                      out=args.out, expect=None if args.expect is None else [k for k in args.expect.split(",") if k],
                      copy_from=args.copy_from, copy_keys=[k for k in (args.copy_keys or "").split(",") if k],
                      input_digest=_digest_reader(args.input_digest))
    if args.name == RECORDER:
        spec.metadata = json.loads(Path(args.metadata).read_text()) if args.metadata else {
            "tool": "poseidon service recorder", "config": config.model_dump(mode="json")}
    return spec


def _key_list(value: str | None) -> list[str] | None:
    """A comma-separated key list flag: None when not given (``--read ''`` is the empty list)."""
    return None if value is None else [k for k in value.split(",") if k]


def _digest_reader(path: str | None) -> Callable[[], str] | None:
    """``--input-digest FILE``: the recorder reads the launcher's digest of the input there."""
    if path is None:
        return None
    from common.mcap_io import digest_from_file
    return lambda: digest_from_file(path)


def run_worker(worker: Worker, signals: _Signals, duration_s: float | None = None) -> dict[str, Any]:
    """Run ``worker`` to its end, stopping it at the first signal or after ``duration_s``:
    its counters (:meth:`common.worker.WorkerStats.as_dict`)."""
    signals.on_stop(worker.stop)
    timer = threading.Timer(duration_s, worker.stop) if duration_s else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    try:
        stats: dict[str, Any] = worker.run().as_dict()
    finally:
        if timer is not None:
            timer.cancel()
    return stats


class ProcessUsage(TypedDict):
    """The process's CPU seconds (user + system, every thread: Zenoh's included) and peak
    resident memory (MB): the per-service cost of a distributed run."""

    cpu_s: float
    peak_rss_mb: float


def process_usage() -> ProcessUsage:
    """This process's :class:`ProcessUsage` so far."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return {"cpu_s": round(usage.ru_utime + usage.ru_stime, 3),
            "peak_rss_mb": round(usage.ru_maxrss / 1024.0, 1)}   # Linux: KiB


def _service_checks(args: argparse.Namespace) -> str | None:
    """What a player or a recorder lacks among its flags; None when nothing."""
    from system.services import PLAYER, RECORDER
    if args.name == PLAYER and not args.input:
        return "--input REC.mcap is required"
    if args.name == RECORDER and not args.out:
        return "--out RUN.mcap is required"
    return None


def cmd_service(args: argparse.Namespace) -> int:
    """``poseidon service NAME``: the worker's counters on stdout (or ``--stats FILE``); the exit
    codes are in the module docstring."""
    from common.config import ConfigError
    from system.config import load_config
    from system.services import build_worker
    try:
        config = load_config(args.config, args.set)
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
    lacking = _service_checks(args)
    if lacking is not None:
        print(f"poseidon service {args.name}: {lacking}", file=sys.stderr)
        return 2
    what = f"poseidon service {args.name}"
    signals = _Signals(what)
    try:
        bus = join_bus(what, signals, config.bus.startup_timeout_s, namespace, connect, mode=args.mode,
                       config_file=args.zenoh_config, **secure_args(args))
    except (OSError, ValueError, zenoh_error()) as exc:
        print(f"{what}: cannot join the bus: {exc}", file=sys.stderr)
        return 2
    if bus is None:
        return 0 if signals.stopped.is_set() else 2
    try:
        stats = run_worker(build_worker(args.name, config, bus, worker_spec(args, config, supervision)), signals)
    except Exception:  # the service's own failure: logged with its traceback, exit 1
        log.exception("service %s failed", args.name)
        return 1
    finally:
        bus.close()
    stats.update(process_usage())
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
    from common.config import ConfigError
    from services.bridge_ros1.ros_io import RosUnavailable
    from system.config import load_config
    from system.services import BRIDGE_ROS1, WorkerSpec, build_worker
    try:
        config = load_config(args.config, args.set)
    except ConfigError as exc:
        print(f"poseidon bridge {args.kind}: {exc}", file=sys.stderr)
        return 2
    connect = [args.connect] if args.connect else config.bus.connect
    what = f"poseidon bridge {args.kind}"
    signals = _Signals(what)
    bus = join_bus(what, signals, config.bus.startup_timeout_s, args.namespace or config.bus.namespace, connect)
    if bus is None:
        return 0 if signals.stopped.is_set() else 2
    spec = WorkerSpec(announce=[k for k in (args.announce or "").split(",") if k], drain=False,
                      read=_key_list(args.read))
    worker = build_worker(BRIDGE_ROS1, config, bus, spec)
    try:
        stats = run_worker(worker, signals, args.duration)
    except RosUnavailable as exc:
        print(f"poseidon bridge {args.kind}: {exc}", file=sys.stderr)
        return 2
    finally:
        bus.close()
    print(json.dumps(stats, indent=2 if args.json else None))
    return 0
