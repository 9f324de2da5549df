"""One filter step for ``u`` users at once: move, observe, weigh, recover, resample, estimate.

Shared by the single-user :class:`~localize.filter.Localizer` (``u = 1``) and the multi-user
:class:`~localize.engine.MultiUserEngine`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localize.maps import FilterMap
from localize.params import FilterParams
from localize.particles import (
    ParticleState,
    estimate,
    estimate_mode,
    move,
    observe,
    reinit_rows,
    resample,
)
from localize.resample import effective_sample_size
from localize.steps import AttitudeCode
from localize.update import magnetic_update, normalise_rows

__all__ = ["StepInputs", "StepOutputs", "advance"]


@dataclass(frozen=True)
class StepInputs:
    """One step of ``u`` users; every array has shape (u,).

    Attributes
    ----------
    compass_deg, frequency_hz, turn_deg : ndarray
        Compass heading (deg), step frequency (Hz, NaN = nominal), turn over the step (deg).
    strength_ut, azimuth_deg, polar_deg : ndarray
        Observed field features of the step (NaN = not measured).
    attitude : ndarray of int
        :class:`~localize.steps.AttitudeCode` per user.
    relative_heading_deg : ndarray, optional
        Gyroscope heading (deg, arbitrary origin; NaN = none), for the deviation feature.
    delta_acc_ms2 : ndarray, optional
        Acceleration swing of the step (m/s^2), for the Weinberg step model.
    """

    compass_deg: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]
    turn_deg: NDArray[np.float64]
    strength_ut: NDArray[np.float64]
    azimuth_deg: NDArray[np.float64]
    polar_deg: NDArray[np.float64]
    attitude: NDArray[np.integer]
    relative_heading_deg: NDArray[np.float64] | None = None
    delta_acc_ms2: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class StepOutputs:
    """Estimates after the step, shape (u,) each (m; alive share; recovered flag)."""

    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    spread_m: NDArray[np.float64]
    alive_fraction: NDArray[np.float64]
    recovered: NDArray[np.bool_]


def advance(st: ParticleState, fmap: FilterMap, params: FilterParams, rng: np.random.Generator,
            inp: StepInputs, last_xy: NDArray[np.float64], consecutive: NDArray[np.int64], *,
            raw_strength_ut: NDArray[np.float64] | None = None,
            extra_update: Callable[[ParticleState], None] | None = None) -> StepOutputs:
    """Advance every user row of ``st`` by one step.

    Parameters
    ----------
    st : ParticleState
        Modified in place.
    last_xy : ndarray (u, 2)
        Last estimates: the centres of a recovery when all of a user's particles died.
    consecutive : ndarray of int (u,)
        Consecutive recoveries per user (updated in place); the recovery square doubles with
        each.
    raw_strength_ut : ndarray, optional
        Raw magnetometer strengths of the step (DTW mode, single user).
    extra_update : callable(ParticleState), optional
        Further weight update (e.g. radio) applied before recovery and resampling.
    """
    p = params
    carried = np.asarray(inp.attitude) == int(AttitudeCode.CARRIED)
    ok = move(st, fmap, p, rng, inp.compass_deg, inp.frequency_hz, inp.turn_deg,
              inp.delta_acc_ms2, compass_axis=carried)
    ufh = np.asarray(inp.attitude) == int(AttitudeCode.UFH)
    obs = {"strength": np.asarray(inp.strength_ut, dtype=np.float64),
           "azimuth": np.where(ufh, inp.azimuth_deg, np.nan),
           "polar": np.where(ufh, inp.polar_deg, np.nan)}
    if inp.relative_heading_deg is not None:
        obs["deviation"] = np.where(carried, np.nan, np.asarray(inp.compass_deg)
                                    - np.asarray(inp.relative_heading_deg))
    observe(st, fmap, p, obs)
    magnetic_update(st, fmap, p, inp.attitude, raw_strength_ut)
    if extra_update is not None:
        extra_update(st)
    w = st.w
    dead = ~np.any(w > 0, axis=1)
    if dead.any():
        rows = np.flatnonzero(dead)
        hw = np.minimum(p.recovery_half_width_m * 2.0 ** consecutive[rows],
                        p.recovery_max_half_width_m)
        reinit_rows(st, fmap, p, rng, rows, last_xy[rows], hw)
    consecutive[dead] += 1
    consecutive[~dead] = 0
    st.w = normalise_rows(st.w)
    uniform = False
    if p.weight_mode in ("mass_centered", "none"):
        resample(st, rng)
        uniform = True
    else:
        low = effective_sample_size(st.w) < p.neff_fraction * st.shape[1]
        if low.all():
            resample(st, rng)
            uniform = True
        elif low.any():
            resample(st, rng, rows=low)
    mx, my, spread = estimate(st, uniform=uniform)
    wide = spread > p.mode_spread_m
    if wide.any():
        ox, oy = estimate_mode(st)
        mx, my = np.where(wide, ox, mx), np.where(wide, oy, my)
    return StepOutputs(mx, my, spread, ok.mean(axis=1), dead)
