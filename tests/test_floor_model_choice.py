"""Floor models of a site bundle: which one decides a walk's floor, and incomplete models.

- A Wi-Fi floor model that lacks some of the site's floors (Wi-Fi surveyed on only some of
  them, the others walked with a phone that logs BLE only) puts every walk on a floor it knows:
  when the BLE model names a floor the Wi-Fi model lacks, BLE decides (it used to decide only
  after Wi-Fi, so every walk with Wi-Fi landed on the Wi-Fi floors).
- A site bundle whose floor model tables are incomplete (coef without intercept) or that
  announces a model in ``metrics`` without its tables is refused, naming what is there and
  what is missing (it loaded without the model, silently).
- A malformed ``ble_floor_*`` table is named as such, with the bundle's path.
- The whole sample site, with both floor models in its site bundle, builds to the same bytes
  twice.
"""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import pyarrow as pa
import pytest
from click.testing import CliRunner

from localize.bundle import load_bundle
from localize.cli_common import FloorChoices
from localize.errors import LocalizationError
from localize.floors import MODEL_LACKS, SiteMaps
from mapping.bundle_writer import BundleContent, write_bundle
from mapping.radio_build import site_observations, site_radio
from survey.cli import main
from survey.step_summaries import ble_scans_of, scans_of
from survey.store import SurveyStore
from survey.trace_reader import read_trace

from radio_fixtures import SITE, built, sample_store  # noqa: F401  (fixtures)

F2_WALKS = sorted((SITE / "F2" / "path_data_files").glob("*.txt.gz"))


def _with_site(built: Path, target: Path, content: BundleContent | None = None, *,
               drop=(), replace=None, metrics_drop=(), metrics_replace=None) -> Path:
    """The floor bundles of ``built`` beside ``content`` (or ``built``'s site bundle with
    tables dropped or replaced, metrics dropped or replaced) as ``_site``."""
    for floor in ("F1", "F2"):
        shutil.copytree(built / floor, target / floor)
    if content is None:
        site = load_bundle(built / "_site")
        m = site.manifest
        tables = {n: site.table(n) for n in m["tables"] if n not in drop}
        tables.update(replace or {})
        content = BundleContent(site_id=m["site_id"], floor_id="", floor_name="", kind="site",
                                tables=tables, build=m["build"],
                                metrics={k: v for k, v in {**m["metrics"],
                                                           **(metrics_replace or {})}.items()
                                         if k not in metrics_drop})
    write_bundle(target / "_site", content)
    return target


@pytest.fixture(scope="module")
def wifi_on_f1_only(built, sample_store, tmp_path_factory) -> Path:  # noqa: F811
    """The sample site's bundles with a site bundle built as if F2 had been surveyed without
    Wi-Fi: the Wi-Fi floor model knows F1 only, the BLE one both floors."""
    store = SurveyStore.open(sample_store)
    obs = {k: site_observations(store, None, ["F1", "F2"], k) for k in ("wifi", "ble")}
    device_of = store.catalog().set_index("trace_id")["device_model"].astype(str)
    radio = site_radio({"wifi": obs["wifi"][obs["wifi"]["floor"] == "F1"], "ble": obs["ble"]},
                       device_of, ["F1", "F2"])
    assert radio.floor_model_kind == "wifi" and radio.floor_model.floors.tolist() == ["F1"]
    assert radio.ble_floor_model is not None
    site_id = load_bundle(built / "_site").site_id
    return _with_site(built, tmp_path_factory.mktemp("wifi_f1") / "b",
                      radio.site_content(site_id))


