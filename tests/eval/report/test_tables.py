"""The report's tables (eval/report/tables.py): what is left out, and how a long table is shown."""
from __future__ import annotations

import base64
import csv
import io
import re

from eval.report.tables import EMPTY, HEAD_ROWS, LONG_ROWS, prune, render_table, rows_table


def test_missing_values_rows_and_columns_are_left_out() -> None:
    assert prune({"ate": {"map": None, "dead_reckoning": None}, "rpe": None, "table": []}) is EMPTY
    assert render_table("Evaluation", {"ate": {"map": None}, "drift": float("nan")}) == ""
    rows = [{"seq": 1, "d_gt_m": None, "label": None}, {"seq": None, "d_gt_m": None, "label": None},
            {"seq": 3, "d_gt_m": None, "label": "TP"}]
    assert prune(rows) == [{"seq": 1, "label": None}, {"seq": 3, "label": "TP"}]
    # a labelled row (metric, run A, run B) with no value in any run goes
    metrics = [{"metric": "ATE (m)", "A": 0.4, "B": None}, {"metric": "nodes", "A": 3, "B": 4},
               {"metric": "recall", "A": None, "B": None}]
    assert prune(metrics) == metrics[:2]
    # a matrix (quantity x run): a row missing in every run goes, a row missing in one run stays
    matrix = {"nodes": {"A": 3, "B": 4}, "PR F1": {"A": None, "B": None}, "ATE": {"A": 0.5, "B": None}}
    assert prune(matrix) == {"nodes": {"A": 3, "B": 4}, "ATE": {"A": 0.5, "B": None}}
    assert prune({"events": 0, "closures": {"accepted": 0}}) == {"events": 0, "closures": {"accepted": 0}}


def test_long_table_shows_its_head_and_folds_the_rest_with_a_csv_of_every_row() -> None:
    n = LONG_ROWS + 25
    rows = [{"id": i, "error_m": i / 10, "label": "TP" if i % 4 else "FP", "note": f'a, "quoted" {i}'}
            for i in range(n)]
    html = rows_table(rows, "Loop closures: run A")
    assert f'data-rows="{n}"' in html
    summary = re.search(r'<p class="table-summary">(.*?)</p>', html).group(1)
    assert f"{n} rows" in summary and "id: 0 to 39" in summary and "median 1.95" in summary
    assert "TP 30" in summary and "FP 10" in summary
    head, full = html.split("<details>", 1)
    assert head.count("<tr>") == 1 + HEAD_ROWS and full.count("<tr>") == 1 + n
    m = re.search(r'download="loop-closures-run-a\.csv" href="data:text/csv;charset=utf-8;base64,([^"]+)"', html)
    back = list(csv.DictReader(io.StringIO(base64.b64decode(m.group(1)).decode("utf-8"))))
    assert len(back) == n
    assert back[7] == {"id": "7", "error_m": "0.7", "label": "TP", "note": 'a, "quoted" 7'}
    short = rows_table(rows[:LONG_ROWS], "short")
    assert "<details>" not in short and short.count("<tr>") == 1 + LONG_ROWS
