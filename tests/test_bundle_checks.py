"""Numbers are checked at load (promise 7) and the registry pointer against its history
(promise 6): bundles edited and re-sealed (every sha256, the rows and the bundle id made to
match again, as a buggy writer or another tool would leave them) are refused by
``load_bundle`` and ``bundle verify``, naming the bundle, the table and the column."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from localize.bundle import (MAX_GRID_CELLS, RSSI_RANGE_DBM, Grid, bundle_id_of, load_bundle,
                             manifest_bytes)
from localize.fingerprint_positioner import FingerprintPositioner, fingerprint_kinds
from mapping.bundle_writer import BundleContent, Layer, write_bundle
from mapping.registry import Registry
from survey.cli import main
from survey.errors import BundleError, BundleIntegrityError, RegistryError
from survey.publish import file_sha256

import radio_fixtures

SITE = radio_fixtures.SITE
built = radio_fixtures.built  # the sample site's bundles, built once per session (fixture)


def _table(frame: pd.DataFrame) -> pa.Table:
    """As the build makes its tables (mapping.radio_build._table)."""
    return pa.Table.from_pandas(frame.reset_index(drop=True), preserve_index=False)


def _content(seed: int = 0) -> BundleContent:
    g = Grid(0.0, 0.0, 0.5, 20, 12)
    mask = np.ones(g.shape, bool)
    mask[:2, :3] = False
    xc, yc = g.cell_centers()
    xx, yy = np.meshgrid(xc, yc)

    def layer(values, unit, kind="scalar"):
        v = np.where(mask, values, np.nan).astype(np.float32)
        return Layer(v, np.where(mask, 1.5, np.nan).astype(np.float32), unit, kind)

    layers = {"strength": layer(40 + xx + seed, "uT"), "vertical": layer(-30 + yy, "uT"),
              "horizontal": layer(25 + 0 * xx, "uT"),
              "azimuth": layer(np.mod(10 * xx, 360), "deg", "angle"),
              "polar": layer(130 + yy, "deg", "angle"),
              "heading_offset": layer(np.mod(355 + xx, 360), "deg", "angle")}
    rng = np.random.default_rng(seed)
    rp = pd.DataFrame({"rp_id": np.arange(6, dtype=np.int64), "x_m": rng.uniform(0, 10, 6),
                       "y_m": rng.uniform(0, 6, 6), "n_scans": np.full(6, 3, np.int64)})
    aps = ["00:00:00:00:00:0%d" % i for i in range(4)]
    fp = pd.DataFrame([{"rp_id": r, "ap": a, "mean_dbm": -40.0 - 10 * i - r,
                        "var_db2": np.nan if r == 0 else 4.0, "n": 1 if r == 0 else 3,
                        "detection_rate": 1.0}
                       for r in range(6) for i, a in enumerate(aps)])
    fp["ap"] = fp["ap"].astype(str)
    meta = pd.DataFrame({"kind": ["wifi"], "cell_m": [1.0], "max_age_ms": [6000.0],
                         "format_version": [1]})
    devices = pd.DataFrame([{"device_model": "A", "k": 1.0, "b": 0.0, "n_pairs": 0,
                             "residual_sd_db": 0.0, "method": "reference"},
                            {"device_model": "B", "k": 0.95, "b": 0.7, "n_pairs": 12,
                             "residual_sd_db": np.nan, "method": "too_few_pairs"}])
    walks = pd.DataFrame({"trace_id": ["w1", "w2"], "session": ["s", "s"],
                          "sha256": ["a" * 64, "b" * 64], "calibration": ["", ""],
                          "heading_offset_median_deg": [359.0, np.nan]})
    lev = pd.DataFrame({"session": ["s"], "r_x_ut": [0.5], "r_y_ut": [-0.2], "r_z_ut": [1.0],
                        **{f"s_{a}": [0.0] for a in ("xx", "yy", "zz", "xy", "xz", "yz")},
                        "device": ["A"], "n_samples": [10], "n_pairs": [4]})
    tables = {"wifi_rp": rp, "wifi_fp": fp, "wifi_meta": meta, "devices": devices,
              "source_walks": walks, "levelling": lev}
    return BundleContent("site", "f1", "F1", grid=g, mask=mask, layers=layers,
                         tables={k: _table(v) for k, v in tables.items()},
                         build={"build_time": "2026-01-01T00:00:00Z", "params": {}})


def reseal(folder: Path) -> None:
    """Make an edited bundle self-consistent again as the writer would have written it: every
    member's sha256 and size, each table's rows, the bundle id (mapping.bundle_writer)."""
    m_path = folder / "manifest.json"
    manifest = json.loads(m_path.read_text())
    manifest.pop("bundle_id")
    manifest["members"] = {
        p.relative_to(folder).as_posix(): {"sha256": file_sha256(p), "size": p.stat().st_size}
        for p in sorted(folder.rglob("*")) if p.is_file() and p != m_path}
    for name, meta in manifest.get("tables", {}).items():
        meta["rows"] = pq.ParquetFile(folder / meta["file"]).metadata.num_rows
    manifest["bundle_id"] = bundle_id_of(manifest)
    m_path.write_bytes(manifest_bytes(manifest))


def _write_table(folder: Path, name: str, table: pa.Table) -> None:
    pq.write_table(table, folder / "tables" / f"{name}.parquet", compression="zstd",
                   write_page_checksum=True)


def _edit_table(folder: Path, name: str, edit) -> None:
    frame = pq.read_table(folder / "tables" / f"{name}.parquet").to_pandas()
    out = edit(frame)
    _write_table(folder, name, out if isinstance(out, pa.Table) else _table(out))
    reseal(folder)


def _edit_manifest(folder: Path, edit) -> None:
    manifest = json.loads((folder / "manifest.json").read_text())
    edit(manifest)
    (folder / "manifest.json").write_bytes(manifest_bytes(manifest))
    reseal(folder)


@pytest.fixture
def bundle(tmp_path) -> Path:
    write_bundle(tmp_path / "b", _content())
    return tmp_path / "b"


def test_a_valid_bundle_loads_with_its_tables_checked_once(bundle):
    b = load_bundle(bundle)
    assert sorted(b.tables) == ["devices", "levelling", "source_walks", "wifi_fp", "wifi_meta",
                                "wifi_rp"]
    assert b.table("wifi_fp") is b.tables["wifi_fp"]  # read and checked once, at load
    assert fingerprint_kinds(b) == ["wifi"]
    assert FingerprintPositioner.from_bundle(b).xy_m.shape == (6, 2)
    reseal(bundle)  # re-sealing an untouched bundle changes nothing
    assert load_bundle(bundle).bundle_id == b.bundle_id
    res = CliRunner().invoke(main, ["bundle", "verify", str(bundle)])
    assert res.exit_code == 0 and res.output.startswith("ok"), res.output


def _set(frame, column, row, value):
    frame = frame.copy()
    if isinstance(value, str) and frame[column].dtype != object:
        frame[column] = frame[column].astype(object)
    frame.loc[row, column] = value
    return frame


TABLE_TAMPERING = [
    ("empty fingerprints", "wifi_fp", lambda f: f.iloc[:0],
     "table 'wifi_fp' has no rows"),
    ("empty reference points", "wifi_rp", lambda f: f.iloc[:0],
     "table 'wifi_rp' has no rows"),
    ("NaN position", "wifi_rp", lambda f: _set(f, "x_m", 2, np.nan),
     "table 'wifi_rp' column 'x_m'"),
    ("far position", "wifi_rp", lambda f: _set(f, "y_m", 2, 1e300),
     "table 'wifi_rp' column 'y_m'"),
    ("duplicate rp", "wifi_rp", lambda f: _set(f, "rp_id", 1, 0),
     "table 'wifi_rp': duplicate rows for the key ['rp_id']"),
    ("+50 dBm", "wifi_fp", lambda f: _set(f, "mean_dbm", 3, 50.0),
     "table 'wifi_fp' column 'mean_dbm'"),
    ("-300 dBm", "wifi_fp", lambda f: _set(f, "mean_dbm", 3, -300.0),
     "table 'wifi_fp' column 'mean_dbm'"),
    ("NaN dBm", "wifi_fp", lambda f: _set(f, "mean_dbm", 3, np.nan),
     "table 'wifi_fp' column 'mean_dbm'"),
    ("text dBm", "wifi_fp", lambda f: f.assign(mean_dbm=f["mean_dbm"].astype(str)),
     "table 'wifi_fp' column 'mean_dbm': type"),
    ("int dBm", "wifi_fp", lambda f: f.assign(mean_dbm=f["mean_dbm"].astype(np.int64)),
     "table 'wifi_fp' column 'mean_dbm': type int64, expected double"),
    ("duplicate (rp_id, ap)", "wifi_fp",
     lambda f: pd.concat([f, f.iloc[[5]]], ignore_index=True),
     "table 'wifi_fp': duplicate rows for the key ['rp_id', 'ap']"),
    ("negative detection rate", "wifi_fp", lambda f: _set(f, "detection_rate", 0, -0.5),
     "table 'wifi_fp' column 'detection_rate'"),
    ("detection rate above 1", "wifi_fp", lambda f: _set(f, "detection_rate", 0, 1.5),
     "table 'wifi_fp' column 'detection_rate'"),
    ("negative variance", "wifi_fp", lambda f: _set(f, "var_db2", 7, -1.0),
     "table 'wifi_fp' column 'var_db2'"),
    ("zero count", "wifi_fp", lambda f: _set(f, "n", 7, 0),
     "table 'wifi_fp' column 'n'"),
    ("null transmitter", "wifi_fp", lambda f: _set(f, "ap", 7, None),
     "table 'wifi_fp' column 'ap': 1 null values"),
    ("unknown reference point", "wifi_fp", lambda f: _set(f, "rp_id", 7, 99),
     "table 'wifi_fp' column 'rp_id' names reference points that 'wifi_rp' lacks"),
    ("missing column", "wifi_fp", lambda f: f.drop(columns=["detection_rate"]),
     "table 'wifi_fp': columns"),
    ("extra column", "wifi_rp", lambda f: f.assign(z_m=0.0),
     "unexpected ['z_m']"),
    ("meta of another kind", "wifi_meta", lambda f: f.assign(kind="ble"),
     "table 'wifi_meta' column 'kind' must be one row 'wifi'"),
    ("meta cell", "wifi_meta", lambda f: f.assign(cell_m=-1.0),
     "table 'wifi_meta' column 'cell_m'"),
    ("device k zero", "devices", lambda f: _set(f, "k", 1, 0.0),
     "table 'devices' column 'k'"),
    ("device twice", "devices", lambda f: _set(f, "device_model", 1, "A"),
     "table 'devices': duplicate rows for the key ['device_model']"),
    ("walk listed twice", "source_walks", lambda f: _set(f, "trace_id", 1, "w1"),
     "table 'source_walks': duplicate rows"),
    ("levelling infinite", "levelling", lambda f: _set(f, "r_x_ut", 0, np.inf),
     "table 'levelling' column 'r_x_ut'"),
]


@pytest.mark.parametrize("what, name, edit, message", TABLE_TAMPERING,
                         ids=[t[0] for t in TABLE_TAMPERING])
def test_a_resealed_table_with_bad_numbers_or_schema_is_refused(bundle, what, name, edit,
                                                                 message):
    _edit_table(bundle, name, edit)
    with pytest.raises(BundleIntegrityError) as err:
        load_bundle(bundle)
    assert message in str(err.value) and str(bundle) in str(err.value), str(err.value)
    res = CliRunner().invoke(main, ["bundle", "verify", str(bundle)])
    assert res.exit_code == 1 and "FAILED" in res.output and message in res.output


def test_a_kinds_tables_come_together(bundle):
    (bundle / "tables" / "wifi_meta.parquet").unlink()

    def drop(m):
        del m["tables"]["wifi_meta"]
    _edit_manifest(bundle, drop)
    with pytest.raises(BundleIntegrityError, match=r"tables \['wifi_rp', 'wifi_fp'\] without "
                                                   r"\['wifi_meta'\]"):
        load_bundle(bundle)


def test_a_table_whose_rows_are_not_the_manifests_is_refused(bundle):
    def lie(m):
        m["tables"]["wifi_fp"]["rows"] += 1
    manifest = json.loads((bundle / "manifest.json").read_text())
    lie(manifest)
    manifest.pop("bundle_id")
    manifest["bundle_id"] = bundle_id_of(manifest)
    (bundle / "manifest.json").write_bytes(manifest_bytes(manifest))
    with pytest.raises(BundleIntegrityError, match="table 'wifi_fp' has 24 rows, the manifest "
                                                   "says 25"):
        load_bundle(bundle)


MANIFEST_TAMPERING = [
    ("angle layer made scalar", lambda m: m["layers"]["heading_offset"].update(kind="scalar"),
     "layer 'heading_offset' must have unit 'deg' and kind 'angle'"),
    ("strength in nT", lambda m: m["layers"]["strength"].update(unit="nT"),
     "layer 'strength' must have unit 'uT'"),
    ("angle layer in radians", lambda m: m["layers"].update(
        extra={**m["layers"]["azimuth"], "unit": "rad"}),
     "layer 'extra' must have unit 'deg' and kind 'angle'"),
    ("1e-300 m cells", lambda m: m["grid"].update(cell_m=1e-300), "grid cell_m 1e-300 m"),
    ("1 km cells", lambda m: m["grid"].update(cell_m=1000.0), "grid cell_m 1000 m"),
    ("far origin", lambda m: m["grid"].update(x0_m=1e12), "grid origin"),
    # each passed every check before session 38
    ("strength read from the vertical layer's file",
     lambda m: m["layers"]["strength"].update(file=m["layers"]["vertical"]["file"]),
     "field 'layers.strength.file' is missing or malformed"),
    ("Wi-Fi fingerprints read from another table's file",
     lambda m: m["tables"]["wifi_fp"].update(file=m["tables"]["source_walks"]["file"]),
     "field 'tables.wifi_fp.file' is missing or malformed"),
    ("a newline in the floor name (a registry folder name)",
     lambda m: m.update(floor_name="F1\nF2"), "field 'floor_name' holds a control character"),
]


@pytest.mark.parametrize("what, edit, message", MANIFEST_TAMPERING,
                         ids=[t[0] for t in MANIFEST_TAMPERING])
def test_resealed_manifest_values_out_of_range_are_refused(bundle, what, edit, message):
    _edit_manifest(bundle, edit)
    with pytest.raises(BundleIntegrityError) as err:
        load_bundle(bundle)
    assert message in str(err.value) and str(bundle) in str(err.value), str(err.value)


def test_a_grid_over_the_builders_cell_limit_is_refused(tmp_path):
    from mapping.grid import MAX_GRID_CELLS as BUILD_LIMIT
    from mapping.radio_scans import RSSI_RANGE_DBM as BUILD_RSSI

    assert MAX_GRID_CELLS == BUILD_LIMIT and tuple(RSSI_RANGE_DBM) == tuple(BUILD_RSSI)
    write_bundle(tmp_path / "b", _content())

    def huge(m):
        m["grid"].update(width=MAX_GRID_CELLS, height=2)
    _edit_manifest(tmp_path / "b", huge)
    with pytest.raises(BundleIntegrityError, match="over the limit of 20,000,000"):
        load_bundle(tmp_path / "b")


@pytest.mark.parametrize("layer, file, value, message", [
    ("strength", "strength.npy", 1e6, "layer strength file holds values from"),
    ("azimuth", "azimuth.npy", 720.0, "layer azimuth file holds values"),
    ("strength", "strength_std.npy", -1.0, "layer strength std_file holds values"),
    ("vertical", "vertical.npy", -np.inf, "layer vertical file holds infinite values"),
])
def test_resealed_layer_values_out_of_range_are_refused(bundle, layer, file, value, message):
    path = bundle / "layers" / file
    arr = np.load(path)
    arr[5, 5] = value
    np.save(path, arr, allow_pickle=False)
    reseal(bundle)
    with pytest.raises(BundleIntegrityError, match=message):
        load_bundle(bundle)


def test_what_older_or_newer_writers_add_still_loads(tmp_path):
    """Levelling before the soft-iron fit (no s_* or device), a table or layer this reader
    does not know (it ignores them), an empty table (pandas gives its columns no type)."""
    c = _content()
    lev = c.tables["levelling"]
    c.tables["levelling"] = lev.drop_columns([n for n in lev.column_names
                                              if n.startswith("s_") or n == "device"])
    c.tables["future"] = pa.table({"anything": ["goes"], "x": [float("nan")]})
    c.tables["devices"] = _table(pd.DataFrame({n: [] for n in c.tables["devices"].column_names}))
    c.layers["roughness"] = Layer(c.layers["strength"].values, c.layers["strength"].std, "m")
    write_bundle(tmp_path / "b", c)
    b = load_bundle(tmp_path / "b")
    assert "future" not in b.tables and b.table("future").num_rows == 1
    assert b.tables["devices"].num_rows == 0 and "s_xx" not in b.table("levelling").column_names


def test_text_columns_may_be_string_or_large_string(bundle):
    """pandas before 3 writes text as ``string``, pandas 3 as ``large_string``."""
    t = pq.read_table(bundle / "tables" / "wifi_fp.parquet")
    assert t.schema.field("ap").type == pa.large_string()
    i = t.column_names.index("ap")
    _write_table(bundle, "wifi_fp", t.set_column(i, "ap", t.column("ap").cast(pa.string())))
    reseal(bundle)
    assert load_bundle(bundle).table("wifi_fp").schema.field("ap").type == pa.string()


# -- the registry pointer against its history (promise 6) --------------------------------------

@pytest.fixture
def registry(tmp_path):
    write_bundle(tmp_path / "v1", _content(0))
    write_bundle(tmp_path / "v2", _content(1))
    reg = Registry(tmp_path / "reg")
    e1, e2 = reg.publish(tmp_path / "v1"), reg.publish(tmp_path / "v2")
    return reg, e1, e2


def _point(reg: Registry, pointer: dict) -> Path:
    path = reg.root / "site" / "F1" / "CURRENT"
    path.write_text(json.dumps(pointer))
    return path


@pytest.mark.parametrize("case", ["old id, current seq", "current id, unknown seq",
                                  "old id, unknown seq", "current id, old seq"])
def test_a_pointer_that_is_no_entry_of_the_history_is_refused(registry, case):
    reg, e1, e2 = registry
    pointer = {"old id, current seq": {"bundle_id": e1["bundle_id"], "seq": 2},
               "current id, unknown seq": {"bundle_id": e2["bundle_id"], "seq": 99},
               "old id, unknown seq": {"bundle_id": e1["bundle_id"], "seq": 99},
               "current id, old seq": {"bundle_id": e2["bundle_id"], "seq": 1}}[case]
    path = _point(reg, pointer)
    floor = reg.root / "site" / "F1"
    with pytest.raises(RegistryError) as err:
        load_bundle(floor)
    msg = str(err.value)
    assert str(path) in msg and f"as #{pointer['seq']}, but history.json" in msg, msg
    with pytest.raises(RegistryError):
        reg.open("site", "F1")
    run = CliRunner().invoke
    res = run(main, ["bundle", "verify", str(floor)])
    assert res.exit_code == 1 and "FAILED" in res.output and "history.json" in res.output
    res = run(main, ["bundle", "list", str(reg.root)])
    assert res.exit_code == 1 and "history.json" in res.output and "Traceback" not in res.output
    # repaired by pointing it at a version: the newest freely, an older one as a rollback
    assert run(main, ["bundle", "use", str(reg.root), "site/F1", "#1"]).exit_code == 1
    res = run(main, ["bundle", "use", str(reg.root), "site/F1", "#2"])
    assert res.exit_code == 0, res.output
    assert reg.current("site", "F1") == e2 and load_bundle(floor).bundle_id == e2["bundle_id"]
    assert [e["current"] for e in reg.list()] == [False, True]


def test_a_history_with_repeated_entries_is_refused(registry):
    reg, e1, e2 = registry
    hist = reg.root / "site" / "F1" / "history.json"
    hist.write_text(json.dumps([e1, {**e2, "seq": 1}]))
    with pytest.raises(RegistryError, match="two entries share a seq"):
        load_bundle(reg.root / "site" / "F1")


def test_a_consistent_registry_moves_forward_and_rolls_back_on_request(registry, tmp_path):
    reg, e1, e2 = registry
    floor = reg.root / "site" / "F1"
    assert load_bundle(floor).bundle_id == e2["bundle_id"]
    with pytest.raises(RegistryError, match="rolling back needs allow_rollback"):
        reg.set_current("site", "F1", e1["bundle_id"])
    reg.set_current("site", "F1", e1["bundle_id"], allow_rollback=True)
    assert reg.current("site", "F1") == e1 and load_bundle(floor).bundle_id == e1["bundle_id"]
    res = CliRunner().invoke(main, ["bundle", "verify", str(floor)])
    assert res.exit_code == 0, res.output
    write_bundle(tmp_path / "v3", _content(2))
    e3 = reg.publish(tmp_path / "v3")
    assert e3["seq"] == 3 and reg.current("site", "F1") == e3
    assert [e["current"] for e in reg.list()] == [False, False, True]


def test_a_version_folder_removed_is_named(registry):
    reg, e1, e2 = registry
    shutil.rmtree(reg.root / "site" / "F1" / "versions" / e2["bundle_id"])
    with pytest.raises(RegistryError, match="its folder is missing"):
        load_bundle(reg.root / "site" / "F1")


@pytest.mark.parametrize("name", ["CURRENT", "history.json"])
@pytest.mark.parametrize("kind", ["link", "fifo"])
def test_a_registry_file_that_is_a_link_or_a_fifo_is_refused_unread(registry, tmp_path, name,
                                                                    kind):
    """Before session 39 a FIFO named CURRENT made every reader wait forever, and a CURRENT
    linked to another floor's was followed."""
    reg, e1, e2 = registry
    path = reg.root / "site" / "F1" / name
    kept = tmp_path / name
    shutil.move(path, kept)
    if kind == "link":
        path.symlink_to(kept)
    else:
        os.mkfifo(path)
    with pytest.raises(RegistryError, match=f"{name}: damaged registry file"):
        load_bundle(reg.root / "site" / "F1")  # no wait: a FIFO is not opened
    path.unlink()
    shutil.move(kept, path)
    assert load_bundle(reg.root / "site" / "F1").bundle_id == e2["bundle_id"]


