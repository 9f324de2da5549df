"""Review of the publication journal (survey.publish.replace_together and its recovery):
failures and races the first tests did not cover."""

from __future__ import annotations

import ctypes
import errno
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import survey.publish as pub
from survey.errors import PublishError
from survey.publish import JOURNAL_NAME, finish_interrupted_publication, folder_identity, \
    replace_together

ROOT = Path(__file__).resolve().parents[1]



def _old_set_and_staged_new(root: Path, names: str = "abc", stage: str = ".tmp-stage") -> None:
    for name in names:
        (root / name).mkdir()
        (root / name / "v").write_text("old")
        (root / stage / name).mkdir(parents=True)
        (root / stage / name / "v").write_text("new")


def _contents(root: Path, names: str = "abc") -> list[str | None]:
    return [(root / n / "v").read_text() if (root / n / "v").exists() else None for n in names]


def test_a_move_failing_after_its_old_target_went_aside_keeps_the_old_target(
        tmp_path, monkeypatch):
    """Two-rename fallback: the old target is renamed aside, then renaming the new one in
    fails (EIO, ENOSPC, a signal). The undo must put the old target back; it was left in the
    aside folder, which was then deleted: the old output was lost and its path left empty."""
    monkeypatch.setattr(pub, "exchange_paths", lambda a, b: False)
    _old_set_and_staged_new(tmp_path, "ab")
    real = os.replace

    def failing(src, dst):
        if Path(src) == tmp_path / ".tmp-stage" / "b":
            raise OSError(errno.EIO, "injected")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="injected"):
        replace_together([(tmp_path / ".tmp-stage" / n, tmp_path / n) for n in "ab"],
                         overwrite=True)
    monkeypatch.setattr(os, "replace", real)
    assert _contents(tmp_path, "ab") == ["old", "old"]
    assert not (tmp_path / JOURNAL_NAME).exists()


def test_exchange_paths_is_false_where_ctypes_cannot_open_the_c_library(tmp_path, monkeypatch):
    """On Windows ``ctypes.CDLL(None)`` raises TypeError (``'/' in None``), which escaped
    exchange_paths: every replaced bundle (atomic_directory, replace_together) failed there."""

    def windows_cdll(name, *args, **kwargs):
        if name is None:
            raise TypeError("argument of type 'NoneType' is not iterable")
        raise OSError(name)

    monkeypatch.setattr(pub, "_renameat2", None)
    monkeypatch.setattr(ctypes, "CDLL", windows_cdll)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    assert pub.exchange_paths(tmp_path / "a", tmp_path / "b") is False
    target = tmp_path / "out"
    for text in ("1", "2"):
        with pub.atomic_directory(target, overwrite=True) as tmp:
            (tmp / "x").write_text(text)
    assert (target / "x").read_text() == "2"


def _dead_journal(root: Path, names: str = "abc", done: int = 1, *,
                  bundles: bool = False) -> None:
    """The state a writer killed after its first ``done`` moves (with the swap) leaves; with
    ``bundles`` every folder is a bundle folder as far as ``bundle_dirs`` is concerned."""
    stage = ".tmp-999999-dead-stage"
    _old_set_and_staged_new(root, names, stage)
    for folder in (root, root / stage) if bundles else ():
        for n in names:
            (folder / n / "manifest.json").write_text("{}")
    moves = [(root / stage / n, root / n) for n in names]
    (root / JOURNAL_NAME).write_text(json.dumps({
        "format": 1, "owner": "4194304-dead-", "aside": ".tmp-999999-dead-aside",
        "moves": pub._journal_entries(root, moves)}))
    for staged, target in moves[:done]:
        assert pub.exchange_paths(staged, target)


