"""Tests of survey.field_features: earth-frame field features and circular statistics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from survey.errors import ProcessingError
from survey.field_features import (
    azimuth_deg,
    circular_mean_deg,
    circular_median_deg,
    circular_resultant_length,
    field_features,
    horizontal_ut,
    polar_deg,
    strength_ut,
    vertical_ut,
    wrap_deg,
)
from survey.rotation import rotate_to_earth


def test_real_data_like_field():
    # ILC traces: horizontal field along map north, vertical about -29 of 42 uT.
    b = np.array([[0.0, np.sqrt(42.0**2 - 29.0**2), -29.0]])
    f = field_features(b)
    assert f.strength_ut[0] == pytest.approx(42.0, abs=1e-12)
    assert f.horizontal_ut[0] == pytest.approx(np.sqrt(42.0**2 - 29.0**2), abs=1e-12)
    assert f.vertical_ut[0] == pytest.approx(-29.0)
    assert f.azimuth_deg[0] == pytest.approx(0.0, abs=1e-12)
    assert f.polar_deg[0] == pytest.approx(np.degrees(np.arccos(-29.0 / 42.0)), abs=1e-9)
    assert 133.0 < f.polar_deg[0] < 134.0


@pytest.mark.parametrize("vec,az", [([1, 0, 0], 90.0), ([0, 1, 0], 0.0), ([0, -1, 0], 180.0),
                                    ([-1, 0, 0], 270.0), ([1, 1, 5], 45.0), ([-1, 1, -5], 315.0),
                                    ([-1e-12, 1, 0], 360.0 - np.degrees(1e-12))])
def test_azimuth_compass_convention(vec, az):
    got = azimuth_deg(np.array([vec], float))[0]
    assert 0.0 <= got < 360.0
    assert got == pytest.approx(az, abs=1e-9)


@pytest.mark.parametrize("vec,polar", [([0, 0, 1], 0.0), ([0, 3, 0], 90.0), ([0, 0, -2], 180.0),
                                       ([1, 0, 1], 45.0), ([0, 1, -1], 135.0)])
def test_polar_angle(vec, polar):
    assert polar_deg(np.array([vec], float))[0] == pytest.approx(polar, abs=1e-9)


def test_zero_field_gives_nan_angles():
    z = np.zeros((1, 3))
    assert np.isnan(azimuth_deg(z)[0]) and np.isnan(polar_deg(z)[0])
    assert strength_ut(z)[0] == 0.0
    # vertical only: polar defined, azimuth not
    v = np.array([[0.0, 0.0, -30.0]])
    assert np.isnan(azimuth_deg(v)[0]) and polar_deg(v)[0] == 180.0


def test_features_from_constructed_angles():
    rng = np.random.default_rng(0)
    n = 1000
    az = rng.uniform(0, 360, n)
    pol = rng.uniform(1, 179, n)
    s = rng.uniform(25, 65, n)
    b = np.column_stack([s * np.sin(np.radians(pol)) * np.sin(np.radians(az)),
                         s * np.sin(np.radians(pol)) * np.cos(np.radians(az)),
                         s * np.cos(np.radians(pol))])
    f = field_features(b)
    np.testing.assert_allclose(f.strength_ut, s, rtol=1e-12)
    np.testing.assert_allclose(wrap_deg(f.azimuth_deg - az), 0.0, atol=1e-9)
    np.testing.assert_allclose(f.polar_deg, pol, atol=1e-9)
    np.testing.assert_allclose(f.horizontal_ut**2 + f.vertical_ut**2, f.strength_ut**2,
                               rtol=1e-12)
    np.testing.assert_allclose(horizontal_ut(b), f.horizontal_ut)
    np.testing.assert_allclose(vertical_ut(b), b[:, 2])


def test_features_do_not_depend_on_phone_attitude():
    # device-frame samples of one earth field in random attitudes -> identical features
    b_earth = np.array([2.0, 30.0, -29.0])
    mats = Rotation.random(300, random_state=1).as_matrix()
    b_dev = np.einsum("nji,j->ni", mats, b_earth)
    q = Rotation.from_matrix(mats).as_quat()
    rv = np.where(q[:, 3:4] < 0, -q, q)[:, :3]
    f = field_features(rotate_to_earth(b_dev, rv))
    ref = field_features(b_earth)
    for name in ("strength_ut", "horizontal_ut", "vertical_ut", "azimuth_deg", "polar_deg"):
        np.testing.assert_allclose(getattr(f, name), getattr(ref, name)[0], atol=1e-9)


def test_bad_shape_raises():
    with pytest.raises(ProcessingError):
        field_features(np.zeros((4, 2)))


def test_wrap_deg():
    a = np.array([0.0, 179.999, 180.0, -180.0, 190.0, 359.0, 720.0, -540.0, np.nan])
    np.testing.assert_allclose(wrap_deg(a)[:-1], [0.0, 179.999, -180.0, -180.0, -170.0, -1.0,
                                                   0.0, -180.0], atol=1e-9)
    assert np.isnan(wrap_deg(a)[-1])
    assert wrap_deg(np.zeros((2, 3))).shape == (2, 3)
    r = wrap_deg(np.random.default_rng(2).uniform(-1e4, 1e4, 10_000))
    assert np.all((r >= -180.0) & (r < 180.0))
    assert wrap_deg(-1e-15) < 180.0


def test_circular_mean():
    assert circular_mean_deg([350.0, 10.0]) == pytest.approx(0.0, abs=1e-9) or \
        circular_mean_deg([350.0, 10.0]) == pytest.approx(360.0, abs=1e-9)
    assert circular_mean_deg([0.0, 90.0]) == pytest.approx(45.0)
    assert circular_mean_deg([0.0, 90.0], weights=[3.0, 1.0]) == pytest.approx(
        np.degrees(np.arctan2(1.0, 3.0)))
    assert circular_mean_deg([10.0, np.nan, 20.0]) == pytest.approx(15.0)
    assert np.isnan(circular_mean_deg([0.0, 180.0]))
    assert np.isnan(circular_mean_deg([np.nan]))
    m = circular_mean_deg(np.array([[350.0, 10.0], [100.0, 120.0]]), axis=1)
    np.testing.assert_allclose(wrap_deg(m - [0.0, 110.0]), 0.0, atol=1e-9)
    with pytest.raises(ProcessingError):
        circular_mean_deg([1.0, 2.0], weights=[1.0, -1.0])


def test_circular_mean_of_noisy_directions():
    rng = np.random.default_rng(3)
    a = (355.0 + rng.vonmises(0.0, 20.0, 20_000) * 180 / np.pi) % 360.0
    assert abs(wrap_deg(circular_mean_deg(a) - 355.0)) < 0.2
    r = circular_resultant_length(a)
    assert 0.9 < r < 1.0
    assert circular_resultant_length(np.arange(0.0, 360.0, 1.0)) < 1e-12


def _brute_force_median(a: np.ndarray) -> float:
    grid = np.arange(0.0, 360.0, 0.01)
    cost = np.abs(wrap_deg(a[None, :] - grid[:, None])).sum(axis=1)
    return float(grid[np.argmin(cost)])


def test_circular_median_matches_definition_and_is_robust():
    rng = np.random.default_rng(4)
    for trial in range(5):
        centre = rng.uniform(0, 360)
        core = centre + rng.normal(0, 8.0, 181)
        outliers = centre + rng.uniform(60, 120, 20)  # all on one side: they drag the mean
        a = np.concatenate([core, outliers]) % 360.0
        med = circular_median_deg(a)
        assert abs(wrap_deg(med - _brute_force_median(a))) <= 0.02
        # the median stays with the core, the mean is pulled towards the outliers
        assert abs(wrap_deg(med - centre)) < abs(wrap_deg(circular_mean_deg(a) - centre))
    assert circular_median_deg([350.0, 355.0, 5.0]) == pytest.approx(355.0)
    assert np.isnan(circular_median_deg([]))
    assert np.isnan(circular_median_deg([np.nan, np.nan]))


def test_unwrap_deg_carries_on_past_a_missing_heading():
    """A heading that is undefined for one sample (phone's y axis vertical) must not turn the
    rest of the walk's compass into NaN, as ``np.unwrap`` alone does."""
    from survey.field_features import unwrap_deg

    got = unwrap_deg([10.0, 20.0, np.nan, 30.0, 40.0, 350.0, 10.0])
    np.testing.assert_allclose(got, [10, 20, np.nan, 30, 40, -10, 10], atol=1e-9)
    assert np.isnan(np.unwrap(np.radians([10.0, np.nan, 30.0]))[2])  # why the helper exists