def test_polar_may_be_scalar_as_in_the_simulators_truth_bundles(bundle):
    _edit_manifest(bundle, lambda m: m["layers"]["polar"].update(kind="scalar"))
    assert load_bundle(bundle).manifest["layers"]["polar"]["kind"] == "scalar"


def test_commands_on_a_resealed_bad_map_stop_with_one_line_naming_it(built, tmp_path):
    """The sample site's F2 with +50 dBm in its Wi-Fi map: `wifi-locate` and `localize` ran
    on it (exit 0); with an empty Wi-Fi map they stopped with a traceback."""
    for what, edit, message in (
            ("loud", lambda f: _set(f, "mean_dbm", 0, 50.0), "'wifi_fp' column 'mean_dbm'"),
            ("empty", lambda f: f.iloc[:0], "table 'wifi_fp' has no rows")):
        out = tmp_path / what
        shutil.copytree(built, out)
        _edit_table(out / "F2", "wifi_fp", edit)
        walk = SITE / "F2" / "path_data_files"
        for cmd in (["wifi-locate", str(out), str(walk)],
                    ["localize", str(out / "F2"), str(next(walk.iterdir())), "-o",
                     str(tmp_path / f"{what}_tracks")]):
            res = CliRunner().invoke(main, cmd)
            assert res.exit_code == 1 and message in res.output, (cmd, res.output)
            assert "Traceback" not in res.output


