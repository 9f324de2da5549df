"""Device calibration: offline fit recovers the simulated phones' distortion, online search
undoes a known transform, unknown models fail clearly."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from radio_fixtures import device_of, sample_store, sample_truth, wifi_obs  # noqa: F401

from localize.rssi_calibration import estimate_rssi_calibration
from mapping.device_calibration import (
    DEVICE_TABLE_COLUMNS,
    calibrate_devices,
    fit_device_calibration,
    lookup_calibration,
    rma_fit,
)
from mapping.errors import FingerprintError
from mapping.fingerprints import build_fingerprints
from mapping.matching import align_scans
from mapping.radio_scans import scan_set


def _site_obs(wifi_obs) -> pd.DataFrame:
    parts, offset = [], 0
    for floor, obs in wifi_obs.items():
        parts.append(obs.assign(floor=floor, scan_id=obs["scan_id"] + offset))
        offset += int(obs["scan_id"].max()) + 1
    return pd.concat(parts, ignore_index=True)


def test_offline_calibration_recovers_simulated_phone(wifi_obs, device_of, sample_truth):
    reference = next(d["model"] for d in sample_truth["devices"] if d["reference"])
    table = calibrate_devices(_site_obs(wifi_obs), device_of, reference_model=reference,
                              floor_column="floor")
    assert list(table.columns) == list(DEVICE_TABLE_COLUMNS)
    assert table.set_index("device_model").loc[reference, "method"] == "reference"
    for dev in sample_truth["devices"]:
        if dev["reference"]:
            continue
        # the simulator distorts rssi_dev = k_d * rssi_ref + b_d; calibration is the inverse
        k_true, b_true = 1.0 / dev["rssi_k"], -dev["rssi_b"] / dev["rssi_k"]
        cal = lookup_calibration(table, dev["model"])
        assert cal.method == "offline" and cal.n_pairs >= 100
        assert abs(cal.k - k_true) < 0.05
        assert abs(cal.b - b_true) < 1.0


def test_offline_fit_with_too_few_pairs_is_the_identity(wifi_obs, device_of):
    obs = wifi_obs["F2"]
    ref = obs[obs["trace_id"].map(device_of) == "SIM-A1"]
    far = obs[obs["trace_id"].map(device_of) == "SIM-B2"].assign(x_m=1e4)  # never co-located
    cal = fit_device_calibration(far, ref, device_model="far")
    assert (cal.k, cal.b, cal.method, cal.n_pairs) == (1.0, 0.0, "too_few_pairs", 0)
    assert cal.apply(np.array([-60.0, np.nan]))[0] == -60.0


def test_rma_is_exact_without_noise_and_robust_to_outliers():
    x = np.linspace(-90, -40, 200)
    y = 1.2 * x + 9.0
    y[::25] += 40.0                                  # 4 % gross outliers
    k, b, _ = rma_fit(x, y)
    assert k == pytest.approx(1.2, abs=0.01) and b == pytest.approx(9.0, abs=0.8)


def test_online_calibration_undoes_a_known_transform(wifi_obs, device_of):
    slopes, offsets = [], []
    for obs in wifi_obs.values():
        obs = obs[obs["trace_id"].map(device_of) == "SIM-A1"]
        for walk in sorted(obs["trace_id"].unique()):
            db = build_fingerprints(obs[obs["trace_id"] != walk]).dense()
            scans = scan_set(obs[(obs["trace_id"] == walk) & (obs["age_ms"] <= 3000)])
            rssi, _ = align_scans(scans.subset(np.arange(len(scans)) < 8), db.aps)
            cal = estimate_rssi_calibration(0.85 * rssi - 8.0, db.mean_dbm, db.var_db2)
            assert cal.cost_db2 < cal.identity_cost_db2 and cal.n_scans == 8
            slopes.append(cal.k * 0.85)      # the combined map should be the identity
            offsets.append(cal.k * (0.85 * -70 - 8) + cal.b + 70)
    assert len(slopes) == 7
    assert abs(np.median(slopes) - 1) < 0.1 and abs(np.median(offsets)) < 1.5
    assert (np.abs(offsets) < 3.0).sum() >= 5     # 8 scans: one walk in 7 may miss by more


def test_online_calibration_of_the_simulated_phone(wifi_obs, device_of, sample_truth):
    obs = wifi_obs["F2"]
    model = obs["trace_id"].map(device_of)
    db = build_fingerprints(obs[model == "SIM-A1"]).dense()
    dev = next(d for d in sample_truth["devices"] if d["model"] == "SIM-B2")
    k_true, b_true = 1.0 / dev["rssi_k"], -dev["rssi_b"] / dev["rssi_k"]
    for walk in sorted(obs.loc[model == "SIM-B2", "trace_id"].unique()):
        scans = scan_set(obs[(obs["trace_id"] == walk) & (obs["age_ms"] <= 3000)])
        rssi, _ = align_scans(scans.subset(np.arange(len(scans)) < 8), db.aps)
        cal = estimate_rssi_calibration(rssi, db.mean_dbm, db.var_db2)
        err_70 = (cal.k - k_true) * -70 + (cal.b - b_true)      # error at -70 dBm
        assert abs(err_70) < 3.0 and 0.5 <= cal.k <= 2.0


def test_online_calibration_without_usable_scans_is_the_identity():
    cal = estimate_rssi_calibration(np.full((3, 4), np.nan), np.zeros((5, 4)) - 60)
    assert (cal.k, cal.b, cal.n_scans) == (1.0, 0.0, 0) and np.isnan(cal.cost_db2)
    with pytest.raises(ValueError, match="transmitters"):
        estimate_rssi_calibration(np.zeros((1, 3)), np.zeros((2, 4)))


def test_unknown_device_model_is_named(wifi_obs, device_of):
    table = pd.DataFrame([{"device_model": "SIM-A1", "k": 1.0, "b": 0.0, "n_pairs": 0,
                           "residual_sd_db": 0.0, "method": "reference"}])
    with pytest.raises(FingerprintError, match=r"unknown device model 'Pixel 9'.*SIM-A1.*online"):
        lookup_calibration(table, "Pixel 9")
    assert lookup_calibration(table, "Pixel 9", unknown="identity").method == "identity"
    with pytest.raises(FingerprintError, match="no device model for traces"):
        calibrate_devices(wifi_obs["F1"], {})


def test_calibrated_rssi_stays_within_what_a_phone_reports():
    """A phone mapped by b > 0 (or k > 1) put readings near 0 dBm above it, and the bundle's
    fingerprint check (RSSI within [-127, 0] dBm) then refused the whole build."""
    from mapping.radio_build import _with_calibration

    obs = pd.DataFrame({"trace_id": ["w", "w", "w", "v"],
                        "rssi_dbm": [-1.0, -60.0, -126.0, -1.0]})
    out = _with_calibration(obs, {"w": (1.2, 5.0)})
    assert out["rssi_dbm"].tolist() == [0.0, -67.0, -127.0, -1.0]
