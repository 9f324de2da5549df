"""The particle-filter localizer of one user: batch (:meth:`Localizer.run`) and streaming
(:meth:`Localizer.start`, then :meth:`Localizer.step` per step).

Paper 001, Algorithm 1: particles start on the reachable area around a fix (square of
half-width ``delta``), move each step with their own step-length genomes and the map's heading
offset (eqs. 13-15), die when they leave the reachable area, are weighted by the mass-centered
magnetic update (eq. 12; or a baseline update, see :mod:`localize.update`), resampled
systematically, and the estimate is their mean. When every particle has died the filter
re-draws them around the last estimate with a growing spread (counted as a recovery).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from functools import partial
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import Grid, MapBundle
from localize.errors import LocalizationError
from localize.floors import check_walk_fits
from localize.maps import FilterMap
from localize.methods import method_label
from localize.params import FilterParams, is_switch
from localize.particles import (
    ParticleState,
    estimate,
    init_state,
    inject_around_fix,
    inject_around_guide,
    needed_layers,
    resample,
    start_half_width_m,
)
from localize.radio import RadioModel
from localize.smoothing import Genealogy
from localize.stepper import StepInputs, advance
from localize.steps import (STEP_NUMBER_FIELDS, RadioScan, StepSummaries, StepSummary,
                            check_step_numbers, check_step_values)
from localize.track import Estimate, Track
from localize.update import position_update, radio_likelihood, radio_update
from survey.errors import require_type

__all__ = ["BaseLocalizer", "Localizer", "RadioFix", "first_radio_fix", "make_rng"]


def make_rng(rng: np.random.Generator | np.random.SeedSequence | int | None
             ) -> np.random.Generator:
    """A generator from a generator (used as is), anything ``numpy.random.default_rng``
    takes as a seed (a whole number >= 0, a sequence of them, a ``SeedSequence`` or a bit
    generator), or None (seed 0: reproducible); a LocalizationError naming ``rng`` for text,
    a bool, a fraction or a negative seed (numpy's own errors did not say which argument)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, (str, bytes, bool, np.bool_, float, np.floating)) or (
            isinstance(rng, (int, np.integer)) and rng < 0):
        raise LocalizationError(f"rng must be a seed (a whole number >= 0), a "
                                f"numpy.random.Generator or None, got {rng!r}")
    try:
        return np.random.default_rng(rng)
    except (TypeError, ValueError) as err:
        raise LocalizationError(f"rng is not a seed numpy takes ({err})") from err


class RadioFix(NamedTuple):
    """A radio fix of a walk: position and accuracy (m), the scan's time (Unix ms; its
    step's for a scan without one) and the scan."""

    x_m: float
    y_m: float
    sigma_m: float
    t_ms: float
    scan: RadioScan


def first_radio_fix(radio: RadioModel | None, steps: StepSummaries) -> RadioFix | None:
    """The fix of the first scan of ``steps`` that ``radio`` (anything with
    ``locate(scan)``) can locate; None without radio, scans or a fix."""
    if radio is None or steps.scans is None:
        return None
    for i, scan in enumerate(steps.scans):
        if scan is None:
            continue
        fix = radio.locate(scan)
        if fix is not None:
            return RadioFix(fix[0], fix[1], fix[2], scan.time_or(steps.t_ms[i]), scan)
    return None


def walk_fixes(radio: RadioModel | None, steps: StepSummaries
               ) -> list[tuple[int, float, tuple[float, float, float]]]:
    """``(step, scan time, (x_m, y_m, sigma_m))`` of each of a walk's scans ``radio``
    locates, in one ``locate_scans`` call where the radio has it (each scan on its own, as
    ``locate`` gives it; one at a time took 5 ms a scan on ILC)."""
    if radio is None or steps.scans is None:
        return []
    at = [(i, scan.time_or(steps.t_ms[i]), scan) for i, scan in enumerate(steps.scans)
          if scan is not None]
    if not at:
        return []
    if hasattr(radio, "locate_scans"):
        fix = radio.locate_scans([scan for _, _, scan in at])
        return [(i, t, (float(x), float(y), float(s)))
                for (i, t, _), (x, y), s in zip(at, fix.xy_m, fix.sigma_m) if np.isfinite(x)]
    return [(i, t, f) for i, t, scan in at if (f := radio.locate(scan)) is not None]