@pytest.mark.parametrize("edit, message", [
    (lambda c: c.tables.update(wifi_fp=c.tables["wifi_fp"].set_column(
        2, "mean_dbm", pa.array(np.full(c.tables["wifi_fp"].num_rows, 50.0)))),
     "table 'wifi_fp' column 'mean_dbm'"),
    (lambda c: c.layers.update(heading_offset=Layer(
        c.layers["heading_offset"].values, c.layers["heading_offset"].std, "deg")),
     "layer 'heading_offset' must have unit 'deg' and kind 'angle'"),
    (lambda c: c.layers["strength"].values.__setitem__((5, 5), 1e6),
     "layer strength file holds values from"),
    (lambda c: c.metrics.update(heldout_strength={"corr_5m": 0.8, "skill": 0.2}),
     "field 'metrics.heldout_strength.shape_rmse_ut' is missing or malformed"),
])
def test_the_writer_refuses_what_a_reader_would(tmp_path, edit, message):
    """A bundle the loader would refuse is not written (and so never published)."""
    content = _content()
    edit(content)
    with pytest.raises(BundleError, match="refused before writing: .*" + message):
        write_bundle(tmp_path / "b", content)
    assert not (tmp_path / "b").exists()


def test_floor_bundles_have_a_grid_and_site_bundles_none(tmp_path, bundle):
    """The writer refuses, and the loader (re-sealed) refuses, the other combination."""
    import dataclasses

    content = _content()
    for wrong in (dataclasses.replace(content, grid=None, mask=None, layers={}),
                  dataclasses.replace(content, kind="site")):
        with pytest.raises(BundleError, match="a floor bundle needs a grid and a site bundle "
                                              "has none"):
            write_bundle(tmp_path / "w", wrong)
        assert not (tmp_path / "w").exists()
    _edit_manifest(bundle, lambda m: m.update(kind="site"))
    with pytest.raises(BundleIntegrityError, match="a site bundle has no grid, mask or layers"):
        load_bundle(bundle)


