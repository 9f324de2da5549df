"""The localizer methods by name: what ``localize --method`` and ``evaluate --method`` accept.

No imports beyond the standard library, so that the command line can list the choices without
loading the localizers (:func:`localize.baselines.make_localizer` builds them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

#: ``auto`` takes the particle filter on a floor whose strength map predicts the field's change
#: over 5 m of walks it did not see with at least this correlation (the build's
#: ``metrics.heldout_strength.corr_5m``), else the alignment. Set between the two sites
#: measured (docs/localize.md): the simulated floors, 0.77-0.87, where the filter's magnetic
#: update works, and the ILC mall, 0.27-0.33, where it does not and the alignment is better.
AUTO_MIN_CORR_5M = 0.5

#: Method name -> description. ``auto`` is the default of ``indoormap localize``.
METHODS: dict[str, str] = {
    "auto": "indoormap where the floor's magnetic map predicts walks it did not see (the "
            f"build's held-out 5 m change correlation >= {AUTO_MIN_CORR_5M}), else align",
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


def auto_method(metrics: Mapping) -> tuple[str, str]:
    """The method ``auto`` runs on a floor bundle with these manifest ``metrics``, and why.

    ``indoormap`` (the particle filter) when the strength map's held-out 5 m change
    correlation is :data:`AUTO_MIN_CORR_5M` or more, or when the bundle does not record it
    (built before it was measured, or from fewer than 3 walks); else ``align``.
    """
    quality = metrics.get("heldout_strength") or {}
    corr = quality.get("corr_5m") if isinstance(quality, Mapping) else None
    if not isinstance(corr, (int, float)) or not math.isfinite(corr):
        return "indoormap", "the bundle records no held-out map quality"
    if corr >= AUTO_MIN_CORR_5M:
        return "indoormap", (f"the magnetic map's held-out 5 m change correlation {corr:.2f} "
                             f">= {AUTO_MIN_CORR_5M}")
    return "align", (f"the magnetic map's held-out 5 m change correlation {corr:.2f} < "
                     f"{AUTO_MIN_CORR_5M}")
