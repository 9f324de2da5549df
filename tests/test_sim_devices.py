"""Simulated phones: soft/hard iron, calibration sessions, magnetometer and RSSI distortion."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from survey.sim import rotations as rot
from survey.sim.devices import (
    DEVICE_MODELS,
    accelerometer,
    distort_rssi,
    gyroscope,
    magnetometer,
    make_device,
    make_sessions,
)
from survey.sim.rng import child_rng

REF, OTHER = "SimPhone SIM-A1", "SimPhone SIM-B2"


@pytest.fixture
def phones():
    ref = make_device("dev0", DEVICE_MODELS[REF], True, child_rng(1, "d", 0))
    other = make_device("dev1", DEVICE_MODELS[OTHER], False, child_rng(1, "d", 1))
    return ref, other


def test_device_parameters(phones):
    ref, other = phones
    assert (ref.rssi_k, ref.rssi_b) == (1.0, 0.0)
    assert 0.8 <= other.rssi_k <= 1.2 and -10.0 <= other.rssi_b <= 5.0
    for d in phones:
        s = np.asarray(d.soft_iron)
        assert np.abs(s - np.eye(3)).max() < 0.15
        assert np.allclose(s, s.T)
    np.testing.assert_allclose(distort_rssi(np.array([-60.0, -80.0]), ref), [-60.0, -80.0])
    np.testing.assert_allclose(distort_rssi(np.array([-60.0]), other),
                               [other.rssi_k * -60.0 + other.rssi_b])


def test_sessions_jump_and_residuals(phones):
    for d in phones:
        sessions = make_sessions(d, [0, 2, 4, 6], child_rng(2, d.device_id))
        h = np.array([s.true_hard_iron_ut for s in sessions])
        rep = np.array([s.reported_bias_ut for s in sessions])
        jumps = np.linalg.norm(np.diff(h, axis=0), axis=1)
        assert np.all(jumps > 5.0)                            # tens of uT between sessions
        resid = rep - h
        assert np.all(np.abs(resid[:, :2]) < 8.0)             # a few uT ...
        assert np.all(np.abs(resid[:, 2]) < 20.0)             # ... larger in z
        res = d.model.mag_resolution
        np.testing.assert_allclose(rep / res, np.round(rep / res), atol=1e-6)
        assert [s.session_id for s in sessions] == [f"{d.device_id}-s{i}" for i in range(4)]


def test_magnetometer_model(phones):
    rng = np.random.default_rng(3)
    n = 400
    q = rot.canonical(rng.normal(size=(n, 4)))
    b_earth = np.array([0.0, 30.7, -28.6]) + rng.normal(0.0, 5.0, (n, 3))
    for d in phones:
        s = make_sessions(d, [0], child_rng(4, d.device_id))[0]
        m = magnetometer(b_earth, q, d, s, child_rng(5))
        np.testing.assert_array_equal(m.calibrated_ut, m.uncalibrated_ut - m.bias_ut)
        np.testing.assert_array_equal(m.bias_ut, s.reported_bias_ut)
        res = d.model.mag_resolution
        np.testing.assert_allclose(m.uncalibrated_ut / res, np.round(m.uncalibrated_ut / res),
                                   atol=1e-6)
        # noise-free and unquantized, the model inverts exactly
        quiet = dataclasses.replace(d, model=dataclasses.replace(d.model, mag_noise_ut=0.0))
        exact = magnetometer(b_earth, q, quiet, s, child_rng(5), quantized=False)
        b_dev = np.linalg.solve(np.asarray(d.soft_iron),
                                (exact.uncalibrated_ut - s.true_hard_iron_ut).T).T
        np.testing.assert_allclose(rot.rotate(q, b_dev), b_earth, atol=1e-9)
        # noise level: quantized noisy readings stay within a few uT of the exact ones
        err = m.uncalibrated_ut - exact.uncalibrated_ut
        assert 0.3 < np.std(err) < 1.5


def test_accelerometer_and_gyroscope_streams(phones):
    rng = np.random.default_rng(6)
    f = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 1.0, (300, 3))
    w = rng.normal(0.0, 0.3, (300, 3))
    for d in phones:
        s = make_sessions(d, [0], child_rng(7, d.device_id))[0]
        cal, unc, bias = accelerometer(f, d, child_rng(8))
        np.testing.assert_array_equal(bias, np.zeros(3))    # like the real phone
        assert np.abs(np.mean(unc - cal, axis=0) - d.accel_offset_mps2).max() < 0.02
        gcal, gunc, gbias = gyroscope(w, d, s, child_rng(9))
        np.testing.assert_array_equal(gbias, s.gyro_bias_reported_rps)
        expected = np.asarray(s.gyro_bias_rps) - np.asarray(s.gyro_bias_reported_rps)
        assert np.abs(np.mean(gunc - gbias - gcal, axis=0) - 0.0).max() < 0.002
        assert np.abs(np.mean(gcal - w, axis=0) - expected).max() < 0.002