def test_the_writer_refuses_a_site_id_the_reader_would(tmp_path):
    """A control character in a trace header's SiteID reached the manifest: the build wrote
    bundles that `bundle verify` then refused."""
    import dataclasses

    content = dataclasses.replace(_content(), site_id="site\x01")
    with pytest.raises(BundleError, match="bundle site_id 'site.x01' holds a control character"):
        write_bundle(tmp_path / "b", content)
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("damage", ["deleted", "emptied", "cut"])
def test_a_history_that_lost_versions_is_refused_by_writers(registry, tmp_path, damage):
    """A floor whose history.json was deleted, emptied or cut while CURRENT and versions/
    kept the newer version: publishing took the floor for a new one, numbered the older
    bundle #1 again and moved CURRENT back to it (exit 0, and verify then said ok). Every
    writer now refuses, naming the file; list and verify name it too, and nothing moves."""
    reg, e1, e2 = registry
    floor = reg.root / "site" / "F1"
    hist = floor / "history.json"
    if damage == "deleted":
        hist.unlink()
    else:
        hist.write_text(json.dumps([] if damage == "emptied" else [e1]))
    said = {"deleted": "is missing", "emptied": "lists no version", "cut": "ends at #1"}[damage]
    message = f"history.json: {said}, but CURRENT names version {e2['bundle_id'][:16]} as #2"
    write_bundle(tmp_path / "v3", _content(2))
    for bundle in ("v1", "v3"):
        with pytest.raises(RegistryError, match=message):
            reg.publish(tmp_path / bundle)
    for seq in ("#1", "#2"):
        res = CliRunner().invoke(main, ["bundle", "use", str(reg.root), "site/F1", seq])
        assert res.exit_code == 1 and said in res.output, res.output
    with pytest.raises(RegistryError, match=message):
        load_bundle(floor)
    res = CliRunner().invoke(main, ["bundle", "list", str(reg.root)])
    assert res.exit_code == 1 and message in res.output, res.output
    res = CliRunner().invoke(main, ["bundle", "verify", str(floor)])
    assert res.exit_code == 1 and said in res.output
    assert json.loads((floor / "CURRENT").read_text()) == e2
    assert sorted(p.name for p in (floor / "versions").iterdir()) == sorted(
        [e1["bundle_id"], e2["bundle_id"]])


