"""Interpolators: the local plane removes the local constant's slope bias; parameters checked."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from localize.bundle import Grid
from mapping.holdout import SLOPE_RIDGE_CANDIDATES, choose_smoothing
from mapping.interpolate import RasterParams, raster

GRID = Grid(0.0, 0.0, 0.25, 120, 40)  # 30 x 10 m
MASK = np.ones(GRID.shape, dtype=bool)


def _survey(rng, n_walks=6, noise_ut=0.0):
    """Walks along y = 2.1..5.9 m over a field of slope 4 uT/m in x and 3 uT/m in y, the
    samples at cell centres (so that the cell means carry no binning error)."""
    x, y, walk = [], [], []
    for k in range(n_walks):
        xs = np.repeat(np.arange(1.125, 29.0, GRID.cell_m), 3)
        x.append(xs)
        y.append(np.full_like(xs, 2.125 + 0.75 * k))
        walk.append(np.full(len(xs), k))
    x, y, walk = np.concatenate(x), np.concatenate(y), np.concatenate(walk)
    v = 40.0 + 4.0 * (x - 15) + 3.0 * (y - 3.5) + noise_ut * rng.standard_normal(len(x))
    return x, y, v, walk


def _truth_on(values):
    xc, yc = GRID.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    ok = np.isfinite(values)
    return values[ok], (40.0 + 4.0 * (xx - 15) + 3.0 * (yy - 3.5))[ok]


def test_local_plane_is_exact_on_a_plane_where_the_local_constant_is_biased():
    x, y, v, walk = _survey(np.random.default_rng(0))
    plane = RasterParams(method="local_linear", bandwidth_m=2.0, prior_walks=0.0,
                         slope_ridge=0.0)
    got, truth = _truth_on(raster(GRID, MASK, x, y, v, walk, plane)[0])
    assert len(got) > 2000  # the band of support plus 3 m either side
    assert np.max(np.abs(got - truth)) < 1e-3  # float32 rasters
    const, truth_c = _truth_on(raster(GRID, MASK, x, y, v, walk,
                                      replace(plane, method="kernel"))[0])
    # beside the surveyed band and at its ends, the local constant flattens the slope
    assert np.max(np.abs(const - truth_c)) > 3.0


def test_a_large_slope_ridge_is_the_local_constant():
    x, y, v, walk = _survey(np.random.default_rng(1), noise_ut=1.0)
    ll = RasterParams(method="local_linear", bandwidth_m=1.0, prior_walks=0.5, slope_ridge=1e9)
    a, sa = raster(GRID, MASK, x, y, v, walk, ll)
    b, sb = raster(GRID, MASK, x, y, v, walk, replace(ll, method="kernel"))
    np.testing.assert_allclose(a, b, atol=1e-3)
    np.testing.assert_array_equal(sa, sb)  # one uncertainty model for both


def test_cross_validation_chooses_a_slope_ridge_for_the_local_plane():
    x, y, v, walk = _survey(np.random.default_rng(2), noise_ut=0.5)
    chosen, scores = choose_smoothing(GRID, MASK, x, y, v, walk, RasterParams(), subsample=2,
                                      candidates=(1.0, 3.0))
    assert chosen.method == "local_linear" and chosen.slope_ridge in SLOPE_RIDGE_CANDIDATES
    assert all(len(k.split("/")) == 3 for k in scores)
    # on a plane with little noise the wide plane wins over the local constant's bias
    _, kscores = choose_smoothing(GRID, MASK, x, y, v, walk,
                                  RasterParams(method="kernel"), subsample=2,
                                  candidates=(1.0, 3.0))
    assert all(len(k.split("/")) == 2 for k in kscores)
    assert min(scores.values()) < 0.8 * min(kscores.values())
    with pytest.raises(ValueError, match="no bandwidth"):
        choose_smoothing(GRID, MASK, x, y, v, walk, RasterParams(method="linear"))


@pytest.mark.parametrize("kwargs, message", [
    ({"method": "spline"}, "unknown interpolator 'spline'"),
    ({"bandwidth_m": -1.0}, "bandwidth_m"),
    ({"slope_ridge": float("nan")}, "slope_ridge"),
    ({"prior_walks": -0.1}, "prior_walks"),
])
def test_bad_raster_parameters_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RasterParams(**kwargs)
