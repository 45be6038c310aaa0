"""How the launcher starts a service process: it dies with the launcher, and a replay's
services run under Linux ``SCHED_BATCH`` (``bus.batch_scheduling``; why:
``docs/DECISIONS.md``, "Replays under SCHED_BATCH")."""
from __future__ import annotations

import ctypes
import logging
import os
import signal
import subprocess
from pathlib import Path
from typing import Any

__all__ = ["check_batch_scheduling", "die_with_launcher", "child_pid"]

log = logging.getLogger(__name__)

PR_SET_PDEATHSIG = 1
_SCHED_BATCH: int | None = getattr(os, "SCHED_BATCH", None)


def die_with_launcher(launcher_pid: int, batch_scheduling: bool = False) -> Any:
    """``preexec_fn`` of every child: the kernel sends it SIGTERM when the launcher dies, even
    by SIGKILL (``prctl(PR_SET_PDEATHSIG)``), so a service never outlives its run as an
    orphan; SIGTERM lets the recorder close its file with a summary.

    ``batch_scheduling`` (replays, ``bus.batch_scheduling``): the child and every thread it
    starts run under Linux ``SCHED_BATCH``.  A refusal is not raised here (the launcher
    checks the policy each child got, :func:`check_batch_scheduling`)."""
    def setup() -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
        if os.getppid() != launcher_pid:  # the launcher died before prctl took effect
            os.kill(os.getpid(), signal.SIGTERM)
        if batch_scheduling and _SCHED_BATCH is not None:
            try:
                os.sched_setscheduler(0, _SCHED_BATCH, os.sched_param(0))
            except OSError:  # reported by the launcher, which reads the policy the child got
                pass
    return setup



def check_batch_scheduling(name: str, proc: subprocess.Popen[Any]) -> None:
    """Warn when a child asked for ``SCHED_BATCH`` did not get it (it runs, only slower)."""
    if _SCHED_BATCH is None:
        log.warning("bus.batch_scheduling: this system has no SCHED_BATCH; service %s runs with the "
                    "default scheduling", name)
        return
    try:
        policy = os.sched_getscheduler(proc.pid)
    except OSError as exc:  # the child already exited: its exit code tells the rest
        log.debug("bus.batch_scheduling: cannot read the policy of %s: %s", name, exc)
        return
    if policy != _SCHED_BATCH:
        log.warning("bus.batch_scheduling: service %s did not get SCHED_BATCH (policy %d); it runs with the "
                    "default scheduling", name, policy)


def child_pid(launcher_pid: int, name: str) -> int | None:
    """The pid of the launcher's child running service ``name`` (``... service NAME ...``; the
    hub: ``... hub ...``), read from ``/proc`` (Linux); None when there is none right now.
    For tests and benchmarks that stop one process of a run."""
    for task in Path(f"/proc/{launcher_pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            try:
                argv = Path(f"/proc/{child}/cmdline").read_bytes().decode(errors="replace").split("\0")
            except FileNotFoundError:      # the child ended between the two reads
                continue
            if name == "hub" and "hub" in argv:
                return int(child)
            if "service" in argv and argv.index("service") + 1 < len(argv) and argv[argv.index("service") + 1] == name:
                return int(child)
    return None