def test_a_wifi_floor_model_lacking_a_floor_does_not_outvote_the_ble_model(wifi_on_f1_only,
                                                                           capsys):
    maps = SiteMaps.open(wifi_on_f1_only)
    assert maps.floor_model.floors.tolist() == ["F1"]
    for f in F2_WALKS[:3]:  # Wi-Fi and BLE, recorded on F2
        t = read_trace(f)
        assert scans_of(t) and ble_scans_of(t)
        bundle, how = maps.choose(t.trace_id, "", "", "", scans_of(t), ble_scans_of(t))
        assert bundle.manifest["floor_name"] == "F2", how
        assert how.startswith("BLE floor model (") and "lacks floor F2" in how
    # BLE names a floor the Wi-Fi model knows: Wi-Fi decides
    t = read_trace(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0])
    bundle, how = maps.choose(t.trace_id, "", "", "", scans_of(t), ble_scans_of(t))
    assert bundle.manifest["floor_name"] == "F1" and how.startswith("Wi-Fi floor model ("), how
    assert MODEL_LACKS not in how  # BLE, which knows F2, agrees: no warning
    # without BLE windows the one-floor Wi-Fi model still answers, as before, and says what
    # it lacks as a warning (before session 39 a note, and none without a BLE model)
    t = read_trace(F2_WALKS[0])
    bundle, how = maps.choose(t.trace_id, "", "", "", scans_of(t), [])
    assert bundle.manifest["floor_name"] == "F1" and how.startswith("Wi-Fi floor model (")
    assert f"{MODEL_LACKS} F2: walks there are put on a floor it knows; no BLE windows in " \
        "the walk" in how, how
    maps.ble_floor_model = None  # a site bundle rebuilt from F1 alone beside F2's bundle
    bundle, how = maps.choose(t.trace_id, "", "", "", scans_of(t), ble_scans_of(t))
    assert bundle.manifest["floor_name"] == "F1" and how.endswith(
        f"{MODEL_LACKS} F2: walks there are put on a floor it knows"), how
    said = FloorChoices()
    said.say(t.trace_id, bundle, how)
    assert capsys.readouterr().err.startswith(f"warning: {t.trace_id}: floor F1 by the Wi-Fi")
    # the next walks of the run: the same lack is warned of once, then a note refers to it
    said.say("next-walk", bundle, how)
    err = capsys.readouterr().err
    assert err.startswith("next-walk: floor F1 by the Wi-Fi floor model (") and err.endswith(
        f"{MODEL_LACKS} F2 (warned above)\n"), err
    # a run of its own warns again; so does a walk with another lack in the same run
    FloorChoices().say("other-run", bundle, how)
    assert capsys.readouterr().err.startswith("warning: other-run: ")
    said.say("third", bundle, how.replace(f"{MODEL_LACKS} F2:", f"{MODEL_LACKS} F2, F3:"))
    assert capsys.readouterr().err.startswith("warning: third: ")
    odd = how.replace(f"{MODEL_LACKS} F2:", f"{MODEL_LACKS} Level 2: east; B:")  # ':' and ';'
    for k in range(2):  # a floor name with a colon is warned of too, then referred to
        said.say("odd", bundle, odd)
        err = capsys.readouterr().err
        assert err.startswith("warning: odd: ") if k == 0 else err.endswith(
            f"{MODEL_LACKS} Level 2: east; B (warned above)\n"), err


def test_floor_models_that_both_lack_a_given_floor_warn_even_when_they_agree(built, tmp_path):
    """A site bundle of F1 and F2 beside bundles of F1, F2 and F3 (a site bundle rebuilt from
    fewer floors): BLE naming the floor Wi-Fi chose confirms nothing, as neither model can
    name F3, so a walk on F3 would be put on F1 or F2: a warning, not a note."""
    import numpy as np

    from mapping.bundle_writer import Layer

    for name in ("F1", "F2", "_site"):
        shutil.copytree(built / name, tmp_path / name)
    f2 = load_bundle(built / "F2")
    m = f2.manifest
    write_bundle(tmp_path / "F3", BundleContent(
        m["site_id"], "floor-3", "F3", grid=f2.grid, mask=np.asarray(f2.mask),
        layers={n: Layer(np.asarray(v), np.asarray(f2.std[n]), m["layers"][n]["unit"],
                         m["layers"][n]["kind"]) for n, v in f2.layers.items()},
        tables=dict(f2.tables), build=m["build"], metrics=m["metrics"]))
    maps = SiteMaps.open(tmp_path)
    assert maps.ble_floor_model is not None
    t = read_trace(F2_WALKS[0])
    bundle, how = maps.choose(t.trace_id, "", "", "", scans_of(t), ble_scans_of(t))
    assert bundle.manifest["floor_name"] == "F2" and how.startswith("Wi-Fi floor model (")
    assert how.endswith(f"{MODEL_LACKS} F3: walks there are put on a floor it knows"), how


