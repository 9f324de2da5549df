"""Tests of survey.rotation: Android rotation vectors -> quaternions -> ENU rotation, angles."""

from __future__ import annotations

import numpy as np
import pytest
from ilc_sample import ilc_walks, load_streams
from scipy.spatial.transform import Rotation

from survey.errors import ProcessingError
from survey.rotation import (
    heading_deg,
    interpolate_quaternions,
    interpolate_rotation_vector,
    pitch_deg,
    quaternion_continuity,
    quaternion_from_rotation_vector,
    roll_deg,
    rotate_to_earth,
    rotation_matrices,
    tilt_deg,
)


def rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def rx(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def ry(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def android_rotvec(mat: np.ndarray) -> np.ndarray:
    """(x, y, z) of the Android rotation vector for device->earth matrices, w >= 0."""
    q = Rotation.from_matrix(mat).as_quat()  # (x, y, z, w)
    q = np.atleast_2d(q)
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q[:, :3]


def test_zero_rotation_vector_is_identity():
    r = rotation_matrices(np.zeros((2, 3)))
    assert r.shape == (2, 3, 3)
    np.testing.assert_allclose(r, np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-15)


def test_matrix_matches_standard_quaternion_formula():
    # Android's getRotationMatrixFromVector is the standard active-rotation matrix of
    # q = (w, x, y, z); scipy's from_quat uses the same convention with (x, y, z, w) order.
    rng = np.random.default_rng(0)
    q = rng.standard_normal((200, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[:, 3] = np.abs(q[:, 3])  # w >= 0, as a 3-component rotation vector implies
    expected = Rotation.from_quat(q).as_matrix()
    np.testing.assert_allclose(rotation_matrices(q[:, :3]), expected, atol=1e-12)
    np.testing.assert_allclose(rotation_matrices(q), expected, atol=1e-12)  # (x, y, z, w)


def test_matrices_are_proper_rotations_even_for_non_unit_input():
    rng = np.random.default_rng(1)
    q = rng.standard_normal((100, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[:, 3] = np.abs(q[:, 3])
    exact = rotation_matrices(q[:, :3])
    # 3-component vectors a little too long/short (|xyz| up to 1.02 gives w = 0 and a
    # renormalized half-turn), 4-component vectors scaled by 0.97-1.03.
    noisy3 = q[:, :3] * rng.uniform(0.99, 1.01, (100, 1))
    noisy4 = q * rng.uniform(0.97, 1.03, (100, 1))
    for r in (rotation_matrices(noisy3), rotation_matrices(noisy4)):
        np.testing.assert_allclose(r @ np.transpose(r, (0, 2, 1)),
                                   np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    # scaling a 4-vector does not change the rotation at all
    np.testing.assert_allclose(rotation_matrices(noisy4), exact, atol=1e-12)
    # A 0.5 % error in |xyz| moves the rotation by a small angle when w is not small (the
    # completed w = sqrt(1 - |xyz|^2) is ill-determined near half-turns, an Android property).
    keep = q[:, 3] >= 0.5
    noisy3 = q[keep, :3] * rng.uniform(0.995, 1.005, (int(keep.sum()), 1))
    dq = Rotation.from_matrix(rotation_matrices(noisy3)) * Rotation.from_matrix(exact[keep]).inv()
    assert np.degrees(dq.magnitude()).max() < 2.0


def test_longer_than_unit_xyz_becomes_half_turn():
    q = quaternion_from_rotation_vector([0.0, 0.0, 1.05])
    np.testing.assert_allclose(q, [[0.0, 0.0, 0.0, 1.0]], atol=1e-15)


def test_negated_quaternion_is_same_rotation():
    q = np.array([[0.3, -0.2, 0.5, 0.787]])
    np.testing.assert_allclose(rotation_matrices(q), rotation_matrices(-q), atol=1e-15)


def test_rotate_to_earth_known_attitude():
    # Phone flat, screen up, top edge pointing east: device y -> earth +x (east).
    r = rz(-90.0)
    rv = android_rotvec(r)
    np.testing.assert_allclose(rotate_to_earth([[0.0, 1.0, 0.0]], rv), [[1.0, 0.0, 0.0]],
                               atol=1e-12)
    assert heading_deg(rv)[0] == pytest.approx(90.0, abs=1e-9)
    # The accelerometer of a resting phone measures +g along earth up in any attitude.
    rng = np.random.default_rng(2)
    mats = Rotation.random(50, random_state=rng).as_matrix()
    rvs = android_rotvec(mats)
    acc_device = np.einsum("nji,j->ni", mats, [0.0, 0.0, 9.81])  # R^T g
    np.testing.assert_allclose(rotate_to_earth(acc_device, rvs),
                               np.tile([0.0, 0.0, 9.81], (50, 1)), atol=1e-12)
    # the same with scalar-first quaternions
    q = quaternion_from_rotation_vector(rvs)
    np.testing.assert_allclose(rotate_to_earth(acc_device, q, quaternion=True),
                               np.tile([0.0, 0.0, 9.81], (50, 1)), atol=1e-12)


def test_earth_field_recovered_for_any_attitude():
    b_earth = np.array([0.0, 30.0, -29.0])
    mats = Rotation.random(100, random_state=3).as_matrix()
    b_device = np.einsum("nji,j->ni", mats, b_earth)
    np.testing.assert_allclose(rotate_to_earth(b_device, android_rotvec(mats)),
                               np.tile(b_earth, (100, 1)), atol=1e-10)


@pytest.mark.parametrize("heading", [0.0, 30.0, 90.0, 179.0, 181.0, 270.0, 359.5])
@pytest.mark.parametrize("pitch,roll", [(0.0, 0.0), (8.0, -3.0), (-20.0, 10.0), (60.0, 0.0)])
def test_heading_pitch_roll_tilt(heading, pitch, roll):
    # Yaw clockwise from north = rotation about up by -heading; then pitch about device x,
    # then roll about device y.
    mat = (rz(-heading) @ rx(pitch) @ ry(roll))[None]
    rv = android_rotvec(mat)
    assert heading_deg(rv)[0] == pytest.approx(heading, abs=1e-7) or \
        abs(heading_deg(rv)[0] - heading) == pytest.approx(360.0, abs=1e-7)
    assert pitch_deg(rv)[0] == pytest.approx(pitch, abs=1e-7)
    assert roll_deg(rv)[0] == pytest.approx(roll, abs=1e-7)
    expected_tilt = np.degrees(np.arccos(np.cos(np.radians(pitch)) * np.cos(np.radians(roll))))
    assert tilt_deg(rv)[0] == pytest.approx(expected_tilt, abs=1e-6)
    # matrices and quaternions give the same angles
    assert heading_deg(mat)[0] == pytest.approx(heading_deg(rv)[0], abs=1e-9)
    q = quaternion_from_rotation_vector(rv)
    assert tilt_deg(q, quaternion=True)[0] == pytest.approx(tilt_deg(rv)[0], abs=1e-9)


def test_heading_range_and_upright_nan():
    mats = Rotation.random(500, random_state=4).as_matrix()
    h = heading_deg(mats)
    assert np.all((h >= 0) & (h < 360))
    upright = (rx(90.0))[None]  # top edge points up: heading undefined
    assert np.isnan(heading_deg(upright)[0])
    assert tilt_deg(upright)[0] == pytest.approx(90.0)
    down = (ry(180.0))[None]
    assert tilt_deg(down)[0] == pytest.approx(180.0)


def test_slerp_constant_rate_rotation():
    # Phone flat, turning clockwise at 40 deg/s, rotation vector at 10 Hz, read at 50 Hz.
    t_src = np.arange(0, 10_000, 100.0)
    t_dst = np.arange(0, 9_900, 20.0) + 3.0
    mats = np.stack([rz(-0.04 * t) for t in t_src])
    rv = android_rotvec(mats)  # w >= 0: xyz flips sign every 360 deg of turn
    q = interpolate_rotation_vector(t_src, rv, t_dst)
    h = heading_deg(q, quaternion=True)
    expected = (0.04 * t_dst) % 360.0
    err = (h - expected + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(err)) < 1e-9
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)


def test_slerp_across_sign_flip_takes_short_arc():
    # Two samples at heading 179 and 181 deg: the 3-component vectors have opposite signs
    # (w >= 0), but the midpoint must be heading 180, not 0.
    rv = android_rotvec(np.stack([rz(-179.0), rz(-181.0)]))
    assert np.dot(quaternion_from_rotation_vector(rv)[0],
                  quaternion_from_rotation_vector(rv)[1]) < 0
    q = interpolate_rotation_vector([0.0, 10.0], rv, [5.0])
    assert heading_deg(q, quaternion=True)[0] == pytest.approx(180.0, abs=1e-9)


def test_slerp_matches_scipy_and_holds_ends():
    rng = np.random.default_rng(5)
    t_src = np.cumsum(rng.uniform(15, 25, 40))
    rot = Rotation.random(1, random_state=6) * Rotation.from_rotvec(
        np.cumsum(rng.normal(0, 0.1, (40, 3)), axis=0))
    q_xyzw = rot.as_quat()
    q = np.column_stack([q_xyzw[:, 3], q_xyzw[:, :3]])
    q[::3] *= -1  # arbitrary sign flips must not matter
    t_dst = np.linspace(t_src[0] - 50, t_src[-1] + 50, 300)
    got = interpolate_quaternions(t_src, q, t_dst)
    from scipy.spatial.transform import Slerp
    inside = (t_dst >= t_src[0]) & (t_dst <= t_src[-1])
    ref = Slerp(t_src, rot)(t_dst[inside]).as_matrix()
    np.testing.assert_allclose(rotation_matrices(got[inside], quaternion=True), ref, atol=1e-9)
    # held constant outside the source range
    np.testing.assert_allclose(rotation_matrices(got[~inside][:1], quaternion=True),
                               rot[0].as_matrix()[None], atol=1e-12)
    np.testing.assert_allclose(rotation_matrices(got[-1:], quaternion=True),
                               rot[-1].as_matrix()[None], atol=1e-12)


def test_interpolation_with_duplicate_times_and_single_sample():
    rv = android_rotvec(np.stack([rz(-10.0), rz(-10.0), rz(-20.0)]))
    q = interpolate_rotation_vector([0.0, 0.0, 10.0], rv, [0.0, 5.0])
    np.testing.assert_allclose(heading_deg(q, quaternion=True), [10.0, 15.0], atol=1e-9)
    q1 = interpolate_rotation_vector([5.0], rv[:1], [0.0, 9.0])
    np.testing.assert_allclose(heading_deg(q1, quaternion=True), [10.0, 10.0], atol=1e-9)


def test_quaternion_continuity():
    q = np.array([[1.0, 0, 0, 0], [-0.99, -0.1, 0, 0], [0.98, 0.2, 0, 0], [0.97, 0.24, 0, 0]])
    c = quaternion_continuity(q)
    assert np.all(np.einsum("ij,ij->i", c[1:], c[:-1]) > 0)
    np.testing.assert_allclose(np.abs(c), np.abs(q))


@pytest.mark.parametrize("bad", [np.zeros((3, 2)), np.zeros((2, 5)), np.zeros((2, 2, 3)),
                                 np.array([[np.nan, 0.0, 0.0]])])
def test_bad_rotation_vectors_raise(bad):
    with pytest.raises(ProcessingError):
        rotation_matrices(bad)


def test_bad_inputs_raise():
    with pytest.raises(ProcessingError):
        rotation_matrices(np.zeros((1, 4)))  # zero 4-vector has no rotation
    with pytest.raises(ProcessingError):
        rotate_to_earth(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ProcessingError):
        interpolate_rotation_vector([10.0, 0.0], np.zeros((2, 3)), [5.0])
    with pytest.raises(ProcessingError):
        interpolate_rotation_vector([0.0, 1.0], np.zeros((3, 3)), [5.0])



@pytest.mark.shared
def test_real_traces_earth_frame_field():
    # ILC walks: with Android's convention the east component of the earth-frame field is ~0
    # (map y ~ magnetic north) and the field points down at ~133 deg from up.
    for path in ilc_walks("F1", 5):
        d = load_streams(path, ("TYPE_MAGNETIC_FIELD", "TYPE_ROTATION_VECTOR"))
        mag, rv = d["TYPE_MAGNETIC_FIELD"], d["TYPE_ROTATION_VECTOR"]
        q = interpolate_rotation_vector(rv[:, 0], rv[:, 1:4], mag[:, 0])
        b = rotate_to_earth(mag[:, 1:4], q, quaternion=True)
        assert abs(np.median(b[:, 0])) < 2.0
        assert -45.0 < np.median(b[:, 2]) < -20.0
        polar = np.degrees(np.arccos(np.median(b[:, 2] / np.linalg.norm(b, axis=1))))
        assert 125.0 < polar < 140.0
        assert np.median(tilt_deg(q, quaternion=True)) < 10.0  # held nearly flat
