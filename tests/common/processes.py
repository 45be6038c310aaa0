"""Waiting for a launcher run in a test, and saying why when it does not end.

:func:`finish` is ``proc.communicate(timeout=...)`` that, on a timeout, asks the launcher and
every process it started for their Python stacks (``SIGUSR1``: :mod:`faulthandler`, registered
by the ``poseidon`` command and by every service), stops the run and fails the test with the
tails of the run's stderr and log file: a run that hangs on a loaded machine then names the
thread it hangs in."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from launcher.children import children

__all__ = ["finish"]


def _tail(path: Path | None, chars: int) -> str:
    if path is None or not path.exists():
        return f"({path}: none)"
    return path.read_text(errors="replace")[-chars:]


def finish(proc: subprocess.Popen, timeout_s: float, err: Path, log: Path | None = None) -> str:
    """The run's stdout once it exits within ``timeout_s``; otherwise its processes' stacks go to
    ``err`` (where their stderr goes), the run is stopped and the test fails with ``err``'s and
    ``log``'s tails."""
    try:
        stdout, _ = proc.communicate(timeout=timeout_s)
        return str(stdout)
    except subprocess.TimeoutExpired:
        pass
    for pid in [proc.pid, *children(proc.pid)]:  # one after another: they share the stderr
        try:
            os.kill(pid, signal.SIGUSR1)
        except ProcessLookupError:
            continue
        time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
    pytest.fail(f"the run did not end within {timeout_s:.0f} s; stderr with every process's stacks:\n"
                f"{_tail(err, 30000)}\n--- log ---\n{_tail(log, 8000)}")
