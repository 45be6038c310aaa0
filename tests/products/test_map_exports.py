"""``poseidon export --grid / --grid-odometry / --cloud / --cloud-odometry / --survex`` on
synthetic runs made here (a corridor driven there and back with a laser or a sonar), a short
simulated mission through the services, and the real ACES log."""
from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from common.geometry import quaternion_of_yaw
from common.mcap_io import RecordingWriter
from common.messages import (
    ExperienceLink,
    ExperienceMap,
    ExperienceNode,
    Header,
    LaserScan,
    MapSessions,
    Odometry,
    RangeImageBeam,
)
from products.cli import main as export_main
from products.grid import make_grid, sharpness
from products.mapsource import load_map_source

T0 = 1_700_000_000_000_000_000
DT = 200_000_000                     # 5 Hz
WALL_Y = 1.5                         # corridor walls at y = +-1.5 m, x from -1 to 21 m
X_END = (-1.0, 21.0)


def _ray(px: float, py: float, a: float) -> float:
    """Range from (px, py) along angle a to the corridor's walls (m)."""
    c, s = math.cos(a), math.sin(a)
    ts = []
    if abs(s) > 1e-12:
        ts += [(WALL_Y - py) / s, (-WALL_Y - py) / s]
    if abs(c) > 1e-12:
        ts += [(X_END[0] - px) / c, (X_END[1] - px) / c]
    return min(t for t in ts if t > 0)


def _route() -> np.ndarray:
    """(x, y, yaw) every 0.1 m: along the corridor from x=0 to 20, a turn, and back."""
    out = [(x, -0.3, 0.0) for x in np.arange(0.0, 20.0, 0.1)]
    out += [(20.0, -0.3 + 0.6 * k / 10, math.pi * k / 10) for k in range(1, 11)]
    out += [(x, 0.3, math.pi) for x in np.arange(19.9, -0.05, -0.1)]
    return np.array(out)


def _drift(truth: np.ndarray, deg_per_m: float = 0.6) -> np.ndarray:
    """Odometry whose heading drifts by ``deg_per_m`` per metre travelled: each true step turned by
    the heading error accumulated so far."""
    odo = [truth[0].copy()]
    bias = 0.0
    for k in range(1, len(truth)):
        d = truth[k, :2] - truth[k - 1, :2]
        bias += math.radians(deg_per_m) * float(np.hypot(*d))
        c, s = math.cos(bias), math.sin(bias)
        prev = odo[-1]
        odo.append(np.array([prev[0] + c * d[0] - s * d[1], prev[1] + s * d[0] + c * d[1], truth[k, 2] + bias]))
    return np.array(odo)


def _odom(seq: int, t: int, p: np.ndarray) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=t, frame_id="odom"), position=[float(p[0]), float(p[1]), 0.0],
                    orientation=quaternion_of_yaw(float(p[2])))


def _map(truth: np.ndarray, stamps: np.ndarray, sessions: bool) -> tuple[ExperienceMap, MapSessions | None]:
    """Experiences every 0.5 m of the exact route; loop closures where the way back passes the way out."""
    idx = list(range(0, len(truth), 5))
    nodes = [ExperienceNode(id=k, lvc_id=k, position=[float(truth[i, 0]), float(truth[i, 1]), 0.0],
                            yaw=float(truth[i, 2]), stamp=int(stamps[i])) for k, i in enumerate(idx)]
    links = [ExperienceLink(source=k - 1, target=k, delta=[0.0, 0.0, 0.0], duration_s=1.0, weight=1.0)
             for k in range(1, len(nodes))]
    for back, out in ((len(nodes) - 1, 0), (len(nodes) - 21, 20)):
        d = np.array(nodes[out].position) - np.array(nodes[back].position)
        links.append(ExperienceLink(source=back, target=out, delta=[float(v) for v in d], duration_s=0.0, weight=1.0,
                                    loop_closure=True))
    m = ExperienceMap(header=Header(seq=0, stamp=int(stamps[-1]), frame_id="odom"), nodes=nodes, links=links)
    if not sessions:
        return m, None
    half = len(nodes) // 2
    ms = MapSessions(header=Header(seq=0, stamp=int(stamps[-1])), node_session=[0] * half + [1] * (len(nodes) - half),
                     loaded_nodes=0, links=[])
    return m, ms


