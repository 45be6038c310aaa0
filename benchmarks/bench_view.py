"""The live view's cost: the same live run of a simulated mission with and without ``--view`` and a
headless Chromium polling the page.

- at 4x real time, ``--pairs`` times without and with the view, interleaved (the pairs alternate
  which goes first): frames dropped by
  the services' bounded queues (run summary ``dropped``) and the live latency p50 per stage (the
  live player's report; ``latency_n``: the outputs each p50 is taken over); per stage, the ratio of the median p50 with the view over the median without, and
  the range of the pairs' own ratios (one pair alone varies by 10-30 % on a
  2-core machine);
- in every run with the view: the CPU seconds of the view process (``view_cpu_s``: all of it,
  start-up included; ``view_stream_cpu_s``: from the first data to the run's end) and of the
  browser's processes (all under SCHED_IDLE) over the same span (``browser_stream_cpu_s``), the view's peak RSS
  (``/proc``), the bytes per second the hub delivered to it (per key when the view reports
  them) and the bytes per second it served to the browser;
- every run, with and without the view, takes ``--run-set`` settings; by default
  ``expmap.map_publish_every=10``: the default (a map every 100 events at least) publishes 3 maps
  in a 2-minute mission, too few for a p50, where 10 gives about 20 (and the view more maps to
  decode and send);
- screenshots: the page during the 1x run (``--shots DIR``/view_live.png) and ``poseidon view`` of
  that run's recording (view_demo.png).

    .venv/bin/python benchmarks/bench_view.py [--minutes 0.5] [--pairs 3] [--no-1x] [--shots docs/images]
        [--view-set view.nice=0] [--run-set expmap.map_publish_every=100]
"""
from __future__ import annotations

import argparse
import base64
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.eval.report.cdp import CHROMIUM, Browser  # noqa: E402
from tests.viewer.runs import free_port, view_state  # noqa: E402

CLI = [sys.executable, "-m", "launcher.cli"]


def _view_pid(launcher: int) -> int | None:
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text().rsplit(")", 1)[1].split()
            cmd = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if int(stat[1]) == launcher and b"view" in cmd:
            return int(d.name)
    return None


def _usage(pid: int) -> tuple[float, float]:
    """CPU seconds and peak RSS (MB) of ``pid``."""
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")
    hwm = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("VmHWM"))
    return cpu, int(hwm.split()[1]) / 1024


