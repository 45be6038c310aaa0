"""PoseCellsNode through common.node.run_offline on hand-made Odometry + LocalViewCells streams."""
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.messages import ExperienceEvent, Header, LocalViewCell, LocalViewCells, Message, Odometry
from common.node import run_offline
from services.posecells.node import yaw_of_quaternion
from system.config import PoseidonConfig
from system.services import build_node

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
LATTICE_M = 1.5


def odom(seq: int, stamp: int, pos: Sequence[float], yaw: float) -> Odometry:
    return Odometry(header=Header(seq=seq, stamp=stamp, frame_id="odom_enu"), child_frame_id="base_link",
                    position=[float(v) for v in pos], orientation=[0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])


def lvc(seq: int, stamp: int, cell: int, extra: Iterable[tuple[int, float]] = ()) -> LocalViewCells:
    cells = [LocalViewCell(id=cell, rate=0.6)] + [LocalViewCell(id=i, rate=r) for i, r in extra]
    return LocalViewCells(header=Header(seq=seq, stamp=stamp, frame_id="camera"), most_active_cell=cell,
                          active_cells=cells, is_new=False, intersection=12)


def trajectory(t: float) -> tuple[tuple[float, float, float], float]:
    """A descending turn: 0.2 m/s, yaw rate 0.05 rad/s, 2 cm/s down (ENU)."""
    yaw = 0.3 + 0.05 * t
    x = 2.0 + 4.0 * (math.sin(yaw) - math.sin(0.3))
    y = -1.0 - 4.0 * (math.cos(yaw) - math.cos(0.3))
    return (x, y, -3.0 - 0.02 * t), yaw


def stream(seconds: float = 60.0, ids: Callable[[int], int] = lambda k: k // 4, odom_hz: float = 10.0,
           frame_hz: float = 4.0, odom_delay_s: float = 0.0) -> list[tuple[str, Message]]:
    msgs: list[tuple[str, Message]] = []
    n_odom = int(seconds * odom_hz)
    for k in range(n_odom):
        t = odom_delay_s + k / odom_hz
        pos, yaw = trajectory(t)
        msgs.append(("Odometry", odom(k, T0 + round(t * NS), pos, yaw)))
    for k in range(int(seconds * frame_hz)):
        t = k / frame_hz + 0.013
        msgs.append(("local_view_cells", lvc(k, T0 + round(t * NS), ids(k))))
    msgs.sort(key=lambda km: km[1].header.stamp)
    return msgs


def config(**vpr: Any) -> PoseidonConfig:
    cfg = PoseidonConfig()
    for k, v in vpr.items():
        setattr(cfg.vpr_guard, k, v)
    return cfg


def events(out: list[tuple[str, Message]]) -> list[ExperienceEvent]:
    evs: list[ExperienceEvent] = []
    for k, m in out:
        if k == "experience_event":
            assert isinstance(m, ExperienceEvent)
            evs.append(m)
    return evs


def latest_odom(msgs: list[tuple[str, Message]], stamp: int) -> Odometry | None:
    best: Odometry | None = None
    for k, m in msgs:
        if k == "Odometry" and isinstance(m, Odometry) and m.header.stamp <= stamp:
            best = m
    return best


def test_events_only_when_the_gates_pass_with_the_lvc_headers() -> None:
    msgs = stream()
    node = build_node("posecells", config())
    out = run_offline(node, msgs)
    assert {k for k, _ in out} == {"experience_event", "posecells/activity"}
    evs = events(out)
    frames: dict[int, Any] = {m.header.stamp: m for k, m in msgs if k == "local_view_cells"}
    # the same decisions, recomputed from Eqs. 4.11-4.12 and the motion gate by hand
    window: list[int] = []
    last: list[float] | None = None
    expected: list[int] = []
    for stamp in sorted(frames):
        f = frames[stamp]
        window = (window + [f.most_active_cell])[-26:]
        count = window.count(f.most_active_cell)
        odo = latest_odom(msgs, stamp)
        assert odo is not None
        p = odo.position
        moved = last is None or math.hypot(p[0] - last[0], p[1] - last[1]) >= 0.12 or abs(p[2] - last[2]) >= 0.05
        if moved and count >= 3:
            expected.append(stamp)
            last = p
    assert [e.header.stamp for e in evs] == expected
    assert len(evs) >= 10
    for seq, e in enumerate(evs):
        f = frames[e.header.stamp]
        assert e.header.stamp == f.header.stamp and e.header.frame_id == f.header.frame_id == "camera"
        assert e.header.seq == seq
        assert e.lvc_id == f.most_active_cell
        assert e.gate == "vpr" and e.vpr_count >= 3
        o = latest_odom(msgs, e.header.stamp)
        assert o is not None and e.odom_position == o.position
        assert e.odom_yaw == pytest.approx(yaw_of_quaternion(o.orientation))
    n_frames = len(frames)
    c = node.counters
    assert c["events"] == c["events_vpr"] == len(evs)
    assert c["events"] + c.get("rejected_motion", 0) + c.get("rejected_vpr", 0) == n_frames
    assert c["rejected_motion"] > 0 and c["rejected_vpr"] > 0


