"""The experience map's public state (services/expmap/state.py): ExperienceMap.state() and
load_state() continue a map exactly, in memory as through a file."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from services.expmap.graph import ExperienceMap
from services.expmap.state import NODE_COLUMNS, ExperienceMapState
from services.expmap.storage import load_map, save_map
from tests.expmap.test_sessions import FRAME_B, OFF_TRUE, cfg, lap, session_a


def _two_sessions() -> ExperienceMap:
    em = session_a(cfg())
    em.begin_session()
    lap(em, 100, range(40), FRAME_B, OFF_TRUE)
    return em


def _assert_same(a: ExperienceMapState, b: ExperienceMapState) -> None:
    assert a.columns.keys() == b.columns.keys() == NODE_COLUMNS.keys()
    for k in a.columns:
        np.testing.assert_array_equal(a.columns[k], b.columns[k], err_msg=k)
    assert a.loops == b.loops and len(a.sweeps) == len(b.sweeps) == a.n_nodes
    for x, y in zip(a.loop_deltas, b.loop_deltas):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(a.sweeps, b.sweeps):
        assert (x is None and y is None) or (x is not None and y is not None and np.array_equal(x, y))
    skip = {"columns", "loop_deltas", "sweeps", "last_odom", "session_links", "lattice_spacing"}
    for name in ExperienceMapState.__dataclass_fields__:
        if name not in skip:
            assert getattr(a, name) == getattr(b, name), name
    np.testing.assert_array_equal(a.last_odom, b.last_odom)
    assert [lk.m for lk in a.session_links] == [lk.m for lk in b.session_links]


def test_a_map_continued_from_its_state_matches_the_uninterrupted_one(tmp_path: Path) -> None:
    whole = _two_sessions()
    cut = session_a(cfg())
    state = cut.state()
    back = ExperienceMap(cfg())
    back.load_state(state)
    _assert_same(back.state(), state)
    save_map(state, tmp_path / "m.npz")                 # and through the file
    _assert_same(load_map(tmp_path / "m.npz", back.lattice_shape, back.lattice_spacing), state)
    back.begin_session()
    lap(back, 100, range(40), FRAME_B, OFF_TRUE)
    np.testing.assert_array_equal(back.positions, whole.positions)
    assert back.loops == whole.loops and len(back.session_links) == len(whole.session_links) == 1


def test_the_state_is_a_copy() -> None:
    em = session_a(cfg())
    state = em.state()
    state.columns["pos"][:] = 99.0
    state.loops.clear()
    assert not np.any(em.positions == 99.0) and em.loops == session_a(cfg()).loops


def test_a_state_that_does_not_fit_is_refused() -> None:
    em = session_a(cfg())
    state = em.state()
    with pytest.raises(ValueError, match="lattice"):
        ExperienceMap(cfg(), lattice_shape=(11, 11, 11, 8)).load_state(state)
    with pytest.raises(ValueError, match="node columns"):
        ExperienceMap(cfg()).load_state(replace(state, columns={k: v for k, v in state.columns.items() if k != "odom"}))
    with pytest.raises(ValueError, match="sonar sweeps"):
        ExperienceMap(cfg()).load_state(replace(state, sweeps=state.sweeps[:-1]))
    with pytest.raises(ValueError, match="empty map"):
        em.load_state(state)
