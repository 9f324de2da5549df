"""Radio maps in the bundles: what `indoormap build` writes, what the localizer reads from it,
and the `floor` / `wifi-locate` commands."""

from __future__ import annotations

import csv
import dataclasses
import gzip
import io
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from localize.bundle import load_bundle
from localize.cli_common import SeenWalks
from localize.errors import LocalizationError
from localize.fingerprint_positioner import FingerprintPositioner, fingerprint_kinds
from localize.floor_classifier import FloorClassifier
from localize.floors import SiteMaps
from localize.radio_match import BLE_MIN_STRONGEST_DBM, WalkSmoothing
from localize.steps import RadioScan
from localize.walk_radio import radio_for_walk
from mapping.fingerprints import FingerprintDB
from mapping.floor_model import FloorModel
from mapping.registry import Registry
from mapping.matching import align_scans, default_matcher, default_walk_matcher
from mapping.radio_scans import scan_set
from survey.cli import main

from radio_fixtures import (  # noqa: F401  (fixtures)
    SITE, ble_obs, built, device_of, sample_store, sample_truth, wifi_obs)


def _tables(bundle, prefix: str) -> dict:
    return {name: bundle.table(f"{prefix}_{name}").to_pandas() for name in ("rp", "fp", "meta")}


def test_a_one_floor_build_keeps_the_registrys_site_model_of_more_floors(built, tmp_path):
    """Building F1 alone with --registry replaced the registry's F1+F2 floor model by one of
    F1 only, silently: `floor` then put every F2 scan on F1."""
    reg = Registry(tmp_path / "reg")
    for name in ("F1", "F2", "_site"):
        reg.publish(built / name)
    site = load_bundle(built / "_site").site_id
    res = CliRunner().invoke(main, ["build", str(SITE / "F1"), "-o", str(tmp_path / "one"),
                                    "--registry", str(reg.root)])
    assert res.exit_code == 0, res.output
    assert f"warning: not published: the registry's current {site}/_site #1 models floors F2" \
        in res.output
    assert reg.current(site, "_site")["seq"] == 1 and len(reg.history(site, "_site")) == 1
    assert reg.current(site, "F1")["bundle_id"] == load_bundle(tmp_path / "one" / "F1").bundle_id
    fresh = CliRunner().invoke(main, ["build", str(SITE / "F1"), "-o", str(tmp_path / "two"),
                                      "--registry", str(tmp_path / "reg2")])
    assert fresh.exit_code == 0 and "not published" not in fresh.output
    assert Registry(tmp_path / "reg2").current(site, "_site")["seq"] == 1
    # the same build again, after another F1 became current, is that older version: it is
    # not made current, and the warning says how (it raised allow_rollback's refusal)
    reg2 = Registry(tmp_path / "reg2")
    assert reg2.publish(built / "F1")["seq"] == 2
    again = CliRunner().invoke(main, ["build", str(SITE / "F1"), "-o", str(tmp_path / "three"),
                                      "--registry", str(reg2.root)])
    assert again.exit_code == 0, again.output
    assert (f"warning: not made current: {tmp_path / 'three' / 'F1'}: already published as #1, "
            f"older than the current #2; to make it current: indoormap bundle use {reg2.root} "
            f"{site}/F1 '#1' --rollback") in again.output
    assert reg2.current(site, "F1")["seq"] == 2 and "allow_rollback" not in again.output


def test_build_writes_radio_tables_and_a_site_bundle(built):
    for floor in ("F1", "F2"):
        b = load_bundle(built / floor)
        assert fingerprint_kinds(b) == ["wifi", "ble"]
        db = FingerprintDB.from_tables(_tables(b, "wifi"))
        assert db.kind == "wifi" and len(db) > 50 and db.cell_m == 1.0
        fp = db.fp
        # eq. 2: unbiased variance exists only where a reference point has >= 2 rows
        assert fp.loc[fp["n"] < 2, "var_db2"].isna().all()
        assert (fp.loc[fp["n"] >= 2, "var_db2"] >= 0).all()
        assert ((fp["detection_rate"] > 0) & (fp["detection_rate"] <= 1)).all()
        radio = b.manifest["metrics"]["radio"]
        assert radio["wifi"]["reference_points"] == len(db)
        devices = b.table("devices").to_pandas()
        assert set(devices["device_model"]) == {"SIM-A1", "SIM-B2"}
    site = load_bundle(built / "_site")
    assert site.manifest["kind"] == "site" and site.grid is None
    fm = site.manifest["metrics"]["floor_model"]
    assert fm["kind"] == "wifi" and fm["floors"] == ["F1", "F2"]
    assert fm["cv_scan_accuracy"] >= 0.95 and fm["cv_folds"] == 5
    assert site.has_table("wifi_dropped") and site.has_table("floor_coef")


def test_device_table_matches_the_simulated_phone(built, sample_truth):
    """The build's device table undoes the simulated distortion rssi = k_dev * ref + b_dev."""
    dev = {d["model"]: d for d in sample_truth["devices"]} if "devices" in sample_truth else {}
    table = load_bundle(built / "F1").table("devices").to_pandas().set_index("device_model")
    assert table.loc["SIM-A1", "method"] == "reference"
    assert table.loc["SIM-A1", "k"] == 1.0 and table.loc["SIM-A1", "b"] == 0.0
    if "SIM-B2" in dev:
        k_dev, b_dev = dev["SIM-B2"]["rssi_k"], dev["SIM-B2"]["rssi_b"]
        assert table.loc["SIM-B2", "k"] == pytest.approx(1 / k_dev, abs=0.05)
        assert table.loc["SIM-B2", "b"] == pytest.approx(-b_dev / k_dev, abs=1.0)


