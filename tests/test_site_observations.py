"""The build's radio inputs are read walk by walk (bounded memory, docs/reliability.md): the
result must equal the whole-floor computation exactly, with compact text columns."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pandas.testing as pdt

from mapping.floor_model import fit_floor_model
from mapping.radio_build import site_observations
from mapping.radio_scans import OBS_COLUMNS, ble_observations, wifi_observations
from survey.process_store import processed_table
from survey.store import SurveyStore

from radio_fixtures import sample_store  # noqa: F401


def _plain(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.copy()
    for c in out.columns:
        if isinstance(out[c].dtype, pd.CategoricalDtype) or out[c].dtype == object:
            out[c] = out[c].astype(str)
    return out.reset_index(drop=True)


def test_walk_by_walk_equals_whole_floor(sample_store):  # noqa: F811
    st = SurveyStore.open(sample_store)
    for kind, whole in (("wifi", lambda r: wifi_observations(r, invalid="drop")),
                        ("ble", lambda r: ble_observations(r, invalid="drop"))):
        got = site_observations(st, None, ["F1", "F2"], kind)
        assert len(got)
        for col in ("trace_id", "ap", "floor"):
            assert isinstance(got[col].dtype, pd.CategoricalDtype), col
        expected = []
        for floor in ("F1", "F2"):
            rows = processed_table(st, kind, floor=floor)
            obs = whole(rows).assign(floor=floor)
            if kind == "wifi":
                ssid = (rows.assign(ap=rows["bssid"].astype(str).str.lower())
                        .drop_duplicates("ap").set_index("ap")["ssid"].astype(str))
                obs["ssid"] = obs["ap"].map(ssid).fillna("")
            else:
                obs["ssid"] = ""
            expected.append(obs)
        exp = pd.concat(expected, ignore_index=True)
        # scan ids: unique over the site, numbered floor by floor, walk by walk
        key = exp["floor"] + "\x00" + exp["scan_id"].astype(str)
        exp["scan_id"] = pd.factorize(key)[0].astype(np.int64)
        cols = [*OBS_COLUMNS, "ssid", "floor"]
        pdt.assert_frame_equal(_plain(got[cols]), _plain(exp[cols]), check_dtype=False)


def test_store_part_equals_table_rows(sample_store):  # noqa: F811
    st = SurveyStore.open(sample_store)
    row = st.catalog().iloc[1]
    for name in ("sensors", "wifi", "ble", "waypoints"):
        pdt.assert_frame_equal(st.part(name, row), st.table(name, trace_ids=[row["trace_id"]]))
    part = st.part("sensors", row, columns=["t_ms", "x"])
    assert list(part.columns) == ["trace_id", "t_ms", "x"]


def test_one_floor_model_needs_no_regression(sample_store):  # noqa: F811
    st = SurveyStore.open(sample_store)
    obs = site_observations(st, None, ["F1"], "wifi")
    model = fit_floor_model({"F1": obs})
    assert model.floors.tolist() == ["F1"]
    assert (model.coef == 0).all() and len(model.aps) > 0
    assert model.meta["n_scans"] == obs["scan_id"].nunique()
    assert model.meta["n_walks"] == obs["trace_id"].nunique()