def test_guard_off_gives_more_events_than_on_and_leak_fires_on_unstable_ids() -> None:
    msgs = stream(ids=lambda k: k)  # every frame a different id: never 3 repetitions
    on = run_offline(build_node("posecells", config(vpr_leak_rate=20)), msgs)
    off_node = build_node("posecells", config(require_vpr_for_event=False))
    off = run_offline(off_node, msgs)
    ev_on, ev_off = events(on), events(off)
    assert ev_on and all(e.gate == "leak" and e.vpr_count == 1 for e in ev_on)
    # the 20th candidate leaks; after an event the vehicle (5 cm per frame) needs 3 frames to
    # pass the 12 cm motion gate, and those 2 non-candidate frames do not count as rejections
    frame_s = 0.25
    assert (ev_on[0].header.stamp - T0) / NS == pytest.approx(0.013 + 19 * frame_s)
    gaps = np.diff([e.header.stamp for e in ev_on]) / NS
    assert np.allclose(gaps, 22 * frame_s)
    assert all(e.gate == "off" for e in ev_off)
    assert len(ev_off) > 5 * len(ev_on)
    assert off_node.counters.get("rejected_vpr", 0) == 0


def msgs_of(msgs: list[tuple[str, Message]], key: str) -> list[Any]:
    return [m for k, m in msgs if k == key]


def test_pose_cell_centroid_follows_the_odometry_modulo_the_lattice() -> None:
    # distinct ids: no LVC is ever seen twice, so nothing is injected; guard off for many events
    msgs = stream(seconds=90.0, ids=lambda k: k)
    evs = events(run_offline(build_node("posecells", config(require_vpr_for_event=False)), msgs))
    assert len(evs) > 50
    for e in evs:
        for axis in range(3):
            d = (e.pc_centroid[axis] - e.odom_position[axis] + LATTICE_M / 2) % LATTICE_M - LATTICE_M / 2
            assert abs(d) < 1e-6, (axis, e.pc_centroid, e.odom_position)
        dyaw = (e.pc_centroid[3] - e.odom_yaw + math.pi) % (2 * math.pi) - math.pi
        assert abs(dyaw) < 1e-6
        assert 0.0 <= e.pc_centroid[0] < LATTICE_M and -math.pi <= e.pc_centroid[3] < math.pi


def test_odometry_first_at_equal_stamps() -> None:
    stamp = T0 + 5 * NS
    msgs = [("local_view_cells", lvc(0, stamp, 3)), ("Odometry", odom(0, stamp, (1.0, 2.0, -3.0), 0.5))]
    out = run_offline(build_node("posecells", config(require_vpr_for_event=False)), msgs)
    (e,) = events(out)
    assert e.odom_position == [1.0, 2.0, -3.0] and e.header.stamp == stamp
    # the packet starts at the odometry pose modulo the 1.5 m lattice
    assert e.pc_centroid == pytest.approx([1.0, 0.5, 0.0, 0.5], abs=1e-9)


def test_frames_before_any_odometry_make_no_event_but_fill_the_window() -> None:
    msgs = stream(seconds=10.0, ids=lambda k: 7, odom_delay_s=2.0)
    node = build_node("posecells", config())
    evs = events(run_offline(node, msgs))
    assert node.counters["lvc_before_odometry"] == 8
    assert evs and evs[0].header.stamp >= T0 + 2 * NS
    assert evs[0].vpr_count == 9  # the 8 frames before the odometry counted in C_t