def test_localizer_positions_equal_the_mapping_matcher(built, wifi_obs):
    """Bundle tables -> numpy positioner gives the same fixes as mapping's default matcher."""
    b = load_bundle(built / "F1")
    pos = FingerprintPositioner.from_bundle(b, "wifi")
    assert repr(pos) == (f"FingerprintPositioner({len(pos.xy_m)} reference points, "
                         f"{len(pos.aps)} emitters, k=5, rssi_k=1, rssi_b=+0 dB)")  # not tables
    with pytest.raises(LocalizationError, match="kind must be one of wifi, ble, got 'WiFi'"):
        FingerprintPositioner.from_bundle(b, "WiFi")  # it returned None: "no fingerprints"
    db = FingerprintDB.from_tables(_tables(b, "wifi"))
    obs = wifi_obs["F1"]
    scans = scan_set(obs)  # every row, with its age
    assert np.nanmax(scans.age_ms) > 4000  # old rows are there, to be down-weighted
    want = default_matcher().fit(db).predict(scans)
    rssi = np.full((len(scans), len(pos.aps)), np.nan)
    age = np.full_like(rssi, np.nan)
    idx = np.searchsorted(pos.aps, scans.aps)
    known = (idx < len(pos.aps)) & (pos.aps[np.minimum(idx, len(pos.aps) - 1)] == scans.aps)
    rssi[:, idx[known]] = scans.rssi_dbm[:, known]
    age[:, idx[known]] = scans.age_ms[:, known]
    got = pos.locate_matrix(rssi, age_ms=age)
    ok = np.isfinite(want.xy_m[:, 0])
    assert ok.mean() > 0.99
    np.testing.assert_allclose(got.xy_m[ok], want.xy_m[ok], atol=1e-6)
    assert np.all(got.sigma_m[ok] >= 1.0)
    # without the ages the old rows count in full and the fixes differ
    assert not np.allclose(pos.locate_matrix(rssi).xy_m[ok], want.xy_m[ok])
    # RadioScan objects carry the same ages through locate_scans
    one = [RadioScan(0, pos.aps[np.isfinite(r)], r[np.isfinite(r)], a[np.isfinite(r)])
           for r, a in zip(rssi[:20], age[:20])]
    np.testing.assert_allclose(pos.locate_scans(one).xy_m, got.xy_m[:20], atol=1e-6)
    # BSSIDs written upper-case (another phone or tool) locate alike: they gave fixes 11 m
    # off in median (35 m on a real floor), still "located" by the few all-digit keys
    upper = [RadioScan(0, np.char.upper(sc.keys), sc.rssi_dbm, sc.age_ms) for sc in one]
    np.testing.assert_array_equal(pos.locate_scans(upper).xy_m, pos.locate_scans(one).xy_m)
    for bad in (5.0, np.inf, np.nan, -200.0):  # not an RSSI in dBm
        with pytest.raises(LocalizationError, match=rf"scan at 7: RSSI .* dBm of "
                           rf"{one[0].keys[0]} is not in \[-127, 0\) dBm"):
            RadioScan(7, np.char.upper(one[0].keys), np.r_[bad, one[0].rssi_dbm[1:]])
    # 0 dBm, a driver's "no reading", read as the strongest signal: refused as ingest does
    with pytest.raises(LocalizationError, match=r"RSSI 0 dBm of .* is a driver's 'no "
                                                r"reading'"):
        RadioScan(7, one[0].keys, np.r_[0.0, one[0].rssi_dbm[1:]])
    # whole walks: the same scores on both sides
    want_walk = default_walk_matcher().fit(db).predict(scans)
    walk = scans.scans["trace_id"].to_numpy().astype(str)
    t = scans.scans["t_ms"].to_numpy(np.float64)
    for w in np.unique(walk):
        mine = (walk == w) & ok
        got_walk = pos.locate_matrix(rssi[mine], t[mine], WalkSmoothing(), age_ms=age[mine])
        np.testing.assert_allclose(got_walk.xy_m, want_walk.xy_m[mine], atol=1e-6)
    assert not np.allclose(want_walk.xy_m[ok], want.xy_m[ok])
    with pytest.raises(LocalizationError, match="one time per scan"):
        pos.locate_matrix(rssi[:3], None, WalkSmoothing())


def test_ble_fixes_equal_the_mapping_matchers_weak_windows_and_all(built, ble_obs,
                                                                   monkeypatch):
    """`indoormap validate` scores the BLE windows the localizer locates, no others: every
    window heard by default, and the same windows under a limit on the strongest beacon
    (BLE_MIN_STRONGEST_DBM, which both read)."""
    from localize import radio_match

    b = load_bundle(built / "F2")
    db = FingerprintDB.from_tables(_tables(b, "ble"))
    scans = scan_set(ble_obs["F2"])
    for limit in (-np.inf, -88.0):
        monkeypatch.setattr(radio_match, "BLE_MIN_STRONGEST_DBM", limit)
        pos = FingerprintPositioner.from_bundle(b, "ble")
        want = default_matcher(kind="ble").fit(db).predict(scans)
        rssi = align_scans(scans, pos.aps)[0]
        got = pos.locate_matrix(rssi)
        located = np.isfinite(want.xy_m[:, 0])
        np.testing.assert_array_equal(np.isfinite(got.xy_m[:, 0]), located)
        np.testing.assert_allclose(got.xy_m[located], want.xy_m[located], atol=1e-6)
        heard = np.isfinite(rssi).any(axis=1)
        weak = np.nanmax(np.where(np.isfinite(rssi), rssi, -np.inf), axis=1) < -88.0
        assert (weak & heard).any() and (heard & ~weak).any()
        assert located[heard & ~weak].all()
        assert located[weak & heard].all() == (limit == -np.inf)
        assert not located[weak & heard].any() or limit == -np.inf
    with pytest.raises(Exception, match="kind must be 'wifi' or 'ble'"):
        default_matcher(kind="lte")


def test_localizer_floor_model_equals_the_fitted_one(built, wifi_obs):
    site = load_bundle(built / "_site")
    clf = FloorClassifier.from_bundle(site)
    tables = {n: site.table(f"floor_{n}").to_pandas() for n in ("coef", "intercept", "meta")}
    model = FloorModel.from_tables(tables)
    for floor, obs in wifi_obs.items():
        s = scan_set(obs)
        want = model.predict(s)
        rssi = np.full((len(s), len(clf.aps)), np.nan)
        common, i_s, i_c = np.intersect1d(s.aps, clf.aps, return_indices=True)
        rssi[:, i_c] = s.rssi_dbm[:, i_s]
        lp = clf.log_proba(rssi)
        got = np.where(np.isfinite(lp).all(1), clf.floors[np.argmax(np.nan_to_num(lp, nan=-1e9),
                                                                      axis=1)], "")
        assert (got == want).all()
        assert (want == floor).mean() >= 0.95


