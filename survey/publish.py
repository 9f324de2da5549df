"""Crash-safe publication of files and directories.

Every output indoormap writes goes through here: content is written into a temporary sibling,
fsynced, moved into place with :func:`os.replace`, and the parent directory is fsynced. A crash at
any point leaves either the old output or the new one, plus at most a ``.tmp-<pid>-*`` sibling
that the next publish to the same parent removes once that process is gone.

Tests inject crashes with the ``INDOORMAP_CRASH_AT`` environment variable: when it names a crash
point passed to :func:`crash_point`, the process exits immediately with ``os._exit(70)``.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .errors import PublishError

TMP_PREFIX = ".tmp-"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: Permissions of published files and folders: what ``open``/``mkdir`` would give (the
#: temporary-file functions create 0600/0700, which must not leak into outputs).
FILE_MODE = 0o666 & ~_umask()
DIR_MODE = 0o777 & ~_umask()


def file_sha256(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def crash_point(name: str) -> None:
    """Exit at once (no cleanup, like a power cut) if ``INDOORMAP_CRASH_AT == name``."""
    if os.environ.get("INDOORMAP_CRASH_AT") == name:
        os._exit(70)


def fsync_dir(path: str | os.PathLike) -> None:
    """fsync a directory so a rename inside it is durable (no-op where unsupported)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    for dirpath, _dirnames, filenames in os.walk(root):
        for name in filenames:
            with open(os.path.join(dirpath, name), "rb") as fh:
                os.fsync(fh.fileno())
        fsync_dir(dirpath)


#: Marks this process's temporaries apart from those of a dead process that had its pid.
_PROCESS_TOKEN = secrets.token_hex(4)


def tmp_prefix(prefix: str = TMP_PREFIX) -> str:
    """``prefix`` plus this process's id and token: temporaries say who made them, so that
    cleaning up after a crash never removes the work in progress of a live process."""
    return f"{prefix}{os.getpid()}-{_PROCESS_TOKEN}-"


def _owner_alive(name: str, prefix: str) -> bool:
    """Whether the process that made a temporary (``<prefix><pid>-<token>-...``) still runs."""
    pid, _, rest = name[len(prefix):].partition("-")
    if not pid.isdigit() or int(pid) >= 2**22:
        return False  # no owner recorded: a leftover of an older indoormap
    if int(pid) == os.getpid():
        return rest.startswith(_PROCESS_TOKEN + "-")  # else a dead process had our pid
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's live process
    return True


def remove_stale_temporaries(parent: str | os.PathLike, prefix: str = TMP_PREFIX) -> int:
    """Remove ``prefix*`` leftovers of crashed or killed processes in ``parent`` (those whose
    process no longer runs); returns how many."""
    parent = Path(parent)
    if not parent.is_dir():
        return 0
    n = 0
    for p in parent.glob(prefix + "*"):
        if _owner_alive(p.name, prefix):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        n += 1
    return n


def refuse_to_replace(path: str | os.PathLike, overwrite: bool) -> None:
    """A :class:`PublishError` when a command's output ``path`` exists and ``--overwrite``
    was not given; commands call it before any work."""
    if not overwrite and Path(path).exists():
        raise PublishError(f"{path} exists; pass --overwrite to replace it")


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False,
                       sync_dir: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (temp file, fsync, rename, dir fsync).

    With ``sync_dir=False`` the caller fsyncs the parent folder itself (once for many files)
    before relying on the rename being durable."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise PublishError(f"{path}: exists; pass overwrite=True (CLI: --overwrite) to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=tmp_prefix(), dir=path.parent)
    try:
        os.fchmod(fd, FILE_MODE)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if sync_dir:
        fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_directory(target: str | os.PathLike, *, overwrite: bool = False,
                     crash_prefix: str = "publish") -> Iterator[Path]:
    """Build a directory in a temporary sibling and move it into place on success.

    Yields the temporary directory to fill. On an exception the temporary directory is removed
    and ``target`` is untouched. With ``overwrite`` an existing target is replaced: it is first
    renamed aside, the new one renamed in, then the old one deleted, so that the target path
    always holds a complete directory except for the instant between two renames.
    """
    target = Path(target)
    if target.exists() and not overwrite:
        raise PublishError(f"{target}: exists; pass overwrite=True (CLI: --overwrite) to replace it")
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(target.parent)
    tmp = Path(tempfile.mkdtemp(prefix=tmp_prefix(), dir=target.parent))
    os.chmod(tmp, DIR_MODE)
    try:
        yield tmp
        crash_point(f"{crash_prefix}:before-fsync")
        _fsync_tree(tmp)
        crash_point(f"{crash_prefix}:before-rename")
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=tmp_prefix(), dir=target.parent))
            os.replace(target, old / "old")
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
        fsync_dir(target.parent)
        crash_point(f"{crash_prefix}:after-rename")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def replace_together(moves: list[tuple[Path, Path]], *, overwrite: bool = False) -> None:
    """Move finished directories (each staged in a temporary folder on the targets' file
    system) onto their targets one right after the other, so that a set of outputs made to
    go together (a site's floor bundles and its site bundle) changes at once.

    A crash while the set is being made leaves the old set whole. If a move fails (or the
    process is interrupted by an exception) the moves done so far are undone, so the old set
    is back. Only a kill in the milliseconds of the moves themselves can leave a mix, or an
    old target aside in a ``.tmp-*`` folder. Replaced targets are deleted after all moved.
    """
    for _, target in moves:
        if target.exists() and not overwrite:
            raise PublishError(f"{target}: exists; pass overwrite=True (CLI: --overwrite) to "
                               "replace it")
    if not moves:
        return
    aside = Path(tempfile.mkdtemp(prefix=tmp_prefix(), dir=moves[0][1].parent))
    done: list[tuple[Path, Path, Path | None]] = []  # (staged, target, old target's place)
    try:
        for i, (staged, target) in enumerate(moves):
            old = None
            if target.exists():
                old = aside / str(i)
                os.replace(target, old)
            done.append((staged, target, old))
            os.replace(staged, target)
            crash_point(f"replace_together:after-{i}")
    except BaseException:
        for staged, target, old in reversed(done):  # undo: the old set comes back
            with contextlib.suppress(OSError):
                if target.exists() and not staged.exists():
                    os.replace(target, staged)
                if old is not None:
                    os.replace(old, target)
        with contextlib.suppress(OSError):
            aside.rmdir()  # empty once every old target is back
        raise
    finally:
        for parent in {target.parent for _, target in moves}:
            fsync_dir(parent)
    shutil.rmtree(aside, ignore_errors=True)
