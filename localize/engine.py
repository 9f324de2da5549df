"""Many users' particle filters advanced together, vectorized across users.

A positioning provider runs one process per core; each tick it receives the steps users took
since the last tick and advances all their filters at once. The particles of all users of a
floor live in one array of shape ``(users, particles)`` (see
:class:`~localize.particles.ParticleState`), so a tick is the same few dozen numpy operations
whether it serves one user or ten thousand: the per-step cost per user falls with the batch
size instead of being dominated by interpreter overhead (paper 001 reports 130 users per core
for a single-user implementation).

Supports the mass-centered update, no magnetic update and the Gaussian update (the DTW update
compares per-user raw sequences and stays single-user). Radio fixes (a Wi-Fi or BLE position
per user, located by the caller, e.g. with the bundle's
:class:`~localize.fingerprint_positioner.FingerprintPositioner`) update and re-seed the users
that have one, as the single-user filter does with the default distance rule
(:meth:`MultiUserEngine.tick`).

Examples
--------
>>> eng = MultiUserEngine(bundle, FilterParams(n_particles=300), rng=1)   # doctest: +SKIP
>>> ids = eng.add_users([[10.0, 5.0], [30.0, 12.0]])                        # doctest: +SKIP
>>> x, y, spread = eng.tick(ids, StepInputs(...))                           # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import MapBundle
from localize.errors import LocalizationError
from localize.filter import make_rng
from localize.maps import FilterMap
from localize.params import FilterParams
from localize.particles import (ParticleState, estimate, init_state, inject_around_fix,
                                needed_layers)
from localize.stepper import StepInputs, StepOutputs, advance
from localize.update import position_update

__all__ = ["MultiUserEngine"]


class MultiUserEngine:
    """Particle filters of many users on one floor bundle.

    Parameters
    ----------
    bundle : MapBundle
        Floor bundle all users are on (run one engine per floor).
    params : FilterParams, optional
        Shared by all users; ``weight_mode`` must not be ``"dtw"``.
    rng : numpy.random.Generator or int, optional
    dtype : numpy dtype
        Particle storage (float32 halves memory per user).
    """

    def __init__(self, bundle: MapBundle, params: FilterParams | None = None, *,
                 rng: np.random.Generator | int | None = None, dtype=np.float64,
                 fmap: FilterMap | None = None) -> None:
        self.params = params or FilterParams()
        if self.params.weight_mode == "dtw":
            raise LocalizationError("the multi-user engine does not run the DTW update")
        self.bundle = bundle
        self.rng = make_rng(rng)
        self.dtype = dtype
        if fmap is None:
            layers, stds = needed_layers(self.params)
            fmap = FilterMap(bundle, layers, stds)
        self.fmap = fmap
        self.state: ParticleState | None = None
        self.user_ids = np.empty(0, dtype=np.int64)   # row -> user id
        self.last_xy = np.empty((0, 2))
        self.consecutive = np.empty(0, dtype=np.int64)
        self.n_recoveries = np.empty(0, dtype=np.int64)
        self._next_id = 0

    # -- users ----------------------------------------------------------------------------
    @property
    def n_users(self) -> int:
        return len(self.user_ids)

    def add_users(self, start_xy: ArrayLike, half_width_m: ArrayLike | None = None
                  ) -> NDArray[np.int64]:
        """Start filters for new users around their start positions; returns their ids."""
        xy = np.asarray(start_xy, dtype=np.float64).reshape(-1, 2)
        k = len(xy)
        hw = np.broadcast_to(self.params.init_half_width_m if half_width_m is None
                             else np.asarray(half_width_m, dtype=np.float64), (k,))
        new = init_state(self.fmap, self.params, self.rng, xy, hw, dtype=self.dtype)
        ids = np.arange(self._next_id, self._next_id + k, dtype=np.int64)
        self._next_id += k
        if self.state is None:
            self.state = new
        else:
            self.state.data = np.concatenate([self.state.data, new.data], axis=1)
            for name in self.state.obs:
                self.state.obs[name] = np.concatenate([self.state.obs[name], new.obs[name]],
                                                      axis=1)
        mx, my, _ = estimate(new)
        self.user_ids = np.concatenate([self.user_ids, ids])
        self.last_xy = np.concatenate([self.last_xy, np.column_stack([mx, my])])
        self.consecutive = np.concatenate([self.consecutive, np.zeros(k, dtype=np.int64)])
        self.n_recoveries = np.concatenate([self.n_recoveries, np.zeros(k, dtype=np.int64)])
        return ids

    def remove_users(self, ids: ArrayLike) -> None:
        """Drop users (their filters are freed)."""
        keep = ~np.isin(self.user_ids, np.asarray(ids))
        if self.state is not None:
            self.state.data = self.state.data[:, keep]
            for name in self.state.obs:
                self.state.obs[name] = self.state.obs[name][:, keep]
        self.user_ids = self.user_ids[keep]
        self.last_xy = self.last_xy[keep]
        self.consecutive = self.consecutive[keep]
        self.n_recoveries = self.n_recoveries[keep]

    def rows_of(self, ids: ArrayLike) -> NDArray[np.intp]:
        """Rows of user ids (raises for unknown ids)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        order = np.argsort(self.user_ids)
        pos = np.searchsorted(self.user_ids, ids, sorter=order)
        pos = np.minimum(pos, len(order) - 1) if len(order) else pos
        rows = order[pos] if len(order) else pos
        if len(order) == 0 or not np.array_equal(self.user_ids[rows], ids):
            raise LocalizationError("unknown user id in tick")
        return rows

    @property
    def bytes_per_user(self) -> float:
        """Memory of the particle state per user (bytes)."""
        if self.state is None or self.n_users == 0:
            return 0.0
        return self.state.nbytes / self.n_users

    # -- ticks ----------------------------------------------------------------------------
    def tick(self, ids: ArrayLike | None, inputs: StepInputs,
             fix_xy_m: ArrayLike | None = None, fix_sigma_m: ArrayLike | None = None
             ) -> StepOutputs:
        """Advance the users ``ids`` (all users when None) by one step each.

        Parameters
        ----------
        ids : array_like of int (k,) or None
            Users that took a step since the last tick.
        inputs : StepInputs
            Their step summaries, arrays of shape (k,) in the order of ``ids``.
        fix_xy_m : array_like (k, 2), optional
            Their radio fixes at this step (m, map frame; NaN rows: no fix), e.g. the
            ``xy_m`` of :meth:`FingerprintPositioner.locate_scans
            <localize.fingerprint_positioner.FingerprintPositioner.locate_scans>` over one
            scan or None per user. A user with one has its weights multiplied by a Gaussian
            around it (SD ``max(fix_sigma_m, radio_sigma_floor_m)``, mixed with a uniform share
            ``radio_outlier``) when ``params.radio_update``, and, when the fix is
            ``radio_inject_distance_m`` or more from its last estimate, a share
            ``radio_inject_fraction`` of its particles re-drawn around it: the single-user
            filter's update with a radio model that only locates (its ``"fit"`` rule and
            ``radio_guide="align"`` are single-user).
        fix_sigma_m : array_like (k,), optional
            The fixes' accuracy (m; NaN or absent: ``radio_sigma_floor_m``).

        Returns
        -------
        StepOutputs
            Estimates of those users, shape (k,).
        """
        if self.state is None:
            raise LocalizationError("no users")
        if ids is not None:
            ids = np.asarray(ids, dtype=np.int64).ravel()
            if len(np.unique(ids)) != len(ids):
                raise LocalizationError("a user id appears twice in one tick")
        users = self.user_ids if ids is None else ids
        check_tick_inputs(inputs, users)
        fixes = None if fix_xy_m is None else checked_tick_fixes(fix_xy_m, fix_sigma_m, len(users),
                                                            self.params.radio_sigma_floor_m)
        rows = slice(None) if ids is None else self.rows_of(ids)
        last = self.last_xy[rows]
        extra = None if fixes is None else (lambda st: self._fix_update(st, *fixes, last))
        if ids is None:
            out = advance(self.state, self.fmap, self.params, self.rng, inputs, last,
                          self.consecutive, extra_update=extra)
        else:
            sub = self.state.subset(rows)
            cons = self.consecutive[rows]
            out = advance(sub, self.fmap, self.params, self.rng, inputs, last, cons,
                          extra_update=extra)
            self.state.put(rows, sub)
            self.consecutive[rows] = cons
        self.last_xy[rows] = np.column_stack([out.x_m, out.y_m])
        self.n_recoveries[rows] += out.recovered
        return out

    def _fix_update(self, st: ParticleState, fix_xy: NDArray[np.float64],
                    sigma: NDArray[np.float64], last_xy: NDArray[np.float64]) -> None:
        """The radio update of :meth:`tick` on the tick's rows ``st``: fixes (k, 2) (m; NaN:
        none), their SDs (k,) (m) and the rows' last estimates (k, 2)."""
        p = self.params
        rows = np.flatnonzero(np.isfinite(fix_xy).all(axis=1))
        if rows.size == 0:
            return
        fx, fy = fix_xy[:, 0], fix_xy[:, 1]
        if p.radio_update:  # one vectorized update over every user with a fix
            position_update(st, rows, fx[rows, None], fy[rows, None], sigma[rows, None],
                            p.radio_outlier)
        if p.radio_inject_fraction > 0:  # rare (far fixes): one user at a time
            far = rows[np.hypot(fx[rows] - last_xy[rows, 0], fy[rows] - last_xy[rows, 1])
                       >= p.radio_inject_distance_m]
            for r in far:
                inject_around_fix(st, self.fmap, p, self.rng, int(r), p.radio_inject_fraction,
                                  (fx[r], fy[r]), sigma[r])


