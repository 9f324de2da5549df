"""The site bundle's BLE floor model: built beside the Wi-Fi one, and used by ``SiteMaps`` (so by
``localize``, ``evaluate``, ``wifi-locate``) and ``floor`` for a walk that names no floor and has
no Wi-Fi scan the Wi-Fi model classifies (an iPhone logs BLE only). Wi-Fi stays first; a site
bundle built before the BLE model (none in it) still loads and behaves as before."""

from __future__ import annotations

import csv
import gzip
import io
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from localize.bundle import load_bundle
from localize.errors import LocalizationError
from localize.floor_classifier import FloorClassifier, floor_model_kind, site_floor_models
from localize.floors import SiteMaps
from localize.steps import RadioScan
from mapping.bundle_writer import BundleContent, write_bundle
from mapping.radio_build import RadioParams, site_observations, site_radio
from survey.cli import main
from survey.step_summaries import ble_scans_of, scans_of
from survey.store import SurveyStore
from survey.trace_reader import read_trace

from radio_fixtures import SITE, sample_store  # noqa: F401  (fixture)

#: An F1 walk held out of the build: its floor must come from the others' BLE windows.
HELD = "641046ffdf517c629fdd39b3"
WALK = SITE / "F1" / "path_data_files" / f"{HELD}.txt.gz"
#: An F2 walk (its Wi-Fi scans say F2).
F2_WALK = min((SITE / "F2" / "path_data_files").glob("*.txt.gz"))


def _lines(path: Path) -> list[str]:
    return gzip.decompress(path.read_bytes()).decode().splitlines(keepends=True)


def _without(path: Path, target: Path, *, header=False, wifi=False, ble=False) -> Path:
    """``path`` written to ``target`` without its header lines (so no floor, site or phone),
    Wi-Fi rows and/or beacon rows."""
    def keep(ln: str) -> bool:
        return not ((header and ln.startswith("#")) or (wifi and "\tTYPE_WIFI" in ln)
                    or (ble and "\tTYPE_BEACON" in ln))
    target.write_text("".join(ln for ln in _lines(path) if keep(ln)))
    return target


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """Both floors built without :data:`HELD`."""
    out = tmp_path_factory.mktemp("floor_ble") / "bundles"
    res = CliRunner().invoke(main, ["build", str(SITE), "-o", str(out), "--exclude", HELD])
    assert res.exit_code == 0, res.output
    assert "floor model (ble, beside Wi-Fi, presence): 2 floors" in res.output
    assert "; BLE floor model per BLE window " in res.output
    return out


@pytest.fixture(scope="module")
def old_style(built, tmp_path_factory) -> Path:
    """``built`` with its site bundle rewritten as builds before the BLE floor model wrote it:
    no ``ble_floor_*`` tables, no ``metrics.ble_floor_model`` (same schema version)."""
    out = tmp_path_factory.mktemp("floor_ble_old") / "bundles"
    for floor in ("F1", "F2"):
        shutil.copytree(built / floor, out / floor)
    site = load_bundle(built / "_site")
    m = site.manifest
    write_bundle(out / "_site", BundleContent(
        site_id=m["site_id"], floor_id="", floor_name="", kind="site",
        tables={n: site.table(n) for n in m["tables"] if not n.startswith("ble_floor_")},
        build=m["build"], metrics={k: v for k, v in m["metrics"].items()
                                   if k != "ble_floor_model"}))
    return out


@pytest.fixture(scope="module")
def bare(tmp_path_factory) -> Path:
    """:data:`HELD` without its header (no floor named) and without its Wi-Fi rows."""
    return _without(WALK, tmp_path_factory.mktemp("walks") / f"{HELD}.txt", header=True,
                    wifi=True)


def _rows(text: str) -> list[dict]:
    lines = [ln for ln in text.splitlines() if "," in ln]
    return list(csv.DictReader(io.StringIO("\n".join(lines))))


