"""A tick's inputs for the multi-user servers (:class:`~localize.engine.MultiUserEngine`,
:class:`~localize.align_engine.MultiUserAligner`): checked before any user moves, so that one
bad user cannot leave the others half advanced."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import Grid
from localize.errors import LocalizationError, TickRefused
from localize.filter import MAX_START_OFF_MAP_M, step_time_problem, within_reach
from localize.stepper import StepInputs
from localize.steps import MAX_FIX_AFTER_STEP_MS, fix_time_problem

__all__ = ["check_tick_inputs", "check_user_step_times", "checked_fix_times",
           "checked_tick_fixes", "later_than", "per_user", "start_points", "tick_ids",
           "unknown_ids_error"]


def tick_ids(ids: ArrayLike, what: str = "tick") -> NDArray[np.int64]:
    """The users of a tick (or of another call, ``what``: ``"remove_users"``) as int64 ids
    (k,); a LocalizationError when one is not a whole number (1.7 was taken as user 1) or
    appears twice."""
    raw = np.asarray(ids)
    whole = raw.dtype.kind in "iu" or raw.dtype.kind == "f" and bool(
        np.all(np.isfinite(raw)) and np.all(raw == np.round(raw))
        and np.all(np.abs(raw) < 2.0 ** 62))
    nobody = _nobody(what)
    if not whole:
        raise LocalizationError(f"user ids must be whole numbers (the ids add_users gave), "
                                f"got {raw.ravel()[:5].tolist()}; {nobody}")
    ids = raw.astype(np.int64).ravel()
    if len(np.unique(ids)) != len(ids):
        raise LocalizationError(f"a user id appears twice in one {what}; {nobody}")
    return ids


def _nobody(what: str) -> str:
    return "nobody was advanced" if what == "tick" else "nobody was removed"


def unknown_ids_error(unknown: list[int], what: str = "tick") -> LocalizationError:
    """The error for ids given to a tick (a :class:`TickRefused` naming them) or to another
    call (``what``: ``"remove_users"``) that are no user of the server."""
    message = f"unknown user ids in {what}: {unknown[:10]}; {_nobody(what)}"
    return TickRefused(message, unknown) if what == "tick" else LocalizationError(message)


def checked_tick_fixes(fix_xy_m: ArrayLike, fix_sigma_m: ArrayLike | None, k: int,
                       floor_m: float, grid: Grid, ids: NDArray[np.int64]
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fixes as (k, 2) and their SDs as (k,) (NaN or absent: ``floor_m``; raised to it), or a
    LocalizationError before anyone moves; copies (the engines write into them).

    A row is a fix (two finite numbers within
    :data:`~localize.filter.MAX_START_OFF_MAP_M` of the floor's ``grid``, as a start) or
    NaN, NaN (none); anything else names the users of ``ids`` it came from: a fix in other
    units or for another floor would drag their tracks off the map."""
    xy = _floats(fix_xy_m, "fix_xy_m")
    if xy.shape == (2,) and k == 1:
        xy = xy.reshape(1, 2)
    if xy.shape != (k, 2):
        raise LocalizationError(f"fix_xy_m has shape {xy.shape}, expected ({k}, 2): one fix "
                                "(or a NaN row) per user")
    none = np.isnan(xy).all(axis=1)
    bad = ~none & ~within_reach(grid, xy[:, 0], xy[:, 1])
    if bad.any():
        raise TickRefused(
            f"users {ids[bad][:10].tolist()}: fix_xy_m {xy[bad][0].tolist()} is not two "
            f"finite numbers within {MAX_START_OFF_MAP_M:g} m of the floor's map (NaN, NaN "
            "for no fix; wrong floor or units?); nobody was advanced", ids[bad])
    sigma = (np.full(k, np.nan) if fix_sigma_m is None else
             _floats(fix_sigma_m, "fix_sigma_m").reshape(-1))
    if sigma.shape != (k,):
        raise LocalizationError(f"fix_sigma_m has {sigma.size} values, expected {k}: one per "
                                "user")
    return xy, np.fmax(sigma, floor_m)  # NaN: the floor


def _floats(values: ArrayLike, name: str, nobody: str = "nobody was advanced"
            ) -> NDArray[np.float64]:
    """``values`` as a new float64 array; a LocalizationError naming ``name`` (and ending
    with ``nobody``) for text, bools or objects, which numpy would convert ("10" to 10)."""
    try:
        kind = np.asarray(values).dtype.kind
    except (TypeError, ValueError) as err:  # ragged lists
        raise LocalizationError(f"{name} is not numeric ({err}); {nobody}") from err
    if kind not in "iuf":
        raise LocalizationError(f"{name} is not numeric (numpy dtype kind {kind!r}); {nobody}")
    return np.array(values, dtype=np.float64)


