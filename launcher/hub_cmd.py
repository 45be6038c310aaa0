"""``poseidon hub``: a hub (Zenoh router), the meeting point of services on other hosts, until
SIGINT/SIGTERM.  Exit 0."""
from __future__ import annotations

import argparse
import signal
import sys
import threading

__all__ = ["serve_hub", "cmd_hub"]


def serve_hub(listen: str, stop: threading.Event, config_file: str | None = None, **secure: str | None) -> None:
    """Open a hub listening on ``listen`` (a Zenoh endpoint) and keep it until ``stop`` is set.

    :param config_file: a Zenoh JSON5 configuration file
    :param secure: the secured profile (:func:`launcher.service_cmd.secure_args`)
    """
    from common.bus import open_hub
    hub = open_hub(listen, config_file=config_file, **secure)
    print(f"hub listening on {listen}", file=sys.stderr)
    try:
        stop.wait()
    finally:
        hub.close()  # type: ignore[no-untyped-call]  # zenoh.Session.close has no annotations


def cmd_hub(args: argparse.Namespace) -> int:
    """``poseidon hub``: the hub until interrupted."""
    from launcher.service_cmd import secure_args
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    serve_hub(args.listen, stop, config_file=args.zenoh_config, **secure_args(args))
    return 0
