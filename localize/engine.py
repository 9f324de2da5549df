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
(:meth:`MultiUserEngine.tick`). With ``FilterParams(radio_guide="align")`` (what ``--method
auto`` runs on a floor whose magnetic map predicts walks it did not see) the users started
from a radio fix take their radio evidence from a walk alignment instead, one per user
(:class:`~localize.align_engine.MultiUserAligner`), as the single-user guided filter does.

Examples
--------
>>> eng = MultiUserEngine(bundle, FilterParams(n_particles=300), rng=1)   # doctest: +SKIP
>>> ids = eng.add_users([[10.0, 5.0], [30.0, 12.0]])                        # doctest: +SKIP
>>> x, y, spread = eng.tick(ids, StepInputs(...))                           # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.align_engine import (MultiUserAligner, advance_aligners, step_time_problems,
                                   step_columns)
from localize.bundle import MapBundle
from localize.errors import LocalizationError
from localize.filter import BUNDLE_HINT, make_rng
from localize.maps import FilterMap
from localize.params import FilterParams
from localize.particles import (ParticleState, estimate, init_state, inject_around_fix,
                                inject_around_guide, needed_layers, start_half_width_m)
from localize.stepper import StepInputs, StepOutputs, advance
from localize.ticks import (check_tick_inputs, check_user_step_times, checked_fix_times,
                            checked_tick_fixes, later_than, per_user, start_points, tick_ids,
                            unknown_ids_error)
from localize.update import position_update
from survey.errors import require_type

__all__ = ["MultiUserEngine"]

