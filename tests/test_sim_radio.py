"""Simulated Wi-Fi and BLE: path loss, fixed shadowing, scans, staleness, duplicates."""

from __future__ import annotations

import re

import numpy as np
import pytest

from survey.sim.devices import DEVICE_MODELS, make_device
from survey.sim.floorplan import make_floorplan
from survey.sim.radio import (
    RadioEnvironment,
    RadioParams,
    beacon_distance_m,
    make_access_points,
    make_beacons,
    simulate_ble,
    simulate_wifi,
)
from survey.sim.rng import child_rng
from survey.sim.routes import build_graph, click_points, random_route
from survey.sim.walker import WalkerParams, simulate_walk


@pytest.fixture(scope="module")
def radio():
    plans = [make_floorplan(f"F{i + 1}", i, 40.0, 25.0, (5.0, 3.0, 1.2), (2.5, 4.0, 1.2),
                            child_rng(31, "plan", i)) for i in range(2)]
    prm = RadioParams()
    env = RadioEnvironment(plans, make_access_points(plans, prm, 31, child_rng(31, "aps")),
                           make_beacons(plans, prm, 31, child_rng(31, "ble")), prm)
    graph = build_graph(plans[0])
    kins = [simulate_walk(click_points(random_route(graph, 45.0, child_rng(31, "r", i))),
                          plans[0], 1_700_000_000_000 + i * 200_000, WalkerParams(),
                          child_rng(31, "w", i)) for i in range(3)]
    return plans, env, kins


def test_access_points(radio):
    _, env, _ = radio
    bssids = [a.bssid for a in env.aps]
    assert len(set(bssids)) == len(bssids)
    assert all(re.fullmatch(r"[0-9a-f]{2}(:[0-9a-f]{2}){5}", b) for b in bssids)
    assert {a.floor for a in env.aps} == {0, 1}
    assert all(2.0 <= a.n_exp <= 4.0 for a in env.aps)
    assert any(a.ssid == "" for a in env.aps) and any(a.freq_mhz > 5000 for a in env.aps)


def test_path_loss_and_fixed_shadowing(radio):
    _, env, _ = radio
    ap = next(i for i, a in enumerate(env.aps) if a.floor == 0)
    a = env.aps[ap]
    d = np.linspace(1.0, 20.0, 40)
    pts = np.column_stack([np.clip(a.x_m + d, 0, 40), np.full_like(d, a.y_m)])
    r1 = env.ap_rssi_dbm(0, pts)[:, ap]
    r2 = env.ap_rssi_dbm(0, pts)[:, ap]
    np.testing.assert_array_equal(r1, r2)                      # same place, same value
    assert np.corrcoef(np.log10(np.hypot(pts[:, 0] - a.x_m, 1.7)), r1)[0, 1] < -0.5
    # the same AP is weaker from the other floor
    assert np.mean(env.ap_rssi_dbm(1, pts)[:, ap]) < np.mean(r1) - 10.0


def test_wifi_scans(radio):
    _, env, kins = radio
    dev = make_device("dev1", DEVICE_MODELS["SimPhone SIM-B2"], False, child_rng(32))
    rows = [simulate_wifi(env, k, 0, dev, child_rng(33, i)) for i, k in enumerate(kins)]
    for k, w in zip(kins, rows):
        scans = np.unique(w["scan_t_ms"])
        assert np.all((scans >= k.t_ms[0]) & (scans <= k.t_ms[-1]))
        assert 1.5 <= np.median(np.diff(scans)) / 1000.0 <= 2.6
        assert (w["rssi_dbm"] >= -95).all() and (w["rssi_dbm"] < 0).all()
        assert (w["age_ms"] == w["scan_t_ms"] - w["last_seen_ms"]).all()
        assert (w["age_ms"] >= 0).all()
    allw = np.concatenate([w["age_ms"].to_numpy() for w in rows]) / 1000.0
    assert 1.5 <= np.median(allw) <= 6.0                       # real: 3-4 s
    assert 0.02 <= np.mean(allw > 20.0) <= 0.25                 # real: 10 %
    dups = sum(int(w.duplicated(["scan_t_ms", "bssid"]).sum()) for w in rows)
    assert dups > 0


def test_ble(radio):
    _, env, kins = radio
    ble, lines = simulate_ble(env, kins[0], 0, child_rng(34))
    assert len(ble) > 5
    assert (ble["key"] == ble["uuid"] + ":" + ble["major"].astype(str) + ":"
            + ble["minor"].astype(str)).all()
    np.testing.assert_allclose(ble["distance_m"],
                               beacon_distance_m(ble["rssi_dbm"], ble["tx_power_dbm"]))
    assert beacon_distance_m(np.array([-93]), np.array([-56]))[0] == pytest.approx(45.04,
                                                                                   abs=0.05)
    assert len(lines) >= 2 * len(ble)
    blue = [ln for ln in lines if "\tTYPE_BLUE\t" in ln]
    blu4 = [ln for ln in lines if "\tTYPE_BLU4\t" in ln]
    assert len(blue) == len(blu4)
    assert all(re.fullmatch(r"\d{13}\tTYPE_BLUE\t\t[0-9A-F:]{17}\t-\d+", ln) for ln in blue)
    assert all(re.fullmatch(r"\d{13}\tTYPE_BLU4\t\d+\t\d+\t-\d+", ln) for ln in blu4)
