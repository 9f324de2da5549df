"""The localizer methods by name: what ``localize --method`` and ``evaluate --method`` accept.

No imports beyond the standard library, so that the command line can list the choices without
loading the localizers (:func:`localize.baselines.make_localizer` builds them).
"""

from __future__ import annotations

#: Method name -> description. ``indoormap`` is the default (mass-centered update).
METHODS: dict[str, str] = {
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
SMOOTHABLE = (*PARTICLE_FILTERS, "align")
