"""Sequence memory (services/htm/sequence.py): a revisit whose frames look different from the
stored ones, one by one, is recognised by the order of its frames; a shuffled revisit is not."""
from __future__ import annotations

import numpy as np
import pytest

from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm
from services.htm.sequence import SequenceMatcher
from tests.htm.sdr_places import L
from tests.htm.sdr_places import other_appearance as _other_appearance
from tests.htm.sdr_places import place as _place

K = 8


def _route(seed: int = 3, n: int = 40):
    rng = np.random.default_rng(seed)
    route = [_place(rng) for _ in range(n)]
    # a revisit of places 10..29, every frame a new appearance: R with its place = 0.35 (0.72 gate
    # fails; two unrelated frames overlap by ~0.15)
    revisit = [_other_appearance(route[p], 0.35, rng) for p in range(10, 30)]
    return route, revisit, rng


def test_pack_matches_the_set_overlap():
    m = SequenceMatcher(L, 3, [1.0], 0)
    rng = np.random.default_rng(0)
    a, b = _place(rng), _place(rng)
    pa, pb = m.pack(a), m.pack(b)
    inter = sum(bin(int(x) & int(y)).count("1") for x, y in zip(pa, pb))
    assert inter == np.intersect1d(a, b).size
    with pytest.raises(ValueError, match="out of range"):
        m.pack(np.array([L]))


def test_consistent_revisit_scores_its_diagonal_and_a_shuffled_one_does_not():
    route, revisit, rng = _route()
    m = SequenceMatcher(L, K, [1.0], 0)
    for i, p in enumerate(route):
        m.add(p, i)
    m.reset()
    ordered = [m.score(f) for f in revisit]
    # once K frames of the revisit are in, the best diagonal ends at the stored frame of the place
    assert [s.frame for s in ordered[K:]] == list(range(10 + K, 30))
    assert min(s.score for s in ordered[K:]) > 2.0
    assert min(s.score - s.second for s in ordered[K:]) > HtmConfig().seqmem.margin
    m.reset()
    order = rng.permutation(len(revisit))
    shuffled = [m.score(revisit[k]) for k in order]
    # single hits, no line: nothing scores like the diagonal, nothing passes the default margin gate
    assert max(s.score for s in shuffled) < 0.6 * min(s.score for s in ordered[K:])
    assert max(s.score - s.second for s in shuffled) < HtmConfig().seqmem.margin


def test_causal_the_score_of_a_frame_ignores_later_frames():
    route, revisit, _ = _route()
    a, b = SequenceMatcher(L, K, [1.0], 0), SequenceMatcher(L, K, [1.0], 0)
    for i, p in enumerate(route):
        a.add(p, i)
        b.add(p, i)
    a.reset()
    b.reset()
    sa = [a.score(f) for f in revisit[:12]]
    sb = [b.score(f) for f in revisit[:12] + revisit[12:]][:12]
    assert [(s.frame, s.score, s.second) for s in sa] == [(s.frame, s.score, s.second) for s in sb]


def _pipeline(seqmem_length: int, revisit_order=None, tmp_path=None):
    route, revisit, rng = _route()
    cfg = HtmConfig(input_size=L, seqmem={"length": seqmem_length, "exclude": 5}, lvc={"successor_threshold": 0.0})
    h = NeocortexHtm(cfg)
    first = [h.step(p.astype(np.uint32)).lvc_id for p in route]
    if tmp_path is not None:   # the frame memory and its history are part of the saved state
        h.save(tmp_path / "h.npz")
        h = NeocortexHtm.load(tmp_path / "h.npz", cfg)
    frames = revisit if revisit_order is None else [revisit[k] for k in revisit_order]
    again = [h.step(f.astype(np.uint32)) for f in frames]
    return first, again, h


def test_pipeline_gives_a_consistent_revisit_the_ids_of_its_places(tmp_path):
    first, again, h = _pipeline(K, tmp_path=tmp_path)
    assert first == list(range(40))                      # the route: one new LVC per place
    late = again[K:]
    assert all(r.by_sequence and not r.is_new for r in late)
    assert [r.lvc_id for r in late] == list(range(10 + K, 30))
    assert all(r.rate < 0.72 for r in late)              # each frame alone fails Eq. 4.9's gate
    _, off, _ = _pipeline(0)
    assert all(r.is_new for r in off)                    # without the sequence memory: new places


def test_pipeline_does_not_match_a_shuffled_revisit():
    order = np.random.default_rng(11).permutation(20)
    _, again, _ = _pipeline(K, revisit_order=order)
    assert not any(r.by_sequence for r in again)
    assert all(r.is_new for r in again)


def test_query_only_steps_leave_the_memory_unchanged():
    route, revisit, _ = _route()
    h = NeocortexHtm(HtmConfig(input_size=L, seqmem={"length": K}, lvc={"successor_threshold": 0.0}))
    for p in route:
        h.step(p.astype(np.uint32))
    h.reset_sequence()
    ids = [h.step(f.astype(np.uint32), store=False) for f in revisit]
    assert len(h.seqmem) == 40 and len(h.lvc) == 40
    assert [r.lvc_id for r in ids[K:]] == list(range(10 + K, 30))
    assert [r.frame for r in ids[K:]] == list(range(10 + K, 30))


