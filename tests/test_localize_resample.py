"""Systematic resampling: properties for any valid weights, clear errors for invalid ones."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from localize.errors import LocalizationError
from localize.resample import (
    check_weights,
    effective_sample_size,
    systematic_resample,
    systematic_resample_rows,
)

finite_nonneg = st.floats(min_value=0.0, max_value=1e12, allow_nan=False, allow_infinity=False)
weights_1d = arrays(np.float64, st.integers(1, 60), elements=finite_nonneg).filter(
    lambda w: w.sum() > 0 and np.isfinite(w.sum()))


def _check_counts(w: np.ndarray, idx: np.ndarray, n: int) -> None:
    assert idx.shape == (n,)
    assert np.all(np.diff(idx) >= 0), "indexes come sorted"
    assert np.all(w[idx] > 0), "a zero-weight particle was drawn"
    counts = np.bincount(idx, minlength=len(w))
    expected = n * w / w.sum()
    # systematic resampling: floor or ceil of the expected count (one draw of slack for
    # floating-point rounding at the boundaries)
    assert np.all(counts >= np.floor(expected) - 1)
    assert np.all(counts <= np.ceil(expected) + 1)


@settings(max_examples=300, deadline=None)
@given(w=weights_1d, seed=st.integers(0, 2**32 - 1))
def test_any_nonnegative_weights_with_positive_sum_work(w, seed):
    idx = systematic_resample(w, np.random.default_rng(seed))
    _check_counts(w, idx, len(w))


@settings(max_examples=200, deadline=None)
@given(w=weights_1d, seed=st.integers(0, 2**32 - 1), n=st.integers(1, 200))
def test_other_sample_sizes(w, seed, n):
    idx = systematic_resample(w, np.random.default_rng(seed), n=n)
    _check_counts(w, idx, n)


@settings(max_examples=150, deadline=None)
@given(rows=st.integers(1, 6), n=st.integers(1, 40), seed=st.integers(0, 2**32 - 1),
       data=st.data())
def test_rows_version_matches_single_row(rows, n, seed, data):
    w = data.draw(arrays(np.float64, (rows, n), elements=finite_nonneg))
    w[:, 0] += 1e-3  # a positive sum per row
    many = systematic_resample_rows(w, np.random.default_rng(seed))
    assert many.shape == (rows, n)
    rng = np.random.default_rng(seed)
    offsets = rng.random((rows, 1))
    for r in range(rows):
        _check_counts(w[r], many[r], n)
        # same draws as the searchsorted formulation with the same offset
        cs = np.cumsum(w[r])
        ref = np.searchsorted(cs, (offsets[r, 0] + np.arange(n)) / n * cs[-1], side="right")
        ref = np.minimum(ref, np.flatnonzero(w[r] > 0)[-1])
        assert np.sum(ref != many[r]) <= 2  # only float rounding at exact boundaries


def test_same_generator_state_same_draws():
    w = np.random.default_rng(1).random(100)
    a = systematic_resample(w, np.random.default_rng(5))
    b = systematic_resample(w, np.random.default_rng(5))
    assert np.array_equal(a, b)


def test_scale_does_not_matter():
    w = np.random.default_rng(2).random(50)
    a = systematic_resample(w, np.random.default_rng(3))
    b = systematic_resample(w * 1e-200, np.random.default_rng(3))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("bad", [
    [], [0.0, 0.0], [1.0, -0.1], [np.nan, 1.0], [np.inf, 1.0], [[1.0, 2.0], [0.0, 0.0]],
    [1e308, 1e308],  # overflowing sum
])
@pytest.mark.filterwarnings("ignore:overflow")
def test_wrong_weights_raise(bad):
    with pytest.raises(LocalizationError):
        if np.ndim(bad) == 2:
            systematic_resample_rows(np.array(bad), np.random.default_rng(0))
        else:
            systematic_resample(np.array(bad, dtype=float), np.random.default_rng(0))


@given(w=arrays(np.float64, st.integers(1, 30),
                elements=st.one_of(st.floats(-1e6, 1e6), st.just(0.0), st.just(np.nan),
                                   st.just(np.inf))))
def test_check_weights_accepts_exactly_the_valid(w):
    valid = (np.all(np.isfinite(w)) and np.all(w >= 0) and w.sum() > 0
             and np.isfinite(w.sum()))
    if valid:
        assert np.array_equal(check_weights(w), w)
    else:
        with pytest.raises(LocalizationError):
            check_weights(w)


def test_effective_sample_size():
    assert effective_sample_size(np.ones(10)) == pytest.approx(10.0)
    assert effective_sample_size(np.array([0.0, 5.0, 0.0])) == pytest.approx(1.0)
    assert np.allclose(effective_sample_size(np.array([[1.0, 1.0], [1.0, 0.0]])), [2.0, 1.0])


def test_subnormal_weights_resample_in_proportion():
    """Found by hypothesis: weights of 5e-324 (subnormal) rounded in ``u * total``."""
    w = np.array([5e-324, 5e-324, 0.0, 0.0, 0.0, 0.0])
    for seed in range(20):
        idx = systematic_resample(w, np.random.default_rng(seed))
        _check_counts(w, idx, len(w))
        rows = systematic_resample_rows(w[None, :], np.random.default_rng(seed))
        _check_counts(w, np.sort(rows[0]), len(w))
