"""The experience map's parts driven on their own: candidates, loop policy, relaxation, storage."""
import math

import numpy as np
import pytest

from services.expmap.candidates import candidate_nodes, choose_match, lattice_geometry, match_scores
from services.expmap.config import ExpMapConfig
from services.expmap.loop_policy import LoopEdges, loop_displacement
from services.expmap.relaxation import plan_correction, relax_fraction, solve_optimum
from services.expmap.storage import ColumnStore


def test_candidates_are_old_enough_and_of_the_same_lvc_when_only_it_can_match() -> None:
    cfg = ExpMapConfig(min_experience_age=5, lv_factor=1.0, pc_factor=0.5, match_threshold=0.9)
    index = {7: [0, 3, 6, 9], 8: [1, 2]}
    assert candidate_nodes(9, cfg, index, 7).tolist() == [0, 3]        # cutoff 4
    assert candidate_nodes(4, cfg, index, 7).tolist() == []            # nothing old enough
    cfg_all = ExpMapConfig(min_experience_age=5, pc_factor=1.0, match_threshold=0.9)
    assert candidate_nodes(9, cfg_all, index, 7).tolist() == [0, 1, 2, 3, 4]


def test_scores_are_lvc_plus_wrap_aware_proximity() -> None:
    cfg = ExpMapConfig(lv_factor=1.0, pc_factor=0.5, pc_proximity_sigma_cells=1.0)
    period, cell = lattice_geometry((15, 15, 15, 8), (0.1, 0.1, 0.1))
    pc = np.array([[0.05, 0.0, 0.0, 0.0], [1.45, 0.0, 0.0, 0.0], [0.75, 0.0, 0.0, 0.0]])
    lvc = np.array([3, 4, 3])
    s = match_scores(np.arange(3), pc, lvc, np.array([0.05, 0.0, 0.0, 0.0]), 3, period, cell, cfg)
    assert s[0] == pytest.approx(1.5)
    assert s[1] == pytest.approx(0.5 * math.exp(-1.0 / 2))      # 1.45 m is one cell away across the wrap
    assert s[2] == pytest.approx(1.0, abs=1e-6)                  # same LVC, 7 cells away


def test_choose_match_continues_the_chain_or_starts_at_the_best() -> None:
    matches, scores = np.array([10, 20, 30]), np.array([1.2, 1.5, 1.5])
    assert choose_match(matches, scores, -1, 0, 3) == (1, 1)          # best score, oldest of the ties
    assert choose_match(matches, scores, 11, 2, 3) == (0, 3)          # within the gap of the last match
    assert choose_match(matches, scores, 15, 2, 3) == (1, 1)          # too far: a new chain


def test_route_length_takes_loop_edges_and_the_bound_is_cached() -> None:
    edges = LoopEdges()
    assert edges.route_length(0, 50, 100) == 50
    edges.add(5, 45, 1.0, 0)
    assert edges.route_length(0, 50, 100) == 11                       # 0-5, loop, 45-50
    assert edges.route_length(0, 50, 100, limit=4) >= 4
    assert edges.route_bound(10, 40, 100, 100.0) == 11                # 10-5, loop, 45-40
    assert edges.route_bound(11, 41, 100, 100.0) == 13                # from the cache: 11 + 1 + 1
    assert edges.deltas[0].tolist() == [0.0, 0.0, 0.0]


def test_loop_displacement_without_sweeps_is_zero_or_the_place_radius() -> None:
    cfg = ExpMapConfig(loops={"scan_matching": False})
    tallies = {"trusted": 0, "partial": 0, "untrusted": 0, "no_sweep": 0}
    d = np.array([3.0, 4.0, 0.0])
    delta, reg = loop_displacement(cfg, d, None, None, 0.0, tallies)
    assert delta is not None and delta.tolist() == [0.0, 0.0, 0.0] and reg is None
    cfg_r = ExpMapConfig(loops={"scan_matching": False, "place_radius_m": 1.0})
    assert loop_displacement(cfg_r, d, None, None, 0.0, tallies)[0] == pytest.approx([0.6, 0.8, 0.0])
    cfg_s = ExpMapConfig(loops={"scan_matching": True})
    loop_displacement(cfg_s, d, None, np.zeros((3, 2)), 0.0, tallies)
    assert tallies["no_sweep"] == 1


def test_optimum_of_a_loop_spreads_the_residual_evenly() -> None:
    # a square driven with odometry that drifts 0.4 m in x; a loop edge says the end is the start
    delta = np.array([[0, 0, 0], [1.1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)
    cum = np.cumsum(delta, axis=0)
    cumres = np.arange(5, dtype=float)
    pos, solved = solve_optimum(cum, cumres, [(0, 4, 1.0, 0)], [np.zeros(3)], np.zeros(3))
    assert solved
    # five equal edges share the 0.1 m misfit: the end moves 4 * 0.1 / 5 towards the start
    assert pos[4] == pytest.approx([0.1 - 0.08, 0.0, 0.0])
    assert pos[0].tolist() == [0.0, 0.0, 0.0]
    chain, solved = solve_optimum(cum[:1], cumres[:1], [], [], np.array([1.0, 2.0, 3.0]))
    assert not solved and chain.tolist() == [[1.0, 2.0, 3.0]]


def test_plan_correction_clamps_uniformly_and_relaxation_is_capped_per_iteration() -> None:
    target, pos = np.array([[0.0, 0, 0], [2.0, 0, 0]]), np.zeros((2, 3))
    disp, clamped, norm, peak = plan_correction(target, pos, 1.0)
    assert clamped and norm == 1.0 and peak == pytest.approx(1.0) and disp[1, 0] == pytest.approx(1.0)
    phi, ran, step_max, capped = relax_fraction(0.0, 1.0, 0.1, 3)
    assert phi == pytest.approx(0.3) and (ran, step_max, capped) == (3, 0.1, True)
    phi, ran, step_max, capped = relax_fraction(0.95, 1.0, 0.1, 3)
    assert (phi, ran, capped) == (1.0, 1, False) and step_max == pytest.approx(0.05)


def test_column_store_grows_and_keeps_the_rows() -> None:
    g = ColumnStore()
    g.add("x", (2,), np.float64)
    g.add("k", (), np.int64)
    for i in range(100):
        g.reserve(g.n + 1)
        g.arrays["x"][i] = (i, -i)
        g.arrays["k"][i] = i
        g.n += 1
    assert g.arrays["x"].shape[0] == 128 and g.arrays["k"][:100].tolist() == list(range(100))
    assert g.arrays["x"][99].tolist() == [99.0, -99.0]
