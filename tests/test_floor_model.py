"""Floor model: accuracy with walks held out, plain-table round trip, bad input."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from radio_fixtures import sample_store, wifi_obs  # noqa: F401

from mapping.errors import FingerprintError
from mapping.floor_model import FloorModel, cross_validate_floor_model, fit_floor_model
from mapping.radio_scans import scan_set


def test_cross_validated_accuracy_on_the_simulated_site(wifi_obs):
    cv = cross_validate_floor_model(wifi_obs, folds=5)
    assert cv.n_walks == 11 and cv.n_scans == sum(o["scan_id"].nunique()
                                                 for o in wifi_obs.values())
    assert cv.scan_accuracy >= 0.97 and cv.walk_accuracy == 1.0
    assert cv.sequence_accuracy >= cv.scan_accuracy - 1e-9
    assert cv.confusion.to_numpy().sum() == cv.n_scans


def test_tables_round_trip_predicts_the_same(wifi_obs):
    model = fit_floor_model(wifi_obs, cv_folds=3)
    assert model.meta["cv_folds"] == 3 and model.meta["cv_scan_accuracy"] > 0.9
    tables = model.to_tables()
    assert set(tables) == {"coef", "intercept", "meta"}
    assert all(isinstance(t, pd.DataFrame) for t in tables.values())
    back = FloorModel.from_tables(tables)
    scans = scan_set(wifi_obs["F2"])
    assert np.array_equal(back.predict(scans), model.predict(scans))
    assert np.allclose(back.log_proba(scans), model.log_proba(scans))
    assert back.meta["cv_scan_accuracy"] == model.meta["cv_scan_accuracy"]
    walks = back.predict_walks(scans)
    assert (walks == "F2").all() and len(walks) == wifi_obs["F2"]["trace_id"].nunique()
    seq = back.predict_sequence(scans, window=3)
    assert (seq == "F2").mean() >= (back.predict(scans) == "F2").mean()


def test_scan_without_known_ap_and_localizer_scan(wifi_obs):
    model = fit_floor_model(wifi_obs)
    obs = pd.DataFrame({"trace_id": "q", "scan_id": [0, 1], "t_ms": [0, 1], "x_m": np.nan,
                        "y_m": np.nan, "ap": ["zz:zz", wifi_obs["F1"]["ap"].iloc[0]],
                        "rssi_dbm": -60.0, "age_ms": 0.0})
    pred = model.predict(scan_set(obs))
    assert pred[0] == "" and pred[1] in ("F1", "F2")
    assert np.isnan(model.log_proba(scan_set(obs))[0]).all()

    class Scan:  # duck type of localize.steps.RadioScan
        keys = np.array(["zz:zz"])
        rssi_dbm = np.array([-60.0])

    assert model.floor_of(Scan()) is None
    Scan.keys = model.aps[np.argsort(model.coef[1] - model.coef[0])[-5:]]  # F2's strongest
    Scan.rssi_dbm = np.full(len(Scan.keys), -60.0)
    assert model.floor_of(Scan()) == "F2"


def test_floor_without_wifi_is_skipped_and_no_wifi_at_all_refused(wifi_obs):
    empty = wifi_obs["F1"].iloc[:0]
    model = fit_floor_model({"F0": empty, **wifi_obs})
    assert model.meta["skipped_floors"] == ["F0"] and model.floors.tolist() == ["F1", "F2"]
    assert FloorModel.from_tables(model.to_tables()).meta["skipped_floors"] == ["F0"]
    with pytest.raises(FingerprintError, match="no floor has any scan"):
        fit_floor_model({"F0": empty})
    single = fit_floor_model({"F2": wifi_obs["F2"]})
    assert (single.predict(scan_set(wifi_obs["F2"])) == "F2").all()
    with pytest.raises(FingerprintError, match="lacks"):
        FloorModel.from_tables({"coef": pd.DataFrame({"ap": []})})


def test_an_unknown_feature_is_refused_by_fit_cross_validation_and_tables(wifi_obs):
    """The mapping side raises its own error, naming the feature, before any work."""
    message = r"feature must be one of \('level', 'presence'\), not 'rank'"
    with pytest.raises(FingerprintError, match=message):
        fit_floor_model(wifi_obs, feature="rank")
    with pytest.raises(FingerprintError, match=message):
        cross_validate_floor_model(wifi_obs, feature="rank")
    tables = fit_floor_model(wifi_obs, feature="presence").to_tables()
    tables["meta"]["feature"] = "rank"
    with pytest.raises(FingerprintError, match=message):
        FloorModel.from_tables(tables)