def test_a_wifi_floor_model_lacking_the_header_floor_does_not_doubt_it(wifi_on_f1_only):
    """The header names F2, which the Wi-Fi model (F1 only) cannot put a scan on: it puts
    them all on F1, and that is no reason to doubt the header. On F1 it still may."""
    maps = SiteMaps.open(wifi_on_f1_only)
    t = read_trace(F2_WALKS[0])
    assert len(scans_of(t)) >= 5
    bundle, how = maps.choose(t.trace_id, "", "", "F2", scans_of(t), ble_scans_of(t))
    assert bundle.manifest["floor_name"] == "F2"
    assert how == "floor name in the trace header", how
    # the same F2 scans under an F1 header: the model knows F1, agrees, and says nothing
    bundle, how = maps.choose(t.trace_id, "", "", "F1", scans_of(t), ble_scans_of(t))
    assert bundle.manifest["floor_name"] == "F1" and how == "floor name in the trace header"


def test_floor_auto_does_not_let_a_wifi_model_lacking_a_floor_decide(wifi_on_f1_only):
    res = CliRunner().invoke(main, ["floor", str(wifi_on_f1_only), str(F2_WALKS[0])])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    walk = [r for r in rows if r["level"] == "walk"]
    assert [(r["floor"], r["kind"]) for r in walk] == [("F2", "ble")]
    res = CliRunner().invoke(main, ["floor", "--kind", "wifi", str(wifi_on_f1_only),
                                    str(F2_WALKS[0])])
    walk = [r for r in csv.DictReader(io.StringIO(res.stdout)) if r["level"] == "walk"]
    assert [(r["floor"], r["kind"]) for r in walk] == [("F1", "wifi")]  # forced: as asked


@pytest.mark.parametrize("drop,metrics_drop,names", [
    (("ble_floor_intercept",), (), ("ble_floor_coef", "ble_floor_intercept")),
    (("ble_floor_coef", "ble_floor_intercept", "ble_floor_meta"), (),
     ("ble_floor_model", "ble_floor_coef")),
    (("floor_intercept",), (), ("floor_coef", "floor_intercept")),
    ((), ("ble_floor_model",), ("ble_floor_model", "ble_floor_coef")),
])
def test_an_incomplete_floor_model_in_a_site_bundle_is_refused(built, tmp_path, drop,
                                                                metrics_drop, names):
    out = _with_site(built, tmp_path / "b", drop=drop, metrics_drop=metrics_drop)
    with pytest.raises(LocalizationError) as err:
        SiteMaps.open(out)
    msg = str(err.value)
    assert str(out / "_site") in msg and all(n in msg for n in names), msg
    res = CliRunner().invoke(main, ["floor", str(out), str(F2_WALKS[0])])
    assert res.exit_code != 0 and str(out / "_site") in res.output


def test_a_malformed_ble_floor_table_is_named(built, tmp_path):
    site = load_bundle(built / "_site")
    coef = site.table("ble_floor_coef").rename_columns(["ap", "floor", "weight"])
    out = _with_site(built, tmp_path / "a", replace={"ble_floor_coef": coef})
    with pytest.raises(LocalizationError, match=r"table 'ble_floor_coef' lacks columns "
                                                r"\['coef'\]") as err:
        SiteMaps.open(out)
    assert str(out / "_site") in str(err.value)
    icpt = site.table("ble_floor_intercept")
    other = pa.table({"floor": ["F1", "F9"], "intercept": icpt.column("intercept")})
    out = _with_site(built, tmp_path / "b", replace={"ble_floor_intercept": other})
    with pytest.raises(LocalizationError, match="ble_floor_coef names floors that "
                                                "ble_floor_intercept lacks"):
        SiteMaps.open(out)
    text = pa.table({"ap": coef.column("ap"), "floor": coef.column("floor"),
                     "coef": pa.array(["x"] * len(coef))})
    out = _with_site(built, tmp_path / "c", replace={"ble_floor_coef": text})
    with pytest.raises(LocalizationError, match="ble_floor_coef"):
        SiteMaps.open(out)


