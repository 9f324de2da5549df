"""Tests of survey.magcal: ellipsoid / sphere / attitude-aided magnetometer calibration."""

from __future__ import annotations

import numpy as np
import pytest
from ilc_sample import ilc_walks, load_streams
from scipy.spatial.transform import Rotation

from survey.errors import ProcessingError
from survey.magcal import (
    STATUS_ILL,
    STATUS_OK,
    fit_ellipsoid,
    fit_sphere,
    fit_with_rotation,
    sample_coverage,
)

#: Earth field like the ILC mall (north 32, up -29 uT), scaled to 45 uT.
B_EARTH = np.array([0.0, 32.0, -29.0]) * 45.0 / np.hypot(32.0, 29.0)


def soft_iron(rng, amp=0.05):
    """Symmetric soft-iron matrix I + E, entries of E within +-amp."""
    e = rng.uniform(-amp, amp, (3, 3))
    return np.eye(3) + (e + e.T) / 2


def raw_samples(rng, rot, s, h, noise, b_earth=B_EARTH):
    """raw = S @ (R^T b_earth) + h + noise, rot: device -> earth, shape (n, 3, 3)."""
    b_dev = np.einsum("nji,j->ni", rot, b_earth)
    return b_dev @ s.T + h + noise * rng.standard_normal(b_dev.shape)


def flat_rotations(rng, n, max_tilt_deg):
    """Random heading, tilt of the screen normal within max_tilt_deg of up."""
    yaw = Rotation.from_euler("z", rng.uniform(0, 360, (n, 1)), degrees=True)
    tilt_axis_az = rng.uniform(0, 2 * np.pi, n)
    tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform(0, 1, n))
    axis = np.column_stack([np.cos(tilt_axis_az), np.sin(tilt_axis_az), np.zeros(n)])
    return (Rotation.from_rotvec(axis * tilt[:, None]) * yaw).as_matrix()


