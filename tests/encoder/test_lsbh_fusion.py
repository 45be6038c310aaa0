"""LSBH (Eq. 4.2) and fusion (Eq. 4.3): the worked example of Section 4.2.2 and invariants."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.encoder.fusion import fuse
from services.encoder.lsbh import (
    LsbhEncoder,
    LsbhError,
    load_or_create_projection,
    lsbh_bits,
    lsbh_k,
    make_projection,
    projection_path,
)

CAM_V = [0.9, -1.2, 0.1, -0.8, 2.1, -0.4, 0.7, -1.5]
SON_V = [0.2, -0.9, 1.5, -1.1, 0.4, -0.2, 0.8, -1.7]


def one_based(bits: np.ndarray) -> set[int]:
    return {int(b) + 1 for b in bits}


def test_worked_example_section_4_2_2() -> None:
    k = lsbh_k(16, 0.25)
    assert k == 2
    cam = lsbh_bits(np.array(CAM_V), k)
    son = lsbh_bits(np.array(SON_V), k)
    assert one_based(cam) == {1, 5, 10, 16}
    assert one_based(son) == {3, 7, 12, 16}
    assert cam.dtype == np.uint32 and list(cam) == sorted(cam)
    dense = np.zeros(16, dtype=int)
    dense[cam] = 1
    assert dense.tolist() == [1, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1]
    fused = fuse({"camera": cam, "sonar": son}, "union")
    assert one_based(fused) == {1, 3, 5, 7, 10, 12, 16}
    assert one_based(fuse({"camera": cam, "sonar": son}, "and")) == {16}


@pytest.mark.parametrize("p,s", [(8, 0.25), (1024, 0.25), (1024, 0.02), (37, 0.5), (5, 0.9)])
def test_exactly_2k_bits_random_and_ties(p: int, s: float) -> None:
    rng = np.random.default_rng(p)
    k = int(np.floor(s * p))
    for trial in range(50):
        if trial % 3 == 0:
            v = rng.standard_normal(p)
        elif trial % 3 == 1:
            v = rng.integers(-2, 3, p).astype(float)  # many ties
        else:
            v = np.full(p, 0.5)  # everything tied
        bits = lsbh_bits(v, k)
        assert bits.size == 2 * k
        assert np.unique(bits).size == 2 * k
        top, bottom = bits[bits < p], bits[bits >= p] - p
        assert top.size == k and bottom.size == k
        # no excluded value beats a selected one
        assert v[top].min() >= np.delete(v, top).max() if k < p else True
        assert v[bottom].max() <= np.delete(v, bottom).min() if k < p else True
        # ties: deterministic (lowest index first) and repeatable
        assert np.array_equal(bits, lsbh_bits(v.copy(), k))


def test_ties_break_towards_lower_index() -> None:
    v = np.array([1.0, 1.0, 1.0, 0.0, -1.0, -1.0, -1.0, 0.0])
    assert lsbh_bits(v, 2).tolist() == [0, 1, 8 + 4, 8 + 5]


def test_bad_inputs_are_clear() -> None:
    with pytest.raises(LsbhError, match="non-finite"):
        lsbh_bits(np.array([0.0, np.nan, 1.0, 2.0]), 1)
    with pytest.raises(LsbhError, match="even"):
        lsbh_k(15, 0.25)
    with pytest.raises(LsbhError, match="k = floor"):
        lsbh_k(4, 0.25)


def test_projection_unit_columns_seeded_per_modality() -> None:
    a = make_projection(50, 16, 42, "camera")
    assert a.shape == (50, 16) and a.dtype == np.float32
    assert np.allclose(np.linalg.norm(a, axis=0), 1.0, atol=1e-5)
    assert np.array_equal(a, make_projection(50, 16, 42, "camera"))
    assert not np.allclose(a, make_projection(50, 16, 42, "sonar"))
    assert not np.allclose(a, make_projection(50, 16, 43, "camera"))


def test_projection_persisted_and_reloaded(tmp_path: Path) -> None:
    path = projection_path(str(tmp_path / "st" / "lsbh_{backbone}_{modality}.npy"), "shufflenetv2", "sonar")
    assert path.name == "lsbh_shufflenetv2_sonar.npy"
    p1 = load_or_create_projection(path, 30, 8, 42, "sonar")
    assert path.exists()
    # overwrite with a different (valid) matrix: reload must return the file, not regenerate
    other = np.random.default_rng(0).standard_normal((30, 8)).astype(np.float32)
    np.save(path, other)
    p2 = load_or_create_projection(path, 30, 8, 42, "sonar")
    assert np.array_equal(p2, other) and not np.array_equal(p1, other)
    np.save(path, p1)
    assert np.array_equal(load_or_create_projection(path, 30, 8, 42, "sonar"), p1)
    with pytest.raises(LsbhError, match=r"lsbh_shufflenetv2_sonar.npy has shape \(30, 8\).*\(31, 8\)"):
        load_or_create_projection(path, 31, 8, 42, "sonar")
    with pytest.raises(LsbhError, match="lsbh.matrix_path"):
        projection_path("state/{model}.npy", "a", "b")


def test_lsbh_encoder_batch_matches_single() -> None:
    enc = LsbhEncoder(make_projection(40, 32, 1, "camera"), 64, 0.25)
    y = np.random.default_rng(3).standard_normal((5, 40)).astype(np.float32)
    batch = enc.encode_batch(y)
    for i in range(5):
        assert np.array_equal(batch[i], enc.encode(y[i]))
        assert batch[i].size == 2 * 8
    with pytest.raises(LsbhError, match="41 dimensions"):
        enc.encode(np.zeros(41))


def test_fusion_modes_and_missing_modality() -> None:
    cam = np.array([1, 4, 9], dtype=np.uint32)
    son = np.array([4, 7], dtype=np.uint32)
    both = {"camera": cam, "sonar": son}
    assert fuse(both, "union").tolist() == [1, 4, 7, 9]
    assert fuse(both, "and").tolist() == [4]
    assert fuse(both, "camera").tolist() == [1, 4, 9]
    assert fuse(both, "sonar").tolist() == [4, 7]
    # a missing modality is not an error
    assert fuse({"camera": cam}, "union").tolist() == [1, 4, 9]
    assert fuse({"camera": cam, "sonar": None}, "and").tolist() == [1, 4, 9]
    assert fuse({"sonar": son}, "camera").size == 0
    assert fuse({}, "union").size == 0
    assert fuse(both, "union").dtype == np.uint32
    with pytest.raises(ValueError, match="fusion_mode"):
        fuse(both, "xor")


def test_union_is_each_bit_once_sorted_and_leaves_the_inputs_alone() -> None:
    rng = np.random.default_rng(11)
    for _ in range(300):
        sdrs = {m: np.sort(rng.choice(2048, int(rng.integers(0, 700)), replace=False)).astype(np.uint32)
                for m in ("camera", "sonar") if rng.random() < 0.85}
        before = {m: v.copy() for m, v in sdrs.items()}
        out = fuse(sdrs, "union")
        ref = np.unique(np.concatenate(list(sdrs.values()))) if sdrs else np.zeros(0)
        assert out.dtype == np.uint32 and out.tolist() == ref.tolist()
        assert all(np.array_equal(sdrs[m], before[m]) for m in sdrs)
    unsorted = np.array([9, 1, 4], dtype=np.uint32)      # a single modality, not sorted: still sorted out
    assert fuse({"camera": unsorted}, "union").tolist() == [1, 4, 9] and unsorted.tolist() == [9, 1, 4]