def test_scan_without_known_transmitter_gives_no_fix(built):
    pos = FingerprintPositioner.from_bundle(load_bundle(built / "F1"), "wifi")
    unknown = RadioScan(0, np.array(["02:00:00:00:00:01"]), np.array([-50.0]))
    assert pos.locate(unknown) is None
    assert pos.likelihood(unknown, np.zeros(3), np.zeros(3)) is None
    fixes = pos.locate_scans([unknown, RadioScan(1, pos.aps[:3], np.array([-60.0, -70, -80]))])
    assert np.isnan(fixes.xy_m[0]).all() and np.isfinite(fixes.xy_m[1]).all()
    assert fixes.n_known.tolist() == [0, 3]
    for k, b in ((0.0, 1.0), (1e308, 1.0), (1.0, -1e308), (float("nan"), 0.0)):
        with pytest.raises(LocalizationError, match="k must lie in 0.1-10 and"):
            pos.with_calibration(k, b)
    with pytest.raises(Exception, match="neighbour_mix must lie in"):
        dataclasses.replace(pos, neighbour_mix=2.0)


def test_unknown_phone_is_calibrated_online(built):
    b = load_bundle(built / "F1")
    pos = FingerprintPositioner.from_bundle(b, "wifi")
    # scans at three reference points, reported on a weaker scale: rssi = 0.85 * ref - 8
    scans = []
    for i in range(0, 40, 5):
        heard = np.flatnonzero(np.isfinite(pos.mean_dbm[i]))
        scans.append(RadioScan(i, pos.aps[heard], 0.85 * pos.mean_dbm[i, heard] - 8.0))
    cal, how = radio_for_walk(b, "Unknown-Phone", scans)
    assert how.startswith("online")
    assert cal.rssi_k * 0.85 == pytest.approx(1.0, abs=0.05)
    assert cal.rssi_k * -8.0 + cal.rssi_b == pytest.approx(0.0, abs=1.5)
    known, how = radio_for_walk(b, "SIM-B2", scans)
    assert how.startswith("device table")
    # two usable scans (and one hearing too few transmitters) are not enough to calibrate
    few = scans[:2] + [RadioScan(99, pos.aps[:2], np.array([-60.0, -70.0]))]
    plain, how = radio_for_walk(b, "Unknown-Phone", few)
    assert (plain.rssi_k, plain.rssi_b) == (1.0, 0.0)
    assert how == ("uncalibrated (2 of the first 3 scans hear enough known transmitters to "
                   "calibrate from; 3 needed)")


def test_ble_is_calibrated_by_an_offset_only_when_it_is_large(built):
    """A walk's BLE windows hear too few beacons to fit a slope; an offset within the
    estimate's noise (BLE_MIN_OFFSET_DB) is left alone, a phone reading 12 dB low is not."""
    b = load_bundle(built / "F2")
    pos = FingerprintPositioner.from_bundle(b, "ble")
    rng = np.random.default_rng(3)
    # windows at the reference points hearing 5 beacons or more (6 on the sample's F2)
    rich = np.flatnonzero(np.isfinite(pos.mean_dbm).sum(axis=1) >= 5)[:8]
    assert len(rich) >= 3

    def windows(offset_db: float) -> list[RadioScan]:
        out = []
        for i in rich:
            heard = np.flatnonzero(np.isfinite(pos.mean_dbm[i]))
            rssi = pos.mean_dbm[i, heard] + offset_db + rng.normal(0.0, 2.0, len(heard))
            out.append(RadioScan(int(i), pos.aps[heard], rssi))
        return out

    for offset in (0.0, 2.5, -3.0):
        plain, how = radio_for_walk(b, None, windows(offset), kind="ble")
        assert (plain.rssi_k, plain.rssi_b) == (1.0, 0.0), how
        assert how.startswith("uncalibrated (the BLE offset found online from")
        assert how.endswith("is within 4 dB)")
    low, how = radio_for_walk(b, None, windows(-12.0), kind="ble")
    assert how.startswith("online from") and "offset only" in how
    assert low.rssi_k == 1.0
    assert low.rssi_b == pytest.approx(12.0, abs=1.0)


def test_a_limit_on_the_strongest_beacon_leaves_weak_ble_windows_unlocated(built):
    """By default every window that hears a known beacon is located (a limit left site1's
    walks no better and some of them without any fix: BLE_MIN_STRONGEST_DBM); given a limit,
    a window of weak beacons only gives no fix and no likelihood."""
    b = load_bundle(built / "F2")
    default = FingerprintPositioner.from_bundle(b, "ble")
    assert default.min_strongest_dbm == BLE_MIN_STRONGEST_DBM == -np.inf
    ble = FingerprintPositioner.from_bundle(b, "ble", min_strongest_dbm=-88.0)
    i = int(np.argmax(np.isfinite(ble.mean_dbm).sum(axis=1)))
    heard = np.flatnonzero(np.isfinite(ble.mean_dbm[i]))
    levels = np.linspace(-89.0, -99.0, len(heard))
    weak = RadioScan(0, ble.aps[heard], levels)
    assert default.locate(weak) is not None
    assert ble.locate(weak) is None
    assert ble.likelihood(weak, [0.0], [0.0]) is None
    # one beacon at the limit locates the window; so does a calibration that lifts it there
    at_limit = RadioScan(0, ble.aps[heard], np.r_[-88.0, levels[1:]])
    assert ble.locate(at_limit) is not None
    assert ble.with_calibration(1.0, 1.0).locate(weak) is not None
    fixes = ble.locate_scans([weak, at_limit])
    assert np.isnan(fixes.xy_m[0]).all() and np.isfinite(fixes.xy_m[1]).all()
    # Wi-Fi scans are not cut
    wifi = FingerprintPositioner.from_bundle(b, "wifi")
    assert wifi.min_strongest_dbm == -np.inf
    j = np.flatnonzero(np.isfinite(wifi.mean_dbm[0]))
    assert wifi.locate(RadioScan(0, wifi.aps[j], np.full(len(j), -95.0))) is not None
    with pytest.raises(LocalizationError, match="min_strongest_dbm is NaN"):
        dataclasses.replace(ble, min_strongest_dbm=float("nan"))


def _rows(text: str) -> list[dict]:
    lines = [ln for ln in text.splitlines() if "," in ln]
    return list(csv.DictReader(io.StringIO("\n".join(lines))))


