"""Place-sequence prior of NeocortexHtm: a revisit locked onto an earlier stretch keeps its ids."""
from __future__ import annotations

import numpy as np

from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm

L = 2048


def _place(rng: np.random.Generator) -> np.ndarray:
    return np.sort(rng.choice(L, 500, replace=False)).astype(np.uint32)


def _noisy(bits: np.ndarray, frac: float, rng: np.random.Generator) -> np.ndarray:
    """Replace ``frac`` of the bits by bits outside the set: R with the original = 1 - frac."""
    keep = rng.choice(bits, int(round(bits.size * (1 - frac))), replace=False)
    others = np.setdiff1d(np.arange(L), bits)
    new = rng.choice(others, bits.size - keep.size, replace=False)
    return np.sort(np.concatenate([keep, new])).astype(np.uint32)


def _run(seq_gate: float, tmp_path=None):
    rng = np.random.default_rng(4)
    route = [_place(rng) for _ in range(12)]
    h = NeocortexHtm(HtmConfig(input_size=L, lvc={"successor_threshold": seq_gate}))
    first = [h.step(p).lvc_id for p in route]
    # the revisit: the first frame close to the stored place (passes the 0.72 gate), the others at R = 0.68
    revisit = [_noisy(route[0], 0.1, rng)] + [_noisy(p, 0.32, rng) for p in route[1:]]
    if tmp_path is not None:  # the successor graph is part of the saved state
        h.save(tmp_path / "h.npz")
        h = NeocortexHtm.load(tmp_path / "h.npz", h.cfg)
    again = [h.step(p).lvc_id for p in revisit]
    strangers = [h.step(_place(rng)) for _ in range(5)]
    return first, again, strangers, h


def test_revisit_follows_the_stored_sequence_only_with_the_prior(tmp_path):
    first, again, strangers, h = _run(0.65, tmp_path)
    assert first == list(range(12))
    assert again == first                                   # every weak frame kept its place's id
    assert all(s.is_new for s in strangers)                 # unrelated places are not pulled in
    assert all(i + 1 in h.successors[i] for i in range(11))  # the route's chain survived save/load
    _, again_off, _, _ = _run(0.0)
    assert again_off[0] == 0 and all(i >= 12 for i in again_off[1:])  # without: new ids after the first


def test_query_only_steps_use_the_graph_without_learning():
    rng = np.random.default_rng(9)
    route = [_place(rng) for _ in range(6)]
    h = NeocortexHtm(HtmConfig(input_size=L, lvc={"successor_threshold": 0.65}))
    for p in route:
        h.step(p)
    graph = {a: set(b) for a, b in h.successors.items()}
    h.reset_sequence()
    assert h.predicted_ids() == []
    ids = [h.step(p, store=False).lvc_id for p in [_noisy(route[0], 0.1, rng)] +
           [_noisy(p, 0.32, rng) for p in route[1:]]]
    assert ids == list(range(6)) and h.successors == graph and len(h.lvc) == 6
