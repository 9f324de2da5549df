"""Map bundles: round trip, lookup, tamper evidence, schema, crash-safe publication, registry."""

from __future__ import annotations

import json
import multiprocessing
import os
import pickle
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from click.testing import CliRunner

from localize.bundle import Grid, bundle_id_of, load_bundle, manifest_bytes, read_npy_checked, \
    sample_grid
from mapping.bundle_report import bundle_differences, metric_lines
from mapping.bundle_writer import BundleContent, Layer, write_bundle
from mapping.registry import Registry
from survey.cli import main
from survey.errors import BundleError, BundleIntegrityError, RegistryError, RollbackRefused


def _content(offset: float = 0.0, floor: str = "F1") -> BundleContent:
    g = Grid(10.0, 20.0, 0.5, 24, 16)
    mask = np.ones(g.shape, bool)
    mask[:4, :4] = False
    xc, yc = g.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    strength = np.where(mask, 40 + xx - 10 + offset, np.nan).astype(np.float32)
    az = np.where(mask, np.mod(350 + 4 * (xx - 10), 360), np.nan).astype(np.float32)
    return BundleContent(
        "site", "floor-1", floor, grid=g, mask=mask,
        layers={"strength": Layer(strength, np.where(mask, 1.0, np.nan).astype(np.float32),
                                  "uT"),
                "azimuth": Layer(az, np.where(mask, 2.0, np.nan).astype(np.float32), "deg",
                                 "angle")},
        tables={"walks": pa.table({"trace_id": ["a", "b"], "n": [1, 2]})},
        build={"build_time": "2026-01-01T00:00:00Z", "params": {"cell_m": 0.5}},
        metrics={"heldout_strength": {"shape_rmse_ut": 4.2, "constant_shape_rmse_ut": 5.0,
                                      "skill": 0.16, "corr_0.7m": 0.1, "corr_5m": None,
                                      "n_samples": 900, "n_walks": 9, "folds": 5}})


@pytest.fixture
def bundle_dir(tmp_path):
    write_bundle(tmp_path / "b", _content())
    return tmp_path / "b"


def test_verify_after_a_rebuild_says_replaced_not_corrupted(bundle_dir):
    """A service holding a loaded bundle calls verify() as a health check after the map team
    rebuilt the folder with --overwrite: it said a member "does not match its checksum
    (changed or corrupted)". It says the folder now holds another bundle, naming both ids;
    what was loaded still samples as before. A manifest edited under the same id is damage."""
    from survey.errors import BundleReplaced

    b = load_bundle(bundle_dir)
    before = b.sample("strength", 15.0, 25.0)
    b.verify()
    new_id = write_bundle(bundle_dir, _content(offset=1.0), overwrite=True)
    with pytest.raises(BundleReplaced, match=rf"now holds bundle {new_id[:16]}, not the "
                                             rf"{b.bundle_id[:16]} loaded from it"):
        b.verify()
    assert b.sample("strength", 15.0, 25.0) == before
    fresh = load_bundle(bundle_dir)
    fresh.verify()
    manifest = json.loads((bundle_dir / "manifest.json").read_text())
    manifest["site_name"] = "edited"
    (bundle_dir / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleIntegrityError, match="bundle id does not match the manifest"):
        fresh.verify()
    shutil.rmtree(bundle_dir)  # moved or deleted: still an integrity error, as before
    with pytest.raises(BundleIntegrityError, match="the bundle's folder no longer holds it"):
        fresh.verify()


def test_round_trip_and_lookup(bundle_dir):
    b = load_bundle(bundle_dir)
    assert b.manifest["floor_name"] == "F1" and b.grid == Grid(10.0, 20.0, 0.5, 24, 16)
    assert b.layer_unit("strength") == "uT" and b.table("walks").num_rows == 2
    # bilinear in metres: the layer is 40 + (x - 10), so lookups are exact inside
    x = np.array([11.0, 15.3, 20.7])
    np.testing.assert_allclose(b.sample("strength", x, 25.0), 40 + x - 10, atol=1e-4)
    # off the mask, off the grid: NaN; angles across north interpolate through 0
    assert np.isnan(b.sample("strength", [10.5, 100.0, 5.0], [20.5, 25.0, 25.0])).all()
    a = b.sample("azimuth", [12.4, 12.6], [25.0, 25.0])
    assert abs(((a[0] - 359.6) + 180) % 360 - 180) < 1e-3 and abs(a[1] - 0.4) < 1e-3
    assert b.sample("strength", 15.0, 25.0, std=True) == pytest.approx(1.0)
    assert b.reachable([10.5, 15.0], [20.5, 25.0]).tolist() == [False, True]
    # a table read after the load (one no schema describes) whose file went since: named
    (bundle_dir / b.manifest["tables"]["walks"]["file"]).unlink()
    with pytest.raises(BundleIntegrityError, match=r"table 'walks' is not a readable Parquet"):
        b.table("walks")


def test_lookups_refuse_what_is_no_layer_or_no_coordinates(bundle_dir):
    """From a notebook (session 48's tour): a list for the layer name ("unhashable type"),
    text coordinates (numpy's ValueError), None coordinates (NaN, silently), a site bundle's
    layer (KeyError 'layers') and layer_unit of a wrong name (KeyError) now name what is
    wrong; the mask is read-only as the layers are (an assignment to it moved every
    localizer's walls); a bundle's manifest.json given for the bundle names its folder."""
    b = load_bundle(bundle_dir)
    with pytest.raises(BundleError, match=r"no layer \['strength'\]; has \['azimuth', 'strength'\]"):
        b.sample(["strength"], 11.0, 25.0)
    with pytest.raises(BundleError, match="no layer 'nope'"):
        b.layer_unit("nope")
    for x, said in (("a", "x_m must be numbers (m), got <U1"), (None, "x_m must be numbers")):
        with pytest.raises(ValueError, match=re.escape(said)):
            b.sample("strength", x, 25.0)
        with pytest.raises(ValueError, match=re.escape(said)):
            b.reachable(x, 25.0)
    with pytest.raises(ValueError, match="assignment destination is read-only"):
        b.mask[:] = True
    assert not b.layers["strength"].flags.writeable
    site = load_bundle(bundle_dir)
    site.grid = None  # what a site bundle loads as (no rasters)
    for call in (lambda: site.sample("strength", 1.0, 1.0), lambda: site.reachable(1.0, 1.0),
                 lambda: site.layer_unit("strength")):
        with pytest.raises(BundleError, match="a site-level bundle has no"):
            call()
    with pytest.raises(BundleError, match=re.escape(f"a map bundle is a folder: give "
                                                    f"{bundle_dir}")):
        load_bundle(bundle_dir / "manifest.json")


