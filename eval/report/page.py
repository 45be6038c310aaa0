"""One self-contained HTML page from the loaded runs, their figures and the evaluation tables.

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
import re
from pathlib import Path
from typing import Any

import numpy as np
import plotly.io as pio
from plotly.offline import get_plotlyjs

from eval.report.data import RunView
from eval.report.figures import FigureSpec, build_figures

__all__ = ["render_report", "render_table", "table_id"]

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
details { margin: 8px 0; } summary { cursor: pointer; font-weight: bold; }
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


def table_id(name: str) -> str:
    """``table-`` + the name in lower case with runs of other characters as ``-``."""
    return "table-" + re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def _fmt(v: Any) -> tuple[str, bool]:
    """Cell text and whether it is numeric."""
    if v is None:
        return "&mdash;", False
    if isinstance(v, (bool, np.bool_)):
        return ("yes" if v else "no"), False
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}", True
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if not np.isfinite(f):
            return html.escape(str(f)), True
        if f != 0 and (abs(f) >= 1e6 or abs(f) < 1e-3):
            return f"{f:.3e}", True
        return f"{f:.4g}" if abs(f) < 1000 else f"{f:,.1f}", True
    if isinstance(v, (list, tuple)) and all(not isinstance(x, (dict, list, tuple)) for x in v):
        return html.escape(", ".join(_fmt(x)[0] if not isinstance(x, str) else x for x in v)), False
    if isinstance(v, (dict, list, tuple)):
        return f"<code>{html.escape(json.dumps(v, default=str))}</code>", False
    return html.escape(str(v)), False


def _cell(v: Any, tag: str = "td") -> str:
    text, num = _fmt(v)
    return f'<{tag} class="num">{text}</{tag}>' if num and tag == "td" else f"<{tag}>{text}</{tag}>"


def _scalar(v: Any) -> bool:
    return not isinstance(v, (dict, list, tuple)) or (
        isinstance(v, (list, tuple)) and all(not isinstance(x, (dict, list, tuple)) for x in v))


def _rows_table(rows: list[dict[str, Any]]) -> str:
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
    body = "".join("<tr>" + "".join(_cell(r.get(c)) for c in cols) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _matrix_table(d: dict[str, dict[str, Any]]) -> str:
    """Rows = outer keys, columns = the inner keys (e.g. metric -> {run A, run B})."""
    return _rows_table([{"": k, **v} for k, v in d.items()])


def _render_value(d: Any, depth: int) -> str:
    if isinstance(d, list) and d and all(isinstance(x, dict) for x in d) and all(_scalar(v) for x in d for v in x.values()):
        return _rows_table(d)
    if isinstance(d, dict):
        if d and all(isinstance(v, dict) and v and all(_scalar(x) for x in v.values()) for v in d.values()) and \
                len({tuple(v) for v in d.values()}) == 1 and len(d) > 1:
            return _matrix_table(d)
        scalars = {k: v for k, v in d.items() if _scalar(v)}
        out = []
        if scalars:
            rows = "".join(f"<tr><th>{html.escape(str(k))}</th>{_cell(v)}</tr>" for k, v in scalars.items())
            out.append(f"<table><tbody>{rows}</tbody></table>")
        level = min(depth + 4, 6)
        subs = [f'<div class="sub"><h{level}>{html.escape(str(k))}</h{level}>{_render_value(v, depth + 1)}</div>'
                for k, v in d.items() if not _scalar(v)]
        if subs:
            out.append(f'<div class="subs">{"".join(subs)}</div>')
        return "".join(out) if out else '<p class="note">(empty)</p>'
    if isinstance(d, list):
        if not d:
            return '<p class="note">(none)</p>'
        return "".join(_render_value(x, depth + 1) for x in d)
    return f"<p>{_fmt(d)[0]}</p>"


def render_table(name: str, data: dict[str, Any], folded: bool = False) -> str:
    """A named table (nested dicts become sub-tables; lists of dicts become row tables); ``folded``
    puts it in a closed ``<details>`` (the detail tables under a comparison)."""
    body = _render_value(data, 0)
    if folded:
        return (f'<div class="table" id="{table_id(name)}"><details><summary>{html.escape(name)} '
                f'(click to unfold)</summary>{body}</details></div>')
    return f'<div class="table" id="{table_id(name)}"><h3>{html.escape(name)}</h3>{body}</div>'


def _run_summary(runs: list[RunView], pr: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Plain counts read from the recordings (no metric: those are in the evaluation tables)."""
    out: dict[str, dict[str, Any]] = {}
    for r in runs:
        p = pr.get(r.label, {})
        out[r.label] = {
            "file": str(r.path), "size (MB)": round(r.path.stat().st_size / 1e6, 2),
            "duration (s)": round(r.duration_s, 2), "code revision": r.metadata.get("code_revision"),
            "tool": r.metadata.get("tool"), "mode": r.metadata.get("mode"),
            "messages": sum(r.counts.values()),
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


def _configuration(runs: list[RunView]) -> str:
    parts = []
    flat = [_flatten(r.metadata.get("config") or {}) for r in runs]
    if len(runs) > 1:
        keys = sorted({k for f in flat for k in f})
        diff = [{"field": k, **{r.label: f.get(k, "(absent)") for r, f in zip(runs, flat)}} for k in keys
                if len({json.dumps(f.get(k, "(absent)"), sort_keys=True, default=str) for f in flat}) > 1]
        if diff:
            parts.append(f'<div class="table" id="table-config-differences"><h3>Configuration fields that differ '
                         f'between the runs</h3>{_rows_table(diff)}</div>')
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
            rows = "".join(f"<tr><th>{html.escape(k)}</th>{_cell(v)}</tr>" for k, v in f.items())
            body += f"<details><summary>Full configuration of {html.escape(r.label)} ({len(f)} fields)</summary>" \
                    f"<table><tbody>{rows}</tbody></table></details>"
        parts.append(body)
    return "".join(parts)


def _figure_html(spec: FigureSpec, scripts: list[str]) -> str:
    notes = "".join(f'<p class="note">{html.escape(n)}</p>' for n in spec.notes)
    content = spec.html
    if spec.figure is not None:
        plot_id = f"{spec.id}-plot"
        height = spec.figure.layout.height or 450
        content = f'<div class="plot" id="{plot_id}" style="height:{int(height)}px"></div>'
        payload = pio.to_json(spec.figure, validate=False).replace("</", "<\\/")
        scripts.append(f'poseidonPlot("{plot_id}", {payload});')
    elif not content:
        content = '<p class="note">Not shown: the runs lack the data for this figure (see the notes).</p>'
    return (f'<section class="figure" id="{spec.id}"><h3>{html.escape(spec.title)}</h3>{content}'
            f'<p class="caption">{html.escape(spec.caption)}</p>{notes}</section>')


SECTIONS = [
    ("sec-trajectories", "Trajectories and map", ["fig-overlay-3d", "fig-projections", "fig-topology"]),
    ("sec-deviation", "Deviation from ground truth", ["fig-deviation-time", "fig-deviation-xy"]),
    ("sec-recognition", "Place recognition", ["fig-similarity", "fig-viewcells", "fig-pr"]),
    ("sec-evidence", "Evidence", ["fig-evidence"]),
]


def render_report(runs: list[RunView], tables: dict[str, dict], out_dir: str | Path, *,
                  unavailable: dict[str, str] | None = None, folded: list[str] | tuple[str, ...] = (), max_points: int = 3000, max_frames: int = 500,
                  min_gap_m: float = 10.0, title: str = "PoseidonSLAM run report",
                  extra_sections: list[tuple[str, str, list[FigureSpec]]] | None = None) -> dict[str, Any]:
    """Write ``out_dir/index.html``; return ``{"out", "bytes", "figures", "tables", "unavailable",
    "precision_recall"}`` (figure id -> ``shown`` or the reason it is not).

    ``extra_sections``: (section id, title, figures) drawn after the standard sections
    (e.g. :mod:`eval.report.benchmark`).

    ``tables``: name -> dict, rendered in order after the run summary (nested dicts become
    sub-tables, lists of dicts row tables); ``unavailable``: name -> why a table is missing;
    ``folded``: names of tables shown in a closed ``<details>``."""
    if not runs:
        raise ValueError("render_report: no runs given")
    unavailable = dict(unavailable or {})
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    specs, pr_summary = build_figures(runs, max_points=max_points, max_frames=max_frames, min_gap_m=min_gap_m)
    sections = list(SECTIONS)
    for sid, name, extra in extra_sections or []:
        specs = specs + list(extra)
        sections.append((sid, name, [x.id for x in extra]))
    by_id = {s.id: s for s in specs}
    scripts: list[str] = []
    keys = sorted({k for r in runs for k in r.counts})
    all_tables = {"Run summary (read from the recordings)": _run_summary(runs, pr_summary), **tables,
                  "Messages per key": {k: {r.label: r.counts.get(k, 0) for r in runs} for k in keys}}
    runs_list = "".join(
        f"<li><b>{html.escape(r.label)}</b>: <code>{html.escape(str(r.path))}</code>, {r.duration_s:.1f} s of "
        f"mission, code revision <code>{html.escape(str(r.metadata.get('code_revision', 'unknown')))}</code></li>"
        for r in runs)
    toc = ['<li><a href="#sec-tables">Tables</a></li>']
    toc += [f'<li><a href="#{sid}">{html.escape(name)}</a></li>' for sid, name, _ in sections]
    toc.append('<li><a href="#sec-config">Configuration and code revision</a></li>')
    body = [f"<h1>{html.escape(title)}</h1>", f"<ul>{runs_list}</ul>",
            "<p>How to read this page: the tables first give the numbers (what each run recorded, the "
            "event-evidence audit, the ON/OFF comparison of Table 5.4, loop closures of Tables 5.2-5.3 and the "
            "trajectory error); the figures then show where those numbers come from. Every figure is interactive "
            "(hover for values, drag to zoom, double-click to reset, click a legend entry to hide a series) and "
            "has a caption saying what to look for. Positions are metres in a world frame with x east, y north, "
            "z up.</p>",
            f'<nav><ol>{"".join(toc)}</ol></nav>', '<h2 id="sec-tables">Tables</h2>']
    for name, data in all_tables.items():
        body.append(render_table(name, data, folded=name in folded))
    for name, reason in unavailable.items():
        body.append(f'<div class="unavailable" id="{table_id(name)}"><h3>{html.escape(name)}</h3>'
                    f'<p>Unavailable: {html.escape(reason)}</p></div>')
    for sid, name, ids in sections:
        body.append(f'<h2 id="{sid}">{html.escape(name)}</h2>')
        body += [_figure_html(by_id[i], scripts) for i in ids]
    body.append('<h2 id="sec-config">Configuration and code revision</h2>')
    body.append(_configuration(runs))
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{CSS}</style>"
            f"<script>{get_plotlyjs()}</script><script>{JS_BOOT}</script></head>"
            f'<body data-figures-expected="{len(scripts)}" data-figures-rendered="0">'
            + "\n".join(body)
            + "<script>\n" + "\n".join(scripts) + "\n</script></body></html>")
    path = out_dir / "index.html"
    path.write_text(page, encoding="utf-8")
    figures = {s.id: ("shown" if (s.figure is not None or s.html) else "not shown: " + "; ".join(s.notes))
               for s in specs}
    log.debug("report: %s (%.1f MB, %d plots)", path, path.stat().st_size / 1e6, len(scripts))
    return {"out": str(path), "bytes": path.stat().st_size, "figures": figures, "tables": list(all_tables),
            "unavailable": unavailable, "precision_recall": _jsonable(pr_summary)}


def _jsonable(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (np.floating, np.integer)):
        return d.item()
    return d
