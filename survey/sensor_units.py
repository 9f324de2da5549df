"""Sensor values in another unit than indoormap reads: a converted log's accelerometer in g,
magnetometer in gauss, nanotesla or tesla, gyroscope in deg/s.

Such a walk used to be processed: in gauss the bundle's field layers read 0.4-0.5 "uT"; in
deg/s every turn of the track was 57 times too sharp and every leg missed its waypoints
(blamed on the waypoints); in g no step was found ("no steps detected"). Each check here
compares a stream with what any phone reads (gravity, the Earth's field, the rotation
vector's own turns) and names the unit the values look like.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .steps import STANDARD_GRAVITY

#: Median magnitude (m/s^2) of a carried phone's accelerometer: gravity and the walk's swing
#: (ILC site1: 7.6-10.1; a simulated phone swinging in the hand, 14.2); in g or mg a walk
#: reads 1-1.5 or 1000-1500.
ACCELERATION_MEDIAN_MS2 = (4.0, 50.0)
#: Median strength (uT) of a calibrated magnetometer indoors (the Earth's 25-65 uT, bent by
#: the building); also :class:`survey.process.ProcessParams`' plausible calibrated field.
FIELD_MEDIAN_UT = (15.0, 120.0)
#: Other units (name, factor to uT or m/s^2) a log's values may be in, tried in turn.
ACCELERATION_UNITS = (("g (1 g = 9.81 m/s^2)", STANDARD_GRAVITY), ("mg or cm/s^2", 0.01))
FIELD_UNITS = (("gauss (1 G = 100 uT)", 100.0), ("nanotesla (1 nT = 0.001 uT)", 1e-3),
               ("tesla (1 T = 10^6 uT)", 1e6))
#: A gyroscope turning over this many times as far as the rotation vector (or less than its
#: inverse) is in another unit or broken; deg/s read as rad/s turn 57.3 times as far.
GYRO_TURN_RATIO_LIMIT = 10.0
#: Window (s) and least turn of the rotation vector (deg) in it over which turns are compared.
TURN_WINDOW_S, TURN_MIN_DEG = 2.0, 45.0


def _unit_hint(median: float, valid: tuple[float, float], units: tuple[tuple[str, float], ...]
               ) -> str:
    lo, hi = valid
    for name, factor in units:
        if lo <= median * factor <= hi:
            return f"in {name}?"
    return "in another unit?"


def acceleration_unit_problem(acc_xyz: NDArray[np.float64]) -> str | None:
    """Why an accelerometer's values (n, 3) are not m/s^2 a phone reads, or None: their
    median magnitude outside :data:`ACCELERATION_MEDIAN_MS2`, with the unit it looks like."""
    magnitude = np.linalg.norm(acc_xyz, axis=1)
    magnitude = magnitude[np.isfinite(magnitude)]
    if not len(magnitude):
        return None
    median = float(np.median(magnitude))
    lo, hi = ACCELERATION_MEDIAN_MS2
    if lo <= median <= hi:
        return None
    hint = _unit_hint(median, ACCELERATION_MEDIAN_MS2, ACCELERATION_UNITS)
    if median < lo:  # gravity taken out reads as small as g
        hint = hint[:-1] + ", or linear acceleration (without gravity)?"
    return (f"the accelerometer's median magnitude is {median:.3g}, where a phone reads "
            f"gravity, about 9.8 m/s^2: {hint} indoormap reads m/s^2 with gravity")


def field_unit_problem(strengths: dict[str, float]) -> str | None:
    """Why a walk's magnetometer is not in uT, or None: ``strengths`` maps each field it
    logs (calibrated, uncalibrated minus the phone's bias) to its median strength; when none
    is within :data:`FIELD_MEDIAN_UT` and all of them are in one other unit, that unit is
    named. A field out of range in no unit of :data:`FIELD_UNITS` is the calibration's to
    judge (:func:`survey.process.calibrated_field`), not a unit's."""
    lo, hi = FIELD_MEDIAN_UT
    medians = {k: v for k, v in strengths.items() if np.isfinite(v)}
    if not medians or any(lo <= v <= hi for v in medians.values()):
        return None
    for name, factor in FIELD_UNITS:
        if all(lo <= v * factor <= hi for v in medians.values()):
            shown = ", ".join(f"{k} {v:.3g}" for k, v in medians.items())
            return (f"the magnetometer's median strength is {shown}, where the Earth's field "
                    f"is 25-65 uT: in {name}? indoormap reads uT")
    return None


def gyro_turn_problem(rotation: tuple[NDArray, NDArray], gyro: tuple[NDArray, NDArray]
                      ) -> str | None:
    """Why a gyroscope's turns are not those of the rotation vector, or None.

    ``rotation`` and ``gyro`` are ``(t_ms, heading_deg)`` tracks (unwrapped) of the phone's
    turn about the vertical by its rotation vector
    (:func:`survey.process.rotation_vector_turn_deg`) and by its gyroscope. Over every
    :data:`TURN_WINDOW_S` window in which the rotation vector turns :data:`TURN_MIN_DEG` or
    more, the gyroscope's turn is compared with it; when the gyroscope turns over
    :data:`GYRO_TURN_RATIO_LIMIT` times as far in all (or less than its inverse), it is in
    another unit (deg/s read as rad/s: 57.3 times) or broken. A walk without such turns is
    not judged. (ILC site1: 0.50-1.14 on the 257 walks judged; simulated walks, swinging
    in the hand too, 0.93-1.02.)"""
    (tc, hc), (tg, hg) = rotation, gyro
    t0, t1 = max(tc[0], tg[0]), min(tc[-1], tg[-1])
    if not t1 - t0 > 2 * TURN_WINDOW_S * 1000:
        return None
    t = np.arange(t0, t1, 500.0)
    lag = int(round(TURN_WINDOW_S * 1000 / 500.0))
    c, g = np.interp(t, tc, hc), np.interp(t, tg, hg)
    dc, dg = np.abs(c[lag:] - c[:-lag]), np.abs(g[lag:] - g[:-lag])
    turns = dc >= TURN_MIN_DEG
    if turns.sum() < 3:
        return None
    ratio = float(dg[turns].sum() / dc[turns].sum())
    if 1 / GYRO_TURN_RATIO_LIMIT <= ratio <= GYRO_TURN_RATIO_LIMIT:
        return None
    hint = ("in deg/s? indoormap reads rad/s" if 30 <= ratio <= 110 else
            "in another unit, or broken?")
    return (f"the gyroscope turns {ratio:.3g} times as far as the rotation vector over the "
            f"walk's turns ({int(turns.sum())} windows of {TURN_WINDOW_S:g} s): {hint}")
