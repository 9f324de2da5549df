"""Magnetic-field features in the earth frame, and circular statistics of angles.

The map stores strength, azimuth and polar angle of the field in the earth frame (paper 001,
figures 19-21; NOTES.md "Maps exist for strength, azimuth and polar angle"). Input vectors are
earth-frame (ENU: east, north, up) field samples in uT, e.g. from
:func:`survey.rotation.rotate_to_earth`.

Angle conventions
-----------------
* azimuth: direction of the horizontal field, degrees clockwise from the frame's north (+y)
  towards east (+x), in [0, 360) -- the compass convention of
  :func:`survey.rotation.heading_deg`. In the frame of Android's rotation vector, whose north
  is the sensed field's, it is near 0 wherever the phone is (the field's direction on the map
  is the heading offset's, negated: ``mapping.field_layers``);
* polar angle: angle between the field vector and earth up, in [0, 180]; the ILC traces (vertical
  about -29 uT of 42 uT) give about 133 deg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import ProcessingError

__all__ = [
    "FieldFeatures",
    "azimuth_deg",
    "circular_mean_deg",
    "circular_median_deg",
    "circular_resultant_length",
    "field_features",
    "horizontal_ut",
    "polar_deg",
    "strength_ut",
    "vertical_ut",
    "wrap_deg",
]


def _field(b_earth: ArrayLike) -> NDArray[np.float64]:
    b = np.asarray(b_earth, dtype=np.float64)
    if b.ndim == 1 and b.shape[0] == 3:
        b = b[None, :]
    if b.ndim != 2 or b.shape[1] != 3:
        raise ProcessingError(f"earth-frame field must have shape (n, 3), got {b.shape}")
    return b


def strength_ut(b_earth: ArrayLike) -> NDArray[np.float64]:
    """Field strength ``|B|``.

    Parameters
    ----------
    b_earth : array_like, shape (n, 3)
        Field (east, north, up) in uT. Any frame works: the norm is rotation invariant.

    Returns
    -------
    ndarray, shape (n,)
        Strength in uT.
    """
    return np.linalg.norm(_field(b_earth), axis=1)


def horizontal_ut(b_earth: ArrayLike) -> NDArray[np.float64]:
    """Horizontal field strength ``sqrt(B_east^2 + B_north^2)``.

    Parameters
    ----------
    b_earth : array_like, shape (n, 3)
        Earth-frame field (east, north, up) in uT.

    Returns
    -------
    ndarray, shape (n,)
        uT, >= 0.
    """
    b = _field(b_earth)
    return np.hypot(b[:, 0], b[:, 1])


def vertical_ut(b_earth: ArrayLike) -> NDArray[np.float64]:
    """Vertical field component, up positive.

    Parameters
    ----------
    b_earth : array_like, shape (n, 3)
        Earth-frame field (east, north, up) in uT.

    Returns
    -------
    ndarray, shape (n,)
        uT; negative in the northern hemisphere (field points down).
    """
    return _field(b_earth)[:, 2].copy()


def azimuth_deg(b_earth: ArrayLike) -> NDArray[np.float64]:
    """Direction of the horizontal field, clockwise from the frame's north (+y).

    Parameters
    ----------
    b_earth : array_like, shape (n, 3)
        Earth-frame field (east, north, up) in uT.

    Returns
    -------
    ndarray, shape (n,)
        Degrees in [0, 360): 0 = field points north (+y), 90 = east (+x). NaN when the horizontal
        field is exactly zero.
    """
    b = _field(b_earth)
    az = np.degrees(np.arctan2(b[:, 0], b[:, 1])) % 360.0
    az = np.where(az >= 360.0, 0.0, az)
    return np.where((b[:, 0] == 0) & (b[:, 1] == 0), np.nan, az)


def polar_deg(b_earth: ArrayLike) -> NDArray[np.float64]:
    """Angle between the field vector and earth up.

    Parameters
    ----------
    b_earth : array_like, shape (n, 3)
        Earth-frame field (east, north, up) in uT.

    Returns
    -------
    ndarray, shape (n,)
        Degrees in [0, 180] (``arccos(B_up / |B|)``), 90 for a horizontal field, > 90 when the
        field points down. NaN for a zero vector.
    """
    b = _field(b_earth)
    s = np.linalg.norm(b, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.clip(b[:, 2] / s, -1.0, 1.0)
    return np.where(s > 0, np.degrees(np.arccos(c)), np.nan)


@dataclass(frozen=True)
class FieldFeatures:
    """Per-sample field features; every array has shape (n,).

    Attributes
    ----------
    strength_ut, horizontal_ut, vertical_ut : ndarray
        ``|B|``, horizontal strength, up component (uT).
    azimuth_deg : ndarray
        Horizontal-field direction, clockwise from the frame's north (+y), [0, 360).
    polar_deg : ndarray
        Angle between field and up, [0, 180].
    """

    strength_ut: NDArray[np.float64]
    horizontal_ut: NDArray[np.float64]
    vertical_ut: NDArray[np.float64]
    azimuth_deg: NDArray[np.float64]
    polar_deg: NDArray[np.float64]


def field_features(b_earth: ArrayLike) -> FieldFeatures:
    """All map features of earth-frame field samples (paper 001, figures 19-21).

    Parameters
    ----------
    b_earth : array_like, shape (n, 3)
        Earth-frame field (east, north, up) in uT.

    Returns
    -------
    FieldFeatures
        Strength, horizontal, vertical (uT), azimuth and polar angle (deg), each shape (n,).
    """
    b = _field(b_earth)
    return FieldFeatures(strength_ut=strength_ut(b), horizontal_ut=horizontal_ut(b),
                         vertical_ut=vertical_ut(b), azimuth_deg=azimuth_deg(b),
                         polar_deg=polar_deg(b))


def wrap_deg(angle_deg: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles to [-180, 180).

    Parameters
    ----------
    angle_deg : array_like, any shape
        Angles in degrees (NaN passes through).

    Returns
    -------
    ndarray, same shape
        ``angle`` shifted by a multiple of 360 into [-180, 180); e.g. the signed difference of two
        azimuths is ``wrap_deg(a - b)``.
    """
    a = np.asarray(angle_deg, dtype=np.float64)
    w = (a + 180.0) % 360.0 - 180.0
    return np.where(w >= 180.0, -180.0, w)  # float rounding of tiny negatives