def test_a_bundle_without_its_manifest_is_named_not_passed_over(tmp_path):
    """Deleting one file, a bundle's manifest.json, made the bundle vanish from a folder of
    bundles: `bundle verify`/`info` on the folder exited 0 without it and `localize` said the
    bundles held no such floor. It is now a damaged bundle, refused by name; a registry floor
    with no current version (published with --no-current) is said, not failed."""
    from localize.floors import SiteMaps

    out = tmp_path / "out"
    write_bundle(out / "F1", _content(0))
    content = _content(1)
    content.floor_id, content.floor_name = "f2", "F2"
    write_bundle(out / "F2", content)
    (out / "F1" / "manifest.json").unlink()
    run = CliRunner().invoke
    for args in (["bundle", "verify", str(out)], ["bundle", "info", str(out)]):
        res = run(main, args)
        assert res.exit_code == 1 and f"{out / 'F1'}: manifest.json is missing, but the " \
            "folder holds a bundle's mask.npy, layers" in res.output, res.output
    with pytest.raises(BundleIntegrityError, match="F1: manifest.json is missing"):
        SiteMaps.open(out)
    reg = Registry(tmp_path / "reg")
    reg.publish(out / "F2", make_current=False)
    floor = reg.root / "site" / "F2"
    with pytest.raises(BundleError, match="a registry floor folder with no current version"):
        load_bundle(floor)
    with pytest.raises(BundleError, match="no current version .* indoormap bundle use"):
        SiteMaps.open(floor)  # localize said "neither a bundle nor a folder of bundles"
    res = run(main, ["bundle", "verify", str(reg.root / "site")])
    assert f"note: {floor}: no current version" in res.output


