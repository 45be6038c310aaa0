"""``poseidon report RUN --relations FILE``: the benchmark section on a hand-made laser run."""
from __future__ import annotations

import base64
import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from common.mcap_io import RecordingWriter
from common.messages import ExperienceLink, ExperienceMap, ExperienceNode, Header, LaserScan, Odometry
from eval.report.benchmark import _world_points, raster_png, relations_table, scan_endpoints
from eval.report.cli import main as report_main
from eval.trajectory import PoseSeries

NS = 1_000_000_000
T0 = 1_000 * NS
ROOM = 5.0  # half-width of a square room centred on the origin (m)


def _q(yaw: float) -> list[float]:
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def _room_ranges(x: float, y: float, yaw: float, angles: np.ndarray) -> np.ndarray:
    """Ranges from (x, y, yaw) to the walls of the square room |x|, |y| <= ROOM."""
    a = yaw + angles
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (ROOM - x) / c, np.where(c < 0, (-ROOM - x) / c, np.inf))
        ty = np.where(s > 0, (ROOM - y) / s, np.where(s < 0, (-ROOM - y) / s, np.inf))
    return np.minimum(tx, ty)


def _write_run(path: Path) -> None:
    """A robot circling the room twice (radius 2 m, 60 s per lap); its wheel odometry drifts in yaw
    (0.2 deg/s), its Odometry and the map are exact; one loop closure at the start of lap 2."""
    angles = -math.pi / 2 + np.arange(181) * math.pi / 180
    nodes = []
    with RecordingWriter(path) as w:
        for k in range(121):
            t = T0 + k * NS
            th = 2 * math.pi * k / 60
            x, y, yaw = 2 * math.cos(th), 2 * math.sin(th), th + math.pi / 2
            drift = math.radians(0.2) * k
            w.write("wheel_odometry", Odometry(header=Header(seq=k, stamp=t), position=[x, y, 0.0],
                                               orientation=_q(yaw + drift)))
            w.write("Odometry", Odometry(header=Header(seq=k, stamp=t), position=[x, y, 0.0], orientation=_q(yaw)))
            r = _room_ranges(x, y, yaw, angles).astype(np.float32)
            w.write("scan", LaserScan(header=Header(seq=k, stamp=t), angle_min=-math.pi / 2, angle_max=math.pi / 2,
                                      angle_increment=math.pi / 180, range_min=0.0, range_max=81.9, ranges=r,
                                      intensities=np.zeros(0, np.float32)))
            if k % 10 == 0:
                nodes.append(ExperienceNode(id=len(nodes), lvc_id=0, position=[x, y, 0.0], yaw=yaw, stamp=t))
        links = [ExperienceLink(source=i, target=i + 1, delta=[0, 0, 0], duration_s=10, weight=1)
                 for i in range(len(nodes) - 1)]
        links.append(ExperienceLink(source=6, target=0, delta=[0, 0, 0], duration_s=0, weight=1, loop_closure=True))
        w.write("map", ExperienceMap(header=Header(seq=0, stamp=T0 + 120 * NS), nodes=nodes, links=links))
        w.add_metadata("poseidon", {"laser_offsets": {"scan": {"dx": 0.0, "dy": 0.0, "dtheta": 0.0}}})