def test_two_readers_finishing_one_journal_at_once_do_not_undo_each_other(tmp_path,
                                                                          monkeypatch):
    """Two processes opening the folder after a kill (two `localize` workers) both finish the
    journal. Unserialized, one checked that b was still to move, the other moved it in, and
    the first swapped it back out: the set ended mixed (the old b in place, the new one in a
    temporary that the next writer deletes), and the second failed on the journal the first
    had removed (BundleError in localize)."""
    _dead_journal(tmp_path)
    real = pub._swap_in
    errors: list[BaseException] = []
    second: list[threading.Thread] = []
    second_swapped, first_done = threading.Event(), threading.Event()

    def second_reader():
        try:
            finish_interrupted_publication(tmp_path)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    def swap_in(new, target, aside):
        if threading.current_thread() is threading.main_thread():
            if not second:  # the first reader has decided to move b; the second runs now
                second.append(threading.Thread(target=second_reader))
                second[0].start()
                second_swapped.wait(1.0)
            return real(new, target, aside)
        out = real(new, target, aside)
        second_swapped.set()
        first_done.wait(5.0)
        return out

    monkeypatch.setattr(pub, "_swap_in", swap_in)
    try:
        finish_interrupted_publication(tmp_path)
    except BaseException as exc:  # noqa: BLE001
        errors.append(exc)
    first_done.set()
    second[0].join(10)
    assert (_contents(tmp_path), errors) == (["new"] * 3, [])
    assert not (tmp_path / JOURNAL_NAME).exists()


def test_a_reader_that_read_the_journal_of_a_writer_which_then_finished_is_not_refused(
        tmp_path, monkeypatch):
    """A reader reads the journal; the writer ends its moves, removes its journal and exits;
    only then does the reader see its owner gone. It "finished" the set again and failed
    (FileNotFoundError on the journal, BundleError to localize)."""
    _dead_journal(tmp_path, done=3)
    text = (tmp_path / JOURNAL_NAME).read_text()
    real_alive = pub._owner_alive

    def alive(name, prefix):  # the writer finishes between the reader's read and check
        (tmp_path / JOURNAL_NAME).unlink(missing_ok=True)
        return real_alive(name, prefix)

    monkeypatch.setattr(pub, "_owner_alive", alive)
    assert text and finish_interrupted_publication(tmp_path) is False
    assert _contents(tmp_path) == ["new"] * 3


_SLOW_WRITER = """
import sys, time
from pathlib import Path
import survey.publish as p
real = p._swap_in
def slow(new, target, aside):
    time.sleep(0.5)
    return real(new, target, aside)
p._swap_in = slow
root = Path(sys.argv[1])
p.replace_together([(root / ".tmp-stage1" / n, root / n) for n in "ab"], overwrite=True)
"""


def test_two_writers_into_one_folder_take_turns(tmp_path):
    """A second writer (another build into OUT) whose moves fell among a live one's wrote
    its journal over the first's and removed it when done: the first then failed on its own
    journal (FileNotFoundError after its moves), and a kill of it would have left its set
    mixed with no journal to finish it."""
    _old_set_and_staged_new(tmp_path, "ab", ".tmp-stage1")
    (tmp_path / ".tmp-stage2" / "c").mkdir(parents=True)
    (tmp_path / ".tmp-stage2" / "c" / "v").write_text("new")
    first = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(tmp_path)],
                             cwd=ROOT, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 20
    while not (tmp_path / JOURNAL_NAME).exists():  # the first is among its moves
        assert first.poll() is None and time.monotonic() < deadline
        time.sleep(0.01)
    replace_together([(tmp_path / ".tmp-stage2" / "c", tmp_path / "c")])
    assert first.wait(20) == 0, first.stderr.read()
    assert _contents(tmp_path) == ["new"] * 3
    assert not (tmp_path / JOURNAL_NAME).exists()


def test_without_a_lock_a_second_writer_refuses_a_live_writers_journal(tmp_path, monkeypatch):
    """Where the folder cannot be locked (Windows), a journal whose process runs is a writer
    at work: a second writer says so instead of overwriting its journal."""
    import contextlib

    monkeypatch.setattr(pub, "_publication_lock", lambda parent: contextlib.nullcontext(False))
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        _old_set_and_staged_new(tmp_path, "ab", ".tmp-live")
        journal = json.dumps({
            "format": 1, "owner": f"{live.pid}-abcdef01-", "aside": ".tmp-live-aside",
            "moves": pub._journal_entries(tmp_path, [
                (tmp_path / ".tmp-live" / n, tmp_path / n) for n in "ab"])})
        (tmp_path / JOURNAL_NAME).write_text(journal)
        (tmp_path / ".tmp-stage" / "c").mkdir(parents=True)
        with pytest.raises(PublishError, match="is publishing there"):
            replace_together([(tmp_path / ".tmp-stage" / "c", tmp_path / "c")])
        assert (tmp_path / JOURNAL_NAME).read_text() == journal
    finally:
        live.kill()
        live.wait()


