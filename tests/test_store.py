"""Survey store: idempotent ingest, replacement, atomic commit, crash safety, locking."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from factories import small_trace
from survey.errors import StoreError, SurveyFormatError
from survey.ingest import ingest
from survey.store import SurveyStore
from survey.trace_writer import write_trace


def _walks(folder: Path, n: int = 3) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    return [write_trace(folder / f"w{i}.txt.gz", small_trace(n=80, seed=i, trace_id=f"w{i}"))
            for i in range(n)]


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()}


def test_ingest_then_read_tables(tmp_path):
    _walks(tmp_path / "in")
    s = ingest([tmp_path / "in"], tmp_path / "store")
    assert s.status_counts() == {"new": 3}
    # in a notebook the totals, not every outcome and message
    assert repr(s).startswith("IngestSummary(files={'new': 3}, rows={'traces': 3, ")
    store = SurveyStore.open(tmp_path / "store")
    cat = store.catalog()
    assert list(cat["trace_id"]) == ["w0", "w1", "w2"]
    assert set(cat["site"]) == {"site_a"} and set(cat["floor"]) == {"F1"}
    assert (cat["sha256"].str.len() == 64).all()
    sensors = store.table("sensors", site="site_a", floor="F1")
    assert len(sensors) == 3 * 7 * 80 and set(sensors["trace_id"]) == {"w0", "w1", "w2"}
    wifi = store.table("wifi", trace_ids=["w1"])
    expected = small_trace(n=80, seed=1).wifi
    assert list(wifi["rssi_dbm"]) == list(expected.sort_values(["scan_t_ms", "bssid"])["rssi_dbm"])
    # partitioned layout
    assert any(p.startswith("sensors/site=site_a/floor=F1/w0-") for p in _files(store.root))


def test_ingest_reports_progress_file_by_file(tmp_path):
    """In one process every new file counts as it is through (it was all at once at the end:
    a fresh ingest of 305 real traces was silent for 10 s)."""
    _walks(tmp_path / "in")
    calls = []
    ingest([tmp_path / "in"], tmp_path / "store", progress=lambda d, n: calls.append((d, n)))
    assert calls == [(1, 3), (2, 3), (3, 3)]


def test_same_files_twice_is_a_no_op(tmp_path):
    _walks(tmp_path / "in")
    ingest([tmp_path / "in"], tmp_path / "store")
    before = {p: (tmp_path / "store" / p).read_bytes() for p in _files(tmp_path / "store")}
    s = ingest([tmp_path / "in"], tmp_path / "store")
    assert s.status_counts() == {"unchanged": 3}
    after = {p: (tmp_path / "store" / p).read_bytes() for p in _files(tmp_path / "store")}
    assert before == after


def test_copied_file_is_a_duplicate(tmp_path):
    (p,) = _walks(tmp_path / "in", 1)
    ingest([p], tmp_path / "store")
    copy = tmp_path / "other" / "copy.txt.gz"
    copy.parent.mkdir()
    copy.write_bytes(p.read_bytes())
    s = ingest([copy], tmp_path / "store")
    assert [o.status for o in s.outcomes] == ["duplicate"] and "w0" in s.outcomes[0].detail


def test_changed_file_replaces_its_rows(tmp_path):
    paths = _walks(tmp_path / "in")
    ingest([tmp_path / "in"], tmp_path / "store")
    write_trace(paths[1], small_trace(n=30, seed=99, trace_id="w1"))
    s = ingest([tmp_path / "in"], tmp_path / "store")
    assert sorted(o.status for o in s.outcomes) == ["changed", "unchanged", "unchanged"]
    store = SurveyStore.open(tmp_path / "store")
    assert len(store.table("sensors", trace_ids=["w1"])) == 7 * 30
    assert len(store.table("sensors", trace_ids=["w0"])) == 7 * 80
    # the old version's part files are gone
    assert sum("/w1-" in p for p in _files(store.root)) == 4


def test_strict_failure_keeps_store(tmp_path):
    _walks(tmp_path / "in")
    ingest([tmp_path / "in"], tmp_path / "store")
    before = {p: (tmp_path / "store" / p).read_bytes() for p in _files(tmp_path / "store")}
    bad = tmp_path / "bad" / "bad.txt"
    bad.parent.mkdir()
    bad.write_text("1\tTYPE_WIFI\tonly\ttwo\n")
    with pytest.raises(SurveyFormatError, match=r"bad.txt:1: TYPE_WIFI needs 5 values, got 2"):
        ingest([bad], tmp_path / "store", strict=True)
    after = {p: (tmp_path / "store" / p).read_bytes() for p in _files(tmp_path / "store")}
    assert after == before
    # lenient: a file whose only line is bad holds no walk; it fails with its first problem
    # and nothing else changes
    s = ingest([bad], tmp_path / "store")
    assert [o.status for o in s.outcomes] == ["failed"]
    assert "no sensor sample" in s.failed[0].detail
    assert "bad.txt:1: TYPE_WIFI needs 5 values, got 2" in s.failed[0].detail
    assert len(SurveyStore.open(tmp_path / "store").catalog()) == 3
    # a strict failure into an empty folder leaves it empty (store.json stayed behind)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SurveyFormatError):
        ingest([bad], tmp_path / "empty", strict=True)
    assert (tmp_path / "empty").is_dir() and not any((tmp_path / "empty").iterdir())


def test_unreadable_file_is_reported_and_others_ingested(tmp_path):
    _walks(tmp_path / "in", 2)
    (tmp_path / "in" / "broken.txt").mkdir()  # a folder named like a trace: cannot be read
    s = ingest([tmp_path / "in" / "w0.txt.gz", tmp_path / "in" / "w1.txt.gz"],
               tmp_path / "store")
    assert s.status_counts() == {"new": 2}


def test_not_a_store_and_schema_version(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "file").write_text("hi")
    with pytest.raises(StoreError, match="not a survey store"):
        SurveyStore.create(tmp_path / "x")
    with pytest.raises(StoreError, match="missing store.json"):
        SurveyStore.open(tmp_path / "nothing")
    SurveyStore.create(tmp_path / "s")
    (tmp_path / "s" / "store.json").write_text('{"format": "indoormap-survey-store", '
                                               '"schema_version": 99}')
    with pytest.raises(StoreError, match="schema version 99"):
        SurveyStore.open(tmp_path / "s")
    (tmp_path / "s" / "store.json").write_text("[]")  # was an AttributeError traceback
    with pytest.raises(StoreError, match="store.json: not a JSON object"):
        SurveyStore.open(tmp_path / "s")


def test_lock_held_by_live_process(tmp_path):
    store = SurveyStore.create(tmp_path / "s")
    with store.writer():
        with pytest.raises(StoreError, match=f"locked by running process {os.getpid()}"):
            with store.writer():
                pass
    (store.root / ".lock").write_text("999999999")  # stale: that process is gone
    with store.writer():
        pass
    assert not (store.root / ".lock").exists()


LOCK_RACE = """
import os, sys, time
import survey.store as st
from survey.errors import StoreError
st._StoreWriter.__init__ = lambda self, store: None  # the lock alone, many times a second
st._StoreWriter.collect_garbage = st._StoreWriter.commit = lambda self: None
store, marker, overlaps, end = st.SurveyStore.open(sys.argv[1]), sys.argv[2], 0, time.time() + 3
while time.time() < end:
    try:
        with store.writer():
            try:
                os.close(os.open(marker, os.O_CREAT | os.O_EXCL))
            except FileExistsError:
                overlaps += 1
                continue
            time.sleep(0.0005)
            os.remove(marker)
    except StoreError:
        pass