def checked_tick_fixes(fix_xy_m: ArrayLike, fix_sigma_m: ArrayLike | None, k: int,
                   floor_m: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fixes as (k, 2) and their SDs as (k,) (NaN or absent: ``floor_m``; raised to it), or a
    LocalizationError before anyone moves."""
    xy = np.asarray(fix_xy_m, dtype=np.float64)
    if xy.shape == (2,) and k == 1:
        xy = xy.reshape(1, 2)
    if xy.shape != (k, 2):
        raise LocalizationError(f"fix_xy_m has shape {xy.shape}, expected ({k}, 2): one fix "
                                "(or a NaN row) per user")
    sigma = np.full(k, np.nan) if fix_sigma_m is None else \
        np.asarray(fix_sigma_m, dtype=np.float64).reshape(-1)
    if sigma.shape != (k,):
        raise LocalizationError(f"fix_sigma_m has {sigma.size} values, expected {k}: one per "
                                "user")
    return xy, np.fmax(sigma, floor_m)  # NaN: the floor


def check_tick_inputs(inputs: StepInputs, ids: NDArray[np.int64]) -> None:
    """Every array of ``inputs`` one value per user of ``ids``, and a finite compass heading
    for each: checked before any state moves, so that one bad user cannot leave the others
    half advanced."""
    shapes = [(len(ids),)] + ([()] if len(ids) == 1 else [])  # one user: scalars too
    for f in fields(inputs):
        values = getattr(inputs, f.name)
        if values is not None and np.shape(values) not in shapes:
            raise LocalizationError(f"tick input {f.name} has shape {np.shape(values)}, "
                                    f"expected ({len(ids)},): one value per user")
    bad = ~np.isfinite(np.asarray(inputs.compass_deg, dtype=float).reshape(-1))
    if bad.any():
        raise LocalizationError(f"users {ids[bad][:10].tolist()}: no compass heading "
                                "(NaN or infinite compass_deg); nobody was advanced")