def test_cleaning_the_system_temp_folder_leaves_a_journal_there_alone(tmp_path):
    """`build` cleans its temporary stores out of the shared system temporary folder
    (remove_stale_temporaries(tempfile.gettempdir(), prefix='indoormap-build-')). That also
    acted on any .publish-journal.json there: anyone can plant one in /tmp, and the build then
    moved folders named in it, or failed (unlinking another user's file in a sticky folder)."""
    _dead_journal(tmp_path, done=1)
    before = (tmp_path / JOURNAL_NAME).read_text()
    pub.remove_stale_temporaries(tmp_path, prefix="indoormap-build-")
    assert (tmp_path / JOURNAL_NAME).read_text() == before
    assert _contents(tmp_path) == ["new", "old", "old"]


def test_bundle_dirs_of_a_file_is_empty_not_an_interrupted_publication(tmp_path):
    """`bundle verify FILE`, `localize` on a file: bundle_dirs said 'a build's publication
    here was interrupted and cannot be finished: ... Not a directory'."""
    from localize.bundle import bundle_dirs

    f = tmp_path / "notes.txt"
    f.write_text("x")
    assert bundle_dirs(f) == []


def test_a_bundle_missing_between_two_renames_is_found_when_opened_by_its_own_path(tmp_path):
    """Without the swap (no RENAME_EXCHANGE: NFS, macOS), a kill between renaming the old
    bundle aside and the new one in leaves OUT/b missing. Opening OUT/b itself (`localize
    --bundle OUT/b`, SiteMaps.open) found no bundle there: bundle_dirs finished a journal in
    OUT/b, not in OUT where it is."""
    from localize.bundle import bundle_dirs

    _dead_journal(tmp_path, done=1, bundles=True)
    (tmp_path / ".tmp-999999-dead-aside").mkdir()
    os.replace(tmp_path / "b", tmp_path / ".tmp-999999-dead-aside" / "1")  # killed here
    assert bundle_dirs(tmp_path / "b") == [tmp_path / "b"]
    assert _contents(tmp_path) == ["new"] * 3


