"""Shared fixtures. Tests that need ``../shared`` skip cleanly when it is absent.

The simulated sample site the tests read (``data/sample_site``) is generated, not tracked: it is
simulated here, before any test module is collected, when it is missing (~8 s, once)."""

from __future__ import annotations

from pathlib import Path

import pytest
from ilc_sample import SHARED_ILC, SKIP_REASON

from survey.sim.site import ensure_sample_site

REPO = Path(__file__).resolve().parents[1]
ensure_sample_site(REPO / "data" / "sample_site")


@pytest.fixture
def ilc_floor():
    """``site1/F1`` of the ILC traces (``$INDOORMAP_ILC`` or ``../shared/ilc``), or skip."""
    floor = SHARED_ILC / "site1" / "F1"
    if not (floor / "path_data_files").is_dir():
        pytest.skip(SKIP_REASON)
    return floor