#: Largest map coordinate (m) float32 particles are allowed: float32's spacing there is 2 mm
#: (at a UTM easting of 500 km it is 3 cm, at a northing of 4,000 km 25 cm).
FLOAT32_REACH_M = 16_384.0


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
        Particle storage (float32 halves memory per user; refused for a map whose
        coordinates reach beyond :data:`FLOAT32_REACH_M`, a plan in UTM say).

    With ``params.radio_guide == "align"`` (and a radio update or injection on), users added
    with ``fix_sigma_m`` (started from a radio fix) are guided: a walk alignment of their
    steps and fixes (:attr:`guide`) gives, at every step, the position their particles are
    weighted towards (a Gaussian of ``max(its spread, guide_sigma_m)``) and re-drawn around
    when it is ``guide_inject_distance_m`` or more from their estimate; the single-user
    :class:`~localize.filter.Localizer`'s guided filter, per user. Their ticks need the
    steps' times. Users started at a known position use their fixes themselves.
    """

    def __init__(self, bundle: MapBundle, params: FilterParams | Mapping | None = None, *,
                 rng: np.random.Generator | int | None = None, dtype=np.float64,
                 fmap: FilterMap | None = None) -> None:
        require_type(bundle, MapBundle, "MultiUserEngine(bundle)", BUNDLE_HINT)
        self.params = FilterParams.coerce(params, "MultiUserEngine(params)")
        if self.params.weight_mode == "dtw":
            raise LocalizationError("the multi-user engine does not run the DTW update")
        self.bundle = bundle
        self.rng = make_rng(rng)
        g = bundle.grid
        reach_m = max(abs(g.x0_m), abs(g.y0_m), abs(g.x1_m), abs(g.y1_m))
        if np.dtype(dtype).itemsize < 8 and reach_m > FLOAT32_REACH_M:
            raise LocalizationError(
                f"the map's coordinates reach {reach_m:,.0f} m, where {np.dtype(dtype).name} "
                f"particles would move in steps of {np.spacing(np.float32(reach_m)):g} m; "
                f"use float64 (float32 keeps centimetres within {FLOAT32_REACH_M:,.0f} m of "
                "the origin)")
        self.dtype = dtype
        if fmap is None:
            layers, stds = needed_layers(self.params)
            fmap = FilterMap(bundle, layers, stds)
        self.fmap = fmap
        p = self.params
        #: The users' walk alignments when the filter is guided (``radio_guide="align"``).
        self.guide = (MultiUserAligner(bundle) if p.radio_guide == "align" and (
            p.radio_update or p.radio_inject_fraction > 0) else None)
        self.state: ParticleState | None = None
        self.user_ids = np.empty(0, dtype=np.int64)   # row -> user id
        self.guide_ids = np.empty(0, dtype=np.int64)  # row -> id in self.guide, -1: none
        self.last_xy = np.empty((0, 2))
        #: each user's last step (or start) time (Unix ms; NaN: never given), and whether it
        #: is a step's (a first step may come at the start's time)
        self.last_t_ms = np.empty(0)
        self.stepped = np.empty(0, dtype=bool)
        self.consecutive = np.empty(0, dtype=np.int64)
        self.n_recoveries = np.empty(0, dtype=np.int64)
        self._next_id = 0

    # -- users ----------------------------------------------------------------------------
    @property
    def n_users(self) -> int:
        return len(self.user_ids)

    def add_users(self, start_xy: ArrayLike, half_width_m: ArrayLike | None = None, *,
                  fix_sigma_m: ArrayLike | None = None, t_ms: ArrayLike | None = None
                  ) -> NDArray[np.int64]:
        """Start filters for new users around their start positions; returns their ids.

        Parameters
        ----------
        start_xy : array_like (k, 2)
            Start positions (m, map frame).
        half_width_m : array_like (k,), optional
            Half-widths of the start squares (m); default ``init_half_width_m``, widened to
            ``init_from_fix_scale * fix_sigma_m`` for a start from a fix.
        fix_sigma_m : array_like (k,), optional
            For starts that are radio fixes: their accuracy (m; NaN: a known position). On a
            guided engine those users are guided (class docstring).
        t_ms : array_like (k,), optional
            The starts' times (Unix ms); needed for guided users. Given, a tick's step times
            (``tick(t_ms=...)``) are checked to come after them.
        """
        p = self.params
        xy = start_points(start_xy)
        k = len(xy)
        sigma = np.full(k, np.nan) if fix_sigma_m is None else \
            per_user(fix_sigma_m, k, "fix_sigma_m")
        hw = start_half_width_m(p, sigma) if half_width_m is None else \
            per_user(half_width_m, k, "half_width_m")
        guided = np.isfinite(sigma) & (self.guide is not None)
        guide_ids = np.full(k, -1, dtype=np.int64)
        t = np.full(k, np.nan) if t_ms is None else per_user(t_ms, k, "t_ms")
        if not np.isfinite(t).all() and t_ms is not None:
            raise LocalizationError("add_users: a start time is not finite (t_ms); nobody was "
                                    "added")
        if guided.any():  # first: it checks the starts and times, and draws nothing
            if t_ms is None:
                raise LocalizationError("add_users: users started from a fix on a guided "
                                        "engine need their start times (t_ms)")
            guide_ids[guided] = self.guide.add_users(xy[guided], t[guided], sigma[guided])
        try:
            new = init_state(self.fmap, p, self.rng, xy, hw, dtype=self.dtype)
        except BaseException:
            if guided.any():  # no user half added
                self.guide.remove_users(guide_ids[guided])
            raise
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
        self.guide_ids = np.concatenate([self.guide_ids, guide_ids])
        self.last_xy = np.concatenate([self.last_xy, np.column_stack([mx, my])])
        self.last_t_ms = np.concatenate([self.last_t_ms, t])
        self.stepped = np.concatenate([self.stepped, np.zeros(k, dtype=bool)])
        self.consecutive = np.concatenate([self.consecutive, np.zeros(k, dtype=np.int64)])
        self.n_recoveries = np.concatenate([self.n_recoveries, np.zeros(k, dtype=np.int64)])
        return ids

    def remove_users(self, ids: ArrayLike) -> None:
        """Drop users (their filters, and their alignments when guided, are freed); a
        :class:`LocalizationError` naming ids the engine does not hold (a user removed twice,
        an id of another engine), before any is removed."""
        gone = self.rows_of(tick_ids(ids, "remove_users"), "remove_users")
        keep = np.ones(len(self.user_ids), dtype=bool)
        keep[gone] = False
        if self.state is not None:
            self.state.data = self.state.data[:, keep]
            for name in self.state.obs:
                self.state.obs[name] = self.state.obs[name][:, keep]
        if self.guide is not None:
            self.guide.remove_users(self.guide_ids[~keep & (self.guide_ids >= 0)])
        self.user_ids = self.user_ids[keep]
        self.guide_ids = self.guide_ids[keep]
        self.last_xy = self.last_xy[keep]
        self.last_t_ms = self.last_t_ms[keep]
        self.stepped = self.stepped[keep]
        self.consecutive = self.consecutive[keep]
        self.n_recoveries = self.n_recoveries[keep]

    def rows_of(self, ids: ArrayLike, what: str = "tick") -> NDArray[np.intp]:
        """Rows of user ids (raises for unknown ids, naming ``what`` they were given to)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if not len(ids):
            return np.empty(0, dtype=np.intp)
        order = np.argsort(self.user_ids)
        pos = np.searchsorted(self.user_ids, ids, sorter=order)
        pos = np.minimum(pos, len(order) - 1) if len(order) else pos
        rows = order[pos] if len(order) else pos
        if len(order) == 0 or not np.array_equal(self.user_ids[rows], ids):
            known = set(self.user_ids.tolist())
            unknown = [i for i in ids.tolist() if i not in known]
            raise unknown_ids_error(unknown, what)
        return rows

    @property
    def bytes_per_user(self) -> float:
        """Memory of the particle state per user (bytes)."""
        if self.state is None or self.n_users == 0:
            return 0.0
        return self.state.nbytes / self.n_users

    # -- ticks ----------------------------------------------------------------------------
    def tick(self, ids: ArrayLike | None, inputs: StepInputs,
             fix_xy_m: ArrayLike | None = None, fix_sigma_m: ArrayLike | None = None, *,
             t_ms: ArrayLike | None = None, fix_t_ms: ArrayLike | None = None
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
            filter's update with a radio model that only locates (its ``"fit"`` rule is
            single-user). Guided users' fixes go to their alignment instead (class docstring).
        fix_sigma_m : array_like (k,), optional
            The fixes' accuracy (m; NaN or absent: ``radio_sigma_floor_m``).
        t_ms : array_like (k,), optional
            The steps' times (Unix ms); needed when a guided user steps.
        fix_t_ms : array_like (k,), optional
            The fixes' scan times (Unix ms; NaN or absent: the step's), for guided users.

        Returns
        -------
        StepOutputs
            Estimates of those users, shape (k,).
        """
        if self.state is None:
            raise LocalizationError("no users")
        if ids is not None:
            ids = tick_ids(ids)
        users = self.user_ids if ids is None else ids
        k = len(users)
        check_tick_inputs(inputs, users)
        p = self.params
        if fix_xy_m is not None:
            fix_xy, sigma = checked_tick_fixes(fix_xy_m, fix_sigma_m, k, p.radio_sigma_floor_m,
                                              self.bundle.grid, users)
        rows = slice(None) if ids is None else self.rows_of(ids)
        last = self.last_xy[rows]
        guided = self.guide_ids[rows] >= 0
        if guided.any() and t_ms is None:  # the alignments need them
            raise LocalizationError("tick: guided users need their step times (t_ms)")
        step_t = None if t_ms is None else per_user(t_ms, k, "t_ms")
        if step_t is not None:  # every user's time checked at once, named by engine ids
            aligners = self.guide.aligners_of(self.guide_ids[rows][guided]) \
                if guided.any() else []
            check_user_step_times(
                later_than(step_t[~guided], self.last_t_ms[rows][~guided],
                           self.stepped[rows][~guided], users[~guided])
                + step_time_problems(aligners, step_t[guided], users[guided]))
        if guided.any():  # the alignments step first: their positions are these users'
            t = step_t[guided]  # radio evidence at this step
            fix_t = None if fix_t_ms is None else checked_fix_times(
                per_user(fix_t_ms, k, "fix_t_ms")[guided], t, users[guided],
                None if fix_xy_m is None else np.isfinite(fix_xy[guided]).all(axis=1))
            if fix_xy_m is None:  # the guides' positions go in here
                fix_xy, sigma = np.full((k, 2), np.nan), np.full(k, p.radio_sigma_floor_m)
            g = advance_aligners(aligners, t, tuple(c[guided] for c in step_columns(inputs, k)),
                                 fix_xy[guided], fix_t, search_spread=True)
            fix_xy[guided] = np.column_stack([g.x_m, g.y_m])
            sigma[guided] = np.fmax(g.spread_m, p.guide_sigma_m)
        extra = (None if fix_xy_m is None and not guided.any() else
                 lambda st: self._fix_update(st, fix_xy, sigma, last, guided))
        if ids is None:
            out = advance(self.state, self.fmap, p, self.rng, inputs, last,
                          self.consecutive, extra_update=extra)
        else:
            sub = self.state.subset(rows)
            cons = self.consecutive[rows]
            out = advance(sub, self.fmap, p, self.rng, inputs, last, cons,
                          extra_update=extra)
            self.state.put(rows, sub)
            self.consecutive[rows] = cons
        self.last_xy[rows] = np.column_stack([out.x_m, out.y_m])
        if step_t is not None:
            self.last_t_ms[rows] = step_t
        self.stepped[rows] = True
        self.n_recoveries[rows] += out.recovered
        return out

    def _fix_update(self, st: ParticleState, fix_xy: NDArray[np.float64],
                    sigma: NDArray[np.float64], last_xy: NDArray[np.float64],
                    guided: NDArray[np.bool_]) -> None:
        """The radio update of :meth:`tick` on the tick's rows ``st``: fixes or guide
        positions (k, 2) (m; NaN: none), their SDs (k,) (m), the rows' last estimates (k, 2),
        and which rows are guided (they re-draw particles from ``guide_inject_distance_m``
        away, the others from ``radio_inject_distance_m``)."""
        p = self.params
        rows = np.flatnonzero(np.isfinite(fix_xy).all(axis=1))
        if rows.size == 0:
            return
        fx, fy = fix_xy[:, 0], fix_xy[:, 1]
        if p.radio_update:  # one vectorized update over every user with a fix
            position_update(st, rows, fx[rows, None], fy[rows, None], sigma[rows, None],
                            p.radio_outlier)
        if p.radio_inject_fraction > 0:  # rare (far fixes): one user at a time
            far_m = np.where(guided[rows], p.guide_inject_distance_m, p.radio_inject_distance_m)
            far = rows[np.hypot(fx[rows] - last_xy[rows, 0], fy[rows] - last_xy[rows, 1])
                       >= far_m]
            for r in far:
                if guided[r]:  # as the single-user guided filter re-draws
                    inject_around_guide(st, self.fmap, p, self.rng, int(r), (fx[r], fy[r]),
                                        sigma[r])
                else:
                    inject_around_fix(st, self.fmap, p, self.rng, int(r),
                                      p.radio_inject_fraction, (fx[r], fy[r]), sigma[r])
