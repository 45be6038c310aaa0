import numpy as np
import pytest

from common.messages import Header, NeocortexSdr, Sdr
from common.node import run_offline
from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm, descriptor_similarity
from system.config import PoseidonConfig
from system.services import build_node

L = 2048


# the SP -> TM -> descriptor chain with Table 4.1's SP, TM and LVC gates (the default descriptor is
# the fused SDR, and the default SP/TM are the overlap-standardised ones)
_CHAIN = {"descriptor.source": "tm", "descriptor.interval_mode": True, "lvc.match_threshold": 0.38, "lvc.min_f1": 0.55,
          "lvc.successor_threshold": 0.0, "tm.decide": False, "sp.columns": 2048, "sp.num_active_columns": 20,
          "sp.potential_radius": 600, "sp.boost_strength": 2.0, "sp.overlap_norm_steps": 0, "tm.input_columns": 0,
          "tm.cells_per_column": 40, "tm.activation_threshold": 5, "tm.max_new_synapse_count": 20}


def TmConfig(changes: dict | None = None) -> HtmConfig:  # noqa: N802 - reads like the config class it builds
    return HtmConfig().updated({**_CHAIN, **(changes or {})})


def route(n_places=12, seed=0):
    rng = np.random.default_rng(seed)
    return [np.sort(rng.choice(L, 512, replace=False)).astype(np.uint32) for _ in range(n_places)]


def noisy(rng, sdr, frac=0.05):
    keep = rng.random(sdr.size) >= frac
    extra = rng.choice(np.setdiff1d(np.arange(L), sdr), int((~keep).sum()), replace=False)
    return np.unique(np.concatenate([sdr[keep], extra])).astype(np.uint32)


def stream(laps=3, seed=0):
    rng = np.random.default_rng(seed + 100)
    places = route(seed=seed)
    return [noisy(rng, p) for _ in range(laps) for p in places for _ in range(2)]


def test_same_input_and_seed_same_id_stream():
    frames = stream()
    a, b = NeocortexHtm(TmConfig()), NeocortexHtm(TmConfig())
    ra = [a.step(f) for f in frames]
    rb = [b.step(f) for f in frames]
    assert ra == rb
    assert ra[0].lvc_id == 0 and ra[0].is_new
    ids = [r.lvc_id for r in ra]
    assert max(ids) == len(a.lvc) - 1
    other = NeocortexHtm(TmConfig({"seed": 43}))
    assert [other.step(f).lvc_id for f in frames] != ids or \
        not np.array_equal(other.last_descriptor, a.last_descriptor)


@pytest.mark.parametrize("literal", [False, True])
def test_route_revisited_after_a_detour_maps_back_to_its_ids(literal):
    route_places = route(n_places=15, seed=1)
    detour = route(n_places=10, seed=9)
    if literal:  # no boosting, cell descriptor, SP always learning
        h = NeocortexHtm(TmConfig({"sp.boost_strength": 0.0, "descriptor.tm_bits": "cells", "sp.learn_steps": 0}))
    else:  # defaults: the SP learns (with boosting) for sp.learn_steps, then keeps its columns
        h = NeocortexHtm(TmConfig())
        for p in route(n_places=HtmConfig().sp.learn_steps, seed=5):
            h.step(p)
        assert h.sp.iteration_learn == HtmConfig().sp.learn_steps
    first = [h.step(p) for p in route_places]
    for p in detour:
        h.step(p)
    second = [h.step(p) for p in route_places]
    assert [r.lvc_id for r in first][0] == (0 if literal else first[0].lvc_id)
    # the route's first place bursts (new context after the detour); from its second place on
    # the TM replays the learnt cells, and once the descriptor.tm_window (7) has flushed the detour
    # the descriptors are those of the first pass again
    for k in range(8, 15):
        r = second[k]
        assert not r.is_new and r.rate >= 0.30 and r.intersection >= 12
        near = {first[j].lvc_id for j in range(max(0, k - 2), min(15, k + 3))}
        assert r.lvc_id in near
    assert max(r.anomaly for r in second[1:]) <= 0.1   # at most 2 of 20 columns unpredicted


