"""``poseidon report`` on small hand-made runs whose content is known (tests/eval/report/handmade.py)."""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import eval.report.cli as report_cli
from eval.report import FIGURE_IDS, RunView, render_report, run_view, table_id
from eval.report.cli import main as report_main
from eval.report.figures import build_figures, frame_similarity, precision_recall
from eval.rundata import RunData
from eval.rundata import load_run as load_eval_run
from tests.eval.report.handmade import PLACES, T0, dead_reckoning_ned, square_ned, write_handmade_run

TABLE_FUNCTIONS = ("evaluate_run", "audit_run", "compare_runs")


def load_run(path: Path) -> RunView:
    """What the report draws of one recording."""
    return run_view(load_eval_run(path))


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("report-runs")
    on, off = d / "guard_on.mcap", d / "guard_off.mcap"
    write_handmade_run(on, guard_on=True)
    write_handmade_run(off, guard_on=False, event_every_m=1.0, false_closure=True)
    return on, off


def _left_out(*args: Any, **kwargs: Any) -> dict:
    raise RuntimeError("left out of this test")


def _without_eval_tables(monkeypatch: pytest.MonkeyPatch) -> None:
    """The eval table functions fail (figures only; the tables are tested apart)."""
    for name in TABLE_FUNCTIONS:
        monkeypatch.setattr(report_cli, name, _left_out)


