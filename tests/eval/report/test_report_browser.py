"""The report opened in a real headless browser: Chromium from the system packages
(``deploy/setup.sh`` installs it as root with apt-get), driven over the DevTools pipe."""
from __future__ import annotations

import io
import json
import os
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from eval.report import FIGURE_IDS
from eval.report.cli import main as report_main
from tests.eval.report.cdp import CHROMIUM
from tests.eval.report.handmade import write_handmade_run
from tests.eval.report.test_report import _without_eval_tables

pytestmark = pytest.mark.skipif(
    not os.access(CHROMIUM, os.X_OK),
    reason=f"Chromium is not installed at {CHROMIUM}: deploy/setup.sh installs the Debian package when run as "
           "root with apt-get (its log is named in the setup output); install it with "
           "'apt-get install chromium' to run this test")


def test_report_renders_in_headless_chromium(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from PIL import Image

    from tests.eval.report.browser import check_page
    on, off = tmp_path / "on.mcap", tmp_path / "off.mcap"
    write_handmade_run(on, guard_on=True)
    write_handmade_run(off, guard_on=False, event_every_m=1.0, false_closure=True)
    _without_eval_tables(monkeypatch)  # figures only: tables tested apart
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert report_main([str(on), str(off), "--out", str(tmp_path / "report"), "--json"]) == 0
    page = Path(json.loads(buf.getvalue())["out"])

    seen = check_page(page, tmp_path)

    # every plot drawn, none failed, no console error or uncaught exception
    assert seen.expected == len(FIGURE_IDS) - 1 and seen.rendered == seen.expected, seen
    assert seen.failed == []
    assert seen.console_errors == []
    # every figure in the rendered DOM, each plot drawn by plotly with its traces, the 3D one on a canvas
    for fid in FIGURE_IDS:
        assert fid in seen.ids, fid
    for fid in FIGURE_IDS[:-1]:
        plot = seen.plots[f"{fid}-plot"]
        assert plot["plotly"] and plot["svg"] >= 1 and plot["traces"] >= 1, (fid, plot)
        assert plot["width"] > 600 and plot["height"] > 300, (fid, plot)
    assert seen.plots["fig-overlay-3d-plot"]["canvas"] >= 1
    assert sum(i.startswith("evidence-") for i in seen.ids) == 24
    # offline: the page asked for nothing but itself and its data: URIs
    assert seen.requests and seen.requests[0] == page.resolve().as_uri()
    assert all(u.startswith(("file://", "data:")) for u in seen.requests), \
        [u for u in seen.requests if not u.startswith(("file://", "data:"))]
    # a real screenshot of the whole page: a PNG, page-sized, with colourful content
    assert seen.screenshot[:8] == b"\x89PNG\r\n\x1a\n"
    img = Image.open(io.BytesIO(seen.screenshot)).convert("RGB")
    assert img.width >= 1300 and img.height >= 5000 and img.height == pytest.approx(seen.height_px, abs=5)
    small = np.asarray(img.resize((img.width // 4, img.height // 4)))
    assert len(np.unique(small.reshape(-1, 3), axis=0)) > 500  # plots, images, text: not a blank page
    (tmp_path / "report" / "screenshot.png").write_bytes(seen.screenshot)
