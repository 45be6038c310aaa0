"""Dead-reckoning gate (services/htm/geometry.py, Eq. G.1): a stretch that repeats an earlier
stretch's appearance *in order* is claimed as a revisit by appearance alone; with the frames'
dead-reckoned positions it is claimed only where the vehicle could be back."""
from __future__ import annotations

import numpy as np
import pytest

from services.htm.config import HtmConfig
from services.htm.geometry import DeadReckoningGate
from services.htm.pipeline import NeocortexHtm
from tests.htm.sdr_places import L
from tests.htm.sdr_places import other_appearance as _other_appearance
from tests.htm.sdr_places import place as _place

K = 8


def test_plausible_frames_follow_eq_g1():
    g = DeadReckoningGate(min_radius_m=2.0, drift=0.01, jump_m=5.0, min_path_m=10.0)
    for x in range(0, 101):              # a straight 100 m line, one frame per metre
        g.locate([float(x), 0.0, 0.0])
        g.add()
    g.locate([100.0, 0.0, 0.0])          # the vehicle stays at the end of the line
    ok = g.passes(np.arange(101))
    assert ok is not None
    # within 2 m + 1 % of the path back, and at least 10 m of path back: none on a straight line
    assert not ok.any()
    g2 = DeadReckoningGate(2.0, 0.01, 5.0, 10.0)
    for x in list(range(0, 51)) + list(range(50, -1, -1)):     # out 50 m and back along the same line
        g2.locate([float(x), 0.0, 0.0])
        g2.add()
    g2.locate([0.0, 0.5, 0.0])           # back at the start, 100 m of path later
    ok = g2.passes(np.arange(g2.size))
    assert ok is not None
    # frame 0 (0.5 m away, path 100 m back) passes; frames 3 m away pass only with 1 m of drift
    assert ok[0] and ok[2] and not ok[4]
    assert not ok[-5:].any()             # the last metres: close, but no revisit (path < 10 m)
    assert g2.any_plausible(np.array([g2.size - 1]), revisit=False)   # the distance alone passes


