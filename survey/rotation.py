"""Android rotation vectors: quaternions, device-to-earth rotation, heading and tilt.

Frames
------
*Device frame*: Android sensor axes -- x to the right of the screen, y to the top edge of the
phone, z out of the screen.
*Earth frame*: ENU -- x east, y (magnetic) north, z up. The map frame of indoormap is x east,
y north, so the first two earth components are directly map components (``/work/shared/ilc``
FINDINGS: with Android's convention the east component of the earth-frame field is ~0, no
declination visible).

An Android ``TYPE_ROTATION_VECTOR`` sample ``(x, y, z[, w])`` is the unit quaternion
``q = (w, x, y, z) = (cos(theta/2), sin(theta/2) * axis)`` of the rotation that takes device
coordinates to earth coordinates; when the scalar part is absent
``w = sqrt(max(0, 1 - x^2 - y^2 - z^2))`` (Android ``SensorManager.getQuaternionFromVector``).
The matrix ``R`` built from it (``getRotationMatrixFromVector``) maps device vectors to earth
vectors: ``v_earth = R @ v_device``; its columns are the device axes expressed in the earth frame.

Quaternions are stored scalar-first, shape ``(n, 4)`` as ``(w, x, y, z)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import ProcessingError

__all__ = [
    "heading_deg",
    "interpolate_quaternions",
    "interpolate_rotation_vector",
    "pitch_deg",
    "quaternion_continuity",
    "quaternion_from_rotation_vector",
    "roll_deg",
    "rotate_to_earth",
    "rotation_matrices",
    "tilt_deg",
]

#: Below this |(x, y, z, w)| a rotation vector carries no usable rotation.
_MIN_NORM = 1e-9
#: Horizontal projection of the device y axis below which the heading is undefined (NaN).
_MIN_HORIZONTAL = 1e-6


def _as_rows(a: ArrayLike, ncols: tuple[int, ...], name: str) -> NDArray[np.float64]:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] in ncols:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] not in ncols:
        raise ProcessingError(f"{name} must have shape (n, {'|'.join(map(str, ncols))}), "
                              f"got {arr.shape}")
    return arr


def quaternion_from_rotation_vector(rotvec: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternions from Android rotation-vector samples.

    Parameters
    ----------
    rotvec : array_like, shape (n, 3) or (n, 4)
        Rotation-vector components ``(x, y, z)`` or ``(x, y, z, w)`` (dimensionless), in Android
        order (scalar last). A single sample of shape (3,) or (4,) is accepted as n = 1.

    Returns
    -------
    ndarray, shape (n, 4)
        Unit quaternions ``(w, x, y, z)``, scalar first. Slightly non-unit input is normalized:
        with 3 components ``w = sqrt(max(0, 1 - |xyz|^2))`` is completed first (so a vector with
        ``|xyz| > 1`` becomes a half-turn, ``w = 0``), then the 4-vector is divided by its norm.

    Raises
    ------
    ProcessingError
        Wrong shape, non-finite values or an all-zero 4-component sample.
    """
    rv = _as_rows(rotvec, (3, 4), "rotvec")
    if not np.all(np.isfinite(rv)):
        raise ProcessingError("rotation vector contains NaN or infinite values")
    xyz = rv[:, :3]
    if rv.shape[1] == 4:
        w = rv[:, 3]
    else:
        w = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("ij,ij->i", xyz, xyz)))
    q = np.column_stack([w, xyz])
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < _MIN_NORM):
        raise ProcessingError("rotation vector sample with zero norm")
    return q / norm[:, None]


def quaternion_continuity(q: ArrayLike) -> NDArray[np.float64]:
    """Flip quaternion signs so that consecutive samples lie in the same hemisphere.

    ``q`` and ``-q`` are the same rotation; interpolation and averaging need the sequence to be
    sign-continuous (``dot(q[i], q[i+1]) >= 0``).

    Parameters
    ----------
    q : array_like, shape (n, 4)
        Quaternions ``(w, x, y, z)``.

    Returns
    -------
    ndarray, shape (n, 4)
        The same rotations, ``q[0]`` unchanged, later samples multiplied by +-1.
    """
    qa = _as_rows(q, (4,), "q").copy()
    if len(qa) < 2:
        return qa
    dots = np.einsum("ij,ij->i", qa[1:], qa[:-1])
    flips = np.where(dots < 0.0, -1.0, 1.0)
    sign = np.concatenate([[1.0], np.cumprod(flips)])
    return qa * sign[:, None]


