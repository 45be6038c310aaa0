"""One self-contained HTML page from the loaded runs, their figures and the evaluation tables.

The page adapts to the runs: a figure or table without data is left out (the figures left
out are listed, folded, under the introduction), and so is a section with nothing left.
A single run is titled by its name (:func:`eval.report.data.run_label`).  Order
(:func:`page_sections`): runs with ground truth lead with the tables (the comparison of two
runs, the evaluation), then the trajectories, the deviation from the truth, place
recognition and the evidence; runs without ground truth, and laser runs, lead with the map
(laser point maps, topology), then the benchmark relations when given (``lead_tables``),
then the trajectories and loop closures over time, then the numbers.  The recording's messages and configuration close the
page.  Tables are drawn by :mod:`eval.report.tables` (long ones summarised and downloadable).

Self-contained: plotly.js is inlined once from the installed ``plotly`` package, images are
data URIs, nothing is fetched when the page is opened (no ``src``/``href`` to the network).
Every figure element has the id of :data:`eval.report.figures.FIGURE_IDS`; every table a
``table-*`` id.  The page sets ``document.body.dataset.figuresRendered`` to the number of
plots drawn (``figuresExpected`` is the total), so a headless browser can wait for them.
"""
from __future__ import annotations

import html
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import plotly.io as pio
from plotly.offline import get_plotlyjs

from eval.report.data import RunView
from eval.report.figures import FigureSpec, build_figures
from eval.report.naming import recording_name, run_details
from eval.report.tables import cell, render_table, rows_table, table_id

__all__ = ["render_report", "render_table", "table_id", "page_sections", "Section", "SUMMARY_TABLE",
           "MESSAGES_TABLE"]

log = logging.getLogger(__name__)

CSS = """
body { font-family: Helvetica, Arial, sans-serif; margin: 0 auto; max-width: 1400px; padding: 0 24px 48px;
       color: #1d2733; line-height: 1.45; }
h1 { margin-top: 24px; } h2 { border-bottom: 2px solid #d7dee7; padding-bottom: 4px; margin-top: 40px; }
nav ol { columns: 2; } nav a { color: #1f5f9f; }
.figure { margin: 18px 0 30px; } .plot { width: 100%; }
.caption { background: #f4f7fa; border-left: 4px solid #7aa6d6; padding: 8px 12px; margin: 6px 0; font-size: 14px; }
.note { color: #8a4b00; font-size: 14px; margin: 4px 0; }
table { border-collapse: collapse; margin: 8px 0 16px; font-size: 14px; }
th, td { border: 1px solid #d7dee7; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #eef2f6; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.subs { display: flex; flex-wrap: wrap; gap: 4px 28px; align-items: flex-start; }
.sub h4, .sub h5, .sub h6 { margin: 8px 0 2px; }
.unavailable { background: #fff4e5; border: 1px solid #f0c27b; padding: 8px 12px; margin: 8px 0; }
.gallery { display: flex; flex-wrap: wrap; gap: 10px; } .thumb { margin: 0; font-size: 12px; }
.thumb img { width: 192px; display: block; border: 1px solid #ccc; }
.scan-map { flex: 1 1 45%; max-width: 49%; } .scan-map img { width: 100%; image-rendering: pixelated; }
details { margin: 8px 0; } summary { cursor: pointer; font-weight: bold; }
.lede { color: #4a5868; margin-top: -8px; } .left-out summary { font-weight: normal; color: #4a5868; }
.table-summary { margin: 4px 0; } .table-head { margin: 4px 0 0; font-size: 13px; color: #4a5868; }
a.csv { font-size: 14px; color: #1f5f9f; }
code { background: #eef2f6; padding: 0 3px; }
"""

JS_BOOT = """
window.poseidonReport = {rendered: 0, failed: []};
function poseidonWebgl() {
  try { const c = document.createElement("canvas");
        return !!(window.WebGLRenderingContext && (c.getContext("webgl") || c.getContext("experimental-webgl"))); }
  catch (e) { return false; }
}
function poseidonDone() {
  window.poseidonReport.rendered += 1;
  document.body.dataset.figuresRendered = String(window.poseidonReport.rendered);
}
function poseidonPlot(id, spec) {
  const el = document.getElementById(id);
  if (spec.data.some(t => t.type === "scatter3d") && !poseidonWebgl()) {
    el.innerHTML = '<p class="note">This 3D view needs WebGL, which this browser does not offer; ' +
                   'the planar projections show the same data.</p>';
    window.poseidonReport.failed.push(id + ": no WebGL");
    poseidonDone();
    return;
  }
  Plotly.newPlot(el, spec.data, spec.layout, {responsive: true, displaylogo: false})
    .then(poseidonDone, function (err) {
      window.poseidonReport.failed.push(id + ": " + err);
      console.error("figure " + id + " failed: " + err);
      poseidonDone();
    });
}
"""