def test_the_site_bundle_holds_a_ble_floor_model_beside_the_wifi_one(built):
    site = load_bundle(built / "_site")
    metrics = site.manifest["metrics"]
    assert metrics["floor_model"]["kind"] == "wifi"
    ble = metrics["ble_floor_model"]
    assert ble["kind"] == "ble" and ble["floors"] == ["F1", "F2"] and ble["cv_folds"] == 5
    assert ble["feature"] == "presence" and metrics["floor_model"]["feature"] == "level"
    # 11 walks, 8 beacons a floor: presence 100 % of the BLE windows and walks (levels: 74.7 %
    # of the windows)
    assert ble["cv_scan_accuracy"] >= 0.95 and ble["cv_walk_accuracy"] == 1.0
    assert all(site.has_table(f"ble_floor_{n}") for n in ("coef", "intercept", "meta"))
    assert floor_model_kind(site) == "wifi"
    models = site_floor_models(site)
    assert sorted(models) == ["ble", "wifi"]
    assert all("@" in k for k in models["ble"].aps) and not any("@" in k for k in
                                                               models["wifi"].aps)
    assert FloorClassifier.from_bundle(site).aps.tolist() == models["wifi"].aps.tolist()
    with pytest.raises(LocalizationError, match="kind must be one of"):
        FloorClassifier.from_bundle(site, "uwb")
    maps = SiteMaps.open(built)
    assert maps.floor_model is not None and maps.ble_floor_model is not None


def test_a_walk_without_wifi_and_floor_header_is_put_on_its_floor_by_ble(built, bare,
                                                                        tmp_path):
    trace = read_trace(bare)
    assert not trace.header.floor_id and not trace.header.floor_name and not scans_of(trace)
    maps = SiteMaps.open(built)
    f1 = load_bundle(built / "F1")
    bundle, how = maps.choose(trace.trace_id, "", "", "", scans_of(trace), ble_scans_of(trace))
    assert bundle.floor_id == f1.floor_id
    assert how.startswith("BLE floor model (") and how.endswith("; no Wi-Fi scans in the walk")
    assert maps.select_for(trace.trace_id, "", "", "", [], ble_scans_of(trace)) is bundle
    with pytest.raises(LocalizationError, match="no BLE windows in the walk"):
        maps.select_for(trace.trace_id, "", "", "", [])  # the fallback needs the windows

    runner = CliRunner()
    res = runner.invoke(main, ["localize", str(built), str(bare), "-o", str(tmp_path / "loc"),
                               "--no-plot", "--particles", "100"])
    assert res.exit_code == 0, res.output
    assert f"{HELD}: floor F1 by the BLE floor model (" in res.output
    assert f"steps on {f1.floor_id} (F1)" in res.output
    track = pd.read_parquet(tmp_path / "loc" / f"{HELD}.parquet")
    row, col, inside = f1.grid.cell_of(track["x_m"].to_numpy(), track["y_m"].to_numpy())
    assert inside.all()  # on F1's grid (84 % of the steps on its mask: BLE fixes are rough)

    res = runner.invoke(main, ["evaluate", str(built), str(bare), "--method", "radio"])
    assert res.exit_code == 0, res.output
    assert "floor F1 by the BLE floor model" in res.output
    res = runner.invoke(main, ["wifi-locate", "--kind", "ble", str(built), str(bare)])
    assert res.exit_code == 0, res.output
    assert {r["floor"] for r in _rows(res.stdout)} == {"F1"}
    res = runner.invoke(main, ["floor", str(built), str(bare)])
    assert res.exit_code == 0, res.output
    walk = [r for r in _rows(res.stdout) if r["level"] == "walk"]
    assert [(r["floor"], r["kind"], r["recorded_floor"]) for r in walk] == [("F1", "ble", "")]
    # asked for BLE of a walk with none: said so (it read "no ble scan hears a transmitter")
    no_ble = _without(WALK, tmp_path / "no_ble.txt", ble=True)
    res = runner.invoke(main, ["floor", "--kind", "ble", str(built), str(no_ble)])
    assert res.exit_code == 1 and ": no BLE windows in the walk; floor unknown" in res.stderr


def _reading(ble: list, offset_db: float) -> list:
    """BLE windows as a phone whose RSSI reads ``offset_db`` dB higher would log them."""
    return [None if s is None else RadioScan(s.t_ms, s.keys, s.rssi_dbm + offset_db)
            for s in ble]


