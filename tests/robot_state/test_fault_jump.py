"""robot_state's fault injection: from ``debug.fault_jump_at_s`` after the first output on,
every published position carries ``debug.fault_jump_m`` (a kidnapped vehicle); off by default."""
from __future__ import annotations

import math

import numpy as np
from synth import mission, odometry_positions

from common.node import run_offline
from system.config import load_config
from system.services import build_node

# the filter on a 10 Hz grid of outputs (these tests count and time its outputs on it)
NED = ["robot_state.axis_remap=xyz", "robot_state.axis_sign_z=1", "robot_state.publish_rate_hz=10"]


def _run(extra: list[str]):
    msgs = mission(20, lambda t: (0.5, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0), lambda t: (0.0, 0.0, 0.0),
                   lambda t: 5.0)
    node = build_node("robot_state", load_config(overrides=NED + extra))
    out = run_offline(node, msgs)
    return out, node


def test_the_published_position_jumps_at_the_set_time_and_only_then() -> None:
    base, _ = _run([])
    out, node = _run(["debug.fault_jump_at_s=10", "debug.fault_jump_m=[20.0,-5.0,0.0]"])
    t, p = odometry_positions(out)
    t0, p0 = odometry_positions(base)
    assert np.array_equal(t, t0)
    before, after = t < 10.0 - 1e-9, t >= 10.0 - 1e-9
    assert np.array_equal(p[before], p0[before])
    np.testing.assert_allclose(p[after] - p0[after], np.tile([20.0, -5.0, 0.0], (int(after.sum()), 1)), atol=1e-12)
    flagged = [("fault_jump" in m.status) for k, m in out if k == "Odometry"]
    assert flagged == list(after) and node.counters["fault_jump"] == 1
    assert not any("fault_jump" in m.status for k, m in base if k == "Odometry")
    assert math.isclose(t[after][0], 10.0)
