"""Vectorized unit-quaternion algebra (``(..., 4)`` arrays ordered x, y, z, w).

A quaternion ``q`` here always rotates *device* coordinates into *earth* (ENU) coordinates:
``v_earth = rotate(q, v_device)``, which is the rotation Android's rotation vector describes.
"""

from __future__ import annotations

import numpy as np


def multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q`` (apply ``q`` first, then ``p``); shapes broadcast, last axis 4."""
    px, py, pz, pw = np.moveaxis(np.asarray(p, dtype=np.float64), -1, 0)
    qx, qy, qz, qw = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    ], axis=-1)


def conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion."""
    q = np.asarray(q, dtype=np.float64)
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


def from_axis_angle(axis: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Quaternions of rotations by ``angle_rad`` (shape (n,)) about a fixed unit ``axis`` (3,).

    Returns
    -------
    numpy.ndarray, shape (n, 4)
    """
    axis = np.asarray(axis, dtype=np.float64)
    half = 0.5 * np.asarray(angle_rad, dtype=np.float64)
    s = np.sin(half)[..., None]
    return np.concatenate([s * axis, np.cos(half)[..., None]], axis=-1)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by quaternions ``q`` (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u = q[..., :3]
    w = q[..., 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors by the inverse of ``q``: earth -> device for a device->earth ``q``."""
    return rotate(conjugate(q), v)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def canonical(q: np.ndarray) -> np.ndarray:
    """Normalize and flip sign so that ``w >= 0`` (Android's rotation-vector convention)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:] < 0, -q, q)


def continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 so that consecutive quaternions have a positive dot product."""
    q = np.asarray(q, dtype=np.float64).copy()
    if len(q) < 2:
        return q
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    flips = np.concatenate([[False], dots < 0])
    sign = np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)
    return q * sign[:, None]


def body_rates(q: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Angular velocity in the device frame (rad/s) of a sampled attitude.

    Parameters
    ----------
    q : numpy.ndarray, shape (n, 4)
        Device-to-earth attitude at the sample times.
    t_s : numpy.ndarray, shape (n,)
        Sample times in seconds, strictly increasing.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Rates at the sample times (the mean of the two adjacent finite-difference rates).
    """
    q = continuous(q)
    n = len(q)
    if n < 2:
        return np.zeros((n, 3))
    dq = multiply(conjugate(q[:-1]), q[1:])  # rotation from sample k to k+1, in device k frame
    dq = np.where(dq[:, 3:] < 0, -dq, dq)
    vec = dq[:, :3]
    sin_half = np.linalg.norm(vec, axis=1)
    angle = 2.0 * np.arctan2(sin_half, dq[:, 3])
    scale = np.where(sin_half > 1e-12, angle / np.maximum(sin_half, 1e-300), 2.0)
    rates_mid = vec * (scale / np.diff(t_s))[:, None]
    out = np.empty((n, 3))
    out[1:-1] = 0.5 * (rates_mid[:-1] + rates_mid[1:])
    out[0] = rates_mid[0]
    out[-1] = rates_mid[-1]
    return out


def axis_azimuth_deg(q: np.ndarray, axis: tuple[float, float, float] = (0.0, 1.0, 0.0)) -> np.ndarray:
    """Azimuth (degrees clockwise from north, [0, 360)) of a device axis in the earth frame.

    With the default device ``y`` axis this is the compass heading of a phone held flat.
    """
    v = rotate(q, np.broadcast_to(np.asarray(axis, dtype=np.float64), np.shape(q)[:-1] + (3,)))
    return np.degrees(np.arctan2(v[..., 0], v[..., 1])) % 360.0


def tilt_deg(q: np.ndarray) -> np.ndarray:
    """Angle between the device ``z`` axis and earth up, degrees (0 = lying flat, screen up)."""
    z = rotate(q, np.broadcast_to(np.array([0.0, 0.0, 1.0]), np.shape(q)[:-1] + (3,)))
    return np.degrees(np.arccos(np.clip(z[..., 2], -1.0, 1.0)))


E_X = np.array([1.0, 0.0, 0.0])
E_Y = np.array([0.0, 1.0, 0.0])
E_Z = np.array([0.0, 0.0, 1.0])


def from_yaw_pitch_roll(azimuth_deg: np.ndarray, pitch_deg: np.ndarray,
                        roll_deg: np.ndarray) -> np.ndarray:
    """Device-to-earth attitude of a phone whose ``y`` axis points to ``azimuth_deg``.

    ``q = Rz(-azimuth) * Rx(pitch) * Ry(roll)``: roll about the device ``y`` axis, then pitch
    (nose up positive) about the device ``x`` axis, then the compass rotation about earth up
    (azimuth clockwise from north, hence the minus sign).

    Returns
    -------
    numpy.ndarray, shape (n, 4)
    """
    qz = from_axis_angle(E_Z, -np.radians(azimuth_deg))
    qx = from_axis_angle(E_X, np.radians(pitch_deg))
    qy = from_axis_angle(E_Y, np.radians(roll_deg))
    return multiply(qz, multiply(qx, qy))