def test_sample_grid_next_to_missing_cells_renormalises():
    g = Grid(0, 0, 1.0, 3, 1)
    mask = np.ones((1, 3), bool)
    v = np.array([[10.0, 20.0, np.nan]], np.float32)
    got = sample_grid(g, mask, v, [1.4, 1.9, 2.5], [0.5, 0.5, 0.5])
    assert got[0] == pytest.approx(20.0 - 10 * 0.1) and got[1] == pytest.approx(20.0)
    assert np.isnan(got[2])


def test_same_content_same_bytes(tmp_path):
    a = write_bundle(tmp_path / "a", _content())
    b = write_bundle(tmp_path / "b", _content())
    assert a == b
    for p in (tmp_path / "a").rglob("*"):
        if p.is_file():
            assert p.read_bytes() == (tmp_path / "b" / p.relative_to(tmp_path / "a")).read_bytes()


def _members(path: Path) -> list[Path]:
    return sorted(p for p in path.rglob("*") if p.is_file())


def test_every_flipped_byte_is_rejected(tmp_path, bundle_dir):
    """Flip each byte of the manifest, and a seeded sample of bytes in every member."""
    rng = np.random.default_rng(0)
    tried = 0
    for member in _members(bundle_dir):
        data = member.read_bytes()
        positions = (range(len(data)) if member.name == "manifest.json"
                     else rng.choice(len(data), size=min(len(data), 40), replace=False))
        for pos in positions:
            copy = tmp_path / "copy"
            shutil.copytree(bundle_dir, copy)
            target = copy / member.relative_to(bundle_dir)
            mutated = bytearray(data)
            mutated[pos] ^= 0x01 << int(rng.integers(0, 8))
            target.write_bytes(bytes(mutated))
            with pytest.raises(BundleError):
                load_bundle(copy)
            shutil.rmtree(copy)
            tried += 1
    assert tried > 300


@pytest.mark.parametrize("edit", ["trailing space", "no final newline", "other indent",
                                  "keys reordered", "escaped character", "number respelled"])
def test_a_manifest_edited_without_changing_its_content_is_refused(bundle_dir, edit):
    """RELIABILITY #3 is about every byte: white space, key order and spellings of the same
    values change the file, so they are refused although the parsed content (and so the bundle
    id) is the same."""
    m_path = bundle_dir / "manifest.json"
    text = m_path.read_text()
    manifest = json.loads(text)
    edited = {
        "trailing space": text + " ",
        "no final newline": text.rstrip("\n"),
        "other indent": json.dumps(manifest, sort_keys=True, indent=2) + "\n",
        "keys reordered": json.dumps(dict(reversed(manifest.items())), indent=1) + "\n",
        "escaped character": text.replace('"format"', '"\\u0066ormat"', 1),
        "number respelled": text.replace('"cell_m": 0.5,', '"cell_m": 0.50,', 1),
    }[edit]
    assert edited != text and manifest_bytes(manifest) == text.encode()
    assert bundle_id_of(json.loads(edited)) == manifest["bundle_id"]  # the same content
    m_path.write_text(edited)
    with pytest.raises(BundleIntegrityError, match="bytes are not the ones indoormap writes"):
        load_bundle(bundle_dir)


def test_a_manifest_string_that_is_not_unicode_is_an_integrity_error(bundle_dir):
    """A lone surrogate escape is valid JSON but no UTF-8 string: refused with the bundle's
    error, not a UnicodeEncodeError traceback."""
    m_path = bundle_dir / "manifest.json"
    m_path.write_text(m_path.read_text().replace('"floor_name": "F1"',
                                                 '"floor_name": "\\udcff"', 1))
    with pytest.raises(BundleIntegrityError, match="unreadable manifest"):
        load_bundle(bundle_dir)


@pytest.mark.parametrize("change, match", [
    ({"kind": "building"}, "kind must be 'floor' or 'site'"),
    ({"floor_name": None}, "floor_name must be a string"),
    ({"build": {"source_walks": [{"trace_id": "walk\udcff"}]}}, "cannot be written as JSON"),
    ({"metrics": {"score": float("nan")}}, "cannot be written as JSON"),
])
def test_the_writer_refuses_what_the_reader_would(tmp_path, change, match):
    content = _content()
    for key, value in change.items():
        setattr(content, key, value)
    with pytest.raises(BundleError, match=match):
        write_bundle(tmp_path / "b", content)
    assert list(tmp_path.iterdir()) == []  # nothing written, no litter


def test_metric_lines_skip_values_that_are_not_numbers():
    lines = metric_lines({"metrics": {"interpolator": "local_linear", "bandwidth_m": "3",
                                      "smoothing_cv_shape_rmse_ut": {"a": "x", "b": 4.25},
                                      "coverage": {"within_2m": None, "within_5m": 0.5}}})
    assert lines == {"smoothing": "smoothing local_linear (cross-validated shape RMSE 4.25 uT)",
                     "coverage": "reachable area near a sample: 50 % within 5 m"}


@pytest.mark.parametrize("attack", ["extra", "empty_folder", "missing", "symlink", "dotdot",
                                    "absolute", "schema", "npy_object"])