def test_a_staging_folder_the_journal_cannot_name_is_refused_before_any_move(tmp_path):
    """The journal names staged folders relative to OUT, at most two parts deep, and refuses
    others when read. replace_together wrote such names anyway (a staging folder beside OUT,
    or deeper in it): a kill among its moves then left a journal read as damaged, and the
    set mixed for good."""
    (tmp_path / "out").mkdir()
    _old_set_and_staged_new(tmp_path / "out", "ab", "deep/stage")
    with pytest.raises(ValueError, match="staging"):
        replace_together([(tmp_path / "out" / "deep" / ".tmp-stage" / n, tmp_path / "out" / n)
                          for n in "ab"], overwrite=True)
    assert _contents(tmp_path / "out", "ab") == ["old", "old"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a", "b", "deep"]


def test_a_relative_out_with_an_absolute_staging_folder_is_published(tmp_path, monkeypatch):
    """tempfile.mkdtemp(dir='OUT') gives an absolute path on Python 3.12+: a build into a
    relative OUT stages there, and the journal still names the staged folders."""
    monkeypatch.chdir(tmp_path)
    Path("out").mkdir()
    _old_set_and_staged_new(Path("out"), "ab", ".tmp-stage")
    replace_together([(tmp_path / "out" / ".tmp-stage" / n, Path("out") / n) for n in "ab"],
                     overwrite=True)
    assert _contents(tmp_path / "out", "ab") == ["new", "new"]


def test_a_build_whose_undo_failed_keeps_its_staged_bundles_for_the_journal(tmp_path,
                                                                            monkeypatch):
    """A move fails and so does undoing an earlier one: replace_together keeps its journal
    for the next run to finish the set, but the build's staging folder was deleted on the
    way out, staged bundles with it, so the journal could never be finished (readers refused
    OUT, the next build dropped the journal with the set mixed)."""
    from mapping.cli_build import staging_folder

    out = tmp_path / "out"
    out.mkdir()
    for n in "ab":
        (out / n).mkdir()
        (out / n / "v").write_text("old")
    real_swap, real_exchange = pub._swap_in, pub.exchange_paths
    with pytest.raises(OSError, match="injected"):
        with staging_folder(out) as stage:
            for n in "ab":
                (stage / n).mkdir()
                (stage / n / "v").write_text("new")

            def swap_in(new, target, aside):
                if target.name == "b":
                    raise OSError(errno.EIO, "injected")
                return real_swap(new, target, aside)

            def exchange(a, b):
                if Path(b).name == "a" and (Path(b) / "v").read_text() == "new":
                    raise OSError(errno.EIO, "injected undo")  # the undo of a's swap
                return real_exchange(a, b)

            monkeypatch.setattr(pub, "_swap_in", swap_in)
            monkeypatch.setattr(pub, "exchange_paths", exchange)
            replace_together([(stage / n, out / n) for n in "ab"], overwrite=True)
    monkeypatch.undo()
    assert (out / JOURNAL_NAME).exists() and _contents(out, "ab") == ["new", "old"]
    record = json.loads((out / JOURNAL_NAME).read_text())  # the build exits: its
    record["owner"] = "4194304-gone-"                        # process is gone
    (out / JOURNAL_NAME).write_text(json.dumps(record))
    pub.remove_stale_temporaries(out)  # the next build
    assert _contents(out, "ab") == ["new", "new"]
    assert not (out / JOURNAL_NAME).exists()


@pytest.mark.parametrize("linked", ["staged", "aside"])
def test_a_journal_cannot_reach_outside_its_folder_through_a_link(tmp_path, linked):
    """_inside checks the journal's names, not what they lead to: a staging folder (or aside
    folder) in OUT that is a link to elsewhere made the finisher delete a folder there (the
    staged folder it found changed) or move an old bundle out into it."""
    victim = tmp_path / "victim"
    (victim / "F1").mkdir(parents=True)
    (victim / "F1" / "keep").write_text("x")
    out = tmp_path / "out"
    for n in "ab":
        (out / n).mkdir(parents=True)
    (out / ".tmp-1-x-staged-b").mkdir()
    if linked == "staged":
        os.symlink(victim, out / ".tmp-1-x-stage")
        moves = [{"staged": ".tmp-1-x-stage/F1", "target": "a",
                  "identity": folder_identity(out / "a")}]
        aside = ".tmp-1-x-aside"
    else:
        moves = [{"staged": ".tmp-1-x-staged-b", "target": "b",
                  "identity": folder_identity(out / ".tmp-1-x-staged-b")}]
        aside = ".tmp-1-x-aside"
        os.symlink(victim, out / aside)
    (out / JOURNAL_NAME).write_text(json.dumps({
        "format": 1, "owner": "4194304-dead-", "aside": aside, "moves": moves}))
    with pytest.raises(PublishError, match="damaged publication journal"):
        finish_interrupted_publication(out)
    assert sorted(p.name for p in victim.iterdir()) == ["F1"]
    assert (victim / "F1" / "keep").read_text() == "x"


@pytest.mark.skipif(pub._start_mark(os.getpid()) is None,
                    reason="the system does not say when processes started (/proc)")
def test_a_temporary_whose_pid_now_belongs_to_another_process_is_stale(tmp_path):
    """A killed build's staging folder (``.tmp-<pid>-<token>-...``) was kept for as long as any
    process had its pid; the token carries its process's start time, so another process given
    the pid later no longer keeps it (temporaries of older indoormaps, without one, are judged
    by the pid alone)."""
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        mark = pub._start_mark(other.pid)
        names = {"its own": f".tmp-{other.pid}-0badc0des{mark}-a",
                 "an earlier owner's": f".tmp-{other.pid}-0badc0des1{mark}-b",
                 "no start recorded": f".tmp-{other.pid}-0badc0de-c"}
        for name in names.values():
            (tmp_path / name).mkdir()
        assert pub.remove_stale_temporaries(tmp_path) == 1
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            [names["its own"], names["no start recorded"]])
    finally:
        other.kill()
        other.wait()
    assert pub.tmp_prefix().endswith(f"s{pub._start_mark(os.getpid())}-")


@pytest.mark.skipif(pub._start_mark(os.getpid()) is None,
                    reason="the system does not say when processes started (/proc)")