def rel_frobenius(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("seed", range(8))
def test_ellipsoid_full_coverage(seed):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(600, random_state=rng).as_matrix()
    s = soft_iron(rng)
    h = rng.uniform(-60, 60, 3)
    raw = raw_samples(rng, rot, s, h, noise=0.5)
    res = fit_ellipsoid(raw)
    assert res.status == STATUS_OK and res.ok and res.reason == ""
    assert np.linalg.norm(res.hard_iron_ut - h) < 1.0
    # only S * B is observable: compare with the unit-determinant truth
    s_unit = s / np.cbrt(np.linalg.det(s))
    assert rel_frobenius(res.soft_iron, s_unit) < 0.02
    assert np.linalg.det(res.soft_iron) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(res.soft_iron, res.soft_iron.T, atol=1e-12)
    assert res.field_strength_ut == pytest.approx(45.0 * np.cbrt(np.linalg.det(s)), rel=0.01)
    assert 0.3 < res.residual_rms_ut < 0.8  # the 0.5 uT noise, radial component
    assert res.coverage > 0.7 and res.condition_number < 6
    assert np.all(res.hard_iron_se_ut < 0.2)
    # calibrated samples have a constant strength
    strength = np.linalg.norm(res.apply(raw), axis=1)
    assert np.std(strength) < 0.8
    # with the true strength known, S itself is recovered
    known = fit_ellipsoid(raw, reference_strength_ut=45.0)
    assert rel_frobenius(known.soft_iron, s) < 0.02
    np.testing.assert_allclose(known.hard_iron_ut, res.hard_iron_ut, atol=1e-9)
    known_strength = np.linalg.norm(known.apply(raw), axis=1)
    assert np.mean(known_strength) == pytest.approx(45.0, abs=0.1)
    assert np.std(known_strength) < 0.8


def test_ellipsoid_fit_without_refinement_is_close():
    rng = np.random.default_rng(20)
    rot = Rotation.random(600, random_state=rng).as_matrix()
    s, h = soft_iron(rng), np.array([25.0, -40.0, 12.0])
    res = fit_ellipsoid(raw_samples(rng, rot, s, h, 0.5), refine=False)
    assert res.ok and np.linalg.norm(res.hard_iron_ut - h) < 1.0


@pytest.mark.parametrize("seed", range(5))
def test_flat_held_phone_is_ill_conditioned(seed):
    rng = np.random.default_rng(100 + seed)
    rot = flat_rotations(rng, 3000, max_tilt_deg=7.0)
    h = rng.uniform(-60, 60, 3)
    raw = raw_samples(rng, rot, soft_iron(rng), h, noise=0.5)
    res = fit_ellipsoid(raw)
    assert res.status == STATUS_ILL and not res.ok
    assert "coverage" in res.reason
    assert np.all(np.isnan(res.hard_iron_ut)) and np.all(np.isnan(res.soft_iron))
    assert res.coverage < 0.15
    assert np.all(np.isnan(res.apply(raw)))
    # the baseline sphere fit returns numbers but flags them
    sph = fit_sphere(raw)
    assert sph.status == STATUS_ILL and np.all(np.isfinite(sph.hard_iron_ut))
    # without the checks the ellipsoid fit would return a wildly wrong offset
    forced = fit_ellipsoid(raw, min_coverage=0.0, max_condition=np.inf,
                           max_hard_iron_se_ut=np.inf)
    assert not forced.ok or np.linalg.norm(forced.hard_iron_ut - h) > 5.0


def test_rotation_about_two_axes_only_is_ill_conditioned():
    # yaw circle + roll circle: good covariance spread, but many quadrics fit two circles
    rng = np.random.default_rng(30)
    ang = rng.uniform(0, 360, 1000)
    rot = np.concatenate([Rotation.from_euler("z", ang[:500, None], degrees=True).as_matrix(),
                          Rotation.from_euler("y", ang[500:, None], degrees=True).as_matrix()])
    raw = raw_samples(rng, rot, soft_iron(rng), np.array([10.0, 20.0, -30.0]), 0.5)
    res = fit_ellipsoid(raw)
    assert res.coverage > 0.45  # passes the coverage check ...
    assert res.status == STATUS_ILL and "condition" in res.reason  # ... not the condition check


def test_partial_coverage_thresholds():
    # tilts up to 60 deg in every direction: enough for an "ok" fit of about 1 uT accuracy
    rng = np.random.default_rng(40)
    rot = flat_rotations(rng, 3000, max_tilt_deg=60.0)
    s, h = soft_iron(rng), np.array([-35.0, 15.0, 50.0])
    res = fit_ellipsoid(raw_samples(rng, rot, s, h, 0.5))
    assert res.ok
    assert np.linalg.norm(res.hard_iron_ut - h) < 1.0
    # up to 25 deg: rejected
    rot = flat_rotations(rng, 3000, max_tilt_deg=25.0)
    assert fit_ellipsoid(raw_samples(rng, rot, s, h, 0.5)).status == STATUS_ILL


def test_sphere_fit_baseline():
    rng = np.random.default_rng(50)
    rot = Rotation.random(400, random_state=rng).as_matrix()
    h = np.array([30.0, -12.0, 45.0])
    raw = raw_samples(rng, rot, np.eye(3), h, 0.5)
    res = fit_sphere(raw)
    assert res.ok and res.method == "sphere"
    assert np.linalg.norm(res.hard_iron_ut - h) < 0.3
    assert res.field_strength_ut == pytest.approx(45.0, abs=0.3)
    np.testing.assert_array_equal(res.soft_iron, np.eye(3))
    assert np.all(res.hard_iron_se_ut < 0.2)


def test_sample_coverage():
    rng = np.random.default_rng(60)
    full = raw_samples(rng, Rotation.random(2000, random_state=rng).as_matrix(), np.eye(3),
                       np.zeros(3), 0.5)
    flat = raw_samples(rng, flat_rotations(rng, 2000, 7.0), np.eye(3), np.zeros(3), 0.5)
    assert sample_coverage(full) > 0.85
    assert sample_coverage(flat) < 0.15
    assert sample_coverage(np.tile([1.0, 2.0, 3.0], (10, 1))) == 0.0


def test_rotation_aided_fit():
    rng = np.random.default_rng(70)
    h = np.array([20.0, -35.0, 48.0])
    # full rotation: h and the earth field are both determined
    rot = Rotation.random(300, random_state=rng).as_matrix()
    res = fit_with_rotation(raw_samples(rng, rot, np.eye(3), h, 0.5), rot)
    assert res.ok and res.method == "rotation"
    np.testing.assert_allclose(res.hard_iron_ut, h, atol=0.2)
    np.testing.assert_allclose(res.earth_field_ut, B_EARTH, atol=0.2)
    assert res.residual_rms_ut < 1.2  # sqrt(3) * 0.5 uT
    # yaw only: vertical offset and vertical field are inseparable
    yaw = Rotation.from_euler("z", rng.uniform(0, 360, (300, 1)), degrees=True).as_matrix()
    raw = raw_samples(rng, yaw, np.eye(3), h, 0.5)
    ill = fit_with_rotation(raw, yaw)
    assert ill.status == STATUS_ILL and "condition" in ill.reason
    # ... unless the vertical field is known
    ok = fit_with_rotation(raw, yaw, reference_vertical_ut=float(B_EARTH[2]))
    assert ok.ok
    np.testing.assert_allclose(ok.hard_iron_ut, h, atol=0.2)
    np.testing.assert_allclose(ok.earth_field_ut, B_EARTH, atol=0.2)


def test_rotation_aided_fit_rejects_varying_field():
    # samples along a walk: the earth-frame field changes by several uT
    rng = np.random.default_rng(80)
    n = 600
    yaw = Rotation.from_euler("z", rng.uniform(0, 360, (n, 1)), degrees=True).as_matrix()
    b = B_EARTH + 6.0 * np.sin(np.linspace(0, 12, n))[:, None] * np.array([0.6, 0.5, 0.6])
    b_dev = np.einsum("nji,nj->ni", yaw, b)
    raw = b_dev + np.array([5.0, 5.0, 5.0]) + 0.5 * rng.standard_normal((n, 3))
    res = fit_with_rotation(raw, yaw, reference_vertical_ut=float(B_EARTH[2]))
    assert res.status == STATUS_ILL and "residual" in res.reason


def test_bad_inputs_raise():
    with pytest.raises(ProcessingError):
        fit_ellipsoid(np.zeros((50, 2)))
    with pytest.raises(ProcessingError):
        fit_ellipsoid(np.ones((10, 3)))  # too few samples
    bad = np.random.default_rng(0).normal(size=(50, 3))
    bad[4, 1] = np.nan
    with pytest.raises(ProcessingError):
        fit_sphere(bad)
    with pytest.raises(ProcessingError):
        fit_with_rotation(np.zeros((5, 3)), np.zeros((4, 3, 3)))


@pytest.mark.shared
def test_real_flat_walks_are_ill_conditioned():
    # ILC walks (phone flat): the ellipsoid fit refuses, the sphere baseline is flagged and its
    # vertical offset is far from Android's own hard-iron estimate.
    z_errors = []
    for path in ilc_walks("F1", 5):
        unc = load_streams(path, ("TYPE_MAGNETIC_FIELD_UNCALIBRATED",))
        raw = unc["TYPE_MAGNETIC_FIELD_UNCALIBRATED"]
        ell = fit_ellipsoid(raw[:, 1:4])
        assert ell.status == STATUS_ILL and np.all(np.isnan(ell.hard_iron_ut))
        sph = fit_sphere(raw[:, 1:4])
        assert sph.status == STATUS_ILL
        z_errors.append(abs(sph.hard_iron_ut[2] - np.median(raw[:, 6])))
    assert np.median(z_errors) > 5.0
