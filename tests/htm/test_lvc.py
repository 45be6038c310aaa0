import numpy as np
import pytest

from services.htm.lvc import LvcMatcher

N = 81920


def matcher(i_min=12, tau=0.30, f1=True, min_f1=0.55, iou=True):
    return LvcMatcher(N, i_min, tau, f1, min_f1, iou)


def bits(*xs):
    return np.array(sorted(xs), np.int32)


def test_first_place_revisited_is_lvc_0():
    m = matcher()
    first = np.arange(100, 115, dtype=np.int32)
    r0 = m.match(first)
    assert (r0.lvc_id, r0.is_new) == (0, True)
    # other places in between
    for k in range(1, 6):
        assert m.match(np.arange(1000 * k, 1000 * k + 15, dtype=np.int32)).lvc_id == k
    again = m.match(first)
    assert (again.lvc_id, again.is_new, again.intersection, again.rate) == (0, False, 15, 1.0)
    assert len(m) == 6                                   # the first frame was stored once


def test_new_place_new_id_and_ids_dense():
    m = matcher()
    ids = [m.match(np.arange(20 * k, 20 * k + 15, dtype=np.int32)).lvc_id for k in range(10)]
    assert ids == list(range(10))


def _query_with(proto, i, n, extra_base=50000):
    """A query of n bits sharing exactly i bits with proto."""
    return np.sort(np.concatenate([proto[:i], np.arange(extra_base, extra_base + n - i)])).astype(np.int32)


def test_eq_4_9_intersection_floor():
    proto = np.arange(0, 15, dtype=np.int32)
    m = matcher(i_min=12, tau=0.30, f1=False)
    m.add(proto)
    r = m.match(_query_with(proto, 12, 15))
    assert (r.lvc_id, r.is_new, r.intersection) == (0, False, 12)
    m2 = matcher(i_min=12, tau=0.30, f1=False)
    m2.add(proto)
    r = m2.match(_query_with(proto, 11, 15))          # I = 11 < I_min although R = 0.73
    assert r.is_new and r.lvc_id == 1 and r.best_candidate == 0 and r.best_intersection == 11


def test_eq_4_9_rate_threshold_at_and_below():
    proto = np.arange(0, 40, dtype=np.int32)
    # |D_t| = 40, I = 12 -> R = 0.30 exactly: accepted with tau_R = 0.30
    m = matcher(i_min=12, tau=0.30, f1=False)
    m.add(proto)
    r = m.match(_query_with(proto, 12, 40))
    assert not r.is_new and r.rate == pytest.approx(0.30)
    # |D_t| = 41, I = 12 -> R = 0.2927 < 0.30: new id
    m = matcher(i_min=12, tau=0.30, f1=False)
    m.add(proto)
    r = m.match(_query_with(proto, 12, 41))
    assert r.is_new and r.best_rate == pytest.approx(12 / 41)
    # same through tau_R = 0.38 (htm.lvc.match_threshold): 19/50 = 0.38 passes, 18/50 does not
    proto50 = np.arange(0, 50, dtype=np.int32)
    for i, new in ((19, False), (18, True)):
        m = matcher(i_min=12, tau=0.38, f1=False)
        m.add(proto50)
        assert m.match(_query_with(proto50, i, 50)).is_new is new


def test_f1_gate():
    # I = 12, |D_t| = 15 (R = 0.8) against a dense prototype of 30 bits: F1 = 24/45 = 0.533
    proto = np.arange(0, 30, dtype=np.int32)
    q = _query_with(proto, 12, 15)
    on = matcher(f1=True, min_f1=0.55)
    on.add(proto)
    assert on.match(q).is_new
    off = matcher(f1=False)
    off.add(proto)
    assert not off.match(q).is_new
    # F1 exactly at the gate: I = 11, |D_t| = 15, |D_l| = 25 -> F1 = 22/40 = 0.55
    gate = matcher(i_min=11, f1=True, min_f1=0.55)
    gate.add(np.arange(0, 25, dtype=np.int32))
    assert not gate.match(_query_with(np.arange(0, 25, dtype=np.int32), 11, 15)).is_new


