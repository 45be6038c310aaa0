"""`poseidon transform`: Section 5.2 protocol on a short simulated recording."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import read_messages, read_metadata
from missions.sim.mission import SimParams, generate
from missions.transform import Perturbation, default_segments, main, parse_segments, perturb_image, transform

SEGS = "0:2,2:6,6:8,8:12,12:15"  # entry, area-1 loop, transition, area-2 loop, exit (s)


@pytest.fixture(scope="module")
def transformed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, Any]]:
    d = tmp_path_factory.mktemp("tr")
    src = d / "src.mcap"
    generate(src, SimParams(minutes=0.25, seed=3), progress=False)
    out = d / "out.mcap"
    summary = transform(src, out, parse_segments(SEGS), seed=5, progress=False)
    return src, out, summary


def _by_key(path: Path) -> dict[str, list[Any]]:
    """Every message by key (typed loosely: each test reads the fields of its key's type)."""
    out: dict[str, list[Any]] = {}
    for r in read_messages(path):
        out.setdefault(r.key, []).append(r.message())
    return out


def test_nine_segments_and_timeline(transformed: tuple[Path, Path, dict[str, Any]]) -> None:
    src, out, summary = transformed
    segs = summary["segments"]
    assert [s["name"] for s in segs] == ["entry", "area1_loop1", "area1_loop2", "area1_loop3", "transition",
                                         "area2_loop1", "area2_loop2", "area2_loop3", "exit"]
    assert [s["perturbed"] for s in segs] == [False, False, True, True, False, False, True, True, False]
    for a, b in zip(segs, segs[1:]):
        assert b["start_s"] > a["end_s"]  # sequential, continuous timeline
    assert abs(summary["duration_s"] - (2 + 3 * 4 + 2 + 3 * 4 + 3)) < 0.05
    meta = read_metadata(out)
    assert len(json.loads(meta["transform_segments"]["segments"])) == 9
    rec = _by_key(out)
    srec = _by_key(src)
    for key, msgs in rec.items():
        stamps = [m.header.stamp for m in msgs]
        assert all(b > a for a, b in zip(stamps, stamps[1:])), key
        assert [m.header.seq for m in msgs] == list(range(len(msgs))), key
    # every stream replicated: counts = entry + 3 x loop1 + transition + 3 x loop2 + exit of the source
    t0 = min(m.header.stamp for v in srec.values() for m in v)

    def n_in(key: str, a: float, b: float) -> int:
        return sum(1 for m in srec[key] if t0 + a * 1e9 <= m.header.stamp < t0 + b * 1e9)

    r = parse_segments(SEGS)
    for key in ("camera/image_raw", "depth_sensor", "dvl_linkquest", "sonar_micron", "imu_adis", "truth/pose"):
        expect = n_in(key, *r[0]) + 3 * n_in(key, *r[1]) + n_in(key, *r[2]) + 3 * n_in(key, *r[3]) + n_in(key, *r[4])
        assert len(rec[key]) == expect, key
    # non-image streams of loop 2 are loop 1's values
    d_loop1 = [m.depth for m in srec["depth_sensor"] if t0 + 2e9 <= m.header.stamp < t0 + 6e9]
    n_entry = n_in("depth_sensor", *r[0])
    out_depth = [m.depth for m in rec["depth_sensor"]]
    assert out_depth[n_entry:n_entry + len(d_loop1)] == d_loop1
    assert out_depth[n_entry + len(d_loop1):n_entry + 2 * len(d_loop1)] == d_loop1


def test_perturbed_loops(transformed: tuple[Path, Path, dict[str, Any]]) -> None:
    src, out, summary = transformed
    rec = _by_key(out)
    srec = _by_key(src)
    t0 = min(m.header.stamp for v in srec.values() for m in v)
    src_loop = [np.asarray(m.data) for m in srec["camera/image_raw"] if t0 + 2e9 <= m.header.stamp < t0 + 6e9]
    n_entry = sum(1 for m in srec["camera/image_raw"] if m.header.stamp < t0 + 2e9)
    n = len(src_loop)
    imgs = [np.asarray(m.data) for m in rec["camera/image_raw"]]
    for k in range(n):
        np.testing.assert_array_equal(imgs[n_entry + k], src_loop[k])  # loop 1 unaltered
    w = src_loop[0].shape[1]
    for copy in (1, 2):
        for k in range(0, n, 5):
            p = imgs[n_entry + copy * n + k].astype(float)
            o = src_loop[k].astype(float)
            assert not np.array_equal(p, o)
            # the best horizontal shift of the original onto the perturbed image is 5 % +- 3 % of the width
            errs = {s: np.abs(p[40:-40, 60:-60] - np.roll(o, s, axis=1)[40:-40, 60:-60]).mean()
                    for s in range(-int(0.1 * w), int(0.1 * w) + 1)}
            best = min(errs, key=lambda s: errs[s])
            assert 0.02 * w <= abs(best) <= 0.08 * w
    st = summary["perturbation_stats"]
    assert st["images"] == 4 * n
    assert abs(st["shift_px_mean"] - 0.05 * w) < 0.015 * w
    assert st["rotation_deg_std"] < 1.0


def test_revisits_point_to_loop1(transformed: tuple[Path, Path, dict[str, Any]]) -> None:
    _, out, summary = transformed
    rec = _by_key(out)
    rev = rec["truth/revisits"]
    assert [m.frame_index for m in rev] == list(range(len(rec["camera/image_raw"])))
    segs = summary["segments"]
    frames = rec["camera/image_raw"]
    t0 = min(m.header.stamp for v in rec.values() for m in v)  # the output timeline starts at the source's start

    def seg_of(stamp: int) -> int:
        s = (stamp - t0) / 1e9
        return next(i for i, g in enumerate(segs) if g["start_s"] - 1e-6 <= s <= g["end_s"] + 1e-6)

    seg = [seg_of(f.header.stamp) for f in frames]
    first = {k: seg.index(k) for k in range(9)}
    for i, m in enumerate(rev):
        same = set(int(j) for j in np.asarray(m.same_place))
        if seg[i] in (2, 3, 6, 7):
            k = i - first[seg[i]]
            loop1 = 1 if seg[i] < 5 else 5
            assert first[loop1] + k in same  # the copy of the same source frame in loop 1
            if seg[i] in (3, 7):
                assert first[loop1 + 1] + k in same  # and in loop 2
            assert all(seg[j] in (loop1, loop1 + 1) and seg[j] < seg[i] for j in same)
            assert all(abs((j - first[seg[j]]) - k) <= 2 for j in same)  # +- 2 frames tolerance
        else:
            assert same == set()


def test_default_segments_and_cli_errors(tmp_path: Path, transformed: tuple[Path, Path, dict[str, Any]], capsys: pytest.CaptureFixture[str]) -> None:
    segs, how = default_segments({}, 100.0)
    assert segs == [(0.0, 10.0), (10.0, 40.0), (40.0, 50.0), (50.0, 80.0), (80.0, 100.0)] and "fractions" in how
    with pytest.raises(ValueError, match="5 ranges"):
        parse_segments("0:1,1:2")
    with pytest.raises(ValueError, match="transition range '5:4'"):
        parse_segments("0:1,1:2,5:4,6:7,8:9")
    src = transformed[0]
    assert main([str(src), "--out", str(tmp_path / "x.mcap"), "--segments", "0:1,1:2,2:3,3:4,400:500",
                 "--no-progress"]) == 2
    assert "exit range 400.0:500.0 s starts after the recording ends" in capsys.readouterr().err
    assert main([str(tmp_path / "missing.mcap"), "--out", str(tmp_path / "y.mcap"), "--no-progress"]) == 2
    assert "missing.mcap" in capsys.readouterr().err
    assert main([str(src), "--out", str(tmp_path / "z.mcap"), "--image-key", "cam2", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "no messages on the camera key 'cam2'" in err and "camera/image_raw" in err
    assert not list(tmp_path.glob("*.part"))


def test_extra_perturbations_change_image_deterministically() -> None:
    rng0 = np.random.default_rng(1)
    img = (rng0.random((288, 384, 3)) * 255).astype(np.uint8)
    p = Perturbation(illumination=0.25, particles=40, blur=1.5, occlusion=0.15, scale=0.05)
    a, da = perturb_image(img, np.random.default_rng(7), p)
    b, db = perturb_image(img, np.random.default_rng(7), p)
    np.testing.assert_array_equal(a, b)
    assert da == db and {"gain", "blur_sigma_px", "particles", "occlusion_fraction", "scale"} <= set(da)
    assert a.shape == img.shape and a.dtype == img.dtype and not np.array_equal(a, img)
    mono = img[..., 0]
    m, _ = perturb_image(mono, np.random.default_rng(7), p)
    assert m.shape == mono.shape


def test_default_segments_from_sim_route() -> None:
    """A sim mission long enough for the whole route (35 min, trajectory only): the default
    source ranges are the approach, the first complete loop of each area and the transitions."""
    from missions.sim.mission import segments_of
    from missions.sim.trajectory import make_trajectory
    from missions.sim.world import build_world

    traj = make_trajectory(build_world(3), 35 * 60.0, 3)
    segs = segments_of(traj, 35 * 60.0)
    ranges, how = default_segments({"poseidon": {"segments": json.dumps(segs)}}, 35 * 60.0)
    assert how == "sim route segments"
    names = []
    for a, b in ranges:
        seg = next(s for s in segs if s["start_s"] == a and s["end_s"] == b)
        names.append((seg["name"], seg["loop"]))
    assert names == [("transition_2_1", 0), ("area1_ellipse", 0), ("transition_1_2", 0), ("area2_cave2", 0),
                     ("transition_2_1", 0)]
    assert all(b > a for a, b in ranges) and ranges[4][0] > ranges[3][1]  # exit after the three area-2 loops


def test_source_revisits_carried_to_every_copy(tmp_path: Path, fast_mission: tuple[Path, dict[str, Any]]) -> None:
    """A source whose own truth/revisits has loop closures (the conftest's fast mission: the
    approach and more than a loop of area 1): each source pair appears between the copies."""
    src = fast_mission[0]
    srec = _by_key(src)
    src_pairs = {(m.frame_index, int(j)) for m in srec["truth/revisits"] for j in np.asarray(m.same_place)}
    assert src_pairs
    out = tmp_path / "out.mcap"
    transform(src, out, parse_segments("0:1,1:29,29:29.4,29.4:29.7,29.7:30"), progress=False)
    rec = _by_key(out)
    t0 = min(x.header.stamp for v in srec.values() for x in v)
    stamps = np.array([m.header.stamp for m in srec["camera/image_raw"]])
    n_entry = int((stamps < t0 + 1e9).sum())
    n_loop = int(((stamps >= t0 + 1e9) & (stamps < t0 + 29e9)).sum())
    out_same = {m.frame_index: set(int(j) for j in np.asarray(m.same_place)) for m in rec["truth/revisits"]}
    carried = 0
    for i, j in src_pairs:
        if i >= n_entry and j >= n_entry and i < n_entry + n_loop:
            for copy in range(3):  # the pair inside each copy of the loop
                oi, oj = n_entry + copy * n_loop + (i - n_entry), n_entry + copy * n_loop + (j - n_entry)
                assert oj in out_same[oi], (i, j, copy)
                carried += 1
    assert carried > 0


def test_one_area_five_segments_and_revisits(transformed: tuple[Path, Path, dict[str, Any]], tmp_path: Path) -> None:
    """--areas 1 (the demo's mission): entry | three copies of the area-1 loop | exit; frames of
    the perturbed copies revisit the same frames of the earlier copies."""
    src = transformed[0]
    out = tmp_path / "one.mcap"
    summary = transform(src, out, parse_segments("0:2,2:6,6:9", areas=1), seed=5, progress=False, areas=1)
    segs = summary["segments"]
    assert [s["name"] for s in segs] == ["entry", "area1_loop1", "area1_loop2", "area1_loop3", "exit"]
    assert [s["perturbed"] for s in segs] == [False, False, True, True, False]
    assert abs(summary["duration_s"] - (2 + 3 * 4 + 3)) < 0.05
    rec = _by_key(out)
    frames = [m.header.stamp for m in rec["camera/image_raw"]]
    t0 = min(m.header.stamp for v in rec.values() for m in v)
    seg_of = [next(k for k, s in enumerate(segs) if s["start_s"] - 1e-6 <= (f - t0) / 1e9 <= s["end_s"] + 1e-6)
              for f in frames]
    truth = {m.frame_index: set(m.same_place.tolist()) for m in rec["truth/revisits"]}
    loop1 = [i for i, k in enumerate(seg_of) if k == 1]
    loop3 = [i for i, k in enumerate(seg_of) if k == 3]
    assert loop1 and len(loop3) == len(loop1)
    # the n-th frame of loop 3 revisits the n-th frame of loop 1 (same source frame)
    assert all(loop1[n] in truth[loop3[n]] for n in range(len(loop1)))
    assert all(not truth[i] for i in loop1)  # loop 1 itself is no revisit of anything earlier here
    with pytest.raises(ValueError, match="3 ranges"):
        parse_segments(SEGS, areas=1)
    assert main([str(src), "--out", str(tmp_path / "bad.mcap"), "--areas", "1", "--no-progress"]) == 2
