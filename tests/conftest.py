"""Shared test fixtures.  Real data lives in ../shared/data beside the checkout."""
import os
from pathlib import Path

import pytest

from common.bus import Bus, open_local_session

os.environ.setdefault("NUMBA_CACHE_DIR", "/tmp/poseidon-numba-cache")
# runs in the tests remember their inputs' digests here, not in the user's cache (common.mcap_io.DigestCache)
os.environ.setdefault("POSEIDON_DIGEST_CACHE", "/tmp/poseidon-digest-cache-tests")

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


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests marked ``slow`` (multi-process runs of a minute or more) first, each file's tests
    kept together: the two workers (``-n 2 --dist loadfile``, pyproject.toml) take the long files
    early and fill the end with short ones, instead of one worker finishing a long file alone."""
    items.sort(key=lambda item: 0 if item.get_closest_marker("slow") else 1)
