"""The report's tables: what of a result is shown (:func:`prune`) and how (:func:`render_table`).

A table is a named value: nested dicts become sub-tables, lists of flat dicts become row
tables, a dict of equally keyed dicts a matrix (rows = outer keys, columns = inner keys).

- What is shown: a value that is missing (``None``, an empty dict) is left out, and so is a
  row or column of a row table, or a row of a matrix, whose every cell is missing (but for
  a row's leading label, e.g. a metric's name); a table
  with nothing left is not drawn at all (:func:`prune` returns :data:`EMPTY`).  An empty
  list or dict is missing too (a count beside it says "none").
- Long row tables (more than :data:`LONG_ROWS` rows): the page shows the count, a few
  statistics of the columns (the range of an integer column, range and median of a real
  one, counts of a column of a few values) and the first :data:`HEAD_ROWS` rows; the whole table follows in a closed
  ``<details>`` and as a CSV download (a ``data:`` URI link: the page stays one file).
"""
from __future__ import annotations

import base64
import csv
import html
import io
import json
import re
from typing import Any

import numpy as np

__all__ = ["EMPTY", "LONG_ROWS", "HEAD_ROWS", "prune", "render_table", "table_id", "rows_table", "cell", "to_csv"]

#: row tables longer than this are summarised, the full table collapsed and downloadable
LONG_ROWS = 15
#: rows shown above a summarised table's collapsed full version
HEAD_ROWS = 5


class _Empty:
    """Marks a value with nothing to show."""

    def __repr__(self) -> str:
        return "EMPTY"


EMPTY: Any = _Empty()


def table_id(name: str) -> str:
    """``table-`` + the name in lower case with runs of other characters as ``-``."""
    return "table-" + re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def _scalar(v: Any) -> bool:
    return not isinstance(v, (dict, list, tuple)) or (
        isinstance(v, (list, tuple)) and all(not isinstance(x, (dict, list, tuple)) for x in v))


def _is_rows(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v) and \
        all(_scalar(y) for x in v for y in x.values())


def _is_matrix(d: Any) -> bool:
    return isinstance(d, dict) and len(d) > 1 and all(
        isinstance(v, dict) and v and all(_scalar(x) for x in v.values()) for v in d.values()) and \
        len({tuple(v) for v in d.values()}) == 1


def _missing(v: Any) -> bool:
    """None, NaN, an empty string or container, or a list of missing values."""
    return v is None or v is EMPTY or v == "" or (isinstance(v, float) and np.isnan(v)) or \
        (isinstance(v, (list, tuple, dict)) and not v) or \
        (isinstance(v, (list, tuple)) and all(_missing(x) for x in v))


def prune(value: Any) -> Any:
    """``value`` without what is missing (module docstring); :data:`EMPTY` when nothing is left."""
    if _missing(value):
        return EMPTY
    if _is_rows(value):
        cols = [c for c in dict.fromkeys(k for r in value for k in r) if any(not _missing(r.get(c)) for r in value)]
        # a row's values: every cell but a leading label (a string, e.g. the metric's name)
        rows = [{c: r.get(c) for c in cols} for r in value
                if any(not _missing(r.get(c)) for c in (cols[1:] if isinstance(r.get(cols[0]), str) else cols))]
        return rows if rows else EMPTY
    if _is_matrix(value):
        kept = {k: v for k, v in value.items() if any(not _missing(x) for x in v.values())}
        return kept if kept else EMPTY
    if isinstance(value, dict):
        out = {k: p for k, p in ((k, prune(v)) for k, v in value.items()) if p is not EMPTY}
        return out if out else EMPTY
    if isinstance(value, list) and value and not _scalar(value):
        items = [p for p in (prune(x) for x in value) if p is not EMPTY]
        return items if items else EMPTY
    return value


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


def cell(v: Any, tag: str = "td") -> str:
    """One table cell of ``v`` (numbers right-aligned)."""
    text, num = _fmt(v)
    return f'<{tag} class="num">{text}</{tag}>' if num and tag == "td" else f"<{tag}>{text}</{tag}>"


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    return list(dict.fromkeys(k for r in rows for k in r))


