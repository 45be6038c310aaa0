"""`poseidon import LOG.clf`: the CARMEN importer on hand-made logs and on the real Freiburg logs."""
from __future__ import annotations

import bz2
import gzip
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import read_messages, read_metadata
from common.messages import LaserScan, Odometry
from launcher.cli import main as poseidon
from missions.importers.carmen import DEFAULT_RANGE_MAX_M, flaser_geometry, import_carmen, ns_to_text, seconds_to_ns
from missions.importers.cli import main as import_main
from missions.importers.errors import InputFormatError

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "radish"
needs_radish = pytest.mark.skipif(not (DATA / "aces.clf.bz2").is_file(),
                                  reason=f"the Freiburg CARMEN logs are not present at {DATA}")


def _flaser(kind: str, ranges: list[float], laser: tuple[float, ...], odom: tuple[float, ...], ts: str) -> str:
    r = " ".join(f"{v:.2f}" for v in ranges)
    return f"{kind} {len(ranges)} {r} {' '.join(map(str, laser))} {' '.join(map(str, odom))} {ts} host 0.5"


R180 = [1.0 + 0.01 * i for i in range(180)]
R361 = [2.0] * 361

#: line number -> what it is, in file order (a hand-made log covering every path)
LINES = [
    "# CARMEN Logfile",                                                                  # 1 comment
    "PARAM robot_front_laser_max 50.0 nohost 0",                                          # 2 PARAM, no ipc_ts
    "PARAM robot_rear_laser_max 30.0 1071078718.462518 merci 1071078718.462517",         # 3 PARAM with ipc_ts
    "",                                                                                  # 4 blank
    "ODOM 1.0 2.0 0.5 0.3 0.1 0.0 100.000000001 host 0.1",                               # 5 ODOM
    _flaser("FLASER", R180, (1.1, 2.0, 0.5), (1.0, 2.0, 0.5), "99.5"),                   # 6 FLASER, earlier stamp
    "ODOM 1.1 2.1 0.6 0.3 0.1 0.0 100.1 host 0.2",                                       # 7 ODOM
    _flaser("RLASER", R361, (0.9, 2.0, 3.64), (1.0, 2.0, 0.5), "100.1"),                 # 8 RLASER, same stamp
    "TRUEPOS 1 2 3 4 5 6 100.2 host 0.3",                                                # 9 known, unused
    "SYNC tag 100.3 host 0.4",                                                           # 10 known, unused
    "ODOM 1.2 2.2 0.7 0.3 0.1 100.4 host 0.5",                                           # 11 rejected: 9 fields
    "ODOM 1.2 abc 0.7 0.3 0.1 0.0 100.4 host 0.5",                                       # 12 rejected: non-numeric
    "FLASER 5 1 2 3 4 1 2 3 1 2 3 100.5 host 0.6",                                       # 13 rejected: n != fields
    "ODOM 1.2 2.2 nan 0.3 0.1 0.0 100.6 host 0.7",                                       # 14 rejected: non-finite
    "WEIRD 1 2 3",                                                                       # 15 unknown
    "  # indented comment",                                                              # 16 comment
    "WEIRD 4 5 6",                                                                       # 17 unknown again
    "ODOM 1.3 2.3 3.1 0.3 0.1 0.0 100.7 host 0.8",                                       # 18 ODOM
    "   ",                                                                               # 19 blank
]


def _write(path: Path, lines: list[str]) -> Path:
    text = "\n".join(lines) + "\n"
    if path.name.endswith(".bz2"):
        path.write_bytes(bz2.compress(text.encode()))
    elif path.name.endswith(".gz"):
        path.write_bytes(gzip.compress(text.encode()))
    else:
        path.write_text(text)
    return path


def _recorded(path: Path) -> list[tuple[str, Any]]:
    """(key, message) in file order (typed loosely: each test reads the fields of its key's type)."""
    return [(r.key, r.message()) for r in read_messages(path)]


@pytest.mark.parametrize("name", ["log.clf", "log.clf.bz2", "log.clf.gz"])
def test_every_line_is_accounted_for(tmp_path: Path, name: str) -> None:
    s = import_carmen(_write(tmp_path / name, LINES), tmp_path / "out.mcap")
    assert s["lines"] == len(LINES) == s["accounted"]
    assert s["comments"] == 2 and s["blank"] == 2
    assert s["line_types"] == {
        "FLASER": {"lines": 2, "mapped": 1, "unused": 0, "rejected": 1},
        "ODOM": {"lines": 6, "mapped": 3, "unused": 0, "rejected": 3},
        "PARAM": {"lines": 2, "mapped": 2, "unused": 0, "rejected": 0},
        "RLASER": {"lines": 1, "mapped": 1, "unused": 0, "rejected": 0},
        "SYNC": {"lines": 1, "mapped": 0, "unused": 1, "rejected": 0},
        "TRUEPOS": {"lines": 1, "mapped": 0, "unused": 1, "rejected": 0},
    }
    assert s["known_unused"] == 2
    assert s["unknown"] == {"WEIRD": {"lines": 2, "first_line": 15}}
    assert [(r["line"], r["type"]) for r in s["rejected"]] == [(11, "ODOM"), (12, "ODOM"), (13, "FLASER"), (14, "ODOM")]
    reasons = [r["reason"] for r in s["rejected"]]
    assert "9 fields, expected 10" in reasons[0]
    assert "'abc' is not a number" in reasons[1]
    assert "with n = 5" in reasons[2]
    assert "non-finite" in reasons[3]
    assert s["written"] == {"scan": 1, "scan_rear": 1, "wheel_odometry": 3}
    assert s["odometry_from"] == "ODOM"


