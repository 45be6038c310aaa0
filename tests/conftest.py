"""Shared test fixtures.  Real data lives in ../shared/data beside the checkout."""
import os
from pathlib import Path

import pytest

from common.bus import Bus, open_local_session

os.environ.setdefault("NUMBA_CACHE_DIR", "/tmp/poseidon-numba-cache")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, or skip with the reason when the folder is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder {SHARED_DATA} is absent (see shared/data/README.md)")
    return SHARED_DATA


@pytest.fixture
def bus():
    """A bus on a fresh in-process Zenoh session (no router), closed after the test."""
    session = open_local_session()
    b = Bus(session=session)
    yield b
    b.close()
    session.close()
