"""Baselines behind the localizer interface, and the method registry.

- :class:`PdrLocalizer`: dead reckoning from the start fix, a fixed step length along the
  compass heading (no map; the ILC baseline uses 0.7 m);
- :class:`RadioOnlyLocalizer`: the latest Wi-Fi/BLE fix, held until the next scan;
- the particle-filter variants are :class:`~localize.filter.Localizer` with another
  ``weight_mode`` (see :data:`METHODS`);
- ``align``: :class:`~localize.align.WalkAligner`, the step track fitted to the radio fixes
  and the walls (no particles, no magnetic map).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from localize.align import WalkAligner
from localize.bundle import MapBundle
from localize.errors import LocalizationError
from localize.filter import BUNDLE_HINT, BaseLocalizer, Localizer, check_step
from localize.maps import FilterMap
from localize.methods import METHODS, PARTICLE_FILTERS, SMOOTHABLE, WEIGHT_MODE_OF, auto_method
from localize.params import FilterParams
from localize.radio import RadioModel
from localize.steps import StepSummaries, StepSummary
from localize.track import Estimate
from survey.errors import require_type

__all__ = ["METHODS", "PARTICLE_FILTERS", "PdrLocalizer", "RadioOnlyLocalizer", "SMOOTHABLE",
           "make_localizer"]


class PdrLocalizer(BaseLocalizer):
    """Pedestrian dead reckoning with a fixed step length.

    Parameters
    ----------
    bundle : MapBundle
        Only its floor id is used (and the compatibility checks).
    step_length_m : float
        Length of every step (m).
    heading_offset_deg : float
        Constant subtracted from the compass heading (deg); 0 = the compass as is.
    """

    method = "pdr"

    def __init__(self, bundle: MapBundle, step_length_m: float = 0.7, *,
                 radio: RadioModel | None = None,
                 heading_offset_deg: float = 0.0) -> None:
        super().__init__(bundle, radio=radio)
        if not step_length_m > 0:
            raise LocalizationError(f"step_length_m must be positive, got {step_length_m}")
        self.step_length_m = float(step_length_m)
        self.heading_offset_deg = float(heading_offset_deg)

    def _start_at(self, x, y, t_ms, sigma, half_width_m) -> Estimate:
        return Estimate(t_ms, x, y, 0.0, 1.0, False, self.bundle.floor_id)

    def step(self, s: StepSummary) -> Estimate:
        check_step(s, self)
        self.check_next(s.t_ms, s.compass_deg)
        h = np.radians(s.compass_deg - self.heading_offset_deg)
        x = self._last.x_m + self.step_length_m * np.sin(h)
        y = self._last.y_m + self.step_length_m * np.cos(h)
        self._last = Estimate(float(s.t_ms), float(x), float(y), 0.0, 1.0, False,
                              self.bundle.floor_id)
        return self._last


class RadioOnlyLocalizer(BaseLocalizer):
    """The latest Wi-Fi/BLE fix of the radio model, held between scans."""

    method = "radio"
    step_numbers_read = ("t_ms",)  # the radio alone: its time and scan

    def __init__(self, bundle: MapBundle, *, radio: RadioModel) -> None:
        if radio is None:
            raise LocalizationError("the radio-only method needs a radio model")
        super().__init__(bundle, radio=radio)

    def check(self, steps: StepSummaries) -> None:
        """Also refuse a walk none of whose scans the radio model locates: its track would be
        the start, held to the end."""
        super().check(steps)
        if self.first_fix(steps) is None:
            raise LocalizationError(f"{steps.trace_id or 'walk'}: no scan of the walk located "
                                    "by the radio model; method radio has nothing to go on")

    def _start_at(self, x, y, t_ms, sigma, half_width_m) -> Estimate:
        return Estimate(t_ms, x, y, 0.0 if sigma is None else float(sigma), 1.0, False,
                        self.bundle.floor_id)

    def step(self, s: StepSummary) -> Estimate:
        check_step(s, self)
        self.check_next(s.t_ms)  # the radio alone: no compass needed
        x, y, spread = self._last.x_m, self._last.y_m, self._last.spread_m
        if s.scan is not None:
            fix = self.radio.locate(s.scan)
            if fix is not None:
                x, y, spread = fix
        self._last = Estimate(float(s.t_ms), float(x), float(y), float(spread), 1.0, False,
                              self.bundle.floor_id)
        return self._last


def make_localizer(method: str, bundle: MapBundle, params: FilterParams | Mapping | None = None, *,
                   radio: RadioModel | None = None,
                   rng: np.random.Generator | int | None = None,
                   fmap: FilterMap | None = None, magnetometer: bool = True
                   ) -> BaseLocalizer:
    """Build a localizer of the named method (see :data:`METHODS`).

    For the particle-filter methods ``params`` gives everything but the weight mode, which
    the method fixes. ``auto`` builds the one :func:`~localize.methods.auto_method` picks
    for the bundle (its ``method`` attribute names it and ``auto_choice`` says why;
    ``params.radio_guide`` is set by the choice: ``"align"`` where it guides the filter, else
    ``"fixes"``); pass
    ``magnetometer=steps.has_magnetometer`` so that it takes ``align`` for a walk without
    magnetometer values. ``params`` only concerns the particle filters (``pdr``, ``radio`` and
    ``align`` have none); ``rng`` is a seed or generator for their random draws, None meaning
    seed 0 (the same track every run).
    """
    if method not in METHODS:
        raise LocalizationError(f"unknown method {method!r}; expected one of {sorted(METHODS)}")
    require_type(bundle, MapBundle, "make_localizer(bundle)", BUNDLE_HINT)
    params = FilterParams.coerce(params, "make_localizer(params)")
    if method == "auto":  # by the floor map's measured quality (localize.methods)
        choice = auto_method(bundle.manifest.get("metrics") or {}, magnetometer=magnetometer)
        params = replace(params,
                         radio_guide="align" if choice.guided else "fixes")
        loc = make_localizer(choice.method, bundle, params, radio=radio, rng=rng, fmap=fmap)
        loc.auto_choice = choice
        return loc
    if method == "pdr":
        return PdrLocalizer(bundle, radio=radio)
    if method == "radio":
        return RadioOnlyLocalizer(bundle, radio=radio)
    if method == "align":
        return WalkAligner(bundle, radio=radio)
    p = replace(params, weight_mode=WEIGHT_MODE_OF[method])
    return Localizer(bundle, p, radio=radio, rng=rng, method=method, fmap=fmap)
