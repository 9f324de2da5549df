"""Where a walk's localization starts: a given position, the walk's first waypoint, or the
first Wi-Fi/BLE fix (left to the localizer, which locates the walk's scans itself; which kind
the walk's scans are is :func:`localize.walk_radio.walk_radio`'s choice).

Policies (``start``):

- ``"auto"``: the first radio fix when the radio model locates one of the walk's scans, else
  the first waypoint;
- ``"waypoint"``: the first waypoint (the ILC PDR baseline's start);
- ``"radio"``: the first radio fix (an error without a radio model);
- ``(x, y)``: that position (m, map frame).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from localize.errors import LocalizationError
from localize.filter import first_radio_fix
from localize.radio import RadioModel
from localize.steps import StepSummaries

__all__ = ["START_POLICIES", "start_position"]

#: The named start policies.
START_POLICIES = ("auto", "waypoint", "radio")


def start_position(start: str | Sequence[float], steps: StepSummaries,
                   radio: RadioModel | None, waypoints_xy_m: ArrayLike, *,
                   radio_name: str = "Wi-Fi") -> tuple[tuple[float, float] | None, str]:
    """The start of a walk and how it was chosen.

    Parameters
    ----------
    start : str or (float, float)
        A policy of :data:`START_POLICIES` or a position (m).
    steps : StepSummaries
        The walk (its scans decide whether ``"auto"`` has a radio fix).
    radio : RadioModel or None
        The radio model the walk will be localized with.
    waypoints_xy_m : array-like, shape (k, 2)
        The walk's waypoints in time order (m); may be empty.
    radio_name : str
        What the radio model's fixes are called in ``how`` and errors: ``"Wi-Fi"``, ``"BLE"``
        (:attr:`localize.walk_radio.WalkRadio.name`), ``"Wi-Fi or BLE"`` for the fallback
        when both were tried (:attr:`~localize.walk_radio.WalkRadio.tried`).

    Returns
    -------
    (xy or None, how)
        ``xy`` None means: start at the localizer's first radio fix (``Localizer.run`` with
        ``start_xy=None``); ``how`` says which start was taken, for logs: ``"given"``,
        ``"first <radio_name> fix"``, ``"first waypoint"`` or ``"first waypoint (no
        <radio_name> fix in the walk)"``.

    Raises
    ------
    LocalizationError
        An unknown policy; ``"radio"`` without a radio model; no radio fix (``"auto"``) and
        no waypoint.
    """
    if not isinstance(start, str):
        xy = np.asarray(start, dtype=np.float64).ravel()
        if xy.shape != (2,) or not np.isfinite(xy).all():
            raise LocalizationError(f"a start position is two finite numbers (x, y) in "
                                    f"metres, got {start!r}")
        return (float(xy[0]), float(xy[1])), "given"
    if start not in START_POLICIES:
        raise LocalizationError(f"start must be one of {START_POLICIES} or a position (x, y), "
                                f"got {start!r}")
    if start == "radio":
        if radio is None:
            raise LocalizationError("a start at the radio fix needs a bundle with Wi-Fi or BLE "
                                    "fingerprints (wifi_rp/wifi_fp or ble_rp/ble_fp tables)")
        return None, f"first {radio_name} fix"
    how = "first waypoint"
    if start == "auto" and radio is not None:
        if first_radio_fix(radio, steps) is not None:
            return None, f"first {radio_name} fix"
        how = f"first waypoint (no {radio_name} fix in the walk)"
    wp = np.asarray(waypoints_xy_m, dtype=np.float64).reshape(-1, 2)
    if not len(wp):
        raise LocalizationError(f"{steps.trace_id or 'walk'}: no waypoint to start from"
                                + (f" and no {radio_name} fix" if start == "auto" else "")
                                + "; give a start position (X,Y in metres)")
    return (float(wp[0, 0]), float(wp[0, 1])), how