def test_structural_tampering_is_refused(tmp_path, bundle_dir, attack):
    m_path = bundle_dir / "manifest.json"
    manifest = json.loads(m_path.read_text())

    def rewrite(m):
        m["bundle_id"] = bundle_id_of(m)
        m_path.write_bytes(manifest_bytes(m))

    if attack == "extra":
        (bundle_dir / "layers" / "evil.npy").write_bytes(b"x")
        match = "not listed"
    elif attack == "empty_folder":
        (bundle_dir / "layers" / "more").mkdir()
        match = "folder layers/more holds no member"
    elif attack == "missing":
        (bundle_dir / "layers" / "azimuth_std.npy").unlink()
        match = "missing"
    elif attack == "symlink":
        target = bundle_dir / "tables" / "walks.parquet"
        data = target.read_bytes()
        (tmp_path / "outside.parquet").write_bytes(data)
        target.unlink()
        os.symlink(tmp_path / "outside.parquet", target)
        match = "link"
    elif attack in ("dotdot", "absolute"):
        name = "../escape.npy" if attack == "dotdot" else "/etc/passwd"
        manifest["members"][name] = {"sha256": "0" * 64, "size": 1}
        rewrite(manifest)
        match = "plain relative path"
    elif attack == "schema":
        manifest["schema_version"] = 99
        rewrite(manifest)
        match = "schema version 99"
    else:  # an object-dtype .npy (would need pickle) listed with a correct checksum
        import hashlib
        import io

        buf = io.BytesIO()
        np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
        data = buf.getvalue()
        (bundle_dir / "mask.npy").write_bytes(data)
        manifest["members"]["mask.npy"] = {"sha256": hashlib.sha256(data).hexdigest(),
                                           "size": len(data)}
        rewrite(manifest)
        match = "not allowed"
    with pytest.raises(BundleError, match=match):
        load_bundle(bundle_dir)


def _set(m: dict, path: str, value) -> None:
    """Set (or with value None, delete) the manifest field at dotted ``path``."""
    *parents, last = path.split(".")
    for key in parents:
        m = m[key]
    if value is None:
        del m[last]
    else:
        m[last] = value


@pytest.mark.parametrize("field, value, match", [
    ("members.mask.npy", "x", "'members' is missing or malformed"),
    ("layers.azimuth.file", None, "layer 'azimuth' file None is not a listed member"),
    ("mask", "x.npy", "mask 'x.npy' is not a listed member"),
    ("mask", None, "field 'mask' is missing or malformed"),
    ("layers", ["a"], "'layers' is missing or malformed"),
    ("site_id", None, "'site_id' is missing or malformed"),
    ("floor_name", 3, "'floor_name' is missing or malformed"),
    ("metrics", [1], "'metrics' is missing or malformed"),
    ("kind", "building", "'kind' is missing or malformed"),
    ("build", None, "'build' is missing or malformed"),
    ("tables", [1], "'tables' is missing or malformed"),
    ("tables.walks.rows", None, "'tables' is missing or malformed"),
    ("layers.azimuth.kind", None, "'layers' is missing or malformed"),
    ("build.source_walks", [1], "'build.source_walks' is missing or malformed"),
    ("build.params", [1], "'build' is missing or malformed"),
    ("grid.width", 24.5, "manifest grid is malformed: width and height must be whole"),
    # each loaded before session 39
    ("tables", None, "field 'tables' is missing or malformed"),  # wifi-locate failed later
    ("grid", None, "field 'grid' is missing or malformed"),  # a floor bundle with no map
    ("grid.x0_m", "1.5", "field 'grid' is missing or malformed"),
    ("signature", "trust me", "unknown field(s) 'signature'"),
    # localize --method auto chose another method by it
    ("metrics.heldout_strength", {"corr_5m": "0.9"},
     "field 'metrics.heldout_strength.shape_rmse_ut' is missing or malformed"),
    ("metrics.heldout_strength.corr_5m", "0.9",
     "field 'metrics.heldout_strength.corr_5m' is missing or malformed"),
    ("metrics.heldout_strength.folds", 5.0,
     "field 'metrics.heldout_strength.folds' is missing or malformed"),
    # a table outside the bundle, by path or by a name the members do not list
    ("tables.walks.file", "../outside.parquet", "table 'walks' file '../outside.parquet' is "
                                                "not a listed member"),
])
def test_a_manifest_with_a_valid_id_but_malformed_fields_is_refused(bundle_dir, field, value,
                                                                     match):
    """Someone who rewrites the manifest can recompute its id: every reader (load, verify,
    info, diff) still gets a clear integrity error naming the field, not a traceback."""
    m_path = bundle_dir / "manifest.json"
    manifest = json.loads(m_path.read_text())
    if field.startswith("members."):
        manifest["members"]["mask.npy"] = value
    else:
        _set(manifest, field, value)
    manifest["bundle_id"] = bundle_id_of(manifest)
    m_path.write_bytes(manifest_bytes(manifest))
    with pytest.raises(BundleIntegrityError, match=re.escape(match)):
        load_bundle(bundle_dir)
    res = CliRunner().invoke(main, ["bundle", "verify", str(bundle_dir)])
    assert res.exit_code == 1 and "FAILED" in res.output and "Traceback" not in res.output
    for command in (["info", str(bundle_dir)], ["diff", str(bundle_dir), str(bundle_dir)]):
        res = CliRunner().invoke(main, ["bundle", *command])
        assert res.exit_code == 1 and match in res.output, res.output


def test_non_finite_numbers_in_a_manifest_are_refused(bundle_dir):
    m_path = bundle_dir / "manifest.json"
    original = m_path.read_text()
    for number in ("NaN", "Infinity", "1e999"):
        text, n = re.subn(r'"cell_m":\s*0\.5', f'"cell_m": {number}', original, count=1)
        assert n == 1
        m_path.write_text(text)
        with pytest.raises(BundleIntegrityError, match=f"non-finite number {number}"):
            load_bundle(bundle_dir)


