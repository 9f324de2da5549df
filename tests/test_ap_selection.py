"""AP selection: every drop reason on a constructed survey, the MAC bit reported only."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from mapping.ap_selection import APSelectionParams, is_locally_administered, select_aps
from mapping.errors import FingerprintError

DAY = 86_400_000


def _survey() -> tuple[pd.DataFrame, dict[str, str]]:
    """Six walks along y = 0 from x = 0 to 100 m on floors F1 and F4, one scan per metre;
    walks 3-5 a day later."""
    rows = []
    scan = 0
    rng = np.random.default_rng(0)
    for w in range(6):
        for floor in ("F1", "F4"):
            for x in np.arange(0.0, 100.0, 1.0):
                t = w * 1_000_000 + int(x) * 1000 + (DAY if w >= 3 else 0)
                fade = rng.normal(0, 2)

                def add(ap, rssi, w=w, floor=floor, scan=scan, t=t, x=x):
                    rows.append((f"w{w}{floor}", scan, t, x, 0.0, ap, rssi, 0.0, floor))

                if floor == "F4":
                    add("00:00:00:00:00:09", -45 - 0.4 * abs(x - 60) + fade)   # normal, F4
                    if x < 50:
                        add("00:00:00:00:00:06", -50 - 0.3 * abs(x - 40) + fade)  # far floors
                    scan += 1
                    continue
                add("00:00:00:00:00:01", -40 - 0.4 * abs(x - 30) + fade)       # normal
                add("02:00:00:00:00:02", -45 - 0.4 * abs(x - 70) + fade)       # LAA, normal
                add("00:00:00:00:00:03", -60 + fade / 10)                       # flat
                add("00:00:00:00:00:04", -50 - 0.4 * abs(x - 50) + fade)       # hotspot ssid
                add("00:00:00:00:00:05", -40 - 0.5 * abs(x - 99 * (w % 2)) + fade)  # moving
                add("00:00:00:00:00:06", -50 - 0.3 * abs(x - 40) + fade)
                moved = 20 if w < 3 else 80                                     # moved on day 2
                add("00:00:00:00:00:07", -40 - 0.8 * abs(x - moved) + fade)
                if w == 0 and x < 2:
                    add("00:00:00:00:00:08", -70)                               # rare
                scan += 1
    obs = pd.DataFrame(rows, columns=["trace_id", "scan_id", "t_ms", "x_m", "y_m", "ap",
                                      "rssi_dbm", "age_ms", "floor"])
    ssid = {"00:00:00:00:00:04": "Lucy's iPhone", "00:00:00:00:00:01": "MallGuest"}
    return obs, ssid


def test_every_reason_and_nothing_else():
    obs, ssid = _survey()
    sel = select_aps(obs, ssid=ssid, floor_column="floor", floor_order=["F1", "F2", "F3", "F4"])
    reasons = dict(zip(sel.dropped["ap"], sel.dropped["reason"]))
    assert reasons["00:00:00:00:00:03"] == "flat"
    assert reasons["00:00:00:00:00:04"] == "hotspot_ssid"
    assert "moving" in reasons["00:00:00:00:00:05"]
    assert reasons["00:00:00:00:00:06"] == "far_floors"
    assert reasons["00:00:00:00:00:07"] == "moved"
    assert reasons["00:00:00:00:00:08"] == "rare"
    assert sel.kept.tolist() == ["00:00:00:00:00:01", "00:00:00:00:00:09", "02:00:00:00:00:02"]
    assert sel.summary()["rare"] == 1
    # 6 dropped, 7 reasons: the text says why the counts add up to more
    assert sel.summary_text() == ("far_floors 1, flat 2, hotspot_ssid 1, moved 1, moving 1, "
                                  "rare 1; 1 for more than one reason")
    assert set(sel.dropped.columns) >= {"ap", "ssid", "reason", "detail", "locally_administered"}
    detail = dict(zip(sel.dropped["ap"], sel.dropped["detail"]))
    assert "floors 3 apart" in detail["00:00:00:00:00:06"]
    assert "Lucy's iPhone" in detail["00:00:00:00:00:04"]


def test_locally_administered_is_reported_not_dropped_by_default():
    obs, ssid = _survey()
    keep = select_aps(obs, ssid=ssid, floor_column="floor")
    assert "02:00:00:00:00:02" in keep.kept
    drop = select_aps(obs, ssid=ssid, floor_column="floor",
                      params=APSelectionParams(drop_locally_administered=True))
    assert "02:00:00:00:00:02" not in drop.kept
    assert is_locally_administered(["02:00:00:00:00:00", "0e:11:22:33:44:55", "00:aa:bb:cc:dd:ee",
                                     "f8:00:00:00:00:00", "x"]).tolist() == [
        True, True, False, False, False]


def test_without_floors_or_ssids_the_rules_needing_them_are_skipped():
    obs, _ = _survey()
    sel = select_aps(obs[obs["floor"] == "F1"])
    reasons = dict(zip(sel.dropped["ap"], sel.dropped["reason"]))
    assert "00:00:00:00:00:04" not in reasons and "00:00:00:00:00:06" not in reasons
    with pytest.raises(FingerprintError, match="no floor column"):
        select_aps(obs, floor_column="level")


def test_missing_floor_and_rssi_values_do_not_break_selection():
    obs, ssid = _survey()
    obs["rssi_dbm"] = obs["rssi_dbm"].astype(float)
    obs.loc[obs.index[::50], "rssi_dbm"] = np.nan  # invalid rows are left out
    sel = select_aps(obs, ssid=ssid, floor_column="floor", floor_order=["F1", "F2", "F3", "F4"])
    assert "00:00:00:00:00:07" in set(sel.dropped["ap"])  # the moved AP is still found
    obs["floor"] = np.nan  # no floor known: no floor-gap rule, no crash
    sel = select_aps(obs, ssid=ssid, floor_column="floor")
    assert not any("far_floors" in r for r in sel.dropped["reason"])
