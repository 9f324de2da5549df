"""Fixtures of the Wi-Fi/BLE tests: the simulated sample site, ingested and processed once per
session, its bundles built once per session (read only: copy them to change them), and its
ground truth (devices with their RSSI distortion)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mapping.radio_scans import ble_observations, wifi_observations
from survey.ingest import ingest
from survey.process_store import process_store, processed_table
from survey.store import SurveyStore

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"


@pytest.fixture(scope="session")
def sample_store(tmp_path_factory) -> Path:
    store = tmp_path_factory.mktemp("radio") / "store"
    ingest([SITE / "F1" / "path_data_files", SITE / "F2" / "path_data_files"], store)
    process_store(store)
    return store


@pytest.fixture(scope="session")
def built(tmp_path_factory) -> Path:
    """The whole sample site built with `indoormap build` (floors and ``_site``)."""
    from click.testing import CliRunner

    from survey.cli import main

    out = tmp_path_factory.mktemp("sample_bundles") / "bundles"
    res = CliRunner().invoke(main, ["build", str(SITE), "-o", str(out)])
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture(scope="session")
def sample_truth() -> dict:
    return json.loads((SITE / "truth" / "site.json").read_text())


@pytest.fixture(scope="session")
def device_of(sample_store) -> dict[str, str]:
    cat = SurveyStore.open(sample_store).catalog()
    return dict(zip(cat["trace_id"], cat["device_model"]))


@pytest.fixture(scope="session")
def wifi_obs(sample_store) -> dict[str, pd.DataFrame]:
    """Floor -> Wi-Fi observation table (rows of any age)."""
    return {f: wifi_observations(processed_table(sample_store, "wifi", floor=f))
            for f in ("F1", "F2")}


@pytest.fixture(scope="session")
def ble_obs(sample_store) -> dict[str, pd.DataFrame]:
    """Floor -> BLE observation table (4 s windows: the simulated beacons are sparse)."""
    return {f: ble_observations(processed_table(sample_store, "ble", floor=f), window_ms=4000)
            for f in ("F1", "F2")}


def split_walks(obs: pd.DataFrame, held: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    test = obs["trace_id"].to_numpy() == held
    return obs[~test], obs[test]


def walk_ids(obs: pd.DataFrame) -> list[str]:
    return sorted(np.unique(obs["trace_id"].to_numpy().astype(str)).tolist())
