"""``poseidon run --view [HOST:]PORT`` / ``--foxglove PORT``: ``poseidon view`` beside the run.

The view is one more process on the run's hub, read-only, no part of the run (never counted in
its summary).  It is started before the run and the run waits for it: once the hub listens, the
launcher starts nothing else until the view is *ready* -- subscribed to the hub and serving its
page, which it says by writing the page's address into a file (``poseidon view --ready-file``).
So the view's start-up (Python's imports, the page) is over before the first service starts and
is not inside the run's data.  The launcher passes the view each service's input and output keys
(``poseidon view --io``): the view imports no service to find them.

A view that ends before it is ready (a page address already in use, say: its own message comes
first) or is not ready within the run's start-up timeout stops the run before any service started
(:class:`ViewStartError`, exit 2).  After the run the view serves ``view.linger_s`` more seconds:
when the run ended well, the final state of its recording (``poseidon view --final-recording``,
asked by SIGUSR1 once the recording is complete), so the page ends with the recording's counts
even when the view, slowed or starved of CPU, dropped frames while the run went on.
"""
from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from launcher.children import child_env

if TYPE_CHECKING:
    from system.config import PoseidonConfig

__all__ = ["view_beside", "ViewProcess", "ViewStartError"]


class ViewStartError(RuntimeError):
    """``--view``: the view ended, or was not ready in time, before the run started (the message says which)."""


class ViewProcess:
    """A ``poseidon view`` process and its readiness.

    :param cmd: its command line; it must write its page's address into ``ready_file`` when ready
    :param ready_file: the file it writes (must not exist yet)
    :param what: the view's name in messages (e.g. ``--view 8080``)
    :param timeout_s: longest time from the start to readiness [s]
    """

    def __init__(self, cmd: Sequence[str], ready_file: Path, what: str, timeout_s: float):
        self.ready_file = ready_file
        self.what = what
        self.timeout_s = timeout_s
        self.url = ""  # the page's address, once ready
        self.started = time.monotonic()
        # its stdout goes to our stderr: our stdout carries only the run's own output (--json)
        self.proc = subprocess.Popen(list(cmd), stdout=2, env=child_env())

    def wait_ready(self) -> None:
        """Return once the view is ready (:attr:`url` set).

        :raises ViewStartError: the view ended before it was ready, or was not ready within
            ``timeout_s`` of its start (it is then stopped)
        """
        deadline = self.started + self.timeout_s
        while not self.ready_file.exists():
            rc = self.proc.poll()
            if rc is not None:
                raise ViewStartError(f"{self.what}: the view exited with code {rc} before it served its page "
                                     f"(its own message comes before this one)")
            if time.monotonic() > deadline:
                self.stop()
                raise ViewStartError(f"{self.what}: the view was not subscribed to the run's hub and serving its "
                                     f"page within {self.timeout_s:.0f} s of its start")
            time.sleep(0.05)
        self.url = self.ready_file.read_text().strip()

    def stop(self, linger_s: float = 0.0, final: bool = False, interrupt: threading.Event | None = None) -> None:
        """Let it serve ``linger_s`` more seconds if it runs (``final``: the run's recording's final
        state, asked by SIGUSR1; ``interrupt``: an event that ends the wait early, when it was not
        set already), then stop it (SIGTERM; killed after 10 s)."""
        if self.proc.poll() is None and linger_s > 0:
            if final:
                self.proc.send_signal(signal.SIGUSR1)
            print(f"poseidon run: the view serves the final state for {linger_s:.0f} s more (view.linger_s; "
                  f"Ctrl-C ends it)", file=sys.stderr)
            if interrupt is not None and not interrupt.is_set():
                interrupt.wait(linger_s)
            else:
                try:
                    time.sleep(linger_s)
                except KeyboardInterrupt:  # the run is over: Ctrl-C ends the linger, not the command
                    print("poseidon run: the view's linger ended by Ctrl-C", file=sys.stderr)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def view_command(args: argparse.Namespace, hub_port: int, startup_s: float, io_file: Path,
                 ready_file: Path) -> list[str]:
    """The command line of the view of a run whose hub listens on loopback ``hub_port``."""
    cmd = [sys.executable, "-m", "launcher.cli", "view", "--connect", f"tcp/127.0.0.1:{hub_port}",
           "--io", str(io_file), "--ready-file", str(ready_file), "--set", f"view.connect_timeout_s={startup_s}"]
    cmd += ["--listen", args.view] if args.view is not None else []
    cmd += ["--final-recording", str(args.out)]
    cmd += ["--foxglove", str(args.foxglove)] if args.foxglove is not None else []
    cmd += ["--config", args.config] if args.config else []
    for item in args.set:
        cmd += ["--set", item]
    return cmd


def _io_json(config: PoseidonConfig) -> str:
    """Each service's input and output keys as ``poseidon view --io`` reads them."""
    from system.services import available_services, node_io
    return json.dumps({n: [list(keys) for keys in node_io(n, config)]
                       for n in config.services or available_services(config)})


@contextmanager
def view_beside(args: argparse.Namespace, config: PoseidonConfig, startup_s: float,
                interrupt: threading.Event | None = None) -> Iterator[tuple[int | None, Callable[[], None] | None]]:
    """``--view``/``--foxglove``: the view process on the hub of the run started inside the block.

    Yields ``(hub_port, before_services)`` for :func:`launcher.run.run_distributed` /
    :func:`launcher.live.run_live`: the loopback port the run's hub must listen on and the call
    that waits until the view is ready (:meth:`ViewProcess.wait_ready`); ``(None, None)`` without
    a view.  After the block the view serves ``view.linger_s`` more seconds, then is stopped.

    :param startup_s: the view's readiness timeout and its hub connection timeout [s]
    :param interrupt: the run's stop event (SIGINT/SIGTERM): set during the linger, it ends it
    """
    if args.view is None and args.foxglove is None:
        yield None, None
        return
    from launcher.run import _free_port
    port = _free_port()
    what = f"--view {args.view}" if args.view is not None else f"--foxglove {args.foxglove}"
    with tempfile.TemporaryDirectory(prefix="poseidon-view-") as tmp:
        io_file, ready_file = Path(tmp) / "io.json", Path(tmp) / "ready"
        io_file.write_text(_io_json(config))
        view = ViewProcess(view_command(args, port, startup_s, io_file, ready_file), ready_file, what, startup_s)
        try:
            yield port, view.wait_ready
        except BaseException:
            view.stop(config.view.linger_s, interrupt=interrupt)
            raise
        view.stop(config.view.linger_s, final=True, interrupt=interrupt)
