"""Many users' real-time walk alignments on one floor, served by one object per process.

The counterpart of :class:`~localize.engine.MultiUserEngine` for floors where ``--method
auto`` runs the walk alignment (:func:`localize.methods.auto_method`: the floor's magnetic
map does not predict walks it did not see, as on the real mall traces). Each user keeps one
:class:`~localize.align.WalkAligner` (its last ``window_s`` of steps and fixes; the older ones
are forgotten, so a user's memory stays bounded however long they walk) and a tick advances
the users that stepped, one after the other: the alignment searches transforms per user and
does not batch across users as the particle filters do. Expect about 1 ms of CPU per user
step (``benchmarks/localize_speed.py``), i.e. several hundred users per core at a step every
0.67 s, against thousands for the filter. On floors where ``auto`` runs the filter guided
by the alignment, :class:`~localize.engine.MultiUserEngine` with
``FilterParams(radio_guide="align")`` keeps one of these for its users.

Examples
--------
>>> eng = MultiUserAligner(bundle)                                            # doctest: +SKIP
>>> ids = eng.add_users([[10.0, 5.0]], t_ms=[t0], sigma_m=[3.0])              # doctest: +SKIP
>>> out = eng.tick(ids, [t0 + 600.0], StepInputs(...), fix_xy_m=[[11.0, 6.0]])  # doctest: +SKIP
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.align import AlignParams, WalkAligner
from localize.bundle import MapBundle
from localize.errors import LocalizationError
from localize.filter import BUNDLE_HINT
from localize.steps import AttitudeCode
from localize.stepper import StepInputs, StepOutputs
from localize.ticks import (check_tick_inputs, check_user_step_times, checked_fix_times,
                            checked_tick_fixes, per_user, start_points, tick_ids,
                            unknown_ids_error)
from survey.errors import require_type

__all__ = ["MultiUserAligner"]


class MultiUserAligner:
    """Real-time walk alignments of many users on one floor bundle.

    Parameters
    ----------
    bundle : MapBundle
        Floor bundle all users are on (run one per floor).
    params : AlignParams, optional
        Shared by all users.
    """

    def __init__(self, bundle: MapBundle, params: AlignParams | None = None) -> None:
        require_type(bundle, MapBundle, "MultiUserAligner(bundle)", BUNDLE_HINT)
        self.bundle = bundle
        self.params = params or AlignParams()
        self._aligners: dict[int, WalkAligner] = {}
        self._next_id = 0

    @property
    def n_users(self) -> int:
        return len(self._aligners)

    @property
    def user_ids(self) -> NDArray[np.int64]:
        """The users' ids, in the order they were added."""
        return np.fromiter(self._aligners, dtype=np.int64, count=len(self._aligners))

    def add_users(self, start_xy: ArrayLike, t_ms: ArrayLike,
                  sigma_m: ArrayLike | None = None) -> NDArray[np.int64]:
        """Start alignments for new users; returns their ids.

        Parameters
        ----------
        start_xy : array_like (k, 2)
            Start positions (m, map frame): radio fixes, or known positions.
        t_ms : array_like (k,)
            Their times (Unix ms): a fix's scan time.
        sigma_m : array_like (k,), optional
            Finite (a fix's accuracy, m, not negative): the start is the first of the user's
            fixes, weighed by the fixes' error model (``AlignParams.fix_*``), not by this
            value. NaN or absent: a known position (``AlignParams.start_sd_m``).
        """
        xy = start_points(start_xy)
        k = len(xy)
        t = per_user(t_ms, k, "t_ms")
        sigma = np.full(k, np.nan) if sigma_m is None else per_user(sigma_m, k, "sigma_m")
        if not np.isfinite(t).all():
            raise LocalizationError("add_users: a start time is not finite (t_ms)")
        if (sigma < 0).any():
            raise LocalizationError("add_users: a fix's accuracy sigma_m is negative")
        new = []
        for (x, y), t0, s in zip(xy, t, sigma):
            aligner = WalkAligner(self.bundle, self.params)
            aligner.begin(*aligner._checked_start((x, y)), float(t0),
                          float(s) if np.isfinite(s) else None)
            new.append(aligner)  # every start checked before anyone is added
        ids = np.arange(self._next_id, self._next_id + k, dtype=np.int64)
        self._next_id += k
        self._aligners.update(zip(ids.tolist(), new))
        return ids

    def remove_users(self, ids: ArrayLike) -> None:
        """Drop users (their alignments are freed); a LocalizationError for an id that is
        no whole number or no user of this server (a user removed twice), before any is
        removed (unknown ids were ignored, and 1.7 removed user 1)."""
        ids = tick_ids(ids, "remove_users").tolist()
        unknown = [i for i in ids if i not in self._aligners]
        if unknown:
            raise unknown_ids_error(unknown, "remove_users")
        for i in ids:
            del self._aligners[i]

    def tick(self, ids: ArrayLike | None, t_ms: ArrayLike, inputs: StepInputs,
             fix_xy_m: ArrayLike | None = None, fix_t_ms: ArrayLike | None = None
             ) -> StepOutputs:
        """Advance the users ``ids`` by one step each.

        Parameters
        ----------
        ids : array_like of int (k,) or None
            Users that took a step since the last tick (None: every user, in the order of
            :attr:`user_ids`).
        t_ms : array_like (k,)
            The steps' times (Unix ms), after each user's last step.
        inputs : StepInputs
            Their step summaries, arrays of shape (k,) in the order of ``ids``: the compass
            and gyroscope headings (``relative_heading_deg``; NaN: the compass alone), the
            acceleration swing (``delta_acc_ms2``; NaN: the nominal step) and the attitude.
        fix_xy_m : array_like (k, 2), optional
            Their radio fixes at this step (m, map frame; NaN rows: none).
        fix_t_ms : array_like (k,), optional
            The fixes' scan times (Unix ms; NaN or absent: the step's time).

        Returns
        -------
        StepOutputs
            Estimates of those users, shape (k,): the end of each one's aligned track and the
            spread of its shift (m); ``alive_fraction`` 1 and ``recovered`` False.
        """
        ids = self.user_ids if ids is None else tick_ids(ids)
        unknown = [i for i in ids.tolist() if i not in self._aligners]
        if unknown:
            raise unknown_ids_error(unknown)
        k = len(ids)
        check_tick_inputs(inputs, ids)
        t = per_user(t_ms, k, "t_ms")
        users = self.aligners_of(ids)
        check_user_step_times(step_time_problems(users, t, ids))
        fix_xy = (None if fix_xy_m is None else
                  checked_tick_fixes(fix_xy_m, None, k, 0.0, self.bundle.grid, ids)[0])
        fix_t = None if fix_t_ms is None else checked_fix_times(
            fix_t_ms, t, ids, None if fix_xy is None else np.isfinite(fix_xy).all(axis=1))
        return advance_aligners(users, t, step_columns(inputs, k), fix_xy, fix_t)

    def aligners_of(self, ids: NDArray[np.int64]) -> list[WalkAligner]:
        """The users' aligners, in the order of ``ids`` (known ids)."""
        return [self._aligners[i] for i in ids.tolist()]