def test_argmax_r_then_iou_then_lowest_id():
    m = matcher(i_min=1, tau=0.0, f1=False)
    big = np.arange(0, 40, dtype=np.int32)            # id 0: shares 13, 40 bits
    small = np.arange(0, 13, dtype=np.int32)          # id 1: shares 13, 13 bits (higher IoU)
    other = np.concatenate([np.arange(0, 12), [60000]]).astype(np.int32)  # id 2: shares 12
    for p in (big, small, other):
        m.add(p)
    q = np.concatenate([np.arange(0, 13), np.arange(70000, 70002)]).astype(np.int32)
    assert m.match(q).lvc_id == 1
    m_no_iou = LvcMatcher(N, 1, 0.0, False, 0.0, False)
    for p in (big, small, other):
        m_no_iou.add(p)
    assert m_no_iou.match(q).lvc_id == 0               # equal R: lowest id
    dup = matcher(i_min=1, tau=0.0, f1=False)
    dup.add(small)
    dup.add(small.copy())
    assert dup.match(q).lvc_id == 0


def test_matches_brute_force_on_random_sets():
    rng = np.random.default_rng(0)
    m = matcher(i_min=3, tau=0.2, f1=True, min_f1=0.3)
    protos = []
    for _ in range(400):
        if protos and rng.random() < 0.5:
            base = protos[rng.integers(len(protos))]
            keep = base[rng.random(base.size) < 0.7]
            d = np.unique(np.concatenate([keep, rng.integers(0, 300, 15 - keep.size)])).astype(np.int32)
        else:
            d = np.unique(rng.integers(0, 300, 15)).astype(np.int32)
        inter = np.array([np.intersect1d(d, p).size for p in protos])
        r = m.match(d)
        if protos and inter.max() > 0:
            lens = np.array([p.size for p in protos])
            order = np.lexsort((np.arange(len(protos)), lens, -inter))
            best = order[0]
            ok = inter[best] >= 3 and inter[best] / d.size >= 0.2 and 2 * inter[best] / (d.size + lens[best]) >= 0.3
        else:
            ok = False
        if ok:
            assert (r.lvc_id, r.is_new) == (best, False)
        else:
            assert r.is_new and r.lvc_id == len(protos)
            protos.append(d)


def test_state_roundtrip_and_validation():
    m = matcher()
    for k in range(50):
        m.match(np.arange(7 * k, 7 * k + 15, dtype=np.int32))
    m2 = matcher()
    m2.set_state(m.state())
    assert len(m2) == len(m)
    for k in range(60):
        q = np.arange(5 * k, 5 * k + 15, dtype=np.int32)
        assert m.match(q) == m2.match(q)
    with pytest.raises(ValueError, match="sorted unique"):
        m.match(np.array([3, 1], np.int32))
    with pytest.raises(IndexError):
        m.prototype(10_000)


@pytest.mark.parametrize("bits,n_bits", [(900, 2048), (40, 2048), (300, 8192)])
def test_packed_and_inverted_searches_choose_the_same_lvc(bits, n_bits):
    """The bit-packed search (dense spaces) and the inverted index give the same l*, I and ids,
    ties included (prototypes of equal I and of equal size), through the stores' growth."""
    rng = np.random.default_rng(bits)
    kw = dict(min_intersection=12, tau_r=0.6, f1_gate=True, min_f1=0.6, iou_tiebreak=True)
    packed = LvcMatcher(n_bits, search="packed", **kw)
    inverted = LvcMatcher(n_bits, search="inverted", **kw)
    assert packed.packed and not inverted.packed
    assert LvcMatcher(n_bits, **kw).packed == (n_bits <= 8192)
    places = [np.sort(rng.choice(n_bits, bits, replace=False)) for _ in range(40)]
    for t in range(2600):
        base = places[rng.integers(len(places))]
        keep = rng.random(base.size) > rng.uniform(0.0, 0.9)
        d = np.unique(np.concatenate([base[keep], rng.choice(n_bits, int((~keep).sum()), replace=False)]))
        if t % 5 == 0:
            d = d[: max(1, d.size - int(rng.integers(0, 3)))]   # sizes that differ: the IoU tie-break
        assert packed.best(d) == inverted.best(d), t
        a, b = packed.match(d), inverted.match(d)
        assert (a.lvc_id, a.is_new, a.intersection) == (b.lvc_id, b.is_new, b.intersection), t
    assert len(packed) == len(inverted) > 1024    # the stores grew past their first capacity
    assert packed.best(np.array([], np.int32)) == inverted.best(np.array([], np.int32)) == (-1, 0)
    with pytest.raises(ValueError, match="auto, inverted or packed"):
        LvcMatcher(n_bits, search="dense", **kw)