def test_floor_command_per_scan_and_per_walk(built):
    runner = CliRunner()
    for floor in ("F1", "F2"):
        res = runner.invoke(main, ["floor", str(built), str(SITE / floor / "path_data_files")])
        assert res.exit_code == 0, res.output
        rows = _rows(res.stdout)
        walks = [r for r in rows if r["level"] == "walk"]
        scans = [r for r in rows if r["level"] == "scan"]
        # F1 has a walk without any Wi-Fi (like one real walk): its floor from its BLE windows
        assert len(walks) == 6 and all(r["floor"] == floor for r in walks)
        assert [r["kind"] for r in walks].count("ble") == (1 if floor == "F1" else 0)
        assert np.mean([r["floor"] == floor for r in scans if r["kind"] == "wifi"]) >= 0.95
        assert all(r["recorded_floor"] == floor for r in rows)
        # the Wi-Fi model alone: that walk's floor is unknown, a failure (no rows, exit 1)
        wifi = runner.invoke(main, ["floor", "--kind", "wifi", str(built),
                                    str(SITE / floor / "path_data_files")])
        assert wifi.exit_code == (1 if floor == "F1" else 0), wifi.output
        walks = [r for r in _rows(wifi.stdout) if r["level"] == "walk"]
        assert [r["floor"] for r in walks] == [floor] * (5 if floor == "F1" else 6)
        assert ("floor unknown" in wifi.stderr) == (floor == "F1")
        assert ("1 failure(s) in 6 walk(s)" in wifi.stderr) == (floor == "F1")
    bad = runner.invoke(main, ["floor", str(built / "F1"), str(SITE / "F1" / "path_data_files")])
    assert bad.exit_code != 0 and "not a site bundle" in bad.output


