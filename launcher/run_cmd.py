"""``poseidon run``: the command line of a replay (:mod:`launcher.run`) or a live run
(:mod:`launcher.live`), and the printing of its summary (:mod:`launcher.run_report`).

``--view [HOST:]PORT`` / ``--foxglove PORT``: ``poseidon view`` (:mod:`services.viewer`) runs as
one more process on the run's hub, read-only, and serves the page while the run lasts (and
``view.linger_s`` after); the run's services start once it is ready, and it is otherwise no part
of the run (:mod:`launcher.view_beside`).

Exit codes: 0 on success, 2 on bad configuration/input, 3 when a service failed (its name and
the partial recording are printed).  The flags are documented in :mod:`launcher.cli`.
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from launcher.run import RunFailed
    from system.config import PoseidonConfig

__all__ = ["cmd_run", "print_run", "services_arg", "flags_error"]


def print_run(result: Mapping[str, Any], as_json: bool, config: PoseidonConfig | None) -> None:
    """Print the result of ``run`` with its evaluation, places and log
    (:func:`launcher.run_report.complete_run`): the ``--json`` document (the hints of services
    that received nothing also on stderr), or the readable summary."""
    from launcher.run_report import complete_run, format_run, input_hints
    report = complete_run(result, config)
    if as_json:
        print(json.dumps(report, indent=2))
        for hint in input_hints(report):  # what the user must act on, also with --json
            print(f"poseidon run: {hint}", file=sys.stderr)
        return
    for line in format_run(report):
        print(line)


def services_arg(args: argparse.Namespace) -> list[str] | None:
    """``--services a,b`` as a list (``none`` or empty: no services); None when not given (all)."""
    return [s for s in args.services.split(",") if s and s != "none"] if args.services is not None else None


def flags_error(args: argparse.Namespace) -> str | None:
    """Why the flags of ``poseidon run`` do not go together; None when they do."""
    if (args.live in (None, "mcap")) != (args.input is not None):
        return "give --input REC.mcap (a replay, or with --live mcap) or --live ros1"
    if args.live is not None and (args.embedded or (args.rate is not None and args.live != "mcap")):
        return f"--embedded{'' if args.live == 'mcap' else ' and --rate'} do not apply to --live {args.live}"
    if args.embedded and (args.view is not None or args.foxglove is not None):
        return "--view and --foxglove watch the run's hub; an --embedded run has none"
    return None


def _report_run_failed(args: argparse.Namespace, exc: RunFailed) -> int:
    """Exit 3 naming the failed service and where the partial recording is."""
    from launcher.logs import log_file
    print(f"poseidon run: {exc}; what was recorded so far is in {exc.partial} ({args.out} left as it was); "
          f"the log: {log_file()}", file=sys.stderr)
    return 3


def stop_on_signals(what: str) -> threading.Event:
    """An event set by the first SIGTERM/SIGINT; a second one (more than a second later) exits
    at once with exit code 4, and a stop still running 75 s after the first prints every thread's
    stack (:class:`launcher.service_cmd._Signals`, as every service does).  Called off the main
    thread (an in-process caller), where signals cannot be taken: an event nothing sets."""
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        from launcher.service_cmd import _Signals
        _Signals(what).on_stop(stop.set)
    return stop


def _run_live(args: argparse.Namespace) -> int:
    """``run --live SOURCE``: stop on SIGINT/SIGTERM or ``--duration`` (:mod:`launcher.live`)."""
    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.live import run_live
    from launcher.run import RunFailed
    from launcher.view_beside import ViewStartError, view_beside
    from system.config import load_config
    stop = stop_on_signals("poseidon run")
    try:
        config = load_config(args.config, args.set)
        services = services_arg(args)
        with view_beside(args, config, config.live.startup_timeout_s, stop) as (hub_port, view_ready):
            result = run_live(config, args.live, args.out, services=services, duration_s=args.duration, stop=stop,
                              input_path=args.input if args.live == "mcap" else None,
                              rate=1.0 if args.rate is None else args.rate, hub_port=hub_port,
                              before_services=view_ready)
    except (ConfigError, RecordingError, ValueError, KeyError, TimeoutError, FileNotFoundError,
            ViewStartError) as exc:
        print(f"poseidon run: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        return _report_run_failed(args, exc)
    print_run(result.as_dict(), args.json, config)
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """``poseidon run``: a replay (embedded or distributed) or, with ``--live``, a live run."""
    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.run import RunFailed, run_distributed, run_embedded
    from launcher.view_beside import ViewStartError, view_beside
    from system.config import load_config
    error = flags_error(args)
    if error is not None:
        print(f"poseidon run: {error}", file=sys.stderr)
        return 2
    if args.live is not None:
        return _run_live(args)
    try:
        config = load_config(args.config, args.set)
        if args.rate is not None:
            config.player.rate = args.rate
        if args.map_dir:
            from launcher.map_dir import use_map_dir
            use_map_dir(config, args.map_dir)
        services = services_arg(args)
        with view_beside(args, config, config.bus.startup_timeout_s) as (hub_port, view_ready):
            if args.embedded:  # no hub: flags_error refuses --view with --embedded
                result = run_embedded(config, args.input, args.out, services=services, timeout_s=args.timeout,
                                      progress=not args.json)
            else:
                result = run_distributed(config, args.input, args.out, services=services, timeout_s=args.timeout,
                                         progress=not args.json, hub_port=hub_port, before_services=view_ready)
    except (ConfigError, RecordingError, ValueError, KeyError, FileNotFoundError, ViewStartError) as exc:
        print(f"poseidon run: {exc}", file=sys.stderr)
        return 2
    except RunFailed as exc:
        return _report_run_failed(args, exc)
    print_run(result.as_dict(), args.json, config)
    return 0