def test_unknown_positions_and_discontinuities_are_not_checked():
    g = DeadReckoningGate(1.0, 0.0, jump_m=3.0)
    g.locate(None)
    g.add()                              # stored without a position
    assert g.passes(np.arange(1)) is None        # unknown current position: nothing is checked
    g.locate([0.0, 0.0, 0.0])
    g.add()
    g.locate([0.5, 0.0, 0.0])
    g.add()
    g.locate([50.0, 0.0, 0.0])           # a 49.5 m step: a restarted odometry
    ok = g.passes(np.arange(3))
    assert ok is not None and ok.all()   # earlier positions are in another frame: all pass
    assert g.discontinuities == 1
    with pytest.raises(ValueError, match="finite"):
        g.locate([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="min_radius_m"):
        DeadReckoningGate(-1.0, 0.0)


def _aliased_mission(seed: int = 5):
    """40 places flown, then 20 frames that repeat places 10..29 in order with another appearance."""
    rng = np.random.default_rng(seed)
    route = [_place(rng) for _ in range(40)]
    repeat = [_other_appearance(route[p], 0.35, rng) for p in range(10, 30)]
    return route, repeat


def _claims(positions_route, positions_repeat, gate: bool) -> list:
    route, repeat = _aliased_mission()
    cfg = HtmConfig(input_size=L, seqmem={"length": K, "exclude": 5}, lvc={"successor_threshold": 0.0}, dr_gate={"enabled": gate, "min_m": 2.0, "drift": 0.01, "min_path_m": 10.0, "jump_m": 1000.0})   # the test jumps to the repeat: no discontinuity
    h = NeocortexHtm(cfg)
    for d, p in zip(route, positions_route):
        h.step(d.astype(np.uint32), position=p)
    return [h.step(d.astype(np.uint32), position=p) for d, p in zip(repeat, positions_repeat)]


def test_an_ordered_look_alike_far_away_is_no_revisit_and_a_true_one_is():
    along = [[2.0 * k, 0.0, -5.0] for k in range(40)]            # 2 m per frame along x
    elsewhere = [[2.0 * k, 30.0, -5.0] for k in range(10, 30)]    # a parallel tunnel 30 m away
    back = [[2.0 * k, 0.3, -5.0] for k in range(10, 30)]          # the same stretch again
    # appearance alone: the look-alike stretch in the other tunnel is claimed as places 18..29
    blind = _claims(along, elsewhere, gate=False)
    assert [r.lvc_id for r in blind[K:] if r.by_sequence] == list(range(10 + K, 30))
    gated = _claims(along, elsewhere, gate=True)
    assert not any(r.by_sequence for r in gated)
    assert all(r.is_new for r in gated)
    true_revisit = _claims(along, back, gate=True)
    assert [r.lvc_id for r in true_revisit[K:]] == list(range(10 + K, 30))
    assert all(r.by_sequence for r in true_revisit[K:])


def test_a_map_loaded_from_an_earlier_run_forgets_its_positions(tmp_path):
    route, repeat = _aliased_mission()
    cfg = HtmConfig(input_size=L, seqmem={"length": K, "exclude": 5}, lvc={"successor_threshold": 0.0}, dr_gate={"enabled": True, "min_m": 2.0, "drift": 0.01})
    h = NeocortexHtm(cfg)
    for k, d in enumerate(route):
        h.step(d.astype(np.uint32), position=[2.0 * k, 0.0, 0.0])
    h.save(tmp_path / "map.npz")
    again = NeocortexHtm.load(tmp_path / "map.npz", cfg)
    # the new run's odometry starts elsewhere: the stored frames are not compared with it
    out = [again.step(d.astype(np.uint32), position=[500.0 + k, 0.0, 0.0]) for k, d in enumerate(repeat)]
    assert [r.lvc_id for r in out[K:]] == list(range(10 + K, 30))


def test_without_the_sequence_memory_the_gate_is_off():
    from services.htm.node import HtmNode
    cfg = HtmConfig(dr_gate={"enabled": True}, seqmem={"length": 0})
    assert NeocortexHtm(cfg).dr_gate is None
    assert HtmNode.io_keys(cfg)[0] == ("neocortex/sdr",)
    assert HtmNode.io_keys(HtmConfig())[0] == ("Odometry", "neocortex/sdr")


def _node_stream(repeat_y: float) -> list:
    """Odometry + SDR messages: 40 places 2 m apart along x, then places 10..29 again in order
    (another appearance) flown at lateral offset ``repeat_y``; Odometry just before each frame."""
    from common.messages import Header, NeocortexSdr, Odometry, Sdr
    route, repeat = _aliased_mission()
    xs = [2.0 * k for k in range(40)] + [2.0 * k for k in range(10, 30)]
    ys = [0.0] * 40 + [repeat_y] * 20
    out = []
    for i, (d, x, y) in enumerate(zip(route + repeat, xs, ys)):
        t = 1_000_000_000 + i * 200_000_000
        out.append(("Odometry", Odometry(header=Header(seq=i, stamp=t - 50_000_000, frame_id="odom"),
                                          position=[x, y, -5.0], orientation=[0.0, 0.0, 0.0, 1.0])))
        h = Header(seq=i, stamp=t, frame_id="base_link")
        sdr = Sdr(header=h, modality="fused", size=L, active=d.astype(np.uint32))
        out.append(("neocortex/sdr", NeocortexSdr(header=h, modalities=[], fused=sdr, fusion_mode="union")))
    return out


def test_the_node_gates_with_the_latest_odometry():
    from common.node import run_offline
    from system.config import PoseidonConfig
    from system.services import build_node
    cfg = PoseidonConfig().model_copy(update={"htm": HtmConfig(input_size=L, seqmem={"length": K, "exclude": 5}, lvc={"successor_threshold": 0.0}, tm={"decide": False}, dr_gate={"jump_m": 1000.0})})
    results = {}
    for y in (0.3, 40.0):
        node = build_node("htm", cfg)
        assert node.inputs == ("Odometry", "neocortex/sdr")
        out = run_offline(node, _node_stream(y))
        ids = [m.most_active_cell for _, m in out]
        results[y] = (ids[40 + K:], node.counters)
    back, counters = results[0.3]
    assert back == list(range(10 + K, 30)) and "dr_gate_rejections" not in counters
    far, counters = results[40.0]
    assert not set(far) & set(range(40)) and counters["dr_gate_rejections"] > 0
