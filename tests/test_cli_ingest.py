"""`indoormap ingest` and the CLI's error handling (exit codes 0 / 1 / 2)."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from click.testing import CliRunner

from factories import small_trace
from survey.cli import main
from survey.store import SurveyStore
from survey.trace_writer import write_trace


def test_version():
    result = CliRunner().invoke(main, ["--version"])
    assert result.exit_code == 0 and "indoormap, version" in result.output


def test_ingest_prints_summary_and_is_idempotent(tmp_path):
    write_trace(tmp_path / "in" / "w1.txt.gz", small_trace(trace_id="w1"),
                extra_lines=["1600000000001\tTYPE_BLUE\t\taa:bb:cc:dd:ee:ff\t-80"])
    (tmp_path / "in" / "w2.txt").write_text(
        "1600000000000\tTYPE_WAYPOINT\t1\t2\n1600000000001\tTYPE_WIFI\tx\n")
    runner = CliRunner()
    result = runner.invoke(main, ["ingest", str(tmp_path / "in"), "--store",
                                  str(tmp_path / "store")])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "files:    new 2" in out
    assert "ingest: 2/2 files" in result.stderr  # progress in a log, not only a bare label
    assert "TYPE_BLUE" in out and "field_count" in out
    assert "w2.txt:2: TYPE_WIFI needs 5 values, got 1" in out
    assert len(SurveyStore.open(tmp_path / "store").catalog()) == 2
    again = runner.invoke(main, ["ingest", str(tmp_path / "in"), "--store",
                                 str(tmp_path / "store")])
    assert again.exit_code == 0 and "unchanged 2" in again.output
    # another file of w1's name (a cut copy elsewhere) replaces the stored walk: said, with
    # what it replaced (it was only counted as "changed 1")
    write_trace(tmp_path / "copy" / "w1.txt.gz", small_trace(n=20, trace_id="w1"))
    cut = runner.invoke(main, ["ingest", str(tmp_path / "copy"), "--store",
                               str(tmp_path / "store")])
    lines = SurveyStore.open(tmp_path / "store").catalog().set_index("trace_id")
    assert cut.exit_code == 0 and "changed 1" in cut.output
    assert (f"changed w1: now {tmp_path / 'copy' / 'w1.txt.gz'}; replaced "
            f"{tmp_path / 'in' / 'w1.txt.gz'}, ") in cut.output, cut.output
    assert lines.loc["w1", "source_path"] == str(tmp_path / "copy" / "w1.txt.gz")
    write_trace(tmp_path / "copy" / "w1.txt.gz", small_trace(n=30, trace_id="w1"))
    edited = runner.invoke(main, ["ingest", str(tmp_path / "copy"), "--store",
                                  str(tmp_path / "store")])  # the same file edited: a count
    assert "changed 1" in edited.output and "changed w1:" not in edited.output


def test_strict_exits_1_with_file_and_line(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("1600000000000\tTYPE_ACCELEROMETER\t1\tx\t3\t3\n")
    result = CliRunner().invoke(main, ["ingest", str(bad), "--store", str(tmp_path / "s"),
                                       "--strict"])
    assert result.exit_code == 1
    assert "bad.txt:1: TYPE_ACCELEROMETER: field 'y' expected a number, got 'x'" in result.output
    assert not (tmp_path / "s").exists()  # the store this run created is not left half made


def test_strict_refuses_an_empty_file_and_commits_nothing(tmp_path):
    (tmp_path / "in").mkdir()
    write_trace(tmp_path / "in" / "w.txt", small_trace(trace_id="w"))
    (tmp_path / "in" / "x_empty.txt").write_text("")
    result = CliRunner().invoke(main, ["ingest", str(tmp_path / "in"), "--store",
                                       str(tmp_path / "s"), "--strict"])
    assert result.exit_code == 1 and "x_empty.txt: no sensor sample" in result.output
    assert not (tmp_path / "s").exists()
    ingest_ok = CliRunner().invoke(main, ["ingest", str(tmp_path / "in" / "w.txt"), "--store",
                                          str(tmp_path / "s")])
    assert ingest_ok.exit_code == 0
    again = CliRunner().invoke(main, ["ingest", str(tmp_path / "in"), "--store",
                                      str(tmp_path / "s"), "--strict"])
    assert again.exit_code == 1  # an existing store is kept as it was
    assert list(SurveyStore.open(tmp_path / "s").catalog()["trace_id"]) == ["w"]


def test_empty_or_foreign_files_are_not_walks(tmp_path):
    """An empty file or a file with no trace line fails (named, exit 1) instead of becoming a
    walk with no data; a folder without any trace file is an error and creates no store."""
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "empty.txt").write_text("")
    (tmp_path / "in" / "notes.txt").write_text("walked the east wing twice\n")
    write_trace(tmp_path / "in" / "w.txt", small_trace(trace_id="w"))
    result = CliRunner().invoke(main, ["ingest", str(tmp_path / "in"), "--store",
                                       str(tmp_path / "s")])
    assert result.exit_code == 1
    assert "FAILED " + str(tmp_path / "in" / "empty.txt") + ": no sensor sample" in result.output
    assert "notes.txt: no sensor sample, waypoint or scan in 1 lines" in result.output
    assert list(SurveyStore.open(tmp_path / "s").catalog()["trace_id"]) == ["w"]
    (tmp_path / "nothing").mkdir()
    result = CliRunner().invoke(main, ["ingest", str(tmp_path / "nothing"), "--store",
                                       str(tmp_path / "s2")])
    assert result.exit_code == 1 and "no trace files" in result.output
    assert not (tmp_path / "s2").exists()


def test_a_lenient_ingest_of_only_failed_files_leaves_no_store(tmp_path):
    """Every file failing in lenient mode commits nothing: a store folder this run would have
    made is not left behind (a later `process` would call it a store without walks), an empty
    folder given as the store stays empty, and an existing store keeps its walks."""
    (tmp_path / "bad.txt").write_text("garbage\n")
    args = ["ingest", str(tmp_path / "bad.txt"), "--store"]
    result = CliRunner().invoke(main, [*args, str(tmp_path / "s")])
    assert result.exit_code == 1 and "FAILED " + str(tmp_path / "bad.txt") in result.output
    assert not (tmp_path / "s").exists()
    (tmp_path / "empty").mkdir()
    assert CliRunner().invoke(main, [*args, str(tmp_path / "empty")]).exit_code == 1
    assert (tmp_path / "empty").is_dir() and not any((tmp_path / "empty").iterdir())
    write_trace(tmp_path / "w.txt", small_trace(trace_id="w"))
    assert CliRunner().invoke(main, ["ingest", str(tmp_path / "w.txt"), "--store",
                                     str(tmp_path / "s")]).exit_code == 0
    assert CliRunner().invoke(main, [*args, str(tmp_path / "s")]).exit_code == 1
    assert list(SurveyStore.open(tmp_path / "s").catalog()["trace_id"]) == ["w"]


def test_usage_errors_exit_2(tmp_path):
    runner = CliRunner()
    assert runner.invoke(main, ["ingest", str(tmp_path)]).exit_code == 2  # no --store
    assert runner.invoke(main, ["ingest", str(tmp_path / "missing"), "--store",
                                str(tmp_path / "s")]).exit_code == 2


def test_store_that_is_not_a_store_exits_1(tmp_path):
    (tmp_path / "notastore").mkdir()
    (tmp_path / "notastore" / "x").write_text("")
    write_trace(tmp_path / "w.txt", small_trace())
    result = CliRunner().invoke(main, ["ingest", str(tmp_path / "w.txt"), "--store",
                                       str(tmp_path / "notastore")])
    assert result.exit_code == 1 and "not a survey store" in result.output


def test_an_output_the_system_refuses_is_one_line_naming_it(tmp_path):
    """An operating-system refusal (here: a path under a file; also a read-only disk, no
    permission, a full disk) is exit 1 with the path and the reason, not a traceback."""
    (tmp_path / "FILE").write_text("keep me")
    write_trace(tmp_path / "w.txt", small_trace())
    res = CliRunner().invoke(main, ["ingest", str(tmp_path / "w.txt"), "--store",
                                    str(tmp_path / "FILE" / "store")])
    assert res.exit_code == 1
    assert res.output == f"error: {tmp_path / 'FILE' / 'store'}: Not a directory\n"
    assert (tmp_path / "FILE").read_text() == "keep me"


def test_progress_off_a_terminal_prints_about_every_tenth():
    import io

    from survey.progress import progress

    log = io.StringIO()  # not a terminal
    with progress("process", 25, unit="walks", file=log) as update:
        for i in range(1, 26):
            update(i, 25)
    lines = log.getvalue().splitlines()
    assert lines[0] == "process: 2/25 walks" and lines[-1] == "process: 25/25 walks"
    assert 10 <= len(lines) <= 13 and len(set(lines)) == len(lines)


def test_one_trace_id_twice_or_one_content_twice_in_a_run(tmp_path):
    """Two files with one trace id: the second fails (it would replace the first); the same
    content under two names: the second is a duplicate, as in separate runs."""
    from survey.errors import SurveyFormatError
    from survey.ingest import ingest

    write_trace(tmp_path / "a" / "X.txt.gz", small_trace(seed=1, trace_id="X"))
    write_trace(tmp_path / "b" / "X.txt", small_trace(seed=2, trace_id="X"))
    (tmp_path / "a" / "Y.txt.gz").write_bytes((tmp_path / "a" / "X.txt.gz").read_bytes())
    s = ingest([tmp_path / "a", tmp_path / "b"], tmp_path / "store")
    by_path = {Path(o.path).relative_to(tmp_path).as_posix(): o for o in s.outcomes}
    assert by_path["a/X.txt.gz"].status == "new"
    assert by_path["a/Y.txt.gz"].status == "duplicate"
    assert by_path["b/X.txt"].status == "failed" and "also comes from" in by_path["b/X.txt"].detail
    with pytest.raises(SurveyFormatError, match="also comes from"):
        ingest([tmp_path / "a", tmp_path / "b"], tmp_path / "store2", strict=True)
    # the error keeps its fields across processes (ingest workers)
    err = pickle.loads(pickle.dumps(SurveyFormatError("bad", path="f.txt", line=3,
                                                      reason="r")))
    assert (str(err), err.path, err.line, err.reason) == ("f.txt:3: bad", "f.txt", 3, "r")
