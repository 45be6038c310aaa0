"""Real Girona (Cala Viuda) DVL + depth logs: dead reckoning scored on the cone passes.

The logs carry no heading (the LinkQuest's roll/pitch/heading are exactly 0 in every record
and no IMU log is available), so both the filter and plain integration keep a constant
heading; the per-cone distances then measure the along-track distance between the passes.
This test guards the figures (measured 2026-11-21 with services/robot_state/presets/
girona_linkquest.yaml) from regressing.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from eval.deadreckon import read_cone_passes, run_deadreckon
from system.config import load_config

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "girona_caves"
PRESET = Path(__file__).resolve().parents[2] / "services" / "robot_state" / "presets" / "girona_linkquest.yaml"

# measured: filter / plain integration, vehicle positions at the passes (no offsets), metres
FILTER_MEAN_M = 252.43
PLAIN_MEAN_M = 252.30
MARGIN_M = 0.5


@pytest.fixture(scope="module")
def summary():
    if not (DATA / "dvl_linkquest.csv").exists() or not (DATA / "depth_sensor.csv").exists():
        pytest.skip(f"Girona logs not found under {DATA}")
    importer = pytest.importorskip("missions.importers.rostopic_csv")
    msgs = (importer.read_rostopic_csv(DATA / "dvl_linkquest.csv", "dvl_linkquest")
            + importer.read_rostopic_csv(DATA / "depth_sensor.csv", "depth_sensor"))
    cones = read_cone_passes(DATA / "cone_passes.csv")
    return run_deadreckon(msgs, load_config(PRESET), cones, recording="girona_caves")


def test_girona_counts_and_flags(summary):
    c = summary["counters"]
    assert c["dvl_invalid_flag"] == 482  # velocityInstFlag 0 in the log
    assert c["dvl_attitude_zero"] == 5564  # every record: no compass
    for bad in ("dvl_nonfinite", "dvl_few_beams", "dvl_too_fast", "timestamp_backwards", "gap", "late"):
        assert bad not in c
    assert summary["status_flags"]["heading_unobserved"] == summary["odometry_count"]
    assert summary["duration_s"] == pytest.approx(1954.9, abs=0.2)
    assert 12.0 < summary["end_position_m"][2] < 15.0  # z from pressure (depth ~13.7 m at the end)


def test_girona_cone_distances_do_not_regress(summary):
    cones = summary["cones"]
    assert cones["passes_used"] == 12 and cones["passes_outside"] == 0
    f = cones["filter"]["no_offset"]
    p = cones["plain"]["no_offset"]
    assert sorted(f["per_cone_m"]) == ["0", "1", "2", "3", "4", "5"]
    assert f["mean_m"] <= FILTER_MEAN_M + MARGIN_M
    # with the heading constant the filter cannot beat plain integration; it must not be worse
    assert f["mean_m"] <= p["mean_m"] + MARGIN_M
    assert p["mean_m"] == pytest.approx(PLAIN_MEAN_M, abs=MARGIN_M)
    for variant in ("offset", "offset_y_flipped"):
        assert abs(cones["filter"][variant]["mean_m"] - f["mean_m"]) < 2.0
