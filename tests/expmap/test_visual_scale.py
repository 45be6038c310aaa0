"""The odometry's scale measured by the downward camera: the image shift,
the running estimate against an odometry that reads long, and the map's retroactive rescale."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from services.expmap.config import VisualScaleConfig
from services.expmap.graph import ExperienceMap
from services.expmap.node import ExpMapNode
from services.expmap.session_link import SESSION_BREAK_WEIGHT
from services.expmap.visual_scale import VisualScale, _reduce, image_shift
from tests.expmap.helpers import SEC, pc_of, small_cfg

H, W = 96, 128            # small frames: the measurement does not depend on the size
FOCAL = 200.0             # px
ALTITUDE = 1.7            # m over the floor at the DVL; the camera 0.2 m below it
PX_PER_M = FOCAL / (ALTITUDE - 0.2)


def floor_texture(seed: int = 3, size: int = 2048) -> np.ndarray:
    """A floor's albedo: smoothed noise at two scales (sand and rock patches)."""
    rng = np.random.default_rng(seed)
    t = gaussian_filter(rng.normal(size=(size, size)), 1.5) + 0.5 * gaussian_filter(rng.normal(size=(size, size)), 6)
    out: np.ndarray = (t - t.min()) / (t.max() - t.min())
    return out


def frame_at(tex: np.ndarray, row: int, col: int) -> np.ndarray:
    return tex[row:row + H, col:col + W].astype(np.float32)


def test_image_shift_finds_a_known_displacement() -> None:
    tex = floor_texture()
    a = frame_at(tex, 500, 500)
    for dr, dc in ((7, -3), (-12, 5), (0, 9)):
        b = frame_at(tex, 500 + dr, 500 + dc)      # the camera moved: the content moves the other way
        rows, cols = image_shift(a, b)
        assert rows == pytest.approx(-dr, abs=0.15) and cols == pytest.approx(-dc, abs=0.15)


def test_image_shift_on_block_means_finds_it_in_full_resolution_pixels() -> None:
    tex = floor_texture()
    a = frame_at(tex, 500, 500)
    for dr, dc in ((7, -3), (-12, 5), (0, 9), (5, 0)):
        b = frame_at(tex, 500 + dr, 500 + dc)
        rows, cols = image_shift(a, b, downsample=2)
        assert rows == pytest.approx(-dr, abs=0.3) and cols == pytest.approx(-dc, abs=0.3)
    with pytest.raises(ValueError, match="does not fit"):
        image_shift(a[:3, :3], b[:3, :3], downsample=2)


def test_block_means_are_the_means_of_whole_blocks() -> None:
    img = np.arange(7 * 9, dtype=np.uint8).reshape(7, 9)
    got = _reduce(img, 2)
    assert got.dtype == np.float32 and got.shape == (3, 4)
    assert np.array_equal(got, img[:6, :8].astype(np.float64).reshape(3, 2, 4, 2).mean(axis=(1, 3)))
    assert np.array_equal(_reduce(img, 1), img.astype(np.float32))


def test_image_shift_refuses_frames_of_two_shapes() -> None:
    with pytest.raises(ValueError, match="one shape"):
        image_shift(np.zeros((10, 12)), np.zeros((12, 10)))


def fly(vs: VisualScale, odometry_gain: float, n: int = 400, bad_every: int = 7, seed: int = 5) -> None:
    """A vehicle flying a lawnmower leg and back over the textured floor, a frame every 0.2 s
    (8 and 3 px of the floor: whole pixels, so every pair's true shift is exact); its odometry reads
    ``odometry_gain`` times the true path; every ``bad_every``-th frame is murk (noise)."""
    tex = floor_texture()
    rng = np.random.default_rng(seed)
    for k in range(n):
        t = int(k * 0.2 * SEC)
        leg = min(k, 199) - max(k - 199, 0)
        r, c = 100 + 8 * leg, 100 + 3 * k
        x, y = (r - 100) / PX_PER_M, (c - 100) / PX_PER_M
        vs.add_altitude(t, ALTITUDE)
        vs.add_odometry(t - 1, odometry_gain * x, odometry_gain * y)
        img = frame_at(tex, r, c)
        if bad_every and k % bad_every == 3:
            img = rng.normal(size=img.shape).astype(np.float32)
        vs.add_frame(t, img)
        vs.add_odometry(t + 1, odometry_gain * x, odometry_gain * y)


def test_the_estimate_recovers_an_odometry_that_reads_long() -> None:
    vs = VisualScale(VisualScaleConfig(focal_px=FOCAL, camera_height_m=0.2, pair_every=1, min_pairs=100, downsample=1))
    fly(vs, odometry_gain=1.02)
    assert vs.scale is not None
    # the Hann window stays while the floor moves under it: the phase correlation reads ~0.2 %
    # short on frames this small (image_shift test: 6.984 px for 7), hence the tolerance
    assert vs.scale == pytest.approx(1 / 1.02, abs=0.004)
    assert vs.counts["outliers"] > 0, "the murky frames must be left out, not averaged in"
    exact = VisualScale(VisualScaleConfig(focal_px=FOCAL, camera_height_m=0.2, pair_every=1, min_pairs=100, downsample=1))
    fly(exact, odometry_gain=1.0)
    assert exact.scale == pytest.approx(1.0, abs=0.004)


