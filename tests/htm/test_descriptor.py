import numpy as np
import pytest

from services.htm.descriptor import DescriptorBuilder


def builder(mode="tm", n_bits=81920, window=7, topk=15, interval=True, alpha=0.65, rho=3, max_bits=0):
    return DescriptorBuilder(mode, n_bits, window, topk, interval, alpha, rho, max_bits, 42)


def test_temporal_pooling_keeps_most_frequent_winners():
    b = builder(interval=False)
    rng = np.random.default_rng(0)
    stable = np.arange(0, 800, 80)                   # 10 cells present every step
    for _ in range(7):
        d = b.update(np.concatenate([stable, rng.choice(np.arange(1000, 80000), 10, replace=False)]))
    assert d.size == 15
    assert np.isin(stable, d).all()                  # count 7 beats count 1
    # the window forgets: after 7 steps without them the stable cells are gone
    for _ in range(7):
        d = b.update(rng.choice(np.arange(1000, 80000), 20, replace=False))
    assert not np.isin(stable, d).any()


def test_equal_windows_give_equal_descriptors_and_ties_are_not_low_index_biased():
    rng = np.random.default_rng(1)
    steps = [rng.choice(81920, 20, replace=False) for _ in range(7)]
    a, b = builder(interval=False), builder(interval=False)
    for s in steps:
        da = a.update(s)
        db = b.update(s[::-1])
    assert np.array_equal(da, db)
    union = np.unique(np.concatenate(steps))
    assert not np.array_equal(da, union[:15])        # min-hash order, not the lowest indices


def test_interval_union_runs_and_cap():
    b = builder(mode="sp", n_bits=2048, interval=True, alpha=0.65, rho=3, max_bits=0)
    base = np.arange(0, 20)
    d1 = b.update(base)
    assert b.run_length == 1 and np.array_equal(d1, base)
    s2 = np.concatenate([base[:14], np.arange(100, 106)])     # overlap 14/20 = 0.70 >= 0.65
    d2 = b.update(s2)
    assert b.run_length == 2 and np.array_equal(d2, np.union1d(base, s2))
    s3 = np.concatenate([s2[:13], np.arange(200, 207)])       # 13/20 = 0.65: continues
    d3 = b.update(s3)
    assert b.run_length == 3 and np.array_equal(d3, np.union1d(np.union1d(base, s2), s3))
    s4 = np.concatenate([s3[:14], np.arange(300, 306)])       # continues, but K_max = 3
    d4 = b.update(s4)
    assert b.run_length == 3 and np.array_equal(d4, np.union1d(np.union1d(s2, s3), s4))
    s5 = np.concatenate([s4[:12], np.arange(400, 408)])       # 12/20 = 0.60 < 0.65: new run
    d5 = b.update(s5)
    assert b.run_length == 1 and np.array_equal(d5, s5)
    # with a cap the union is re-sparsified, bits in more of the run's sets first
    c = builder(mode="sp", n_bits=2048, interval=True, alpha=0.65, rho=3, max_bits=20)
    c.update(base)
    d = c.update(s2)
    assert d.size == 20 and np.isin(base[:14], d).all()


def test_tm_mode_cap_defaults_to_topk_and_modes_validated():
    b = builder(interval=True, alpha=0.0)             # every step continues the run
    rng = np.random.default_rng(2)
    for _ in range(10):
        d = b.update(rng.choice(81920, 20, replace=False))
        assert d.size <= 15
    with pytest.raises(ValueError, match="descriptor.source"):
        DescriptorBuilder("cells", 10, 1, 1, False, 0.5, 3, 0, 1)
    with pytest.raises(ValueError, match="out of range"):
        builder().update(np.array([81920]))


def test_state_roundtrip():
    rng = np.random.default_rng(3)
    steps = [rng.choice(81920, 20, replace=False) for _ in range(30)]
    a = builder(alpha=0.1)
    for s in steps[:12]:
        a.update(s)
    b = builder(alpha=0.1)
    b.set_state(a.state())
    for s in steps[12:]:
        assert np.array_equal(a.update(s), b.update(s))