def _tree_cpu(root: int) -> float:
    """CPU seconds of ``root`` and its descendants alive now."""
    total, todo = 0.0, [root]
    while todo:
        pid = todo.pop()
        try:
            total += _usage(pid)[0]
            for task in Path(f"/proc/{pid}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, StopIteration):   # the process ended meanwhile
            continue
    return total


def _page(b: Browser, url: str) -> str:
    target = b.call("Target.createTarget", {"url": "about:blank"})
    s: str = b.call("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})["sessionId"]
    b.call("Page.enable", session=s)
    b.call("Emulation.setDeviceMetricsOverride", {"width": 1400, "height": 1080, "deviceScaleFactor": 1,
                                                  "mobile": False}, session=s)
    b.call("Page.navigate", {"url": url}, session=s)
    return s


def _shot(b: Browser, s: str, path: Path) -> None:
    path.write_bytes(base64.b64decode(b.call("Page.captureScreenshot", {"format": "png"}, session=s)["data"]))


def live_run(mission: Path, out: Path, rate: float, view: bool, shots: Path | None, work: Path,
             view_set: list[str] | None = None, run_set: list[str] | None = None,
             browser: bool = True) -> dict[str, Any]:
    """One live run; with ``view``, Chromium polls the page throughout unless not ``browser``
    (``view_set``: more ``--set KEY=VALUE`` of the run with the view, e.g. ``view.nice=0``;
    ``run_set``: of every run)."""
    cmd = [*CLI, "run", "--live", "mcap", "--input", str(mission), "--rate", str(rate), "--out", str(out), "--json",
           "--set", "live.lateness_ms=2000"]
    for item in run_set or []:
        cmd += ["--set", item]
    port = free_port()
    url = f"http://127.0.0.1:{port}/"
    if view:
        cmd += ["--view", str(port), "--set", "view.linger_s=8"]
        for item in view_set or []:
            cmd += ["--set", item]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    row: dict[str, Any] = {"rate": rate, "view": view, "browser": view and browser}
    if view:
        # the browser stands for the operator's own computer: under SCHED_IDLE from its start, every
        # process and thread it makes takes only CPU time the SLAM leaves
        page: Any = Browser(work / f"chromium-{rate}", idle=True) if browser else _NoBrowser()
        with page as b:
            while view_state(url) is None and proc.poll() is None:
                time.sleep(0.2)
            s = _page(b, url) if browser else ""
            first_t = None
            first_cpu = (0.0, 0.0)  # view, browser
            while not out.exists() and proc.poll() is None:
                st = view_state(url)
                if st and st["t"] > 0 and first_t is None:
                    first_t = time.monotonic()
                    pid = _view_pid(proc.pid)
                    first_cpu = (_usage(pid)[0] if pid is not None else 0.0, _tree_cpu(b.proc.pid) if browser else 0.0)
                if shots is not None and st and first_t and st["t"] > 0.6 * 30 and not (shots / "view_live.png").exists():
                    _shot(b, s, shots / "view_live.png")
                b.pump(0.5)
            pid = _view_pid(proc.pid)
            if pid is not None:
                row["view_stream_cpu_s"] = round(_usage(pid)[0] - first_cpu[0], 2)
            if browser:
                row["browser_stream_cpu_s"] = round(_tree_cpu(b.proc.pid) - first_cpu[1], 2)
            b.pump(3.0)
            st = view_state(url) or {}
            if pid is not None:
                row["view_cpu_s"], row["view_peak_rss_mb"] = (round(v, 1) for v in _usage(pid))
            served = st.get("view", {}).get("bytes_sent", 0)
            received = st.get("view", {}).get("received_bytes", 0)
            span = time.monotonic() - (first_t or t0)
            row["served_bytes"] = served
            row["served_kb_per_s"] = round(served / 1e3 / span, 1)
            row["bus_kb_per_s"] = round(received / 1e3 / span, 1)
            by_key = st.get("view", {}).get("received_by_key", {})
            row["bus_kb_per_s_by_key"] = {k: round(v / 1e3 / span, 1) for k, v in sorted(by_key.items(), key=lambda kv: -kv[1])}
            row["sampled_keys"] = st.get("view", {}).get("sampled", [])
            row["progress_reports"] = st.get("view", {}).get("progress_reports")
    stdout, _ = proc.communicate(timeout=600)
    summary = json.loads(stdout)
    row["wall_s"] = round(time.monotonic() - t0, 1)
    row["dropped"] = {n: sum(v.get("dropped", {}).values()) for n, v in summary["services"].items()
                      if isinstance(v.get("dropped"), dict)}
    lat = summary["services"]["live_player"].get("latency", {})
    row["p50_ms"] = {k: v.get("p50_ms") for k, v in lat.items()}
    row["latency_n"] = {k: v.get("n") for k, v in lat.items()}
    row["load_1min"] = round(os.getloadavg()[0], 2)
    return row


class _NoBrowser:
    """``--no-browser``: the view runs and only the benchmark's own state polls read it."""

    def __enter__(self) -> _NoBrowser:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def pump(self, seconds: float) -> None:
        time.sleep(seconds)


def ratios(plain: list[dict[str, Any]], viewed: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per stage: ``median`` (median p50 with the view over median p50 without) and ``min``/``max``
    of the pairs' own ratios."""
    out: dict[str, dict[str, float]] = {}
    for stage in plain[0]["p50_ms"]:
        a = [r["p50_ms"][stage] for r in plain if r["p50_ms"].get(stage)]
        b = [r["p50_ms"][stage] for r in viewed if r["p50_ms"].get(stage)]
        if not a or not b:
            continue
        pairs = [y / x for x, y in zip(a, b, strict=False)]
        out[stage] = {"median": round(statistics.median(b) / statistics.median(a), 3),
                      "min": round(min(pairs), 2), "max": round(max(pairs), 2)}
    return out


def demo_shot(run: Path, shots: Path, work: Path) -> None:
    """``poseidon view RUN.mcap`` at 80 % of the run, played to there."""
    port = free_port()
    url = f"http://127.0.0.1:{port}/"
    proc = subprocess.Popen([*CLI, "view", str(run), "--listen", str(port)], cwd=REPO, stderr=subprocess.DEVNULL)
    try:
        while view_state(url) is None:
            time.sleep(0.2)
        with Browser(work / "chromium-demo") as b:
            s = _page(b, url)
            b.pump(2.0)
            b.call("Runtime.evaluate", {"expression": "view.t = 0.8 * view.duration; $('slider').value = view.t;"},
                   session=s)
            b.pump(2.0)
            _shot(b, s, shots / "view_demo.png")
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=0.5, help="simulated mission length")
    ap.add_argument("--pairs", type=int, default=3, help="4x runs without and with the view, interleaved")
    ap.add_argument("--no-1x", action="store_true", help="skip the 1x run (view CPU, RSS and bytes)")
    ap.add_argument("--shots", type=Path, help="write view_live.png and view_demo.png here")
    ap.add_argument("--view-set", action="append", default=[], metavar="KEY=VALUE",
                    help="a setting of the runs with the view only, e.g. view.nice=0 (repeatable)")
    ap.add_argument("--no-browser", action="store_true", help="the runs with the view without a browser on the "
                    "page (the benchmark's own state polls only): the view's cost apart from the page's")
    ap.add_argument("--run-set", action="append", metavar="KEY=VALUE",
                    help="a setting of every run, with and without the view (repeatable; default: "
                         "expmap.map_publish_every=10)")
    args = ap.parse_args()
    run_set = args.run_set if args.run_set is not None else ["expmap.map_publish_every=10"]
    if not CHROMIUM.exists():
        print(f"bench_view: headless Chromium ({CHROMIUM}) is needed", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bench-view-") as tmp:
        work = Path(tmp)
        mission = work / "sim.mcap"
        subprocess.run([*CLI, "sim", "--minutes", str(args.minutes), "--seed", "3", "--out", str(mission),
                        "--no-progress"], cwd=REPO, check=True, stderr=subprocess.DEVNULL)
        if args.shots is not None:
            args.shots.mkdir(parents=True, exist_ok=True)
            (args.shots / "view_live.png").unlink(missing_ok=True)
        rows = []
        for i in range(args.pairs):
            for view in ((False, True) if i % 2 == 0 else (True, False)):   # ABBA: neither goes first always
                out = work / f"run4-{i}-{int(view)}.mcap"
                rows.append(live_run(mission, out, 4.0, view, None, work, args.view_set, run_set,
                                     browser=not args.no_browser))
                out.unlink(missing_ok=True)
        if not args.no_1x:
            rows.append(live_run(mission, work / "view1.mcap", 1.0, True, args.shots, work, args.view_set, run_set))
            if args.shots is not None:
                demo_shot(work / "view1.mcap", args.shots, work)
    fast = [r for r in rows if r["rate"] == 4.0]
    ratio = ratios([r for r in fast if not r["view"]], [r for r in fast if r["view"]])
    drops = {mode: sum(sum(r["dropped"].values()) for r in fast if r["view"] == view)
             for mode, view in (("without", False), ("with", True))}
    cost = {k: [r[k] for r in fast if k in r] for k in ("view_stream_cpu_s", "browser_stream_cpu_s", "view_cpu_s",
                                                          "bus_kb_per_s", "served_kb_per_s")}
    print(json.dumps({"run_set": run_set, "rows": rows, "p50_ratio_with_over_without": ratio, "dropped_at_4x": drops, "cost_at_4x": cost},
                     indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