@pytest.mark.parametrize("mode", ["sp", "sdr"])
def test_revisiting_first_place_returns_lvc_0_in_sp_and_sdr_modes(mode):
    places = route(seed=2)
    # no boosting: with boost the SP moves the columns of a place during its learning phase
    h = NeocortexHtm(TmConfig({"descriptor.source": mode, "sp.boost_strength": 0.0}))
    first = h.step(places[0])
    assert (first.lvc_id, first.is_new) == (0, True)
    ids = [h.step(p).lvc_id for p in places[3:]]
    assert 0 not in ids
    back = h.step(places[0])
    assert (back.lvc_id, back.is_new) == (0, False)


def test_save_load_continues_identically(tmp_path):
    frames = stream(laps=2, seed=3)
    a = NeocortexHtm(TmConfig())
    for f in frames[:30]:
        a.step(f)
    path = tmp_path / "htm_state.npz"
    a.save(path)
    b = NeocortexHtm.load(path, TmConfig())
    assert [a.step(f) for f in frames[30:]] == [b.step(f) for f in frames[30:]]
    assert np.array_equal(a.last_descriptor, b.last_descriptor)
    with pytest.raises(ValueError, match="tm.cells_per_column"):
        NeocortexHtm.load(path, TmConfig({"tm.cells_per_column": 32}))


def test_input_validation_and_similarity_helper():
    h = NeocortexHtm(TmConfig())
    with pytest.raises(ValueError, match="sorted unique"):
        h.step(np.array([5, 3], np.uint32))
    with pytest.raises(ValueError, match=r"\[0, 2048\)"):
        h.step(np.array([1, 2048], np.uint32))
    s = descriptor_similarity(np.arange(15), np.arange(3, 18))
    assert s["I"] == 12 and s["R"] == pytest.approx(0.8) and s["F1"] == pytest.approx(0.8)


def _messages(frames, camera_only=()):
    out = []
    for i, f in enumerate(frames):
        h = Header(seq=i, stamp=1_000_000_000 + i * 100_000_000, frame_id="base_link")
        mods = [Sdr(header=h, modality="camera", size=L, active=f)]
        out.append(("neocortex/sdr", NeocortexSdr(header=h, modalities=mods,
                                                  fused=Sdr(header=h, modality="fused", size=L, active=f),
                                                  fusion_mode="union")))
    return out


def test_node_publishes_every_frame_with_its_header_and_persists(tmp_path):
    rng = np.random.default_rng(5)
    cam, son = route(seed=5), route(seed=6)
    frames = []
    for lap in range(2):
        for k in range(12):
            fused = np.union1d(cam[k], son[k]) if not (lap == 1 and 4 <= k < 9) else cam[k]  # sonar drops out
            frames.append(noisy(rng, fused.astype(np.uint32), 0.02))
    msgs = _messages(frames)
    cfg = PoseidonConfig(htm=TmConfig())
    out = run_offline(build_node("htm", cfg), msgs)
    assert [k for k, _ in out] == ["local_view_cells"] * len(frames)
    for i, ((_, m), (_, src)) in enumerate(zip(out, msgs)):
        assert m.header.seq == i and m.header.stamp == src.header.stamp and m.header.frame_id == "base_link"
        assert m.most_active_cell == m.active_cells[0].id and 0.0 <= m.active_cells[0].rate <= 1.0
    assert out[0][1].most_active_cell == 0 and out[0][1].is_new

    # state_path: two runs over halves equal one run over everything
    state = tmp_path / "htm.npz"
    cfg_state = PoseidonConfig(htm=TmConfig({"state_path": str(state)}))
    first = run_offline(build_node("htm", cfg_state), msgs[:10])
    assert state.exists()
    second = run_offline(build_node("htm", cfg_state), msgs[10:])
    strip = [(m.most_active_cell, m.is_new, m.intersection, m.active_cells[0].rate) for _, m in first + second]
    assert strip == [(m.most_active_cell, m.is_new, m.intersection, m.active_cells[0].rate) for _, m in out]


