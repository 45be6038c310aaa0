"""Logging of every ``poseidon`` process: its console and the run's log file.

The console (stderr) shows what a user must act on: WARNING and above.  ``--verbose`` adds
INFO (progress and results of the services); ``--log-level LEVEL`` sets the console's level
outright.  Progress bars and result tables are printed, not logged, and stay on the console.

A run writes the full log to a file beside its output -- ``poseidon run --out RUN.mcap``:
``RUN.log``; ``poseidon demo --out DIR``: ``DIR/demo.log`` -- with every record of this code
base from DEBUG and of other libraries from INFO, each line naming the service that wrote it:
the service of a ``poseidon service NAME`` process (a distributed run's service processes
append to the launcher's file, ``--log-file``), the thread of an embedded run's service
(``poseidon-NAME``), else the command.  :func:`setup` is the one place a process configures
its logging; the launcher hands its console level and file to its service processes with
:func:`child_args`.
"""
from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path

__all__ = ["setup", "console_level", "log_file", "child_args", "PACKAGES"]

#: this code base's top-level packages: their loggers write DEBUG records to the log file
PACKAGES = ("common", "eval", "launcher", "missions", "products", "services", "state", "system", "poseidon")

CONSOLE_FORMAT = "%(levelname)s [%(service)s] %(name)s: %(message)s"
FILE_FORMAT = "%(asctime)s %(levelname)s [%(service)s] %(name)s: %(message)s"

class _State:
    console: int = logging.WARNING
    file: Path | None = None


_lock = threading.Lock()


class _ServiceName(logging.Filter):
    """Puts ``record.service``: the process's service, or the embedded service of the thread."""

    def __init__(self, default: str):
        super().__init__()
        self.default = default

    def filter(self, record: logging.LogRecord) -> bool:
        thread = record.threadName or ""
        record.service = thread.removeprefix("poseidon-") if thread.startswith("poseidon-") else self.default
        return True


def level_number(name: str | int) -> int:
    """A level by name (``debug``, ``INFO``...) or number; ValueError naming it otherwise."""
    if isinstance(name, int):
        return name
    value = logging.getLevelName(name.upper())
    if not isinstance(value, int):
        raise ValueError(f"unknown log level {name!r} (DEBUG, INFO, WARNING, ERROR)")
    return value


def console_level_of(log_level: str | None, verbose: bool) -> int:
    """The console's level: ``--log-level`` when given, else INFO with ``--verbose``, else WARNING."""
    if log_level:
        return level_number(log_level)
    return logging.INFO if verbose else logging.WARNING


def setup(console: str | int, file: str | Path | None = None, service: str = "poseidon",
          append: bool = False) -> None:
    """Configure this process's logging (replacing what an earlier call installed).

    :param console: the console's level (name or number)
    :param file: the log file (None: none); created with its folder, emptied unless ``append``
    :param service: the name on this process's lines (a thread ``poseidon-NAME`` says NAME)
    :param append: add to ``file`` (a service process of a run) instead of starting it
    """
    level = level_number(console)
    root = logging.getLogger()
    with _lock:
        for h in list(root.handlers):
            if getattr(h, "_poseidon", False):
                root.removeHandler(h)
                h.close()
        tag = _ServiceName(service)
        handlers: list[logging.Handler] = []
        out = logging.StreamHandler(sys.stderr)
        out.setLevel(level)
        out.setFormatter(logging.Formatter(CONSOLE_FORMAT))
        handlers.append(out)
        path = None
        if file is not None:
            path = Path(file)
            path.parent.mkdir(parents=True, exist_ok=True)
            fh = logging.FileHandler(path, mode="a" if append else "w", encoding="utf-8")
            fh.setLevel(logging.DEBUG)
            fh.setFormatter(logging.Formatter(FILE_FORMAT))
            handlers.append(fh)
        for h in handlers:
            h.addFilter(tag)
            h._poseidon = True  # type: ignore[attr-defined]  # marks ours: a second call replaces them
            root.addHandler(h)
        # without a file nothing below the console's level is formatted; with one, other
        # libraries' records from INFO (numba's DEBUG alone would fill it) and ours from DEBUG
        root.setLevel(min(level, logging.INFO) if path is not None else level)
        for name in PACKAGES:
            logging.getLogger(name).setLevel(logging.DEBUG if path is not None else logging.NOTSET)
        _State.console = level
        _State.file = path
    try:  # Zenoh's own errors (TLS handshakes, refused authentication) on stderr; RUST_LOG overrides
        import zenoh
        zenoh.init_log_from_env_or("error")
    except (ImportError, AttributeError):
        pass


def console_level() -> str:
    """The console's level by name (a service process of the run logs to its console like this one)."""
    return logging.getLevelName(_State.console)


def log_file() -> Path | None:
    """The log file :func:`setup` opened, or None."""
    return _State.file


def child_args() -> list[str]:
    """The ``poseidon service`` arguments that make a service process log like this one:
    its console level and, when there is one, appending to the same log file."""
    file = log_file()
    return ["--log-level", console_level()] + (["--log-file", str(file)] if file is not None else [])
