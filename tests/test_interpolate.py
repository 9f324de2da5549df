"""Interpolators: the local plane removes the local constant's slope bias, the local quadratic
the plane's curvature bias; the batched solver and the cross-validation's shortcuts agree with
plain computations; parameters checked."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from localize.bundle import BilinearLookup, Grid, sample_grid
from mapping.holdout import (
    CURVATURE_RIDGE_CANDIDATES,
    SLOPE_RIDGE_CANDIDATES,
    _centred_squares,
    choose_smoothing,
)
from mapping.interpolate import (
    RasterParams,
    cell_stats,
    kernel_mean,
    kernel_sums,
    raster,
    walk_cell_means,
)
from mapping.local_fit import ridge_intercepts

GRID = Grid(0.0, 0.0, 0.25, 120, 40)  # 30 x 10 m
MASK = np.ones(GRID.shape, dtype=bool)


def _plane(x, y):
    return 40.0 + 4.0 * (x - 15) + 3.0 * (y - 3.5)


def _bowl(x, y):
    """A field with curvature: Laplacian 2 * (0.3 + 0.5) = 1.6 uT/m^2 everywhere."""
    return 40.0 + 0.3 * (x - 15) ** 2 + 0.5 * (y - 3.5) ** 2 - 0.4 * (x - 15) * (y - 3.5)


def _survey(rng, n_walks=6, noise_ut=0.0, field=_plane):
    """Walks along y = 2.1..5.9 m over ``field`` (default: slope 4 uT/m in x and 3 uT/m in y),
    the samples at cell centres (so that the cell means carry no binning error)."""
    x, y, walk = [], [], []
    for k in range(n_walks):
        xs = np.repeat(np.arange(1.125, 29.0, GRID.cell_m), 3)
        x.append(xs)
        y.append(np.full_like(xs, 2.125 + 0.75 * k))
        walk.append(np.full(len(xs), k))
    x, y, walk = np.concatenate(x), np.concatenate(y), np.concatenate(walk)
    v = field(x, y) + noise_ut * rng.standard_normal(len(x))
    return x, y, v, walk


def _truth_on(values, field=_plane):
    xc, yc = GRID.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    ok = np.isfinite(values)
    return values[ok], field(xx, yy)[ok]


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


def test_local_quadratic_is_exact_on_a_quadratic_where_the_plane_is_biased():
    x, y, v, walk = _survey(np.random.default_rng(0), field=_bowl)
    quad = RasterParams(method="local_quadratic", bandwidth_m=1.0, prior_walks=0.0,
                        slope_ridge=0.0, curvature_ridge=0.0)
    values = raster(GRID, MASK, x, y, v, walk, quad)[0]
    # exact wherever three walks lie within the kernel's reach (3 sigma), which a quadratic
    # across them needs; farther out the undetermined curvature is left out
    yc = GRID.cell_centers()[1]
    three_walks = (yc > 0.6) & (yc < 7.4)
    got, truth = _truth_on(np.where(three_walks[:, None], values, np.nan), _bowl)
    assert len(got) > 3000
    assert np.max(np.abs(got - truth)) < 2e-3  # float32 rasters of values up to ~110 uT
    plane, truth_p = _truth_on(raster(GRID, MASK, x, y, v, walk,
                                      replace(quad, method="local_linear"))[0], _bowl)
    # the plane's bias is about bandwidth^2 / 2 x Laplacian = 0.8 uT inside the band
    inside = np.abs(plane - truth_p)[(len(plane) // 3):(2 * len(plane) // 3)]
    assert np.median(np.abs(plane - truth_p)) > 0.5 and inside.max() > 0.5


def test_a_large_curvature_ridge_is_the_local_plane():
    x, y, v, walk = _survey(np.random.default_rng(1), noise_ut=1.0, field=_bowl)
    lq = RasterParams(method="local_quadratic", bandwidth_m=1.0, prior_walks=0.5,
                      slope_ridge=1.0, curvature_ridge=1e9)
    a, sa = raster(GRID, MASK, x, y, v, walk, lq)
    b, sb = raster(GRID, MASK, x, y, v, walk, replace(lq, method="local_linear"))
    np.testing.assert_allclose(a, b, atol=1e-3)
    np.testing.assert_array_equal(sa, sb)


def test_an_infinite_curvature_ridge_is_the_plane_from_the_same_sums():
    x, y, v, walk = _survey(np.random.default_rng(5), noise_ut=1.0, field=_bowl)
    stats = cell_stats(GRID, *walk_cell_means(GRID, x, y, v, walk)[1:])
    quad = kernel_sums(GRID, MASK, stats, 1.5, 3.0, degree=2)
    plane = kernel_sums(GRID, MASK, stats, 1.5, 3.0, degree=1)
    np.testing.assert_allclose(kernel_mean(quad, 0.5, 40.0, 1.0, np.inf),
                               kernel_mean(plane, 0.5, 40.0, 1.0), rtol=1e-6)


def test_ridge_intercepts_solve_the_ridged_normal_equations():
    rng = np.random.default_rng(3)
    design = rng.normal(size=(200, 12, 6))
    gram = design.transpose(0, 2, 1) @ design
    rhs = rng.normal(size=(200, 6))
    ridge = np.array([0.5, 0.1, 0.1, 2.0, 2.0, 2.0])
    want = np.linalg.solve(gram + np.diag(ridge), (rhs + [[3.0, 0, 0, 0, 0, 0]])[..., None])
    np.testing.assert_allclose(ridge_intercepts(gram, rhs, ridge, 3.0), want[:, 0, 0],
                               rtol=1e-9, atol=1e-12)
    # a term no data determines (all zero, no ridge) gets a zero coefficient; the others are
    # fitted as if it were absent, and nothing blows up
    gram[:, 5, :] = gram[:, :, 5] = 0.0
    ridge[5] = 0.0
    sub = np.linalg.solve(gram[:, :5, :5] + np.diag(ridge[:5]), rhs[:, :5, None])
    np.testing.assert_allclose(ridge_intercepts(gram, rhs, ridge), sub[:, 0, 0], rtol=1e-9)
    # no data and no shrinkage: no value
    assert np.isnan(ridge_intercepts(np.zeros((1, 3, 3)), np.zeros((1, 3)), np.zeros(3)))[0]
    with pytest.raises(ValueError, match="shapes"):
        ridge_intercepts(gram, rhs[:, :3], ridge)
    with pytest.raises(ValueError, match="n_terms"):
        ridge_intercepts(gram, rhs, ridge, n_terms=7)


def test_cross_validation_shortcuts_match_the_plain_computation():
    rng = np.random.default_rng(4)
    x, y, v, walk = _survey(rng, noise_ut=1.0, field=_bowl)
    stats = cell_stats(GRID, *walk_cell_means(GRID, x, y, v, walk)[1:])
    # the lookup at fixed points is sample_grid's bilinear lookup (NaN cells, mask, edges)
    mask = MASK.copy()
    mask[:, 60:64] = False
    px = np.r_[x[::7] + 0.1, -1.0, 0.05, 29.99, 15.4]
    py = np.r_[y[::7] - 0.05, 3.0, 0.05, 9.99, 3.0]
    look = BilinearLookup.at(GRID, mask, px, py)
    full = kernel_mean(kernel_sums(GRID, mask, stats, 1.0, 3.0, degree=2), 0.5, 40.0, 1.0, 1.0)
    want = sample_grid(GRID, mask, full, px, py)
    assert np.isfinite(want).sum() > 100 and np.isnan(want).sum() >= 3
    np.testing.assert_allclose(look(full), want, rtol=1e-12)
    # values made only at the cells the lookup reads give the same lookups
    part = kernel_mean(kernel_sums(GRID, mask, stats, 1.0, 3.0, degree=2,
                                   cells=look.cells(GRID)),
                       0.5, 40.0, 1.0, 1.0)
    assert np.isfinite(part).sum() < 0.5 * np.isfinite(full).sum()
    np.testing.assert_array_equal(look(part), look(full))
    # the vectorised shape RMSE equals a per-walk loop, NaNs (unpredicted samples) left out
    res = rng.normal(size=(3, 500)) + rng.integers(0, 3, size=500)
    res[0, ::9] = np.nan
    res[2, :] = np.nan
    wk = rng.integers(0, 7, size=500)
    squares, counts = _centred_squares(res, wk)
    for row in (0, 1):
        centred = [res[row, wk == k] - np.nanmedian(res[row, wk == k]) for k in range(7)]
        r = np.concatenate(centred)
        assert counts[row] == np.isfinite(r).sum()
        assert squares[row] == pytest.approx(np.nansum(r ** 2), rel=1e-12)
    assert counts[2] == 0 and squares[2] == 0


def test_cross_validation_chooses_the_ridges_of_the_local_polynomials():
    x, y, v, walk = _survey(np.random.default_rng(2), noise_ut=0.5)
    chosen, scores = choose_smoothing(GRID, MASK, x, y, v, walk, RasterParams(), subsample=2,
                                      candidates=(1.0, 3.0))
    # the field is a plane: the cross-validation may keep the quadratic or fall back to the
    # plane (an infinite curvature ridge), never to anything else
    assert chosen.method in ("local_quadratic", "local_linear")
    assert chosen.slope_ridge in SLOPE_RIDGE_CANDIDATES
    assert len(scores) == 2 * 4 * 4 * 5 and all(len(k.split("/")) == 4 for k in scores)
    assert sum(k.endswith("/inf") for k in scores) == 2 * 4 * 4
    if chosen.method == "local_quadratic":
        assert chosen.curvature_ridge in CURVATURE_RIDGE_CANDIDATES
    # on a field with curvature, the quadratic wins
    x, y, v, walk = _survey(np.random.default_rng(2), noise_ut=0.5, field=_bowl)
    chosen, _ = choose_smoothing(GRID, MASK, x, y, v, walk, RasterParams(), subsample=2,
                                 candidates=(1.0, 3.0))
    assert chosen.method == "local_quadratic" and np.isfinite(chosen.curvature_ridge)
    chosen, scores = choose_smoothing(GRID, MASK, x, y, v, walk,
                                      RasterParams(method="local_linear"), subsample=2,
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
    ({"curvature_ridge": -1.0}, "curvature_ridge"),
    ({"prior_walks": -0.1}, "prior_walks"),
])
def test_bad_raster_parameters_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RasterParams(**kwargs)