print(overlaps)
"""


@pytest.mark.skipif(os.name != "posix", reason="flock")
def test_two_writers_never_hold_the_lock_at_once(tmp_path):
    """Four processes taking the writer in a loop: none may enter while another is inside
    (the lock file was created empty and its pid written after, so a writer reading it in
    between took it as stale: thousands of overlaps in 20 s, and concurrent ingests lost
    each other's traces)."""
    SurveyStore.create(tmp_path / "s")
    procs = [subprocess.Popen([sys.executable, "-c", LOCK_RACE, str(tmp_path / "s"),
                               str(tmp_path / "inside")], stdout=subprocess.PIPE, text=True)
             for _ in range(4)]
    assert [int(p.communicate()[0]) for p in procs] == [0, 0, 0, 0]


CRASH_SCRIPT = """
import sys
from survey.ingest import ingest
ingest([sys.argv[1]], sys.argv[2], workers=1)
"""


@pytest.mark.parametrize("point", ["ingest:before-catalog", "ingest:after-catalog"])
def test_crash_during_ingest_leaves_a_consistent_store(tmp_path, point):
    paths = _walks(tmp_path / "in")
    ingest([tmp_path / "in"], tmp_path / "store")
    old_cat = SurveyStore.open(tmp_path / "store").catalog()
    write_trace(paths[0], small_trace(n=20, seed=50, trace_id="w0"))  # a changed file
    write_trace(tmp_path / "in" / "w9.txt.gz", small_trace(n=40, seed=9, trace_id="w9"))
    env = {**os.environ, "INDOORMAP_CRASH_AT": point}
    proc = subprocess.run([sys.executable, "-c", CRASH_SCRIPT, str(tmp_path / "in"),
                           str(tmp_path / "store")], env=env, capture_output=True)
    assert proc.returncode == 70, proc.stderr.decode()
    store = SurveyStore.open(tmp_path / "store")
    cat = store.catalog()
    if point == "ingest:before-catalog":
        pd.testing.assert_frame_equal(cat, old_cat)  # the old store, untouched
        assert len(store.table("sensors", trace_ids=["w0"])) == 7 * 80
    else:
        assert sorted(cat["trace_id"]) == ["w0", "w1", "w2", "w9"]
        assert len(store.table("sensors", trace_ids=["w0"])) == 7 * 20
    for name in ("sensors", "wifi", "ble", "waypoints"):
        store.table(name)  # every part file the catalog names is there and readable
    # stray parts, never read: the crashed ingest's new ones (w0 changed, w9), or the
    # replaced w0's old ones; verify names them and passes
    from click.testing import CliRunner

    from survey.cli import main
    stray = store.stray_files()
    n_stray = 8 if point == "ingest:before-catalog" else 4
    assert len(stray) == n_stray and all(p.name.startswith(("w0-", "w9-")) for p in stray)
    res = CliRunner().invoke(main, ["store", "verify", str(store.root)])
    assert res.exit_code == 0, res.output
    assert f"note    {n_stray} file(s) the catalog does not name" in res.output
    # the next ingest takes over the stale lock, finishes the work and removes all litter
    s = ingest([tmp_path / "in"], tmp_path / "store")
    assert not s.failed
    files = _files(store.root)
    assert not any(".tmp-" in p or p.endswith(".lock") for p in files) and \
        not store.stray_files()
    assert len([p for p in files if p.endswith(".parquet") and "/" in p]) == 4 * 4
    assert np.array_equal(sorted(store.catalog()["trace_id"]), ["w0", "w1", "w2", "w9"])


def _one_sample_trace(tmp_path: Path) -> SurveyStore:
    trace = min((Path(__file__).resolve().parents[1] / "data" / "sample_site" / "F1"
                 / "path_data_files").glob("*.txt.gz"))
    ingest([trace], tmp_path / "s")
    return SurveyStore.open(tmp_path / "s")


def _as_schema_1(store: SurveyStore) -> None:
    """Make ``store`` what indoormap wrote before part hashes (schema version 1)."""
    import pyarrow.parquet as pq

    path = store.root / "catalog.parquet"
    pq.write_table(pq.read_table(path).drop_columns(["parts_json"]), path)
    (store.root / "store.json").write_text('{"format": "indoormap-survey-store", '
                                           '"schema_version": 1}')


def test_a_corrupted_part_file_is_named_not_read(tmp_path):
    """A flipped byte inside a stored Parquet page: refused by the part's sha256 in the
    catalog, and in a schema-1 store (no part hashes) by the page checksum written at ingest
    (without it, pyarrow decodes most such flips into wrong numbers)."""
    store = _one_sample_trace(tmp_path)
    part = min(store.root.glob("sensors/**/*.parquet"))
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0x10
    part.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=f"{part.name}: part file changed since it was written"):
        store.table("sensors")
    _as_schema_1(store)
    with pytest.raises(StoreError, match=f"{part.name}: missing, unreadable or corrupted"):
        SurveyStore.open(store.root).table("sensors")


