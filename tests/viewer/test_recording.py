"""``poseidon view RUN.mcap``: the state served at time t is what the recording holds at t (the
counts and the pose-cell activity); the page and its files are served; bad inputs fail naming
themselves (exit 2)."""
from __future__ import annotations

import base64
import json
import math
import os
import urllib.request
from pathlib import Path

import pytest

from common.mcap_io import read_messages
from common.messages import ExperienceMap, LocalViewCells, PoseCellActivity, PoseStamped
from launcher.cli import main as poseidon
from services.viewer.config import ViewConfig
from services.viewer.live import ViewError
from services.viewer.recording import RecordingView
from services.viewer.server import ViewServer, parse_listen
from tests.viewer.runs import T0, free_port, write_run


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("view") / "run.mcap"
    write_run(path)
    return path


def _held_at(path: Path, t_s: float) -> dict[str, object]:
    """What the recording holds at ``t_s`` after its first message, read independently."""
    end = T0 + int(round(t_s * 1e9)) + 1
    maps = [m.message() for m in read_messages(path, keys=["map"], end_ns=end)]
    lvcs = [m.message() for m in read_messages(path, keys=["local_view_cells"], end_ns=end)]
    poses = [m.message() for m in read_messages(path, keys=["dead_reckoning"], end_ns=end)]
    last_map = maps[-1] if maps else None
    assert last_map is None or isinstance(last_map, ExperienceMap)
    assert all(isinstance(m, LocalViewCells) for m in lvcs) and all(isinstance(p, PoseStamped) for p in poses)
    return {"nodes": len(last_map.nodes) if last_map else 0,
            "loop_closures": sum(lk.loop_closure for lk in last_map.links) if last_map else 0,
            "last_lvc": lvcs[-1].most_active_cell if lvcs else -1,  # type: ignore[union-attr]
            "lvc": len({m.most_active_cell for m in lvcs}),  # type: ignore[union-attr]
            "pose": [round(v, 3) for v in poses[-1].position] if poses else None}  # type: ignore[union-attr]


@pytest.mark.parametrize("t_s", [0.0, 3.05, 7.5, 12.0, 19.9])
def test_the_state_at_t_is_what_the_recording_holds_at_t(run: Path, t_s: float) -> None:
    view = RecordingView(run, ViewConfig())
    counts = view.snapshot({}, t_s)["counts"]
    shown = {"nodes": counts["nodes"], "loop_closures": counts["loop_closures"], "last_lvc": counts["last_lvc"],
             "lvc": counts["lvc"], "pose": counts["pose"][:3] if counts["pose"] else None}
    assert shown == _held_at(run, t_s)


@pytest.mark.parametrize("t_s", [0.0, 0.2, 3.05, 12.0, 19.9])
def test_the_activity_at_t_is_the_recording_s_at_t(run: Path, t_s: float) -> None:
    view = RecordingView(run, ViewConfig())
    snap = view.snapshot({}, t_s)
    held = [m.message() for m in read_messages(run, keys=["posecells/activity"], end_ns=T0 + int(round(t_s * 1e9)) + 1)]
    assert snap["streams"]["activity"] is True
    if not held:  # before the first one
        assert snap["activity_version"] == 0 and "activity" not in snap
        return
    last = held[-1]
    assert isinstance(last, PoseCellActivity)
    got = snap["activity"]
    assert snap["activity_version"] == len(held) and got["stamp"] == last.header.stamp and got["steps"] == last.steps
    for name, img, scale in (("xy", last.xy, last.xy_scale), ("zyaw", last.zyaw, last.zyaw_scale)):
        assert got[name]["shape"] == list(img.shape) and got[name]["scale"] == scale
        assert base64.b64decode(got[name]["data"]) == img.tobytes()
    assert got["centroid"] == [round(v, 3) for v in last.centroid]
    x, y, z, yaw = last.centroid
    assert got["centroid_cells"] == [round(x / 0.1, 2), round(y / 0.1, 2), round(z / 0.1, 2),
                                     round((yaw % (2 * math.pi)) / (math.pi / 4), 2)]
    again = view.snapshot({"activity": str(snap["activity_version"])}, t_s)
    assert "activity" not in again  # the client holds it: not sent again


