"""Shared fixtures. Tests that need ``../shared`` skip cleanly when it is absent."""

from __future__ import annotations

from pathlib import Path

import pytest

from factories import small_trace

REPO = Path(__file__).resolve().parents[1]
SHARED_ILC = REPO.parent / "shared" / "ilc"


@pytest.fixture
def ilc_floor():
    """``../shared/ilc/site1/F1`` or skip."""
    floor = SHARED_ILC / "site1" / "F1"
    if not (floor / "path_data_files").is_dir():
        pytest.skip("../shared/ilc is not available")
    return floor


@pytest.fixture
def trace_factory():
    return small_trace
