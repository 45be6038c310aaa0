"""Shared fixtures of the missions tests."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from missions.sim.mission import SimParams, generate

SEED = 3
# 0.5 min at 4.5 m/s: the approach and more than one loop of area 1, so places are revisited
FAST: dict[str, Any] = dict(minutes=0.5, seed=SEED, speed_m_s=4.5)


@pytest.fixture(scope="session")
def fast_mission(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """(path, summary) of a short simulated mission whose loop closes; its parameters are
    ``summary["seed"]``, ``summary["minutes"]`` and :data:`FAST`."""
    path = tmp_path_factory.mktemp("sim") / "fast.mcap"
    summary = generate(path, SimParams(**FAST), progress=False)
    return path, summary