def step_time_problem(t_ms: float, last_t_ms: float, *, after_step: bool) -> str | None:
    """Why a streaming step's time (ms) cannot be taken, or None: it must be finite and
    after the last step's (``last_t_ms``), or not before the start's (``after_step`` false:
    no step yet). Estimates would go back in time, and a step sent twice would be walked
    twice, where :meth:`run` refuses steps that are not strictly increasing."""
    if not np.isfinite(t_ms):
        return f"step at {t_ms} ms has no time"
    if after_step and t_ms == last_t_ms:
        return (f"step at {t_ms:.0f} ms has the last step's time: the same step sent twice? "
                "(steps must be strictly increasing in time)")
    if after_step and t_ms < last_t_ms:
        return f"step at {t_ms:.0f} ms comes before the last one ({last_t_ms:.0f} ms)"
    if t_ms < last_t_ms:  # the first step; begin(scan=...) starts at the scan's time
        return (f"step at {t_ms:.0f} ms comes before the start ({last_t_ms:.0f} ms; a start "
                "from a scan takes the scan's time): skip the steps before it, or start "
                "earlier (a start time at most the first step's: start(..., t_ms=), or "
                "add_users(..., t_ms=) for the multi-user servers)")
    return None


def check_step_time(t_ms: float, last_t_ms: float, *, after_step: bool) -> None:
    """A LocalizationError for a step time :func:`step_time_problem` refuses."""
    if (problem := step_time_problem(t_ms, last_t_ms, after_step=after_step)) is not None:
        raise LocalizationError(problem)


def check_compass(t_ms: float, compass_deg: float) -> None:
    """A streaming step's compass heading (deg) must be a finite number; else a
    LocalizationError before the localizer takes the step (it carries on with the next)."""
    try:
        ok = bool(np.isfinite(float(compass_deg)))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        given = f"{compass_deg:g}" if isinstance(compass_deg, (float, np.floating)) \
            else repr(compass_deg)
        raise LocalizationError(f"step at {t_ms} ms: no compass heading (compass_deg is "
                                f"{given}); the step was not taken")


#: How to get a floor's map (what a wrong-type error suggests).
BUNDLE_HINT = ("localize.bundle.load_bundle(path) opens one; "
               "localize.floors.SiteMaps.open(folder).floor_bundle(floor) gives a site's")
#: How to get a walk's steps (what a wrong-type error suggests).
STEPS_HINT = "survey.step_summaries.step_summaries(trace) gives a walk's"


def check_step(s: StepSummary, owner: BaseLocalizer) -> None:
    """Refuse what is not one :class:`StepSummary` (the whole walk, say: :meth:`run` takes
    that) as ``owner``'s step, or one whose fields are not of their kinds
    (:func:`~localize.steps.check_step_values`, for the number fields ``owner`` reads:
    :attr:`BaseLocalizer.step_numbers_read`)."""
    require_type(s, StepSummary, f"{type(owner).__name__}.step(s)",
                 "one element of StepSummaries; run() localizes a whole walk")
    check_step_values(s, owner.step_numbers_read)


#: How far (m) outside the floor's grid a given start may lie (the filter's start square
#: doubles up to 200 m looking for reachable cells; farther is a wrong floor or wrong units).
MAX_START_OFF_MAP_M = 200.0


