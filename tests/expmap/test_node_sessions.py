"""The expmap node with a map directory: a loaded map begins a new session and the
node publishes ``map_sessions``; without sessions nothing is published on that key."""
from __future__ import annotations

from pathlib import Path

from common.messages import ExperienceEvent, Header, MapSessions
from common.node import run_offline
from launcher.map_dir import MAP_DIR_FILES, use_map_dir
from system.config import PoseidonConfig
from system.services import build_node
from tests.expmap.helpers import SEC


def events(n: int, x0: float) -> list[tuple[str, ExperienceEvent]]:
    return [("experience_event", ExperienceEvent(
        header=Header(seq=i, stamp=i * SEC, frame_id="map"), lvc_id=1000 + i, pc_centroid=[0.0, 0.0, 0.0, 0.0],
        odom_position=[x0 + i * 0.5, 0.0, 0.0], odom_yaw=0.0, gate="vpr", vpr_count=3)) for i in range(n)]


def test_use_map_dir_points_every_state_into_the_folder(tmp_path: Path) -> None:
    cfg = PoseidonConfig()
    made = use_map_dir(cfg, tmp_path / "m")
    assert (tmp_path / "m").is_dir()
    assert cfg.htm.state_path == str(tmp_path / "m" / MAP_DIR_FILES["htm.state_path"])
    assert cfg.posecells.state_path.startswith(str(tmp_path / "m"))
    assert cfg.expmap.map_path == str(tmp_path / "m" / "expmap.npz") and cfg.expmap.sessions.begin_on_load
    assert cfg.posecells.state_new_odometry_frame, "the loaded pose cells must not lend their odometry"
    assert "{backbone}" in cfg.encoder.embedding_norm.path and len(made) == 6
    (tmp_path / "f").write_text("x")
    try:
        use_map_dir(PoseidonConfig(), tmp_path / "f")
    except ValueError as exc:
        assert "not a directory" in str(exc)
    else:
        raise AssertionError("a file as map dir was accepted")


def test_a_loaded_map_begins_a_session_and_publishes_map_sessions(tmp_path: Path) -> None:
    cfg = PoseidonConfig()
    use_map_dir(cfg, tmp_path)
    cfg.expmap.image.publish_experience = False
    out1 = run_offline(build_node("expmap", cfg), events(10, 0.0))
    assert not [m for k, m in out1 if k == "map_sessions"]          # one session: nothing on the key
    assert (tmp_path / "expmap.npz").exists()
    out2 = run_offline(build_node("expmap", cfg), events(8, 50.0))
    sess = [m for k, m in out2 if k == "map_sessions"]
    maps = [m for k, m in out2 if k == "map"]
    assert sess and isinstance(sess[-1], MapSessions)
    last = sess[-1]
    assert last.header.stamp == maps[-1].header.stamp
    assert last.loaded_nodes == 10 and last.node_session == [0] * 10 + [1] * 8 and not last.links
    # the new session sits in its own odometry frame
    assert maps[-1].nodes[10].position[0] == 50.0
    # saved merged: a third run loads 18 nodes and begins session 2
    out3 = run_offline(build_node("expmap", cfg), events(3, -20.0))
    s3 = [m for k, m in out3 if k == "map_sessions"][-1]
    assert s3.loaded_nodes == 18 and s3.node_session[-1] == 2


def test_without_map_sessions_a_loaded_map_is_continued_in_the_same_frame(tmp_path: Path) -> None:
    cfg = PoseidonConfig()
    cfg.expmap.map_path = str(tmp_path / "m.npz")
    cfg.expmap.image.publish_experience = False
    run_offline(build_node("expmap", cfg), events(5, 0.0))
    out = run_offline(build_node("expmap", cfg), events(3, 2.5))
    assert not [m for k, m in out if k == "map_sessions"]