def test_a_journal_whose_pid_now_belongs_to_another_process_is_finished(tmp_path):
    """After a reboot (or a wrap of the pids) a killed writer's pid can belong to a live,
    unrelated process. Readers took the journal for a live writer's and read a mix of two
    builds until the next writer came; the journal's owner token records when its writer
    started."""
    _old_set_and_staged_new(tmp_path)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        def journal(started):
            (tmp_path / JOURNAL_NAME).write_text(json.dumps({
                "format": 1, "owner": f"{other.pid}-0badc0des{started}-", "aside": ".tmp-aside",
                "moves": [{"staged": f".tmp-stage/{n}", "target": n,
                           "identity": folder_identity(tmp_path / ".tmp-stage" / n)}
                          for n in "abc"]}))

        journal(pub._start_mark(other.pid))  # its writer: at work, left alone
        assert finish_interrupted_publication(tmp_path) is False
        assert _contents(tmp_path) == ["old"] * 3
        journal(pub._start_mark(os.getpid()))  # a process started at another time
        assert finish_interrupted_publication(tmp_path) is True
        assert _contents(tmp_path) == ["new"] * 3
    finally:
        other.kill()
        other.wait()


def _killed_bundle_set(root: Path, crash_at: str) -> None:
    from test_publish import _KILLED_SET

    _old_set_and_staged_new(root)
    for n in "abc":  # bundle folders as far as bundle_dirs is concerned
        for folder in (root, root / ".tmp-stage"):
            (folder / n / "manifest.json").write_text("{}")
    res = subprocess.run([sys.executable, "-c", _KILLED_SET, str(root), "exchange"],
                         env={**os.environ, "INDOORMAP_CRASH_AT": crash_at}, cwd=ROOT,
                         check=False)
    assert res.returncode == 70 and (root / JOURNAL_NAME).exists()


def test_a_finished_set_in_a_folder_that_cannot_be_written_is_read_as_it_is(tmp_path,
                                                                            monkeypatch):
    """Killed after its last move, before removing its journal, then the folder made read-only
    (a read-only mount, a copy): the set is whole, yet readers failed on the journal they could
    not remove. They read it now; a set with moves still to make is refused as before."""
    from localize.bundle import bundle_dirs
    from survey.errors import BundleError

    done, half = tmp_path / "done", tmp_path / "half"
    done.mkdir()
    half.mkdir()
    _killed_bundle_set(done, "replace_together:before-cleanup")
    _killed_bundle_set(half, "replace_together:after-0")

    def read_only(method):
        def refuse(self, *args, **kwargs):
            if tmp_path in (self, *self.parents):
                raise PermissionError(13, "Read-only file system", str(self))
            return method(self, *args, **kwargs)
        return refuse

    monkeypatch.setattr(Path, "unlink", read_only(Path.unlink))
    monkeypatch.setattr(Path, "mkdir", read_only(Path.mkdir))
    assert [p.name for p in bundle_dirs(done)] == ["a", "b", "c"]
    assert _contents(done) == ["new"] * 3 and (done / JOURNAL_NAME).exists()
    with pytest.raises(BundleError, match="cannot be finished.*Read-only file system"):
        bundle_dirs(half)
    assert _contents(half) == ["new", "old", "old"]


@pytest.mark.parametrize("field", ["staged", "aside", "target"])
def test_a_tampered_journal_cannot_delete_an_output_in_its_folder(tmp_path, field):
    """Session 29: the journal's names were only kept inside OUT, so a journal naming a
    published bundle (F1) as a staged folder, whose identity it copied, had the finisher take
    the set for whole and delete F1; naming F1 as the aside folder deleted it too. Staged
    and aside folders must be ``.tmp-`` temporaries now, and a target cannot be one."""
    out = tmp_path / "out"
    for n in ("F1", "F2"):
        (out / n).mkdir(parents=True)
        (out / n / "manifest.json").write_text(n)
    (out / ".tmp-1-x-stage" / "F2").mkdir(parents=True)
    staged, target, aside = ".tmp-1-x-stage/F2", "F2", ".tmp-1-x-aside"
    identity = folder_identity(out / "F2")  # the move looks made: staged folders are deleted
    if field == "staged":
        staged = "F1"
    elif field == "aside":
        aside = "F1"
    else:
        target = ".tmp-1-x-stage"
    (out / JOURNAL_NAME).write_text(json.dumps({
        "format": 1, "owner": "4194304-dead-", "aside": aside,
        "moves": [{"staged": staged, "target": target, "identity": identity}]}))
    with pytest.raises(PublishError, match="damaged publication journal"):
        finish_interrupted_publication(out)
    assert [(out / n / "manifest.json").read_text() for n in ("F1", "F2")] == ["F1", "F2"]
    assert (out / ".tmp-1-x-stage" / "F2").is_dir()