def test_floor_command_refuses_a_walk_of_another_site(built, tmp_path):
    """As localize, evaluate and wifi-locate do: a walk recorded at another site used to get
    rows of 'floor unknown' and exit 0."""
    import gzip
    import re

    walk = min((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
    text = gzip.decompress(walk.read_bytes()).decode()
    assert "SiteID:" in text
    (tmp_path / walk.name).write_bytes(gzip.compress(
        re.sub(r"SiteID:[^\t\n]*", "SiteID:othersite", text, count=1).encode()))
    res = CliRunner().invoke(main, ["floor", str(built), str(tmp_path / walk.name)])
    assert res.exit_code == 1 and "recorded at site othersite" in res.output


def test_two_walks_with_one_trace_id_are_refused_by_floor_and_wifi_locate(built, tmp_path):
    """As localize and evaluate refuse them: their rows would share one trace_id (before
    session 39 both walks' rows were printed under it, exit 0). The first walk's rows stay."""
    first, other = sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[:2]
    for folder, walk in (("a", first), ("b", other)):  # same name, other walk
        (tmp_path / folder).mkdir()
        (tmp_path / folder / first.name).write_bytes(walk.read_bytes())
    tid = first.name.split(".")[0]
    for command in ("floor", "wifi-locate"):
        res = CliRunner().invoke(main, [command, str(built), str(tmp_path / "a"),
                                        str(tmp_path / "b")])
        assert res.exit_code == 1 and f"trace id {tid} is also" in res.stderr, res.output
        rows = _rows(res.stdout)
        assert rows and {r["trace_id"] for r in rows} == {tid}
        alone = CliRunner().invoke(main, [command, str(built), str(tmp_path / "a")])
        assert alone.exit_code == 0 and _rows(alone.stdout) == rows


def test_wifi_locate_command(built, tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["wifi-locate", str(built), str(SITE / "F2" / "path_data_files")])
    assert res.exit_code == 0, res.output
    rows = _rows(res.stdout)
    assert rows and {"x_m", "y_m", "sigma_m", "n_known", "error_m"} <= set(rows[0])
    err = np.array([float(r["error_m"]) for r in rows if r["error_m"]])
    assert len(err) > 100 and np.median(err) < 3.0  # walks the map was built from
    assert "device table (SIM-B2" in res.stderr
    ble = runner.invoke(main, ["wifi-locate", "--kind", "ble", str(built / "F2"),
                               str(SITE / "F2" / "path_data_files")])
    assert ble.exit_code == 0, ble.output
    assert len(_rows(ble.stdout)) > 10
    alone = runner.invoke(main, ["wifi-locate", "--smoothing", "none", str(built),
                                 str(SITE / "F2" / "path_data_files")])
    assert alone.exit_code == 0, alone.output
    err_alone = np.array([float(r["error_m"]) for r in _rows(alone.stdout) if r["error_m"]])
    assert len(err_alone) == len(err) and not np.allclose(err_alone, err)
    # usage errors before any walk is read (1e308 made every level -inf: no fix, no error)
    for bad, why in (("1.1,x", "K,B"), ("1", "K,B"), ("0,0", "out of range"),
                     ("-5,3", "out of range"), ("1,nan", "out of range"),
                     ("1e308,1", "out of range")):
        given = runner.invoke(main, ["wifi-locate", "--calibration", bad, str(built / "F2"),
                                     str(SITE / "F2" / "path_data_files")])
        assert given.exit_code == 2 and why in given.output, given.output


def test_wifi_locate_fails_a_walk_whose_scans_hear_no_known_transmitter(built, tmp_path):
    """Scans, but none hears an access point of the bundle: a failure (no rows, exit 1), not
    rows of empty positions and exit 0; the other walks still get theirs."""
    import gzip
    import re

    walks = sorted((SITE / "F2" / "path_data_files").glob("*.txt.gz"))
    text = gzip.decompress(walks[0].read_bytes()).decode()
    unknown = re.sub(r"(TYPE_WIFI\t[^\t]*\t)([0-9a-f:]{17})",
                     lambda m: m.group(1) + "02:" + m.group(2)[3:], text)
    assert unknown != text
    (tmp_path / walks[0].name).write_bytes(gzip.compress(unknown.encode()))
    args = ["wifi-locate", "--calibration", "none", str(built / "F2"),
            str(tmp_path / walks[0].name), str(walks[1])]
    res = CliRunner().invoke(main, args[:1] + ["--kind", "wifi"] + args[1:])
    assert res.exit_code == 1, res.output
    assert "wifi scans hears a transmitter the F2 bundle knows" in res.stderr
    assert "1 failure(s) in 2 walk(s)" in res.stderr
    assert {r["trace_id"] for r in _rows(res.stdout)} == {walks[1].name.split(".")[0]}
    # --kind auto (the default) locates that walk by its BLE windows instead, and says why
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    tid = walks[0].name.split(".")[0]
    assert re.search(rf"{tid}: \d+ ble scans on F2, \d+ located; calibration .*\(Wi-Fi: none "
                     r"of its \d+ wifi scans hears a transmitter the F2 bundle knows",
                     res.stderr), res.stderr
    kinds = {(r["trace_id"], r["kind"]) for r in _rows(res.stdout)}
    assert kinds == {(tid, "ble"), (walks[1].name.split(".")[0], "wifi")}
    # a K,B given is the Wi-Fi scans': the walk located by BLE is calibrated online
    given = CliRunner().invoke(main, args[:1] + ["--calibration", "1,0"] + args[3:])
    assert given.exit_code == 0, given.output
    assert re.search(rf"{tid}: \d+ ble scans .*calibration (?!given)", given.stderr)
    assert re.search(r"wifi scans .*calibration given k=1, b=\+0 dB", given.stderr)


def test_walk_without_wifi(built, tmp_path):
    """The sample's walk with no Wi-Fi rows (one real walk has none): clear message."""
    walk = SITE / "F1" / "path_data_files" / "641189778a6ffd7aae963f2c.txt.gz"
    runner = CliRunner()
    res = runner.invoke(main, ["wifi-locate", "--kind", "wifi", str(built), str(walk)])
    assert res.exit_code == 1 and "no wifi scans; it has ble scans: --kind ble" in res.stderr
    assert res.stdout.strip() == "trace_id,floor,t_ms,n_known,x_m,y_m,sigma_m,error_m,kind"
    res = runner.invoke(main, ["wifi-locate", str(built), str(walk)])  # auto: by BLE
    assert res.exit_code == 0 and "(Wi-Fi: no wifi scans)" in res.stderr, res.output
    assert {r["kind"] for r in _rows(res.stdout)} == {"ble"}
    res = runner.invoke(main, ["floor", str(built), str(walk)])  # by BLE: said so
    assert res.exit_code == 0 and "(no Wi-Fi scan classified)" in res.stderr
    assert [(r["floor"], r["kind"]) for r in _rows(res.stdout) if r["level"] == "walk"] == \
        [("F1", "ble")]
    res = runner.invoke(main, ["floor", "--kind", "wifi", str(built), str(walk)])
    assert res.exit_code == 1 and "floor unknown" in res.stderr
    assert not _rows(res.stdout)  # the header only
    # the radio-only method goes by the walk's BLE windows
    res = runner.invoke(main, ["localize", str(built), str(walk), "-o", str(tmp_path / "ble"),
                               "--method", "radio", "--start", "waypoint", "--no-plot"])
    assert res.exit_code == 0, res.output
    assert "start first waypoint; BLE fixes (no Wi-Fi scans in the walk)" in res.output
    # without beacons either, it held its start to the end (a constant track, exit 0)
    lines = gzip.decompress(walk.read_bytes()).decode().splitlines(keepends=True)
    bare = tmp_path / "bare.txt"
    bare.write_text("".join(ln for ln in lines if "TYPE_BEACON" not in ln))
    res = runner.invoke(main, ["localize", str(built), str(bare), "-o", str(tmp_path / "out"),
                               "--method", "radio", "--start", "waypoint"])
    assert res.exit_code == 1 and "no scan of the walk located by the radio model" in res.output
    assert not list((tmp_path / "out").glob("*.parquet"))


def test_wifi_locate_needs_no_motion_sensors(built, tmp_path):
    """A log of scans only (no accelerometer, no rotation vector) is located as the full walk
    is: wifi-locate refused it ('no accelerometer stream') though it uses no step."""
    walk = min((SITE / "F2" / "path_data_files").glob("*.txt.gz"))
    with gzip.open(walk, "rt") as src:
        kept = [ln for ln in src if not ln.split("\t")[1:2] or
                not ln.split("\t")[1].startswith(("TYPE_ACC", "TYPE_ROTATION", "TYPE_GYRO"))]
    scans_only = tmp_path / walk.name
    with gzip.open(scans_only, "wt") as dst:
        dst.writelines(kept)
    runner = CliRunner()
    full = runner.invoke(main, ["wifi-locate", str(built), str(walk)])
    res = runner.invoke(main, ["wifi-locate", str(built), str(scans_only)])
    assert full.exit_code == 0 and res.exit_code == 0, res.output
    assert len(_rows(res.stdout)) > 10 and _rows(res.stdout) == _rows(full.stdout)


def test_radio_commands_report_a_failing_walk_and_go_on(built, tmp_path):
    """A bad trace among good ones: `floor` and `wifi-locate` name it with its reason, still
    print the good walk's rows (as soon as it is through), and exit 1."""
    good = min((SITE / "F2" / "path_data_files").glob("*.txt*"))
    junk = tmp_path / "junk.txt"
    junk.write_text("not a trace\n")
    runner = CliRunner()
    for cmd in ("floor", "wifi-locate"):
        res = runner.invoke(main, [cmd, str(built), str(junk), str(good), str(tmp_path / "no")])
        assert res.exit_code == 1, res.output
        assert f"error: {junk}:" in res.stderr and "2 failure(s) in 3 walk(s)" in res.stderr
        assert f"error: {tmp_path / 'no'}: no such file or folder" in res.stderr
        assert {r["trace_id"] for r in _rows(res.stdout)} == {good.name.split(".")[0]}
        # rows are written as each walk is through: the good walk's come before a later failure
        walks = tmp_path / "walks"  # walks run in path order: the good one, then the bad
        walks.mkdir(exist_ok=True)
        shutil.copy(good, walks / good.name)
        shutil.copy(junk, walks / "z_junk.txt")
        later = runner.invoke(main, [cmd, str(built), str(walks)])
        assert later.exit_code == 1
        tid = good.name.split(".")[0]
        assert later.output.rindex(f"{tid},") < later.output.index(
            f"error: {walks / 'z_junk.txt'}:")


def test_site_without_wifi_builds_without_radio_tables(tmp_path):
    """A floor folder whose walks carry no Wi-Fi and no BLE: bundles without radio tables."""
    floor = tmp_path / "site" / "F1"
    shutil.copytree(SITE / "F1", floor, ignore=shutil.ignore_patterns("path_data_files"))
    (floor / "path_data_files").mkdir()
    for src in sorted((SITE / "F1" / "path_data_files").iterdir())[:3]:
        opener = gzip.open if src.suffix == ".gz" else open
        with opener(src, "rt", encoding="utf-8") as fh:
            lines = [ln for ln in fh if "TYPE_WIFI" not in ln and "TYPE_BEACON" not in ln]
        lines.append("1600000000000\tTYPE_ACCELEROMETER\t1\tx\t3\t3\n")  # one bad line each
        (floor / "path_data_files" / src.name.replace(".gz", "")).write_text("".join(lines))
    (floor / "path_data_files" / "empty.txt").write_text("")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["build", str(floor), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "no floor model" in res.output
    # what the reader skipped is said, as `indoormap ingest` says it
    assert "3 bad line(s) skipped (non_numeric 3); first: " in res.output
    assert f"unreadable: {floor / 'path_data_files' / 'empty.txt'}: no sensor sample" \
        in res.output
    b = load_bundle(out / "F1")
    assert fingerprint_kinds(b) == [] and b.manifest["metrics"]["radio"]["wifi"] is None
    assert FloorClassifier.from_bundle(load_bundle(out / "_site")) is None


def test_localize_auto_start_falls_back_to_ble_then_to_the_first_waypoint(built, tmp_path):
    """``--start auto`` (the default) on a bundle with fingerprints: the Wi-Fi fix where the
    walk has one, the BLE fix for the walk without Wi-Fi, the first waypoint for a walk with
    neither (not an error)."""
    no_wifi = SITE / "F1" / "path_data_files" / "641189778a6ffd7aae963f2c.txt.gz"
    with_wifi = next(p for p in sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))
                     if p != no_wifi)
    lines = gzip.decompress(no_wifi.read_bytes()).decode().splitlines(keepends=True)
    assert not any("TYPE_WIFI" in ln for ln in lines) and any("TYPE_BEACON" in ln for ln in lines)
    no_radio = tmp_path / "no_radio.txt"
    no_radio.write_text("".join(ln for ln in lines if "TYPE_BEACON" not in ln))
    out = tmp_path / "loc"
    res = CliRunner().invoke(main, ["localize", str(built), str(no_wifi), str(with_wifi),
                                    str(no_radio), "-o", str(out), "--no-plot",
                                    "--particles", "100"])
    assert res.exit_code == 0, res.output
    assert "start first BLE fix (no Wi-Fi scans in the walk)" in res.output
    assert "start first Wi-Fi fix," in res.output
    assert "no_radio: " in res.output and \
        "start first waypoint (no Wi-Fi or BLE fix in the walk)" in res.output
    assert len(list(out.glob("*.parquet"))) == 3
    res = CliRunner().invoke(main, ["localize", str(built), str(no_radio), "-o",
                                    str(tmp_path / "radio"), "--start", "radio"])
    assert res.exit_code == 1 and "no scan of the walk located by the radio model" in res.output


def test_walk_without_a_floor_header_gets_its_floor_from_the_floor_model(built, tmp_path):
    """A trace without its header lines names no floor: the site bundle's floor model (which
    speaks floor names) picks the floor bundle (keyed by floor id)."""
    import gzip

    import pandas as pd

    walk = min((SITE / "F2" / "path_data_files").glob("*.txt.gz"))
    lines = gzip.decompress(walk.read_bytes()).decode().splitlines(keepends=True)
    bare = tmp_path / "bare.txt"
    bare.write_text("".join(ln for ln in lines if not ln.startswith("#")))
    res = CliRunner().invoke(main, ["localize", str(built), str(bare), "-o",
                                    str(tmp_path / "loc"), "--no-plot", "--particles", "100"])
    assert res.exit_code == 0, res.output
    f2 = load_bundle(built / "F2")
    track = pd.read_parquet(tmp_path / "loc" / "bare.parquet")
    row, col, inside = f2.grid.cell_of(track["x_m"].to_numpy(), track["y_m"].to_numpy())
    assert inside.all() and f2.mask[row, col].mean() > 0.9


def test_site_maps_open_a_bundle_a_build_folder_or_nothing(built, tmp_path):
    """A build's output folder gives every floor and the _site's floor model; one floor
    bundle gives that floor alone; a folder without bundles is refused by name."""
    site = SiteMaps.open(built)
    assert sorted(site.bundles) == sorted(load_bundle(built / f).floor_id
                                          for f in ("F1", "F2"))
    assert isinstance(site.floor_model, FloorClassifier)
    one = SiteMaps.open(built / "F1")
    assert list(one.bundles) == [load_bundle(built / "F1").floor_id] and one.floor_model is None
    assert list(SiteMaps.open(str(built / "F1")).bundles) == list(one.bundles)
    (tmp_path / "a_file").write_text("x")
    for nothing in (tmp_path, tmp_path / "a_file"):
        with pytest.raises(LocalizationError, match="neither a bundle nor a folder of bundles"):
            SiteMaps.open(nothing)
    with pytest.raises(LocalizationError, match="typo: no such file or folder"):
        SiteMaps.open(tmp_path / "typo")  # it said "neither a bundle nor a folder ..."
    only_site = tmp_path / "only_site"
    only_site.mkdir()
    shutil.copytree(built / "_site", only_site / "_site")
    for site_only in (only_site, only_site / "_site"):  # the message named no path
        with pytest.raises(LocalizationError, match=f"{site_only}: a site bundle only"):
            SiteMaps.open(site_only)
    twice = tmp_path / "twice"
    twice.mkdir()
    for name in ("F1", "F1_copy"):
        shutil.copytree(built / "F1", twice / name)
    with pytest.raises(LocalizationError, match=f"{twice}: two bundles for floor .*F1_copy"):
        SiteMaps.open(twice)


def test_localizing_a_walk_the_map_was_built_from_says_so(built, tmp_path):
    """A source walk's track is better than an unseen walk's: the three commands that
    localize warn, naming the walk and the bundle (wifi-locate did not before session 40); a
    run of many such walks names the first three and counts the rest in one line."""
    import warnings

    from localize.evaluate import SeenWalkWarning

    walk = min((SITE / "F2" / "path_data_files").glob("*.txt*"))
    tid = walk.name.split(".")[0]
    assert tid in load_bundle(built / "F2").source_walk_ids()
    runner = CliRunner()
    for args in (["localize", str(built), str(walk), "-o", str(tmp_path / "out"), "--no-plot",
                  "--method", "pdr"],
                 ["evaluate", str(built), str(walk), "--method", "pdr"],
                 ["wifi-locate", str(built), str(walk)]):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = runner.invoke(main, args)
        assert res.exit_code == 0, res.output
        assert f"warning: {tid} was used to build {built / 'F2'}: the map has seen it" \
            in res.stderr
        assert "more walk(s)" not in res.stderr
        # the commands say it once in their words, not also as the Python API's warning
        assert not [w for w in caught if issubclass(w.category, SeenWalkWarning)]
    walks = sorted((SITE / "F2" / "path_data_files").glob("*.txt*"))
    assert len(walks) > SeenWalks.NAMED
    res = runner.invoke(main, ["evaluate", str(built), *map(str, walks), "--method", "pdr"])
    assert res.exit_code == 0, res.output
    assert res.stderr.count(" was used to build ") == SeenWalks.NAMED
    assert (f"warning: {len(walks) - SeenWalks.NAMED} more walk(s) were used to build their "
            "bundle (") in res.stderr
    # a walk that fails is not warned of (nor counted): it has no track to be better
    res = runner.invoke(main, ["localize", str(built), str(walk), "-o", str(tmp_path / "far"),
                               "--no-plot", "--start", "100000,100000"])
    assert res.exit_code == 1 and "was used to build" not in res.stderr, res.output


@pytest.mark.parametrize("method", ["pdr", "align"])
def test_errors_measured_in_python_on_a_walk_the_map_has_seen_warn(built, method):
    """The Python API said nothing where the commands warn: the track records that the map
    has seen its walk, and waypoint_errors / step_errors warn; an unseen walk stays quiet."""
    import warnings
    from dataclasses import replace

    from localize.baselines import make_localizer
    from localize.evaluate import SeenWalkWarning, step_errors, waypoint_errors
    from survey.step_summaries import step_summaries, waypoints_of
    from survey.trace_reader import read_trace

    walk = min((SITE / "F2" / "path_data_files").glob("*.txt*"))
    trace = read_trace(walk)
    steps, (t_wp, xy_wp) = step_summaries(trace), waypoints_of(trace)
    bundle = load_bundle(built / "F2")
    track = make_localizer(method, bundle).run(steps, start_xy=xy_wp[0])
    assert track.info["seen_by_map"] is True
    with pytest.warns(SeenWalkWarning, match=rf"{trace.trace_id} was used to build the map of "
                      "floor .*: its errors are better than an unseen walk's"):
        waypoint_errors(track, t_wp, xy_wp)
    with pytest.warns(SeenWalkWarning):
        step_errors(track, track.xy_m)
    unseen = make_localizer(method, bundle).run(replace(steps, trace_id="elsewhere"),
                                                start_xy=xy_wp[0])
    assert unseen.info["seen_by_map"] is False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        waypoint_errors(unseen, t_wp, xy_wp)


def test_evaluate_warns_about_waypoints_where_the_map_has_no_data(built, tmp_path):
    """Waypoints where no survey walk passed (two moved 500 m north, off the floor's grid):
    evaluate says how many, as their errors measure a place the map does not cover; the
    walk as recorded gets no such warning."""
    walk = min((SITE / "F2" / "path_data_files").glob("*.txt*"))
    with gzip.open(walk, "rt") as src:
        lines = src.readlines()
    at = [i for i, ln in enumerate(lines) if "\tTYPE_WAYPOINT\t" in ln]
    for i in at[-2:]:
        t, kind, x, y = lines[i].rstrip("\n").split("\t")
        lines[i] = f"{t}\t{kind}\t{x}\t{float(y) + 500.0}\n"
    moved = tmp_path / walk.name
    with gzip.open(moved, "wt") as dst:
        dst.writelines(lines)
    runner = CliRunner()
    res = runner.invoke(main, ["evaluate", str(built), str(moved), "--method", "pdr"])
    assert res.exit_code == 0, res.output
    tid = walk.name.split(".")[0]
    assert f"warning: 2 of {len(at)} waypoints of {tid} lie where {built / 'F2'} has no map " \
        "data (no survey sample within 3 m)" in res.stderr  # the build's raster reach
    plain = runner.invoke(main, ["evaluate", str(built), str(walk), "--method", "pdr"])
    assert plain.exit_code == 0 and "has no map data" not in plain.stderr


def test_a_notebook_shows_what_each_object_is_not_its_arrays(built, sample_store):
    """Printed in a notebook, a bundle, the site's maps and a store showed only ``<...
    object at 0x...>``, and a track, a step and a bundle's content printed thousands of
    characters of arrays. Each is now one line saying what it is."""
    from localize.filter import Localizer
    from localize.walk_radio import walk_radio
    from mapping.build import BuildParams, build_floor
    from mapping.floorplan import read_floor_plan
    from survey.step_summaries import step_summaries
    from survey.store import SurveyStore
    from survey.trace_reader import read_trace

    bundle = load_bundle(built / "F1")
    text = repr(bundle)
    assert text.startswith(f"MapBundle('{built / 'F1'}', floor 'F1' of site ")
    assert "160 x 100 cells of 0.25 m, layers azimuth (deg), heading_offset (deg), " in text
    assert "strength (uT)" in text and ", wifi_fp, " in text
    assert text.endswith(f"id {bundle.bundle_id[:16]})") and len(text) < 500
    assert "site bundle of" in repr(load_bundle(built / "_site"))
    maps = SiteMaps.open(built)
    assert repr(maps) == (f"SiteMaps(site {bundle.site_id!r}, floors F1, F2, floor models "
                          f"Wi-Fi, BLE from {built / '_site'})")
    store = SurveyStore.open(sample_store)
    assert repr(store) == f"SurveyStore('{sample_store}', walks: {bundle.site_id}/F1 6, " \
                          f"{bundle.site_id}/F2 6)"
    with pytest.raises(Exception, match=r"processed 'samples' is read by survey\.process_store"
                                        r"\.processed_table\(store, 'samples'\)"):
        store.table("samples")
    trace = read_trace(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0])
    steps = step_summaries(trace)
    wr = walk_radio(bundle, trace.header.model, steps)
    track = Localizer(bundle, radio=wr.radio, rng=1).run(wr.steps)
    assert repr(track) == (f"Track(method='indoormap', trace_id={trace.trace_id!r}, floor_id="
                           f"{bundle.floor_id!r}, {len(track)} steps, "
                           f"{(track.t_ms[-1] - track.t_ms[0]) / 1000:.0f} s, "
                           f"{track.n_recoveries} recoveries)")
    step = steps[next(i for i, s in enumerate(steps.scans) if s is not None)]
    assert len(repr(step)) < 600 and "transmitters, strongest -" in repr(step)
    content = build_floor(store, read_floor_plan(SITE / "F1"), floor="F1",
                          params=BuildParams(radio=None))
    assert repr(content).startswith(f"BundleContent(floor {bundle.site_id!r}/'F1', Grid(")
    assert len(repr(content)) < 400