@pytest.fixture(scope="module")
def page(runs: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("report-page")
    with pytest.MonkeyPatch.context() as mp:
        _without_eval_tables(mp)
        import io
        from contextlib import redirect_stdout
        buf = io.StringIO()
        with redirect_stdout(buf):
            rc = report_main([str(runs[0]), str(runs[1]), "--out", str(out), "--json"])
    assert rc == 0
    return out / "index.html", json.loads(buf.getvalue())


# --------------------------------------------------------------------------- the page


def test_page_is_written_and_self_contained(page: tuple[Path, dict]) -> None:
    from plotly.offline import get_plotlyjs
    path, result = page
    full = path.read_text(encoding="utf-8")
    assert result["out"] == str(path) and result["bytes"] == path.stat().st_size
    assert full.count(get_plotlyjs()) == 1  # plotly.js inlined exactly once, as shipped
    html = full.replace(get_plotlyjs(), "")  # (its own code mentions URLs; the browser test checks requests)
    # nothing is fetched: no script/img/link/iframe pointing anywhere but data: URIs
    refs = re.findall(r"<(?:script|img|link|iframe|source|video|audio)\b[^>]*\b(?:src|href)\s*=\s*[\"']?([^\"' >]+)",
                      html, flags=re.I)
    assert refs and all(r.startswith("data:") for r in refs), [r for r in refs if not r.startswith("data:")][:5]
    assert not re.search(r"<script[^>]+src=", html, flags=re.I)
    assert not re.search(r"(?:src|href)\s*=\s*[\"']?https?://", html, flags=re.I)
    assert path.stat().st_size < 8_000_000  # plotly.js (~4.8 MB) plus a few hundred KB of data


def test_every_figure_has_its_id_a_caption_and_its_data(page: tuple[Path, dict]) -> None:
    path, result = page
    html = path.read_text(encoding="utf-8")
    assert result["figures"] == {fid: "shown" for fid in FIGURE_IDS}
    for fid in FIGURE_IDS:
        m = re.search(rf'<section class="figure" id="{fid}">(.*?)</section>', html, flags=re.S)
        assert m, fid
        assert '<p class="caption">' in m.group(1), fid
    for fid in FIGURE_IDS[:-1]:  # every one but the image gallery is a plotly figure
        assert f'poseidonPlot("{fid}-plot", ' in html
    assert html.count('<img id="evidence-') == 24  # 12 evenly spaced evidence images per run
    assert 'data-figures-expected="8"' in html


def test_tables_and_configuration_are_on_the_page(page: tuple[Path, dict]) -> None:
    path, result = page
    html = path.read_text(encoding="utf-8")
    assert f'id="{table_id("Run summary (read from the recordings)")}"' in html
    # eval tables failing here: named on the page with the reason
    assert len(result["unavailable"]) == 5
    for name, reason in result["unavailable"].items():
        assert f'id="{table_id(name)}"' in html and "failed: RuntimeError: left out of this test" in reason
    assert "Unavailable: eval.compare.compare_runs failed" in html
    # configuration: the one field that differs, and the code revision of each run
    assert 'id="table-config-differences"' in html
    diff = re.search(r'id="table-config-differences">(.*?)</div>', html, flags=re.S).group(1)
    assert "vpr_guard.require_vpr_for_event" in diff and diff.count("<tr>") == 2  # header + one field
    assert html.count("0123456789abcdef-test") >= 2
    assert "guard_on (VPR Guard ON)" in html and "guard_off (VPR Guard OFF)" in html


def test_eval_tables_rendered_from_the_eval_functions(runs: tuple[Path, Path], tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple] = []

    def load(p: Path) -> RunData:
        calls.append(("load", Path(p).name))
        return load_eval_run(p)

    def evaluate_run(run: RunData) -> dict:
        calls.append(("evaluate", run.path.name))
        return {"ate": {"map": {"rmse_m": 0.8125, "n": 80}, "dead_reckoning": {"rmse_m": 2.5, "n": 80}},
                "loop_closures": {"table": [{"event_seq": 40, "d_gt_m": 0.42, "label": "TP"}]}}

    def audit_run(run: RunData) -> dict:
        calls.append(("audit", run.path.name))
        return {"f1": 1.0, "missing_images": 0}

    def compare_runs(a: RunData, b: RunData) -> dict:
        calls.append(("compare", a.path.name, b.path.name))
        return {"runs": {"a": {"label": "A"}, "b": {"label": "B"}},
                "table_5_4": {"event_density_per_s": {"label": "event density (1/s)", "a": 0.5, "b": 1.0},
                              "nodes": {"label": "nodes", "a": 80, "b": 160}},
                "loop_closures": {"a": [{"event_seq": 40, "d_gt_m": 0.42, "label": "TP"}],
                                  "b": [{"event_seq": 45, "d_gt_m": 10.3, "label": "FP"}]},
                "far_m": 5.0}

    for name, func in (("load_run", load), ("evaluate_run", evaluate_run), ("audit_run", audit_run),
                       ("compare_runs", compare_runs)):
        monkeypatch.setattr(report_cli, name, func)
    rc = report_main([str(runs[0]), str(runs[1]), "--out", str(tmp_path), "--strict"])
    assert rc == 0
    # each recording loaded once; the comparison first, then each run's evaluation and audit
    assert calls == [("load", "guard_on.mcap"), ("load", "guard_off.mcap"),
                     ("compare", "guard_on.mcap", "guard_off.mcap"),
                     ("evaluate", "guard_on.mcap"), ("audit", "guard_on.mcap"),
                     ("evaluate", "guard_off.mcap"), ("audit", "guard_off.mcap")]
    html = (tmp_path / "index.html").read_text(encoding="utf-8")
    assert 'class="unavailable"' not in html
    on, off = "guard_on (VPR Guard ON)", "guard_off (VPR Guard OFF)"
    cmp_id = table_id(f"Comparison (Table 5.4, Tables 5.2-5.3): {on} vs {off}")
    block = re.search(rf'id="{cmp_id}">(.*?)</div></div></div>', html, flags=re.S).group(1)
    # Table 5.4 with the runs as columns, then one loop-closure table per run
    assert f"<th>metric</th><th>{on}</th><th>{off}</th>" in block
    assert '<td>event density (1/s)</td><td class="num">0.5</td><td class="num">1</td>' in block
    assert f"Loop closures (Tables 5.2-5.3): {off}" in block and "10.3" in block and "FP" in block
    # per-run details folded under the comparison, still there with their ids
    for name in (f"Evaluation (trajectory error, loop closures): {on}", f"Audit (event-evidence association): {off}"):
        m = re.search(rf'id="{table_id(name)}"><details><summary>', html)
        assert m, name
    assert "0.8125" in html and "rmse_m" in html


def test_failing_eval_function_is_reported_and_strict_fails(runs: tuple[Path, Path], tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    _without_eval_tables(monkeypatch)

    def audit_run(run: RunData) -> dict:
        raise ValueError("experience_image missing on purpose")
    monkeypatch.setattr(report_cli, "audit_run", audit_run)
    rc = report_main([str(runs[0]), "--out", str(tmp_path), "--strict"])
    assert rc == 3
    html = (tmp_path / "index.html").read_text(encoding="utf-8")  # the page is still written
    assert "eval.audit.audit_run failed: ValueError: experience_image missing on purpose" in html
    assert "eval.run_eval.evaluate_run failed: RuntimeError: left out of this test" in html
    assert any("failed" in r.getMessage() and r.levelname == "ERROR" for r in caplog.records)


def test_bad_input_is_named(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    missing = tmp_path / "nope.mcap"
    assert report_main([str(missing), "--out", str(tmp_path / "o")]) == 2
    assert str(missing) in capsys.readouterr().err
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all" * 10)
    assert report_main([str(garbage), "--out", str(tmp_path / "o")]) == 2
    assert str(garbage) in capsys.readouterr().err


def test_run_with_only_truth_shows_what_it_has_and_lists_what_is_left_out(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from common.mcap_io import RecordingWriter
    from common.messages import Header, Odometry
    _without_eval_tables(monkeypatch)
    rec = tmp_path / "truth_only.mcap"
    with RecordingWriter(rec) as w:
        for i, p in enumerate(square_ned(np.arange(0.0, 80.0, 1.0))):
            w.write("truth/pose", Odometry(header=Header(seq=i, stamp=T0 + i * 10**9), position=p.tolist(),
                                           orientation=[0.0, 0.0, 0.0, 1.0]))
    result = render_report([load_run(rec)], {}, tmp_path / "out")
    figs = result["figures"]
    assert figs["fig-overlay-3d"] == "shown" and figs["fig-projections"] == "shown"
    assert "no map message" in figs["fig-topology"]
    assert "no neocortex/sdr or local_view_cells" in figs["fig-similarity"]
    assert "no local_view_cells" in figs["fig-viewcells"]
    assert "no experience_image" in figs["fig-evidence"]
    html = (tmp_path / "out" / "index.html").read_text(encoding="utf-8")
    for fid in FIGURE_IDS:  # a figure without data is left out of the page, not drawn empty
        assert (f'id="{fid}"' in html) == (figs[fid] == "shown"), fid
    left_out = re.search(r'<details class="left-out">(.*?)</details>', html, flags=re.S).group(1)
    assert "no map message" in left_out and "no experience_image" in left_out
    assert "Not shown" not in html
    assert "has no <code>poseidon</code> metadata record" in html


# --------------------------------------------------------------------------- what the figures are drawn from


def test_positions_are_taken_to_ned_and_anchored(runs: tuple[Path, Path]) -> None:
    r = load_run(runs[0])
    t = (r.truth.t - T0) / 1e9
    np.testing.assert_allclose(r.truth.p, square_ned(t), atol=1e-9)
    # Odometry was published ENU (robot_state's default frame); back in NED it is the known drift
    t_dr = (r.dead_reckoning.t - T0) / 1e9
    expected = dead_reckoning_ned(t_dr, square_ned(t_dr))
    np.testing.assert_allclose(r.dead_reckoning.p, expected, atol=1e-6)
    assert r.dead_reckoning.source == "Odometry"
    # final map: 80 nodes, 30 % of the way from truth to dead reckoning (anchoring moves it < 1 cm here)
    assert len(r.node_ids) == 80 and len(r.links) == 79 + 4 and int(r.link_loop.sum()) == 4
    t_n = (r.node_stamps - T0) / 1e9
    truth_n = square_ned(t_n)
    expected_map = truth_n + 0.3 * (dead_reckoning_ned(t_n, truth_n) - truth_n)
    # anchoring: the first node moved onto dead reckoning at its stamp (from 30 % to 100 % of the drift)
    shift = 0.7 * (dead_reckoning_ned(t_n[:1], truth_n[:1]) - truth_n[:1])
    np.testing.assert_allclose(r.node_ned, expected_map + shift, atol=1e-6)
    assert r.label == "guard_on camera run"  # one run: what it is (guard states name runs compared)
    assert r.metadata["code_revision"] == "0123456789abcdef-test"


def test_deviation_figure_shows_map_better_than_dead_reckoning(runs: tuple[Path, Path]) -> None:
    rs = [load_run(p) for p in runs]
    specs, _ = build_figures(rs)
    dev = next(s for s in specs if s.id == "fig-deviation-time").figure
    names = [tr.name for tr in dev.data]
    # dead reckoning once (same Odometry in both runs), then the map of each run
    assert len(names) == 3 and names[0].startswith("dead reckoning") and names[1].startswith("map: guard_on")
    dr_max = float(np.max(dev.data[0].y))
    map_max = float(np.max(dev.data[1].y))
    # the heading error reaches 0.32 rad after 160 s: several metres; the map keeps 30 % of it
    assert 5.0 < dr_max < 8.0
    assert map_max == pytest.approx(0.3 * dr_max, rel=0.05)


def test_topology_highlights_loop_closures_with_their_true_distance(runs: tuple[Path, Path]) -> None:
    rs = [load_run(p) for p in runs]
    specs, _ = build_figures(rs)
    topo = next(s for s in specs if s.id == "fig-topology").figure
    loops = [tr for tr in topo.data if tr.name == "loop-closure link"]
    assert [int(np.isfinite(np.asarray(tr.x, dtype=float)).sum()) // 2 for tr in loops] == [4, 5]
    hover = [tr for tr in topo.data if tr.name == "loop closure (hover)"]
    d_on = [float(re.search(r"d_gt = ([0-9.]+) m", t).group(1)) for t in hover[0].text]
    d_off = [float(re.search(r"d_gt = ([0-9.]+) m", t).group(1)) for t in hover[1].text]
    assert max(d_on) < 0.01  # every ON closure joins the same place
    assert sum(d > 5.0 for d in d_off) == 1  # the OFF run's one false closure (places 10 m apart)


def test_similarity_and_revisit_truth(runs: tuple[Path, Path]) -> None:
    r = load_run(runs[0])
    sim = frame_similarity(r, max_frames=500)
    assert sim is not None and sim.source == "SDR overlap" and len(sim.stamps) == 320
    assert (np.diag(sim.percent) == 100).all()
    assert np.array_equal(sim.truth, sim.truth.T)
    lap = 160  # camera frames per lap (2 Hz, 80 s)
    # a second-lap frame and the first-lap frame of the same spot: same place, similar SDRs
    k = lap + 41
    assert sim.truth[k, k - lap] and sim.percent[k, k - lap] >= 50
    # frames of different places: not the same place, overlap near chance (8 random bits of 40)
    assert not sim.truth[k, 10] and sim.percent[k, 10] < 30
    # subsampling keeps at most max_frames, evenly spaced
    small = frame_similarity(r, max_frames=100)
    assert small is not None and len(small.stamps) == 100 and small.frame_total == 320


def test_precision_recall_known_answer() -> None:
    pr = precision_recall(np.array([0.9, 0.8, 0.7, 0.6]), np.array([True, False, True, False]))
    np.testing.assert_allclose(pr["precision"], [1.0, 0.5, 2 / 3, 0.5])
    np.testing.assert_allclose(pr["recall"], [0.5, 0.5, 1.0, 1.0])
    assert pr["average_precision"] == pytest.approx(0.5 * 1.0 + 0.5 * 2 / 3)
    assert pr["best_f1"] == pytest.approx(0.8) and pr["best_threshold"] == pytest.approx(0.7)
    # ties share one threshold
    tie = precision_recall(np.array([1.0, 1.0, 0.0]), np.array([True, False, True]))
    np.testing.assert_allclose(tie["precision"], [0.5, 2 / 3])


def test_lvc_operating_point_counts_the_aliased_place(page: tuple[Path, dict]) -> None:
    _path, result = page
    pr = result["precision_recall"]["guard_on (VPR Guard ON)"]
    assert pr["source"] == "SDR overlap" and pr["positives"] > 0
    # place 30 of lap 2 took place 5's LVC id: pairs called the same place that are not
    assert 0.5 < pr["lvc_pair_precision"] < 1.0 and "lvc_precision" not in pr
    assert 0.0 < pr["average_precision"] <= 1.0
    assert PLACES == 40


def test_view_cells_separate_revisits_from_the_same_pass(runs: tuple[Path, Path]) -> None:
    from eval.report.fig_recognition import revisit_frames as _revisit_frames
    r = load_run(runs[0])
    revisit = _revisit_frames(r, 10.0)
    lap = 160
    # every second-lap frame matches a cell created a lap (80 m) earlier; no first-lap frame does
    assert revisit[lap:].all() and not revisit[:lap].any()
    assert int(r.lvc_new.sum()) == PLACES
    specs, _ = build_figures([r])
    vc = next(s for s in specs if s.id == "fig-viewcells").figure
    counts = {tr.name: len(tr.x) for tr in vc.data}
    assert counts == {"matched a cell of the same pass": lap - PLACES, "new view cell": PLACES,
                      "recognised a cell from >= 10 m of travel earlier": lap, "map loop closure": 4}


def test_sessions_drawn_in_their_own_colours(runs: tuple[Path, Path], tmp_path: Path) -> None:
    """A map of two sessions (map_sessions): two session groups, distinct colours, the
    session link marked; a run of one session: one group in the run's colour, drawn as before."""
    from eval.report.style import SESSION_COLORS, run_color, session_groups
    two = tmp_path / "two_sessions.mcap"
    write_handmade_run(two, second_session=True)
    r2, r1 = load_run(two), load_run(runs[0])
    g2, g1 = session_groups(r2), session_groups(r1)
    assert [g.session for g in g2] == [0, 1] and g2[0].color != g2[1].color
    assert [g.color for g in g2] == SESSION_COLORS[:2]
    per_lap = len(r2.node_ids) // 2
    assert g2[0].index.tolist() == list(range(per_lap)) and len(g2[1].index) == len(r2.node_ids) - per_lap
    assert r2.session_links.tolist() == [[0, per_lap]]
    assert len(g1) == 1 and g1[0].color == run_color(0) and len(g1[0].index) == len(r1.node_ids)
    assert (r1.node_session == 0).all() and len(r1.session_links) == 0

    def topology(r: RunView) -> Any:
        specs, _ = build_figures([r])
        return next(s for s in specs if s.id == "fig-topology").figure
    names2 = [tr.name for tr in topology(r2).data if tr.showlegend is not False]
    assert "session 0" in names2 and "session 1" in names2 and "session link" in names2
    colours = {tr.name: tr.marker.color for tr in topology(r2).data if tr.name in ("session 0", "session 1")}
    assert colours == {"session 0": SESSION_COLORS[0], "session 1": SESSION_COLORS[1]}
    link = next(tr for tr in topology(r2).data if tr.name == "session link")
    assert int(np.isfinite(np.asarray(link.x, dtype=float)).sum()) // 2 == 1
    # the link is not counted again as a red loop closure; the other 3 closures are
    loops = next(tr for tr in topology(r2).data if tr.name == "loop-closure link")
    assert int(np.isfinite(np.asarray(loops.x, dtype=float)).sum()) // 2 == 3
    names1 = [tr.name for tr in topology(r1).data]
    assert not any(n.startswith("session") for n in names1) and f"nodes: {r1.label}" in names1


def test_map_line_breaks_between_sessions(runs: tuple[Path, Path], tmp_path: Path) -> None:
    """The overlay and projections draw a map of two sessions with a gap at the session break;
    one session: no gap (as before)."""
    two = tmp_path / "two_sessions.mcap"
    write_handmade_run(two, second_session=True)
    for path, gaps in ((two, 1), (runs[0], 0)):
        r = load_run(path)
        specs, _ = build_figures([r])
        for fid in ("fig-overlay-3d", "fig-projections"):
            fig = next(s for s in specs if s.id == fid).figure
            tr = next(t for t in fig.data if t.name == f"map: {r.label}")
            assert int(np.isnan(np.asarray(tr.x, dtype=float)).sum()) == gaps
