"""The experience map's storage (services/expmap/storage.py): SweepStore, its per-node sonar sweeps."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from common.resume import load_checkpoint, save_checkpoint
from services.expmap.storage import SweepStore


def _sweep(rng, k):
    return rng.normal(size=(k, 2)).astype(np.float32)


def test_behaves_like_the_list_it_replaces():
    rng = np.random.default_rng(0)
    ref = [_sweep(rng, 30), None, _sweep(rng, 5), _sweep(rng, 2000)]   # the last forces growth
    store = SweepStore(ref[:2])
    store.append(ref[2])
    store.append(ref[3])
    assert len(store) == 4
    for got, want in zip([*store], ref):
        assert (got is None and want is None) or np.array_equal(got, want)
    assert store[1] is None and np.array_equal(store[-1], ref[3])
    assert [s is None for s in store[1:3]] == [True, False]
    # a returned sweep is a copy: changing it does not change the map
    a = store[0]
    a[:] = 0
    assert np.array_equal(store[0], ref[0])
    # same length writes in place, another length moves the node's window, None clears
    rot = ref[0] @ np.array([[0, -1], [1, 0]], np.float32)
    store[0] = rot
    store[2] = _sweep(rng, 9)
    store[3] = None
    assert np.array_equal(store[0], rot) and store[2].shape == (9, 2) and store[3] is None
    with pytest.raises(IndexError, match="sweep 4 of 4"):
        store[4]
    back = pickle.loads(pickle.dumps(store))
    assert all((x is None and y is None) or np.array_equal(x, y) for x, y in zip(back, store))


def test_a_checkpoint_writes_only_what_was_appended(tmp_path):
    rng = np.random.default_rng(1)
    store = SweepStore([_sweep(rng, 400) for _ in range(2000)])      # 6.4 MB of points
    path = tmp_path / "expmap.ckpt"
    first = save_checkpoint(path, {"node": {"sweeps": store}})
    for _ in range(20):
        store.append(_sweep(rng, 400))
    second = save_checkpoint(path, {"node": {"sweeps": store}})
    assert first.written > 6_000_000
    assert second.written < 0.4 * first.written          # the new tail and the small index, not the whole
    got = load_checkpoint(path)["node"]["sweeps"]
    assert len(got) == 2020 and all(np.array_equal(x, y) for x, y in zip(got, store))