class BaseLocalizer:
    """What every method shares: the start logic and the batch run over a walk.

    Subclasses implement :meth:`_start_at` and :meth:`step`.
    """

    method = "base"
    #: Whether the method reads the magnetometer (walks without one are refused).
    needs_magnetometer = False
    #: Whether :meth:`run` can smooth offline (particle filters).
    can_smooth = False
    #: The number fields of a streamed step the method reads (:func:`check_step`); the
    #: others may be None.
    step_numbers_read: tuple[str, ...] = STEP_NUMBER_FIELDS
    #: What ``auto`` chose, and why, when :func:`~localize.baselines.make_localizer` built
    #: this localizer for ``method="auto"`` (a :class:`~localize.methods.AutoChoice`); else
    #: None.
    auto_choice = None

    def __init__(self, bundle: MapBundle, *, radio: RadioModel | None = None) -> None:
        require_type(bundle, MapBundle, f"{type(self).__name__}(bundle)", BUNDLE_HINT)
        if bundle.grid is None or bundle.mask is None:
            raise LocalizationError(f"{bundle.path}: a site-level bundle has no floor map; "
                                    "give a floor bundle")
        self.bundle = bundle
        self.radio = radio
        self._last: Estimate | None = None
        self._start_estimate: Estimate | None = None  # _last until the first step
        self._keep_genealogy = False  # set by run(smooth=True) for the start to see

    # -- start ---------------------------------------------------------------------------
    def start(self, x_m: float | None = None, y_m: float | None = None, *,
              t_ms: float | None = None, scan: RadioScan | None = None,
              half_width_m: float | None = None) -> Estimate:
        """Start at a given position, or at the radio fix of ``scan``.

        Parameters
        ----------
        x_m, y_m : float, optional
            Start position (m). Without it ``scan`` and the radio model give the start.
        t_ms : float, optional
            Start time (Unix ms); default the scan's time when starting from a scan, else 0.
            :meth:`run` starts half a second before the walk's first step: streaming from
            that time gives ``run()``'s track exactly. The filter's track does not depend on
            it; the alignment's (and a guided filter's) moves by a fraction of a metre,
            with the same accuracy.
        scan : RadioScan, optional
        half_width_m : float, optional
            ``delta`` (m); default from the parameters (and the fix's accuracy).

        Raises
        ------
        LocalizationError
            No position and no usable fix.
        """
        sigma = None
        if x_m is None or y_m is None:
            if scan is None or self.radio is None:
                raise LocalizationError("no start position: give x_m, y_m or a radio model "
                                        "and a scan")
            fix = self.radio.locate(scan)
            if fix is None:
                raise LocalizationError("the radio model gives no fix for the start scan")
            x_m, y_m, sigma = fix
        if t_ms is None:
            t_ms = scan.time_or(0.0) if sigma is not None else 0.0
        self._keep_genealogy = False  # streaming: real-time estimates only
        est = self.begin(*self._checked_start((x_m, y_m)), t_ms, sigma, half_width_m)
        if sigma is not None:
            self._started_from(scan, scan.time_or(t_ms))
        return est

    def begin(self, x_m: float, y_m: float, t_ms: float, sigma: float | None,
              half_width_m: float | None = None) -> Estimate:
        """Start at ``(x_m, y_m)`` (m) known to ``sigma`` (m; None: exactly, a given start),
        unchecked but for its time, as :meth:`start` and :meth:`run` do; for a localizer run
        inside another."""
        try:
            finite = bool(np.isfinite(float(t_ms)))
        except (TypeError, ValueError):
            finite = False
        if not finite:  # every step after it passed its time check, or crashed
            raise LocalizationError(f"start time {t_ms!r} is not a finite number (Unix ms)")
        return self._set_start(self._start_at(x_m, y_m, float(t_ms), sigma, half_width_m))

    def _set_start(self, start: Estimate) -> Estimate:
        """Record ``start`` as the last estimate and the start (:attr:`stepped` is false
        until the next step); returns it."""
        self._last = self._start_estimate = start
        return start

    def _checked_start(self, xy) -> tuple[float, float]:
        """``xy`` as two finite floats within :data:`MAX_START_OFF_MAP_M` of the floor's grid;
        else a LocalizationError (a wrong floor, a start in other units)."""
        try:
            x, y = (float(v) for v in xy)
        except (TypeError, ValueError) as err:
            raise LocalizationError(f"start position {xy!r} is not two numbers (x, y m)") \
                from err
        check_within_reach(self.bundle.grid, x, y, f"start position ({x:g}, {y:g}) m")
        return x, y

    @property
    def guided(self) -> bool:
        """Whether this run takes its radio evidence from the walk alignment (only a
        guided particle filter does)."""
        return False

    @property
    def label(self) -> str:
        """How this run is named: the method, and whether the walk alignment guided it."""
        return method_label(self.method, self.guided)

    @property
    def last_t_ms(self) -> float:
        """Time (Unix ms) of the last step, or of the start."""
        return self._last.t_ms

    @property
    def stepped(self) -> bool:
        """Whether a step was taken since the start."""
        return self._last is not None and self._last is not self._start_estimate

    def check_next(self, t_ms: float, compass_deg: float | None = None) -> None:
        """What a streamed step must pass before it is taken (else a LocalizationError, and
        the localizer carries on with the next): a start made, a finite compass heading
        (``compass_deg`` None: a method that does not read it), a time after the last
        step's (not before the start's)."""
        if self._last is None:
            raise LocalizationError("call start() (or run()) before step()")
        if compass_deg is not None:
            check_compass(t_ms, compass_deg)
        check_step_time(t_ms, self.last_t_ms, after_step=self.stepped)

    def _start_at(self, x: float, y: float, t_ms: float, sigma: float | None,
                  half_width_m: float | None) -> Estimate:
        raise NotImplementedError

    def _started_from(self, scan: RadioScan | None, t_fix_ms: float) -> None:
        """The start just made was located from ``scan``, whose time is ``t_fix_ms``: for
        methods that keep the fixes (the alignment), a fix at that time, and a scan not to
        apply again when its step brings it."""

    def step(self, s: StepSummary) -> Estimate:
        raise NotImplementedError

    # -- batch ---------------------------------------------------------------------------
    def check(self, steps: StepSummaries) -> None:
        """Refuse walks this method cannot localize on its bundle (see
        :func:`~localize.floors.check_walk_fits`)."""
        require_type(steps, StepSummaries, f"{type(self).__name__}.run(steps)", STEPS_HINT)
        check_walk_fits(self.bundle, steps)
        if self.needs_magnetometer and not steps.has_magnetometer:
            raise LocalizationError(f"{steps.trace_id or 'walk'}: no magnetometer values; "
                                    f"method {self.method} needs the magnetic field "
                                    "(align, pf_no_mag, pdr and radio do without; auto runs "
                                    "align on such a walk, in Python given "
                                    "make_localizer(..., magnetometer=False))")

    def check_run(self, steps: StepSummaries, smooth: object, start_t_ms: object) -> None:
        """What :meth:`run` refuses before any work: a walk this method cannot localize
        (:meth:`check`), ``smooth`` other than True or False (``"no"`` smoothed), a start
        time that is not a finite number (NaN gave a track starting at NaN)."""
        self.check(steps)
        if not is_switch(smooth):
            raise LocalizationError(f"smooth must be True or False, got {smooth!r}")
        if start_t_ms is not None:
            check_step_numbers(start_t_ms, start_t_ms=start_t_ms)
            if not np.isfinite(start_t_ms):
                raise LocalizationError(f"start_t_ms must be a finite time (Unix ms), got "
                                        f"{start_t_ms}")

    def first_fix(self, steps: StepSummaries) -> RadioFix | None:
        """The fix of the first scan of the walk the radio model can locate."""
        return first_radio_fix(self.radio, steps)

    def run(self, steps: StepSummaries, start_xy: tuple[float, float] | None = None, *,
            start_t_ms: float | None = None, half_width_m: float | None = None,
            smooth: bool = False) -> Track:
        """Localize a whole walk.

        Parameters
        ----------
        steps : StepSummaries
        start_xy : (float, float), optional
            Start position (m); default the first radio fix of the walk.
        start_t_ms : float, optional
            Time of the start (default half a second before the first step).
        half_width_m : float, optional
            ``delta`` of the start square (m).
        smooth : bool
            Offline: every position uses the whole walk, later steps included
            (:mod:`localize.smoothing`; particle filters and align only). Default: the filter's
            real-time estimates.

        Returns
        -------
        Track
            One estimate per step (``info["smoothed"]`` says which kind;
            ``info["seen_by_map"]`` whether the bundle was built from this walk).
        """
        self.check_run(steps, smooth, start_t_ms)
        if smooth and not self.can_smooth:
            raise LocalizationError(f"method {self.method} cannot smooth (particle filters "
                                    "and align only)")
        self._keep_genealogy = bool(smooth)
        t0 = float(steps.t_ms[0]) - 500.0 if start_t_ms is None else float(start_t_ms)
        if start_xy is None:
            fix = self.first_fix(steps)
            if fix is None:
                raise LocalizationError(f"{steps.trace_id or 'walk'}: no start position given "
                                        "and no scan of the walk located by the radio model")
            start = self._start_at(fix.x_m, fix.y_m, t0, fix.sigma_m, half_width_m)
            self._started_from(fix.scan, fix.t_ms)
        else:
            start = self._start_at(*self._checked_start(start_xy), t0, None, half_width_m)
        self._set_start(start)
        est = [self.step(s) for s in steps]
        track = Track.from_estimates(start, est, method=self.method, trace_id=steps.trace_id,
                                     floor_id=self.bundle.floor_id)
        track.info.update(smoothed=bool(smooth), seen_by_map=self.seen_by_map(steps))
        out = self._smoothed(track) if smooth else track
        out.info.update(self.provenance())
        return out

    def provenance(self) -> dict:
        """What a track of this localizer records of its making (``Track.info``, and the
        metadata of a written track): ``ran``, the run's :attr:`label` (``indoormap guided by
        align``: the method alone does not tell a guided filter); ``bundle_id``; and for
        ``auto``, ``auto``, why it chose this."""
        out = {"ran": self.label, "bundle_id": self.bundle.bundle_id}
        if self.auto_choice is not None:
            out["auto"] = self.auto_choice.why
        return out

    def seen_by_map(self, steps: StepSummaries) -> bool:
        """Whether the bundle was built from this walk (``track.info["seen_by_map"]``; its
        errors are then better than an unseen walk's, and
        :func:`localize.evaluate.waypoint_errors` warns)."""
        return bool(steps.trace_id) and steps.trace_id in self.bundle.source_walk_ids()

    def _smoothed(self, track: Track) -> Track:
        raise NotImplementedError