def test_list_takes_a_publish_between_its_reads_for_no_damage(registry, tmp_path,
                                                               monkeypatch):
    """A publish writes history.json, then CURRENT; list read them in that order too, so a
    publish landing between its two reads showed a pointer beyond the history: "the history
    lost versions. Restore history.json", on a healthy registry. It reads the pointer first."""
    reg, e1, e2 = registry
    write_bundle(tmp_path / "v3", _content(2))
    current = Registry.current
    landed = []

    def current_then_a_publish(self, *args, **kwargs):
        found = current(self, *args, **kwargs)
        if not landed:  # (the publish asks for the pointer too)
            landed.append(True)
            Registry(self.root).publish(tmp_path / "v3")
        return found

    monkeypatch.setattr(Registry, "current", current_then_a_publish)
    rows = reg.list()
    assert landed and [r["problem"] for r in rows] == [None] * 3
    assert [(r["seq"], r["current"]) for r in rows] == [(1, False), (2, True), (3, False)]
    monkeypatch.undo()
    assert [r["current"] for r in reg.list()] == [False, False, True]
    # a damaged history without a pointer is still one row with its reason
    (reg.root / "site" / "F1" / "CURRENT").unlink()
    (reg.root / "site" / "F1" / "history.json").write_text("{}")
    (row,) = reg.list()
    assert row["seq"] is None and "not a registry history" in row["problem"]


