"""Experience map node through common.node.run_offline with hand-made messages."""
from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.codec import decode, encode
from common.mcap_io import RecordingWriter
from common.messages import (
    ExperienceEvent,
    ExperienceImage,
    ExperienceMap,
    Header,
    Image,
    Message,
    Odometry,
    PoseStamped,
)
from common.node import run_offline
from services.expmap.graph import ExperienceMap as Graph
from services.expmap.node import ExpMapNode
from services.expmap.path import main as path_main
from system.config import PoseidonConfig
from system.services import build_node
from tests.expmap.helpers import SEC, Event, loop_laps

MS = 1_000_000


def frame(seq: int, stamp: int) -> Image:
    data = np.full((4, 6, 3), seq % 256, np.uint8)
    return Image(header=Header(seq=seq, stamp=stamp, frame_id="camera"), height=4, width=6, data=data)


def event(seq: int, stamp: int, lvc: int = 0, odom: Sequence[float] = (0.0, 0.0, 0.0),
          pc: Sequence[float] = (0.0, 0.0, 0.0, 0.0)) -> ExperienceEvent:
    return ExperienceEvent(header=Header(seq=seq, stamp=stamp, frame_id="map"), lvc_id=lvc, pc_centroid=list(pc),
                           odom_position=list(odom), odom_yaw=0.3, gate="vpr", vpr_count=3)


