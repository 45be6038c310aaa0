"""Write ``docs/RESULTS.md``: the measured results by topic, each section from the commands it names.

    .venv/bin/python benchmarks/write_results.py --list              # topics, data, rough duration
    .venv/bin/python benchmarks/write_results.py --only demo,laser   # re-run these, rewrite their sections
    .venv/bin/python benchmarks/write_results.py                     # every topic whose data is present

Over 500 lines because each topic keeps its commands, its measuring function and its table
together in this one file: a topic is added or changed in one place.

A topic (:data:`TOPICS`) runs its commands as subprocesses from the project root, outputs under
``--work-dir`` (default ``/tmp/poseidon-results``: simulated missions are cached there between
runs), reads their ``--json`` output and renders one section of the file: a heading, the
commands, the date (UTC) and the code revision (``git rev-parse --short HEAD``, ``+dirty`` when
a file other than Markdown differs from it), then its tables.  Sections are delimited by
``<!-- results:NAME -->`` and ``<!-- /results:NAME -->``; a run replaces only the sections of
the topics it ran and keeps every other byte of the file; a topic never measured gets a
"Not measured yet" section naming its commands.

Console: one line per command as it starts, a line a minute while it runs (the last line of its
stderr), its duration when it ends.  Each command's stdout and stderr are kept in
``WORK/logs/``.  A command that fails stops the script: its stderr file is named, its last lines
printed, and ``docs/RESULTS.md`` is left unchanged.  A topic whose data (``../shared/data/...``)
is absent is skipped with a message; its section stays as it was.

Exit code: 0 written (or nothing to do), 1 a command failed, 2 bad arguments.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
RESULTS = ROOT / "docs" / "RESULTS.md"
PREAMBLE = (
    "# Measured results\n\n"
    "Written by `benchmarks/write_results.py`; each section names the commands that produced it, the\n"
    "date (UTC) and the code revision (`+dirty`: files other than Markdown differed from it). Re-run one\n"
    "topic with `.venv/bin/python benchmarks/write_results.py --only NAME` (`--list` names them).\n"
    "`WORK` is the script's scratch folder. Speeds depend on the machine and its load; where a speed is\n"
    "compared with a baseline, the baseline was measured in the same run.\n"
)
#: published relation errors, translation m and heading deg, mean ± std as published ("": not published):
#: Kümmerle et al. 2009 (Autonomous Robots 27(4)), Hess et al. 2016 (ICRA, Table II)
PUBLISHED: dict[str, list[tuple[str, str, str]]] = {
    "aces": [("scan matching [published, Kümmerle 2009]", "0.173 ± 0.614", ""),
             ("GMapping [published, Kümmerle 2009]", "0.060 ± 0.049", ""),
             ("graph mapping [published, Kümmerle 2009]", "0.044 ± 0.044", "0.4 ± 0.4"),
             ("Cartographer [published, Hess 2016]", "0.0375 ± 0.0426", "0.37 ± 0.47")],
    "fr079": [("scan matching [published, Kümmerle 2009]", "0.258 ± 0.427", ""),
              ("GMapping [published, Kümmerle 2009]", "0.061 ± 0.044", ""),
              ("graph mapping [published, Kümmerle 2009]", "0.056 ± 0.042", "0.6 ± 0.6"),
              ("Cartographer [published, Hess 2016]", "0.0452 ± 0.0354", "0.54 ± 0.72")],
}
LASER_LOGS = ("aces", "fr079")
#: the laser preset's previous default, run beside it: the trajectory without scan poses
LASER_BASELINE = "expmap.scan_graph.scan_poses=false"
VPR_SEEDS = (4101, 4102, 4103, 4104, 4105)
VPR_CHAINS = ("sdr_seqmem", "no_tm", "no_dr_gate", "no_seqmem")
IMAGE_SETS = {  # name -> (label, poseidon vpr arguments)
    "corridor": ("corridor (VPR-Bench)", ["--ref", "vprbench_corridor/ref", "--query", "vprbench_corridor/query",
                                          "--gt", "vprbench_corridor/ground_truth_new.npy"]),
    "nordland": ("Nordland summer vs winter, ±1 frame", ["--ref", "nordland_trimmed/summer", "--query",
                                                          "nordland_trimmed/winter", "--tolerance", "1"]),
}
IMAGE_MATCHERS = ("htm_lvc", "htm_lvc_accepted", "sp_tm", "sdr_seqmem", "seq_cosine", "cnn_cosine", "patchnorm_sad")


class CommandFailed(RuntimeError):
    """A command exited with a code its topic does not accept, or printed no JSON."""


# ---------------------------------------------------------------- formatting (pure)

def fmt(value: Any, digits: int = 3) -> str:
    """A number with ``digits`` decimals, ``n/a`` for None."""
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    return f"{float(value):.{digits}f}"


def mean_std(block: dict[str, Any] | None, key: str, digits: int) -> str:
    """``mean ± std`` of ``block[key]`` (a relation summary's ``{mean, std}``)."""
    part = (block or {}).get(key) or {}
    if part.get("mean") is None:
        return "n/a"
    return f"{fmt(part['mean'], digits)} ± {fmt(part.get('std'), digits)}"


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- renderers (pure): JSON -> Markdown

def render_demo(d: dict[str, Any]) -> str:
    """The demo's table from ``poseidon demo --json``."""
    labels = {"on": "VPR Guard ON", "off": "VPR Guard OFF (baseline: posecells + expmap on the ON run's front-end)",
              "ratslam": "RatSLAM local view (baseline front-end), Guard ON"}
    rows = []
    for key, label in labels.items():
        r = d.get("runs", {}).get(key)
        if r is None:
            continue
        lc, ate = r.get("loop_closures", {}), r.get("ate_rmse_m", {})
        rows.append([label, fmt(r.get("events")), f"{fmt(lc.get('true'))} / {fmt(lc.get('false'))}",
                     f"{fmt(ate.get('map'), 2)} m", f"{fmt(ate.get('dead_reckoning'), 2)} m", fmt(r.get("audit_f1"), 2),
                     f"{fmt(r.get('mission_s'), 0)} s", f"{fmt(r.get('wall_s'), 0)} s",
                     f"{fmt(r.get('real_time_factor'), 1)}x"])
    out = table(["run", "experience events", "loop closures (true / false)", "ATE map",
                 "ATE dead reckoning (baseline)", "audit F1 (required: 1.0)", "mission", "wall time",
                 "real-time factor"], rows)
    checks = d.get("checks", {})
    if checks:
        out += "\nChecks: " + ", ".join(f"{name} {'PASS' if ok else 'FAIL'}" for name, ok in checks.items()) + ".\n"
    return out


def render_laser(results: dict[str, dict[str, Any]]) -> str:
    """Per log ``{"eval": poseidon eval --relations --json, "run": poseidon run --json}`` of the preset,
    and ``"base_eval"`` / ``"base_run"`` of the previous default (no scan poses) when measured."""
    out = []
    for log, res in results.items():
        ev, run = res["eval"], res.get("run", {})
        rel, odo = ev.get("relations") or {}, ev.get("relations_odometry") or {}
        rows = [["**this preset, map-corrected**", f"**{mean_std(rel, 'trans_abs_m', 3)}**",
                 f"**{mean_std(rel, 'rot_abs_deg', 3)}**"]]
        base = (res.get("base_eval") or {}).get("relations")
        if base:
            rows.append([f"previous default, `{LASER_BASELINE}` (same run)", mean_std(base, "trans_abs_m", 3),
                         mean_std(base, "rot_abs_deg", 3)])
        rows.append(["raw odometry (same run)", mean_std(odo, "trans_abs_m", 3), mean_std(odo, "rot_abs_deg", 2)])
        rows += [list(row) for row in PUBLISHED.get(log, [])]
        lc = ev.get("loop_closures") or {}
        out.append(f"**{log.upper()}** ({fmt(rel.get('count', odo.get('count')))} relations; {fmt(ev.get('nodes'))} "
                   f"experiences, {fmt(lc.get('accepted'))} loop closures{_laser_speed(run, res.get('base_run'))})\n\n"
                   + table(["method", "translation (m)", "heading (deg)"], rows))
    return "\n".join(out)


def _laser_speed(run: dict[str, Any], base: dict[str, Any] | None) -> str:
    """The run's real-time factor and expmap CPU, beside the previous default's when measured."""
    def one(d: dict[str, Any]) -> str:
        wall, span = d.get("wall_s"), (d.get("recording") or {}).get("duration_s")
        cpu = ((d.get("services") or {}).get("expmap") or {}).get("cpu_s")
        return (f"{span / wall:.1f}x real time" if span and wall else "n/a") + \
            (f", expmap {cpu:.1f} CPU s" if cpu is not None else "")
    if not run:
        return ""
    span = (run.get("recording") or {}).get("duration_s")
    text = f"; the log's {span:.0f} s: {one(run)}" if span else f"; {one(run)}"
    return text + (f"; previous default {one(base)}" if base else " (no baseline in this run)")


def render_vpr_images(results: dict[str, dict[str, Any]]) -> str:
    """Average precision per matcher from ``poseidon vpr --ref --query --json``, one row per image set."""
    rows = []
    for name, d in results.items():
        m = d.get("matchers", {})
        rows.append([IMAGE_SETS[name][0] if name in IMAGE_SETS else name, fmt(d.get("n_query_with_gt"))]
                    + [fmt((m.get(k) or {}).get("auc")) for k in IMAGE_MATCHERS])
    header = ["image set", "queries with ground truth", "**default** (`htm_lvc`)",
              "decisions at the gates (`htm_lvc_accepted`)"] + [f"`{k}`" for k in IMAGE_MATCHERS[2:]]
    return "Average precision (area under the precision-recall curve), each column a matcher of the same run.\n\n" \
        + table(header, rows)


def render_vpr_missions(results: dict[str, dict[str, Any]]) -> str:
    """Per-frame LVC revisit recall / precision from ``poseidon vpr --mission --json``, one row per seed."""
    names = ("default",) + VPR_CHAINS
    per: dict[str, list[tuple[float, float]]] = {n: [] for n in names}
    rows = []
    for seed, d in results.items():
        row = [seed]
        for n in names:
            c = d if n == "default" else (d.get("chains") or {}).get(n) or {}
            r, p = c.get("lvc_recall"), c.get("lvc_precision")
            row.append(f"{fmt(r)} / {fmt(p)}")
            if r is not None and p is not None:
                per[n].append((float(r), float(p)))
        rows.append(row + [fmt(d.get("tm_decision_share"))])
    mean = ["mean (lowest precision)"]
    for n in names:
        v = per[n]
        mean.append(f"{fmt(sum(r for r, _ in v) / len(v))} / {fmt(sum(p for _, p in v) / len(v))} "
                    f"({fmt(min(p for _, p in v))})" if v else "n/a")
    header = ["seed = world", "**default**"] + [f"`{n}`" for n in VPR_CHAINS] + ["TM share of decisions"]
    return ("LVC revisit recall / precision per frame (`lvc_recall` / `lvc_precision`), every chain on the "
            "same encoded frames in the same run; 20-minute missions whose seeds chose nothing.\n\n"
            + table(header, rows + [mean]))


def render_live(d: dict[str, Any]) -> str:
    """Latency per stage from ``benchmarks/bench_live.py --json``."""
    stages = ("lvc", "event", "map", "odometry")
    rows = []
    for rate, r in d.get("rates", {}).items():
        pipe, base = r.get("pipeline", {}), r.get("baseline", {})
        row = [f"{rate}x"]
        for s in stages:
            lat = (pipe.get("latency") or {}).get(s) or {}
            row.append(f"{fmt(lat.get('p50_ms'), 0)} / {fmt(lat.get('p95_ms'), 0)} / {fmt(lat.get('p99_ms'), 0)} "
                       f"({fmt((r.get('p50_ratio') or {}).get(s), 2)}x)")
        bl = (base.get("latency") or {}).get("odometry") or {}
        dropped = sum(sum(v.values()) for v in (pipe.get("dropped") or {}).values())
        row += [f"{fmt(bl.get('p50_ms'), 0)} / {fmt(bl.get('p95_ms'), 0)} / {fmt(bl.get('p99_ms'), 0)}",
                f"{dropped}, {sum((pipe.get('late') or {}).values())}", f"{fmt(pipe.get('lvc_ids'))}, "
                f"{fmt(pipe.get('events'))}"]
        rows.append(row)
    return (f"A {fmt(d.get('minutes'), 0)}-minute simulated mission played live (no ROS) through every service. "
            "Latency p50 / p95 / p99 in ms, and the p50 against the baseline's Odometry p50 (robot_state alone, "
            "same rate, same run).\n\n"
            + table(["rate", "LVC id", "experience event", "map", "Odometry", "baseline: Odometry, robot_state alone",
                     "dropped, late", "LVC ids, events"], rows))


def render_recovery(d: dict[str, Any]) -> str:
    """Recovery from kills in a live run, from ``benchmarks/bench_recovery.py --json``."""
    rows = []
    for name in ("baseline", "killed"):
        r = d.get(name, {})
        rss = r.get("peak_rss_mb") or {}
        rows.append([name, fmt(r.get("loop_closures")), fmt(r.get("ate_m")), json.dumps(r.get("restarts") or {}),
                     fmt(rss.get("bridge_ros1"), 0), fmt(rss.get("recorder"), 0)])
    rec = d.get("recovery") or {}
    times = [[k.removesuffix("_s").replace("_", " "), fmt((rec.get(k) or {}).get("p50"), 2),
              fmt((rec.get(k) or {}).get("max"), 2)] for k in ("restarted_s", "resumed_s", "caught_up_s")]
    kills = ", ".join(f"{k['service']} at {fmt(k['at_s'], 1)} s" for k in d.get("kills", []))
    return (f"The demo mission through ROS 1 (`rosbag play` at {fmt(d.get('rate'), 0)}x into `poseidon run --live "
            f"ros1`), once without a fault and once with {kills} of the mission (SIGKILL, in the middle of the loop "
            f"the baseline closed at mid-mission). Same loop closures (the final map's loop links) as the baseline: "
            f"**{d.get('same_loop_closures')}**.\n\n"
            + table(["run", "loop closures", "map ATE (m)", "restarts", "bridge peak RSS (MB)",
                     "recorder peak RSS (MB)"], rows)
            + "\n\nWall seconds from a kill to the restart, to the restarted service's first input done "
            "(`resumed`) and to the end of its catch-up (`caught up`: within `supervise.caught_up_lag_s` of the "
            "source):\n\n" + table(["from the kill to", "p50 (s)", "max (s)"], times))


def render_soak(d: dict[str, Any]) -> str:
    """Speed, CPU and drops from ``benchmarks/bench_soak.py --json``."""
    p, t = d.get("pipeline", {}), d.get("transport_only", {})
    dropped = sum((d.get("dropped") or {}).values())
    speed = table(["run", "mission", "wall time", "real-time factor"],
                  [["every service, own process", f"{fmt(p.get('mission_s'), 0)} s", f"{fmt(p.get('wall_s'), 1)} s",
                    f"**{fmt(p.get('real_time_factor'), 2)}x**"],
                   ["baseline: player + recorder alone", f"{fmt(t.get('mission_s'), 0)} s",
                    f"{fmt(t.get('wall_s'), 1)} s", f"{fmt(t.get('real_time_factor'), 2)}x"]])
    cpu = d.get("cpu_s") or {}
    last = (d.get("last_vs_first") or {}).get("cpu_s") or {}
    growth = d.get("rss_growth_mib") or {}
    rows = [[n, f"{fmt(v, 1)} s", f"{fmt(last.get(n), 2)}x", f"{fmt(growth.get(n), 1)} MiB"]
            for n, v in sorted(cpu.items(), key=lambda kv: -kv[1])]
    rows.append(["all", f"{fmt(sum(cpu.values()), 1)} s", "", ""])
    per_frame = d.get("encoder_ms_per_frame")
    machine = ("" if per_frame is None else
               f" The encoder's own work per camera frame: {fmt(per_frame, 2)} ms of CPU; the work is the same "
               "in every run of this mission, so this moves only with the machine's speed (compare it before "
               "comparing two runs' real-time factors).")
    return (speed + f"\nDropped messages: {dropped}.{machine} Last part of the mission against the first "
            f"({len(d.get('per_mission_part') or [])} equal parts): wall time "
            f"{fmt((d.get('last_vs_first') or {}).get('wall'), 2)}x.\n\n"
            + table(["service", "CPU", "CPU, last part / first", "peak RSS growth, 2nd to 6th sixth"], rows)
            + _cpu_split_text(d.get("cpu_split") or {}))


def _cpu_split_text(split: dict[str, Any]) -> str:
    """Where each algorithm service's CPU went (``bench_soak.py``'s ``cpu_split``); '' when absent."""
    if not split:
        return ""
    rows = [[n, f"{fmt(c.get('cpu_s'), 1)} s", f"{fmt(c.get('startup_s'), 1)} s", f"{fmt(c.get('node_s'), 1)} s",
             f"{fmt(c.get('frame_path_s'), 1)} s", f"{fmt(c.get('rest_s'), 1)} s"]
            for n, c in sorted(split.items(), key=lambda kv: -(kv[1].get("cpu_s") or 0))]
    return ("\nWhere each algorithm service's CPU went: start-up (imports, models, kernels, Zenoh, warm-up), "
            "the node's own work (the algorithm), the frames' handling around it (decoding, merging, encoding "
            "and publishing, checkpoints, progress) and the rest (Zenoh's threads, the callback threads, the "
            "idle loop, the end).\n\n"
            + table(["service", "CPU", "start-up", "node", "frame path", "rest"], rows))


# ---------------------------------------------------------------- the file (pure)

def _marks(name: str) -> tuple[str, str]:
    return f"<!-- results:{name} -->", f"<!-- /results:{name} -->"


def section_text(name: str, heading: str, commands: Sequence[str], stamp: str, revision: str, body: str,
                 machine: str = "") -> str:
    """One delimited section: heading, commands, date, revision (and the machine, if given), body."""
    begin, end = _marks(name)
    cmds = "\n".join(f"    {c}" for c in commands)
    on = f" on {machine}" if machine else ""
    return (f"{begin}\n## {heading}\n\nMeasured {stamp}{on}, revision `{revision}`, by:\n\n{cmds}\n\n"
            f"{body.rstrip()}\n{end}\n")


def unmeasured_section(topic: Topic) -> str:
    """The section of a topic never measured."""
    begin, end = _marks(topic.name)
    cmds = "\n".join(f"    {c}" for c in topic.commands)
    return (f"{begin}\n## {topic.heading}\n\nNot measured yet. `.venv/bin/python benchmarks/write_results.py "
            f"--only {topic.name}` runs:\n\n{cmds}\n{end}\n")


def split_sections(text: str) -> dict[str, tuple[int, int]]:
    """Section name -> (start, end) character span, end marker and its newline included."""
    spans = {}
    for m in re.finditer(r"<!-- results:([\w-]+) -->", text):
        name = m.group(1)
        end_mark = _marks(name)[1]
        stop = text.find(end_mark, m.end())
        if stop < 0:
            raise ValueError(f"section {name}: no closing {end_mark}")
        stop += len(end_mark)
        if text[stop:stop + 1] == "\n":
            stop += 1
        spans[name] = (m.start(), stop)
    return spans


def replace_sections(text: str, new: dict[str, str], order: Sequence[str]) -> str:
    """``text`` with the sections named in ``new`` replaced (or inserted in ``order``), all else kept."""
    for name, section in new.items():
        spans = split_sections(text)
        if name in spans:
            a, b = spans[name]
            text = text[:a] + section + text[b:]
            continue
        i = order.index(name) if name in order else len(order)
        later = [spans[n][0] for n in order[i + 1:] if n in spans]
        earlier = [spans[n][1] for n in order[:i] if n in spans]
        at = min(later) if later else (max(earlier) if earlier else len(text))
        sep = "" if at == 0 or text[:at].endswith("\n\n") else ("\n" if text[:at].endswith("\n") else "\n\n")
        text = text[:at] + sep + section + ("" if text[at:at + 1] in ("", "\n") else "\n") + text[at:]
    return text


# ---------------------------------------------------------------- running commands

def revision(root: Path = ROOT) -> str:
    """``git rev-parse --short HEAD``, ``+dirty`` when a file other than Markdown differs from it."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                          check=True).stdout.strip()
    status = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True,
                            check=True).stdout.splitlines()
    return head + ("+dirty" if any(not line.rstrip().endswith(".md") for line in status) else "")


class Runner:
    """Runs one topic's commands from the project root, logs them, keeps their output in ``work/logs``."""

    def __init__(self, topic: str, work: Path, say: Callable[[str], None] | None = None) -> None:
        self.topic, self.work = topic, work
        self.say = say or (lambda line: print(line, flush=True))
        self.commands: list[str] = []
        (work / "logs").mkdir(parents=True, exist_ok=True)

    def shown(self, argv: Sequence[str]) -> str:
        """The command as the section prints it: project-relative, the scratch folder as WORK."""
        text = shlex.join(argv)
        for path, short in ((str(self.work), "WORK"), (str(DATA), "../shared/data"), (str(ROOT) + "/", "")):
            text = text.replace(path, short)
        return text.replace(".venv/bin/poseidon", "poseidon", 1)

    def json(self, argv: Sequence[str], ok: Sequence[int] = (0,)) -> dict[str, Any]:
        """Run ``argv``; its stdout parsed as JSON.  :class:`CommandFailed` on another exit code."""
        shown = self.shown(argv)
        self.commands.append(shown)
        n = len(self.commands)
        out, err = (self.work / "logs" / f"{self.topic}-{n}.{s}" for s in ("stdout", "stderr"))
        self.say(f"[{self.topic} {n}] {shown}")
        t0 = time.monotonic()
        with out.open("w") as fo, err.open("w") as fe:
            proc = subprocess.Popen(list(argv), cwd=ROOT, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL)
            while True:
                try:
                    code = proc.wait(timeout=60)
                    break
                except subprocess.TimeoutExpired:
                    self.say(f"    {(time.monotonic() - t0) / 60:.0f} min: {last_line(err)}")
        self.say(f"    exit {code} after {time.monotonic() - t0:.0f} s")
        if code not in ok:
            tail = "\n".join(err.read_text(errors="replace").splitlines()[-20:])
            raise CommandFailed(f"{shown}: exit {code}; stderr in {err}:\n{tail}")
        try:
            data: dict[str, Any] = json.loads(out.read_text())
        except json.JSONDecodeError as exc:
            raise CommandFailed(f"{shown}: stdout ({out}) is not JSON: {exc}; stderr in {err}") from exc
        return data


def last_line(path: Path) -> str:
    """The last non-empty line of a file (progress bars split on carriage returns), at most 100 characters."""
    parts = [p.strip() for p in re.split(r"[\r\n]", path.read_text(errors="replace")[-4000:]) if p.strip()]
    return parts[-1][:100] if parts else "(no output yet)"


def poseidon() -> str:
    exe = ROOT / ".venv" / "bin" / "poseidon"
    return str(exe) if exe.exists() else (shutil.which("poseidon") or "poseidon")


# ---------------------------------------------------------------- topics: commands -> body

def measure_demo(r: Runner) -> str:
    return render_demo(r.json([poseidon(), "demo", "--json", "--out", str(r.work / "demo")], ok=(0, 1)))


def measure_laser(r: Runner) -> str:
    res = {}
    for log in LASER_LOGS:
        rec = r.work / f"{log}.mcap"
        r.json([poseidon(), "import", str(DATA / "radish" / f"{log}.clf.bz2"), "--out", str(rec), "--json"])
        res[log] = {}
        for tag, extra in (("", []), ("base_", ["--set", LASER_BASELINE])):
            run = r.work / f"{log}_{tag}run.mcap"
            run.unlink(missing_ok=True)
            res[log][f"{tag}run"] = r.json([poseidon(), "run", "--input", str(rec), "--out", str(run), "--config",
                                           "deploy/presets/laser2d.yaml", "--rate", "0", "--json"] + extra)
            res[log][f"{tag}eval"] = r.json([poseidon(), "eval", str(run), "--relations",
                                            str(DATA / "radish" / f"{log}.relations"), "--json"])
    return render_laser(res)


def measure_vpr_images(r: Runner) -> str:
    res = {}
    for name, (_, args) in IMAGE_SETS.items():
        argv = [poseidon(), "vpr"] + [str(DATA / a) if "/" in a else a for a in args] + ["--json"]
        res[name] = r.json(argv)
    return render_vpr_images(res)


def measure_vpr_missions(r: Runner) -> str:
    res = {}
    for seed in VPR_SEEDS:
        rec = r.work / f"sim20_s{seed}.mcap"
        if not rec.exists():
            r.json([poseidon(), "sim", "--minutes", "20", "--seed", str(seed), "--out", str(rec), "--json",
                    "--no-progress"])
        res[str(seed)] = r.json([poseidon(), "vpr", "--mission", str(rec), "--json"])
    return render_vpr_missions(res)


def measure_live(r: Runner) -> str:
    return render_live(r.json([sys.executable, "benchmarks/bench_live.py", "--rates", "1,4,8", "--cache-dir",
                               str(r.work / "live"), "--json"]))


def measure_recovery(r: Runner) -> str:
    return render_recovery(r.json([sys.executable, "benchmarks/bench_recovery.py", "--cache-dir",
                                   str(r.work / "recovery"), "--json"]))


def soak(minutes: int, seed: int) -> Callable[[Runner], str]:
    def measure(r: Runner) -> str:
        return render_soak(r.json([sys.executable, "benchmarks/bench_soak.py", "--minutes", str(minutes), "--seed",
                                   str(seed), "--cache-dir", str(r.work / "soak"), "--json"]))
    return measure


@dataclass(frozen=True)
class Topic:
    """One section of the file: what it measures, with what, how long it takes, what data it needs."""

    name: str
    heading: str
    minutes: int  # rough, on 2 shared cores
    data: tuple[str, ...]  # paths under ../shared/data that must exist
    commands: tuple[str, ...]  # what it runs, for --list and the "Not measured yet" section
    measure: Callable[[Runner], str]


TOPICS = (
    Topic("demo", "Demo", 5, (),
          ("poseidon demo --json --out WORK/demo",), measure_demo),
    Topic("laser", "Laser logs", 25, ("radish",),
          ("poseidon import ../shared/data/radish/LOG.clf.bz2 --out WORK/LOG.mcap --json",
           "poseidon run --input WORK/LOG.mcap --out WORK/LOG_run.mcap --config deploy/presets/laser2d.yaml --rate 0 --json",
           "poseidon eval WORK/LOG_run.mcap --relations ../shared/data/radish/LOG.relations --json",
           "# the same two with --set expmap.scan_graph.scan_poses=false (the previous default): WORK/LOG_base_run.mcap",
           "# LOG = aces, fr079"), measure_laser),
    Topic("vpr-images", "Place recognition: image sets", 20, ("vprbench_corridor", "nordland_trimmed"),
          ("poseidon vpr --ref ../shared/data/vprbench_corridor/ref --query ../shared/data/vprbench_corridor/query "
           "--gt ../shared/data/vprbench_corridor/ground_truth_new.npy --json",
           "poseidon vpr --ref ../shared/data/nordland_trimmed/summer --query ../shared/data/nordland_trimmed/winter "
           "--tolerance 1 --json"), measure_vpr_images),
    Topic("vpr-missions", "Place recognition: simulated missions", 90, (),
          ("poseidon sim --minutes 20 --seed S --out WORK/sim20_sS.mcap --json --no-progress",
           "poseidon vpr --mission WORK/sim20_sS.mcap --json", "# S = " + ", ".join(map(str, VPR_SEEDS))),
          measure_vpr_missions),
    Topic("live", "Live latency", 10, (),
          ("python benchmarks/bench_live.py --rates 1,4,8 --cache-dir WORK/live --json",), measure_live),
    Topic("recovery", "Live recovery from crashes", 35, (),
          ("python benchmarks/bench_recovery.py --cache-dir WORK/recovery --json",), measure_recovery),
    Topic("soak-60", "Speed: a 60-minute mission", 30, (),
          ("python benchmarks/bench_soak.py --minutes 60 --seed 11 --cache-dir WORK/soak --json",), soak(60, 11)),
    Topic("soak-180", "Speed: a 3-hour mission", 90, (),
          ("python benchmarks/bench_soak.py --minutes 180 --seed 7 --cache-dir WORK/soak --json",), soak(180, 7)),
)
BY_NAME = {t.name: t for t in TOPICS}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default="", help="comma-separated topics (default: every topic); --list names them")
    ap.add_argument("--list", action="store_true", help="list the topics, their data and rough duration, and exit")
    ap.add_argument("--work-dir", default="/tmp/poseidon-results", help="scratch folder (missions cached there)")
    ap.add_argument("--out", default=str(RESULTS), help="the file to write (default docs/RESULTS.md)")
    args = ap.parse_args(argv)
    if args.list:
        for t in TOPICS:
            missing = [d for d in t.data if not (DATA / d).exists()]
            print(f"{t.name:13} ~{t.minutes:3d} min  {t.heading}" + (f"  (absent: {', '.join(missing)})" if missing else ""))
        return 0
    names = [n for n in args.only.split(",") if n] or [t.name for t in TOPICS]
    unknown = [n for n in names if n not in BY_NAME]
    if unknown:
        print(f"unknown topic(s) {', '.join(unknown)}; known: {', '.join(BY_NAME)}", file=sys.stderr)
        return 2
    work, out = Path(args.work_dir), Path(args.out)
    rev = revision()
    new: dict[str, str] = {}
    for name in names:
        topic = BY_NAME[name]
        missing = [str(DATA / d) for d in topic.data if not (DATA / d).exists()]
        if missing:
            print(f"{name}: skipped, data absent: {', '.join(missing)}", flush=True)
            continue
        runner = Runner(name, work / name)
        machine = f"{os.cpu_count()} cores (load average {os.getloadavg()[0]:.1f} at the start)"
        print(f"{name}: ~{topic.minutes} min", flush=True)
        try:
            body = topic.measure(runner)
        except CommandFailed as exc:
            print(f"{name}: FAILED, {out} unchanged\n{exc}", file=sys.stderr)
            return 1
        stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
        new[name] = section_text(name, topic.heading, runner.commands, stamp, rev, body, machine)
    text = out.read_text() if out.exists() else PREAMBLE
    order = [t.name for t in TOPICS]
    spans = split_sections(text)
    filled = {**{t.name: unmeasured_section(t) for t in TOPICS if t.name not in spans and t.name not in new}, **new}
    out.write_text(replace_sections(text, filled, order))
    print(f"wrote {out}: {', '.join(new) or 'no topic measured'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