def rotation_matrices(rotvec: ArrayLike, *, quaternion: bool = False) -> NDArray[np.float64]:
    """Device-to-earth (ENU) rotation matrices.

    Parameters
    ----------
    rotvec : array_like, shape (n, 3) or (n, 4)
        Android rotation vectors (see :func:`quaternion_from_rotation_vector`), or, when
        ``quaternion=True``, quaternions ``(w, x, y, z)`` of shape (n, 4) (normalized here).
    quaternion : bool
        Interpret the input as scalar-first quaternions instead of rotation vectors.

    Returns
    -------
    ndarray, shape (n, 3, 3)
        ``R[i]`` with ``v_earth = R[i] @ v_device``; identical to Android's
        ``SensorManager.getRotationMatrixFromVector``.
    """
    if quaternion:
        q = _as_rows(rotvec, (4,), "quaternion")
        norm = np.linalg.norm(q, axis=1)
        if np.any(~np.isfinite(norm)) or np.any(norm < _MIN_NORM):
            raise ProcessingError("quaternion with zero or non-finite norm")
        q = q / norm[:, None]
    else:
        q = quaternion_from_rotation_vector(rotvec)
    w, x, y, z = q.T
    r = np.empty((len(q), 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z)
    r[:, 0, 1] = 2 * (x * y - z * w)
    r[:, 0, 2] = 2 * (x * z + y * w)
    r[:, 1, 0] = 2 * (x * y + z * w)
    r[:, 1, 1] = 1 - 2 * (x * x + z * z)
    r[:, 1, 2] = 2 * (y * z - x * w)
    r[:, 2, 0] = 2 * (x * z - y * w)
    r[:, 2, 1] = 2 * (y * z + x * w)
    r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def rotate_to_earth(vectors_device: ArrayLike, rotvec: ArrayLike, *,
                    quaternion: bool = False) -> NDArray[np.float64]:
    """Rotate device-frame vectors into the earth (ENU) frame, sample by sample.

    Parameters
    ----------
    vectors_device : array_like, shape (n, 3)
        Vectors in the device frame (any unit, e.g. uT for the magnetometer, m/s^2 for the
        accelerometer), sampled on the same timestamps as ``rotvec`` (interpolate the rotation
        first with :func:`interpolate_rotation_vector` otherwise).
    rotvec : array_like, shape (n, 3) or (n, 4)
        Android rotation vectors ``(x, y, z[, w])`` (scalar last), or with ``quaternion=True``
        scalar-first quaternions ``(w, x, y, z)`` as returned by
        :func:`interpolate_rotation_vector`.
    quaternion : bool
        Interpret ``rotvec`` as scalar-first quaternions.

    Returns
    -------
    ndarray, shape (n, 3)
        The vectors in the earth frame: (east, north, up), same unit as the input.
    """
    v = _as_rows(vectors_device, (3,), "vectors_device")
    r = rotation_matrices(rotvec, quaternion=quaternion)
    if len(r) != len(v):
        raise ProcessingError(f"vectors ({len(v)}) and rotation vectors ({len(r)}) differ in "
                              "length")
    return np.einsum("nij,nj->ni", r, v)


def interpolate_quaternions(t_src: ArrayLike, q_src: ArrayLike,
                            t_dst: ArrayLike) -> NDArray[np.float64]:
    """Spherical linear interpolation (slerp) of a quaternion time series.

    Parameters
    ----------
    t_src : array_like, shape (n,)
        Sample times of ``q_src`` (any unit, e.g. ms), non-decreasing.
    q_src : array_like, shape (n, 4)
        Quaternions ``(w, x, y, z)``; normalized here, signs made continuous.
    t_dst : array_like, shape (m,)
        Times to interpolate at (same unit as ``t_src``). Times outside
        ``[t_src[0], t_src[-1]]`` take the nearest end sample (no extrapolation).

    Returns
    -------
    ndarray, shape (m, 4)
        Unit quaternions at ``t_dst``. Between two samples the rotation turns at constant rate
        about a fixed axis (shortest arc); nearly equal neighbours fall back to normalized linear
        interpolation.
    """
    ts = np.asarray(t_src, dtype=np.float64).ravel()
    td = np.asarray(t_dst, dtype=np.float64).ravel()
    q = _as_rows(q_src, (4,), "q_src")
    if len(ts) != len(q) or len(ts) == 0:
        raise ProcessingError(f"t_src ({len(ts)}) and q_src ({len(q)}) must have the same, "
                              "non-zero length")
    if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(td)) and np.all(np.isfinite(q))):
        raise ProcessingError("non-finite times or quaternions")
    if np.any(np.diff(ts) < 0):
        raise ProcessingError("t_src must be non-decreasing")
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < _MIN_NORM):
        raise ProcessingError("quaternion with zero norm")
    q = quaternion_continuity(q / norm[:, None])
    if len(ts) == 1:
        return np.repeat(q, len(td), axis=0)
    i = np.clip(np.searchsorted(ts, td, side="right") - 1, 0, len(ts) - 2)
    t0, t1 = ts[i], ts[i + 1]
    span = t1 - t0
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(span > 0, (td - t0) / span, 0.0)
    u = np.clip(u, 0.0, 1.0)
    q0, q1 = q[i], q[i + 1]
    dot = np.clip(np.einsum("ij,ij->i", q0, q1), -1.0, 1.0)  # >= 0 after continuity
    omega = np.arccos(dot)
    so = np.sin(omega)
    small = so < 1e-6
    with np.errstate(invalid="ignore", divide="ignore"):
        w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * omega) / so)
        w1 = np.where(small, u, np.sin(u * omega) / so)
    out = w0[:, None] * q0 + w1[:, None] * q1
    return out / np.linalg.norm(out, axis=1)[:, None]