def unwrap_deg(angle_deg: ArrayLike) -> NDArray[np.float64]:
    """Unwrap a sequence of angles (deg, shape (n,)) so that consecutive finite values differ
    by less than 180 deg; NaN stays NaN and does not break the unwrapping of the values after
    it (``np.unwrap`` turns everything after a NaN into NaN)."""
    a = np.asarray(angle_deg, dtype=np.float64)
    out = np.full(a.shape, np.nan)
    ok = np.isfinite(a)
    out[ok] = np.degrees(np.unwrap(np.radians(a[ok])))
    return out


def _prepare(angle_deg: ArrayLike, weights: ArrayLike | None,
             axis: int | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    a = np.asarray(angle_deg, dtype=np.float64)
    w = np.ones_like(a) if weights is None else np.broadcast_to(
        np.asarray(weights, dtype=np.float64), a.shape)
    if np.any(w < 0):
        raise ProcessingError("circular weights must be non-negative")
    valid = np.isfinite(a) & np.isfinite(w)
    w = np.where(valid, w, 0.0)
    a = np.where(valid, a, 0.0)
    if axis is None:
        a, w = a.ravel(), w.ravel()
    return a, w


def _resultant(angle_deg: ArrayLike, weights: ArrayLike | None, axis: int | None
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Weighted sums ``(sum w cos a, sum w sin a, sum w)`` over ``axis`` (NaN angles ignored)."""
    a, w = _prepare(angle_deg, weights, axis)
    ax = 0 if axis is None else axis
    r = np.radians(a)
    return (w * np.cos(r)).sum(axis=ax), (w * np.sin(r)).sum(axis=ax), w.sum(axis=ax)


def circular_resultant_length(angle_deg: ArrayLike, weights: ArrayLike | None = None,
                              axis: int | None = None) -> NDArray[np.float64] | float:
    """Mean resultant length R of angles (1 = all equal, ~0 = uniformly spread).

    Parameters
    ----------
    angle_deg : array_like
        Angles in degrees; NaN entries are ignored.
    weights : array_like, optional
        Non-negative weights broadcastable to ``angle_deg``.
    axis : int, optional
        Axis to reduce; ``None`` reduces all.

    Returns
    -------
    float or ndarray
        R in [0, 1]; NaN where no valid angle.
    """
    c, s, sw = _resultant(angle_deg, weights, axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(sw > 0, np.hypot(c, s) / sw, np.nan)
    return float(out) if np.ndim(out) == 0 else out


def circular_mean_deg(angle_deg: ArrayLike, weights: ArrayLike | None = None,
                      axis: int | None = None) -> NDArray[np.float64] | float:
    """Circular (vector) mean of angles: ``atan2(sum w sin a, sum w cos a)``.

    Parameters
    ----------
    angle_deg : array_like
        Angles in degrees; NaN entries are ignored.
    weights : array_like, optional
        Non-negative weights broadcastable to ``angle_deg``.
    axis : int, optional
        Axis to reduce; ``None`` reduces all.

    Returns
    -------
    float or ndarray
        Mean direction in [0, 360); NaN where there is no valid angle or the resultant vanishes
        (e.g. two opposite angles), since the mean is then undefined.
    """
    c, s, sw = _resultant(angle_deg, weights, axis)
    m = np.degrees(np.arctan2(s, c)) % 360.0
    m = np.where(m >= 360.0, 0.0, m)
    with np.errstate(invalid="ignore", divide="ignore"):
        undefined = (sw <= 0) | (np.hypot(c, s) <= 1e-12 * np.maximum(sw, 1e-300))
    out = np.where(undefined, np.nan, m)
    return float(out) if np.ndim(out) == 0 else out


def circular_median_deg(angle_deg: ArrayLike) -> float:
    """Circular median of angles (robust centre of a concentrated sample).

    Computed as the linear median of the deviations from the circular mean, wrapped to
    [-180, 180), added back to the mean. For samples within a half circle around their mean
    (the case for per-cell azimuths) this is the point minimizing the sum of absolute angular
    deviations, like Fisher's circular median; it needs O(n) time.

    Parameters
    ----------
    angle_deg : array_like, shape (n,)
        Angles in degrees; NaN entries are ignored.

    Returns
    -------
    float
        Median direction in [0, 360); NaN when no valid angle or the circular mean is undefined.
    """
    a = np.asarray(angle_deg, dtype=np.float64).ravel()
    a = a[np.isfinite(a)]
    if len(a) == 0:
        return float("nan")
    mean = circular_mean_deg(a)
    if not np.isfinite(mean):
        return float("nan")
    med = (mean + float(np.median(wrap_deg(a - mean)))) % 360.0
    return 0.0 if med >= 360.0 else float(med)
