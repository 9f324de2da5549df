"""Atomic publication helpers: all or nothing, no litter, normal permissions."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from survey.errors import PublishError
from survey.publish import DIR_MODE, FILE_MODE, atomic_directory, atomic_write_bytes, \
    folder_identity


def test_atomic_write_refuses_overwrite_and_uses_umask_permissions(tmp_path):
    target = tmp_path / "a" / "file.bin"
    atomic_write_bytes(target, b"one")
    assert stat.S_IMODE(os.stat(target).st_mode) == FILE_MODE
    with pytest.raises(PublishError, match="exists; pass overwrite"):
        atomic_write_bytes(target, b"two")
    atomic_write_bytes(target, b"two", overwrite=True)
    assert target.read_bytes() == b"two"
    assert sorted(p.name for p in target.parent.iterdir()) == ["file.bin"]


def test_atomic_directory_all_or_nothing(tmp_path):
    target = tmp_path / "out"
    with atomic_directory(target) as tmp:
        (tmp / "x.txt").write_text("1")
    assert (target / "x.txt").read_text() == "1"
    assert stat.S_IMODE(os.stat(target).st_mode) == DIR_MODE
    with pytest.raises(RuntimeError):
        with atomic_directory(target, overwrite=True) as tmp:
            (tmp / "x.txt").write_text("2")
            raise RuntimeError("build failed")
    assert (target / "x.txt").read_text() == "1"  # the old output is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no litter
    with atomic_directory(target, overwrite=True) as tmp:
        (tmp / "y.txt").write_text("3")
    assert sorted(p.name for p in target.iterdir()) == ["y.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_stale_temporaries_are_those_of_processes_gone(tmp_path):
    """Cleaning up after a crash removes the temporaries of dead processes (and of a dead
    process that had this process's pid) but never a live process's work in progress."""
    import subprocess
    import sys

    from survey.publish import remove_stale_temporaries, tmp_prefix

    dead_pid = subprocess.Popen([sys.executable, "-c", "pass"])
    dead_pid.wait()
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        names = {"mine": tmp_prefix() + "a", "live": f".tmp-{live.pid}-0123abcd-b",
                 "dead": f".tmp-{dead_pid.pid}-0123abcd-c",
                 "reused pid": f".tmp-{os.getpid()}-0123abcd-d", "old format": ".tmp-xyz"}
        for name in names.values():
            (tmp_path / name).mkdir()
        assert remove_stale_temporaries(tmp_path) == 3
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            [names["mine"], names["live"]])
    finally:
        live.kill()
        live.wait()


def test_replace_together_undoes_its_moves_when_one_fails(tmp_path):
    """Two outputs that go together: when the second move fails, the first is moved back and
    both old outputs are in place again (the set never ends up half new, half missing)."""
    from survey.publish import replace_together

    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "v").write_text("old")
    stage = tmp_path / ".tmp-stage"
    (stage / "a").mkdir(parents=True)
    (stage / "a" / "v").write_text("new")  # stage/b is missing: its move fails
    with pytest.raises(OSError):
        replace_together([(stage / "a", tmp_path / "a"), (stage / "b", tmp_path / "b")],
                         overwrite=True)
    assert [(tmp_path / n / "v").read_text() for n in ("a", "b")] == ["old", "old"]
    (stage / "b").mkdir()
    (stage / "b" / "v").write_text("new")
    replace_together([(stage / "a", tmp_path / "a"), (stage / "b", tmp_path / "b")],
                     overwrite=True)
    assert [(tmp_path / n / "v").read_text() for n in ("a", "b")] == ["new", "new"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".tmp-stage", "a", "b"]


_KILLED_SET = """
import sys
from pathlib import Path
import survey.publish as p
if sys.argv[2] == "no-exchange":
    p.exchange_paths = lambda a, b: False
root = Path(sys.argv[1])
p.replace_together([(root / ".tmp-stage" / n, root / n) for n in ("a", "b", "c")], overwrite=True)
"""


def _old_set_and_staged_new(root):
    for name in ("a", "b", "c"):
        (root / name).mkdir()
        (root / name / "v").write_text("old")
        (root / ".tmp-stage" / name).mkdir(parents=True)
        (root / ".tmp-stage" / name / "v").write_text("new")


def _kill_replace_together(root, crash_at, mode="exchange"):
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-c", _KILLED_SET, str(root), mode],
                         env={**os.environ, "INDOORMAP_CRASH_AT": crash_at},
                         cwd=os.path.dirname(os.path.dirname(__file__)), check=False)
    assert res.returncode == 70


@pytest.mark.parametrize("mode", ["exchange", "no-exchange"])
@pytest.mark.parametrize("crash_at", ["replace_together:after-0", "replace_together:after-1",
                                      "replace_together:before-cleanup"])
def test_a_set_of_moves_killed_midway_is_finished_by_the_next_writer(tmp_path, crash_at, mode):
    """A kill among the moves of a set (a site's floor bundles and its site bundle) used to
    leave a mix of old and new outputs, plus the old ones in litter. The journal lets the next
    indoormap that cleans the folder finish the moves: the whole set is new, nothing is left
    over. With the two-rename fallback the killed set can even miss a target for a moment."""
    from survey.publish import JOURNAL_NAME, remove_stale_temporaries

    _old_set_and_staged_new(tmp_path)
    _kill_replace_together(tmp_path, crash_at, mode)
    assert (tmp_path / JOURNAL_NAME).exists()
    if crash_at != "replace_together:before-cleanup":
        seen = {n: (tmp_path / n / "v").read_text() for n in "abc" if (tmp_path / n).exists()}
        assert seen.get("a") == "new" and seen.get("c") == "old"  # mixed until finished
    remove_stale_temporaries(tmp_path)
    assert [(tmp_path / n / "v").read_text() for n in "abc"] == ["new"] * 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "c"]  # staging gone too


def test_a_killed_set_of_bundles_is_finished_when_a_reader_opens_the_folder(tmp_path):
    """Like SQLite finishing a hot journal: `localize` opening the folder (or one bundle in
    it) finishes a killed publication before reading, so it never sees two builds' bundles."""
    from localize.bundle import bundle_dirs
    from survey.publish import JOURNAL_NAME

    _old_set_and_staged_new(tmp_path)
    for n in "abc":  # make them bundle folders as far as bundle_dirs is concerned
        for root in (tmp_path, tmp_path / ".tmp-stage"):
            (root / n / "manifest.json").write_text("{}")
    _kill_replace_together(tmp_path, "replace_together:after-0")
    assert [p.name for p in bundle_dirs(tmp_path)] == ["a", "b", "c"]
    assert not (tmp_path / JOURNAL_NAME).exists()
    assert [(tmp_path / n / "v").read_text() for n in "abc"] == ["new"] * 3


def test_a_journal_that_cannot_be_finished_is_reported(tmp_path):
    """Staged outputs removed by hand: the set cannot be made whole. A reader says so; the
    next writer warns and drops the journal (it is about to write the outputs anew)."""
    import shutil

    from localize.bundle import bundle_dirs
    from survey.errors import BundleError
    from survey.publish import JOURNAL_NAME, remove_stale_temporaries

    _old_set_and_staged_new(tmp_path)
    _kill_replace_together(tmp_path, "replace_together:after-0")
    shutil.rmtree(tmp_path / ".tmp-stage" / "c")
    with pytest.raises(BundleError, match="interrupted and cannot be finished.*tmp-stage/c is gone"):
        bundle_dirs(tmp_path)
    assert (tmp_path / "b" / "v").read_text() == "old"  # no move made when one cannot be
    assert (tmp_path / ".tmp-stage" / "b").is_dir()
    with pytest.warns(UserWarning, match="journal is removed"):
        remove_stale_temporaries(tmp_path)
    assert not (tmp_path / JOURNAL_NAME).exists()


def test_the_journal_of_a_live_process_is_left_alone(tmp_path):
    import json

    from survey.publish import JOURNAL_NAME, finish_interrupted_publication, tmp_prefix

    _old_set_and_staged_new(tmp_path)
    (tmp_path / JOURNAL_NAME).write_text(json.dumps({
        "format": 1, "owner": tmp_prefix(""), "aside": ".tmp-x",
        "moves": [{"staged": ".tmp-stage/a", "target": "a",
                   "identity": folder_identity(tmp_path / ".tmp-stage" / "a")}]}))
    assert not finish_interrupted_publication(tmp_path)  # this process: still at work
    assert (tmp_path / "a" / "v").read_text() == "old"
    (tmp_path / JOURNAL_NAME).write_text("{not json")
    with pytest.raises(PublishError, match="damaged publication journal"):
        finish_interrupted_publication(tmp_path)


def test_atomic_directory_swaps_old_and_new_in_one_step(tmp_path, monkeypatch):
    """Where the system can swap two paths at once the target is never missing; the two-rename
    fallback gives the same result."""
    import survey.publish as pub

    calls = []
    real = pub.exchange_paths
    monkeypatch.setattr(pub, "exchange_paths", lambda a, b: calls.append(1) or real(a, b))
    target = tmp_path / "out"
    for text in ("1", "2"):
        with atomic_directory(target, overwrite=True) as tmp:
            (tmp / "x.txt").write_text(text)
    assert calls and (target / "x.txt").read_text() == "2"
    monkeypatch.setattr(pub, "exchange_paths", lambda a, b: False)
    with atomic_directory(target, overwrite=True) as tmp:
        (tmp / "x.txt").write_text("3")
    assert (target / "x.txt").read_text() == "3"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_tampered_journal_cannot_move_or_delete_outside_its_folder(tmp_path):
    """The journal names folders by relative path: one that points outside the folder (or at
    anything but the temporaries a build makes) is refused before anything is touched."""
    import json

    from survey.publish import JOURNAL_NAME, finish_interrupted_publication

    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep").write_text("x")
    out = tmp_path / "out"
    out.mkdir()
    for staged, target, aside in (("../victim", "a", ".tmp-1-x-"), (".tmp-stage/a", "../victim",
                                  ".tmp-1-x-"), (".tmp-1-x-/a", "a", "../victim"),
                                  ("/abs", "a", ".tmp-1-x-"), ("stage/../../victim", "a", "x")):
        (out / JOURNAL_NAME).write_text(json.dumps({
            "format": 1, "owner": "1-dead-", "aside": aside,
            "moves": [{"staged": staged, "target": target,
                       "identity": folder_identity(victim)}]}))
        with pytest.raises(PublishError, match="damaged publication journal"):
            finish_interrupted_publication(out)
    assert (victim / "keep").read_text() == "x"


def test_a_staged_folder_is_known_by_its_files_not_its_inode(tmp_path):
    """vfat and exfat renumber inodes across a remount (the power cut the journal is for):
    the staged folders were known by inode, so such a journal could not be finished. They
    are known by their files' names, sizes and times now; a copy with those kept (new
    inodes) is the same folder, a folder whose files changed is not."""
    import shutil

    from survey.publish import finish_interrupted_publication

    _old_set_and_staged_new(tmp_path)
    _kill_replace_together(tmp_path, "replace_together:after-0")
    for n in "bc":  # what a remount does to the inode numbers
        shutil.copytree(tmp_path / ".tmp-stage" / n, tmp_path / ".tmp-stage" / f"{n}2")
        shutil.rmtree(tmp_path / ".tmp-stage" / n)
        os.replace(tmp_path / ".tmp-stage" / f"{n}2", tmp_path / ".tmp-stage" / n)
    assert finish_interrupted_publication(tmp_path)
    assert [(tmp_path / n / "v").read_text() for n in "abc"] == ["new"] * 3

    (tmp_path / "again").mkdir()
    _old_set_and_staged_new(tmp_path / "again")
    _kill_replace_together(tmp_path / "again", "replace_together:after-0")
    (tmp_path / "again" / ".tmp-stage" / "c" / "v").write_text("other")  # not what was staged
    with pytest.raises(PublishError, match="stage/c is gone"):
        finish_interrupted_publication(tmp_path / "again")


def test_an_old_target_with_the_staged_folders_names_sizes_and_times_is_not_taken_as_moved(
        tmp_path):
    """An identity of names, sizes and modification times let an old target whose files
    matched the staged ones in all three (the builds' same-size outputs written within one
    tick of a coarse clock, or 2 s on vfat) pass as already moved in, and the set stayed
    mixed. The identity hashes the files' contents."""
    from survey.publish import remove_stale_temporaries

    _old_set_and_staged_new(tmp_path)  # "old" and "new": same name, same size
    for root in (tmp_path, tmp_path / ".tmp-stage"):
        for n in "abc":
            os.utime(root / n / "v", ns=(1_700_000_000_000_000_000,) * 2)
    _kill_replace_together(tmp_path, "replace_together:after-0")
    remove_stale_temporaries(tmp_path)
    assert [(tmp_path / n / "v").read_text() for n in "abc"] == ["new"] * 3


def test_a_full_disk_is_reported_with_the_file_being_written(tmp_path, monkeypatch):
    """A write's "No space left on device" carries no file name; the CLI's line names the
    file (or bundle folder) being written, and nothing is left behind."""
    import errno

    from click.testing import CliRunner

    from survey.cli import main

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError) as err:
        atomic_write_bytes(tmp_path / "a.bin", b"x")
    assert err.value.filename == str(tmp_path / "a.bin") and not list(tmp_path.iterdir())
    with pytest.raises(OSError) as err:
        with atomic_directory(tmp_path / "d") as staged:
            (staged / "f").write_bytes(b"x")
    assert err.value.filename == str(tmp_path / "d") and not list(tmp_path.iterdir())
    # errors of another kind keep their message and their file (a PublishError is an OSError)
    with pytest.raises(PublishError, match="^already there$"):
        with atomic_directory(tmp_path / "d"):
            raise PublishError("already there")
    with pytest.raises(FileNotFoundError) as err:
        with atomic_directory(tmp_path / "d"):
            (tmp_path / "gone.txt").read_bytes()
    assert err.value.filename == str(tmp_path / "gone.txt")
    trace = min((Path(__file__).resolve().parents[1] / "data" / "sample_site" / "F1"
                 / "path_data_files").glob("*.txt.gz"))
    res = CliRunner().invoke(main, ["ingest", str(trace), "--store", str(tmp_path / "s")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert f"error: {tmp_path / 's'}" in res.output and "No space left on device" in res.output


def test_ctrl_c_while_the_cli_loads_ends_like_ctrl_c_in_a_command(monkeypatch, capsys):
    """The console script imports the CLI inside its Ctrl-C handling (before session 39 a
    Ctrl-C in the first second printed a traceback from inside pandas' import)."""
    import sys
    import tomllib

    from survey.entry import run

    scripts = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml")
                            .read_text())["project"]["scripts"]
    assert scripts == {"indoormap": "survey.entry:run"}

    class Interrupted:
        def find_spec(self, name, path=None, target=None):
            if name == "survey.cli":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "survey.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted(), *sys.meta_path])
    with pytest.raises(SystemExit) as end:
        run()
    assert end.value.code == 1 and capsys.readouterr().err == "Aborted!\n"


@pytest.mark.parametrize("module", ["survey", "survey.entry"])
def test_python_m_runs_the_command_line(module):
    """``python -m survey.entry`` ran nothing and exited 0 (a scripted pipeline "succeeded"
    with no output); it and ``python -m survey`` are the command line."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.startswith("indoormap, version "), res
    res = subprocess.run([sys.executable, "-m", module, "no-such-command"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 2 and "No such command" in res.stderr
