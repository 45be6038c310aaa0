"""benchmarks/write_results.py: its pure parts (sections of the file, tables from JSON); no command is run."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "write_results.py"
_spec = importlib.util.spec_from_file_location("write_results", _PATH)
assert _spec is not None and _spec.loader is not None
wr = importlib.util.module_from_spec(_spec)
sys.modules["write_results"] = wr
_spec.loader.exec_module(wr)

ORDER = [t.name for t in wr.TOPICS]


def _doc() -> str:
    demo = wr.section_text("demo", "Demo", ["poseidon demo --json"], "2026-01-01 00:00 UTC", "abc1234", "old demo\n")
    laser = wr.section_text("laser", "Laser logs", ["poseidon eval"], "2026-01-02 00:00 UTC", "def5678+dirty",
                            "| a | b |\n|---|---|\n| 1 | 2 |\n")
    return wr.PREAMBLE + "\nText a person wrote between sections stays.\n\n" + demo + "\n" + laser + "\ntrailing words\n"


def test_replacing_a_section_keeps_every_other_byte():
    text = _doc()
    new = wr.section_text("demo", "Demo", ["poseidon demo --json"], "2026-02-01 00:00 UTC", "fff0000", "new demo\n")
    out = wr.replace_sections(text, {"demo": new}, ORDER)
    a, b = wr.split_sections(text)["demo"]
    c, d = wr.split_sections(out)["demo"]
    assert out[:c] == text[:a] and out[d:] == text[b:]
    assert out[c:d] == new and "old demo" not in out


def test_a_new_section_goes_between_its_neighbours_in_topic_order():
    text = _doc()
    vpr = wr.unmeasured_section(wr.BY_NAME["vpr-images"])
    out = wr.replace_sections(text, {"vpr-images": vpr}, ORDER)
    spans = wr.split_sections(out)
    assert spans["laser"][1] <= spans["vpr-images"][0]
    laser_old = text[slice(*wr.split_sections(text)["laser"])]
    assert out[slice(*spans["laser"])] == laser_old
    assert out.endswith("-->\n\ntrailing words\n") and "--only vpr-images" in out


def test_an_unclosed_section_is_an_error():
    with pytest.raises(ValueError, match="no closing"):
        wr.split_sections("<!-- results:demo -->\n## Demo\n")


def test_a_section_carries_its_commands_date_and_revision():
    s = wr.section_text("soak-60", "Speed: a 60-minute mission", ["python benchmarks/bench_soak.py --json"],
                        "2026-03-04 05:06 UTC", "0123abc+dirty", "body\n")
    assert s.startswith("<!-- results:soak-60 -->\n## Speed: a 60-minute mission\n")
    assert "2026-03-04 05:06 UTC" in s and "`0123abc+dirty`" in s and "    python benchmarks/bench_soak.py --json" in s
    assert s.endswith("<!-- /results:soak-60 -->\n")


def test_the_demo_table_renders_from_its_json():
    run = {"events": 1463, "loop_closures": {"accepted": 8, "true": 8, "false": 0}, "audit_f1": 1.0,
           "ate_rmse_m": {"map": 0.1712, "dead_reckoning": 0.3561}, "mission_s": 780.2, "wall_s": 95.0,
           "real_time_factor": 8.21}
    body = wr.render_demo({"runs": {"on": run, "off": {**run, "events": 1617}},
                           "checks": {"audit_f1_is_1": True, "no_false_loop_closure_on": False}})
    rows = [line for line in body.splitlines() if line.startswith("| VPR Guard")]
    assert rows[0] == "| VPR Guard ON | 1463 | 8 / 0 | 0.17 m | 0.36 m | 1.00 | 780 s | 95 s | 8.2x |"
    assert rows[1].startswith("| VPR Guard OFF") and "| 1617 |" in rows[1]
    assert "audit_f1_is_1 PASS" in body and "no_false_loop_closure_on FAIL" in body


def test_the_laser_table_puts_the_run_beside_the_previous_default_raw_odometry_and_the_published_rows():
    rel = {"count": 1279, "trans_abs_m": {"mean": 0.0361, "std": 0.0337}, "rot_abs_deg": {"mean": 0.3651, "std": 0.354}}
    base = {"count": 1279, "trans_abs_m": {"mean": 0.0362, "std": 0.034}, "rot_abs_deg": {"mean": 0.417, "std": 0.423}}
    odo = {"count": 1279, "trans_abs_m": {"mean": 0.549, "std": 2.681}, "rot_abs_deg": {"mean": 2.22, "std": 6.17}}
    res = {"eval": {"relations": rel, "relations_odometry": odo, "nodes": 1101, "loop_closures": {"accepted": 19}},
           "run": {"wall_s": 100.0, "recording": {"duration_s": 1366.0}, "services": {"expmap": {"cpu_s": 69.4}}}}
    body = wr.render_laser({"aces": res})
    assert "| **this preset, map-corrected** | **0.036 ± 0.034** | **0.365 ± 0.354** |" in body
    assert "| raw odometry (same run) | 0.549 ± 2.681 | 2.22 ± 6.17 |" in body
    assert "| graph mapping [published, Kümmerle 2009] | 0.044 ± 0.044 | 0.4 ± 0.4 |" in body
    assert "| GMapping [published, Kümmerle 2009] | 0.060 ± 0.049 |  |" in body
    assert "1279 relations; 1101 experiences, 19 loop closures; the log's 1366 s: 13.7x real time, expmap 69.4 " \
        "CPU s (no baseline in this run)" in body
    res.update(base_eval={"relations": base}, base_run={"wall_s": 80.0, "recording": {"duration_s": 1366.0},
                                                         "services": {"expmap": {"cpu_s": 55.0}}})
    body = wr.render_laser({"aces": res})
    assert f"| previous default, `{wr.LASER_BASELINE}` (same run) | 0.036 ± 0.034 | 0.417 ± 0.423 |" in body
    assert "expmap 69.4 CPU s; previous default 17.1x real time, expmap 55.0 CPU s" in body
    rows = [ln for ln in body.splitlines() if ln.startswith("| ")]
    assert rows[1].startswith("| **this preset") and rows[2].startswith("| previous default") and \
        rows[3].startswith("| raw odometry")


def test_the_mission_recognition_table_has_a_mean_row_with_the_lowest_precision():
    def fig(r, p):
        return {"lvc_recall": r, "lvc_precision": p}
    chains = {n: fig(0.2, 0.9) for n in wr.VPR_CHAINS}
    body = wr.render_vpr_missions({"4101": {**fig(0.5, 1.0), "chains": chains, "tm_decision_share": 0.01},
                                   "4102": {**fig(0.3, 0.8), "chains": chains, "tm_decision_share": 0.02}})
    assert "| 4101 | 0.500 / 1.000 | 0.200 / 0.900 |" in body
    assert "| mean (lowest precision) | 0.400 / 0.900 (0.800) |" in body


def test_a_missing_figure_renders_as_not_available():
    body = wr.render_vpr_images({"corridor": {"n_query_with_gt": 111, "matchers": {"htm_lvc": {"auc": 1.0}}}})
    assert "| corridor (VPR-Bench) | 111 | 1.000 | n/a |" in body


def test_the_results_file_has_one_section_per_topic_under_the_preamble():
    text = (_PATH.parents[1] / "docs" / "RESULTS.md").read_text()
    assert text.startswith(wr.PREAMBLE)
    spans = wr.split_sections(text)
    assert list(spans) == ORDER, "sections in topic order, one per topic"


def test_the_soak_section_says_where_each_service_cpu_went():
    d = {"pipeline": {"mission_s": 600, "wall_s": 30.0, "real_time_factor": 20.0},
         "transport_only": {"mission_s": 600, "wall_s": 5.0, "real_time_factor": 120.0},
         "cpu_s": {"htm": 8.0, "encoder": 18.0},
         "cpu_split": {"htm": {"cpu_s": 8.1, "startup_s": 2.4, "node_s": 4.0, "frame_path_s": 1.0, "rest_s": 0.7},
                       "encoder": {"cpu_s": 18.2, "startup_s": 3.7, "node_s": 12.0, "frame_path_s": 1.5,
                                   "rest_s": 1.0}}}
    body = wr.render_soak(d)
    assert "| encoder | 18.2 s | 3.7 s | 12.0 s | 1.5 s | 1.0 s |" in body
    assert body.index("| encoder | 18.2 s") < body.index("| htm | 8.1 s")   # the costliest first
    assert "Where each algorithm service's CPU went" not in wr.render_soak({k: v for k, v in d.items()
                                                                            if k != "cpu_split"})


def test_the_soak_section_gives_the_encoders_work_per_frame_when_measured():
    d = {"pipeline": {"mission_s": 600, "wall_s": 30.0, "real_time_factor": 20.0},
         "transport_only": {"mission_s": 600, "wall_s": 5.0, "real_time_factor": 120.0},
         "cpu_s": {"encoder": 18.0}, "encoder_ms_per_frame": 4.172}
    assert "The encoder's own work per camera frame: 4.17 ms of CPU" in wr.render_soak(d)
    assert "work per camera frame" not in wr.render_soak({**d, "encoder_ms_per_frame": None})
    assert "work per camera frame" not in wr.render_soak({k: v for k, v in d.items() if k != "encoder_ms_per_frame"})
