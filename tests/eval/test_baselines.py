"""Baselines of poseidon vpr on tiny hand-made sequences whose answer is known."""
from __future__ import annotations

import numpy as np
import pytest

from eval.baselines import patch_normalise, sad_similarity, sequence_similarity


def test_sequence_matching_recovers_the_route_where_single_frames_fail():
    n = 14
    rng = np.random.default_rng(0)
    sim = 0.2 + 0.05 * rng.random((n, n))
    sim[np.arange(n), np.arange(n)] = 0.5          # the route: query i is reference i
    sim[9, 3] = 0.9                                 # one distractor beats the true frame for query 9
    sim[12, 0] = 0.95                               # and another one for query 12
    single = sim.argmax(axis=1)
    assert single[9] == 3 and single[12] == 0
    seq = sequence_similarity(sim, length=10)
    assert np.array_equal(seq.argmax(axis=1), np.arange(n))
    # masked pairs stay masked and do not enter the sums
    masked = np.where(np.eye(n, k=1, dtype=bool), -np.inf, sim)
    s2 = sequence_similarity(masked, length=3)
    assert np.all(np.isneginf(s2[np.eye(n, k=1, dtype=bool)])) and np.isfinite(s2[5, 5])
    with pytest.raises(ValueError, match="length"):
        sequence_similarity(sim, length=0)


def test_sequence_of_one_frame_ranks_like_per_reference_normalised_cosine():
    sim = np.array([[0.9, 0.1], [0.8, 0.7]])
    # per reference: column 0 values 0.9/0.8, column 1 0.1/0.7 -> query 1 is relatively best at ref 1
    assert np.array_equal(sequence_similarity(sim, length=1).argmax(axis=1), [0, 1])
    assert np.array_equal(sim.argmax(axis=1), [0, 0])


def test_patch_normalised_sad_ignores_brightness_and_finds_the_place():
    rng = np.random.default_rng(1)
    places = [rng.integers(0, 256, (48, 96, 3)).astype(np.float32) for _ in range(5)]
    # queries: same places, darker and with an offset, plus a little noise
    queries = [np.clip(0.5 * p + 60 + rng.normal(0, 4, p.shape), 0, 255) for p in places]
    ref = np.stack([patch_normalise(p) for p in places])
    qry = np.stack([patch_normalise(q) for q in queries])
    assert ref.shape == (5, 32 * 16)
    sim = sad_similarity(qry, ref)
    assert np.array_equal(sim.argmax(axis=1), np.arange(5))
    assert sim[0, 0] == pytest.approx(-np.abs(qry[0] - ref[0]).mean(), rel=1e-5)
    # a gain/offset change leaves the normalised thumbnail as it was; a flat image gives zeros
    np.testing.assert_allclose(patch_normalise(2.0 * places[0] + 3), patch_normalise(places[0]), atol=1e-3)
    assert not np.any(patch_normalise(np.full((32, 64), 7.0)))
    with pytest.raises(ValueError, match="same d"):
        sad_similarity(ref, ref[:, :10])