def interpolate_rotation_vector(t_src: ArrayLike, rotvec: ArrayLike,
                                t_dst: ArrayLike) -> NDArray[np.float64]:
    """Rotation-vector samples resampled onto other timestamps (slerp).

    Parameters
    ----------
    t_src : array_like, shape (n,)
        Times of the rotation-vector samples (e.g. ms), non-decreasing.
    rotvec : array_like, shape (n, 3) or (n, 4)
        Android rotation vectors.
    t_dst : array_like, shape (m,)
        Target times, same unit; held constant outside the source range.

    Returns
    -------
    ndarray, shape (m, 4)
        Unit quaternions ``(w, x, y, z)`` at ``t_dst``; pass them to
        :func:`rotation_matrices` with ``quaternion=True``.
    """
    return interpolate_quaternions(t_src, quaternion_from_rotation_vector(rotvec), t_dst)


def _matrices(rot: ArrayLike, quaternion: bool) -> NDArray[np.float64]:
    arr = np.asarray(rot, dtype=np.float64)
    if arr.ndim == 3 and arr.shape[1:] == (3, 3):
        return arr
    return rotation_matrices(arr, quaternion=quaternion)


def heading_deg(rot: ArrayLike, *, quaternion: bool = False) -> NDArray[np.float64]:
    """Heading of the device's top edge (y axis) projected to the horizontal plane.

    Parameters
    ----------
    rot : array_like
        Rotation vectors (n, 3|4), quaternions (n, 4) with ``quaternion=True``, or rotation
        matrices (n, 3, 3) from :func:`rotation_matrices` (always 3-D; a 2-D (3, 3) input is
        three rotation vectors).
    quaternion : bool
        Interpret a (n, 4) input as scalar-first quaternions.

    Returns
    -------
    ndarray, shape (n,)
        Degrees clockwise from map north (+y) towards east (+x), in [0, 360). NaN when the device
        y axis is vertical (phone upright), where the heading is undefined.
    """
    r = _matrices(rot, quaternion)
    east, north = r[:, 0, 1], r[:, 1, 1]
    h = np.degrees(np.arctan2(east, north)) % 360.0
    h = np.where(h >= 360.0, 0.0, h)
    return np.where(np.hypot(east, north) < _MIN_HORIZONTAL, np.nan, h)


def pitch_deg(rot: ArrayLike, *, quaternion: bool = False) -> NDArray[np.float64]:
    """Elevation of the device's top edge (y axis) above the horizontal plane.

    Parameters
    ----------
    rot : array_like
        Rotation vectors, quaternions or matrices as for :func:`heading_deg`.
    quaternion : bool
        Interpret a (n, 4) input as scalar-first quaternions.

    Returns
    -------
    ndarray, shape (n,)
        Degrees in [-90, 90]; positive when the top edge points up. (Android's
        ``getOrientation`` pitch has the opposite sign.)
    """
    r = _matrices(rot, quaternion)
    return np.degrees(np.arcsin(np.clip(r[:, 2, 1], -1.0, 1.0)))


def roll_deg(rot: ArrayLike, *, quaternion: bool = False) -> NDArray[np.float64]:
    """Rotation about the device y axis, as in Android's ``getOrientation``.

    Parameters
    ----------
    rot : array_like
        Rotation vectors, quaternions or matrices as for :func:`heading_deg`.
    quaternion : bool
        Interpret a (n, 4) input as scalar-first quaternions.

    Returns
    -------
    ndarray, shape (n,)
        Degrees in (-180, 180]: ``atan2(-R[2,0], R[2,2])``; positive when the right edge (+x)
        dips, 0 for a phone lying screen up, 180 for screen down.
    """
    r = _matrices(rot, quaternion)
    return np.degrees(np.arctan2(-r[:, 2, 0], r[:, 2, 2]))


def tilt_deg(rot: ArrayLike, *, quaternion: bool = False) -> NDArray[np.float64]:
    """Angle between the device z axis (screen normal) and earth up.

    Parameters
    ----------
    rot : array_like
        Rotation vectors, quaternions or matrices as for :func:`heading_deg`.
    quaternion : bool
        Interpret a (n, 4) input as scalar-first quaternions.

    Returns
    -------
    ndarray, shape (n,)
        Degrees in [0, 180]: 0 for a phone lying flat screen up, 90 upright, 180 screen down.
    """
    r = _matrices(rot, quaternion)
    return np.degrees(np.arccos(np.clip(r[:, 2, 2], -1.0, 1.0)))