def _plain_table(rows: list[dict[str, Any]], cols: list[str]) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
    body = "".join("<tr>" + "".join(cell(r.get(c)) for c in cols) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _csv_value(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v, default=str)
    if isinstance(v, (np.generic,)):
        return v.item()
    return v


def to_csv(rows: list[dict[str, Any]]) -> str:
    """The rows as CSV text: a header of the columns, then one line per row (missing cells empty)."""
    cols = _columns(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([_csv_value(r.get(c)) for c in cols])
    return buf.getvalue()


def _column_stats(rows: list[dict[str, Any]], cols: list[str], most: int = 4) -> list[str]:
    """A few one-line statistics: range and median of numeric columns, counts of a column of few values."""
    out: list[str] = []
    for c in cols:
        vals = [r.get(c) for r in rows if r.get(c) is not None]
        if not vals or c == "":
            continue
        if all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
               for v in vals):
            a = np.asarray(vals, dtype=np.float64)
            integer = all(isinstance(v, (int, np.integer)) for v in vals)  # ids and counts: their range
            lo, hi = (int(a.min()), int(a.max())) if integer else (float(a.min()), float(a.max()))
            out.append(f"{html.escape(str(c))}: {_fmt(lo)[0]} to {_fmt(hi)[0]}"
                       + ("" if integer else f", median {_fmt(float(np.median(a)))[0]}"))
        elif all(isinstance(v, (str, bool, np.bool_)) for v in vals) and len(set(vals)) <= 6:
            counts = {str(_fmt(v)[0]): 0 for v in vals}
            for v in vals:
                counts[str(_fmt(v)[0])] += 1
            out.append(f"{html.escape(str(c))}: " + ", ".join(f"{k} {n:,}" for k, n in counts.items()))
        if len(out) >= most:
            break
    return out


def rows_table(rows: list[dict[str, Any]], name: str = "table") -> str:
    """A row table; longer than :data:`LONG_ROWS`: summarised, collapsed and downloadable (module docstring)."""
    cols = _columns(rows)
    if len(rows) <= LONG_ROWS:
        return _plain_table(rows, cols)
    stats = _column_stats(rows, cols)
    uri = "data:text/csv;charset=utf-8;base64," + base64.b64encode(to_csv(rows).encode("utf-8")).decode()
    fname = table_id(name)[len("table-"):] or "table"
    summary = f"{len(rows):,} rows" + (" &middot; " + " &middot; ".join(stats) if stats else "")
    return (f'<div class="long-table" data-rows="{len(rows)}"><p class="table-summary">{summary}</p>'
            f'<p class="table-head">First {HEAD_ROWS} rows:</p>{_plain_table(rows[:HEAD_ROWS], cols)}'
            f'<details><summary>All {len(rows):,} rows</summary>{_plain_table(rows, cols)}</details>'
            f'<p><a class="csv" download="{fname}.csv" href="{uri}">Download all {len(rows):,} rows as CSV</a></p>'
            f"</div>")


def _render_value(d: Any, depth: int, name: str) -> str:
    if _is_rows(d):
        return rows_table(d, name)
    if _is_matrix(d):
        return rows_table([{"": k, **v} for k, v in d.items()], name)
    if isinstance(d, dict):
        scalars = {k: v for k, v in d.items() if _scalar(v)}
        out = []
        if scalars:
            rows = "".join(f"<tr><th>{html.escape(str(k))}</th>{cell(v)}</tr>" for k, v in scalars.items())
            out.append(f"<table><tbody>{rows}</tbody></table>")
        level = min(depth + 4, 6)
        subs = [f'<div class="sub"><h{level}>{html.escape(str(k))}</h{level}>'
                f'{_render_value(v, depth + 1, f"{name} {k}")}</div>'
                for k, v in d.items() if not _scalar(v)]
        if subs:
            out.append(f'<div class="subs">{"".join(subs)}</div>')
        return "".join(out) if out else '<p class="note">(empty)</p>'
    if isinstance(d, list):
        if not d:
            return '<p class="note">(none)</p>'
        return "".join(_render_value(x, depth + 1, name) for x in d)
    return f"<p>{_fmt(d)[0]}</p>"


def render_table(name: str, data: Any, folded: bool = False) -> str:
    """A named table (module docstring), pruned first; "" when nothing is left to show.  ``folded``
    puts it in a closed ``<details>`` (the detail tables under a comparison)."""
    data = prune(data)
    if data is EMPTY:
        return ""
    body = _render_value(data, 0, name)
    if folded:
        return (f'<div class="table" id="{table_id(name)}"><details><summary>{html.escape(name)} '
                f'(click to unfold)</summary>{body}</details></div>')
    return f'<div class="table" id="{table_id(name)}"><h3>{html.escape(name)}</h3>{body}</div>'