def test_footer_flips_and_swapped_parts_are_refused(tmp_path):
    """Page checksums do not cover a Parquet footer, where a flip can rename a column (a
    KeyError far away, before) or change a type; and a part file swapped for another walk's
    was read as this walk's. Both are StoreErrors naming the file, with part hashes (schema
    2) and without (schema 1: row counts, columns and trace id are checked)."""
    _walks(tmp_path / "in", 2)
    ingest([tmp_path / "in"], tmp_path / "s")
    store = SurveyStore.open(tmp_path / "s")
    w0, w1 = (min(store.root.glob(f"waypoints/**/w{i}-*.parquet")) for i in (0, 1))
    good = w0.read_bytes()
    for schema in (2, 1):
        if schema == 1:
            _as_schema_1(store)
            store = SurveyStore.open(store.root)
        footer = good.index(b"x_m")  # the schema's column name, in the footer
        w0.write_bytes(good[:footer] + b"q" + good[footer + 1:])
        with pytest.raises(StoreError, match=w0.name):
            store.table("waypoints", trace_ids=["w0"])
        w0.write_bytes(w1.read_bytes())
        with pytest.raises(StoreError, match=w0.name + (
                ": part file changed" if schema == 2 else r": holds \d+ rows of \['w1'\]")):
            store.table("waypoints", trace_ids=["w0"])
        w0.write_bytes(good)
        n = int(store.catalog().set_index("trace_id").loc["w0", "n_waypoints"])
        assert len(store.table("waypoints", trace_ids=["w0"])) == n > 0