def test_odometry_jump_is_a_discontinuity_not_motion() -> None:
    msgs = [("Odometry", odom(0, T0, (0.0, 0.0, 0.0), 0.0)),
            ("Odometry", odom(1, T0 + NS // 10, (0.02, 0.0, 0.0), 0.0)),
            ("Odometry", odom(2, T0 + 2 * NS // 10, (100.0, 50.0, 0.0), 0.0)),
            ("Odometry", odom(3, T0 + 3 * NS // 10, (100.03, 50.0, 0.0), 0.0)),
            ("local_view_cells", lvc(0, T0 + 4 * NS // 10, 1))]
    node = build_node("posecells", config(require_vpr_for_event=False))
    (e,) = events(run_offline(node, msgs))
    assert node.counters["odometry_discontinuities"] == 1
    assert e.pc_centroid[0] == pytest.approx(0.05, abs=1e-6)  # 2 cm + 3 cm, the jump ignored


def test_multiple_active_lvcs_by_rate_and_top_k() -> None:
    node = build_node("posecells", config())
    msg = lvc(0, T0, 5, extra=[(9, 0.5), (2, 0.02), (4, 0.7), (8, 0.1), (6, 0.09)])
    core = node.core
    assert core.active_lvcs(msg.most_active_cell, msg.active_cells) == [5, 4, 9, 8]  # top_k 4, rate >= 0.03
    node.cfg.multiple_local_view_active = False
    assert core.active_lvcs(msg.most_active_cell, msg.active_cells) == [5]


def test_save_load_continue_equals_an_uninterrupted_run(tmp_path: Path) -> None:
    msgs = stream(seconds=40.0, ids=lambda k: (k // 3) % 9)  # revisits: injection and learning
    split = T0 + 17 * NS + NS // 3
    whole = run_offline(build_node("posecells", config()), msgs)
    cfg = config()
    cfg.posecells.state_path = str(tmp_path / "pc" / "state.npz")
    first = run_offline(build_node("posecells", cfg), [m for m in msgs if m[1].header.stamp < split])
    assert (tmp_path / "pc" / "state.npz").exists()
    second_node = build_node("posecells", cfg)
    assert len(second_node.net.beta) > 0
    second = run_offline(second_node, [m for m in msgs if m[1].header.stamp >= split])
    joined = events(first) + events(second)
    ref = events(whole)
    assert len(ref) > 10 and len(events(first)) > 3 and len(events(second)) > 3
    def strip(e: ExperienceEvent) -> dict[str, Any]:
        return e.model_dump(exclude={"header": {"seq"}})  # seq restarts per run

    assert [strip(e) for e in joined] == [strip(e) for e in ref]


def test_a_state_from_another_mission_lends_no_odometry_to_this_one(tmp_path: Path) -> None:
    """A second dive loads the first one's pose cells (``--map-dir``).  Its frames
    before its own first Odometry must make no event carrying the first dive's last pose (an
    experience 40 m off in the map); the network's associations carry over."""
    cfg = config(require_vpr_for_event=False)
    cfg.posecells.state_path = str(tmp_path / "pc.npz")
    first = stream(seconds=20.0, ids=lambda k: (k // 3) % 9)
    run_offline(build_node("posecells", cfg), first)
    (tmp_path / "pc_first.npz").write_bytes((tmp_path / "pc.npz").read_bytes())
    # the second dive: its odometry starts 2 s after its first frames, at its own origin
    second = stream(seconds=10.0, ids=lambda k: (k // 3) % 9, odom_delay_s=2.0)
    shifted = [(k, m.model_copy(update={"position": [v - 40.0 for v in m.position]})) if k == "Odometry" else (k, m)
               for k, m in second]
    cfg.posecells.state_new_odometry_frame = True
    node = build_node("posecells", cfg)
    assert len(node.net.beta) > 0, "the associations must carry over"
    evs = events(run_offline(node, shifted))
    assert node.counters["lvc_before_odometry"] == 8
    assert evs and evs[0].header.stamp >= T0 + 2 * NS
    assert all(e.odom_position[0] < -30.0 for e in evs), "every event carries this dive's odometry"
    # without the setting (a mission continued in one frame) the loaded pose is the reference
    cfg.posecells.state_new_odometry_frame = False
    cfg.posecells.state_path = str(tmp_path / "pc_first.npz")
    cont = build_node("posecells", cfg)
    run_offline(cont, shifted)
    assert cont.counters.get("lvc_before_odometry", 0) == 0


def test_state_file_of_another_kind_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "other.npz"
    np.savez(bad, x=np.zeros(3))
    cfg = config()
    cfg.posecells.state_path = str(bad)
    with pytest.raises(ValueError, match="other.npz"):
        build_node("posecells", cfg)


def test_event_messages_validate_and_roundtrip_through_the_codec() -> None:
    from common.codec import decode, encode

    msgs = stream(seconds=8.0, ids=lambda k: k)
    evs = events(run_offline(build_node("posecells", config(require_vpr_for_event=False)), msgs))
    assert evs
    for e in evs:
        assert isinstance(e, ExperienceEvent)
        assert decode(encode(e), ExperienceEvent) == e


def test_warm_up_leaves_the_network_as_it_was() -> None:
    import numpy as np

    from services.posecells.node import PoseCellsNode
    from system.config import PoseidonConfig

    cfg = PoseidonConfig()
    node = PoseCellsNode(cfg.posecells, cfg.vpr_guard)
    before = node.net.activity.copy()
    node.warm_up()
    assert np.array_equal(node.net.activity, before) and not node.core.placed and len(node.net.beta) == 0
