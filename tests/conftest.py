"""Shared test fixtures."""

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture
def shared_data() -> Path:
    """The real data samples beside the repository; skips the test when they are absent."""
    data = SHARED / "data"
    if not data.is_dir():
        pytest.skip(f"real data samples not found at {data}")
    return data