def test_a_run_without_activity_says_so(tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    write_run(path, seconds=7.0, with_activity=False)  # a map at 5 s
    snap = RecordingView(path, ViewConfig()).snapshot({}, 6.5)
    assert snap["streams"]["activity"] is False and snap["activity_version"] == 0 and "activity" not in snap


def test_scrubbing_back_and_forth_gives_the_same_state(run: Path) -> None:
    view = RecordingView(run, ViewConfig())
    late = view.snapshot({}, 18.0)
    view.snapshot({}, 2.0)
    again = view.snapshot({}, 18.0)
    assert again["counts"] == late["counts"] and again["map"] == late["map"] and again["activity"] == late["activity"]
    assert late["counts"]["loop_closures"] == 1 and late["counts"]["revisits"] > 0
    fresh = RecordingView(run, ViewConfig()).snapshot({}, 18.0)
    assert fresh["trails"] == late["trails"] and fresh["lvc"] == late["lvc"]


def test_a_client_gets_only_what_it_lacks(run: Path) -> None:
    view = RecordingView(run, ViewConfig())
    first = view.snapshot({}, 10.0)
    dr = first["trails"]["dead_reckoning"]
    have = {"map": str(first["map_version"]), "sonar": str(first["sonar_version"]),
            "dead_reckoning": f"{dr['epoch']}.{len(dr['points'])}"}
    later = view.snapshot(have, 10.5)
    assert "map" not in later  # same map version: not sent again
    assert later["trails"]["dead_reckoning"]["start"] == len(dr["points"])
    assert len(later["trails"]["dead_reckoning"]["points"]) == 5  # 0.5 s at 10 Hz


def test_the_camera_frame_at_t_is_a_small_jpeg(run: Path) -> None:
    view = RecordingView(run, ViewConfig())
    snap = view.snapshot({}, 4.2)
    version, jpeg = view.camera()
    assert version == snap["camera_version"] == 9  # frames at 0, 0.5 ... 4.0 s
    assert jpeg[:2] == b"\xff\xd8" and len(jpeg) < 20_000


def test_the_server_serves_the_page_its_files_and_the_state_at_t(run: Path) -> None:
    view = RecordingView(run, ViewConfig())
    server = ViewServer(view, "127.0.0.1", 0)
    server.start()
    try:
        page = urllib.request.urlopen(server.url, timeout=10).read().decode()
        assert '<script src="/static/view.js">' in page and "http" not in page.replace("http-equiv", "")
        for name in ("view.js", "view.css"):
            assert urllib.request.urlopen(server.url + "static/" + name, timeout=10).status == 200
        state = json.loads(urllib.request.urlopen(server.url + "state.json?t=12", timeout=10).read())
        assert state["mode"] == "recording" and state["counts"]["nodes"] == _held_at(run, 12.0)["nodes"]
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(server.url + "static/../config.py", timeout=10)
        assert err.value.code == 404
    finally:
        server.stop()


def test_the_state_carries_the_camera_frame_the_page_lacks(run: Path) -> None:
    """The page gets a new camera frame inside its state poll (no second request per frame)."""
    server = ViewServer(RecordingView(run, ViewConfig()), "127.0.0.1", 0)
    server.start()
    try:
        state = json.loads(urllib.request.urlopen(server.url + "state.json?t=4.2", timeout=10).read())
        assert state["camera_version"] == 9 and base64.b64decode(state["camera_jpeg"])[:2] == b"\xff\xd8"
        held = json.loads(urllib.request.urlopen(server.url + "state.json?t=4.2&camera=9", timeout=10).read())
        assert held["camera_version"] == 9 and "camera_jpeg" not in held
    finally:
        server.stop()


def test_a_recording_without_a_map_is_refused_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "sensors.mcap"
    write_run(path, seconds=3.0, with_map=False)
    with pytest.raises(ViewError, match="holds no experience map"):
        RecordingView(path, ViewConfig())
    assert poseidon(["view", str(path)]) == 2
    assert "sensors.mcap holds no experience map" in capsys.readouterr().err


def test_no_hub_at_the_address_exits_2_naming_it(capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    before = os.sched_getscheduler(0), os.nice(0)
    # view.nice 0: in this process (the test's) a niced view would nice every later test too
    assert poseidon(["view", "--connect", f"tcp/127.0.0.1:{port}", "--set", "view.connect_timeout_s=1",
                     "--set", "view.nice=0"]) == 2
    assert (os.sched_getscheduler(0), os.nice(0)) == before   # a view that never served leaves the caller's priority
    assert f"no hub answers at tcp/127.0.0.1:{port} within 1 s" in capsys.readouterr().err


def test_listen_addresses(tmp_path: Path, run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert parse_listen("8080") == ("127.0.0.1", 8080)
    assert parse_listen("0.0.0.0:81") == ("0.0.0.0", 81)
    with pytest.raises(ValueError, match="'x:y' is not \\[HOST:\\]PORT"):
        parse_listen("x:y")
    assert poseidon(["view", str(run), "--listen", "nohost:99999"]) == 2
    assert "--listen 'nohost:99999' is not [HOST:]PORT" in capsys.readouterr().err
