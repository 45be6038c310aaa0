"""Soak: a long simulated mission through the full distributed pipeline at maximum replay speed.

``--minutes`` (default 60) of ``poseidon sim`` (cached in ``--cache-dir``)
replayed as fast as the services take it (player rate 0), every service in its own process
(``launcher.run.run_distributed``).  Reported:

- messages: for every key the player publishes, recorded / in the input (a drop shows as
  < 1); for the SLAM outputs, one ``neocortex/sdr`` and one ``local_view_cells`` per camera
  frame, one ``experience_image`` per ``experience_event``;
- memory: peak RSS (MiB) of each service process in each sixth of the run's wall time
  (replay speed is roughly constant, so each sixth is ~10 mission minutes of a 60-minute
  mission) -- flat memory means the last sixth's peak is close to the second's;
- speed: real-time factor (mission seconds per wall second) of the full pipeline, next to
  the baseline measured in the same run: the player and the recorder alone on the same
  input (the transport's ceiling: with no service started every key goes over the bus,
  whatever ``player.replay`` says).

    .venv/bin/python benchmarks/bench_soak.py                   # 60 min (~4 min to simulate, ~10 to run)
    .venv/bin/python benchmarks/bench_soak.py --minutes 10 --json

The two run recordings (player + recorder alone, full pipeline) are each deleted once measured,
the first before the second run starts (``--keep-outputs`` keeps them: ~13 GB for the 60-min
mission); the simulated mission stays cached (~6.2 GB per mission hour).

``--json``: ``{"minutes", "mission", "overrides" (``--set``), "pipeline": {"wall_s", "mission_s", "real_time_factor"},
"transport_only": {same}, "rtf_ratio", "dropped": {key: input - recorded}, "outputs":
{"camera_frames", "sdr", "local_view_cells", "events", "experience_images"},
"peak_rss_mib": {service: [peak per sixth]}, "rss_growth_mib": {service: last - second},
"cpu_s": {service: user + system CPU seconds at its last sample (<= 1 s before it ended; a restarted
service's processes summed)},
"cpu_s_per_sixth": {service: [CPU s used in each sixth of the wall time]},
"per_mission_part": [{"mission_s": [from, to], "wall_s", "real_time_factor", "cpu_s": {service: CPU s},
"peak_rss_mib": {service: MiB}}]
(``--parts`` equal parts of the mission time, default 3: the hours of a 3-hour mission; where
the pipeline was is read from the recorder's checkpoint once a second), "last_vs_first":
{"wall": last part's wall s / first's, "cpu_s": {service: last part's CPU s / first's},
"peak_rss_mib": {service: last part's peak RSS - first's}},
"cpu_split": {service: {"cpu_s", "startup_s", "node_s", "frame_path_s", "rest_s"}},
"encoder_ms_per_frame"}`` (``cpu_split``: algorithm services, from the run's own counters: the
process's CPU, and of it the start-up, the node's own work, the frames' handling around it and
the rest -- Zenoh's threads, zenoh-python's callback threads, the receive loop's idle work:
:mod:`common.runtime`; ``encoder_ms_per_frame``: the encoder node's own CPU ms per camera frame,
null without the encoder or a camera frame).  The encoder's work per frame is fixed by the mission
and the configuration, so on one mission ``encoder_ms_per_frame`` moves only with the machine's
speed: compare it before comparing two runs' real-time factors (the same code ran the 60-minute
mission at 16.19x to 27.14x on one 2-core machine within 75 minutes, its encoder at 5.82 to 3.52
ms per frame; the real-time factor times this stayed at 92.5-95.8).
The readable output ends each run with a table per service: CPU seconds and peak RSS in the
mission's first part against its last.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from common.mcap_io import recording_summary
from common.resume import load_checkpoint
from launcher.cli import isolate_stdout
from launcher.run import run_distributed, state_dir_of
from missions.sim.cli import simulate_cached
from system.config import load_config

SIXTHS = 6


def _service_pids(root: int) -> dict[str, int]:
    """name -> pid of the ``launcher.cli service NAME`` children of process ``root``."""
    out = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            if ppid != root:
                continue
            with open(f"/proc/{d}/cmdline", "rb") as f:
                argv = f.read().decode(errors="replace").split("\0")
        except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
            continue  # the process ended while we looked: nothing to sample
        if "service" in argv and argv.index("service") + 1 < len(argv):
            out[argv[argv.index("service") + 1]] = int(d)
    return out


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds a process has used so far (``/proc/PID/stat`` fields 14-15)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
        return None  # ended between listing and reading


def _rss_mib(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except (FileNotFoundError, ProcessLookupError):
        return None  # ended between listing and reading
    return None


def _recorder_seen_ns(ckpt: Path) -> int | None:
    """The event time (ns) of the newest input the recorder had at its last checkpoint."""
    try:
        state = load_checkpoint(ckpt)
    except ValueError:
        return None   # replaced while read beyond its retries: the next sample reads it
    return None if state is None else int(state["seen"])


class RssSampler:
    """Samples the RSS and CPU of every service process every ``period_s`` while a run goes on,
    and (``recorder_ckpt``) the mission time the recorder has reached."""

    def __init__(self, period_s: float = 1.0, recorder_ckpt: Path | None = None):
        self.period_s = period_s
        self.recorder_ckpt = recorder_ckpt
        self.mission_samples: list[tuple[float, int]] = []   # (wall s from start, event time ns recorded)
        self.samples: list[tuple[float, str, float]] = []   # (wall s from start, service, MiB)
        self.cpu_samples: list[tuple[float, str, float]] = []  # (wall s from start, service, CPU s so far)
        self.cpu_s: dict[str, float] = {}                   # service -> CPU s used at its last sample
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._t0 = 0.0
        self.elapsed_s = 0.0   # wall s from the sampler's start to its stop (start-up included)
        self._procs: dict[str, tuple[int, float, float]] = {}  # service -> (pid, CPU s of its ended pids, last)

    def _loop(self) -> None:
        me = os.getpid()
        while not self._stop.wait(self.period_s):
            t = time.monotonic() - self._t0
            for name, pid in _service_pids(me).items():
                rss = _rss_mib(pid)
                if rss is not None:
                    self.samples.append((t, name, rss))
                cpu = _cpu_s(pid)
                if cpu is not None:
                    cpu = self._carried(name, pid, cpu)
                    self.cpu_s[name] = cpu
                    self.cpu_samples.append((t, name, cpu))
            seen = _recorder_seen_ns(self.recorder_ckpt) if self.recorder_ckpt is not None else None
            if seen is not None:
                self.mission_samples.append((t, seen))

    def _carried(self, name: str, pid: int, cpu: float) -> float:
        """CPU s of service ``name`` over all its processes: a restarted service (a new pid) adds
        its predecessor's last sample, so the series never drops."""
        old_pid, offset, last = self._procs.get(name, (pid, 0.0, 0.0))
        if old_pid != pid:
            offset += last
        self._procs[name] = (pid, offset, cpu)
        return offset + cpu

    def __enter__(self) -> RssSampler:
        self._t0 = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join()
        self.elapsed_s = time.monotonic() - self._t0

    def peaks(self, wall_s: float) -> dict[str, list[float]]:
        out: dict[str, list[float]] = {}
        for t, name, rss in self.samples:
            k = min(int(t / max(wall_s, 1e-9) * SIXTHS), SIXTHS - 1)
            row = out.setdefault(name, [0.0] * SIXTHS)
            row[k] = max(row[k], round(rss, 1))
        return out

    def cpu_per_sixth(self, wall_s: float) -> dict[str, list[float]]:
        """CPU seconds each service used in each sixth of the run's wall time (a per-frame cost
        that grows with the map shows as a rising row)."""
        last: dict[str, list[float]] = {}
        for t, name, cpu in self.cpu_samples:
            k = min(int(t / max(wall_s, 1e-9) * SIXTHS), SIXTHS - 1)
            row = last.setdefault(name, [0.0] * SIXTHS)
            row[k] = max(row[k], cpu)
        out = {}
        for name, row in last.items():
            for k in range(1, SIXTHS):  # a sixth without samples: nothing used in it
                row[k] = max(row[k], row[k - 1])
            out[name] = [round(row[0], 1)] + [round(row[k] - row[k - 1], 1) for k in range(1, SIXTHS)]
        return out


    def per_mission_part(self, parts: int, start_ns: int, mission_s: float, wall_s: float) -> list[dict[str, Any]]:
        """Per ``parts`` equal parts of the mission time: the wall time the pipeline took for it
        (from the recorder's progress, interpolated between samples; the last part ends with
        the run), its real-time factor, the CPU seconds each service used in it and each
        service's peak RSS (MiB) over the samples taken in it."""
        ts = np.array([t for t, _ in self.mission_samples] + [wall_s])
        ms = np.array([(s - start_ns) / 1e9 for _, s in self.mission_samples] + [mission_s])
        ms = np.maximum.accumulate(ms)
        bounds = [0.0] + [float(np.interp(mission_s * k / parts, ms, ts)) for k in range(1, parts)] + [wall_s]
        cpu: dict[str, tuple[list[float], list[float]]] = {}
        for t, name, c in self.cpu_samples:
            cpu.setdefault(name, ([0.0], [0.0]))
            cpu[name][0].append(t)
            cpu[name][1].append(c)
        out = []
        for k in range(parts):
            w = bounds[k + 1] - bounds[k]
            rss: dict[str, float] = {}
            for t, name, mib in self.samples:
                if bounds[k] <= t < bounds[k + 1] or (k == parts - 1 and t >= bounds[k]):
                    rss[name] = max(rss.get(name, 0.0), round(mib, 1))
            out.append({"mission_s": [round(mission_s * k / parts, 1), round(mission_s * (k + 1) / parts, 1)],
                        "wall_s": round(w, 1), "real_time_factor": round(mission_s / parts / w, 2) if w > 0 else None,
                        "cpu_s": {n: round(float(np.interp(bounds[k + 1], t_, c_) - np.interp(bounds[k], t_, c_)), 1)
                                  for n, (t_, c_) in sorted(cpu.items())},
                        "peak_rss_mib": dict(sorted(rss.items()))})
        return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--cache-dir", default="/tmp/poseidon-soak")
    ap.add_argument("--parts", type=int, default=3,
                    help="split the mission into this many equal parts for the per-part speed and CPU (default 3: "
                         "hours of a 3-hour mission)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override one configuration field of the full pipeline's run (repeatable), e.g. to "
                         "measure a default against its predecessor on the same cached mission")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--keep-outputs", action="store_true",
                    help="keep the two run recordings (about 13 GB for 60 min) in --cache-dir")
    args = ap.parse_args(argv)
    isolate_stdout()  # the in-process hub's native log lines go to stderr, not into --json
    cache = Path(args.cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    mission = simulate_cached(cache / f"soak_{args.minutes:g}min_seed{args.seed}.mcap", args.minutes, args.seed)
    inp = recording_summary(mission)
    cfg = load_config(overrides=[f"encoder.lsbh.matrix_path={cache}/lsbh_{{backbone}}_{{modality}}.npy", *args.set])

    print("transport only: player -> recorder", file=sys.stderr)
    base = run_distributed(cfg, mission, cache / "soak_transport.mcap", services=[], progress=False)
    if not args.keep_outputs:  # measured: its disk is free for the pipeline's (~19 GB for 3 hours)
        (cache / "soak_transport.mcap").unlink(missing_ok=True)
    print("full pipeline", file=sys.stderr)
    run_out = cache / "soak_run.mcap"
    with RssSampler(recorder_ckpt=state_dir_of(cfg, run_out) / "recorder.ckpt") as sampler:
        res = run_distributed(cfg, mission, run_out, progress=True)
    if not args.keep_outputs:  # measured; the mission itself stays cached
        (cache / "soak_run.mcap").unlink(missing_ok=True)
    counts = res.recording["counts"]
    played = [k for k in inp["counts"] if k not in ("neocortex/sdr", "local_view_cells")]
    dropped = {k: inp["counts"][k] - counts.get(k, 0) for k in played}
    mission_s = float(res.recording["duration_s"])
    # the sampler's clock starts before the services do (their start-up is in the run's first
    # part, not in res.wall_s): its samples are binned on its own elapsed time
    peaks = sampler.peaks(sampler.elapsed_s)
    out = {
        "minutes": args.minutes, "mission": str(mission), "overrides": args.set,
        "pipeline": {"wall_s": round(res.wall_s, 1), "mission_s": round(mission_s, 1),
                     "real_time_factor": round(mission_s / res.wall_s, 2)},
        "transport_only": {"wall_s": round(base.wall_s, 1), "mission_s": round(mission_s, 1),
                           "real_time_factor": round(mission_s / base.wall_s, 2)},
        "rtf_ratio": round(base.wall_s / res.wall_s, 3),
        "dropped": dropped,
        "outputs": {"camera_frames": counts.get("camera/image_raw", 0), "sdr": counts.get("neocortex/sdr", 0),
                    "local_view_cells": counts.get("local_view_cells", 0),
                    "events": counts.get("experience_event", 0),
                    "experience_images": counts.get("experience_image", 0)},
        "peak_rss_mib": peaks,
        "rss_growth_mib": {n: round(v[-1] - v[1], 1) for n, v in peaks.items()},
        "cpu_s": {n: round(v, 1) for n, v in sorted(sampler.cpu_s.items())},
        "cpu_s_per_sixth": sampler.cpu_per_sixth(sampler.elapsed_s),
    }
    out["cpu_split"] = cpu_split(res.services)
    out["encoder_ms_per_frame"] = encoder_ms_per_frame(out["cpu_split"], out["outputs"]["camera_frames"])
    parts = sampler.per_mission_part(args.parts, int(inp["start_ns"]), mission_s, sampler.elapsed_s)
    out["per_mission_part"] = parts
    first, last = parts[0], parts[-1]
    out["last_vs_first"] = {"wall": round(last["wall_s"] / first["wall_s"], 2) if first["wall_s"] > 0 else None,
                            "cpu_s": {n: round(v / first["cpu_s"][n], 2) if first["cpu_s"].get(n) else None
                                      for n, v in last["cpu_s"].items()},
                            "peak_rss_mib": {n: round(v - first["peak_rss_mib"][n], 1)
                                             if n in first["peak_rss_mib"] else None
                                             for n, v in last["peak_rss_mib"].items()}}
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    print_report(out, args.minutes, args.parts)
    return 0


def cpu_split(services: dict[str, dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per algorithm service (those with ``node_cpu_s``): its process CPU and where it went."""
    split = {}
    for name, st in sorted(services.items()):
        if "node_cpu_s" not in st or "cpu_s" not in st:
            continue
        parts = {"startup_s": st["startup_cpu_s"], "node_s": st["node_cpu_s"], "frame_path_s": st["frame_path_cpu_s"]}
        split[name] = {"cpu_s": round(st["cpu_s"], 1), **{k: round(v, 1) for k, v in parts.items()},
                       "rest_s": round(st["cpu_s"] - sum(parts.values()), 1)}
    return split


def encoder_ms_per_frame(split: dict[str, dict[str, float]], camera_frames: int) -> float | None:
    """The encoder node's own CPU (ms) per camera frame: fixed work, so the machine's speed."""
    enc = split.get("encoder")
    if enc is None or camera_frames <= 0:
        return None
    return round(1000.0 * enc["node_s"] / camera_frames, 3)


def print_first_last(first: dict[str, Any], last: dict[str, Any], n_parts: int) -> None:
    """Per service: CPU s and peak RSS of the mission's first part against its last."""
    a, b = first["mission_s"], last["mission_s"]
    print(f"first 1/{n_parts} of the mission ({a[0]:.0f}-{a[1]:.0f} s) against the last ({b[0]:.0f}-{b[1]:.0f} s), "
          "per service:")
    print(f"  {'service':<12} {'CPU s first':>11} {'last':>7} {'last/first':>10}   {'peak RSS MiB first':>18} "
          f"{'last':>7} {'last-first':>10}")
    names = sorted(set(first["cpu_s"]) | set(last["cpu_s"]) | set(first["peak_rss_mib"]) | set(last["peak_rss_mib"]))
    for n in names:
        c0, c1 = first["cpu_s"].get(n), last["cpu_s"].get(n)
        r0, r1 = first["peak_rss_mib"].get(n), last["peak_rss_mib"].get(n)
        ratio = f"{c1 / c0:.2f}x" if c0 and c1 is not None else "-"
        grow = f"{r1 - r0:+.1f}" if r0 is not None and r1 is not None else "-"
        print(f"  {n:<12} {_num(c0):>11} {_num(c1):>7} {ratio:>10}   {_num(r0):>18} {_num(r1):>7} {grow:>10}")


def _num(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


def print_report(out: dict[str, Any], minutes: float, n_parts: int) -> None:
    """The readable form of ``out`` (the ``--json`` document)."""
    dropped, parts, peaks = out["dropped"], out["per_mission_part"], out["peak_rss_mib"]
    p, t = out["pipeline"], out["transport_only"]
    print(f"{minutes:g}-minute mission: full pipeline {p['wall_s']} s wall = {p['real_time_factor']}x real time; "
          f"player + recorder alone {t['wall_s']} s = {t['real_time_factor']}x (pipeline / transport speed "
          f"{out['rtf_ratio']})")
    print(f"messages dropped (input - recorded): {sum(dropped.values())} over {len(dropped)} keys; "
          f"outputs {out['outputs']}")
    total = sum(out["cpu_s"].values())
    print(f"CPU seconds per service (sum {total:.0f} s over {p['wall_s']} s wall on {os.cpu_count()} cores): " +
          ", ".join(f"{n} {v:.0f} s ({100 * v / max(total, 1e-9):.0f} %)" for n, v in
                    sorted(out["cpu_s"].items(), key=lambda kv: -kv[1])))
    if out.get("encoder_ms_per_frame") is not None:
        print(f"encoder's own work per camera frame: {out['encoder_ms_per_frame']} ms of CPU (fixed work: it "
              "moves with the machine's speed; compare it before comparing two runs)")
    print(f"per 1/{n_parts} of the mission: wall s (real-time factor) and CPU s per service; "
          f"last / first: wall {out['last_vs_first']['wall']}x")
    for part in parts:
        print(f"  {part['mission_s'][0]:>7.0f}-{part['mission_s'][1]:<7.0f} s: {part['wall_s']:7.1f} s "
              f"({part['real_time_factor']}x)  " + ", ".join(f"{n} {v:.1f}" for n, v in part["cpu_s"].items()))
    print("CPU seconds per sixth of the run (the first includes start-up):")
    for name, row in sorted(out["cpu_s_per_sixth"].items()):
        print(f"  {name:<12} " + " ".join(f"{v:7.1f}" for v in row))
    print("peak RSS per sixth of the run (MiB):")
    for name, row in sorted(peaks.items()):
        print(f"  {name:<12} " + " ".join(f"{v:7.1f}" for v in row) + f"   growth 2nd->6th {out['rss_growth_mib'][name]:+.1f}")
    print_first_last(parts[0], parts[-1], n_parts)
    print("where each algorithm service's CPU went (s): start-up, the node's own work, the frames' handling "
          "around it, the rest (Zenoh's and the callback threads, idle loop, end)")
    print(f"  {'service':<12} {'CPU':>7} {'start-up':>9} {'node':>7} {'frames':>7} {'rest':>7}")
    for n, c in out["cpu_split"].items():
        print(f"  {n:<12} {c['cpu_s']:7.1f} {c['startup_s']:9.1f} {c['node_s']:7.1f} {c['frame_path_s']:7.1f} "
              f"{c['rest_s']:7.1f}")


if __name__ == "__main__":
    sys.exit(main())