@pytest.mark.filterwarnings("ignore::localize.evaluate.SeenWalkWarning")  # errors compared
def test_a_compass_turned_against_the_fixes_is_found_and_turned_back(built):
    """A phone held in landscape all along (or a rotation vector in another frame) turns
    every compass heading by 90 deg: every method was 11-12 m off, without a word. The step
    track fitted to the walk's radio fixes by a rotation says so, and turned back the walk is
    localized as logged; an ordinary walk is not turned."""
    import dataclasses

    from localize.baselines import make_localizer
    from localize.compass_check import compass_turn
    from localize.evaluate import waypoint_errors
    from localize.walk_radio import walk_radio
    from survey.step_summaries import step_summaries, waypoints_of
    from survey.trace_reader import read_trace

    maps = SiteMaps.open(built)
    bundle = maps.bundles[next(iter(maps.bundles))]
    trace = read_trace(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0])
    wr = walk_radio(bundle, trace.header.model, step_summaries(trace))
    t_wp, xy_wp = waypoints_of(trace)

    def median_error(steps) -> float:
        loc = make_localizer("align", bundle, radio=wr.radio, rng=0)
        return float(np.median(waypoint_errors(loc.run(steps), t_wp, xy_wp)))

    as_logged = compass_turn(wr.steps, wr.radio)
    assert not as_logged.turned and abs(as_logged.turn_deg) < 20
    landscape = dataclasses.replace(wr.steps, compass_deg=(wr.steps.compass_deg + 90) % 360)
    check = compass_turn(landscape, wr.radio)
    assert check.turned and check.turn_deg == pytest.approx(as_logged.turn_deg + 90, abs=1)
    assert f"only turned {check.turn_deg:.0f} deg anticlockwise of its compass" in \
        check.sentence()
    logged, turned, mended = (median_error(s) for s in
                              (wr.steps, landscape, check.mended(landscape)))
    assert turned > 3 * logged and mended < 1.5 * logged, (logged, turned, mended)
    other_way = dataclasses.replace(wr.steps, compass_deg=(wr.steps.compass_deg - 90) % 360)
    check = compass_turn(other_way, wr.radio)
    assert check.turned and check.turn_deg == pytest.approx(as_logged.turn_deg - 90, abs=1)
    assert "deg clockwise of its compass" in check.sentence()
    assert median_error(check.mended(other_way)) < 1.5 * logged