def test_bad_configuration_is_named():
    with pytest.raises(ValueError, match="seqmem.velocities"):
        HtmConfig(seqmem={"velocities": [1.0, 0.0]})


def _stream(seed: int, n: int, places: int = 60, bits: int = 300, noise: float = 0.2) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    route = [_place(rng, bits) for _ in range(places)]
    out = []
    for t in range(n):
        p = route[(t // 2) % places]
        keep = rng.random(p.size) >= noise
        out.append(np.unique(np.concatenate([p[keep], rng.choice(L, int((~keep).sum()), replace=False)])))
    return out


@pytest.mark.parametrize("velocities,exclude,length", [([1.0], 50, 40), ([1.0, 2.0], 5, 10), ([1.0], 0, 5)])
def test_incremental_diagonals_give_the_full_computations_scores(velocities, exclude, length):
    """The running diagonal sums (one add and one subtract per stored frame and frame) score
    like the K-term sums: same ending frame, runner-up and F1s, S* to float rounding, through
    resets, query-only steps, a state round trip and the memory's growth."""
    inc = SequenceMatcher(L, length, velocities, exclude)
    full = SequenceMatcher(L, length, velocities, exclude, incremental=False)
    assert inc.incremental and not full.incremental
    for t, d in enumerate(_stream(1, 700)):
        if t in (250, 520):
            inc.reset()
            full.reset()
        if t == 400:  # a restored checkpoint carries the sums on
            restored = SequenceMatcher(L, length, velocities, exclude)
            restored.set_state(inc.state())
            inc = restored
        a, b = inc.score(d, update=t % 7 != 0), full.score(d, update=t % 7 != 0)
        assert (a.frame, a.f1, a.f1_second) == (b.frame, b.f1, b.f1_second), t
        assert a.score == pytest.approx(b.score, abs=1e-9) and a.second == pytest.approx(b.second, abs=1e-9), t
        assert a.last == b.last
        if t % 3:
            inc.add(d, t)
            full.add(d, t)
    assert len(inc) > 256  # grew past the first allocation


def test_incremental_sums_rebuilt_from_a_state_without_them():
    """A checkpoint written by the full computation (no running sums) restores into the
    incremental matcher, which then scores like the full one."""
    full = SequenceMatcher(L, 10, [1.0], 5, incremental=False)
    stream = _stream(2, 300)
    for t, d in enumerate(stream[:200]):
        full.score(d)
        full.add(d, t)
    inc = SequenceMatcher(L, 10, [1.0], 5)
    st = full.state()
    assert st["diag"].shape[0] == 0
    inc.set_state(st)
    for t, d in enumerate(stream[200:]):
        a, b = inc.score(d), full.score(d)
        assert a.frame == b.frame and a.score == pytest.approx(b.score, abs=1e-9), t
        inc.add(d, t)
        full.add(d, t)


def test_velocities_without_a_constant_step_use_the_full_computation():
    assert not SequenceMatcher(L, 8, [0.8, 1.25], 0).incremental
    assert SequenceMatcher(L, 8, [1.0, 2.0], 0).incremental


def _sparse_stream(seed: int, n: int, bits: int = 15) -> list[np.ndarray]:
    """Descriptors as sparse as the default tm descriptor (15 of L bits), places recurring."""
    rng = np.random.default_rng(seed)
    places = [np.sort(rng.choice(L, bits, replace=False)) for _ in range(60)]
    out = []
    for t in range(n):
        p = places[(t // 3) % len(places)]
        keep = rng.random(bits) < 0.7
        out.append(np.unique(np.concatenate([p[keep], rng.choice(L, int((~keep).sum()), replace=False)])))
    return out


@pytest.mark.parametrize("sparse", [True, False])
def test_f1_row_from_the_posting_lists_equals_the_packed_words(sparse):
    """The inverted index gives the F1 row of the packed words exactly (same scores, ending
    frames and F1s), through resets, query-only steps and a state round trip (which rebuilds
    the index from the memory); a memory holding a dense descriptor (the default sdr source)
    keeps no index at all, before or after a state round trip."""
    stream = _sparse_stream(4, 900) if sparse else _stream(4, 400)
    ix = SequenceMatcher(L, 10, [1.0, 2.0], 20)
    ref = SequenceMatcher(L, 10, [1.0, 2.0], 20)
    ref._postings = None  # no index: the packed words every time
    used = 0
    for t, d in enumerate(stream):
        if t == 500:
            ix.reset()
            ref.reset()
        if t == 300:
            restored = SequenceMatcher(L, 10, [1.0, 2.0], 20)
            restored.set_state(ix.state())
            ix = restored
        if ix._postings is not None:
            used += ix._postings.cost(np.unique(d)) * 4 < ix.candidates() * ix.words
        a, b = ix.score(d, update=t % 5 != 0), ref.score(d, update=t % 5 != 0)
        assert (a.frame, a.score, a.second, a.last, a.f1, a.f1_second) == \
            (b.frame, b.score, b.second, b.last, b.f1, b.f1_second), t
        if t % 4:
            ix.add(d, t)
            ref.add(d, t)
    assert (used > 0) == sparse  # the index is what ran for sparse descriptors, never for dense ones
    assert (ix._postings is not None) == sparse  # a dense memory holds no index (it would never pay)