def odometry(seq: int, stamp: int, pos: Sequence[float], yaw: float) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=stamp, frame_id="world"), position=list(pos),
                    orientation=[0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def outputs(out: list[tuple[str, Message]], key: str) -> list[Any]:
    """The messages on ``key`` (typed loosely: each test reads the fields of its key's type)."""
    return [m for k, m in out if k == key]


def test_every_experience_image_carries_its_event_header() -> None:
    # camera at 5 Hz from 0 to 2 s, then nothing until 4 s, then 4.0 and 4.2 s
    frames = [frame(i, i * 200 * MS) for i in range(11)] + [frame(11, 4000 * MS), frame(12, 4200 * MS)]
    events = [event(0, 400 * MS),          # exactly on a frame
              event(1, 530 * MS),          # 0.53: frame 0.6 is closer than 0.4 (decided when 0.6 arrives)
              event(2, 700 * MS),          # tie 0.6 / 0.8: the earlier frame
              event(3, 3000 * MS),         # nearest frames 2.0 and 4.0 s: beyond 0.75 s -> no image
              event(4, 3300 * MS),         # 4.0 is 0.7 s later: within the window
              event(5, 4500 * MS)]         # after the last frame: decided at the end of the inputs
    node = build_node("expmap", PoseidonConfig())
    out = run_offline(node, [("camera/image_raw", f) for f in frames] + [("experience_event", e) for e in events])
    imgs = outputs(out, "experience_image")
    by_seq = {m.header.seq: m for m in imgs}
    assert sorted(by_seq) == [0, 1, 2, 4, 5]
    for e in events:
        if e.header.seq in by_seq:
            assert by_seq[e.header.seq].header == e.header
    src = {s: m.source_stamp for s, m in by_seq.items()}
    assert src == {0: 400 * MS, 1: 600 * MS, 2: 600 * MS, 4: 4000 * MS, 5: 4200 * MS}
    assert int(by_seq[1].data[0, 0, 0]) == 3                          # the pixels of frame 3 (0.6 s)
    assert node.counters["events_without_image"] == 1 and node.counters["experience_images"] == 5
    assert [m.header.seq for m in imgs] == sorted(m.header.seq for m in imgs)  # event order
    for m in imgs:                                                    # survives the wire
        back = decode(encode(m), ExperienceImage)
        assert back.header == m.header and np.array_equal(back.data, m.data)


def test_watermark_is_held_until_the_image_is_decided() -> None:
    node = build_node("expmap", PoseidonConfig())
    node.process("camera/image_raw", frame(0, 0))
    node.process("experience_event", event(0, 100 * MS))
    assert node.take_outbox() == []
    assert node.output_watermark(150 * MS) == 100 * MS
    node.process("camera/image_raw", frame(1, 200 * MS))
    (key, img), = node.take_outbox()
    assert key == "experience_image" and isinstance(img, ExperienceImage) and img.source_stamp == 0
    assert node.output_watermark(200 * MS) == 200 * MS


def test_event_without_camera_when_images_are_off() -> None:
    cfg = PoseidonConfig()
    cfg.expmap.image.publish_experience = False
    assert "camera/image_raw" in build_node("expmap", cfg).inputs, "the camera's odometry scale reads the frames"
    cfg.expmap.visual_scale.enabled = False
    node = build_node("expmap", cfg)
    assert "camera/image_raw" not in node.inputs
    out = run_offline(node, [("camera/image_raw", frame(0, 0)), ("experience_event", event(0, 0))])
    assert outputs(out, "experience_image") == [] and node.counters["events"] == 1


def stream(events: Iterable[Event], with_odometry: bool = True) -> list[tuple[str, Message]]:
    msgs: list[tuple[str, Message]] = []
    for i, (t, lvc, pc, odom) in enumerate(events):
        stamp = int(round(t * SEC))
        msgs.append(("experience_event", event(i, stamp, lvc, odom, pc)))
        if with_odometry:
            msgs.append(("Odometry", odometry(i, stamp, odom, 0.1 * i)))
    return msgs


def test_map_cadence_and_final_map_equal_the_core() -> None:
    events, _ = loop_laps(3)
    cfg = PoseidonConfig()
    cfg.expmap.map_publish_every = 200
    node = build_node("expmap", cfg)
    out = run_offline(node, stream(events))
    core = Graph(cfg.expmap)
    for t, lvc, pc, odom in events:
        core.add_event(int(round(t * SEC)), lvc, pc, odom, 0.3)
    core.settle()
    maps = outputs(out, "map")
    closures = node.counters["loop_closures"]
    assert closures == len(core.loops) >= 2
    # after each closure, each settled correction, every 200 events, and the end
    assert closures + 4 <= len(maps) <= 2 * closures + 4 + 1
    final = maps[-1]
    assert len(final.nodes) == core.n_nodes and final.corrections == closures
    np.testing.assert_array_equal(np.array([n.position for n in final.nodes]), core.positions)
    loops = [(ln.source, ln.target) for ln in final.links if ln.loop_closure]
    assert loops == [(m, n) for m, n, _w, _s in core.loops]
    assert [n.stamp for n in final.nodes] == [int(round(e[0] * SEC)) for e in events]
    back = decode(encode(final), ExperienceMap)
    assert back.nodes[5].position == final.nodes[5].position and len(back.links) == len(final.links)
    assert [m.header.seq for m in maps] == list(range(len(maps)))
    assert all(b.header.stamp >= a.header.stamp for a, b in zip(maps, maps[1:]))
    dr = outputs(out, "dead_reckoning")
    assert len(dr) == len(events) and isinstance(dr[0], PoseStamped)
    assert dr[7].yaw == pytest.approx(0.7) and dr[7].position == list(events[7][3])


def test_dead_reckoning_decimation() -> None:
    cfg = PoseidonConfig()
    cfg.expmap.dead_reckoning_period_sec = 0.5
    msgs = [("Odometry", odometry(i, i * 100 * MS, (i, 0, 0), 0.0)) for i in range(20)]
    out = run_offline(build_node("expmap", cfg), msgs)
    assert [m.header.stamp for _k, m in out] == [0, 500 * MS, 1000 * MS, 1500 * MS]


def test_invalid_event_is_counted_and_skipped() -> None:
    node = build_node("expmap", PoseidonConfig())
    run_offline(node, [("experience_event", event(0, 0)),
                       ("experience_event", event(1, SEC, odom=(float("nan"), 0.0, 0.0))),
                       ("experience_event", event(2, 2 * SEC, odom=(1.0, 0.0, 0.0)))])
    assert node.counters["events"] == 2 and node.counters["events_invalid"] == 1
    assert node.graph.n_nodes == 2


def test_two_sessions_with_map_path_equal_one_run(tmp_path: Path) -> None:
    events, _ = loop_laps(3)
    cfg = PoseidonConfig()
    one = build_node("expmap", cfg)
    final_one = outputs(run_offline(one, stream(events, with_odometry=False)), "map")[-1]
    # split where no correction is pending (the end of a session settles it)
    probe = Graph(cfg.expmap)
    split = None
    for i, (t, lvc, pc, odom) in enumerate(events):
        probe.add_event(int(round(t * SEC)), lvc, pc, odom, 0.3)
        if i > 450 and probe.corrections >= 1 and not probe.pending:
            split = i + 1
            break
    assert split is not None
    cfg.expmap.map_path = str(tmp_path / "cave.npz")
    run_offline(build_node("expmap", cfg), stream(events[:split], with_odometry=False))
    second = build_node("expmap", cfg)
    assert second.graph.n_nodes == split
    msgs = [(k, m) for k, m in stream(events, with_odometry=False)][split:]
    final_two = outputs(run_offline(second, msgs), "map")[-1]
    assert final_two.model_dump(exclude={"header"}) == final_one.model_dump(exclude={"header"})


def test_poseidon_path_on_a_map_file_and_a_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    events, _ = loop_laps(2)
    cfg = PoseidonConfig()
    cfg.expmap.map_path = str(tmp_path / "m.npz")
    out = run_offline(build_node("expmap", cfg), stream(events, with_odometry=False))
    assert path_main([cfg.expmap.map_path, "--from", "5", "--to", "310", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    # back to node 1, the loop edge 1 <-> 301 (0 s), then forward: 4 + 9 edges of 0.5 s
    assert res["nodes"] == [5, 4, 3, 2, 1] + list(range(301, 311))
    assert res["duration_s"] == pytest.approx(6.5) and res["length_m"] > 0
    assert res["hops"] == len(res["nodes"]) - 1
    rec = tmp_path / "run.mcap"
    with RecordingWriter(rec) as w:
        for k, m in out:
            w.write(k, m)
    assert path_main([str(rec), "--from", "5", "--to", "310", "--json"]) == 0
    res2 = json.loads(capsys.readouterr().out)
    assert res2["nodes"] == res["nodes"] and res2["duration_s"] == pytest.approx(res["duration_s"])
    assert path_main([str(rec), "--from", "0", "--to", "100000"]) == 2
    assert "--to 100000" in capsys.readouterr().err


def test_laser_scans_make_a_scan_graph_map() -> None:
    """expmap.graph=scan_graph: LaserScan + Odometry + events through the node; the scans
    reach the core in each experience's own frame and the published map carries its yaws."""
    from common.messages import LaserScan
    from services.expmap.scan_graph import ScanGraph
    from tests.expmap.laser_world import drifting_odometry, raycast, ring_route, ring_world

    cfg = PoseidonConfig().model_copy(deep=True)
    cfg.expmap.graph = "scan_graph"
    cfg.expmap.scan.topic = "scan"
    cfg.expmap.loops.scan_matching = False
    cfg.expmap.image.publish_experience = False
    truth = ring_route(laps=2, step=0.5)[:150]
    odo = drifting_odometry(truth, yaw_drift_deg_per_m=0.4, scale=1.01)
    rng = np.random.default_rng(1)
    msgs: list[tuple[str, Message]] = []
    for k, (t, o) in enumerate(zip(truth, odo)):
        stamp = (k + 1) * 1_000_000_000
        ranges = raycast(ring_world(), t, noise=0.01, rng=rng).astype(np.float32)
        msgs.append(("Odometry", odometry(k, stamp - 2 * MS, (o[0], o[1], 0.0), float(o[2]))))
        msgs.append(("scan", LaserScan(header=Header(seq=k, stamp=stamp - MS, frame_id="laser"),
                                       angle_min=-math.pi / 2, angle_max=math.pi / 2, angle_increment=math.pi / 180,
                                       range_min=0.0, range_max=30.0, ranges=ranges,
                                       intensities=np.zeros(0, np.float32))))
        ev = ExperienceEvent(header=Header(seq=k, stamp=stamp, frame_id="map"), lvc_id=k, pc_centroid=[0.0] * 4,
                             odom_position=[float(o[0]), float(o[1]), 0.0], odom_yaw=float(o[2]), gate="off",
                             vpr_count=1)
        msgs.append(("experience_event", ev))
    node = build_node("expmap", cfg)
    assert "scan" in ExpMapNode.io_keys(cfg.expmap)[0]
    out = run_offline(node, msgs)
    assert isinstance(node.graph, ScanGraph)
    final = outputs(out, "map")[-1]
    assert len(final.nodes) == 150 and node.counters["loop_closures"] >= 1
    assert node.counters["scans"] == 150 and node.counters["chain_scan"] >= 140
    assert any(link.loop_closure for link in final.links)
    yaw_err = [abs(math.remainder(n.yaw - truth[n.id, 2] + truth[0, 2] - final.nodes[0].yaw, 2 * math.pi))
               for n in final.nodes]
    assert max(yaw_err) < math.radians(2.0)
    # every scan after the first experience is registered against the newest experience's local map
    assert "scan_pose" in ExpMapNode.io_keys(cfg.expmap)[1]
    poses = outputs(out, "scan_pose")
    scan_stamps = {m.header.stamp for k, m in msgs if k == "scan"}
    assert len(poses) == node.counters["scan_pose"] >= 140
    assert all(p.header.stamp in scan_stamps for p in poses)
    for p in poses:   # scan k is taken 1 ms before experience k, from the same place
        assert p.experience_id == (p.header.stamp + MS) // 1_000_000_000 - 1
        assert abs(math.degrees(p.pose[2])) < 0.5 and math.hypot(p.pose[0], p.pose[1]) < 0.05
    cfg.expmap.scan_graph.scan_poses = False
    assert "scan_pose" not in ExpMapNode.io_keys(cfg.expmap)[1]


def test_laser_scan_without_scan_graph_is_a_configuration_error() -> None:
    from common.config import ConfigError
    from common.messages import LaserScan

    cfg = PoseidonConfig().model_copy(deep=True)
    cfg.expmap.scan.topic = "scan"
    node = build_node("expmap", cfg)
    node.process("Odometry", odometry(0, 1, (0.0, 0.0, 0.0), 0.0))
    scan = LaserScan(header=Header(seq=0, stamp=2, frame_id="laser"), angle_min=-1.0, angle_max=1.0,
                     angle_increment=1.0, range_min=0.0, range_max=10.0, ranges=np.ones(3, np.float32),
                     intensities=np.zeros(0, np.float32))
    with pytest.raises(ConfigError, match="scan_graph"):
        node.process("scan", scan)


def test_laser_sensor_offset_places_returns_in_the_robot_frame() -> None:
    """A return 1 m straight ahead of a laser mounted 0.5 m forward and turned 90 degrees
    left lies at (0.5, 1.0) in the robot frame; the experience keeps it there."""
    from common.messages import LaserScan
    from services.expmap.scan_graph import ScanGraph

    cfg = PoseidonConfig().model_copy(deep=True)
    cfg.expmap.graph = "scan_graph"
    cfg.expmap.scan.topic = "scan"
    cfg.expmap.loops.scan_matching = False
    cfg.expmap.image.publish_experience = False
    cfg.expmap.scan_graph.sensor_offset = [0.5, 0.0, 90.0]
    cfg.expmap.scan_graph.min_points = 3
    node = build_node("expmap", cfg)
    node.process("Odometry", odometry(0, 10, (2.0, 3.0, 0.0), math.pi / 2))
    scan = LaserScan(header=Header(seq=0, stamp=20, frame_id="laser"), angle_min=0.0, angle_max=0.0,
                     angle_increment=0.0, range_min=0.0, range_max=10.0, ranges=np.array([1.0], np.float32),
                     intensities=np.zeros(0, np.float32))
    node.process("scan", scan)
    node.process("experience_event", ExperienceEvent(
        header=Header(seq=0, stamp=30, frame_id="map"), lvc_id=0, pc_centroid=[0.0] * 4,
        odom_position=[2.0, 3.0, 0.0], odom_yaw=math.pi / 2, gate="off", vpr_count=1))
    assert isinstance(node.graph, ScanGraph)
    assert node.graph.n_nodes == 0          # the experience waits for the odometry after its stamp
    node.process("Odometry", odometry(1, 40, (2.0, 3.0, 0.0), math.pi / 2))
    assert node.graph.n_nodes == 1
    kept = node.graph.scan(0)
    assert kept is not None and kept.shape == (1, 2)
    np.testing.assert_allclose(kept[0], [0.5, 1.0], atol=1e-9)


def test_a_correction_map_waits_for_nodes_over_divisor_events() -> None:
    """expmap.map_correction_divisor: the map owed to a loop closure (or a settled correction)
    comes once nodes/N events have passed since the last map; at once with 0.  The final map is
    the same either way."""
    events, _ = loop_laps(3)
    D = 3                                        # waits long enough here to merge corrections
    runs = {}
    for div in (0, D):
        cfg = PoseidonConfig()
        cfg.expmap.map_publish_every = 0          # only the maps owed to corrections, and the end
        cfg.expmap.map_correction_divisor = div
        node = build_node("expmap", cfg)
        runs[div] = (node, outputs(run_offline(node, stream(events)), "map"))
    (node0, maps0), (node20, maps20) = runs[0], runs[D]
    assert node0.counters["loop_closures"] == node20.counters["loop_closures"] >= 2
    assert len(maps20) < len(maps0)
    stamp_of = {int(round(e[0] * SEC)): i for i, e in enumerate(events)}
    at20 = [stamp_of[m.header.stamp] for m in maps20]
    # every map waited nodes/D events after the previous one (the last: the end of the inputs)
    assert all(b - a >= (b + 1) // D for a, b in zip(at20, at20[1:-1]))
    # every correction of the undelayed run is in a map of the delayed one within nodes/D + 1 events
    for i in (stamp_of[m.header.stamp] for m in maps0[:-1]):
        assert any(i <= j <= i + (j + 1) // D + 1 for j in at20), i
    assert [n.position for n in maps20[-1].nodes] == [n.position for n in maps0[-1].nodes]


def test_a_laser_experience_takes_the_odometry_at_its_own_stamp() -> None:
    """The robot turns 20 degrees between two Odometry poses; the event halfway between them
    gets the pose halfway (10 degrees), not the older pose the event carries."""
    from services.expmap.scan_graph import ScanGraph

    cfg = PoseidonConfig().model_copy(deep=True)
    cfg.expmap.graph = "scan_graph"
    cfg.expmap.scan.topic = "scan"
    cfg.expmap.loops.scan_matching = False
    cfg.expmap.image.publish_experience = False
    node = build_node("expmap", cfg)
    node.process("Odometry", odometry(0, 100, (0.0, 0.0, 0.0), 0.0))
    node.process("experience_event", ExperienceEvent(
        header=Header(seq=0, stamp=150, frame_id="map"), lvc_id=0, pc_centroid=[0.0] * 4,
        odom_position=[0.0, 0.0, 0.0], odom_yaw=0.0, gate="off", vpr_count=1))
    node.process("Odometry", odometry(1, 200, (1.0, 0.0, 0.0), math.radians(20.0)))
    assert isinstance(node.graph, ScanGraph) and node.graph.n_nodes == 1
    np.testing.assert_allclose(node.graph._odom[0], [0.5, 0.0, math.radians(10.0)], atol=1e-12)
    cfg.expmap.scan_graph.odometry_at_stamps = False       # the previous rule: the pose the event carries
    old = build_node("expmap", cfg)
    old.process("Odometry", odometry(0, 100, (0.0, 0.0, 0.0), 0.0))
    old.process("experience_event", ExperienceEvent(
        header=Header(seq=0, stamp=150, frame_id="map"), lvc_id=0, pc_centroid=[0.0] * 4,
        odom_position=[0.0, 0.0, 0.0], odom_yaw=0.0, gate="off", vpr_count=1))
    assert isinstance(old.graph, ScanGraph) and old.graph.n_nodes == 1
    np.testing.assert_allclose(old.graph._odom[0], [0.0, 0.0, 0.0], atol=1e-12)