@pytest.mark.filterwarnings("ignore::localize.evaluate.SeenWalkWarning")  # errors compared
def test_a_map_drawn_turned_from_north_is_aligned_and_no_turned_phone(built):
    """A plan drawn along its building, 70 deg from magnetic north: its heading offset layer
    reads 70 deg more and so does every compass. The alignment searched rotations around the
    compass's north (+-15 deg) and failed such a floor; the compass check took the map's turn
    for a phone held in landscape. Both now take the floor's heading offset off the compass."""
    import dataclasses

    from localize.baselines import make_localizer
    from localize.bundle import MapBundle
    from localize.compass_check import compass_turn
    from localize.evaluate import waypoint_errors
    from localize.maps import mean_heading_offset_deg
    from localize.walk_radio import walk_radio
    from survey.step_summaries import step_summaries, waypoints_of
    from survey.trace_reader import read_trace

    bundle = load_bundle(built / "F1")
    layers = dict(bundle.layers, heading_offset=(bundle.layers["heading_offset"] + 70.0) % 360)
    turned_map = MapBundle(bundle.path, bundle.manifest, bundle.grid, bundle.mask, layers,
                           bundle.std, bundle.tables)
    assert mean_heading_offset_deg(turned_map) == pytest.approx(
        mean_heading_offset_deg(bundle) + 70.0, abs=0.01)
    trace = read_trace(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0])
    wr = walk_radio(bundle, trace.header.model, step_summaries(trace))
    turned = dataclasses.replace(wr.steps, compass_deg=(wr.steps.compass_deg + 70.0) % 360)
    t_wp, xy_wp = waypoints_of(trace)
    check = compass_turn(turned, wr.radio, mean_heading_offset_deg(turned_map))
    assert not check.turned and abs(check.turn_deg) < 20
    assert compass_turn(turned, wr.radio).turned  # what it said before
    for method in ("align", "indoormap"):
        errors = [float(np.median(waypoint_errors(
            make_localizer(method, b, radio=wr.radio, rng=0).run(s), t_wp, xy_wp)))
            for b, s in ((bundle, wr.steps), (turned_map, turned))]
        assert errors[1] < 1.5 * errors[0] + 0.3, (method, errors)


