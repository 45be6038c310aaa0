"""RatSLAM local view (services/ratslam_lv): templates, SAD shift matching, view-cell ids."""
from __future__ import annotations

import numpy as np
import pytest

from common.config import ConfigError
from services.ratslam_lv.matcher import LocalViewMatcher, area_downsample, grey, patch_normalise
from system.config import load_config

H, W = 288, 384


def _texture(seed: int, h: int = H, w: int = W + 64) -> np.ndarray:
    """A seabed-like rgb8 texture: blobs of 6-12 px, so a 6.4 px template cell keeps structure."""
    rng = np.random.default_rng(seed)
    coarse = rng.random((h // 6 + 2, w // 6 + 2))
    img = np.kron(coarse, np.ones((6, 6)))[:h, :w]
    img = 0.6 * img + 0.4 * np.kron(rng.random((h // 12 + 2, w // 12 + 2)), np.ones((12, 12)))[:h, :w]
    return np.repeat((img * 255).astype(np.uint8)[..., None], 3, axis=2)


def _view(tex: np.ndarray, x0: int) -> np.ndarray:
    return np.ascontiguousarray(tex[:, x0:x0 + W])


def _matcher(*overrides: str) -> LocalViewMatcher:
    # crop 360 px wide -> exactly 6 image px per template px (60 wide), 168 rows -> 20
    return LocalViewMatcher(load_config(overrides=["ratslam_lv.image_crop_x_max=360", *overrides]).ratslam_lv)


def test_defaults_are_the_dissertations() -> None:
    c = load_config().ratslam_lv
    assert (c.image_crop_y_min, c.vt_normalisation, c.vt_patch_normalise, c.vt_match_threshold) == (120, 0.4, 3, 0.018)
    with pytest.raises(ConfigError, match="ratslam_lv.vt_match_threshold"):
        load_config(overrides=["ratslam_lv.vt_match_threshold=-1"])


def test_template_is_grey_cropped_downsampled_and_normalised() -> None:
    m = _matcher()
    img = _view(_texture(1), 0)
    t = m.make_template(img)
    assert t.shape == (20, 60) and t.dtype == np.float32
    assert 0.0 <= t.min() and t.max() <= 1.0
    assert abs(float(t.mean()) - 0.4) < 0.02  # vt_normalisation (a little clipping allowed)
    # only the crop counts: changing the rows above image_crop_y_min changes nothing
    other = img.copy()
    other[:120] = 255
    np.testing.assert_array_equal(m.make_template(other), t)
    # and what is inside does
    other[200:210] = 0
    assert not np.array_equal(m.make_template(other), t)


def test_building_blocks() -> None:
    g = grey(np.array([[[255, 0, 0], [30, 60, 90]]], np.uint8))
    np.testing.assert_allclose(g, [[85 / 255, 60 / 255]], rtol=1e-6)
    src = np.arange(16, dtype=np.float32).reshape(4, 4)
    np.testing.assert_allclose(area_downsample(src, 2, 2), [[2.5, 4.5], [10.5, 12.5]])
    with pytest.raises(ValueError, match="larger than the cropped image"):
        area_downsample(src, 5, 2)
    flat = patch_normalise(np.full((5, 5), 0.3, np.float32), 1)
    np.testing.assert_allclose(flat, 0.5)  # no contrast: z = 0
    edge = np.tile(np.array([0, 0, 0, 1, 1], np.float32), (5, 1))
    out = patch_normalise(edge, 1)
    assert out[2, 2] < 0.5 < out[2, 3]  # local contrast kept ...
    np.testing.assert_allclose(patch_normalise(edge * 0.2 + 0.7, 1), out, atol=1e-5)  # ... levels removed


def test_first_frame_creates_view_cell_zero_and_exact_revisit_matches_it() -> None:
    m = _matcher()
    a = _view(_texture(1), 0)
    r0 = m.step(a)
    assert (r0.view_id, r0.is_new, r0.rate) == (0, True, 1.0)
    r1 = m.step(a.copy())
    assert (r1.view_id, r1.is_new, r1.difference, r1.shift, r1.rate) == (0, False, 0.0, (0, 0), 1.0)
    assert len(m) == 1


def test_shifted_revisit_is_matched_within_vt_shift_match() -> None:
    tex = _texture(2)
    m = _matcher()
    assert m.step(_view(tex, 24)).view_id == 0  # stored at x0 = 24 image px (4 template px)
    shifted = m.step(_view(tex, 42))  # 18 px = 3 template px to the right, within vt_shift_match = 5
    assert not shifted.is_new and shifted.view_id == 0
    assert shifted.shift == (3, 0)  # current pixel x is stored pixel x + 3
    assert shifted.difference < 0.3 * m.cfg.vt_match_threshold and 0.0 < shifted.rate <= 1.0
    # without shift matching the same view is a new place
    m0 = _matcher("ratslam_lv.vt_shift_match=0", "ratslam_lv.vt_shift_match_y=0")
    m0.step(_view(tex, 24))
    assert m0.step(_view(tex, 42)).is_new


def test_vertical_shift_is_matched_too() -> None:
    tex = _texture(3, h=H + 64)
    m = _matcher()
    m.step(np.ascontiguousarray(tex[0:H, :W]))
    # 168 cropped rows -> 20 template rows: 8.4 px each; 17 px is about 2 template rows
    res = m.step(np.ascontiguousarray(tex[17:17 + H, :W]))
    assert not res.is_new and res.view_id == 0 and res.shift == (0, 2)


def test_shift_beyond_the_range_and_a_different_place_create_new_ids() -> None:
    tex = _texture(4)
    m = _matcher()
    m.step(_view(tex, 0))
    far = m.step(_view(tex, 48))  # 8 template px > vt_shift_match
    assert far.is_new and far.view_id == 1
    other = m.step(_view(_texture(5), 0))
    assert other.is_new and other.view_id == 2
    assert other.difference > m.cfg.vt_match_threshold
    # and each is recognised afterwards, by its own id
    assert [m.step(_view(tex, 0)).view_id, m.step(_view(_texture(5), 0)).view_id] == [0, 2]


def test_global_normalisation_absorbs_illumination() -> None:
    tex = _texture(6)
    m = _matcher("ratslam_lv.vt_patch_normalise=0")
    m.step(_view(tex, 0))
    dim = (_view(tex, 0).astype(np.float32) * 0.6).astype(np.uint8)
    res = m.step(dim)
    assert not res.is_new and res.view_id == 0
    raw = _matcher("ratslam_lv.vt_patch_normalise=0", "ratslam_lv.vt_normalisation=0")
    raw.step(_view(tex, 0))
    assert raw.step(dim).is_new  # without it a darker pass is a new place


def test_bad_crop_is_a_clear_error() -> None:
    m = _matcher("ratslam_lv.image_crop_y_min=300")
    with pytest.raises(ValueError, match="crop"):
        m.make_template(_view(_texture(1), 0))