def check_tick_inputs(inputs: StepInputs, ids: NDArray[np.int64]) -> None:
    """Every array of ``inputs`` numbers, one per user of ``ids`` (a scalar for one user),
    and a finite compass heading for each; else a LocalizationError."""
    shapes = [(len(ids),)] + ([()] if len(ids) == 1 else [])  # one user: scalars too
    for f in fields(inputs):
        values = getattr(inputs, f.name)
        if values is None:
            continue
        if np.shape(values) not in shapes:
            raise LocalizationError(f"tick input {f.name} has shape {np.shape(values)}, "
                                    f"expected ({len(ids)},): one value per user")
        dtype = np.asarray(values).dtype
        if dtype.kind not in "biuf":  # text ("1.8") or objects: numpy would convert some
            raise LocalizationError(f"tick input {f.name} is not numeric (dtype {dtype}); "
                                    "nobody was advanced")
    bad = ~np.isfinite(np.asarray(inputs.compass_deg, dtype=float).reshape(-1))
    if bad.any():
        raise TickRefused(f"users {ids[bad][:10].tolist()}: no compass heading (NaN or "
                          "infinite compass_deg); nobody was advanced", ids[bad])


def start_points(start_xy: ArrayLike) -> NDArray[np.float64]:
    """New users' start positions as (k, 2) floats (m); one point ``(x, y)`` is one user. A
    LocalizationError for text, or a shape that is not pairs (``[10, 5, 3]``)."""
    xy = _floats(start_xy, "start_xy", "nobody was added")
    if xy.shape == (2,):
        xy = xy.reshape(1, 2)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise LocalizationError(f"start_xy has shape {xy.shape}, expected (k, 2): an (x, y) "
                                "pair (m) per new user; nobody was added")
    return xy


def checked_fix_times(fix_t_ms: ArrayLike, t_ms: NDArray[np.float64], users: NDArray[np.int64],
                      has_fix: NDArray[np.bool_] | None) -> NDArray[np.float64]:
    """A tick's scan times of its fixes, one per user (k,) (NaN: the step's own), or a
    LocalizationError naming every user with a fix (``has_fix``, (k,); None: none has one)
    stamped at no Unix time or more than :data:`~localize.steps.MAX_FIX_AFTER_STEP_MS` after
    its step (``t_ms``, (k,)): a fix dated an hour ahead was held by the alignment for the
    rest of the walk. The times of users without a fix are not read (0 or a stale time is a
    server's "none")."""
    fix_t = per_user(fix_t_ms, len(users), "fix_t_ms")
    if has_fix is None:
        return fix_t
    suspect = has_fix & ~np.isnan(fix_t) & ~((fix_t > 0)
                                             & (fix_t <= t_ms + MAX_FIX_AFTER_STEP_MS))
    bad = [(int(u), fix_time_problem(f, t, zero_is_none=False))
           for u, f, t in zip(users[suspect].tolist(), fix_t[suspect].tolist(),
                              t_ms[suspect].tolist())]
    if bad:
        raise TickRefused(f"users {[u for u, _ in bad][:10]}: fix_t_ms: the first's fix "
                          f"{bad[0][1]}; nobody was advanced", [u for u, _ in bad])
    return fix_t


def later_than(t_ms: NDArray[np.float64], last_t_ms: NDArray[np.float64],
               stepped: NDArray[np.bool_], users: NDArray[np.int64]) -> list[tuple[int, str]]:
    """``(user, why)`` for each step time of ``t_ms`` (k,) that is not a finite time after
    the user's last step (``last_t_ms``, NaN: none known; a first step, ``stepped`` False,
    may come at the start's time, as the single-user localizers take it): a step sent twice
    (a network retry) was walked twice by an engine that took the times and ignored them."""
    bad = ~np.isfinite(t_ms) | (t_ms < last_t_ms) | (stepped & (t_ms == last_t_ms))
    return [(u, step_time_problem(t, last, after_step=after))
            for u, t, last, after in zip(users[bad].tolist(), t_ms[bad].tolist(),
                                         last_t_ms[bad].tolist(), stepped[bad].tolist())]


def check_user_step_times(problems: list[tuple[int, str]]) -> None:
    """A :class:`TickRefused` naming every user of ``problems`` (``(user id, why their
    step's time cannot be taken)``; the message shows the first), none raised without
    one."""
    if problems:
        shown = "" if len(problems) == 1 else f" (and {len(problems) - 1} more user(s))"
        raise TickRefused(f"user {problems[0][0]}: {problems[0][1]}{shown}; nobody was "
                          "advanced", [u for u, _ in problems])


def per_user(values: ArrayLike, k: int, name: str) -> NDArray[np.float64]:
    """``values`` as one float per user, shape (k,) (a scalar is every user's); else a
    LocalizationError naming the argument ``name``."""
    arr = _floats(values, name, "nobody was added or advanced")
    if arr.shape not in ((), (k,)):
        raise LocalizationError(f"{name} has shape {arr.shape}, expected ({k},): one value "
                                "per user")
    return np.broadcast_to(arr, (k,))
