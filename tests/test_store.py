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
    # the next ingest takes over the stale lock, finishes the work and removes all litter
    s = ingest([tmp_path / "in"], tmp_path / "store")
    assert not s.failed
    files = _files(store.root)
    assert not any(".tmp-" in p or p.endswith(".lock") for p in files)
    assert len([p for p in files if p.endswith(".parquet") and "/" in p]) == 4 * 4
    assert np.array_equal(sorted(store.catalog()["trace_id"]), ["w0", "w1", "w2", "w9"])


def test_a_corrupted_part_file_is_named_not_read(tmp_path):
    """A flipped byte inside a stored Parquet page: the page checksum written at ingest is
    verified on read (without it, pyarrow decodes most such flips into wrong numbers)."""
    trace = min((Path(__file__).resolve().parents[1] / "data" / "sample_site" / "F1"
                 / "path_data_files").glob("*.txt.gz"))
    ingest([trace], tmp_path / "s")
    part = min((tmp_path / "s").glob("sensors/**/*.parquet"))
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0x10
    part.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=f"{part.name}: missing, unreadable or corrupted"):
        SurveyStore.open(tmp_path / "s").table("sensors")
