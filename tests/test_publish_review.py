"""Review of the publication journal (survey.publish.replace_together and its recovery):
failures and races the first tests did not cover."""

from __future__ import annotations

import ctypes
import errno
import os
from pathlib import Path

import pytest

import survey.publish as pub
from survey.publish import JOURNAL_NAME, replace_together

ROOT = Path(__file__).resolve().parents[1]


def _old_set_and_staged_new(root: Path, names: str = "abc", stage: str = "stage") -> None:
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
        if Path(src) == tmp_path / "stage" / "b":
            raise OSError(errno.EIO, "injected")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="injected"):
        replace_together([(tmp_path / "stage" / n, tmp_path / n) for n in "ab"],
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
