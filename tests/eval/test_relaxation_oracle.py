"""eval/relaxation_oracle.py: the offline re-solve of a map given perfect loops, on hand-made
missions whose dead reckoning has a known error."""
from __future__ import annotations

import numpy as np
import pytest

from eval.relaxation_oracle import Mission2D, analyse, ate_xy, main, oracle_loops, similarity_ate_xy, solve_positions


def rectangle_twice() -> np.ndarray:
    """A 20 x 10 m rectangle flown once one way and once back, a node every 0.15 m."""
    corners = np.array([[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]], float)
    route = np.vstack([corners, corners[::-1][1:]])
    pts = [route[0]]
    for a, b in zip(route[:-1], route[1:]):
        steps = int(round(np.linalg.norm(b - a) / 0.15))
        pts += [a + (b - a) * (k / steps) for k in range(1, steps + 1)]
    return np.array(pts)


def test_a_scale_error_is_left_by_perfect_loops_and_taken_out_by_a_similarity_alignment() -> None:
    """A dead reckoning 2 % long everywhere: every loop at the same place agrees with it to 2 %
    of a few centimetres, so even dense perfect loops leave its error; a scale of 1/1.02 removes it."""
    truth = rectangle_twice()
    odom = truth * 1.02
    r = analyse(Mission2D(odom, truth), recorded=[], spacing=5, radius_m=0.5, min_age=100)
    ate = r["ate_xy_m"]
    assert r["loops"]["oracle"] > 20 and ate["dead_reckoning"] > 0.1
    assert ate["relaxation_oracle_loops"] > 0.9 * ate["dead_reckoning"]
    assert ate["dead_reckoning_similarity"] < 1e-6 and abs(r["scale"] - 1 / 1.02) < 1e-4


def test_an_offset_after_a_jump_is_removed_by_the_loops() -> None:
    """A dead reckoning that jumps 0.6 m sideways halfway (on the way back) and is exact before
    and after: loops on the way back pull it onto the first pass, the recorded-loop solve with
    the same loops equals the oracle's, and no scale explains it."""
    truth = rectangle_twice()
    odom = truth.copy()
    half = len(truth) // 2
    odom[half:] += np.array([0.0, 0.6])
    loops = oracle_loops(truth, spacing=5, radius_m=0.5, min_age=100)
    r = analyse(Mission2D(odom, truth), recorded=loops, spacing=5, radius_m=0.5, min_age=100)
    ate = r["ate_xy_m"]
    assert ate["dead_reckoning"] > 0.2
    assert ate["relaxation_oracle_loops"] < 0.35 * ate["dead_reckoning"]
    assert ate["relaxation_recorded_loops"] == pytest.approx(ate["relaxation_oracle_loops"])
    assert r["recorded_loop_error_m"] < 1e-9 and ate["dead_reckoning_similarity"] > 0.2


def test_without_loops_the_solve_is_the_dead_reckoning_and_the_inputs_are_checked(tmp_path) -> None:
    truth = rectangle_twice()
    np.testing.assert_allclose(solve_positions(truth * 1.01, []), truth * 1.01, atol=1e-6)
    assert ate_xy(truth, truth) < 1e-9 and similarity_ate_xy(truth, truth)[1] < 1e-9
    pts = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [5.2, 0.0], [0.3, 0.0]])
    assert [(a, b) for a, b, _ in oracle_loops(pts, spacing=1, radius_m=0.5, min_age=2)] == [(1, 3), (0, 4)]
    with pytest.raises(ValueError, match="at least 2 nodes"):
        solve_positions(pts[:1], [])
    assert main([str(tmp_path / "missing.mcap")]) == 2