def test_messages_follow_the_mapping(tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    import_carmen(_write(tmp_path / "log.clf", LINES), out)
    rec = _recorded(out)
    # chronological (the FLASER at 99.5 s first), equal stamps in file order (ODOM line 7 before RLASER line 8)
    assert [k for k, _ in rec] == ["scan", "wheel_odometry", "wheel_odometry", "scan_rear", "wheel_odometry"]
    stamps = [m.header.stamp for _, m in rec]
    assert stamps == [99_500_000_000, 100_000_000_001, 100_100_000_000, 100_100_000_000, 100_700_000_000]
    odo = [m for k, m in rec if k == "wheel_odometry"]
    assert [m.header.seq for m in odo] == [0, 1, 2]
    o = odo[0]
    assert isinstance(o, Odometry)
    assert (o.header.frame_id, o.child_frame_id) == ("odom", "base_link")
    assert o.position == [1.0, 2.0, 0.0]
    assert o.orientation == pytest.approx([0.0, 0.0, math.sin(0.25), math.cos(0.25)])
    assert o.linear_velocity == [0.3, 0.0, 0.0] and o.angular_velocity == [0.0, 0.0, 0.1]
    front = rec[0][1]
    assert isinstance(front, LaserScan)
    assert front.ranges.dtype == np.float32 and front.ranges[0] == np.float32(1.0) and len(front.ranges) == 180
    assert front.intensities.dtype == np.float32 and len(front.intensities) == 0
    assert front.angle_min == pytest.approx(-math.pi / 2)
    assert front.angle_increment == pytest.approx(math.pi / 180)
    assert front.angle_max == pytest.approx(math.radians(89))
    assert (front.range_min, front.range_max) == (0.0, 50.0)  # PARAM robot_front_laser_max
    rear = rec[3][1]
    assert isinstance(rear, LaserScan) and rear.range_max == 30.0 and rear.header.frame_id == "rear_laser"
    assert rear.angle_max == pytest.approx(math.pi / 2) and rear.angle_increment == pytest.approx(math.pi / 360)
    meta = read_metadata(out)
    assert meta["carmen_params"] == {"robot_front_laser_max": "50.0", "robot_rear_laser_max": "30.0"}
    assert meta["poseidon"]["source_format"] == "CARMEN log"
    assert meta["poseidon"]["odometry_from"] == "ODOM"


def test_cli_exit_1_on_rejected_lines_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = _write(tmp_path / "log.clf", LINES)
    assert import_main([str(log), "--out", str(tmp_path / "o.mcap"), "--json"]) == 1
    s = json.loads(capsys.readouterr().out)
    assert len(s["rejected"]) == 4
    clean = _write(tmp_path / "clean.clf", [ln for i, ln in enumerate(LINES, 1) if i not in (11, 12, 13, 14)])
    assert import_main([str(clean), "--out", str(tmp_path / "c.mcap")]) == 0


def test_cli_refuses_bad_inputs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert import_main([str(tmp_path / "missing.clf"), "--out", str(tmp_path / "o.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err
    junk = _write(tmp_path / "junk.clf", ["hello world", "more text"])
    assert import_main([str(junk), "--out", str(tmp_path / "o.mcap")]) == 2
    assert "not a CARMEN log" in capsys.readouterr().err
    assert not (tmp_path / "o.mcap").exists()
    (tmp_path / "broken.clf.bz2").write_bytes(bz2.compress(b"ODOM 1 2 3 4 5 6 7 h 8\n" * 50)[:60])
    assert import_main([str(tmp_path / "broken.clf.bz2"), "--out", str(tmp_path / "o.mcap")]) == 2
    assert "unreadable after line" in capsys.readouterr().err
    log = _write(tmp_path / "log.clf", LINES)
    with pytest.raises(SystemExit):
        import_main([str(log), str(log), "--out", str(tmp_path / "o.mcap")])


def test_flaser_only_log_takes_odometry_from_its_lines(tmp_path: Path) -> None:
    lines = [_flaser("FLASER", R361, (5.1, 1.0, 0.3), (5.0, 1.0, 0.3), f"{1134864629 + i}.895182") for i in range(3)]
    s = import_carmen(_write(tmp_path / "mit.clf", lines), tmp_path / "o.mcap")
    assert s["odometry_from"] == "FLASER" and s["written"] == {"scan": 3, "wheel_odometry": 3}
    assert s["range_max_from"] == {"scan": "default"}
    rec = _recorded(tmp_path / "o.mcap")
    odo = [m for k, m in rec if k == "wheel_odometry"]
    scans = [m for k, m in rec if k == "scan"]
    assert [o.header.stamp for o in odo] == [sc.header.stamp for sc in scans]
    assert odo[0].position == [5.0, 1.0, 0.0] and odo[0].status == ["velocity_unknown"]
    assert scans[0].range_max == DEFAULT_RANGE_MAX_M
    assert ns_to_text(odo[0].header.stamp) == "1134864629.895182000"
    off = s["laser_offsets"]["scan"]
    assert off["dx"] == pytest.approx(0.1 * math.cos(0.3), abs=1e-6)
    assert off["dy"] == pytest.approx(-0.1 * math.sin(0.3), abs=1e-6)


def test_robotlaser_only_log_uses_its_own_geometry_and_pose(tmp_path: Path) -> None:
    n, rem = 4, 2
    head = "ROBOTLASER1 0 -1.0 2.0 0.5 30.0 0.01 0"
    line = (f"{head} {n} 1 2 3 4 {rem} 9 9 0.22 0 0 0 0 0.1 0.5 0.05 1.0 0.5 0.0 1232658478.161285 zoidberg2 0.1")
    s = import_carmen(_write(tmp_path / "clinic.clf", [line]), tmp_path / "o.mcap")
    assert s["rejected"] == [] and s["odometry_from"] == "ROBOTLASER1"
    rec = dict(_recorded(tmp_path / "o.mcap"))
    sc, od = rec["scan"], rec["wheel_odometry"]
    assert (sc.angle_min, sc.angle_increment, sc.range_max) == (-1.0, 0.5, 30.0)
    assert sc.angle_max == pytest.approx(0.5)
    assert od.position == [0.0, 0.0, 0.0] and od.orientation[2] == pytest.approx(math.sin(0.05))
    assert od.linear_velocity == [0.5, 0.0, 0.0] and od.angular_velocity == [0.0, 0.0, 0.05] and od.status == []
    bad = line.replace(f"{rem} 9 9", f"{rem + 1} 9 9")  # remission count contradicts the fields
    s = import_carmen(_write(tmp_path / "bad.clf", [bad]), tmp_path / "o2.mcap")
    assert s["rejected"][0]["line"] == 1 and "n_rem = 3" in s["rejected"][0]["reason"]


def test_stamps_are_exact_to_the_nanosecond() -> None:
    assert seconds_to_ns("1071078718.462369") == 1_071_078_718_462_369_000
    assert seconds_to_ns("70.179699") == 70_179_699_000
    assert seconds_to_ns("1.0000000005") == 1_000_000_000  # half to even
    assert seconds_to_ns("1.0000000015") == 1_000_000_002
    assert ns_to_text(1_071_078_718_462_369_000) == "1071078718.462369000"
    assert ns_to_text(5) == "0.000000005"
    with pytest.raises(ValueError, match="not a number"):
        seconds_to_ns("12a")
    with pytest.raises(ValueError, match="not finite"):
        seconds_to_ns("inf")


@pytest.mark.parametrize("n,inc_deg,last_deg", [(180, 1.0, 89.0), (181, 1.0, 90.0), (360, 0.5, 89.5),
                                                (361, 0.5, 90.0), (91, 2.0, 90.0)])
def test_flaser_beam_geometry_follows_carmen(n: int, inc_deg: float, last_deg: float) -> None:
    a0, a1, inc = flaser_geometry(n)
    assert a0 == pytest.approx(-math.pi / 2)
    assert math.degrees(inc) == pytest.approx(inc_deg)
    assert math.degrees(a1) == pytest.approx(last_deg)


def test_bad_range_param_is_an_error_naming_it(tmp_path: Path) -> None:
    log = _write(tmp_path / "log.clf", ["PARAM robot_front_laser_max far nohost 0",
                                        _flaser("FLASER", R180, (0, 0, 0), (0, 0, 0), "1.0")])
    with pytest.raises(InputFormatError, match="robot_front_laser_max"):
        import_carmen(log, tmp_path / "o.mcap")


@needs_radish
@pytest.mark.parametrize("name,counts,lines", [
    ("aces", {"ODOM": 7375, "FLASER": 7374, "PARAM": 4}, 14762),
    ("fr079", {"ODOM": 8951, "FLASER": 4934, "PARAM": 187}, 14083),
])
def test_real_freiburg_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, counts: dict[str, int],
                            lines: int) -> None:
    out = tmp_path / f"{name}.mcap"
    s = import_carmen(DATA / f"{name}.clf.bz2", out)
    assert s["lines"] == s["accounted"] == lines
    assert {k: v["mapped"] for k, v in s["line_types"].items()} == counts
    assert s["rejected"] == [] and s["unknown"] == {}
    assert s["written"] == {"scan": counts["FLASER"], "wheel_odometry": counts["ODOM"]}
    assert poseidon(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["counts"] == {"scan": counts["FLASER"], "wheel_odometry": counts["ODOM"]}
    assert info["types"] == {"scan": "poseidon_msgs/LaserScan", "wheel_odometry": "poseidon_msgs/Odometry"}