def test_a_bundle_being_written_beside_others_is_none_of_them(tmp_path):
    """A bundle written into a folder of bundles stays in a hidden .tmp-* folder until its
    manifest is in place; a killed writer leaves it so. Since the damaged-bundle check it was
    taken for a bundle without its manifest, and the folder failed to open."""
    from localize.bundle import bundle_dirs
    from localize.floors import SiteMaps

    write_bundle(tmp_path / "F1", _content(0))
    half = tmp_path / ".tmp-12345-F2"
    shutil.copytree(tmp_path / "F1", half)
    (half / "manifest.json").unlink()
    assert bundle_dirs(tmp_path) == [tmp_path / "F1"]
    assert len(SiteMaps.open(tmp_path).bundles) == 1
    res = CliRunner().invoke(main, ["bundle", "verify", str(tmp_path)])
    assert res.exit_code == 0 and ".tmp-" not in res.output, res.output


def test_a_linked_bundle_folder_is_refused_naming_the_real_one(tmp_path):
    """`bundle verify LINK` said only that a bundle folder may not be a link."""
    write_bundle(tmp_path / "F1", _content(0))
    (tmp_path / "link").symlink_to(tmp_path / "F1")
    res = CliRunner().invoke(main, ["bundle", "verify", str(tmp_path / "link")])
    assert res.exit_code == 1 and "a bundle folder may not be a link; give the folder it " \
        f"links to, {tmp_path / 'F1'}" in " ".join(res.output.split()), res.output
    assert CliRunner().invoke(main, ["bundle", "verify", str(tmp_path / "F1")]).exit_code == 0