def make_run(path: Path, sensor: str = "laser", with_map: bool = True, sessions: bool = False,
             drift_deg_per_m: float = 0.6) -> Path:
    """A run recording: ``Odometry`` = the exact route (so the map-corrected poses are exact),
    ``wheel_odometry`` = a drifting odometry, the final map, and laser scans or sonar beams."""
    truth = _route()
    odo = _drift(truth, drift_deg_per_m)
    stamps = T0 + DT * np.arange(len(truth), dtype=np.int64)
    rng = np.random.default_rng(2)
    with RecordingWriter(path) as w:
        for k, t in enumerate(stamps):
            w.write("Odometry", _odom(k, int(t), truth[k]))
            w.write("wheel_odometry", _odom(k, int(t), odo[k]))
            x, y, yaw = truth[k]
            if sensor == "laser":
                a = -math.pi / 2 + np.arange(181) * math.pi / 180
                r = np.array([_ray(x, y, yaw + v) for v in a]) + rng.normal(0, 0.005, 181)
                w.write("scan", LaserScan(header=Header(seq=k, stamp=int(t) + 1, frame_id="laser"),
                                          angle_min=-math.pi / 2, angle_max=math.pi / 2,
                                          angle_increment=math.pi / 180, range_min=0.05, range_max=30.0,
                                          ranges=r.astype(np.float32), intensities=np.full(181, 7.0, np.float32)))
            elif sensor == "sonar":
                for b in range(4):   # four beams at each pose's stamp, the head turning 9 deg per beam (FRD: clockwise)
                    head = math.radians((k * 4 + b) * 9.0 % 360.0)
                    rr = _ray(x, y, yaw - head)          # ENU published frame: FRD bearing -> -head
                    data = np.zeros(200, np.int32)
                    if rr < 20.0:
                        data[int(rr / 20.0 * 200)] = 150
                    w.write("sonar_micron", RangeImageBeam(header=Header(seq=k * 4 + b, stamp=int(t), frame_id="sonar"),
                                                           angle_grad=head * 200 / math.pi, angle_rad=head, nbins=200,
                                                           max_range=20, beam_data=data))
        if with_map:
            m, ms = _map(truth, stamps, sessions)
            w.write("map", m)
            if ms is not None:
                w.write("map_sessions", ms)
    return path


def _export(*args: str) -> tuple[int, dict[str, Any]]:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = export_main([*args, "--json"])
    return code, (json.loads(buf.getvalue()) if code == 0 else {})


def _read_grid(d: Path) -> tuple[np.ndarray, dict[str, Any]]:
    from PIL import Image

    meta = yaml.safe_load((d / "map.yaml").read_text())
    img = np.asarray(Image.open(d / meta["image"]))
    return img, meta


def test_grid_matches_its_yaml_and_the_walls(tmp_path: Path) -> None:
    run = make_run(tmp_path / "run.mcap")
    code, out = _export(str(run), "--grid", str(tmp_path / "g"), "--grid-odometry", str(tmp_path / "go"))
    assert code == 0
    grid, grid_odo = out["exports"]
    img, meta = _read_grid(tmp_path / "g")
    assert meta["resolution"] == pytest.approx(0.05) and meta["mode"] == "trinary" and meta["negate"] == 0
    assert meta["origin"] == pytest.approx(grid["origin"]) and img.shape == (grid["height"], grid["width"])
    assert set(np.unique(img)) <= {0, 205, 254}
    # every occupied cell's centre lies on a wall (within 1.5 cells), and the long walls are drawn
    rows, cols = np.nonzero(img == 0)
    x = meta["origin"][0] + (cols + 0.5) * meta["resolution"]
    y = meta["origin"][1] + (img.shape[0] - rows - 0.5) * meta["resolution"]
    off = np.minimum(np.abs(np.abs(y) - WALL_Y), np.minimum(np.abs(x - X_END[0]), np.abs(x - X_END[1])))
    assert len(x) > 500 and np.max(off) <= 1.5 * meta["resolution"]
    for wall in (WALL_Y, -WALL_Y):
        on = np.abs(y - wall) < 0.1
        assert np.ptp(x[on]) > 19.0, f"the wall at y={wall} m is not drawn end to end"
    # free space inside the corridor, on the robot's line
    col = int((10.0 - meta["origin"][0]) / meta["resolution"])
    row = img.shape[0] - 1 - int((0.0 - meta["origin"][1]) / meta["resolution"])
    assert img[row, col] == 254
    # the doubled wall of the drifting odometry shows as a worse sharpness, printed beside it
    assert grid["sharpness"] > 0.8 > grid_odo["sharpness"] + 0.2
    assert grid["sharpness_odometry"] == pytest.approx(grid_odo["sharpness"])
    assert grid_odo["trajectory"] == "odometry" and "sharpness_odometry" not in grid_odo
    assert "frame:" in (tmp_path / "g" / "map.yaml").read_text()


