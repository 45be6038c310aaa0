"""`poseidon sim --world-seed W --start area2`: a second mission in the same cave."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.mcap_io import read_messages, read_metadata
from missions.sim.mission import SimParams, generate
from missions.sim.trajectory import make_trajectory
from missions.sim.world import build_world


def test_start_area2_flies_area2_first_in_the_same_world_frame() -> None:
    world = build_world(3)
    a1 = make_trajectory(world, 120.0, 3, 0.3)
    a2 = make_trajectory(world, 120.0, 3, 0.3, start="area2")
    names = a2.segment_names
    # the approach is the transition into area 2, then area 2's loop
    assert names[int(a2.segment[0])] == "transition_1_2"
    assert names[int(a2.segment[-1])] == "area2_cave2"
    assert names[int(a1.segment[-1])] == "area1_ellipse"
    # area 2's tunnel centre line is the world's: the vehicle stays within the tunnel of area 2
    cave2 = world.route[2]
    d = np.min(np.hypot(a2.pos[-1, 0] - cave2[:, 0], a2.pos[-1, 1] - cave2[:, 1]))
    assert d < 1.5
    # and far from where the default mission is by then
    assert np.hypot(*(a2.pos[-1, :2] - a1.pos[-1, :2])) > 20.0
    with pytest.raises(ValueError, match="start must be one of"):
        make_trajectory(world, 10.0, 3, 0.3, start="area3")


def test_world_seed_separates_cave_from_route_noise(tmp_path: Path) -> None:
    base = dict(minutes=0.1, speed_m_s=1.0)
    s_a = generate(tmp_path / "a.mcap", SimParams(seed=5, world_seed=3, start="area2", **base), progress=False)
    s_b = generate(tmp_path / "b.mcap", SimParams(seed=3, start="area2", **base), progress=False)
    assert (s_a["seed"], s_a["world_seed"], s_a["start"]) == (5, 3, "area2")
    assert (s_b["seed"], s_b["world_seed"]) == (3, 3)
    meta = read_metadata(tmp_path / "a.mcap")["poseidon"]
    assert (meta["world_seed"], meta["start"], meta["seed"]) == ("3", "area2", "5")   # metadata values are text
    truth = {p: np.array([r.message().position for r in read_messages(tmp_path / p) if r.key == "truth/pose"])
             for p in ("a.mcap", "b.mcap")}
    # same cave and start: both within a few metres (lateral offset, speed differ by seed), not identical
    assert np.hypot(*(truth["a.mcap"][0, :2] - truth["b.mcap"][0, :2])) < 3.0
    assert not np.array_equal(truth["a.mcap"], truth["b.mcap"])
    # a default mission records neither key (its bytes do not depend on the options)
    generate(tmp_path / "c.mcap", SimParams(seed=3, **base), progress=False)
    meta_c = read_metadata(tmp_path / "c.mcap")["poseidon"]
    assert "world_seed" not in meta_c and "start" not in meta_c and "world_seed" not in meta_c["params"]


def test_world_given_must_match_world_seed(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="world_seed 4"):
        generate(tmp_path / "x.mcap", SimParams(minutes=0.05, seed=3, world_seed=4), progress=False,
                 world=build_world(3))


def test_first_loops_reaches_area1_after_one_loop_of_area2() -> None:
    world = build_world(3)
    dur = 900.0
    full = make_trajectory(world, dur, 3, 0.3, start="area2")
    short = make_trajectory(world, dur, 3, 0.3, start="area2", first_loops=1)

    def first_in_area1(m: object) -> float:
        names = m.segment_names  # type: ignore[attr-defined]
        seg = np.asarray(m.segment)  # type: ignore[attr-defined]
        hit = np.flatnonzero(seg == names.index("area1_ellipse"))
        return float(m.t[hit[0]]) if hit.size else float("inf")  # type: ignore[attr-defined]

    # one loop of area 2 (~90 m) and the transition (~45 m) at 0.3 m/s: area 1 within ~9 minutes;
    # three loops of area 2 first: not within the 15 minutes
    assert first_in_area1(short) < 540.0 and first_in_area1(full) == float("inf")
    assert np.array_equal(short.pos[:100], full.pos[:100])      # the same start, the same seed
    for bad in (0, 4):
        with pytest.raises(ValueError, match="first_loops"):
            make_trajectory(world, 10.0, 3, 0.3, start="area2", first_loops=bad)


def test_compression_changes_the_file_not_the_messages(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    p = SimParams(seed=2, minutes=0.05, speed_m_s=1.0)
    generate(tmp_path / "z.mcap", p, progress=False)
    generate(tmp_path / "n.mcap", p, progress=False, compression="none")
    with open(tmp_path / "n.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and {c.compression for c in summary.chunk_indexes} == {""}
    msgs = {n: [(r.key, r.stamp, r.payload) for r in read_messages(tmp_path / n)] for n in ("z.mcap", "n.mcap")}
    assert len(msgs["z.mcap"]) > 100 and msgs["z.mcap"] == msgs["n.mcap"]
    assert (tmp_path / "n.mcap").stat().st_size > (tmp_path / "z.mcap").stat().st_size
