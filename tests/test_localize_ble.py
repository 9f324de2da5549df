"""BLE fallback of the localizer (``localize.walk_radio.walk_radio``, ``indoormap localize`` and
``evaluate``): a walk without Wi-Fi is located from the bundle's BLE fingerprints, a walk with
Wi-Fi still from Wi-Fi. The walk is held out of the bundle, so its errors are honest."""

from __future__ import annotations

import csv
import gzip
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from localize.bundle import load_bundle
from localize.steps import RadioScan
from localize.walk_radio import walk_radio
from survey.cli import main
from survey.step_summaries import ble_scans_of, step_summaries
from survey.trace_reader import read_trace

from radio_fixtures import SITE, sample_truth  # noqa: F401  (fixture)

#: A walk whose first BLE window is located 0.7 m from the truth by the others' fingerprints.
HELD = "641046ffdf517c629fdd39b3"
WALK = SITE / "F1" / "path_data_files" / f"{HELD}.txt.gz"


@pytest.fixture(scope="module")
def held_out(tmp_path_factory) -> Path:
    """F1's bundle built without :data:`HELD` (Wi-Fi and BLE fingerprints of the others)."""
    out = tmp_path_factory.mktemp("ble") / "bundles"
    res = CliRunner().invoke(main, ["build", str(SITE / "F1"), "-o", str(out), "--exclude",
                                    HELD])
    assert res.exit_code == 0, res.output
    return out / "F1"


@pytest.fixture(scope="module")
def no_wifi(tmp_path_factory) -> Path:
    """:data:`HELD` with its Wi-Fi rows removed (beacons, sensors and waypoints kept)."""
    lines = gzip.decompress(WALK.read_bytes()).decode().splitlines(keepends=True)
    path = tmp_path_factory.mktemp("walks") / f"{HELD}.txt"
    path.write_text("".join(ln for ln in lines if "TYPE_WIFI" not in ln))
    return path


def _truth_at(sample_truth, t_ms):  # noqa: F811
    w = next(w for w in sample_truth["walks"] if w["trace_id"] == HELD)
    truth = pd.read_parquet(SITE / w["truth_path"])
    return np.column_stack([np.interp(t_ms, truth["t_ms"], truth[c]) for c in ("x_m", "y_m")])


def test_walk_radio_takes_wifi_first_then_ble(held_out, no_wifi):
    bundle = load_bundle(held_out)
    full = read_trace(WALK)
    wr = walk_radio(bundle, full.header.model, step_summaries(full), ble_scans_of(full))
    assert (wr.kind, wr.reason, wr.fix_name) == ("wifi", "", "Wi-Fi")
    assert "device table" in wr.calibration

    bare = read_trace(no_wifi)
    steps, ble = step_summaries(bare), ble_scans_of(bare)
    assert all(sc is None for sc in steps.scans) and len(ble) > 10
    wr = walk_radio(bundle, bare.header.model, steps, ble)
    assert (wr.kind, wr.reason, wr.fix_name) == ("ble", "no Wi-Fi scans in the walk", "BLE")
    on_steps = [sc for sc in wr.steps.scans if sc is not None]
    assert len(on_steps) > 10 and all("@" in k for sc in on_steps for k in sc.keys)
    assert walk_radio(bundle, bare.header.model, steps).kind == "wifi"  # no BLE windows given

    # Wi-Fi scans that hear no transmitter of the bundle: BLE too, and said why
    strangers = [RadioScan(int(t), np.array(["00:00:00:00:00:01"]), np.array([-60.0]))
                 for t in steps.t_ms[::10]]
    wr = walk_radio(bundle, bare.header.model, steps.with_scans(strangers), ble)
    assert (wr.kind, wr.reason) == ("ble", "no Wi-Fi scan of the walk located")


def test_localize_starts_a_walk_without_wifi_at_its_first_ble_fix(held_out, no_wifi, tmp_path,
                                                                   sample_truth):  # noqa: F811
    res = CliRunner().invoke(main, ["localize", str(held_out), str(no_wifi), "-o",
                                    str(tmp_path / "o"), "--no-plot", "--method", "pdr"])
    assert res.exit_code == 0, res.output
    assert "start first BLE fix (no Wi-Fi scans in the walk)" in res.output
    track = pd.read_parquet(tmp_path / "o" / f"{HELD}.parquet")
    t = track["t_ms"].to_numpy(np.float64)
    err = np.hypot(*(track[["x_m", "y_m"]].to_numpy() - _truth_at(sample_truth, t)).T)
    assert err[:5].max() < 3.0  # the first BLE window is 0.7 m off; walking on from it
    assert np.median(err) < 3.0


def test_evaluate_scores_a_walk_without_wifi_on_ble_and_one_with_wifi_on_wifi(
        held_out, no_wifi, tmp_path):
    """Every method runs on the BLE walk (``radio`` had no fix at all before), within BLE's
    accuracy; the same walk with its Wi-Fi rows is scored on Wi-Fi, and better."""
    scores = {}
    for name, walk in (("ble", no_wifi), ("wifi", WALK)):
        table = tmp_path / f"{name}.csv"
        res = CliRunner().invoke(main, ["evaluate", str(held_out), str(walk), "--method",
                                        "indoormap,radio,pdr", "--particles", "200", "--csv",
                                        str(table)])
        assert res.exit_code == 0, res.output
        assert (f"{HELD}: start first BLE fix (no Wi-Fi scans in the walk)" in res.output) == \
            (name == "ble")
        with table.open() as f:
            rows = list(csv.DictReader(f))
        scores[name] = {m: np.median([float(r["error_m"]) for r in rows if r["method"] == m])
                        for m in ("indoormap", "radio", "pdr")}
        assert sum(r["method"] == "radio" for r in rows) == 8  # every waypoint
    assert scores["ble"]["radio"] < 8.0 and scores["ble"]["indoormap"] < 6.0
    assert scores["ble"]["pdr"] < 2.0  # started 0.7 m off at the first BLE fix
    assert scores["wifi"]["radio"] < scores["ble"]["radio"]
    assert scores["wifi"]["indoormap"] < scores["ble"]["indoormap"]
