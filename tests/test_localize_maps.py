"""Raster lookups of the filter and the weight arithmetic."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from localize_fixtures import f1_bundle, truth_bundles  # noqa: F401  (fixtures)

from localize.bundle import Grid, load_bundle
from localize.maps import FilterMap
from localize.weights import (
    dtw_distance,
    mass_centered_coefficient,
    newest_delta,
    term_mass_centered,
    window_mean,
)
from mapping.bundle_writer import BundleContent, Layer, write_bundle

LAYERS = ["strength", "azimuth", "polar", "heading_offset"]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lookup_matches_bundle_sample(f1_bundle, dtype):  # noqa: F811
    fm = FilterMap(f1_bundle, LAYERS, ["strength"], dtype=dtype)
    rng = np.random.default_rng(0)
    x = rng.uniform(-3, 43, 20000)
    y = rng.uniform(-3, 28, 20000)
    tol = 1e-3 if dtype == np.float32 else 1e-9
    for k in LAYERS:
        a = f1_bundle.sample(k, x, y)
        b = fm.sample(k, x, y)
        assert np.array_equal(np.isnan(a), np.isnan(b)), k
        d = a - b
        if f1_bundle.manifest["layers"][k]["kind"] == "angle":
            d = (d + 180) % 360 - 180
        assert np.nanmax(np.abs(d)) < tol, k
    assert np.array_equal(f1_bundle.reachable(x, y), fm.reachable(x, y))
    s1 = f1_bundle.sample("strength", x, y, std=True)
    s2 = fm.sample("strength_std", x, y)
    assert np.allclose(s1, s2, equal_nan=True, atol=tol)
    vs, vc = fm.sample_many(["heading_offset"], x, y, vectors=("heading_offset",))[
        "heading_offset"]
    ang = np.degrees(np.arctan2(vs, vc))
    d = (ang - f1_bundle.sample("heading_offset", x, y) + 180) % 360 - 180
    assert np.nanmax(np.abs(d)) < tol * 10


def _wall_bundle(tmp_path):
    """10 x 4 m, 0.25 m cells, a 0.5 m wall at x in [5, 5.5) with a door at y in [3, 4)."""
    g = Grid(0.0, 0.0, 0.25, 40, 16)
    mask = np.ones(g.shape, dtype=bool)
    mask[:12, 20:22] = False
    vals = np.where(mask, 40.0, np.nan).astype(np.float32)
    write_bundle(tmp_path / "b", BundleContent("s", "f", "F1", grid=g, mask=mask,
                                               layers={"strength": Layer(vals, vals * 0 + 1,
                                                                         "uT")}))
    return load_bundle(tmp_path / "b")


def test_segments_do_not_cross_walls(tmp_path):
    fm = FilterMap(_wall_bundle(tmp_path), ["strength"])
    x0 = np.array([4.8, 4.8, 4.8, 1.0])
    y0 = np.array([1.0, 3.5, 1.0, 1.0])
    x1 = np.array([5.8, 5.8, 4.9, 1.7])
    y1 = np.array([1.0, 3.5, 1.9, 1.5])
    ok = fm.segment_free(x0, y0, x1, y1)
    assert ok.tolist() == [False, True, True, True]
    # a move that ends beyond the wall after jumping over it is refused even when long
    assert not fm.segment_free(np.array([4.0]), np.array([1.0]), np.array([6.5]),
                               np.array([1.0]))[0]
    assert not fm.reachable(np.array([5.2]), np.array([1.0]))[0]
    assert not fm.reachable(np.array([-50.0, 1e6]), np.array([1.0, 1.0])).any()


def _dtw_naive(a, b):
    m, k = len(a), len(b)
    d = np.full((m + 1, k + 1), np.inf)
    d[0, 0] = 0.0
    for i in range(1, m + 1):
        for j in range(1, k + 1):
            d[i, j] = abs(a[i - 1] - b[j - 1]) + min(d[i - 1, j], d[i, j - 1], d[i - 1, j - 1])
    return d[m, k]


@settings(max_examples=60, deadline=None)
@given(a=arrays(np.float64, st.integers(1, 9), elements=st.floats(-50, 50)),
       refs=st.integers(1, 4).flatmap(lambda p: arrays(
           np.float64, st.tuples(st.just(p), st.integers(1, 9)), elements=st.floats(-50, 50))))
def test_dtw_matches_the_textbook_recursion(a, refs):
    got = dtw_distance(a, refs)
    want = [_dtw_naive(a, r) for r in refs]
    assert np.allclose(got, want)


def test_mass_centered_coefficient_rules():
    err = np.array([[0.0, 0.05, 0.1, 1.0, np.nan]])
    c = mass_centered_coefficient(err, 70.0, 0.05)
    assert c[0, :4].tolist() == pytest.approx([1400.0, 1400.0, 700.0, 70.0])
    assert c[0, 4] == pytest.approx(70.0)  # unknown = as bad as the worst known
    assert np.all(mass_centered_coefficient(np.full((1, 3), np.nan), 70.0, 0.05) == 1.0)
    thr = np.array([[0.05, 0.5]])
    assert mass_centered_coefficient(np.array([[0.1, 0.1]]), 1.0, thr).tolist() == [[10.0, 2.0]]


def test_deltas_terms_and_windows():
    v = np.array([[350.0], [10.0]])
    assert newest_delta(v, 1, 1, angle=True)[0] == pytest.approx(20.0)
    assert newest_delta(np.array([[10.0], [350.0]]), 1, 1, angle=True)[0] == pytest.approx(-20)
    assert newest_delta(np.array([[1.0], [2.0], [4.0], [8.0]]), 2, 2, False)[0] == \
        pytest.approx((4 + 8) / 2 - (1 + 2) / 2)
    t = term_mass_centered(np.array([[1.0, -3.0, np.nan]]), np.array([2.0]))
    assert np.allclose(t, [[1.0, 1.0, np.nan]], equal_nan=True)
    w = np.array([[[1.0, np.nan]], [[3.0, np.nan]]])
    assert np.allclose(window_mean(w), [[2.0, np.nan]], equal_nan=True)