def step_columns(inputs: StepInputs, k: int) -> tuple[NDArray, ...]:
    """What a step gives an alignment, per user (k,): compass and gyroscope headings (deg;
    gyroscope NaN: the compass alone), acceleration swing (m/s^2; NaN: the nominal step) and
    whether the phone is carried."""
    compass, gyro, swing = (np.broadcast_to(np.asarray(v, dtype=np.float64), (k,)) for v in (
        inputs.compass_deg,
        np.nan if inputs.relative_heading_deg is None else inputs.relative_heading_deg,
        np.nan if inputs.delta_acc_ms2 is None else inputs.delta_acc_ms2))
    carried = np.broadcast_to(np.asarray(inputs.attitude) == AttitudeCode.CARRIED, (k,))
    return compass, gyro, swing, carried


def step_time_problems(aligners: list[WalkAligner], t_ms: NDArray, names: NDArray
                       ) -> list[tuple[int, str]]:
    """``(name, why)`` of each step time (k,) its aligner cannot take next (``names``: the
    ids the caller knows the users by), checked before anyone moves."""
    problems = []
    for name, aligner, t in zip(names.tolist(), aligners, t_ms):
        try:
            aligner.check_next(t)
        except LocalizationError as err:
            problems.append((name, str(err)))
    return problems


def advance_aligners(aligners: list[WalkAligner], t_ms: NDArray, columns: tuple[NDArray, ...],
                     fix_xy: NDArray | None, fix_t_ms: NDArray | None, *,
                     search_spread: bool = False) -> StepOutputs:
    """One step of each aligner (inputs checked with the tick, before anyone moves:
    :func:`check_tick_inputs`, :func:`step_time_problems`, :func:`checked_tick_fixes`, so not
    again per user): its time (Unix ms), its :func:`step_columns`, its fix (k, 2) (m; NaN
    rows or None: none) and the fix's scan time (NaN or None: the step's). ``spread_m`` is
    the estimates' (or with ``search_spread`` the search's finest grid's,
    :attr:`WalkAligner.search_spread_m`, what a guided filter weighs with)."""
    k = len(aligners)
    fix_t = t_ms if fix_t_ms is None else np.where(np.isfinite(fix_t_ms), fix_t_ms, t_ms)
    has_fix = np.zeros(k, bool) if fix_xy is None else np.isfinite(fix_xy).all(axis=1)
    compass, gyro, swing, carried = columns
    out = np.empty((k, 3))
    for r, aligner in enumerate(aligners):
        fix = (float(fix_t[r]), (float(fix_xy[r, 0]), float(fix_xy[r, 1]))) \
            if has_fix[r] else None
        est = aligner._advance(t_ms[r], compass[r], gyro[r], swing[r], bool(carried[r]), fix)
        out[r] = est.x_m, est.y_m, aligner.search_spread_m if search_spread else est.spread_m
    return StepOutputs(out[:, 0], out[:, 1], out[:, 2], np.ones(k), np.zeros(k, bool))
