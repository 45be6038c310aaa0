"""The page adapts to the run: a laser run without ground truth (tests/eval/report/laser.py)
leads with its map, shows no table or section without data, is titled by its name, and its
long loop-closure table is summarised, folded and downloadable as CSV."""
from __future__ import annotations

import base64
import csv
import io
import json
import re
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from eval.report.cli import main as report_main
from eval.report.page import page_sections
from tests.eval.report.laser import loop_closures, write_imported, write_laser_run

LAPS = 2


@pytest.fixture(scope="module")
def laser_page(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, dict]:
    """``poseidon report`` of a laser run made from an ACES import with the laser2d preset (real eval tables)."""
    d = tmp_path_factory.mktemp("laser-run")
    write_imported(d / "aces.mcap")
    write_laser_run(d / "aces_run.mcap", d / "aces.mcap", laps=LAPS)
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert report_main([str(d / "aces_run.mcap"), "--out", str(d / "report"), "--json"]) == 0
    result = json.loads(buf.getvalue())
    return Path(result["out"]).read_text(encoding="utf-8"), result


def _body(page: str) -> str:
    """The page without its inlined plotly.js and figure data (scripts)."""
    return re.sub(r"<script>.*?</script>", "", page, flags=re.S)


def _sections(body: str) -> dict[str, str]:
    """Section id -> its content (up to the next ``<h2>``)."""
    parts = re.split(r'<h2 id="([^"]+)">', body)
    return {parts[i]: parts[i + 1] for i in range(1, len(parts), 2)}


def test_single_run_is_titled_by_its_name(laser_page: tuple[str, dict]) -> None:
    page, result = laser_page
    assert result["runs"][0]["label"] == "ACES laser run (laser2d)"
    assert "<title>ACES laser run (laser2d)</title>" in page
    assert re.search(r"<h1>(.*?)</h1>", page).group(1) == "ACES laser run (laser2d)"
    lede = re.search(r'<p class="lede">(.*?)</p>', page).group(1)
    assert "aces_run.mcap" in lede and "aces.clf.bz2" in lede and "preset laser2d" in lede
    assert "VPR Guard" not in _body(page)


def test_laser_run_leads_with_the_map(laser_page: tuple[str, dict]) -> None:
    page, result = laser_page
    assert result["sections"][0] == "sec-map"
    body = _body(page)
    first = re.search(r"<h2 ", body).start()
    assert '<section class="figure" id="fig-scan-maps">' in _sections(body)["sec-map"]
    assert body.index('id="fig-scan-maps"') > first  # the title and the table of contents, then the map
    assert body.index('id="fig-scan-maps"') < min(body.index('<div class="table"'), body.index('id="sec-tables"'))


def test_run_without_truth_shows_only_what_has_data(laser_page: tuple[str, dict]) -> None:
    page, result = laser_page
    body = _body(page)
    assert "not shown" not in body.lower()
    # every section has a figure or a table
    for sid, content in _sections(body).items():
        assert '<section class="figure"' in content or "<table" in content, sid
    # no table whose every cell is a dash (nor a row)
    tables = re.findall(r"<table>(.*?)</table>", body, flags=re.S)
    assert len(tables) >= 5
    for t in tables:
        cells = re.findall(r"<td[^>]*>(.*?)</td>", t, flags=re.S)
        assert cells and any(c not in ("&mdash;", "") for c in cells), t[:300]
        for row in re.findall(r"<tr>(.*?)</tr>", t, flags=re.S):
            data = re.findall(r"<td[^>]*>(.*?)</td>", row, flags=re.S)
            assert not data or any(c not in ("&mdash;", "") for c in data), row
    # figures without data are not on the page (they are listed, folded, under the title)
    for fid in ("fig-deviation-time", "fig-deviation-xy", "fig-pr", "fig-evidence", "fig-overlay-3d"):
        assert not result["figures"][fid].startswith("shown")
        assert f'id="{fid}"' not in body
    assert re.search(r'<details class="left-out"><summary>\d+ figure\(s\) left out', body)
    # what needs ground truth or a camera is not in the tables
    evaluation = body[body.index('id="table-evaluation-'):body.index('id="table-audit-')]
    for key in ("ate_rmse_m", "<th>true</th>", "<th>precision</th>", "opportunities", "sessions"):
        assert key not in evaluation, key
    assert "Audit (message sequences): ACES laser run (laser2d)" in body and "missing_images" not in body


def test_long_table_is_summarised_folded_and_downloadable(laser_page: tuple[str, dict]) -> None:
    page, _ = laser_page
    n = loop_closures(LAPS)
    assert n > 15
    m = re.search(r'<div class="long-table" data-rows="(\d+)">(.*?)</div>', _body(page), flags=re.S)
    assert m and int(m.group(1)) == n
    block = m.group(2)
    assert f"{n} rows" in re.search(r'<p class="table-summary">(.*?)</p>', block).group(1)
    head, full = block.split("<details>", 1)
    assert head.count("<tr>") == 1 + 5  # header + the first rows
    assert re.search(rf"<summary>All {n} rows</summary>", full)
    rows_html = re.search(r"</summary><table>(.*?)</table></details>", full, flags=re.S).group(1)
    assert rows_html.count("<tr>") == 1 + n
    uri = re.search(r'<a class="csv" download="[^"]+\.csv" href="data:text/csv;charset=utf-8;base64,([^"]+)"',
                    full).group(1)
    rows = list(csv.reader(io.StringIO(base64.b64decode(uri).decode("utf-8"))))
    assert rows[0] == ["event_seq", "current_exp", "matched_exp"]  # the columns without data are left out
    assert len(rows) - 1 == n
    assert [int(x) for x in rows[1]] == [30, 30, 0]


def test_relations_follow_the_map_and_runs_with_truth_lead_with_the_tables() -> None:
    names = ["Run summary", "Relations", "Evaluation"]
    figs = ["fig-topology", "fig-projections", "fig-scan-maps", "fig-pr"]
    laser = page_sections(True, names, ["Relations"], figs)
    assert [s.id for s in laser][:4] == ["sec-map", "sec-benchmark", "sec-trajectories", "sec-tables"]
    assert laser[0].figures == ["fig-scan-maps", "fig-topology"] and laser[2].figures == ["fig-projections"]
    assert laser[1].tables == ["Relations"] and laser[3].tables == ["Run summary", "Evaluation"]
    truth = page_sections(False, names, [], figs)
    assert truth[0].id == "sec-tables" and truth[0].tables == names
