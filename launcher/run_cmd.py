"""``poseidon run``: the command line of a replay (:mod:`launcher.run`) or a live run
(:mod:`launcher.live`), and the printing of its summary (:mod:`launcher.run_report`).

Exit codes: 0 on success, 2 on bad configuration/input, 3 when a service failed (its name and
the partial recording are printed).  The flags are documented in :mod:`launcher.cli`.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
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
    return None


def _report_run_failed(args: argparse.Namespace, exc: RunFailed) -> int:
    """Exit 3 naming the failed service and where the partial recording is."""
    from launcher.logs import log_file
    print(f"poseidon run: {exc}; what was recorded so far is in {exc.partial} ({args.out} left as it was); "
          f"the log: {log_file()}", file=sys.stderr)
    return 3


def _run_live(args: argparse.Namespace) -> int:
    """``run --live SOURCE``: stop on SIGINT/SIGTERM or ``--duration`` (:mod:`launcher.live`)."""
    import threading

    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.live import run_live
    from launcher.run import RunFailed
    from system.config import load_config
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        config = load_config(args.config, args.set)
        services = services_arg(args)
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


def cmd_run(args: argparse.Namespace) -> int:
    """``poseidon run``: a replay (embedded or distributed) or, with ``--live``, a live run."""
    from common.config import ConfigError
    from common.mcap_io import RecordingError
    from launcher.run import RunFailed, run_distributed, run_embedded
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
            from launcher.run import use_map_dir
            use_map_dir(config, args.map_dir)
        services = services_arg(args)
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