def _run_summary(runs: list[RunView], pr: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Plain counts read from the recordings (no metric: those are in the evaluation tables; the file,
    tool and code revision are in the page's header and its configuration section)."""
    out: dict[str, dict[str, Any]] = {}
    for r in runs:
        p = pr.get(r.label, {})
        out[r.label] = {
            "size (MB)": round(r.path.stat().st_size / 1e6, 2), "duration (s)": round(r.duration_s, 2),
            "messages": sum(r.counts.values()), "laser scans": r.counts.get("scan") or None,
            "frames (local_view_cells)": len(r.lvc_stamps), "view cells (LVC ids)": len(np.unique(r.lvc_id)),
            "experience events": len(r.event_stamps),
            "events per second": round(len(r.event_stamps) / r.duration_s, 3) if r.duration_s > 0 else None,
            "map nodes": len(r.node_ids), "map links": len(r.links), "loop-closure links": int(r.link_loop.sum()),
            "experience images": r.image_count,
            "PR average precision (sampled frames)": p.get("average_precision"),
            "PR best F1 (sampled frames)": p.get("best_f1"),
        }
    # transpose: rows = quantity, columns = run
    quantities = list(next(iter(out.values())).keys()) if out else []
    return {q: {label: out[label][q] for label in out} for q in quantities}


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(d, dict):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: d}


def _config_cell(v: Any) -> str:
    """A configuration value as set: an unset (null) or empty one spelled as JSON, not as a missing cell."""
    return f"<td><code>{html.escape(json.dumps(v))}</code></td>" if v is None or v in ([], {}, "") else cell(v)


def _configuration(runs: list[RunView]) -> str:
    parts = []
    flat = [_flatten(r.metadata.get("config") or {}) for r in runs]
    if len(runs) > 1:
        keys = sorted({k for f in flat for k in f})
        diff = [{"field": k, **{r.label: f.get(k, "(absent)") for r, f in zip(runs, flat)}} for k in keys
                if len({json.dumps(f.get(k, "(absent)"), sort_keys=True, default=str) for f in flat}) > 1]
        if diff:
            parts.append(f'<div class="table" id="table-config-differences"><h3>Configuration fields that differ '
                         f'between the runs</h3>{rows_table(diff, "configuration differences")}</div>')
        else:
            parts.append('<p>The runs have the same configuration.</p>')
    for r, f in zip(runs, flat):
        meta = {k: v for k, v in r.metadata.items() if k != "config"}
        if not r.metadata:
            parts.append(f'<p class="note">{html.escape(r.label)}: the recording has no <code>poseidon</code> '
                         'metadata record (configuration and code revision unknown).</p>')
            continue
        body = render_table(f"Run metadata: {r.label}", meta)
        if f:
            rows = "".join(f"<tr><th>{html.escape(k)}</th>{_config_cell(v)}</tr>" for k, v in f.items())
            body += f"<details><summary>Full configuration of {html.escape(r.label)} ({len(f)} fields)</summary>" \
                    f"<table><tbody>{rows}</tbody></table></details>"
        parts.append(body)
    return "".join(parts)




def _figure_html(spec: FigureSpec, scripts: list[str]) -> str:
    """The figure's element, or "" when it has nothing to draw (its notes say why: see ``left out``)."""
    notes = "".join(f'<p class="note">{html.escape(n)}</p>' for n in spec.notes)
    content = spec.html
    if spec.figure is not None:
        plot_id = f"{spec.id}-plot"
        height = spec.figure.layout.height or 450
        content = f'<div class="plot" id="{plot_id}" style="height:{int(height)}px"></div>'
        payload = pio.to_json(spec.figure, validate=False).replace("</", "<\\/")
        scripts.append(f'poseidonPlot("{plot_id}", {payload});')
    elif not content:
        return ""
    return (f'<section class="figure" id="{spec.id}"><h3>{html.escape(spec.title)}</h3>{content}'
            f'<p class="caption">{html.escape(spec.caption)}</p>{notes}</section>')


def _shown(spec: FigureSpec) -> bool:
    return spec.figure is not None or bool(spec.html)


@dataclass
class Section:
    """One ``<h2>`` section of the page: its figures (ids) and tables (names), tables first."""

    id: str
    title: str
    figures: list[str]
    tables: list[str]


SUMMARY_TABLE = "Run summary (read from the recordings)"
MESSAGES_TABLE = "Messages per key"
#: the figures of the map, first on a map-first page (laser maps when the run has scans), and those that
#: follow the benchmark relations there
MAP_FIGURES = ["fig-scan-maps", "fig-topology"]
TRACK_FIGURES = ["fig-loop-closures", "fig-projections", "fig-overlay-3d"]


def page_sections(map_first: bool, table_names: list[str], lead_tables: list[str], figure_ids: list[str]) -> list[Section]:
    """The page's sections in order (module docstring): ``table_names`` the tables besides the lead
    ones, the run summary and the messages; ``figure_ids`` every figure built (the benchmark's too)."""
    lead = [t for t in lead_tables if t in table_names]
    rest = [t for t in table_names if t not in lead and t != MESSAGES_TABLE]
    closing = Section("sec-config", "Recording and configuration", [], [MESSAGES_TABLE])
    recognition = Section("sec-recognition", "Place recognition", ["fig-similarity", "fig-viewcells", "fig-pr"], [])
    deviation = Section("sec-deviation", "Deviation from ground truth", ["fig-deviation-time", "fig-deviation-xy"], [])
    evidence = Section("sec-evidence", "Evidence", ["fig-evidence"], [])
    if map_first:
        return [Section("sec-map", "Map", [f for f in MAP_FIGURES if f in figure_ids], []),
                Section("sec-benchmark", "Benchmark relations", [], lead),
                Section("sec-trajectories", "Trajectories and loop closures",
                        [f for f in TRACK_FIGURES if f in figure_ids], []),
                Section("sec-tables", "Numbers", [], rest), deviation, recognition, evidence, closing]
    extra = [f for f in figure_ids if f in ("fig-scan-maps", "fig-loop-closures")]
    return [Section("sec-tables", "Tables", [], lead + rest),
            Section("sec-trajectories", "Trajectories and map", ["fig-overlay-3d", "fig-projections", "fig-topology"],
                    []),
            deviation, recognition, evidence, Section("sec-laser", "Laser maps and loop closures", extra, []), closing]


def _title(runs: list[RunView]) -> str:
    """One run: its label; several: their labels joined by "vs", after the recording they share."""
    if len(runs) == 1:
        return runs[0].label
    names = {recording_name(r.run) for r in runs}
    labels = " vs ".join(r.label for r in runs)
    return f"{names.pop()}: {labels}" if len(names) == 1 else labels


def _map_first(runs: list[RunView]) -> bool:
    """Lead with the map: no run has ground truth, or a run carries laser scans."""
    return not any(len(r.truth) for r in runs) or any(r.counts.get("scan") for r in runs)


def _header(runs: list[RunView], title: str, left_out: list[FigureSpec], comparison: bool) -> list[str]:
    """Title, what the runs are, how to read the page, and the figures left out for lack of data."""
    out = [f"<h1>{html.escape(title)}</h1>"]
    if len(runs) == 1:
        out.append(f'<p class="lede">{html.escape(run_details(runs[0].run))}</p>')
    else:
        out.append("<ul>" + "".join(f"<li><b>{html.escape(r.label)}</b>: {html.escape(run_details(r.run))}</li>"
                                    for r in runs) + "</ul>")
    how = ("Every figure is interactive (hover for values, drag to zoom, double-click to reset, click a legend "
           "entry to hide a series) and has a caption saying what to look for. Positions are metres in a world "
           "frame with x east, y north, z up.")
    if comparison:
        how = ("The tables first give the numbers (what each run recorded, the ON/OFF comparison of Table 5.4, "
               "the loop closures of Tables 5.2-5.3 and the trajectory error, the event-evidence audit); the "
               "figures then show where those numbers come from. " + how)
    out.append(f"<p>{how}</p>")
    if left_out:
        items = "".join(f"<li>{html.escape(s.title)}: {html.escape('; '.join(s.notes) or 'no data')}</li>"
                        for s in left_out)
        out.append(f'<details class="left-out"><summary>{len(left_out)} figure(s) left out: the run lacks their '
                   f"data</summary><ul>{items}</ul></details>")
    return out


def render_report(runs: list[RunView], tables: dict[str, Any], out_dir: str | Path, *,
                  unavailable: dict[str, str] | None = None, folded: list[str] | tuple[str, ...] = (),
                  max_points: int = 3000, max_frames: int = 500, min_gap_m: float = 10.0, title: str | None = None,
                  extra_figures: list[FigureSpec] | tuple[FigureSpec, ...] = (),
                  lead_tables: list[str] | tuple[str, ...] = (), map_first: bool | None = None) -> dict[str, Any]:
    """Write ``out_dir/index.html``; return ``{"out", "bytes", "figures", "tables", "sections", "unavailable",
    "precision_recall"}`` (figure id -> ``shown`` or the reason it is not; the names of the tables and the
    ids of the sections on the page, in page order).

    ``tables``: name -> value (:mod:`eval.report.tables`), after the run summary; ``unavailable``: name ->
    why a table is missing; ``folded``: names of tables shown in a closed ``<details>``; ``lead_tables``:
    tables shown first (after the map on a map-first page); ``extra_figures``: more figures (the laser
    maps and loop closures of :mod:`eval.report.benchmark`); ``title``: default the run's label for one
    run, the labels joined by "vs" for several (after the name of the recording they were made from,
    when they share it); ``map_first``: lead with the map (default: no run has ground truth
    or one has laser scans)."""
    if not runs:
        raise ValueError("render_report: no runs given")
    unavailable = dict(unavailable or {})
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    specs, pr_summary = build_figures(runs, max_points=max_points, max_frames=max_frames, min_gap_m=min_gap_m)
    specs = specs + list(extra_figures)
    by_id = {s.id: s for s in specs}
    keys = sorted({k for r in runs for k in r.counts})
    all_tables = {SUMMARY_TABLE: _run_summary(runs, pr_summary), **tables,
                  MESSAGES_TABLE: {k: {r.label: r.counts.get(k, 0) for r in runs} for k in keys}}
    if map_first is None:
        map_first = _map_first(runs)
    sections = page_sections(map_first, list(all_tables) + list(unavailable), list(lead_tables), list(by_id))
    title = title or _title(runs)
    scripts: list[str] = []
    parts: list[tuple[Section, str]] = []
    shown_tables: list[str] = []
    for sec in sections:
        blocks = []
        for name in sec.tables:
            if name in unavailable:
                blocks.append(f'<div class="unavailable" id="{table_id(name)}"><h3>{html.escape(name)}</h3>'
                              f"<p>Unavailable: {html.escape(unavailable[name])}</p></div>")
            elif name in all_tables:
                block = render_table(name, all_tables[name], folded=name in folded)
                if block:
                    blocks.append(block)
                    shown_tables.append(name)
        blocks += [b for b in (_figure_html(by_id[f], scripts) for f in sec.figures if f in by_id) if b]
        if sec.id == "sec-config":
            blocks.append(_configuration(runs))
        if blocks:
            parts.append((sec, "".join(blocks)))
    left_out = [s for s in specs if not _shown(s)]
    body = _header(runs, title, left_out, comparison=len(runs) > 1)
    body.append("<nav><ol>" + "".join(f'<li><a href="#{sec.id}">{html.escape(sec.title)}</a></li>'
                                      for sec, _ in parts) + "</ol></nav>")
    for sec, content in parts:
        body.append(f'<h2 id="{sec.id}">{html.escape(sec.title)}</h2>{content}')
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{CSS}</style>"
            f"<script>{get_plotlyjs()}</script><script>{JS_BOOT}</script></head>"
            f'<body data-figures-expected="{len(scripts)}" data-figures-rendered="0">'
            + "\n".join(body)
            + "<script>\n" + "\n".join(scripts) + "\n</script></body></html>")
    path = out_dir / "index.html"
    path.write_text(page, encoding="utf-8")
    figures = {s.id: ("shown" if _shown(s) else "not shown: " + "; ".join(s.notes)) for s in specs}
    log.debug("report: %s (%.1f MB, %d plots)", path, path.stat().st_size / 1e6, len(scripts))
    return {"out": str(path), "bytes": path.stat().st_size, "figures": figures, "tables": shown_tables,
            "sections": [sec.id for sec, _ in parts], "unavailable": unavailable,
            "precision_recall": _jsonable(pr_summary)}


def _jsonable(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (np.floating, np.integer)):
        return d.item()
    return d
