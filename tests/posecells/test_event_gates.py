"""VPR Guard (Eqs. 4.11-4.14, worked example of Section 4.2.3) and the motion gate."""
import pytest

from services.posecells.config import VprGuardConfig
from services.posecells.gates import EventGate, MotionGate, VprGuard


def worked_example_history() -> list[int]:
    """26 emitted ids ending in [12, 12, 7, 12, 5, 9, 12]: 12 four times in the window."""
    older = list(range(20, 39))  # 19 ids, none of 12, 7, 4, 9, 6
    return older + [12, 12, 7, 12, 5, 9, 12]


def test_worked_example_accepts_then_leaks_after_20_rejections_and_resets() -> None:
    guard = VprGuard(window=26, min_rep=3, leak=20)
    history = worked_example_history()
    assert len(history) == 26
    decisions = [guard.step(i) for i in history]
    t = decisions[-1]
    assert t.accepted and t.gate == "vpr" and t.vpr_count == 4  # C_t(12) = 4 >= 3
    # the stream becomes unstable: [7, 4, 9, 6] and then fresh ids
    nxt = [7, 4, 9, 6] + list(range(200, 216))
    assert len(nxt) == 20
    after = [guard.step(i) for i in nxt]
    assert [d.vpr_count for d in after[:4]] == [2, 1, 2, 1]  # 7 and 9 seen once before in the window
    assert all(not d.accepted and d.gate == "vpr" for d in after[:19])
    assert guard.rejection_run == 0  # reset by the forced acceptance
    assert after[19].accepted and after[19].gate == "leak" and after[19].vpr_count == 1  # t + 20
    # counter reset: the next 19 rejections are rejections again, the 20th leaks again
    again = [guard.step(i) for i in range(300, 320)]
    assert [d.accepted for d in again] == [False] * 19 + [True]
    assert again[-1].gate == "leak"


def test_repetition_resets_the_rejection_run() -> None:
    guard = VprGuard(window=26, min_rep=3, leak=20)
    for i in range(15):
        assert not guard.step(100 + i).accepted
    assert guard.rejection_run == 15
    guard.step(5), guard.step(5)
    d = guard.step(5)
    assert d.accepted and d.gate == "vpr" and guard.rejection_run == 0


def test_window_forgets_ids_older_than_w() -> None:
    guard = VprGuard(window=4, min_rep=2, leak=0)
    assert not guard.step(1).accepted
    for i in (2, 3, 4):
        guard.step(i)
    assert guard.step(1).vpr_count == 1  # the first 1 left the 4-id window
    assert guard.step(1).accepted


def test_leak_zero_disables_forced_acceptance() -> None:
    guard = VprGuard(window=26, min_rep=3, leak=0)
    assert not any(guard.step(i).accepted for i in range(100))


def test_off_passes_every_id() -> None:
    guard = VprGuard.from_config(VprGuardConfig(require_vpr_for_event=False))
    ids = [12, 12, 7, 12, 5, 9, 12] + list(range(100))
    decisions = [guard.step(i) for i in ids]
    assert all(d.accepted and d.gate == "off" for d in decisions)
    assert decisions[6].vpr_count == 4  # C_t still reported


def test_bad_guard_parameters_are_refused() -> None:
    with pytest.raises(ValueError):
        VprGuard(window=0)


def test_motion_gate_thresholds_in_xy_and_z() -> None:
    gate = MotionGate(min_xy=0.12, min_dz=0.05)
    assert gate.passes([5.0, 5.0, -2.0])  # the first event always passes
    gate.mark([5.0, 5.0, -2.0])
    assert not gate.passes([5.08, 5.08, -2.04])  # 0.113 m horizontal, 0.04 m vertical
    assert gate.passes([5.09, 5.08, -2.0])  # 0.120 m horizontal
    assert gate.passes([5.0, 5.0, -2.051])  # 0.051 m vertical
    assert gate.passes([5.0, 5.0, -1.949])
    gate.mark([5.09, 5.08, -2.0])
    assert not gate.passes([5.09, 5.08, -2.0])
    assert MotionGate(enabled=False).passes([0, 0, 0])


def test_motion_gate_first_then_vpr_guard_and_the_leak_counts_candidates_only() -> None:
    gate = EventGate(VprGuardConfig(vpr_window=26, vpr_min_rep=3, vpr_leak_rate=3))
    p0 = [0.0, 0.0, -1.0]
    # before the first event the motion gate has no reference: every frame is a candidate
    assert [(d.accepted, d.gate, d.vpr_count) for d in (gate.decide(1, p0) for _ in range(3))] == \
        [(False, "vpr", 1), (False, "vpr", 2), (True, "vpr", 3)]
    # standing still after the event: not candidates (C keeps counting, q untouched)
    d = gate.decide(1, p0)
    assert (d.accepted, d.gate, d.vpr_count) == (False, "motion", 4)
    assert gate.decide(1, [0.05, 0.0, -1.0]).gate == "motion"  # 5 cm < 12 cm
    # fresh ids while moving: two rejections, then the leak (L_max = 3)
    out = [gate.decide(50 + k, [0.2 * (k + 1), 0.0, -1.0]) for k in range(3)]
    assert [(o.accepted, o.gate) for o in out] == [(False, "vpr"), (False, "vpr"), (True, "leak")]
    assert gate.vpr.rejection_run == 0
    # near the last event (0.6 m): not candidates, q stays 0 however long it lasts
    assert [gate.decide(60 + k, [0.6 + 0.01 * k, 0.0, -1.0]).gate for k in range(10)] == ["motion"] * 10
    assert gate.vpr.rejection_run == 0
    out = [gate.decide(80 + k, [0.8 + 0.1 * k, 0.0, -1.0]) for k in range(3)]
    assert [(o.accepted, o.gate) for o in out] == [(False, "vpr"), (False, "vpr"), (True, "leak")]