def test_no_estimate_before_enough_pairs_nor_without_altitude() -> None:
    vs = VisualScale(VisualScaleConfig(focal_px=FOCAL, pair_every=1, min_pairs=500))
    fly(vs, odometry_gain=1.02, n=60)
    assert vs.scale is None and vs.counts["pairs"] > 0
    blind = VisualScale(VisualScaleConfig(focal_px=FOCAL, pair_every=1, min_pairs=10))
    tex = floor_texture()
    for k in range(30):
        blind.add_odometry(int(k * 0.2 * SEC), 0.06 * k, 0.0)
        blind.add_frame(int(k * 0.2 * SEC) + 1, frame_at(tex, 300 + 8 * k, 300))
    assert blind.scale is None and blind.counts["no_altitude"] == 29


def test_pair_every_measures_one_pair_in_n() -> None:
    vs = VisualScale(VisualScaleConfig(focal_px=FOCAL, camera_height_m=0.2, pair_every=4, min_pairs=20, downsample=1))
    fly(vs, odometry_gain=1.02, n=200, bad_every=0)
    assert vs.counts["pairs"] == 49          # pairs (3, 4), (7, 8), ... of 200 frames
    assert vs.scale == pytest.approx(1 / 1.02, abs=0.004)


def test_the_estimate_on_block_means_matches_full_resolution() -> None:
    half = VisualScale(VisualScaleConfig(focal_px=FOCAL, camera_height_m=0.2, pair_every=1, min_pairs=100,
                                         downsample=2))
    fly(half, odometry_gain=1.02)
    assert half.scale == pytest.approx(1 / 1.02, abs=0.006)
    assert half.counts["outliers"] > 0


def straight_run(em: ExperienceMap, t0: int, n: int, gain: float, origin: float = 0.0) -> None:
    for k in range(n):
        x = origin + gain * k
        em.add_event((t0 + k) * SEC, 1000 + t0 + k, pc_of((x, 0.0, 0.0)), [x, 0.0, -2.0], 0.0)


def test_the_map_rescales_this_runs_odometry_edges_only() -> None:
    em = ExperienceMap(small_cfg({"min_experience_age": 1000}))
    straight_run(em, 0, 10, 1.0)                 # a loaded map's part: not this run's odometry
    em.run_first = em.n_nodes
    straight_run(em, 100, 21, 1.02, origin=10.02)  # this run: 21 odometry edges of 1.02 m each, truly 1 m
    before = em.positions.copy()
    em.set_odometry_scale(1 / 1.02)
    em.settle()
    pos = em.positions
    assert np.allclose(pos[:10], before[:10]), "the loaded nodes must not move"
    assert np.allclose(pos[10:, 0], 10.0 + np.arange(21), atol=1e-9), "this run's path is now metric"
    assert np.allclose(pos[:, 1:], before[:, 1:]), "depth (and y here) keep their own scale"
    # a new event after the rescale is scaled as it is added; setting the scale again replaces it
    straight_run(em, 200, 1, 1.02, origin=10.02 + 21 * 1.02)
    assert em.positions[-1, 0] == pytest.approx(31.0)
    em.set_odometry_scale(1.0)
    em.settle()
    assert em.positions[-1, 0] == pytest.approx(9.0 + 22 * 1.02)
    with pytest.raises(ValueError, match="finite and > 0"):
        em.set_odometry_scale(0.0)


def test_a_session_break_edge_is_not_rescaled() -> None:
    em = ExperienceMap(small_cfg({"min_experience_age": 1000}))
    straight_run(em, 0, 5, 1.0)
    em.begin_session()
    straight_run(em, 100, 6, 1.02, origin=50.0)
    k = 5                                        # the break edge into the new session's first node
    assert em.edge_weights[k] == SESSION_BREAK_WEIGHT
    delta_before = em.deltas[k].copy()
    em.set_odometry_scale(0.9)
    assert np.array_equal(em.deltas[k], delta_before)
    assert em.deltas[6][0] == pytest.approx(1.02 * 0.9)


def test_the_node_subscribes_to_camera_and_dvl_only_when_enabled() -> None:
    on = small_cfg({"image.publish_experience": False, "visual_scale": VisualScaleConfig(enabled=True)})
    ins, _ = ExpMapNode.io_keys(on)
    assert on.image.topic in ins and "dvl_linkquest" in ins
    off = small_cfg({"image.publish_experience": False, "visual_scale": VisualScaleConfig(enabled=False)})
    ins, _ = ExpMapNode.io_keys(off)
    assert off.image.topic not in ins and "dvl_linkquest" not in ins


class _Estimate:
    """Stands in for VisualScale's estimate in the node's rule."""

    def __init__(self, scale: float):
        self.scale = scale
        self.counts = {"inliers": 300, "pairs": 400}


def test_the_node_applies_a_plausible_estimate_and_refuses_an_implausible_one() -> None:
    from system.config import PoseidonConfig
    from system.services import build_node
    cfg = PoseidonConfig()
    cfg.expmap.image.publish_experience = False
    node = build_node("expmap", cfg)
    assert isinstance(node, ExpMapNode) and isinstance(node.graph, ExperienceMap)
    straight_run(node.graph, 0, 5, 1.0)
    node.visual = _Estimate(0.99)                       # type: ignore[assignment]
    node._follow_scale()
    assert node.graph.odometry_scale == pytest.approx(0.99)
    node.visual = _Estimate(1.07)                       # type: ignore[assignment]  # zoomed frames, not a DVL
    node._follow_scale()
    assert node.graph.odometry_scale == 1.0 and node.counters["visual_scale_implausible"] == 1