def test_node_skips_counts_and_logs_wrong_sdr_size(caplog):
    h = Header(seq=7, stamp=1, frame_id="")
    bad = Sdr(header=h, modality="fused", size=1024, active=np.arange(10, dtype=np.uint32))
    msg = NeocortexSdr(header=h, modalities=[bad], fused=bad, fusion_mode="union")
    good = _messages([np.arange(0, 1000, 2, dtype=np.uint32)])[0][1]
    good = good.model_copy(update={"header": Header(seq=8, stamp=2, frame_id="")})
    node = build_node("htm", PoseidonConfig())
    out = run_offline(node, [("neocortex/sdr", msg), ("neocortex/sdr", good)])
    assert len(out) == 1 and out[0][1].header.stamp == 2
    assert node.counters["sdr_wrong_size"] == 1
    assert "neocortex/sdr seq 7 skipped" in caplog.text and "htm.input_size" in caplog.text


def test_query_only_and_describe():
    places = route(n_places=6, seed=7)
    h = NeocortexHtm(TmConfig({"descriptor.source": "sp", "descriptor.interval_mode": False, "sp.boost_strength": 0.0}))
    ids = [h.step(p).lvc_id for p in places]
    assert ids == list(range(6))
    n = len(h.lvc)
    q = h.step(places[2], learn=False, store=False)
    assert (q.lvc_id, q.is_new, q.rate) == (2, False, 1.0)
    novel = h.step(route(n_places=1, seed=8)[0], learn=False, store=False)
    assert novel.lvc_id == -1 and not novel.is_new and len(h.lvc) == n
    d = h.describe(places[4], learn=False)
    assert np.array_equal(d, h.lvc.prototype(4))
    h.reset_sequence()
    assert h.step(places[5], store=False).lvc_id == 5


def test_sp_frozen_after_sp_learn_steps_keeps_columns():
    places = route(n_places=30, seed=11)
    h = NeocortexHtm(TmConfig({"sp.learn_steps": 20, "descriptor.source": "sp"}))
    for p in places[:20]:
        h.step(p)
    assert h.sp.iteration_learn == 20
    h.step(places[20])
    cols = h.last_columns.copy()
    perm = h.sp.perm.copy()
    for p in places[21:]:
        h.step(p)
    assert h.sp.iteration_learn == 20 and np.array_equal(h.sp.perm, perm)  # frozen
    h.step(places[20])
    assert np.array_equal(h.last_columns, cols)
    # an always-learning SP with boosting moves the columns of the same input
    g = NeocortexHtm(TmConfig({"sp.learn_steps": 0, "descriptor.source": "sp"}))
    for p in places[:21]:
        g.step(p)
    before = g.last_columns.copy()
    for p in places[21:]:
        g.step(p)
    g.step(places[20])
    assert not np.array_equal(g.last_columns, before)


def test_warm_up_compiles_on_a_throwaway_core_and_leaves_the_node_as_it_was() -> None:
    from services.htm.node import HtmNode
    from system.config import PoseidonConfig

    cfg = PoseidonConfig().htm.model_copy(update={"input_size": 1024})
    node = HtmNode(cfg)
    node.warm_up()
    assert len(node.htm.lvc) == 0 and node.htm.seqmem is not None and len(node.htm.seqmem) == 0
    assert node.position is None and node.counters == {}


