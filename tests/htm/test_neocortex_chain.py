"""The SP + TM chain: overlap-standardised SP, the TM's revisit decision, named chains."""
import numpy as np
import pytest

from services.htm.chains import CHAINS, chain_config
from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm
from services.htm.spatial_pooler import SpatialPooler
from services.htm.tm_match import TmFrameIndex

L = 2048


def _places(n, bits=600, seed=0):
    rng = np.random.default_rng(seed)
    return [np.sort(rng.choice(L, bits, replace=False)) for _ in range(n)]


def _noisy(p, keep, rng):
    k = int(keep * p.size)
    kept = rng.choice(p, k, replace=False)
    rest = np.setdiff1d(np.arange(L), p)
    return np.sort(np.concatenate([kept, rng.choice(rest, p.size - k, replace=False)]))


def test_frame_index_votes_for_the_frame_whose_winners_were_predicted():
    idx = TmFrameIndex(100)
    idx.add(np.array([1, 2, 3]))
    idx.add(np.array([3, 4, 5]))
    idx.add(np.array([5, 6, 7]))
    assert idx.vote(np.array([4, 5]), 3) == (1, 2)
    assert idx.vote(np.array([5]), 3) == (2, 1)          # ties go to the latest frame
    assert idx.vote(np.array([5]), 2) == (1, 1)          # frames >= nc are not candidates
    assert idx.vote(np.array([], np.int64), 3) == (-1, 0)
    clone = TmFrameIndex(100)
    clone.set_state(idx.state())
    assert clone.vote(np.array([4, 5]), 3) == (1, 2) and len(clone) == 3


def test_overlap_standardised_sp_keeps_similarity_better_than_random():
    rng = np.random.default_rng(1)
    places = _places(30)
    sp = SpatialPooler(L, 2048, 200, L, 0.5, 0.006, 0.008, 0.1, 0.0, 1000, 0.001, 7, overlap_norm_steps=60)
    first = [sp.compute(_noisy(p, 0.8, rng)) for p in places]
    second = [sp.compute(_noisy(p, 0.8, rng)) for p in places]
    same = np.mean([np.intersect1d(a, b).size / 200 for a, b in zip(first, second)])
    other = np.mean([np.intersect1d(a, b).size / 200 for a, b in zip(first, second[1:] + second[:1])])
    assert sp.ov_n == 60                                 # statistics frozen after 60 steps
    assert same > 0.25 and other < 0.15 and same > 2 * other   # random: 200 / 2048 ~ 0.1


def test_tm_decides_a_revisit_of_a_learned_sequence():
    places = _places(40, seed=3)
    cfg = HtmConfig(input_size=L, descriptor={"source": "sp"}, tm={"decide": True, "input_columns": 40, "cells_per_column": 8, "decide_share": 0.3}, sp={"potential_radius": L, "num_active_columns": 200, "overlap_norm_steps": 40, "boost_strength": 0.0}, seqmem={"length": 0, "exclude": 5}, lvc={"successor_threshold": 0.0, "match_threshold": 0.99, "min_f1": 0.99})
    h = NeocortexHtm(cfg)
    lap1 = [h.step(p) for p in places]
    lap2 = [h.step(p) for p in places]
    assert not any(r.by_tm for r in lap1)
    by_tm = [r for r in lap2 if r.by_tm]
    assert len(by_tm) > len(places) // 2
    assert all(r.lvc_id == lap1[r.tm_frame].lvc_id for r in by_tm)
    assert sum(r.lvc_id == a.lvc_id for r, a in zip(lap2, lap1)) >= len(by_tm) - 2


def test_a_shuffled_revisit_is_not_decided_by_the_tm():
    places = _places(40, seed=4)
    cfg = HtmConfig(input_size=L, descriptor={"source": "sp"}, tm={"decide": True, "input_columns": 40, "cells_per_column": 8, "decide_share": 0.3}, sp={"potential_radius": L, "num_active_columns": 200, "overlap_norm_steps": 40, "boost_strength": 0.0}, seqmem={"length": 0, "exclude": 5}, lvc={"successor_threshold": 0.0, "match_threshold": 0.99, "min_f1": 0.99})
    h = NeocortexHtm(cfg)
    for p in places:
        h.step(p)
    order = np.random.default_rng(5).permutation(len(places))
    assert sum(h.step(places[i]).by_tm for i in order) <= 3


def test_chains_and_state_round_trip(tmp_path):
    assert set(CHAINS) >= {"sdr_seqmem", "sp_tm"}
    with pytest.raises(ValueError, match="unknown front-end chain"):
        chain_config(HtmConfig(), "nope")
    cfg = chain_config(HtmConfig(input_size=L), "sp_tm").updated({"sp.overlap_norm_steps": 20})
    places = _places(30, seed=6)
    a = NeocortexHtm(cfg)
    for p in places[:20]:
        a.step(p)
    a.save(tmp_path / "s.npz")
    b = NeocortexHtm.load(tmp_path / "s.npz", cfg)
    for p in places[20:] + places[:10]:
        ra, rb = a.step(p), b.step(p)
        assert (ra.lvc_id, ra.by_tm, ra.tm_frame) == (rb.lvc_id, rb.by_tm, rb.tm_frame)
    sdr = NeocortexHtm(chain_config(HtmConfig(input_size=L), "sdr_seqmem"))
    assert sdr.sp is None and sdr.tm is None


def test_the_sp_tm_preset_is_the_sp_tm_chain():
    from system.config import load_config
    from tests.conftest import REPO
    cfg = load_config(REPO / "services" / "htm" / "presets" / "sp_tm.yaml")
    want = chain_config(load_config(None).htm, "sp_tm")
    assert {k: cfg.htm.get(k) for k in CHAINS["sp_tm"]} == {k: want.get(k) for k in CHAINS["sp_tm"]}
