"""`poseidon sim`: determinism, streams and formats, revisit ground truth."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import file_sha256, read_messages, read_metadata
from missions.sim import cli as sim_cli
from missions.sim.mission import SimParams, generate
from missions.sim.trajectory import footprint_centres, make_trajectory, revisits
from missions.sim.world import build_world

SEED = 3  # the seed of the conftest's fast_mission (0.5 min at 4.5 m/s)
FAST: dict[str, Any] = dict(minutes=0.5, seed=SEED, speed_m_s=4.5)


def _by_key(path: Path) -> dict[str, list[Any]]:
    """Every message by key (typed loosely: each test reads the fields of its key's type)."""
    out: dict[str, list[Any]] = {}
    for r in read_messages(path):
        out.setdefault(r.key, []).append(r.message())
    return out


def test_same_seed_same_bytes(fast_mission: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    path, summary = fast_mission
    assert (summary["seed"], summary["minutes"]) == (SEED, FAST["minutes"])
    # the second run rebuilds the world from scratch (not the per-process cache)
    generate(tmp_path / "b.mcap", SimParams(**FAST), progress=False, world=build_world.__wrapped__(SEED))
    assert file_sha256(path) == file_sha256(tmp_path / "b.mcap")


def test_streams_rates_and_formats(fast_mission: tuple[Path, dict[str, Any]]) -> None:
    path, summary = fast_mission
    recs = _by_key(path)
    dur = FAST["minutes"] * 60
    expect_hz = {"camera/image_raw": 5.0, "sonar_micron": 23.3, "sonar_micron_ros": 23.3, "sonar_seaking": 50.0,
                 "sonar_seaking_ros": 50.0, "dvl_linkquest": 2.85, "imu_adis": 10.0, "imu_adis_ros": 10.0,
                 "depth_sensor": 10.0, "odometry": 11.2, "truth/pose": 10.0, "truth/revisits": 5.0}
    assert set(recs) == set(expect_hz)
    for key, hz in expect_hz.items():
        assert abs(len(recs[key]) - hz * dur) <= 2, key
        stamps = [m.header.stamp for m in recs[key]]
        assert all(b > a for a, b in zip(stamps, stamps[1:])), key
        assert [m.header.seq for m in recs[key]] == list(range(len(stamps))), key
    assert summary["counts"] == {k: len(v) for k, v in recs.items()}
    img = recs["camera/image_raw"][10]
    a = np.asarray(img.data)
    assert (img.width, img.height, img.encoding, a.shape) == (384, 288, "rgb8", (288, 384, 3)) and a.dtype == np.uint8
    # blue-green cast and a lamp cone: centre brighter than the corners
    means = a.reshape(-1, 3).mean(axis=0)
    assert means[1] > 1.3 * means[0] and means[2] > 1.2 * means[0]
    g = a[..., 1].astype(float)
    assert g[110:180, 150:230].mean() > 1.3 * np.mean([g[:30, :40].mean(), g[-30:, -40:].mean()])
    beam = recs["sonar_micron"][0]
    assert (beam.nbins, beam.max_range, np.asarray(beam.beam_data).shape) == (397, 20, (397,))
    assert max(int(np.asarray(m.beam_data).max()) for m in recs["sonar_micron"]) > 120  # wall echoes
    scan = recs["sonar_micron_ros"][5]
    assert scan.angle_min == scan.angle_max == recs["sonar_micron"][5].angle_rad
    np.testing.assert_array_equal(np.asarray(scan.intensities), np.asarray(recs["sonar_micron"][5].beam_data))
    heads = np.array([m.angle_rad for m in recs["sonar_micron"][:3]])
    np.testing.assert_allclose(np.diff(np.rad2deg(heads)), 1.8)
    dvl = recs["dvl_linkquest"]
    assert any(m.velocityinstflag == 1 for m in dvl)
    ok = [m for m in dvl if m.velocityinstflag == 1]
    speed = np.median([np.hypot(*m.velocityinst[:2]) for m in ok])
    assert 3.0 < speed < 6.0  # 4.5 m/s mean, +-12 % smooth variation
    depth = np.array([m.depth for m in recs["depth_sensor"]])
    assert 10 < depth.mean() < 20
    imu = recs["imu_adis"][0]
    assert abs(imu.az + 9.81) < 0.5  # specific force, z down
    from missions.importers.rosbags_io import rpy_from_quaternion

    for m in recs["imu_adis"][::50]:  # the quaternion is the reported attitude (ZYX)
        np.testing.assert_allclose(rpy_from_quaternion(m.qx, m.qy, m.qz, m.qw), (m.roll, m.pitch, m.yaw), atol=1e-9)
    truth = recs["truth/pose"]
    yaw_t = np.array([rpy_from_quaternion(*m.orientation)[2] for m in truth])
    yaw_i = np.interp([m.header.stamp for m in recs["imu_adis"]], [m.header.stamp for m in truth], np.unwrap(yaw_t))
    err = (np.array([m.yaw for m in recs["imu_adis"]]) - yaw_i + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(err).max() < np.deg2rad(3.0)  # noise + drift over 30 s stay small
    meta = read_metadata(path)["poseidon"]
    assert json.loads(meta["seed"]) == SEED and json.loads(meta["minutes"]) == FAST["minutes"]
    params = json.loads(meta["params"])
    assert params["imu_yaw_drift_deg_per_min"] > 0 and params["dvl_noise_m_s"] > 0


def test_recorded_revisits_against_truth(fast_mission: tuple[Path, dict[str, Any]]) -> None:
    path, summary = fast_mission
    recs = _by_key(path)
    truth = recs["truth/pose"]
    t = np.array([m.header.stamp for m in truth], float)
    pos = np.array([m.position for m in truth])
    frames = recs["camera/image_raw"]
    fs = np.array([m.header.stamp for m in frames], float)
    fpos = np.stack([np.interp(fs, t, pos[:, k]) for k in range(3)], axis=1)
    rev = recs["truth/revisits"]
    assert [m.frame_index for m in rev] == list(range(len(frames)))
    pairs = [(m.frame_index, int(j)) for m in rev for j in np.asarray(m.same_place)]
    assert len(pairs) > 20 and summary["frames_with_revisits"] > 5  # the loop closes
    for i, j in pairs:
        assert j < i
        assert np.linalg.norm(fpos[i] - fpos[j]) <= 2.0 + 1e-6
    d = np.linalg.norm(fpos[:, None, :] - fpos[None, :, :], axis=2)
    called = np.zeros_like(d, bool)
    for i, j in pairs:
        called[i, j] = True
    assert not (called & (d > 5.0)).any()


def test_revisit_definition_long_mission() -> None:
    """25 minutes of trajectory (no rendering): the definition holds and loops produce revisits."""
    world = build_world(SEED)
    p = SimParams(minutes=25, seed=SEED)
    traj = make_trajectory(world, p.minutes * 60, SEED, p.speed_m_s)
    times = np.arange(0.05, p.minutes * 60, 0.2)
    st = traj.at(times)
    c = footprint_centres(world, st["pos"], st["rpy"], np.asarray(p.camera.lever))
    same = revisits(c, st["pos"], st["dist"], st["rpy"][:, 2], 1.5, 2.0, 10.0)
    n_pairs = sum(len(s) for s in same)
    assert n_pairs > 1000
    bounded = revisits(c, st["pos"], st["dist"], st["rpy"][:, 2], 1.5, 2.0, 10.0, max_heading_diff=np.radians(30))
    n_bounded = 0
    for i, js in enumerate(bounded):
        assert set(js) <= set(same[i])
        dyaw = (st["rpy"][js, 2] - st["rpy"][i, 2] + np.pi) % (2 * np.pi) - np.pi
        assert (np.abs(dyaw) <= np.radians(30) + 1e-9).all()
        n_bounded += len(js)
    assert 0 < n_bounded < n_pairs  # the transition flown back the other way is excluded
    # exactness against brute force on a subsample
    rng = np.random.default_rng(0)
    for i in rng.choice(len(times), 300, replace=False):
        d = np.linalg.norm(c[:i] - c[i], axis=1)
        dv = np.linalg.norm(st["pos"][:i] - st["pos"][i], axis=1)
        gap = st["dist"][i] - st["dist"][:i]
        expect = np.nonzero((d <= 1.5) & (dv <= 2.0) & (gap >= 10.0))[0]
        np.testing.assert_array_equal(np.sort(same[i]), expect)


def test_cli_json_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = sim_cli.main(["--minutes", "0.05", "--seed", str(SEED), "--out", str(tmp_path / "c.mcap"), "--json",
                       "--no-progress"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert s["counts"]["camera/image_raw"] == s["frames"] == 14
    assert {"duration_s", "distance_m", "loops", "segments", "wall_s", "realtime_factor"} <= set(s)
    with pytest.raises(SystemExit):
        sim_cli.main(["--minutes", "-1", "--out", str(tmp_path / "d.mcap")])
    # a mission shorter than some sensor periods: those streams are simply empty
    assert sim_cli.main(["--minutes", "0.001", "--out", str(tmp_path / "e.mcap"), "--no-progress"]) == 0


def test_lazy_tiles_independent_of_generation_order() -> None:
    a = build_world.__wrapped__(SEED)
    b = build_world.__wrapped__(SEED)
    x0, y0 = a.route[0][0]  # the junction of area 1: guideline and tunnel floor
    assert a.ensure_tiles(x0 - 4, x0 + 4, y0 - 4, y0 + 4) > 4
    for dx, dy in ((2, 2), (-3, 1), (0, -3), (-4, -4), (4, 4)):  # other order, overlapping pieces
        b.ensure_tiles(x0 + dx - 1.5, x0 + dx + 1.5, y0 + dy - 1.5, y0 + dy + 1.5)
    both = a.tile_ready & b.tile_ready
    assert both.sum() > 4
    np.testing.assert_array_equal(a.tiles0[both], b.tiles0[both])
    np.testing.assert_array_equal(a.tiles1[both], b.tiles1[both])


def test_a_cached_mission_is_simulated_once(tmp_path):
    from missions.sim.cli import simulate_cached
    out = tmp_path / "m.mcap"
    assert simulate_cached(out, 0.05, 3, progress=False) == out and out.exists()
    first = out.stat().st_mtime_ns
    simulate_cached(out, 0.05, 3, progress=False)
    assert out.stat().st_mtime_ns == first  # the cache is used, not simulated again