def test_a_floor_models_feature_comes_from_the_site_manifest(built, tmp_path):
    """BLE reads presence, Wi-Fi levels; a site bundle built before the feature was recorded
    reads levels, as its models were fitted on; an unknown feature is refused, naming it."""
    site = load_bundle(built / "_site")
    metrics = site.manifest["metrics"]
    assert metrics["floor_model"]["feature"] == "level"
    assert metrics["ble_floor_model"]["feature"] == "presence"
    maps = SiteMaps.open(built)
    assert (maps.floor_model.feature, maps.ble_floor_model.feature) == ("level", "presence")
    old = {k: {n: v for n, v in metrics[k].items() if n != "feature"}
           for k in ("floor_model", "ble_floor_model")}
    before = SiteMaps.open(_with_site(built, tmp_path / "old", metrics_replace=old))
    assert (before.floor_model.feature, before.ble_floor_model.feature) == ("level", "level")
    out = _with_site(built, tmp_path / "odd", metrics_replace={
        "ble_floor_model": {**metrics["ble_floor_model"], "feature": "rank"}})
    with pytest.raises(LocalizationError, match="floor model feature must be one of "
                                                r"\('level', 'presence'\), not 'rank'") as err:
        SiteMaps.open(out)
    assert str(out / "_site") in str(err.value)


def test_the_site_with_both_floor_models_builds_to_the_same_bytes_twice(built, tmp_path):
    again = tmp_path / "again"
    res = CliRunner().invoke(main, ["build", str(SITE), "-o", str(again)])
    assert res.exit_code == 0, res.output
    assert "ble_floor_model" in load_bundle(again / "_site").manifest["metrics"]
    files = sorted(p.relative_to(built) for p in built.rglob("*") if p.is_file())
    assert {str(f).split("/")[0] for f in files} == {"F1", "F2", "_site"}
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    assert all((built / f).read_bytes() == (again / f).read_bytes() for f in files)


def test_ble_windows_are_grouped_as_the_bundles_were_built(built):
    """Localization grouped a walk's BLE rows into 2 s windows whatever the build used
    (``RadioParams.ble_window_ms``, which the manifests record): the window now comes from the
    bundles."""
    from types import SimpleNamespace

    from localize.floors import ble_window_ms

    assert SiteMaps.open(built).ble_window_ms == 2000
    assert ble_window_ms(load_bundle(built / "_site")) == 2000
    for build, want in (({"params": {"radio": {"ble_window_ms": 3000}}}, 3000),
                        ({"radio_params": {"ble_window_ms": 5000}}, 5000), ({}, 2000)):
        assert ble_window_ms(SimpleNamespace(manifest={"build": build}, path="b")) == want
    with pytest.raises(LocalizationError, match="ble_window_ms is 0, not a window length"):
        ble_window_ms(SimpleNamespace(manifest={"build": {"radio_params": {
            "ble_window_ms": 0}}}, path="b"))


def test_a_known_phones_wifi_rssi_is_calibrated_before_its_floor_is_chosen(built):
    """The Wi-Fi floor model is fitted on RSSI mapped through the device table (each phone
    model's ``k, b``), and a walk's scans were classified unmapped: a phone reading 30 dB
    low looked like one far from the access points. Here a model that puts a scan on F2 when
    it hears ``a`` above -50 dBm: the walk's phone hears it at -70 dBm and reads 30 dB low."""
    import numpy as np

    from localize.floor_classifier import FloorClassifier
    from localize.floors import device_table
    from localize.steps import RadioScan

    floors = [load_bundle(built / f) for f in ("F1", "F2")]
    model = FloorClassifier(np.array(["F1", "F2"]), np.array(["a"]), np.array([[0.0], [20.0]]),
                            np.array([0.0, -10.0]))
    maps = SiteMaps(floors, floor_model=model, devices={"PhoneX": (1.0, 30.0)})
    scans = [RadioScan(1000 * i, np.array(["a"]), np.array([-70.0])) for i in range(3)]
    pick = {m: maps.choose("w", "", "", "", scans, device_model=m)[0].manifest["floor_name"]
            for m in ("PhoneX", "other")}
    assert pick == {"PhoneX": "F2", "other": "F1"}  # an unknown phone: as it reads
    # SiteMaps.open takes the table from the site bundle
    assert SiteMaps.open(built).devices == device_table(load_bundle(built / "_site"))
    assert SiteMaps.open(built).devices  # the sample's phones are in it