def test_new_places_memory_grows_with_the_places_not_with_the_laps():
    """A route of 60 places flown four times (the default chain, SP + TM deciding): with
    seqmem.store every_frame the sequence memory and the TM frame index keep every frame;
    with new_places the laps after the first add nearly nothing, and the ids of those laps are
    the ones every_frame gives (the places are recognised the same way)."""
    rng = np.random.default_rng(7)
    places = [np.sort(rng.choice(L, 900, replace=False)).astype(np.uint32) for _ in range(60)]
    frames = [noisy(rng, p, 0.1) for _ in range(4) for p in places for _ in range(3)]
    lap = len(frames) // 4
    runs = {}
    for store in ("every_frame", "new_places"):
        h = NeocortexHtm(HtmConfig(seqmem={"store": store}))
        ids = [h.step(f).lvc_id for f in frames]
        runs[store] = (h, ids)
    full, ids_full = runs["every_frame"]
    kept, ids_kept = runs["new_places"]
    assert full.seqmem.size == len(frames) and full.tm_index.size == len(frames) and full.frames_not_stored == 0
    assert kept.seqmem.size == kept.tm_index.size == len(frames) - kept.frames_not_stored
    assert kept.seqmem.size < lap + 0.15 * 3 * lap          # laps 2-4 add under 15 % of a lap each
    assert ids_kept[:lap] == ids_full[:lap]                 # the first lap stores every frame either way
    same = np.mean(np.array(ids_kept[lap:]) == np.array(ids_full[lap:]))
    assert same >= 0.95, same
    assert len(set(ids_kept[lap:]) - set(ids_kept[:lap])) <= 0.05 * len(set(ids_kept[:lap]))   # revisits, not new ids
    # every_frame up to a limit: every frame until the memory holds it, then the new_places rule
    limit = lap + lap // 2
    capped = NeocortexHtm(HtmConfig(seqmem={"every_frame_limit": limit}))
    ids_capped = [capped.step(f).lvc_id for f in frames]
    assert ids_capped[:limit] == ids_full[:limit]            # below the limit: every_frame exactly
    assert limit <= capped.seqmem.size == capped.tm_index.size < limit + 0.15 * (len(frames) - limit)
    assert capped.frames_not_stored == len(frames) - capped.seqmem.size
    roomy = NeocortexHtm(HtmConfig(seqmem={"every_frame_limit": len(frames)}))
    assert [roomy.step(f).lvc_id for f in frames] == ids_full and roomy.frames_not_stored == 0


def test_new_places_state_round_trips(tmp_path):
    rng = np.random.default_rng(8)
    places = route(n_places=60, seed=3)
    frames = [noisy(rng, p) for _ in range(2) for p in places for _ in range(2)]
    cfg = HtmConfig(seqmem={"store": "new_places"})
    a = NeocortexHtm(cfg)
    for f in frames[:180]:
        a.step(f)
    a.save(tmp_path / "htm.npz")
    b = NeocortexHtm.load(tmp_path / "htm.npz", cfg)
    assert b.frames_not_stored == a.frames_not_stored > 20
    assert [a.step(f) for f in frames[180:]] == [b.step(f) for f in frames[180:]]


def test_node_counts_the_segments_the_tm_budget_evicted():
    """htm.tm.max_synapses reaches the TM of the default chain; the node counts its evictions."""
    rng = np.random.default_rng(9)
    frames = [np.sort(rng.choice(L, 600, replace=False)).astype(np.uint32) for _ in range(120)]   # all new places
    node = build_node("htm", PoseidonConfig(htm=HtmConfig(tm={"max_synapses": 3000})))
    run_offline(node, _messages(frames))
    tm = node.htm.tm
    assert tm.max_synapses == 3000 and tm.num_synapses <= 3000
    assert node.counters["tm_segments_evicted"] == tm.evicted > 0
    free = build_node("htm", PoseidonConfig())
    run_offline(free, _messages(frames))
    assert free.htm.tm.num_synapses > 3000 and "tm_segments_evicted" not in free.counters