def test_report_with_relations_renders_the_benchmark_section(tmp_path, capsys):
    run = tmp_path / "run.mcap"
    _write_run(run)
    rel = tmp_path / "aces.relations"  # the name picks the published ACES rows
    rel.write_text(f"{1000.0} {1030.0} 0 4.0 0 0 0 {math.pi}\n")  # half a lap: 4 m across, turned by pi
    out = tmp_path / "report"
    assert report_main([str(run), "--relations", str(rel), "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["figures"]["fig-scan-maps"] == "shown" and res["figures"]["fig-loop-closures"] == "shown"
    page = (out / "index.html").read_text(encoding="utf-8")
    # a laser run without ground truth: the map first (laser point maps), then the relations' result
    assert res["sections"][:2] == ["sec-map", "sec-benchmark"]
    section = page[page.index('id="sec-map"'):page.index('id="sec-benchmark"')]
    assert section.count("data:image/png;base64,") == 2
    assert 'id="table-relations-freiburg-benchmark' in page[page.index('id="sec-benchmark"'):]
    assert "map-corrected (final map)" in section and "raw odometry (wheel_odometry)" in section
    assert "0.0375 ± 0.0426" in page and "0.37 ± 0.47" in page and "Hess et al. ICRA 2016" in page
    assert "0.2580 ± 0.4270" not in page  # FR079 rows only for an fr079 file
    # this run: the map is exact (0 error); the wheel odometry turned 6 deg too far in 30 s
    rows = re.findall(r"this run: (map-corrected|raw odometry)</td><td[^>]*>([^<]*)</td>", page)
    assert dict(rows) == {"map-corrected": "0.0000 ± 0.0000", "raw odometry": "0.0000 ± 0.0000"}
    rot = re.findall(r"this run: raw odometry</td><td[^>]*>[^<]*</td><td[^>]*>([^<]*)</td>", page)
    assert rot == ["6.00 ± 0.00"]
    assert report_main([str(run), str(run), "--relations", str(rel), "--out", str(out)]) == 2


def test_scans_land_on_the_walls_at_the_corrected_poses():
    scan = LaserScan(header=Header(seq=0, stamp=5), angle_min=0.0, angle_max=math.pi / 2,
                     angle_increment=math.pi / 2, range_min=0.0, range_max=81.9,
                     ranges=np.array([2.0, 90.0], np.float32), intensities=np.zeros(0, np.float32))
    stamps, local = scan_endpoints([scan])
    assert local[0] == pytest.approx(np.array([[2.0, 0.0]]))  # the 90 m beam is beyond range_max: dropped
    poses = PoseSeries(np.array([0, 10], dtype=np.int64), np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0]]),
                       np.array([_q(math.pi / 2)] * 2))
    pts = _world_points(stamps, local, poses, (0.5, 0.0, 0.0))
    assert pts == pytest.approx(np.array([[1.0, 3.5]]))  # laser 0.5 m ahead (north), beam 2 m further north
    assert len(_world_points(np.array([20], dtype=np.int64), local, poses, (0, 0, 0))) == 0  # outside the span
    uri = raster_png(np.array([[0.0, 0.0], [10.0, 0.0]]), 0.1)
    img = Image.open(io.BytesIO(base64.b64decode(uri.split(",", 1)[1])))
    assert img.size == (141, 41)  # 10 m + 2 m margins at 0.1 m per pixel, +1


def test_relations_table_without_map_says_so():
    result = {"relations_file": "/x/fr079.relations", "relations": None,
              "relations_odometry": {"source": "wheel_odometry", "count": 3, "outside": 1,
                                     "trans_abs_m": {"mean": 1.0, "std": 0.5}, "rot_abs_deg": {"mean": 2.0, "std": 1.0},
                                     "trans_sq_m2": {"mean": 1.25, "std": 0.1}}}
    rows = relations_table(result)
    assert rows[0]["method"] == "this run: map-corrected" and rows[0]["source"] == "no map message"
    assert rows[1]["translation (m)"] == "1.0000 ± 0.5000" and rows[1]["relations"] == "3 (1 outside)"
    assert [r["method"] for r in rows[2:]] == ["scan matching", "GMapping", "graph mapping", "Cartographer"]
    assert all(r["data set"] == "fr079" for r in rows)


def test_laser_offset_comes_from_the_run_or_its_input(tmp_path):
    from eval.report.benchmark import _laser_offset

    imported = tmp_path / "imported.mcap"
    with RecordingWriter(imported) as w:
        w.write("Odometry", Odometry(header=Header(seq=0, stamp=1), position=[0, 0, 0], orientation=_q(0)))
        w.add_metadata("poseidon", {"laser_offsets": {"scan": {"dx": -0.04, "dy": 0.0, "dtheta": 0.0}}})
    run = tmp_path / "run.mcap"
    with RecordingWriter(run) as w:
        w.write("Odometry", Odometry(header=Header(seq=0, stamp=1), position=[0, 0, 0], orientation=_q(0)))
        w.add_metadata("poseidon", {"input": str(imported)})
    assert _laser_offset(imported) == ((-0.04, 0.0, 0.0), None)
    offset, note = _laser_offset(run)
    assert offset == (-0.04, 0.0, 0.0) and note is not None and str(imported) in note
    imported.unlink()
    offset, note = _laser_offset(run)
    assert offset == (0.0, 0.0, 0.0) and note is not None and "robot pose" in note
