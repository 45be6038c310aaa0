"""How the launcher starts a service process: it dies with the launcher, and a replay's
services run under Linux ``SCHED_BATCH`` (``bus.batch_scheduling``; why:
``docs/DECISIONS.md``, "Replays under SCHED_BATCH"), and with ``bus.replay_nice`` > 0 all but
the favoured ones (``bus.replay_favoured``) nicer than the launcher ("Replay niceness").

Both are set up by the child itself, first thing in ``poseidon`` (:func:`adopt_launcher`), from
the environment :func:`child_env` gives it, never in a ``preexec_fn``: the launcher has Zenoh
threads running when it starts (and restarts) its services, and code run between ``fork`` and
``exec`` of a multi-threaded process can block for ever on a lock one of those threads held at
the fork (loading libc for ``prctl`` takes the dynamic loader's lock), with the launcher
blocked in ``Popen`` waiting for the ``exec``.  Without ``preexec_fn`` Python starts the child
with ``vfork``/``exec``, where nothing runs in between."""
from __future__ import annotations

import ctypes
import logging
import os
import signal
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

log = logging.getLogger(__name__)

__all__ = ["adopt_launcher", "child_env", "child_pid", "children", "describe_exit", "stop_all", "LAUNCHER_PID_ENV", "BATCH_ENV", "NICE_ENV"]

PR_SET_PDEATHSIG = 1
_SCHED_BATCH: int | None = getattr(os, "SCHED_BATCH", None)
#: the launcher's pid, in a child's environment: the child dies with that process
LAUNCHER_PID_ENV = "POSEIDON_LAUNCHER_PID"
#: "1" in a child's environment: the child (and every thread it starts) runs under SCHED_BATCH
BATCH_ENV = "POSEIDON_SCHED_BATCH"
#: an int in a child's environment: the child raises its niceness by this much, first thing
NICE_ENV = "POSEIDON_NICE"


def child_env(base: Mapping[str, str] | None = None, batch_scheduling: bool = False, nice: int = 0) -> dict[str, str]:
    """The environment of a child the launcher starts (``base``: default this process's): the
    child dies with this process, runs under ``SCHED_BATCH`` if ``batch_scheduling``, and
    ``nice`` (>= 0) nicer than this process."""
    if nice < 0:
        raise ValueError(f"child_env: nice must be >= 0 (a child can only be made nicer), got {nice}")
    env = dict(os.environ if base is None else base)
    env[LAUNCHER_PID_ENV] = str(os.getpid())
    env[BATCH_ENV] = "1" if batch_scheduling else "0"
    env[NICE_ENV] = str(nice)
    return env


def adopt_launcher(what: str = "poseidon") -> None:
    """In a child started with :func:`child_env`, before it starts any thread: the kernel sends
    it SIGTERM when the launcher dies, even by SIGKILL (``prctl(PR_SET_PDEATHSIG)``), so a
    service never outlives its run as an orphan (SIGTERM lets the recorder close its file with a
    summary); asked to, it takes ``SCHED_BATCH``, and says so on stderr when refused (it runs,
    only slower).  The variables are removed, so the child's own children are not bound to the
    launcher.  Without them (a process started by hand): nothing."""
    pid = os.environ.pop(LAUNCHER_PID_ENV, None)
    batch = os.environ.pop(BATCH_ENV, "0") == "1"
    nice = os.environ.pop(NICE_ENV, "0")
    if pid is None:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    if os.getppid() != int(pid):  # the launcher died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)
    if not nice.isdigit():
        raise ValueError(f"poseidon {what}: {NICE_ENV}={nice!r} is not a non-negative integer")
    if int(nice):
        os.nice(int(nice))  # before any thread: every thread the child starts inherits it
    if not batch:
        return
    # on stderr (the launcher's console): logging is not set up yet
    if _SCHED_BATCH is None:
        print(f"poseidon {what}: bus.batch_scheduling: this system has no SCHED_BATCH; running with the "
              "default scheduling", file=sys.stderr)
        return
    try:
        os.sched_setscheduler(0, _SCHED_BATCH, os.sched_param(0))
    except OSError as exc:
        print(f"poseidon {what}: bus.batch_scheduling: did not get SCHED_BATCH ({exc}); running with the default "
              "scheduling", file=sys.stderr)


def children(pid: int) -> list[int]:
    """The pids of process ``pid``'s children, read from ``/proc`` (Linux); [] once it ended."""
    out: list[int] = []
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except FileNotFoundError:
        return out
    for task in tasks:
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except FileNotFoundError:  # the thread ended between the two reads
            continue
    return out


def child_pid(launcher_pid: int, name: str) -> int | None:
    """The pid of the launcher's child running service ``name`` (``... service NAME ...``; the
    hub: ``... hub ...``), read from ``/proc`` (Linux); None when there is none right now.
    For tests and benchmarks that stop one process of a run."""
    for child in children(launcher_pid):
        try:
            argv = Path(f"/proc/{child}/cmdline").read_bytes().decode(errors="replace").split("\0")
        except FileNotFoundError:      # the child ended between the two reads
            continue
        if name == "hub" and "hub" in argv:
            return child
        if "service" in argv and argv.index("service") + 1 < len(argv) and argv[argv.index("service") + 1] == name:
            return child
    return None


def describe_exit(rc: int) -> str:
    """A child's exit status in words (``killed by signal SIGKILL``, ``exit code 3``)."""
    if rc < 0:
        try:
            return f"killed by signal {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exit code {rc}"


def stop_all(procs: dict[str, subprocess.Popen[bytes]], grace_s: float = 10.0, recorder_grace_s: float = 60.0) -> None:
    """SIGTERM to every process still running, then wait for each, ``grace_s`` (the recorder:
    ``recorder_grace_s``, since it first writes what has arrived and then the file's summary,
    which a kill would lose) before SIGKILL."""
    # the recorder last, so that it keeps what the others flushed
    order = [n for n in procs if n != "recorder"] + (["recorder"] if "recorder" in procs else [])
    for name in order:
        p = procs[name]
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for name in order:
        p = procs[name]
        wait_s = recorder_grace_s if name == "recorder" else grace_s
        try:
            p.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            log.error("%s did not stop within %.0f s; killing it", name, wait_s)
            p.kill()
            p.wait()