def test_a_device_row_outside_the_given_limits_does_not_refuse_the_site():
    """The build applies whatever (k, b) its RMA fit gives (no limits: a phone with a
    compressed RSSI scale gets k = 4, b = 210 dB); the Wi-Fi floor model was fitted on RSSI
    mapped so. device_table checked every row against the limits for *user-given*
    calibrations, so one such phone made SiteMaps.open (and `floor`) refuse the whole site,
    for walks of every other phone too."""
    from types import SimpleNamespace

    import pyarrow as pa

    from localize.floors import device_table

    table = pa.table({"device_model": ["ref", "squashed"], "k": [1.0, 4.0],
                      "b": [0.0, 210.0]})
    bundle = SimpleNamespace(path="site", has_table=lambda n: n == "devices",
                             table=lambda n: table)
    assert device_table(bundle) == {"ref": (1.0, 0.0), "squashed": (4.0, 210.0)}
    bad = pa.table({"device_model": ["x"], "k": [float("nan")], "b": [0.0]})
    with pytest.raises(LocalizationError, match="phone 'x'"):
        device_table(SimpleNamespace(path="site", has_table=lambda n: True,
                                     table=lambda n: bad))


def test_an_unknown_phones_wifi_rssi_is_calibrated_online_before_its_floor_is_chosen(built):
    """Session 29: a phone the device table does not know had its scans classified as they
    read, so one reading 20 dB low had a fifth of its scans put on the wrong floor (they look
    far from every access point), and one 24 dB low whole walks. Its RSSI is now calibrated
    online against the fingerprints of the floor the raw scans chose, as its positioner is,
    and classified again. On site1 with RSSI 12 dB low: 98.5 % -> 99.9 % of scans
    (`benchmarks/wifi_accuracy.py --folds 10`)."""
    import dataclasses

    from localize.floors import _walk_floor
    from survey.step_summaries import step_summaries
    from survey.trace_reader import read_trace

    maps = SiteMaps.open(built)
    walks = [[s for s in step_summaries(read_trace(p)).scans if s is not None]
             for p in F2_WALKS]
    for low_db, raw_right_at_most in ((20.0, 0.9), (24.0, 0.7)):
        raw_on = raw_known = raw_walks = 0
        for scans in walks:
            low = [dataclasses.replace(s, rssi_dbm=s.rssi_dbm - low_db) for s in scans]
            floor, n_on, n_known = _walk_floor(maps.floor_model, low, summed=False)
            raw_on += n_on if floor == "F2" else n_known - n_on
            raw_known += n_known
            raw_walks += floor == "F2"
            bundle, how = maps.choose("w", "", "", "", low, device_model="UnknownPhone")
            assert bundle.manifest["floor_name"] == "F2", how
            assert f"{n_known} of {n_known} Wi-Fi scans on it; RSSI calibrated online" in how
        assert raw_on / raw_known < raw_right_at_most  # as they read, scans go astray
    assert raw_walks < len(walks)  # 24 dB low: whole walks too


def test_the_floor_command_calibrates_an_unknown_phone_beside_floor_bundles(built, tmp_path):
    """`indoormap floor OUT WALK` classifies as localize chooses: a walk of a phone the
    device table does not know (no header: no phone, no floor) reading 24 dB low is put on F1
    by its raw scans (14 of 22), and on F2, every scan, once calibrated online against the
    floor bundles in OUT. Given the site bundle alone (no fingerprints) it reads as it is."""
    import csv
    import gzip
    import io

    src = SITE / "F2" / "path_data_files" / "64118a3cbcb1fb66f2c2a8f2.txt.gz"
    lines = []
    for ln in gzip.decompress(src.read_bytes()).decode().splitlines(keepends=True):
        if ln.startswith("#"):
            continue
        cols = ln.split("\t")
        if len(cols) > 4 and cols[1] == "TYPE_WIFI":
            cols[4] = str(int(cols[4]) - 24)
        lines.append("\t".join(cols))
    walk = tmp_path / "64118a3cbcb1fb66f2c2a8f2.txt"
    walk.write_text("".join(lines))

    def floors(path: Path) -> tuple[list[str], str, str]:
        res = CliRunner().invoke(main, ["floor", str(path), str(walk)])
        assert res.exit_code == 0, res.output
        rows = list(csv.DictReader(io.StringIO(
            "\n".join(ln for ln in res.stdout.splitlines() if "," in ln))))
        return ([r["floor"] for r in rows if r["level"] == "scan" and r["floor"]],
                next(r["floor"] for r in rows if r["level"] == "walk"), res.output)

    scans, walk_floor, said = floors(built)
    assert walk_floor == "F2" and set(scans) == {"F2"} and len(scans) >= 21
    assert "Wi-Fi RSSI calibrated online, k=" in said
    scans, _, said = floors(built / "_site")
    assert scans.count("F1") >= 11 and "calibrated" not in said  # as it reads: 14 of 22