def test_a_phone_whose_ble_reads_low_is_put_on_its_floor(built, sample_store):  # noqa: F811
    """The BLE floor model reads presence: a phone (one the device table cannot know: BLE
    only) whose BLE RSSI reads 20 dB low is put on the floor, with the same windows, as one
    that reads like the survey phones. A model on levels, fitted on the same windows, puts
    some F1 walks on F2 then (the weak beacons it weighs fall under its -100 dBm floor)."""
    maps = SiteMaps.open(built)
    f1 = load_bundle(built / "F1").floor_id
    walks = [read_trace(p) for p in sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))]
    assert HELD in {t.trace_id for t in walks} and len(walks) == 6
    for t in walks:
        ble = ble_scans_of(t)
        bundle, how = maps.choose(t.trace_id, "", "", "", [], ble)
        low, how_low = maps.choose(t.trace_id, "", "", "", [], _reading(ble, -20.0))
        assert bundle.floor_id == low.floor_id == f1 and how_low == how, (t.trace_id, how_low)

    store = SurveyStore.open(sample_store)
    obs = {k: site_observations(store, None, ["F1", "F2"], k) for k in ("wifi", "ble")}
    device_of = store.catalog().set_index("trace_id")["device_model"].astype(str)
    levels = site_radio(obs, device_of, ["F1", "F2"],
                        params=RadioParams(ble_floor_feature="level")).ble_floor_model
    assert levels.feature == "level"
    level_maps = SiteMaps(maps.bundles.values(), ble_floor_model=levels.classifier())
    wrong = [t.trace_id for t in walks if level_maps.choose(
        t.trace_id, "", "", "", [], _reading(ble_scans_of(t), -20.0))[0].floor_id != f1]
    assert 1 <= len(wrong) < len(walks)


def test_a_walk_with_neither_gets_an_error_naming_what_was_missing(built, tmp_path):
    nothing = _without(WALK, tmp_path / "nothing.txt", header=True, wifi=True, ble=True)
    trace = read_trace(nothing)
    maps = SiteMaps.open(built)
    with pytest.raises(LocalizationError) as err:
        maps.select_for(trace.trace_id, "", "", "", scans_of(trace), ble_scans_of(trace))
    msg = str(err.value)
    assert "names no floor" in msg and "no Wi-Fi scans in the walk; no BLE windows in the walk" \
        in msg and "floors: F1, F2" in msg
    # scans the models do not know, and no models at all, are named too
    stranger = [RadioScan(0, np.array(["00:00:00:00:00:01"]), np.array([-60.0]))]
    with pytest.raises(LocalizationError, match="none of its 1 Wi-Fi scans hears a transmitter "
                       "the Wi-Fi floor model knows; none of its 1 BLE windows hears"):
        maps.select_for("w", "", "", "", stranger, stranger)
    floors = [load_bundle(built / f) for f in ("F1", "F2")]
    with pytest.raises(LocalizationError, match=r"no Wi-Fi floor model \(no site bundle given\); "
                       r"no BLE floor model \(no site bundle given\)"):
        SiteMaps(floors).select_for("w", "", "", "", stranger, stranger)
    res = CliRunner().invoke(main, ["localize", str(built), str(nothing), "-o",
                                    str(tmp_path / "o"), "--no-plot"])
    assert res.exit_code == 1
    assert "no Wi-Fi scans in the walk; no BLE windows in the walk" in res.output


def test_wifi_decides_when_wifi_and_ble_disagree(built):
    """The F2 walk's Wi-Fi scans with the F1 walk's BLE windows: F2, by Wi-Fi."""
    maps = SiteMaps.open(built)
    wifi_f2 = scans_of(read_trace(F2_WALK))
    ble_f1 = ble_scans_of(read_trace(WALK))
    f1, f2 = (load_bundle(built / f).floor_id for f in ("F1", "F2"))
    alone, how = maps.choose("w", "", "", "", [], ble_f1)
    assert alone.floor_id == f1 and how.startswith("BLE")  # BLE alone says F1
    both, how = maps.choose("w", "", "", "", wifi_f2, ble_f1)
    assert both.floor_id == f2 and how.startswith("Wi-Fi floor model (")
    # the header still comes first (the Wi-Fi floor model's doubt is said)
    named, how = maps.choose("w", "", "", "F1", wifi_f2, ble_f1)
    assert named.floor_id == f1 and how.startswith(
        "floor name in the trace header; but the Wi-Fi floor model puts")


