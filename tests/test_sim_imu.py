"""Simulated attitude, accelerometer, gyroscope and rotation vector."""

from __future__ import annotations

import numpy as np
import pytest

from survey.sim import rotations as rot
from survey.sim.field import FieldParams, make_field
from survey.sim.floorplan import make_floorplan
from survey.sim.imu import (
    GRAVITY_MPS2,
    ImuParams,
    angular_rate,
    holding_attitude,
    rotation_vector,
    specific_force,
)
from survey.sim.rng import child_rng
from survey.sim.routes import build_graph, click_points, random_route
from survey.sim.signals import wrap_deg
from survey.sim.walker import WalkerParams, simulate_walk


@pytest.fixture(scope="module")
def setting():
    plan = make_floorplan("F1", 0, 40.0, 25.0, (5.0, 3.0, 1.2), (2.5, 4.0, 1.2),
                          child_rng(21, "plan"))
    field = make_field(plan, FieldParams(), child_rng(21, "field"))
    graph = build_graph(plan)
    kins = [simulate_walk(click_points(random_route(graph, 40.0, child_rng(21, "r", i))), plan,
                          1_700_000_000_000, WalkerParams(), child_rng(21, "w", i))
            for i in range(4)]
    return field, kins


def _imu(kin, mode, seed=0):
    rng = child_rng(seed, "imu", mode)
    q, swing = holding_attitude(kin, mode, rng)
    return q, specific_force(kin, q, swing, mode, ImuParams(), rng), angular_rate(kin, q)


def test_quaternion_helpers_round_trip():
    rng = np.random.default_rng(0)
    q = rot.canonical(rng.normal(size=(50, 4)))
    v = rng.normal(size=(50, 3))
    np.testing.assert_allclose(rot.rotate_inverse(q, rot.rotate(q, v)), v, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", rot.to_matrix(q), v), rot.rotate(q, v),
                               atol=1e-12)
    q0 = rot.from_yaw_pitch_roll(np.array([30.0]), np.array([0.0]), np.array([0.0]))
    assert rot.axis_azimuth_deg(q0)[0] == pytest.approx(30.0)


def test_rotation_vector_unit_norm_and_yaw(setting):
    field, kins = setting
    for i, kin in enumerate(kins):
        q, _, _ = _imu(kin, "flat_forward", i)
        b = field.field_earth_ut(kin.xy_m[:, 0], kin.xy_m[:, 1])
        dev = field.compass_deviation_deg(kin.xy_m[:, 0], kin.xy_m[:, 1], field_ut=b)
        rv = rotation_vector(q, dev, kin.t_s, ImuParams(), child_rng(i, "rv"))
        assert np.allclose(np.linalg.norm(rv, axis=1), 1.0)
        assert np.all(rv[:, 3] >= 0.0)
        # what a reader reconstructs from the three written values
        xyz = rv[:, :3].astype(np.float32).astype(np.float64)
        assert np.all(np.sum(xyz ** 2, axis=1) <= 1.0 + 1e-6)
        q_read = np.column_stack([xyz, np.sqrt(np.clip(1.0 - np.sum(xyz ** 2, axis=1), 0, 1))])
        yaw = rot.axis_azimuth_deg(q_read)
        err = wrap_deg(yaw - (kin.heading_deg - dev))     # fused heading = true - deviation
        assert abs(np.median(err)) < 3.0
        assert np.percentile(np.abs(err), 95) < 8.0
        # in the reported frame the horizontal field points north (east component ~0)
        b_dev = rot.rotate_inverse(q, b)
        b_rep = rot.rotate(q_read, b_dev)
        assert abs(np.median(b_rep[:, 0])) < 1.5


def test_flat_forward_tilt_and_accelerometer(setting):
    _, kins = setting
    for kin in kins:
        q, f, w = _imu(kin, "flat_forward")
        tilt = rot.tilt_deg(q)
        assert 1.0 <= np.median(tilt) <= 6.0
        assert np.percentile(tilt, 95) <= 10.0
        assert np.mean(np.linalg.norm(f, axis=1)) == pytest.approx(GRAVITY_MPS2, abs=0.3)
        f_earth = rot.rotate(q, f)
        walking = kin.moving > 0.99
        bounce_sd = np.std(f_earth[walking, 2])
        assert 0.6 <= bounce_sd * np.sqrt(2.0) <= 3.5            # amplitude 1-3 m/s^2
        standing = kin.moving == 0.0
        assert np.std(f_earth[standing, 2]) < 0.05
        # yaw rate about earth up matches the heading change
        w_earth = rot.rotate(q, w)
        h = np.unwrap(np.radians(rot.axis_azimuth_deg(q)))
        dh = np.gradient(h, kin.t_s)
        assert np.corrcoef(-w_earth[:, 2], dh)[0, 1] > 0.95


@pytest.mark.parametrize("mode,tilt_range", [("upward_not_flat", (50.0, 70.0)),
                                             ("swinging", (70.0, 135.0)),
                                             ("pocket", (70.0, 110.0))])
def test_other_holding_modes(setting, mode, tilt_range):
    _, kins = setting
    q, f, _ = _imu(kins[0], mode)
    tilt = np.median(rot.tilt_deg(q))
    assert tilt_range[0] <= tilt <= tilt_range[1]
    mean_z = np.mean(f[:, 2])
    if mode == "upward_not_flat":
        assert mean_z > 0.4 * GRAVITY_MPS2
    else:
        assert mean_z < 0.4 * GRAVITY_MPS2                      # "not upward" (paper 001)


def test_attitude_classifier_agrees(setting):
    attitude = pytest.importorskip("survey.attitude")
    _, kins = setting
    expected = {"flat_forward": "UFH", "upward_not_flat": "UFNH", "swinging": "NU",
                "pocket": "NU"}
    for mode, code in expected.items():
        for kin in kins[:2]:
            _, f, _ = _imu(kin, mode)
            res = attitude.classify_attitude(kin.t_ms, f, kin.step_t_ms)
            codes = np.asarray(res.codes if hasattr(res, "codes") else res.attitude)
            assert np.mean(codes == code) > 0.8, (mode, np.unique(codes, return_counts=True))