def test_a_header_floor_the_wifi_floor_model_contradicts_is_said(built, tmp_path):
    """A walk recorded under the wrong floor name (header F1, every scan of F2) was located
    on F1 without a word. The header still decides (it is the user's data), but `localize`
    and `evaluate` warn with the floor model's count; a walk on its own floor gets no
    warning."""
    import gzip

    walk = F2_WALKS[0]
    text = gzip.decompress(walk.read_bytes()).decode()
    f1 = gzip.decompress(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
                         .read_bytes()).decode()
    f2_id = text.split("FloorId:")[1].split("\t")[0].strip()
    f1_id = f1.split("FloorId:")[1].split("\t")[0].strip()
    wrong = tmp_path / "wrong_floor.txt"
    wrong.write_text(text.replace(f2_id, f1_id).replace("FloorName:F2", "FloorName:F1"))
    res = CliRunner().invoke(main, ["evaluate", str(built), str(wrong), str(walk),
                                    "--methods", "pdr"])
    assert res.exit_code == 0, res.output
    warned = [line for line in res.output.splitlines() if "but the Wi-Fi floor model" in line]
    assert len(warned) == 1 and warned[0].startswith("warning: ")
    assert "floor F1 by the floor id in the trace header; but the Wi-Fi floor model puts" in \
        warned[0] and "Wi-Fi scans on floor F2" in warned[0]
    res = CliRunner().invoke(main, ["wifi-locate", str(built), str(wrong), str(walk)])
    assert res.exit_code == 0, res.output
    assert sum("but the Wi-Fi floor model" in line for line in res.output.splitlines()) == 1


def test_a_walk_whose_scans_change_floor_is_said_and_floored_alike(built, tmp_path, capsys):
    """A walk through a lift (its first scans on F1, its last on F2) was localized on one
    floor without a word, and `indoormap floor`'s walk row (summed log-probabilities) and
    `localize` (most scans) could name different floors for it. The change is said, and both
    decide alike; a walk on one floor is not said."""
    import gzip

    from localize.floors import FLOOR_CHANGE

    f1 = gzip.decompress(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0]
                         .read_bytes()).decode().splitlines()
    f2 = gzip.decompress(F2_WALKS[0].read_bytes()).decode().splitlines()
    end = max(int(line.split("\t")[0]) for line in f1 if line[:1].isdigit())
    f2_wifi = [line.split("\t") for line in f2 if "\tTYPE_WIFI\t" in line]
    shift = end + 20_000 - int(f2_wifi[0][0])  # 20 s in the lift
    moved = ["\t".join([str(int(p[0]) + shift), *p[1:6], str(int(p[6]) + shift)])
             for p in f2_wifi]
    both = tmp_path / "lift.txt"
    both.write_text("\n".join(line for line in f1 if "FloorId:" not in line
                              and "FloorName:" not in line) + "\n" + "\n".join(moved) + "\n")
    maps = SiteMaps.open(built)
    trace = read_trace(both)
    scans = scans_of(trace)
    _, how = maps.choose(trace.trace_id, "", "", "", scans)
    assert FLOOR_CHANGE + ", F1 to F2 at scan " in how, how
    plain = read_trace(sorted((SITE / "F1" / "path_data_files").glob("*.txt.gz"))[0])
    assert FLOOR_CHANGE not in maps.choose(plain.trace_id, "", "", "", scans_of(plain))[1]
    # a header naming the first floor decides, and the change is still said, as a warning
    f1_id = maps.floor_bundle("F1").floor_id
    bundle, how = maps.choose(trace.trace_id, "", f1_id, "", scans)
    assert bundle.floor_id == f1_id and FLOOR_CHANGE + ", F1 to F2" in how
    FloorChoices().say(trace.trace_id, bundle, how)
    assert capsys.readouterr().err.startswith(f"warning: {trace.trace_id}: floor F1 by the "
                                              "floor id in the trace header; its Wi-Fi scans "
                                              "change floor, F1 to F2")
    chosen = maps.choose(trace.trace_id, "", "", "", scans)[0].manifest["floor_name"]
    res = CliRunner().invoke(main, ["floor", str(built / "_site"), str(both)])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    assert [r["floor"] for r in rows if r["level"] == "walk"] == [chosen]
