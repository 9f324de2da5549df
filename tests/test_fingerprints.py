"""Fingerprint databases: eqs. 1-2 per reference point, stale rows, missing stays missing,
BLE the same way, bad input with clear messages."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from radio_fixtures import (  # noqa: F401  (fixtures)
    ble_obs,
    sample_store,
    split_walks,
    walk_ids,
    wifi_obs,
)

from mapping.errors import FingerprintError
from mapping.fingerprints import FingerprintDB, build_fingerprints
from mapping.matching import default_matcher
from mapping.radio_scans import ble_observations, scan_set, wifi_observations
from survey.errors import IndoormapError


def _rows(**cols) -> pd.DataFrame:
    base = {"trace_id": "w1", "scan_t_ms": 1000, "bssid": "aa:bb:cc:00:00:01", "rssi_dbm": -60,
            "age_ms": 500, "x_m": 1.0, "y_m": 1.0}
    n = max(len(v) if isinstance(v, list) else 1 for v in cols.values()) if cols else 1
    return pd.DataFrame({k: cols.get(k, [base[k]] * n) if isinstance(cols.get(k), list)
                         else [cols.get(k, base[k])] * n for k in base})


def test_reference_point_statistics_follow_eqs_1_2(wifi_obs):
    obs = wifi_obs["F2"]
    db = build_fingerprints(obs, cell_m=2.0, max_age_ms=3000)
    assert list(db.rp.columns) == ["rp_id", "x_m", "y_m", "n_scans"]
    assert list(db.fp.columns) == ["rp_id", "ap", "mean_dbm", "var_db2", "n", "detection_rate"]
    fp = db.fp
    assert fp["mean_dbm"].notna().all()                       # missing is not stored
    assert (fp["mean_dbm"] >= -100).all() and (fp["mean_dbm"] < 0).all()
    assert (fp["var_db2"].isna() == (fp["n"] < 2)).all()      # unbiased variance needs T >= 2
    n_scans = db.rp.set_index("rp_id").loc[fp["rp_id"], "n_scans"].to_numpy()
    assert (fp["n"].to_numpy() <= n_scans).all()
    assert np.allclose(fp["detection_rate"], fp["n"] / n_scans)
    # recompute one (reference point, AP) by hand: eq. 1 mean, eq. 2 variance (ddof = 1)
    row = fp[fp["n"] >= 3].iloc[0]
    scans = obs.groupby("scan_id")[["x_m", "y_m"]].first()
    cells = np.floor(scans.to_numpy() / 2.0).astype(int)
    rp = db.rp.set_index("rp_id").loc[row["rp_id"]]
    cell = np.floor(np.array([rp["x_m"], rp["y_m"]]) / 2.0).astype(int)
    in_cell = scans.index[(cells == cell).all(axis=1)]
    vals = obs[obs["scan_id"].isin(in_cell) & (obs["ap"] == row["ap"])
               & (obs["age_ms"] <= 3000)]["rssi_dbm"]
    assert len(in_cell) == rp["n_scans"] and len(vals) == row["n"]
    assert row["mean_dbm"] == pytest.approx(vals.mean())
    assert row["var_db2"] == pytest.approx(vals.var(ddof=1))


def test_stale_rows_dropped_but_their_scans_still_count():
    rows = _rows(scan_t_ms=[1000, 1000, 3000, 3000],
                 bssid=["aa:00:00:00:00:01", "aa:00:00:00:00:02"] * 2,
                 rssi_dbm=[-60, -70, -62, -71], age_ms=[500, 500, 9000, 9000])
    db = build_fingerprints(wifi_observations(rows), cell_m=5.0, max_age_ms=3000)
    assert db.rp["n_scans"].tolist() == [2]                   # the all-stale scan counts
    assert db.fp["n"].tolist() == [1, 1]
    assert db.fp["detection_rate"].tolist() == [0.5, 0.5]
    every = build_fingerprints(wifi_observations(rows), cell_m=5.0, max_age_ms=None)
    assert every.fp["n"].tolist() == [2, 2]
    assert every.fp["var_db2"].tolist() == pytest.approx([2.0, 0.5])


def test_duplicate_bssid_keeps_the_freshest_row():
    rows = _rows(bssid=["AA:00:00:00:00:01", "aa:00:00:00:00:01"], rssi_dbm=[-80, -55],
                 age_ms=[4000, 200])
    obs = wifi_observations(rows)
    assert len(obs) == 1 and obs["rssi_dbm"].iloc[0] == -55 and obs["ap"].iloc[0] == rows[
        "bssid"].iloc[1]


def test_one_reference_point_per_scan_with_cell_zero(wifi_obs):
    obs = wifi_obs["F1"]
    db = build_fingerprints(obs, cell_m=0, max_age_ms=None)
    assert len(db) == obs["scan_id"].nunique() and (db.rp["n_scans"] == 1).all()
    assert (db.fp["detection_rate"] == 1).all()


def test_rssi_out_of_range_is_refused_with_a_clear_message():
    rows = _rows(rssi_dbm=[-60, 12, -300], bssid=["a1", "a2", "a3"])
    with pytest.raises(FingerprintError, match=r"2 RSSI values outside \[-127, 0\] dBm"):
        wifi_observations(rows)
    assert wifi_observations(rows, invalid="drop")["rssi_dbm"].tolist() == [-60]
    with pytest.raises(IndoormapError):           # one root for every indoormap error
        wifi_observations(rows.drop(columns=["bssid"]))
    # 0 dBm is no reading (a store ingested before the reader refused it may hold such rows)
    zero = _rows(rssi_dbm=[-60, 0], bssid=["a1", "a2"])
    assert wifi_observations(zero, invalid="drop")["rssi_dbm"].tolist() == [-60]


def test_floor_without_wifi_gives_a_clear_error(sample_store):
    from survey.process_store import processed_table

    rows = processed_table(sample_store, "wifi", floor="F1").iloc[:0]
    obs = wifi_observations(rows)
    assert len(obs) == 0
    with pytest.raises(FingerprintError, match="no positioned wifi scans"):
        build_fingerprints(obs)
    stale = _rows(age_ms=60_000)
    with pytest.raises(FingerprintError, match="no wifi rows younger than 6000"):
        build_fingerprints(wifi_observations(stale))


def test_walk_without_wifi_is_simply_absent(sample_store, wifi_obs):
    from survey.store import SurveyStore

    cat = SurveyStore.open(sample_store).catalog()
    silent = cat[cat["n_scans"] == 0]["trace_id"].tolist()
    assert silent, "the sample site has one walk without Wi-Fi"
    assert not wifi_obs["F1"]["trace_id"].isin(silent).any()


def test_tables_round_trip_and_bad_tables(wifi_obs):
    db = build_fingerprints(wifi_obs["F1"])
    back = FingerprintDB.from_tables(db.to_tables())
    pd.testing.assert_frame_equal(back.fp, db.fp)
    pd.testing.assert_frame_equal(back.rp, db.rp)
    assert (back.kind, back.cell_m, back.max_age_ms) == ("wifi", 1.0, 6000.0)
    tables = db.to_tables()
    tables["fp"] = tables["fp"].drop(columns=["var_db2"])
    with pytest.raises(FingerprintError, match="lacks columns"):
        FingerprintDB.from_tables(tables)


def test_ble_fingerprints_work_like_wifi(ble_obs):
    obs = ble_obs["F2"]
    assert obs["ap"].str.fullmatch(r"[^:]+:\d+:\d+@([0-9a-f]{2}:){5}[0-9a-f]{2}").all()  # key@mac
    errs, guess = [], []
    for held in walk_ids(obs):
        train, test = split_walks(obs, held)
        db = build_fingerprints(train, kind="ble", cell_m=2.0)
        assert db.max_age_ms is None and db.kind == "ble"
        scans = scan_set(test)
        res = default_matcher().fit(db).predict(scans)
        errs.append(np.linalg.norm(res.xy_m - scans.xy_m, axis=1))
        guess.append(np.linalg.norm(db.rp[["x_m", "y_m"]].mean().to_numpy() - scans.xy_m,
                                    axis=1))
    err, base = np.concatenate(errs), np.concatenate(guess)
    assert np.isfinite(err).all()
    assert np.median(err) < 0.8 * np.median(base)   # beacons locate, if coarsely


@pytest.mark.shared
def test_ble_fingerprints_on_real_beacon_rows(ilc_floor, tmp_path):
    from survey.ingest import ingest
    from survey.process_store import process_store, processed_table

    """Real beacons share uuid:major:minor keys (one key for most of them): keyed with their
    MAC, held-out walks locate clearly better than the floor's centre."""
    files = sorted((ilc_floor / "path_data_files").glob("*.txt*"))[:36]
    ingest(files, tmp_path / "s")
    process_store(tmp_path / "s")
    obs = ble_observations(processed_table(tmp_path / "s", "ble"))
    assert obs["ap"].str.contains("@").all()
    walks = np.unique(obs["trace_id"])
    held = np.isin(obs["trace_id"], walks[::3])
    db = build_fingerprints(obs[~held], kind="ble")
    scans = scan_set(obs[held], db.aps)
    res = default_matcher().fit(db).predict(scans)
    ok = np.isfinite(res.xy_m[:, 0])
    err = np.linalg.norm(res.xy_m[ok] - scans.xy_m[ok], axis=1)
    centre = np.linalg.norm(db.rp[["x_m", "y_m"]].mean().to_numpy() - scans.xy_m[ok], axis=1)
    assert ok.mean() > 0.8 and np.median(err) < 0.5 * np.median(centre)


def test_ble_window_groups_sightings():
    rows = pd.DataFrame({"trace_id": "w", "t_ms": [0, 500, 1500, 2500], "key": ["U:1:2"] * 3 + [
        "U:1:3"], "rssi_dbm": [-70, -80, -60, -90], "x_m": [0.0, 1, 2, 3], "y_m": 0.0})
    obs = ble_observations(rows, window_ms=2000)
    assert obs["scan_id"].tolist() == [0, 1]
    assert obs["rssi_dbm"].tolist() == [-70, -90]      # mean of -70, -80, -60
    assert obs["ap"].tolist() == ["u:1:2", "u:1:3"] and obs["x_m"].tolist() == [1.0, 3.0]
    with_mac = ble_observations(rows.assign(mac=["AA:00:00:00:00:01"] * 2 + [""] * 2))
    assert with_mac["ap"].tolist() == ["u:1:2", "u:1:2@aa:00:00:00:00:01", "u:1:3"]
    with pytest.raises(FingerprintError, match="window_ms must be positive"):
        ble_observations(rows, window_ms=0)