def test_an_old_site_bundle_without_the_ble_model_works_as_before(old_style, bare, tmp_path):
    site = load_bundle(old_style / "_site")
    assert not site.has_table("ble_floor_coef")
    assert "ble_floor_model" not in site.manifest["metrics"]
    assert sorted(site_floor_models(site)) == ["wifi"]
    assert FloorClassifier.from_bundle(site, "ble") is None
    maps = SiteMaps.open(old_style)
    assert maps.floor_model is not None and maps.ble_floor_model is None
    # a walk with Wi-Fi and no header: the Wi-Fi model, as before
    wifi_bare = _without(F2_WALK, tmp_path / "f2.txt", header=True)
    t = read_trace(wifi_bare)
    bundle, how = maps.choose(t.trace_id, "", "", "", scans_of(t), ble_scans_of(t))
    assert bundle.manifest["floor_name"] == "F2" and how.startswith("Wi-Fi floor model")
    # a walk without Wi-Fi and no header: refused, saying the BLE floor model is missing
    t = read_trace(bare)
    with pytest.raises(LocalizationError, match="no Wi-Fi scans in the walk; no BLE floor "
                                                "model in the site bundle"):
        maps.select_for(t.trace_id, "", "", "", scans_of(t), ble_scans_of(t))
    runner = CliRunner()
    res = runner.invoke(main, ["floor", str(old_style), str(bare)])
    assert res.exit_code == 1 and "floor unknown" in res.stderr
    assert not _rows(res.stdout)
    res = runner.invoke(main, ["floor", "--kind", "ble", str(old_style), str(bare)])
    assert res.exit_code == 1 and "has no ble floor model" in res.output
    res = runner.invoke(main, ["localize", str(old_style), str(WALK), "-o", str(tmp_path / "o"),
                               "--no-plot", "--method", "pdr"])  # the header names the floor
    assert res.exit_code == 0, res.output


def test_ble_floor_model_needs_ble_on_two_floors_and_a_ble_only_site_keeps_one_model(
        sample_store, tmp_path):  # noqa: F811
    store = SurveyStore.open(sample_store)
    obs = {k: site_observations(store, None, ["F1", "F2"], k) for k in ("wifi", "ble")}
    device_of = store.catalog().set_index("trace_id")["device_model"].astype(str)
    both = site_radio(obs, device_of, ["F1", "F2"])
    assert both.floor_model_kind == "wifi" and both.ble_floor_model is not None
    one_floor_ble = {"wifi": obs["wifi"], "ble": obs["ble"][obs["ble"]["floor"] == "F1"]}
    radio = site_radio(one_floor_ble, device_of, ["F1", "F2"])
    assert radio.floor_model_kind == "wifi" and radio.ble_floor_model is None
    assert "no ble floor model: ble rows on 1 floor(s), two needed" in radio.notes
    content = radio.site_content("s")
    assert content.metrics["ble_floor_model"] is None
    assert not any(n.startswith("ble_floor_") for n in content.tables)
    # a site surveyed without Wi-Fi: its one floor model is BLE, used for BLE windows
    ble_only = site_radio({"ble": obs["ble"]}, device_of, ["F1", "F2"])
    assert ble_only.floor_model_kind == "ble" and ble_only.ble_floor_model is None
    write_bundle(tmp_path / "_site", ble_only.site_content("s"))
    site = load_bundle(tmp_path / "_site")
    assert floor_model_kind(site) == "ble" and sorted(site_floor_models(site)) == ["ble"]
    assert FloorClassifier.from_bundle(site, "wifi") is None


def test_validate_reports_the_ble_floor_model_of_the_site_bundle(built, old_style):
    from types import SimpleNamespace

    from mapping.radio_validation import radio_summary
    from mapping.report_html import _section_radio

    summary = radio_summary(load_bundle(built / "F1"), None, "F1", None)
    ble = summary["ble_floor_model"]
    assert ble == load_bundle(built / "_site").manifest["metrics"]["ble_floor_model"]
    html = _section_radio(SimpleNamespace(metrics={"radio": {"available": True, **summary}}))
    assert "BLE floor model (site bundle" in html
    assert f"per BLE window {100 * ble['cv_scan_accuracy']:.2f} %" in html
    old = radio_summary(load_bundle(old_style / "F1"), None, "F1", None)
    assert old["floor_model"] is not None and old["ble_floor_model"] is None
    html = _section_radio(SimpleNamespace(metrics={"radio": {"available": True, **old}}))
    assert "Floor model (wifi" in html and "BLE floor model" not in html
