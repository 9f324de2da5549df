"""Atomic publication helpers: all or nothing, no litter, normal permissions."""

from __future__ import annotations

import os
import stat

import pytest

from survey.errors import PublishError
from survey.publish import DIR_MODE, FILE_MODE, atomic_directory, atomic_write_bytes


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
    stage = tmp_path / "stage"
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
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "stage"]