def test_sharpness_falls_with_the_drift(tmp_path: Path) -> None:
    figures = []
    for drift in (0.0, 0.3, 1.0):
        src = load_map_source(make_run(tmp_path / f"d{drift}.mcap", drift_deg_per_m=drift))
        figures.append(sharpness(make_grid(src.returns(src.poses("odometry"), horizontal_only=True), 0.05)))
    assert figures[0] is not None and figures[0] > 0.8
    assert figures[0] > figures[1] > figures[2]   # type: ignore[operator]


def test_cloud_reads_back_with_its_fields(tmp_path: Path) -> None:
    from plyfile import PlyData

    run = make_run(tmp_path / "run.mcap")
    code, out = _export(str(run), "--cloud", str(tmp_path / "c.ply"), "--cloud-odometry", str(tmp_path / "co.ply"))
    assert code == 0
    entry = out["exports"][0]
    ply = PlyData.read(str(tmp_path / "c.ply"))
    assert ply.text is False and ply.byte_order == "<"
    v = ply["vertex"]
    assert len(v.data) == entry["points"] > 60_000
    assert [p.name for p in v.properties] == entry["fields"] == ["x", "y", "z", "time", "intensity", "experience",
                                                                 "sensor"]
    assert any("frame:" in c for c in ply.comments) and any("left out:" in c for c in ply.comments)
    # exact poses: every point on a wall; time in s of the input clock; experience ids in time order
    off = np.minimum(np.abs(np.abs(v["y"]) - WALL_Y), np.minimum(np.abs(v["x"] - X_END[0]), np.abs(v["x"] - X_END[1])))
    assert np.max(off) < 0.05
    assert v["time"].min() == pytest.approx(T0 / 1e9, abs=1e-3) and np.all(np.diff(v["time"]) >= 0)
    assert np.all(np.diff(v["experience"]) >= 0) and v["experience"].min() == 0
    assert np.all(v["intensity"] == 7.0)
    odo = PlyData.read(str(tmp_path / "co.ply"))["vertex"]
    assert len(odo.data) == len(v.data) and np.max(np.hypot(odo["x"] - v["x"], odo["y"] - v["y"])) > 1.0


def test_sonar_run_gives_grid_cloud_and_lrud(tmp_path: Path) -> None:
    from plyfile import PlyData

    run = make_run(tmp_path / "sonar.mcap", sensor="sonar")
    code, out = _export(str(run), "--grid", str(tmp_path / "g"), "--cloud", str(tmp_path / "c.ply"),
                        "--survex", str(tmp_path / "s.svx"))
    assert code == 0
    grid, cloud, svx = out["exports"]
    assert grid["sensor"] == "sonar_micron" and grid["occupied_cells"] > 100
    v = PlyData.read(str(tmp_path / "c.ply"))["vertex"]
    off = np.minimum(np.abs(np.abs(v["y"]) - WALL_Y), np.minimum(np.abs(v["x"] - X_END[0]), np.abs(v["x"] - X_END[1])))
    assert len(v.data) == cloud["points"] > 1000 and np.max(off) < 0.1   # the echo bin is 0.1 m deep
    # left + right = the corridor's width (3 m; the echo bins are 0.1 m) away from its ends and the turn
    rows = [ln.split() for ln in _passage_rows((tmp_path / "s.svx").read_text())]
    lr = np.array([[float(r[1]), float(r[2])] for r in rows if r[1] != "-" and r[2] != "-"])
    width = lr.sum(axis=1)
    assert len(lr) > 10 and abs(np.median(width) - 2 * WALL_Y) < 0.1
    assert np.mean(np.abs(width - 2 * WALL_Y) < 0.15) > 0.8
    assert all(r[3] == "-" and r[4] == "-" for r in rows)     # a horizontal sonar sees no roof or floor
    assert svx["lrud_stations"] >= len(lr)


