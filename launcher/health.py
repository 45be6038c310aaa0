"""Health of a supervised live run: what an operator (and ROS tools) can read while it runs.

Per service of the run (the algorithm services, the recorder, the hub and the live source):

- ``alive``: its process is running;
- ``restarts``: how often the launcher started it again;
- ``lag_s``: EVENT time between the newest message the source published and the newest
  input the service finished (its ``@progress``), 0 once it finished; null before either is
  known.  The hub has none;
- ``checkpoint_age_s``: WALL time since its last checkpoint was written (null before the
  first one; sources and the hub keep none).

The launcher publishes a snapshot every ``supervise.health_interval_s`` on
:data:`HEALTH_KEY` as a ``diagnostic_msgs/DiagnosticArray`` (:class:`common.messages.DiagnosticArray`:
one status per service, level 0 OK, 1 WARN -- restarted, or lagging more than
``supervise.caught_up_lag_s`` --, 2 ERROR -- not running), stamped with the source's newest
event time, so the recorder keeps it with the run and the ROS 1 bridge republishes it on
``/diagnostics`` (rqt_robot_monitor, ``rostopic echo /diagnostics``).  The frames are not
numbered: health is a sample, never replayed, and a snapshot published while the recorder
restarts is not in the recording.

Recovery of a restart (:class:`Recovery`): from the moment the launcher saw the process die
(``died``, wall) to its restart (``restarted_s``), to the first input the restarted process
finished (``resumed_s``: its first ``@progress`` after the restart) and to the end of its
catch-up (``caught_up_s``: its lag back within ``supervise.caught_up_lag_s``).  The run
summary (``--json``) has them under ``recoveries`` and the final snapshot under ``health``.

:func:`snapshot` and :func:`diagnostics` compute; the launcher reads the clocks and the files.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

from common.live import HEALTH_KEY
from common.messages import DiagnosticArray, DiagnosticStatus, Header, KeyValue
from common.ordering import END_OF_TIME

__all__ = ["HEALTH_KEY", "ServiceHealth", "Recovery", "snapshot", "diagnostics", "checkpoint_ages"]

class ServiceHealth(TypedDict):
    """One service in a health snapshot (module notes)."""

    alive: bool
    restarts: int
    lag_s: float | None
    checkpoint_age_s: float | None


@dataclass
class Recovery:
    """One restart of a live run and how long its recovery took (wall s from ``died``)."""

    service: str
    cause: str
    died: float                      # monotonic s when the launcher saw it die
    restarted_s: float | None = None
    resumed_s: float | None = None
    caught_up_s: float | None = None
    progress_at_restart: int = -2    # the service's @progress when it was restarted

    def as_dict(self) -> dict[str, Any]:
        def r(v: float | None) -> float | None:
            return None if v is None else round(v, 3)
        return {"service": self.service, "cause": self.cause, "restarted_s": r(self.restarted_s),
                "resumed_s": r(self.resumed_s), "caught_up_s": r(self.caught_up_s)}

    def follow(self, now: float, progress: int, lag_s: float | None, caught_up_lag_s: float) -> None:
        """Note the restarted service's progress (``progress``: its ``@progress``; ``lag_s`` as in
        :func:`snapshot`) at monotonic ``now``."""
        if self.restarted_s is None:
            return
        if self.resumed_s is None and progress != self.progress_at_restart and progress != -2:
            self.resumed_s = now - self.died
        if (self.resumed_s is not None and self.caught_up_s is None and lag_s is not None
                and lag_s <= caught_up_lag_s):
            self.caught_up_s = now - self.died


def _lag_s(source_stamp: int | None, progress: int | None) -> float | None:
    if progress == END_OF_TIME:
        return 0.0
    if source_stamp is None or progress is None or progress < 0:
        return None
    return max(0.0, (source_stamp - progress) / 1e9)


def snapshot(services: list[str], alive: dict[str, bool], restarts: dict[str, int], progress: dict[str, int],
             source_stamp: int | None, checkpoint_age_s: dict[str, float]) -> dict[str, ServiceHealth]:
    """The health of ``services`` (module notes) from what the launcher knows: running or not,
    restarts, ``@progress`` per service (event ns; ``END_OF_TIME`` when finished; absent or < 0
    before the first), the source's newest published stamp and each checkpoint's age (wall s)."""
    out: dict[str, ServiceHealth] = {}
    for name in services:
        lag = _lag_s(source_stamp, progress.get(name))
        out[name] = ServiceHealth(alive=bool(alive.get(name, False)), restarts=int(restarts.get(name, 0)),
                                  lag_s=None if lag is None else round(lag, 3),
                                  checkpoint_age_s=(round(checkpoint_age_s[name], 3)
                                                    if name in checkpoint_age_s else None))
    return out


def diagnostics(health: dict[str, ServiceHealth], stamp: int, seq: int, caught_up_lag_s: float) -> DiagnosticArray:
    """``health`` as a ``diagnostic_msgs/DiagnosticArray`` (one status per service, named
    ``poseidon/<service>``; level and message as in the module notes)."""
    status = []
    for name, h in health.items():
        lag = h["lag_s"]
        if not h["alive"]:
            level, text = 2, "not running"
        elif lag is not None and lag > caught_up_lag_s:
            level, text = 1, f"{lag:.1f} s behind the source"
        elif h["restarts"]:
            level, text = 1, f"running after {h['restarts']} restart(s)"
        else:
            level, text = 0, "running"
        values = [KeyValue(key="alive", value=str(h["alive"]).lower()),
                  KeyValue(key="restarts", value=str(h["restarts"])),
                  KeyValue(key="lag_s", value="" if lag is None else f"{lag:.3f}"),
                  KeyValue(key="checkpoint_age_s",
                           value="" if h["checkpoint_age_s"] is None else f"{h['checkpoint_age_s']:.1f}")]
        status.append(DiagnosticStatus(level=level, name=f"poseidon/{name}", message=text, hardware_id="poseidon",
                                       values=values))
    return DiagnosticArray(header=Header(seq=seq, stamp=max(0, stamp), frame_id=""), status=status)


def checkpoint_ages(state_dir: Path | None, services: list[str], now_wall: float) -> dict[str, float]:
    """Wall seconds since each service's checkpoint file in ``state_dir`` was last written."""
    if state_dir is None:
        return {}
    ages = {}
    for name in services:
        try:
            ages[name] = max(0.0, now_wall - (state_dir / f"{name}.ckpt").stat().st_mtime)
        except FileNotFoundError:
            continue
    return ages
