"""Start policies of a walk (localize.start): the choice behind ``--start``."""

import numpy as np
import pytest

from localize.errors import LocalizationError
from localize.start import start_position
from localize.steps import RadioScan, StepSummaries


class _Radio:
    """Locates a scan at (10, 20) m when it hears "ap1", else gives no fix."""

    def locate(self, scan):
        return (10.0, 20.0, 3.0) if "ap1" in scan.keys else None


def _steps(scan_keys):
    m = 4
    cols = {c: np.zeros(m) for c in ("frequency_hz", "delta_acc_ms2", "compass_deg",
                                     "turn_deg", "strength_ut", "azimuth_deg", "polar_deg")}
    scans = [None] * m
    if scan_keys is not None:
        scans[2] = RadioScan(1000, np.array(scan_keys), np.full(len(scan_keys), -60.0))
    return StepSummaries(t_ms=np.arange(m) * 500.0, attitude=np.zeros(m, dtype=np.int8),
                         scans=tuple(scans), trace_id="walk1", **cols)


WAYPOINTS = np.array([[1.0, 2.0], [5.0, 2.0]])


def test_given_position_wins():
    assert start_position((3, 4), _steps(["ap1"]), _Radio(), WAYPOINTS) == ((3.0, 4.0), "given")
    assert start_position(np.array([3.5, 4.0]), _steps(None), None, []) == ((3.5, 4.0),
                                                                           "given")
    for bad in ((1.0, 2.0, 3.0), (np.nan, 1.0)):
        with pytest.raises(LocalizationError, match="two finite numbers"):
            start_position(bad, _steps(None), None, WAYPOINTS)


def test_radio_policy_leaves_the_fix_to_the_localizer():
    assert start_position("radio", _steps(["ap1"]), _Radio(), WAYPOINTS) == (
        None, "first Wi-Fi fix")


def test_auto_takes_the_radio_fix_when_a_scan_is_located():
    assert start_position("auto", _steps(["ap1"]), _Radio(), WAYPOINTS) == (
        None, "first Wi-Fi fix")
    assert start_position("auto", _steps(["ap1"]), _Radio(), WAYPOINTS, radio_name="BLE") == (
        None, "first BLE fix")


@pytest.mark.parametrize("keys", [None, ["other"]])
def test_auto_falls_back_to_the_first_waypoint_and_says_why(keys):
    xy, how = start_position("auto", _steps(keys), _Radio(), WAYPOINTS)
    assert xy == (1.0, 2.0) and how == "first waypoint (no Wi-Fi fix in the walk)"
    assert start_position("auto", _steps(keys), _Radio(), WAYPOINTS,
                          radio_name="Wi-Fi or BLE")[1] == \
        "first waypoint (no Wi-Fi or BLE fix in the walk)"
    assert start_position("auto", _steps(keys), None, WAYPOINTS) == ((1.0, 2.0),
                                                                     "first waypoint")


def test_waypoint_ignores_the_radio():
    assert start_position("waypoint", _steps(["ap1"]), _Radio(), WAYPOINTS) == (
        (1.0, 2.0), "first waypoint")


def test_errors_name_what_is_missing():
    with pytest.raises(LocalizationError, match="needs a bundle with Wi-Fi or BLE"):
        start_position("radio", _steps(["ap1"]), None, WAYPOINTS)
    with pytest.raises(LocalizationError, match="walk1: no waypoint to start from and no "
                                                "Wi-Fi fix"):
        start_position("auto", _steps(None), _Radio(), np.empty((0, 2)))
    with pytest.raises(LocalizationError, match="walk1: no waypoint to start from; give"):
        start_position("waypoint", _steps(["ap1"]), _Radio(), [])
    with pytest.raises(LocalizationError, match="start must be one of"):
        start_position("first", _steps(None), None, WAYPOINTS)
