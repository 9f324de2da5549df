"""The localizer methods by name: what ``localize --method`` and ``evaluate --method`` accept.

No imports beyond the standard library, so that the command line can list the choices without
loading the localizers (:func:`localize.baselines.make_localizer` builds them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

#: ``auto`` takes the particle filter, guided by the walk alignment, on a floor whose strength
#: map predicts the field's change over 5 m of walks it did not see with at least this
#: correlation (the build's ``metrics.heldout_strength.corr_5m``), else the alignment alone.
#: Set between the two sites measured (docs/localize.md): the simulated floors, 0.77-0.87,
#: where the filter's magnetic update works, and the ILC mall, 0.27-0.33, where it does not
#: and the alignment is better.
AUTO_MIN_CORR_5M = 0.5

#: Method name -> description. ``auto`` is the default of ``indoormap localize``.
METHODS: dict[str, str] = {
    "auto": "indoormap guided by align where the floor's magnetic map predicts walks it did "
            f"not see (the build's held-out 5 m change correlation >= {AUTO_MIN_CORR_5M}), "
            "else align",
    "indoormap": "particle filter, mass-centered MMSE/MMAE/MMPE update (papers 000/001)",
    "pf_no_mag": "particle filter without magnetic update (PDR + map constraints)",
    "magpp_gaussian": "particle filter, Gaussian likelihood of strength deltas (002-style)",
    "magicol_dtw": "particle filter, DTW of raw magnetometer strengths (Magicol-style)",
    "pdr": "dead reckoning, fixed 0.7 m steps along the compass",
    "radio": "Wi-Fi/BLE positioner alone",
    "align": "step track aligned to the radio fixes and the walls (localize.align)",
}

#: The particle-filter methods and their magnetic weight update
#: (:data:`localize.params.WEIGHT_MODES`).
WEIGHT_MODE_OF: dict[str, str] = {"indoormap": "mass_centered", "pf_no_mag": "none",
                                  "magpp_gaussian": "gaussian", "magicol_dtw": "dtw"}
#: The particle-filter methods (they can also smooth offline, :mod:`localize.smoothing`).
PARTICLE_FILTERS = tuple(WEIGHT_MODE_OF)
#: The methods that can also locate a walk offline (``run(steps, smooth=True)``).
SMOOTHABLE = (*PARTICLE_FILTERS, "align", "auto")


class AutoChoice(NamedTuple):
    """What ``auto`` runs on a floor bundle (:func:`auto_method`)."""

    method: str  #: a name of :data:`METHODS`
    guided: bool  #: the filter takes its radio evidence from the walk alignment
    why: str  #: the reason, as a phrase ("the magnetic map's held-out ...")

    @property
    def label(self) -> str:
        return method_label(self.method, self.guided)


def method_label(method: str, guided: bool) -> str:
    """How a run is named: the method, and whether the walk alignment guided the filter."""
    return f"{method} guided by align" if guided else method


def auto_method(metrics: Mapping, *, magnetometer: bool = True) -> AutoChoice:
    """What ``auto`` runs on a floor bundle with these manifest ``metrics``, for a walk with
    (``magnetometer``) or without magnetometer values.

    The particle filter guided by the walk alignment (``FilterParams.radio_guide="align"``)
    when the strength map's held-out 5 m change correlation is :data:`AUTO_MIN_CORR_5M` or
    more; ``align`` when it is less; the filter on the fixes, as before the measure existed,
    when the bundle does not record it (built before, or from fewer than 3 walks) or records
    no 5 m correlation (no held-out walk spans 5 m). A walk without magnetometer values
    gets ``align`` whatever the map (the filter's magnetic update has nothing to weigh).
    """
    if not magnetometer:
        return AutoChoice("align", False, "the walk has no magnetometer values")
    quality = metrics.get("heldout_strength") or {}
    if not isinstance(quality, Mapping) or not quality:
        return AutoChoice("indoormap", False, "the bundle records no held-out map quality")
    corr = quality.get("corr_5m")
    if not isinstance(corr, (int, float)) or not math.isfinite(corr):
        return AutoChoice("indoormap", False, "none of the bundle's held-out walks spans 5 m")
    measured = f"the magnetic map's held-out 5 m change correlation {corr:.2f}"
    if corr >= AUTO_MIN_CORR_5M:
        return AutoChoice("indoormap", True, f"{measured} >= {AUTO_MIN_CORR_5M}")
    return AutoChoice("align", False, f"{measured} < {AUTO_MIN_CORR_5M}")