def test_infinite_layer_values_are_refused(bundle_dir):
    import hashlib

    m_path = bundle_dir / "manifest.json"
    manifest = json.loads(m_path.read_text())
    name = manifest["layers"]["strength"]["file"]
    arr = np.load(bundle_dir / name)
    arr[0, 0] = np.inf
    np.save(bundle_dir / name, arr)
    data = (bundle_dir / name).read_bytes()
    manifest["members"][name] = {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    manifest["bundle_id"] = bundle_id_of(manifest)
    m_path.write_bytes(manifest_bytes(manifest))
    with pytest.raises(BundleIntegrityError, match="infinite values"):
        load_bundle(bundle_dir)


def test_not_a_bundle(tmp_path):
    """A folder without a manifest is no bundle; a path that does not exist says so, in
    Python and in `bundle verify` (which goes on with the other paths)."""
    with pytest.raises(BundleError, match="no manifest.json"):
        load_bundle(tmp_path)
    with pytest.raises(BundleError, match="nope: no such file or folder"):
        load_bundle(tmp_path / "nope")
    res = CliRunner().invoke(main, ["bundle", "verify", str(tmp_path / "nope"), str(tmp_path)])
    assert res.exit_code == 1
    assert f"FAILED  {tmp_path / 'nope'}: no such file or folder" in res.output
    assert f"FAILED  {tmp_path}: not a map bundle" in res.output


@pytest.mark.parametrize("path, text, said", [
    ("out/F1", "out/F1: no manifest.json", "out/F1: no manifest.json"),
    ("a.txt", "a.txt:12: bad field", "a.txt:12: bad field"),
    ("p.geojson", "p.geojson (feature 0): no walk_id", "p.geojson (feature 0): no walk_id"),
    ("out/F1", "out/F10: no manifest.json", "out/F1: out/F10: no manifest.json"),
    ("b", "b/manifest.json: unreadable", "b: b/manifest.json: unreadable"),
])
def test_a_failure_names_its_path_once(path, text, said):
    from survey.errors import at_path

    assert at_path(path, text) == said


def test_writer_refuses_bad_numbers(tmp_path):
    c = _content()
    c.layers["strength"].values[5, 5] = np.inf
    with pytest.raises(BundleError, match="infinite"):
        write_bundle(tmp_path / "x", c)
    c = _content()
    c.layers["strength"].values[0, 0] = 1.0  # off the mask
    with pytest.raises(BundleError, match="outside the reachable mask"):
        write_bundle(tmp_path / "x", c)
    assert not (tmp_path / "x").exists()


CRASH = """
import sys
sys.path.insert(0, sys.argv[2])
from test_bundle import _content
from mapping.bundle_writer import write_bundle
write_bundle(sys.argv[1], _content(offset=5.0), overwrite=True)
"""


@pytest.mark.parametrize("point", ["bundle:member", "bundle:before-fsync",
                                   "bundle:before-rename", "bundle:after-rename"])
def test_killed_write_leaves_previous_bundle(tmp_path, bundle_dir, point):
    old_id = load_bundle(bundle_dir).bundle_id
    env = {**os.environ, "INDOORMAP_CRASH_AT": point}
    proc = subprocess.run([sys.executable, "-c", CRASH, str(bundle_dir),
                           str(Path(__file__).parent)], env=env, capture_output=True)
    assert proc.returncode == 70, proc.stderr.decode()
    b = load_bundle(bundle_dir)  # always a complete, verified bundle
    assert b.bundle_id == old_id or point == "bundle:after-rename"
    write_bundle(bundle_dir, _content(offset=7.0), overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]  # litter cleaned


def test_registry_versions_move_forward(tmp_path):
    reg = Registry(tmp_path / "reg")
    write_bundle(tmp_path / "v1", _content(0.0))
    write_bundle(tmp_path / "v2", _content(1.0))
    e1 = reg.publish(tmp_path / "v1")
    e2 = reg.publish(tmp_path / "v2")
    assert (e1["seq"], e2["seq"]) == (1, 2)
    assert reg.open("site", "F1").bundle_id == e2["bundle_id"]
    assert reg.publish(tmp_path / "v2") == e2  # idempotent
    with pytest.raises(RollbackRefused, match="rolling back needs allow_rollback") as refused:
        reg.set_current("site", "F1", e1["bundle_id"])
    assert (refused.value.seq, refused.value.current_seq) == (1, 2)
    copied = pickle.loads(pickle.dumps(refused.value))  # as when it crosses a process
    assert (type(copied), str(copied), copied.where, copied.current_text) == (
        RollbackRefused, str(refused.value), "site/F1", "the current #2")
    reg.set_current("site", "F1", e1["bundle_id"], allow_rollback=True)
    assert reg.open("site", "F1").bundle_id == e1["bundle_id"]
    with pytest.raises(RegistryError, match="not published"):
        reg.set_current("site", "F1", "f" * 64)
    assert [e["current"] for e in reg.list()] == [True, False]
    # published versions are immutable: a changed byte there is caught on open
    v = tmp_path / "reg" / "site" / "F1" / "versions" / e2["bundle_id"] / "mask.npy"
    v.write_bytes(v.read_bytes()[:-1] + b"\x07")
    with pytest.raises(BundleIntegrityError):
        reg.open("site", "F1", e2["bundle_id"])
    # publishing the intact bundle again repairs it (the id is the content's hash); it
    # failed with the same checksum error, leaving only a hand deletion
    res = CliRunner().invoke(main, ["bundle", "publish", str(tmp_path / "v2"), "--registry",
                                    str(tmp_path / "reg"), "--no-current"])
    assert res.exit_code == 0 and "#2; its damaged copy in the registry was replaced" in \
        res.output, res.output
    assert reg.open("site", "F1", e2["bundle_id"]).bundle_id == e2["bundle_id"]
    assert reg.publish(tmp_path / "v2", make_current=False) == e2  # intact now: reused


def test_a_rollback_sticks_when_the_withdrawn_version_is_published_again(tmp_path):
    """After ``bundle use '#1' --rollback``, a nightly build of unchanged inputs publishes
    #2's bytes again: that made #2 current again, exit 0, no word. It is refused (the CLI
    names the command that makes it current), and stays so until it is chosen by hand; a
    publish that crashed before pointing at its version is still finished by a retry."""
    from survey.errors import WithdrawnVersion

    reg = Registry(tmp_path / "reg")
    for k in (1, 2, 3):
        write_bundle(tmp_path / f"v{k}", _content(float(k)))
    e1, e2 = reg.publish(tmp_path / "v1"), reg.publish(tmp_path / "v2")
    reg.set_current("site", "F1", e1["bundle_id"], allow_rollback=True)
    with pytest.raises(WithdrawnVersion, match=r"\(#2\) was rolled back from \(the current is "
                                               r"#1\)") as refused:
        reg.publish(tmp_path / "v2")
    assert type(pickle.loads(pickle.dumps(refused.value))) is WithdrawnVersion
    assert reg.current("site", "F1")["seq"] == 1
    res = CliRunner().invoke(main, ["bundle", "publish", str(tmp_path / "v2"), "--registry",
                                    str(tmp_path / "reg")])
    assert res.exit_code == 1 and "already published as #2, which was rolled back from (the " \
        f"current is #1); to make it current again: indoormap bundle use {tmp_path / 'reg'} " \
        "site/F1 '#2'" in res.output
    assert reg.publish(tmp_path / "v2", make_current=False) == e2  # adding it is no harm
    e3 = reg.publish(tmp_path / "v3")  # a new version goes forward, and ends the rollback
    assert reg.current("site", "F1") == {"bundle_id": e3["bundle_id"], "seq": 3}
    reg.set_current("site", "F1", e1["bundle_id"], allow_rollback=True)
    reg.set_current("site", "F1", e2["bundle_id"])  # chosen by hand: #3 stays withdrawn
    with pytest.raises(WithdrawnVersion, match=r"\(#3\) was rolled back from"):
        reg.publish(tmp_path / "v3")
    reg.set_current("site", "F1", e3["bundle_id"])
    pointer = tmp_path / "reg" / "site" / "F1" / "CURRENT"
    assert reg.publish(tmp_path / "v3") == e3 and json.loads(pointer.read_text()) == e3
    # a publish killed after writing the history, before the pointer: the retry points
    pointer.write_text(json.dumps({"bundle_id": e2["bundle_id"], "seq": 2}))
    assert reg.publish(tmp_path / "v3") == e3 and reg.current("site", "F1")["seq"] == 3


def test_bundle_diff_names_every_kind_of_change(tmp_path):
    """Grid origin, a walk re-ingested with other content, the seed, a layer's unit and a
    layer's values: each is a line of ``bundle diff`` (and of ``bundle_differences``)."""
    walks = [{"trace_id": "w1", "sha256": "a" * 64}, {"trace_id": "w2", "sha256": "b" * 64}]
    a = _content()
    a.build = {**a.build, "seed": 1, "source_walks": walks,
               "floor_plan": [{"file": "plan.dxf", "sha256": "e" * 64}]}
    b = _content(offset=0.5)
    b.build = {**b.build, "seed": 2, "params": {"cell_m": 0.5, "seed": 2},
               "floor_plan": [{"file": "plan.dxf", "sha256": "f" * 64}],
               "source_walks": [walks[0], {"trace_id": "w2", "sha256": "c" * 64},
                                {"trace_id": "w3", "sha256": "d" * 64}]}
    # a layer of a name indoormap does not know may change unit (a known one may not)
    a.layers["extra"] = Layer(a.layers["strength"].values, a.layers["strength"].std, "m")
    b.layers["extra"] = Layer(a.layers["strength"].values, a.layers["strength"].std, "cm")
    c = _content()
    c.grid = Grid(11.0, 20.0, 0.5, 24, 16)  # same size, moved 1 m east
    for name, content in (("a", a), ("b", b), ("c", c)):
        write_bundle(tmp_path / name, content)
    lines = bundle_differences(load_bundle(tmp_path / "a"), load_bundle(tmp_path / "b"))
    assert "param seed: None -> 2" in lines
    assert "walks: 1 shared, 1 changed content, 1 added, 0 removed" in lines
    assert "walk w2: content changed (sha256 aaaaaaaaaaaa -> cccccccccccc)" not in lines
    assert "walk w2: content changed (sha256 bbbbbbbbbbbb -> cccccccccccc)" in lines
    assert "layer extra unit: m -> cm" in lines
    assert "floor plan: plan.dxf (eeeeeeeeeeee) -> plan.dxf (ffffffffffff)" in lines
    assert not any(line.startswith("build floor_plan") for line in lines)
    assert any(line.startswith("layer strength: mean abs change 0.500 uT") for line in lines)
    assert not any(line.startswith("warning") or line.startswith("grid") for line in lines)
    moved = bundle_differences(load_bundle(tmp_path / "a"), load_bundle(tmp_path / "c"))
    assert ("grid: 24 x 16 cells of 0.5 m from (10, 20) m -> 24 x 16 cells of 0.5 m from "
            "(11, 20) m (layers not compared cell by cell)") in moved
    assert not any("mean abs change" in line for line in moved)
    assert bundle_differences(load_bundle(tmp_path / "a"), load_bundle(tmp_path / "a")) == []
    res = CliRunner().invoke(main, ["bundle", "diff", str(tmp_path / "a"), str(tmp_path / "b")])
    assert res.exit_code == 0 and "layer extra unit: m -> cm" in res.output


def _publish_after(barrier, registry: str, bundle: str) -> None:
    barrier.wait()
    Registry(registry).publish(bundle)


def test_concurrent_publishes_each_get_a_version(tmp_path):
    """Eight processes publish eight bundles of one floor at once: the writer lock gives each
    its own sequence number, none is lost from the history, and CURRENT names the last."""
    n = 8
    for i in range(n):
        write_bundle(tmp_path / f"v{i}", _content(float(i)))
    ctx = multiprocessing.get_context("fork")
    barrier = ctx.Barrier(n)
    procs = [ctx.Process(target=_publish_after, args=(barrier, str(tmp_path / "reg"),
                                                       str(tmp_path / f"v{i}")))
             for i in range(n)]
    for proc in procs:
        proc.start()
    for proc in procs:
        proc.join(60)
    assert [proc.exitcode for proc in procs] == [0] * n
    reg = Registry(tmp_path / "reg")
    history = reg.history("site", "F1")
    assert [h["seq"] for h in history] == list(range(1, n + 1))
    assert len({h["bundle_id"] for h in history}) == n
    assert reg.current("site", "F1") == history[-1]


@pytest.mark.parametrize("name, text, message", [
    ("history.json", "garbage", "history.json: damaged registry file"),
    ("history.json", '{"x": 1}', "history.json: not a registry history"),
    ("CURRENT", "garbage", "CURRENT: damaged registry file"),
    ("CURRENT", '{"bundle_id": "' + "ab" * 32 + '", "seq": 9}',
     "CURRENT: points at version abababababababab, which the registry does not hold"),
])
def test_a_damaged_registry_is_named(tmp_path, name, text, message):
    """list, use and publish on a registry whose history or pointer was damaged: a one-line
    error naming the file (exit 1), never a traceback or a silent "no current version". A
    damaged pointer is repaired by pointing it at the newest version (older ones need
    --rollback: which one was current is unknown)."""
    write_bundle(tmp_path / "v1", _content(0.0))
    write_bundle(tmp_path / "v2", _content(1.0))
    write_bundle(tmp_path / "f2", _content(0.0, floor="F2"))
    reg = tmp_path / "reg"
    for v in ("v1", "v2", "f2"):
        Registry(reg).publish(tmp_path / v)
    (reg / "site" / "F1" / name).write_text(text)
    res = CliRunner().invoke(main, ["bundle", "list", str(reg)])
    assert res.exit_code == 1 and message in res.output and "Traceback" not in res.output
    # the damaged floor is named once; the healthy one lists as before, and the damaged one's
    # versions too when its history is readable (none current: the pointer is not trusted)
    lines = res.output.splitlines()
    assert [ln for ln in lines if ln.startswith("error:")] == [
        next(ln for ln in lines if message in ln)]
    assert [ln.split()[:3] for ln in lines if "site/F2" in ln] == [["*", "site/F2", "#1"]]
    assert [ln.split()[:2] for ln in lines if "site/F1" in ln and "error" not in ln] == (
        [] if name == "history.json" else [["site/F1", "#1"], ["site/F1", "#2"]])
    use_old = CliRunner().invoke(main, ["bundle", "use", str(reg), "site/F1", "#1"])
    use_new = CliRunner().invoke(main, ["bundle", "use", str(reg), "site/F1", "#2"])
    if name == "history.json":  # no way to know the versions: every command refuses
        for res in (use_old, use_new):
            assert res.exit_code == 1 and message in res.output
    else:
        assert use_old.exit_code == 1 and ("#1 is older than the newest #2 (the current "
                                           "pointer is unreadable); pass --rollback"
                                           ) in use_old.output
        assert use_new.exit_code == 0, use_new.output
        assert Registry(reg).current("site", "F1")["seq"] == 2


def test_registry_command_line(tmp_path):
    """publish / list / use (by #seq or id prefix; --rollback to go back) / a non-registry."""
    write_bundle(tmp_path / "v1", _content(0.0))
    write_bundle(tmp_path / "v2", _content(1.0))
    reg, run = str(tmp_path / "reg"), CliRunner().invoke
    res = run(main, ["bundle", "publish", str(tmp_path / "v1"), str(tmp_path / "v2"),
                     "--registry", reg])
    assert res.exit_code == 0 and "#2 (current)" in res.output
    ids = [load_bundle(tmp_path / v).bundle_id for v in ("v1", "v2")]

    def listed():
        res = run(main, ["bundle", "list", reg])
        assert res.exit_code == 0, res.output
        return [ln.split() for ln in res.output.splitlines()]

    assert listed() == [["site/F1", "#1", ids[0]], ["*", "site/F1", "#2", ids[1]]]
    back = run(main, ["bundle", "use", reg, "site/F1", "#1"])
    assert back.exit_code == 1 and ("site/F1: #1 is older than the current #2; pass "
                                    "--rollback to go back to it") in back.output
    assert listed()[1][0] == "*"  # refused: #2 stays current
    again = run(main, ["bundle", "publish", str(tmp_path / "v1"), "--registry", reg])
    assert again.exit_code == 1 and "already published as #1, older than the current #2; " \
        f"to make it current: indoormap bundle use {reg} site/F1 '#1' --rollback" in again.output
    assert run(main, ["bundle", "use", reg, "site/F1", "#1", "--rollback"]).exit_code == 0
    assert listed()[0] == ["*", "site/F1", "#1", ids[0]]
    assert run(main, ["bundle", "use", reg, "site/F1", ids[1][:10]]).exit_code == 0
    assert listed()[1] == ["*", "site/F1", "#2", ids[1]]
    # a bare SEQ, as `bundle list` prints it without its # (it was refused: "names 0
    # versions"); one that also begins another version's id is refused as ambiguous
    assert run(main, ["bundle", "use", reg, "site/F1", "1", "--rollback"]).exit_code == 0
    assert listed()[0] == ["*", "site/F1", "#1", ids[0]]
    assert run(main, ["bundle", "use", reg, "site/F1", "2"]).exit_code == 0
    assert listed()[1] == ["*", "site/F1", "#2", ids[1]]
    (tmp_path / "ids").mkdir()
    for k in range(3, 12):  # more versions, until a SEQ digit begins another version's id
        write_bundle(tmp_path / "ids" / str(k), _content(float(k)))
        ids.append(load_bundle(tmp_path / "ids" / str(k)).bundle_id)
        assert run(main, ["bundle", "publish", str(tmp_path / "ids" / str(k)), "--registry",
                          reg]).exit_code == 0
    seq, other = next((s, i) for s in range(1, 10) for i in ids
                      if i.startswith(str(s)) and i != ids[s - 1])
    res = run(main, ["bundle", "use", reg, "site/F1", str(seq), "--rollback"])
    assert res.exit_code == 2 and (f"'{seq}' is #{seq} and begins bundle id {other[:12]}; "
                                   f"say '#{seq}' or more of the id") in res.output
    for bad, message in ((["site/F1", "zz"], "names 0 versions"),
                         (["site/F1", "999999"], "names 0 versions"),
                         (["site/F9", "#1"], "nothing published for site/F9"),
                         (["F1", "#1"], "expected SITE/FLOOR")):
        res = run(main, ["bundle", "use", reg, *bad])
        assert res.exit_code == 2 and message in res.output
    res = run(main, ["bundle", "list", str(tmp_path)])
    assert res.exit_code == 2 and "not a registry" in res.output



def test_a_registry_floor_folder_opens_its_current_version(tmp_path):
    """Every command that reads a bundle takes ``REG/<site>/<floor>`` for its current
    version, and ``bundle verify`` takes a folder of bundles (``build -o``'s OUT, a registry's
    site folder) and checks each."""
    write_bundle(tmp_path / "out" / "v1", _content(0.0))
    write_bundle(tmp_path / "out" / "v2", _content(1.0))
    reg = tmp_path / "reg"
    Registry(reg).publish(tmp_path / "out" / "v1")
    e2 = Registry(reg).publish(tmp_path / "out" / "v2")
    floor = reg / "site" / "F1"
    assert load_bundle(floor).bundle_id == e2["bundle_id"]
    res = CliRunner().invoke(main, ["bundle", "info", str(floor)])
    assert res.exit_code == 0 and e2["bundle_id"] in res.output, res.output
    res = CliRunner().invoke(main, ["bundle", "verify", str(tmp_path / "out"), str(reg / "site")])
    assert res.exit_code == 0, res.output
    assert [ln.split()[:2] for ln in res.output.splitlines()] == [
        ["ok", str(tmp_path / "out" / "v1")], ["ok", str(tmp_path / "out" / "v2")],
        ["ok", str(floor)]]
    res = CliRunner().invoke(main, ["bundle", "verify", str(reg)])  # the registry's root
    assert res.exit_code == 0 and res.output.split()[:2] == ["ok", str(floor)], res.output
    # publish takes a folder of bundles too (it said "not a map bundle (no manifest.json)")
    res = CliRunner().invoke(main, ["bundle", "publish", str(tmp_path / "out"),
                                    "--registry", str(tmp_path / "reg2")])
    assert res.exit_code == 0 and res.output.count("(current)") == 2, res.output
    assert [h["bundle_id"] for h in Registry(tmp_path / "reg2").history("site", "F1")] == [
        load_bundle(tmp_path / "out" / v).bundle_id for v in ("v1", "v2")]
    (tmp_path / "out" / "v1" / "mask.npy").write_bytes(b"x")  # one bad bundle in the folder
    res = CliRunner().invoke(main, ["bundle", "verify", str(tmp_path / "out")])
    assert res.exit_code == 1 and f"FAILED  {tmp_path / 'out' / 'v1'}" in res.output
    assert f"ok      {tmp_path / 'out' / 'v2'}" in res.output


REG_CRASH = """
import sys
sys.path.insert(0, sys.argv[3])
from mapping.registry import Registry
Registry(sys.argv[1]).publish(sys.argv[2])
"""


@pytest.mark.parametrize("point", ["registry:before-rename", "registry:after-copy",
                                   "registry:after-history"])
def test_killed_publish_keeps_current_version(tmp_path, point):
    reg = Registry(tmp_path / "reg")
    write_bundle(tmp_path / "v1", _content(0.0))
    write_bundle(tmp_path / "v2", _content(1.0))
    e1 = reg.publish(tmp_path / "v1")
    env = {**os.environ, "INDOORMAP_CRASH_AT": point}
    proc = subprocess.run([sys.executable, "-c", REG_CRASH, str(tmp_path / "reg"),
                           str(tmp_path / "v2"), str(Path(__file__).parent)], env=env,
                          capture_output=True)
    assert proc.returncode == 70, proc.stderr.decode()
    assert reg.open("site", "F1").bundle_id == e1["bundle_id"]  # never dangling or partial
    e2 = reg.publish(tmp_path / "v2")  # the retry completes the publication
    assert reg.open("site", "F1").bundle_id == e2["bundle_id"]
    versions = tmp_path / "reg" / "site" / "F1" / "versions"
    assert sorted(p.name for p in versions.iterdir()) == sorted([e1["bundle_id"],
                                                                  e2["bundle_id"]])


def test_a_reader_that_has_gone_ends_the_command_quietly(bundle_dir):
    """``indoormap bundle info B | head -1``: a closed pipe is no traceback and no error."""
    proc = subprocess.Popen([sys.executable, "-m", "survey.cli", "bundle", "info",
                             str(bundle_dir)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader is gone before the first line
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 1
    assert err == b""


def test_registry_refuses_a_version_that_is_not_the_one_current_names(tmp_path):
    """A version folder swapped for another (valid) bundle, or a damaged version pointed at
    by a rollback: refused, not served; publishing the intact bundle again repairs it."""
    write_bundle(tmp_path / "v1", _content(0.0))
    write_bundle(tmp_path / "v2", _content(1.0))
    reg = Registry(tmp_path / "reg")
    e1, e2 = reg.publish(tmp_path / "v1"), reg.publish(tmp_path / "v2")
    versions = tmp_path / "reg" / "site" / "F1" / "versions"
    shutil.rmtree(versions / e2["bundle_id"])
    shutil.copytree(tmp_path / "v1", versions / e2["bundle_id"])
    with pytest.raises(BundleIntegrityError, match="CURRENT names"):
        load_bundle(tmp_path / "reg" / "site" / "F1")
    mask = versions / e1["bundle_id"] / "mask.npy"
    mask.write_bytes(mask.read_bytes()[:-1] + b"\x07")
    with pytest.raises(BundleIntegrityError):
        reg.set_current("site", "F1", e1["bundle_id"], allow_rollback=True)
    # publishing the intact bundles again repairs both versions (the swapped one was kept,
    # as a valid bundle, under the other's id)
    assert reg.publish(tmp_path / "v2") == {**e2, "repaired": True}
    assert load_bundle(tmp_path / "reg" / "site" / "F1").bundle_id == e2["bundle_id"]
    with pytest.raises(RollbackRefused):  # repaired, but older than the current one
        reg.publish(tmp_path / "v1")
    reg.set_current("site", "F1", e1["bundle_id"], allow_rollback=True)
    assert load_bundle(tmp_path / "reg" / "site" / "F1").bundle_id == e1["bundle_id"]


def test_publishing_a_registry_floor_folder_copies_its_current_bundle(tmp_path):
    write_bundle(tmp_path / "v1", _content(0.0))
    Registry(tmp_path / "r1").publish(tmp_path / "v1")
    e = Registry(tmp_path / "r2").publish(tmp_path / "r1" / "site" / "F1")
    version = tmp_path / "r2" / "site" / "F1" / "versions" / e["bundle_id"]
    assert sorted(p.name for p in version.iterdir()) == sorted(
        p.name for p in (tmp_path / "v1").iterdir())
    assert Registry(tmp_path / "r2").publish(tmp_path / "v1") == e


def test_manifests_that_are_not_plain_json_files_are_refused(tmp_path, bundle_dir):
    m_path = bundle_dir / "manifest.json"
    original = m_path.read_text()
    m_path.write_text("[" * 100_000 + "]" * 100_000)   # nesting deeper than the parser's stack
    with pytest.raises(BundleIntegrityError, match="unreadable manifest"):
        load_bundle(bundle_dir)
    m_path.unlink()
    os.mkfifo(m_path)   # would block a plain read
    with pytest.raises(BundleIntegrityError, match="regular file"):
        load_bundle(bundle_dir)
    m_path.unlink()
    (tmp_path / "elsewhere.json").write_text(original)
    m_path.symlink_to(tmp_path / "elsewhere.json")
    with pytest.raises(BundleIntegrityError, match="regular file"):
        load_bundle(bundle_dir)



@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_member_swapped_for_a_fifo_is_refused_without_blocking(tmp_path, bundle_dir):
    """A FIFO in a member's place is refused at once, not read forever (the checksum pass
    also opens a member without blocking and looks at it again, in case it was swapped after
    the check). In a child process with a timeout, so that a regression fails instead of
    hanging."""
    member = next(p for p in sorted(bundle_dir.rglob("*.npy")))
    member.unlink()
    os.mkfifo(member)
    child = ("import sys\nfrom localize.bundle import verify_bundle_dir, json\n"
             "from pathlib import Path\np = Path(sys.argv[1])\n"
             "try:\n    verify_bundle_dir(p, json.loads((p / 'manifest.json').read_text()))\n"
             "except Exception as err:\n    print(type(err).__name__, err)\n")
    res = subprocess.run([sys.executable, "-c", child, str(bundle_dir)], capture_output=True,
                         text=True, timeout=120)
    assert res.stdout.startswith("BundleIntegrityError"), res.stdout + res.stderr
    assert f"member {member.relative_to(bundle_dir)} is not a regular file" in res.stdout


@pytest.mark.parametrize("version", [True, 1.0, "1"])
def test_a_schema_version_of_another_type_is_refused(bundle_dir, version):
    m_path = bundle_dir / "manifest.json"
    manifest = json.loads(m_path.read_text())
    manifest["schema_version"] = version
    manifest["bundle_id"] = bundle_id_of(manifest)
    m_path.write_bytes(manifest_bytes(manifest))
    with pytest.raises(BundleError, match="schema version"):
        load_bundle(bundle_dir)


def _rewrite_member(bundle_dir: Path, name: str, array: np.ndarray) -> None:
    """Replace a member with ``array`` and re-hash the manifest (a forger's full rewrite)."""
    import hashlib

    np.save(bundle_dir / name, array, allow_pickle=False)
    data = (bundle_dir / name).read_bytes()
    m_path = bundle_dir / "manifest.json"
    manifest = json.loads(m_path.read_text())
    manifest["members"][name] = {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    manifest["bundle_id"] = bundle_id_of(manifest)
    m_path.write_bytes(manifest_bytes(manifest))


def test_arrays_with_negative_dimensions_or_a_non_boolean_mask_are_refused(bundle_dir):
    mask = np.load(bundle_dir / "mask.npy")
    _rewrite_member(bundle_dir, "mask.npy", np.where(mask, 7, 0).astype(np.int64))
    with pytest.raises(BundleIntegrityError, match="dtype|0/1"):
        load_bundle(bundle_dir)
    _rewrite_member(bundle_dir, "mask.npy", mask)
    load_bundle(bundle_dir)  # the rewrite itself is sound
    path = bundle_dir / "mask.npy"
    raw = path.read_bytes()
    shape = repr(mask.shape).encode() + b", }  "   # the header's padding absorbs the signs
    bad = raw.replace(shape, f"(-{mask.shape[0]}, -{mask.shape[1]}), }}".encode(), 1)
    assert bad != raw and len(bad) == len(raw)
    path.write_bytes(bad)
    with pytest.raises(BundleIntegrityError, match="shape"):
        read_npy_checked(path)


def test_writer_checks_values_outside_a_uint8_mask(tmp_path):
    content = _content()
    mask = content.mask.astype(np.uint8)
    layer = content.layers["strength"]
    values = layer.values.copy()
    values[0, 0] = 99.0    # a cell outside the mask
    bad = BundleContent(content.site_id, content.floor_id, content.floor_name, grid=content.grid,
                        mask=mask, layers={"strength": Layer(values, layer.std, "uT")},
                        tables=content.tables, build=content.build)
    with pytest.raises(BundleError, match="outside the reachable mask"):
        write_bundle(tmp_path / "b", bad)