def test_a_damaged_catalog_is_refused(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    _walks(tmp_path / "in", 2)
    ingest([tmp_path / "in"], tmp_path / "s")
    path = tmp_path / "s" / "catalog.parquet"
    table = pq.read_table(path)
    pq.write_table(table.drop_columns(["floor"]), path)
    with pytest.raises(StoreError, match=r"catalog.parquet: catalog lacks columns \['floor'\]"):
        SurveyStore.open(tmp_path / "s").catalog()
    pq.write_table(pa.concat_tables([table, table.slice(1, 1)]), path)
    with pytest.raises(StoreError, match="damaged catalog: trace id 'w1' has 2 rows"):
        SurveyStore.open(tmp_path / "s").table("sensors")


def test_a_processed_store_whose_catalog_is_lost_is_refused(tmp_path):
    """`store verify` said 'ok (0 traces)' and `build --store` reused the store."""
    from click.testing import CliRunner

    from survey.cli import main
    from survey.process_store import process_store

    store = _one_sample_trace(tmp_path)
    assert not SurveyStore.open(store.root).verify()  # whole before
    process_store(store)
    (store.root / "catalog.parquet").unlink()
    with pytest.raises(StoreError, match="catalog.parquet: missing, but the store has "
                                         "processed walks"):
        SurveyStore.open(store.root).catalog()
    res = CliRunner().invoke(main, ["store", "verify", str(store.root)])
    assert res.exit_code == 1 and "damaged store" in res.output
    # survey-report read the processed catalog alone and printed its report, exit 0
    res = CliRunner().invoke(main, ["survey-report", "--store", str(store.root)])
    assert res.exit_code == 1 and "catalog.parquet: missing, but the store has processed " \
        "walks" in " ".join(res.output.split()), res.output


def test_a_file_renamed_and_replaced_in_one_run_loses_nothing(tmp_path):
    """w0 renamed to w5 and other content put at w0, in one run: w5 was called a duplicate
    of the stored w0, whose content this same run replaced, so it ended in no catalog row."""
    (p,) = _walks(tmp_path / "in", 1)
    ingest([p], tmp_path / "s")
    old = p.read_bytes()
    (tmp_path / "in" / "w5.txt.gz").write_bytes(old)
    write_trace(p, small_trace(n=30, seed=99, trace_id="w0"))
    s = ingest([tmp_path / "in"], tmp_path / "s")
    assert sorted((o.trace_id, o.status) for o in s.outcomes) == [("w0", "changed"),
                                                                 ("w5", "new")]
    store = SurveyStore.open(tmp_path / "s")
    assert len(store.table("sensors", trace_ids=["w5"])) == 7 * 80
    assert len(store.table("sensors", trace_ids=["w0"])) == 7 * 30
    # a copy of content that stays is still a duplicate
    (tmp_path / "in" / "w6.txt.gz").write_bytes(old)
    s = ingest([tmp_path / "in" / "w6.txt.gz"], tmp_path / "s")
    assert [(o.status, o.detail) for o in s.outcomes] == [("duplicate", "same content as w5")]


def test_reingest_repairs_a_missing_part(tmp_path):
    _walks(tmp_path / "in", 2)
    ingest([tmp_path / "in"], tmp_path / "s")
    part = min((tmp_path / "s").glob("wifi/**/w1-*.parquet"))
    part.unlink()
    store = SurveyStore.open(tmp_path / "s")
    with pytest.raises(StoreError, match=f"{part.name}: missing"):
        store.table("wifi", trace_ids=["w1"])
    s = ingest([tmp_path / "in"], tmp_path / "s")
    assert sorted((o.trace_id, o.status) for o in s.outcomes) == [("w0", "unchanged"),
                                                                 ("w1", "repaired")]
    assert len(store.table("wifi", trace_ids=["w1"])) > 0


def test_a_schema_1_store_is_read_and_upgraded_by_its_next_ingest(tmp_path):
    """A store written before part hashes is read (checked by rows, columns, trace id); the
    next ingest checks its parts and records their hashes, and marks it schema 2."""
    _walks(tmp_path / "in", 2)
    ingest([tmp_path / "in"], tmp_path / "s")
    store = SurveyStore.open(tmp_path / "s")
    hashes = list(store.catalog()["parts_json"])
    _as_schema_1(store)
    store = SurveyStore.open(tmp_path / "s")
    assert len(store.table("sensors")) == 2 * 7 * 80
    assert ingest([tmp_path / "in"], store).status_counts() == {"unchanged": 2}
    assert '"schema_version": 2' in (tmp_path / "s" / "store.json").read_text()
    assert list(store.catalog()["parts_json"]) == hashes
    # a schema-2 catalog that lost its parts_json column (a damaged footer) is refused,
    # not read as schema 1 with every hash check off
    import pyarrow.parquet as pq

    path = tmp_path / "s" / "catalog.parquet"
    pq.write_table(pq.read_table(path).drop_columns(["parts_json"]), path)
    with pytest.raises(StoreError, match="no parts_json column in a schema version 2 store"):
        store.catalog()


def test_a_kill_before_the_schema_upgrade_is_finished_by_the_next_writer(tmp_path):
    """A schema-1 store's ingest killed between writing its (schema 2) catalog and marking
    store.json 2 left the store at 1 with hashes an older indoormap would strip; the next
    writer marks it 2."""
    _walks(tmp_path / "in", 2)
    ingest([tmp_path / "in"], tmp_path / "s")
    _as_schema_1(SurveyStore.open(tmp_path / "s"))
    _walks(tmp_path / "more", 3)
    res = subprocess.run(
        [sys.executable, "-c", "import sys; from survey.ingest import ingest; "
         "ingest([sys.argv[1]], sys.argv[2])", str(tmp_path / "more"), str(tmp_path / "s")],
        env={**os.environ, "INDOORMAP_CRASH_AT": "ingest:after-catalog"}, check=False)
    assert res.returncode == 70
    meta = tmp_path / "s" / "store.json"
    assert '"schema_version": 1' in meta.read_text()  # the catalog has parts_json already
    with SurveyStore.open(tmp_path / "s").writer():
        pass
    assert '"schema_version": 2' in meta.read_text()
    assert SurveyStore.open(tmp_path / "s").catalog()["parts_json"].str.len().gt(0).all()


def test_duplicates_chains_and_damage(tmp_path):
    """Walks renumbered in one run (w1 dropped, w2 -> w1, w3 -> w2, a new w3) lost w2's old
    content (w1 was called a duplicate of the old w2, which the run then replaced). A part
    damaged in place (same size) was called unchanged by the next ingest; and a copy of a
    damaged trace was called its duplicate."""
    folder = tmp_path / "in"
    paths = _walks(folder, 4)
    ingest([folder], tmp_path / "s")
    contents = [p.read_bytes() for p in paths]
    paths[0].unlink()  # w0 dropped from the folder (it stays in the store)
    for i in (1, 2):
        paths[i].write_bytes(contents[i + 1])
    write_trace(paths[3], small_trace(n=30, seed=77, trace_id="w3"))
    s = ingest([folder], tmp_path / "s")
    assert sorted((o.trace_id, o.status) for o in s.outcomes) == [
        ("w1", "changed"), ("w2", "changed"), ("w3", "changed")]
    store = SurveyStore.open(tmp_path / "s")
    import hashlib

    stored = store.catalog().set_index("trace_id")["sha256"].to_dict()
    assert stored == {"w0": hashlib.sha256(contents[0]).hexdigest(),
                      "w1": hashlib.sha256(contents[2]).hexdigest(),
                      "w2": hashlib.sha256(contents[3]).hexdigest(),
                      "w3": hashlib.sha256(paths[3].read_bytes()).hexdigest()}
    assert len(store.table("sensors", trace_ids=["w3"])) == 7 * 30
    # damaged in place, same size: re-ingest repairs it
    part = min((tmp_path / "s").glob("wifi/**/w2-*.parquet"))
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0x01
    part.write_bytes(bytes(data))
    copy = tmp_path / "copy" / "c2.txt.gz"
    copy.parent.mkdir()
    copy.write_bytes(paths[2].read_bytes())
    s = ingest([copy], tmp_path / "s")  # not a duplicate of the damaged w2: stored
    assert [o.status for o in s.outcomes] == ["new"]
    s = ingest([folder], tmp_path / "s")
    assert sorted((o.trace_id, o.status) for o in s.outcomes) == [
        ("w1", "unchanged"), ("w2", "repaired"), ("w3", "unchanged")]
    assert len(store.table("wifi", trace_ids=["w2"])) > 0


def test_a_killed_ingest_worker_is_a_clear_error(tmp_path, monkeypatch):
    """A worker killed (here at its start) broke the pool: a BrokenProcessPool traceback."""
    _walks(tmp_path / "in", 4)
    ingest([tmp_path / "in" / "w0.txt.gz"], tmp_path / "s")
    before = {p: (tmp_path / "s" / p).read_bytes() for p in _files(tmp_path / "s")}
    monkeypatch.setenv("INDOORMAP_CRASH_AT", "ingest:worker")
    with pytest.raises(StoreError, match="an ingest worker process died"):
        ingest([tmp_path / "in"], tmp_path / "s", workers=2, batch_bytes=1)
    monkeypatch.delenv("INDOORMAP_CRASH_AT")
    after = {p: (tmp_path / "s" / p).read_bytes() for p in _files(tmp_path / "s")}
    assert after == before


def test_store_info_and_verify_cli(tmp_path):
    from click.testing import CliRunner

    from survey.cli import main
    from survey.process_store import process_store

    traces = sorted((Path(__file__).resolve().parents[1] / "data" / "sample_site" / "F1"
                     / "path_data_files").glob("*.txt.gz"))[:2]
    ingest(traces, tmp_path / "s")
    runner = CliRunner()
    info = runner.invoke(main, ["store", "info", str(tmp_path / "s")])
    assert info.exit_code == 0, info.output
    assert "schema version 2, 2 traces" in info.output and "processed: not yet" in info.output
    process_store(tmp_path / "s")
    ok = runner.invoke(main, ["store", "verify", str(tmp_path / "s")])
    assert ok.exit_code == 0 and "ok      " in ok.output and "(2 traces)" in ok.output
    assert "processed: ok 2" in runner.invoke(main, ["store", "info", str(tmp_path / "s")]).output
    raw = min((tmp_path / "s").glob("ble/**/*.parquet"))
    done = min((tmp_path / "s" / "processed").glob("steps/**/*.parquet"))
    for part in (raw, done):
        data = bytearray(part.read_bytes())
        data[len(data) // 3] ^= 0x04
        part.write_bytes(bytes(data))
    bad = runner.invoke(main, ["store", "verify", str(tmp_path / "s")])
    assert bad.exit_code == 1
    assert f"FAILED  trace {raw.name.split('-')[0]}: {raw}: part file changed" in bad.output
    assert f"FAILED  processed walk {done.name.split('-')[0]}: {done}: processed part changed" \
        in bad.output


def test_one_path_or_trace_id_given_alone_is_one_not_its_characters(tmp_path, monkeypatch):
    """``ingest("survey/F1", store)`` iterated the string: it searched ``s``, ``u``, ... and
    ``/``, the whole file system (or ingested a folder twice, or failed on a letter);
    ``iter_traces(path)`` yielded a failure per character, and ``table(trace_ids="id")``
    matched no trace. One path, or one id, is now a list of one."""
    from survey.trace_reader import find_trace_files, iter_traces

    folder = tmp_path / "F1"
    folder.mkdir()
    for i in range(2):
        write_trace(folder / f"walk{i}.txt", small_trace(seed=i, trace_id=f"walk{i}"))
    monkeypatch.chdir(tmp_path)
    assert find_trace_files("F1") == find_trace_files(["F1"]) and len(find_trace_files("F1")) == 2
    assert [t.trace_id for t in iter_traces(folder / "walk0.txt")] == ["walk0"]
    assert [t.trace_id for t in iter_traces(str(folder / "walk1.txt"))] == ["walk1"]
    assert ingest("F1", tmp_path / "store").status_counts() == {"new": 2}
    store = SurveyStore.open(tmp_path / "store")
    one = store.table("waypoints", trace_ids="walk1")
    assert set(one["trace_id"]) == {"walk1"} and len(one)
    with pytest.raises(StoreError, match=r"trace_ids=\['nope'\]"):
        store.table("waypoints", trace_ids="nope")
    # a column typo is named as such; it said "missing, unreadable or corrupted part file"
    row = store.catalog().iloc[0]
    with pytest.raises(StoreError, match=r"the sensors table has no column 'tms'; it has "
                                         r"stream, t_ms"):
        store.part("sensors", row, columns=["tms"])
    assert list(store.part("sensors", row, columns=["t_ms"]).columns) == ["trace_id", "t_ms"]