class Localizer(BaseLocalizer):
    """Particle-filter localizer on one floor bundle.

    Parameters
    ----------
    bundle : MapBundle
        A floor bundle (grid, mask, layers ``strength``, ``azimuth``, ``polar``,
        ``heading_offset``; missing layers switch their part off).
    params : FilterParams, optional
    radio : RadioModel, optional
        Wi-Fi/BLE positioner for the start fix (and weight updates when
        ``params.radio_update``).
    rng : numpy.random.Generator or int, optional
        Randomness (same seed and input: same trajectory); None is seed 0, not fresh
        entropy, so that two runs agree unless told otherwise.
    method : str, optional
        Name reported in tracks.
    fmap : FilterMap, optional
        Pre-packed layers (share one between localizers of the same bundle).

    Examples
    --------
    >>> loc = Localizer(load_bundle("bundles/F1"), FilterParams(), rng=7)  # doctest: +SKIP
    >>> track = loc.run(steps, start_xy=(12.0, 30.5))                      # doctest: +SKIP
    >>> loc.start(12.0, 30.5); est = loc.step(steps[0])                    # doctest: +SKIP
    """

    method = "indoormap"
    can_smooth = True

    def __init__(self, bundle: MapBundle, params: FilterParams | Mapping | None = None, *,
                 radio: RadioModel | None = None,
                 rng: np.random.Generator | int | None = None, method: str | None = None,
                 fmap: FilterMap | None = None) -> None:
        super().__init__(bundle, radio=radio)
        self.params = FilterParams.coerce(params, f"{type(self).__name__}(params)")
        self.rng = make_rng(rng)
        if method:
            self.method = method
        if fmap is None:
            layers, stds = needed_layers(self.params)
            fmap = FilterMap(bundle, layers, stds)
        self.fmap = fmap
        self.needs_magnetometer = self.params.weight_mode != "none"
        self.state: ParticleState | None = None
        self.genealogy: Genealogy | None = None
        self.n_recoveries = 0
        self._consecutive = np.zeros(1, dtype=np.int64)
        self.guide: BaseLocalizer | None = None
        self._guided = False
        p = self.params
        if radio is not None and p.radio_guide == "align" and (
                p.radio_update or p.radio_inject_fraction > 0):
            from localize.align import WalkAligner  # (align builds on this module)

            self.guide = WalkAligner(bundle, radio=radio)

    def _start_at(self, x: float, y: float, t_ms: float, sigma: float | None,
                  half_width_m: float | None) -> Estimate:
        p = self.params
        hw = float(start_half_width_m(p, np.nan if sigma is None else sigma)) \
            if half_width_m is None else float(half_width_m)
        n0 = max(p.n_particles_start, p.n_particles)
        self.state = init_state(self.fmap, p, self.rng, np.array([[x, y]]), np.array([hw]),
                                n=n0, with_lineage=self._keep_genealogy)
        self.genealogy = None
        if self._keep_genealogy:
            self.genealogy = Genealogy()
            self.genealogy.record(self.state.x[0], self.state.y[0], None)
        self._steps_since_start = 0
        self._fit: list[float] | None = None  # radio fit averages (fast, slow)
        self.n_recoveries = 0
        self._consecutive = np.zeros(1, dtype=np.int64)
        # the alignment would hold a given start (sigma None) as a fix of 1 m, and a wrong
        # one for its whole window: from a given start the filter uses the fixes themselves
        self._guided = self.guide is not None and sigma is not None
        if self._guided:
            # The guide starts where the particles do, at the fix at the start time, and
            # takes the start scan again at its step: the first fix counts twice. Dating it
            # at its scan and taking it once, as WalkAligner.run does, measured worse
            # (session 42, simulated built maps, auto, seeds 0-3: 1.26 / 3.11 / 2.14 m at the
            # waypoints against 1.22 / 2.97 / 2.07 m; docs/localize.md).
            self.guide.begin(x, y, t_ms, sigma, half_width_m)
        mx, my, spread = estimate(self.state)
        return Estimate(t_ms, float(mx[0]), float(my[0]), float(spread[0]), 1.0, False,
                        self.bundle.floor_id)

    def step(self, s: StepSummary) -> Estimate:
        """Advance by one step and return the new estimate.

        Raises
        ------
        LocalizationError
            Called before :meth:`start`, or a step without a finite compass heading.
        """
        check_step(s, self)
        self.check_next(s.t_ms, s.compass_deg)
        st, p = self.state, self.params
        inp = StepInputs(np.array([s.compass_deg]), np.array([s.frequency_hz]),
                         np.array([s.turn_deg]), np.array([s.strength_ut]),
                         np.array([s.azimuth_deg]), np.array([s.polar_deg]),
                         np.array([s.attitude]), np.array([s.relative_heading_deg]),
                         np.array([s.delta_acc_ms2]))
        extra = None
        if self._guided:
            extra = partial(self._guide_step, guide=self.guide.step(s))
        elif s.scan is not None and self.radio is not None and (
                p.radio_update or p.radio_inject_fraction > 0):
            extra = partial(self._radio_step, scan=s.scan)
        out = advance(st, self.fmap, p, self.rng, inp,
                      np.array([[self._last.x_m, self._last.y_m]]), self._consecutive,
                      raw_strength_ut=s.mag_strength_ut, extra_update=extra)
        recovered = bool(out.recovered[0])
        self.n_recoveries += int(recovered)
        self._steps_since_start += 1
        if st.shape[1] > p.n_particles and (out.spread_m[0] < p.shrink_spread_m
                                           or self._steps_since_start >= p.shrink_after_steps):
            resample(st, self.rng, n_out=p.n_particles)
        if self.genealogy is not None:
            self.genealogy.record(st.x[0], st.y[0], st.lineage[0])
            st.reset_lineage()
        self._last = Estimate(float(s.t_ms), float(out.x_m[0]), float(out.y_m[0]),
                              float(out.spread_m[0]), float(out.alive_fraction[0]), recovered,
                              self.bundle.floor_id)
        return self._last

    def _smoothed(self, track: Track) -> Track:
        """``track`` with the genealogy's smoothed positions (the start stays as it was)."""
        sx, sy, traced = self.genealogy.smoothed(self.state.w[0])
        info = {**track.info, "smoothed_from_end": traced[1:]}
        return replace(track, x_m=np.where(np.isfinite(sx[1:]), sx[1:], track.x_m),
                       y_m=np.where(np.isfinite(sy[1:]), sy[1:], track.y_m), info=info)

    def _radio_step(self, st: ParticleState, scan: RadioScan) -> None:
        """Radio weight update and/or particle injection around the scan's fix."""
        p = self.params
        lk = (radio_likelihood(self.radio, scan, st.x[0], st.y[0])
              if p.radio_update or p.radio_inject_rule == "fit" else None)
        share = p.radio_inject_fraction
        if share > 0 and p.radio_inject_rule == "fit" and lk is not None:
            share = self._fit_share(st, lk)
        if p.radio_update:
            radio_update(st, 0, self.radio, scan, p, likelihood=lk)
        if share > 0:
            fix = self.radio.locate(scan)
            if fix is None:
                return
            if p.radio_inject_rule == "distance" or lk is None:
                far = np.hypot(fix[0] - self._last.x_m, fix[1] - self._last.y_m)
                if far < p.radio_inject_distance_m:
                    return
            inject_around_fix(st, self.fmap, p, self.rng, 0, share, fix[:2], fix[2])

    def _guide_step(self, st: ParticleState, guide: Estimate) -> None:
        """Weight update and/or particle injection around the walk alignment's position
        (``radio_guide="align"``)."""
        p = self.params
        sigma = max(self.guide.search_spread_m, p.guide_sigma_m)
        if p.radio_update:
            position_update(st, 0, guide.x_m, guide.y_m, sigma, p.radio_outlier)
        if p.radio_inject_fraction > 0 and np.hypot(
                guide.x_m - self._last.x_m,
                guide.y_m - self._last.y_m) >= p.guide_inject_distance_m:
            inject_around_guide(st, self.fmap, p, self.rng, 0, (guide.x_m, guide.y_m), sigma)

    def _fit_share(self, st: ParticleState, lk: NDArray) -> float:
        """Augmented MCL: share of particles to inject from how well the cloud fits the
        radio lately (fast average of its mean likelihood) against the long run (slow)."""
        p = self.params
        w = st.w[0]
        total = float(w.sum())
        fit = float((w * lk).sum() / total) if total > 0 else 0.0
        if self._fit is None:
            self._fit = [fit, fit]
        else:
            self._fit[0] += p.radio_fit_fast * (fit - self._fit[0])
            self._fit[1] += p.radio_fit_slow * (fit - self._fit[1])
        fast, slow = self._fit
        if slow <= 0:
            return 0.0
        return float(min(p.radio_inject_fraction, max(0.0, 1.0 - fast / slow)))

    @property
    def guided(self) -> bool:
        """Whether this run's radio evidence is the walk alignment's position
        (``params.radio_guide="align"``, a radio model, and a start from a radio fix)."""
        return self._guided

    @property
    def particles(self) -> tuple[NDArray, NDArray, NDArray]:
        """Current particle positions and weights ``(x (n,), y (n,), w (n,))``."""
        if self.state is None:
            raise LocalizationError("not started")
        return self.state.x[0], self.state.y[0], self.state.w[0]


def check_within_reach(grid: Grid, x: float, y: float, what: str, then: str = "") -> None:
    """A LocalizationError naming ``what`` (a start, a fix) unless ``(x, y)`` (m) is
    :func:`within_reach` of the floor's ``grid`` (``then``: what follows, e.g. that the step
    was not taken)."""
    if not within_reach(grid, x, y):
        raise LocalizationError(f"{what} is not finite or more than {MAX_START_OFF_MAP_M:g} m "
                                f"off the floor's map: wrong floor or units?{then}")


def within_reach(grid: Grid, x: ArrayLike, y: ArrayLike) -> NDArray[np.bool_] | bool:
    """Whether positions (m, map frame; scalars or arrays of one shape) are finite and within
    :data:`MAX_START_OFF_MAP_M` of the floor's ``grid``: a localizer refuses a start or a
    given fix that is not. A bool for scalars."""
    m = MAX_START_OFF_MAP_M
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    ok = ((grid.x0_m - m <= x) & (x <= grid.x1_m + m)
          & (grid.y0_m - m <= y) & (y <= grid.y1_m + m))
    return bool(ok) if ok.ndim == 0 else ok