def _passage_rows(svx: str) -> list[str]:
    out, on = [], False
    for line in svx.splitlines():
        if line.startswith("*"):
            on = line.startswith("*data passage")
            continue
        if on and line.strip() and not line.startswith(";"):
            out.append(line)
    return out


def _cavern(svx: Path) -> tuple[str, str]:
    """cavern's stdout and .err text for ``svx`` (skip when Survex is not installed)."""
    if shutil.which("cavern") is None:
        pytest.skip("cavern (Debian package survex) is not installed: deploy/setup.sh installs it as root")
    res = subprocess.run(["cavern", "--output", str(svx.parent), str(svx)], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "error" not in (res.stdout + res.stderr).lower(), res.stdout + res.stderr
    err = svx.with_suffix(".err")
    return res.stdout, err.read_text() if err.exists() else ""


def _survey_length(stdout: str) -> float:
    m = re.search(r"Total length of survey legs =\s*([\d.]+)m", stdout)
    assert m, stdout
    return float(m.group(1))


def _misclosures(err: str) -> list[tuple[str, float]]:
    """(traverse, moved m) of every traverse cavern adjusted (its .err file)."""
    out = []
    for block in err.strip().split("\n\n"):
        lines = block.splitlines()
        m = re.search(r"moved\s+([\d.]+)m", block)
        if lines and m:
            out.append((lines[0], float(m.group(1))))
    return out


def test_survex_of_a_synthetic_two_session_map_goes_through_cavern(tmp_path: Path) -> None:
    run = make_run(tmp_path / "run.mcap", sessions=True)
    code, out = _export(str(run), "--survex", str(tmp_path / "map.svx"), "--survex-spacing", "2")
    assert code == 0
    e = out["exports"][0]
    text = (tmp_path / "map.svx").read_text()
    assert e["sessions"] == 2 and "*begin s0" in text and "*begin s1" in text and text.count("*equate") == 2
    assert e["loop_closures"] == 2 and text.count("*fix") == 1   # session 1 is joined to 0 by a loop closure
    assert "*date 2023.11.14" in text and "code revision" in text
    stdout, err = _cavern(tmp_path / "map.svx")
    assert _survey_length(stdout) == pytest.approx(e["length_m"], rel=0.01)
    # the map is exact and its loop closures measured exactly: nothing to distribute
    assert _misclosures(err) and max(m for _, m in _misclosures(err)) < 0.01


def test_export_names_what_is_missing_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    no_map = make_run(tmp_path / "nomap.mcap", with_map=False)
    for flag, out, word in (("--grid", "g", "'map'"), ("--cloud", "c.ply", "'map'"), ("--survex", "s.svx", "'map'")):
        assert export_main([str(no_map), flag, str(tmp_path / out)]) == 2
        assert word in capsys.readouterr().err and not (tmp_path / out).exists()
    bare = make_run(tmp_path / "bare.mcap", sensor="none")
    assert export_main([str(bare), "--grid-odometry", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err
    assert "'scan'" in err and "'sonar_micron'" in err and not (tmp_path / "g").exists()
    # an existing output stays as it was
    (tmp_path / "keep.ply").write_text("mine")
    assert export_main([str(no_map), "--cloud-odometry", str(tmp_path / "keep.ply")]) == 2
    assert (tmp_path / "keep.ply").read_text() == "mine" and "exists" in capsys.readouterr().err
    assert export_main([str(no_map), "--grid-odometry", str(tmp_path / "g"), "--resolution", "0"]) == 2
    assert "--resolution" in capsys.readouterr().err and not list(tmp_path.glob("**/*.partial"))


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 0.5 min simulated cave mission (seed 3, 4.5 m/s) run through every service (embedded)."""
    from launcher.run import run_embedded
    from missions.sim.mission import SimParams, generate
    from system.config import load_config

    d = tmp_path_factory.mktemp("simrun")
    generate(d / "sim.mcap", SimParams(minutes=0.5, seed=3, speed_m_s=4.5), progress=False)
    cfg = load_config(overrides=[f"encoder.lsbh.matrix_path={d}/lsbh_{{backbone}}_{{modality}}.npy"])
    run_embedded(cfg, d / "sim.mcap", d / "run.mcap", progress=False, timeout_s=400)
    return d / "run.mcap"


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_survex_of_a_sim_run_goes_through_cavern(sim_run: Path, tmp_path: Path) -> None:
    from plyfile import PlyData

    svx = tmp_path / "sim.svx"
    code, out = _export(str(sim_run), "--survex", str(svx), "--cloud", str(tmp_path / "sim.ply"))
    assert code == 0
    cloud, e = out["exports"]
    assert e["legs"] > 10 and e["lrud_stations"] > 0.5 * e["stations"]
    stdout, err = _cavern(svx)
    assert _survey_length(stdout) == pytest.approx(e["length_m"], rel=0.01)
    loops = re.search(r"There (?:is|are) (\d+) loops?", stdout)
    assert (int(loops.group(1)) if loops else 0) == e["equates"]
    assert len([m for m in _misclosures(err) if m[1] > 0]) <= e["equates"]
    # the sim's cloud: the horizontal sonar and the vertical profiler, 3D
    v = PlyData.read(str(tmp_path / "sim.ply"))["vertex"]
    assert len(v.data) == cloud["points"] and cloud["sensors"] == ["sonar_micron", "sonar_seaking"]
    assert np.ptp(v["z"][v["sensor"] == 1]) > 1.0


@pytest.mark.timeout(120)
def test_aces_wall_lands_in_the_cells_of_the_report_point_map(shared_data: Path, tmp_path: Path) -> None:
    """The raw-odometry grid of the real ACES log against the report's laser point map (raw odometry panel)."""
    from eval.report.benchmark import _laser_offset, _world_points, scan_endpoints
    from missions.importers.cli import main as import_main

    rec = tmp_path / "aces.mcap"
    assert import_main([str(shared_data / "radish" / "aces.clf.bz2"), "--out", str(rec)]) == 0
    code, out = _export(str(rec), "--grid-odometry", str(tmp_path / "g"))
    assert code == 0
    img, meta = _read_grid(tmp_path / "g")
    src = load_map_source(rec)
    assert src.laser is not None and src.raw_name == "wheel_odometry"
    stamps, local = scan_endpoints([s for s in _scans(rec)])
    pts = _world_points(stamps, local, src.poses("odometry"), _laser_offset(rec)[0])
    res, (ox, oy) = meta["resolution"], meta["origin"][:2]
    col = np.floor((pts[:, 0] - ox) / res).astype(int)
    row = img.shape[0] - 1 - np.floor((pts[:, 1] - oy) / res).astype(int)
    counts = np.zeros(img.shape, int)
    np.add.at(counts, (row, col), 1)
    occupied = img == 0
    near_points = np.zeros_like(occupied)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near_points |= np.roll(np.roll(counts > 0, dr, 0), dc, 1)
    # every occupied cell holds (or touches) beam end points of the point map
    assert occupied.sum() > 5000 and np.mean(near_points[occupied]) > 0.99
    # the point map's walls (its 2000 densest cells: walls seen over and over) are occupied in the grid,
    # within one cell; a smeared wall of the raw odometry is partly cleared by later rays, so not all
    walls = counts >= np.sort(counts.ravel())[-2000]
    near_occ = np.zeros_like(occupied)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near_occ |= np.roll(np.roll(occupied, dr, 0), dc, 1)
    print(f"ACES walls: {np.mean(near_occ[walls]):.3f} of the point map's {walls.sum()} densest cells occupied")
    assert np.mean(near_occ[walls]) > 0.9


def _scans(rec: Path) -> list[LaserScan]:
    from common.mcap_io import read_messages

    return [m for m in (r.message() for r in read_messages(rec, keys=["scan"])) if isinstance(m, LaserScan)]
