"""``poseidon view``: serve the page over a running deployment or a finished recording.

:func:`serve_live` joins the hub read-only (:class:`~services.viewer.live.LiveFeed`), optionally
starts the Foxglove server (:class:`~services.viewer.foxglove_live.FoxgloveLive`), serves the page
and returns when ``stop`` is set.  :func:`serve_recording` serves a recording with the page's
time slider.  Both print the page's address on stderr (``ready`` gets it too).
"""
from __future__ import annotations

import json
import logging
import os
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from services.viewer.config import ViewConfig
from services.viewer.live import LiveFeed, ViewError, connect_bus
from services.viewer.recording import RecordingView, final_model
from services.viewer.server import ViewServer, parse_listen

__all__ = ["serve_live", "serve_recording", "show_final", "lower_niceness", "read_io", "ready_file", "ViewError"]

log = logging.getLogger(__name__)


def _server(source: RecordingView | LiveFeed, listen: str) -> ViewServer:
    try:
        host, port = parse_listen(listen)
    except ValueError as exc:
        raise ViewError(f"--listen {exc}") from None
    try:
        return ViewServer(source, host, port)
    except OSError as exc:
        raise ViewError(f"cannot serve the page on {host}:{port}: {exc.strerror or exc}") from None


def _announce(text: str, ready: Callable[[str], None] | None, url: str) -> None:
    print(text, file=sys.stderr, flush=True)
    if ready is not None:
        ready(url)


def serve_recording(path: str | Path, cfg: ViewConfig, stop: threading.Event, listen: str | None = None,
                    ready: Callable[[str], None] | None = None) -> None:
    """Serve the recording at ``path`` until ``stop`` is set (:class:`ViewError` on a bad file or address)."""
    view = RecordingView(path, cfg)
    server = _server(view, listen or cfg.listen)
    server.start()
    try:
        _announce(f"poseidon view: {view.path.name} ({view.duration_s:.0f} s) at {server.url} -- Ctrl-C to stop",
                  ready, server.url)
        stop.wait()
    finally:
        server.stop()


def _lowest_priority() -> None:
    """The calling thread and the threads it starts from now on run under SCHED_IDLE (``view.idle_priority``)."""
    policy = getattr(os, "SCHED_IDLE", None)
    if policy is None:
        log.warning("view.idle_priority: this system has no SCHED_IDLE; the view runs with the default scheduling")
        return
    try:
        os.sched_setscheduler(0, policy, os.sched_param(0))
    except OSError as exc:
        log.warning("view.idle_priority: SCHED_IDLE refused (%s); the view runs with the default scheduling", exc)


def read_io(path: str | Path) -> dict[str, tuple[tuple[str, ...], tuple[str, ...]]]:
    """Each service's input and output keys from the JSON file ``path`` (``{"name": [[inputs],
    [outputs]]}``, as ``poseidon run --view`` writes it: the view then imports no service to
    find them).

    :raises ViewError: the file cannot be read or is not of that shape (the message names it)
    """
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ViewError(f"--io {path}: {exc}") from None
    shape = isinstance(data, dict) and all(
        isinstance(v, list) and len(v) == 2 and all(isinstance(ks, list) and all(isinstance(k, str) for k in ks)
                                                    for ks in v) for v in data.values())
    if not shape:
        raise ViewError(f"--io {path}: not a map of service -> [[input keys], [output keys]]")
    return {str(n): (tuple(ins), tuple(outs)) for n, (ins, outs) in data.items()}


def ready_file(path: str | Path) -> Callable[[str], None]:
    """A ``ready`` callback of :func:`serve_live` that writes the page's address into ``path``
    (whole or not at all: written beside it, then renamed)."""
    target = Path(path)

    def write(url: str) -> None:
        part = target.with_name(target.name + ".part")
        part.write_text(url + "\n")
        os.replace(part, target)
    return write


def lower_niceness(level: int) -> int:
    """Raise the calling thread's niceness to ``level`` (``view.nice``) unless it is that high
    already; the threads it starts from now on inherit it (Linux keeps a niceness per thread).
    Returns the niceness the thread then has.

    :param level: the niceness to run at, 0-19 (0: leave it as it was)
    :raises ValueError: ``level`` outside 0-19
    """
    if not 0 <= level <= 19:
        raise ValueError(f"view.nice {level}: a niceness is 0-19")
    current = os.nice(0)
    if level > current:
        current = os.nice(level - current)
    return current


def show_final(feed: LiveFeed, recording: Path) -> bool:
    """Show the final state of the finished run's ``recording`` on ``feed`` (:meth:`LiveFeed.finish`):
    ``poseidon run --view`` asks for it once the recording is complete.  A recording that cannot
    be read leaves the live state shown, and says why on stderr; returns whether it was taken."""
    try:
        model = final_model(recording, feed.cfg)
    except ViewError as exc:
        print(f"poseidon view: the live state stays shown, the run's recording cannot be read: {exc}",
              file=sys.stderr, flush=True)
        return False
    feed.finish(model, recording.name)
    print(f"poseidon view: the final state of {recording.name} is shown", file=sys.stderr, flush=True)
    return True


def serve_live(cfg: ViewConfig, namespace: str, connect: str, stop: threading.Event,
               io: Mapping[str, tuple[Sequence[str], Sequence[str]]] | None = None, listen: str | None = None,
               foxglove_port: int | None = None, ready: Callable[[str], None] | None = None,
               final: tuple[threading.Event, Path] | None = None, **secure: str | None) -> None:
    """Serve the deployment whose hub is at ``connect`` until ``stop`` is set (``io``: each
    service's input and output keys, for its figures; ``final``: an event and a recording, the
    recording's final state replaces the live one once the event is set (:func:`show_final`);
    ``secure``: the secured profile's ``tls_dir``, ``tls_host``, ``user``, ``password_file``)."""
    if foxglove_port is not None and not 0 <= foxglove_port <= 65535:
        raise ViewError(f"--foxglove {foxglove_port}: not a port (0-65535)")
    try:
        host = parse_listen(listen or cfg.listen)[0]
    except ValueError as exc:
        raise ViewError(f"--listen {exc}") from None
    # Zenoh's threads start with the session and inherit the niceness (not SCHED_IDLE: they only
    # move bytes into the feed's bounded rings, and a starved reader there would hold up the
    # hub's forwarding)
    lower_niceness(cfg.nice)
    bus = connect_bus(namespace, connect, cfg.connect_timeout_s, **secure)
    if cfg.idle_priority:     # this thread and every thread it starts from now on
        _lowest_priority()
    fox = None
    try:
        if foxglove_port is not None:
            from services.viewer.foxglove_live import FoxgloveLive
            try:
                fox = FoxgloveLive(host, foxglove_port, cfg.foxglove_backlog)
            except RuntimeError as exc:
                raise ViewError(f"cannot start the Foxglove server on {host}:{foxglove_port}: {exc}") from None
        feed = LiveFeed(bus, cfg, io, on_update=fox.update if fox is not None else None)
        server = _server(feed, listen or cfg.listen)
        feed.start()
        server.start()
        try:
            extra = f"; Foxglove: ws://{host}:{fox.port}" if fox is not None else ""
            _announce(f"poseidon view: {connect} ({namespace}) at {server.url}{extra} -- Ctrl-C to stop", ready,
                      server.url)
            while not stop.wait(0.1):
                if final is not None and final[0].is_set():
                    final[0].clear()
                    show_final(feed, final[1])
        finally:
            server.stop()
            feed.stop()
    finally:
        if fox is not None:
            fox.stop()
        bus.close()
        bus.session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves close() unannotated
