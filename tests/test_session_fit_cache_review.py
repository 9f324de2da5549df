"""Review of the session-fit cache: what changes a fit but not the cache's key."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

import survey.process_store as ps
from survey.ingest import ingest
from survey.process_store import process_store
from survey.store import SurveyStore
from tests.test_session_fit_cache import _inputs


@pytest.fixture
def mag_reads(monkeypatch):
    """Trace ids of the walks whose magnetometer columns are read (the session fit's)."""
    reads: list[str] = []
    real_part = SurveyStore.part

    def counting(self, name, row, columns=None):
        if name == "sensors" and columns == ps._MAG_COLUMNS:
            reads.append(row.trace_id)
        return real_part(self, name, row, columns)

    monkeypatch.setattr(SurveyStore, "part", counting)
    return reads


def test_a_changed_fit_function_is_fitted_again_not_taken_from_the_cache(tmp_path, monkeypatch, mag_reads):
    """Before the cache every run fitted the sessions, so a change to fit_ellipsoid (or to
    reported_bias, calibration_sessions, session_fits) reached the walks at once (their
    inputs_sha256 holds the fit). With the cache the old fits were used until
    SESSION_FIT_VERSION was bumped by hand; the key now holds the fitting code's sha256."""
    store = tmp_path / "s"
    ingest(_inputs(tmp_path / "in"), store)
    process_store(store)  # the real fit: ill-conditioned on these flat-held walks
    real_fit = ps.fit_ellipsoid

    @functools.wraps(real_fit)  # "a fix" of its body: the same signature and defaults
    def fixed_fit(raw, **kwargs):
        return dataclasses.replace(real_fit(raw, **kwargs), status="ok", reason="",
                                   hard_iron_ut=raw.mean(axis=0), soft_iron=np.eye(3))

    monkeypatch.setattr(ps, "fit_ellipsoid", fixed_fit)
    mag_reads.clear()
    report = process_store(store)
    assert mag_reads and "needs_fit" in report.processed