def test_a_stop_mid_walk_keeps_the_walk_in_the_alignment_window(built):
    """A walker standing two minutes (at a shop) mid-walk: the real-time alignment's window
    of 120 s of time then held the steps after the stop alone (simulated held-out walks so
    stopped: align 2.14 -> 3.04 m median). A pause counts for 2 s of the window now, and the
    track after the stop is the walk's without it."""
    import dataclasses

    from localize.align import AlignParams, WalkAligner
    from localize.walk_radio import walk_radio
    from survey.step_summaries import step_summaries
    from survey.trace_reader import read_trace

    bundle = load_bundle(built / "F1")
    trace = read_trace(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0])
    wr = walk_radio(bundle, trace.header.model, step_summaries(trace))
    steps, k, stop = wr.steps, len(wr.steps) // 2, 120_000
    later = steps.t_ms >= (steps.t_ms[k - 1] + steps.t_ms[k]) / 2
    scans = [s if s is None or not later[i] or not s.t_ms else
             dataclasses.replace(s, t_ms=int(s.t_ms) + stop) for i, s in enumerate(steps.scans)]
    stopped = dataclasses.replace(steps, t_ms=steps.t_ms + stop * later, scans=tuple(scans))
    walked = WalkAligner(bundle, radio=wr.radio).run(steps)

    def moved_m(pause_counts_s: float) -> float:
        track = WalkAligner(bundle, AlignParams(pause_counts_s=pause_counts_s),
                            radio=wr.radio).run(stopped)
        return float(np.median(np.hypot(track.x_m - walked.x_m,
                                        track.y_m - walked.y_m)[later]))

    assert moved_m(2.0) < 0.2 < moved_m(1e6)  # counted in full, the stop moved the track
