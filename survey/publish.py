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
import ctypes
import errno
import hashlib
import json
import os
import secrets
import shutil
import sys
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

from .errors import PublishError
from .regular_files import open_regular, read_regular

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
    """Hex sha256 of a regular file's bytes (:func:`file_sha256_and_size`)."""
    return file_sha256_and_size(path)[0]


def file_sha256_and_size(path: str | os.PathLike) -> tuple[str, int]:
    """Hex sha256 of a regular file's bytes, read in 1 MiB chunks, and how many bytes were
    hashed. Raises :class:`~survey.regular_files.NotRegularFile` (an ``OSError``) for a
    FIFO, device or socket, before reading: hashing one would block or never end."""
    h = hashlib.sha256()
    size = 0
    fd, _ = open_regular(path)
    with open(fd, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
            size += len(chunk)
    return h.hexdigest(), size


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


def _start_mark(pid: int) -> str | None:
    """When process ``pid`` started: its start time in clock ticks since boot, ``b`` and the
    first 8 hex digits of the boot id (Linux's ``/proc``); None where that cannot be read
    (another system, no such process). A pid given to a later process, also after a reboot,
    gives another mark."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        return f"{stat[stat.rindex(')') + 2:].split()[19]}b{boot[:8]}"
    except (OSError, ValueError, IndexError):
        return None


#: Marks this process's temporaries (and journals) apart from those of a dead process that had
#: its pid: a random part, plus ``s<start mark>`` where the system tells.
_PROCESS_TOKEN = secrets.token_hex(4) + (f"s{m}" if (m := _start_mark(os.getpid())) else "")


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
        pass  # another user's live process
    _, _, started = rest.partition("-")[0].partition("s")
    now = _start_mark(int(pid)) if started else None
    return now is None or now == started  # else the pid now belongs to a later process


def remove_stale_temporaries(parent: str | os.PathLike, prefix: str = TMP_PREFIX) -> int:
    """Remove ``prefix*`` leftovers of crashed or killed processes in ``parent`` (those whose
    process no longer runs), after finishing a set of moves such a process left half done
    (:func:`finish_interrupted_publication`; only for indoormap's own ``TMP_PREFIX``
    temporaries: other prefixes clean shared folders such as the system's temporary folder,
    where a journal is none of ours); returns how many."""
    parent = Path(parent)
    if not parent.is_dir():
        return 0
    if prefix == TMP_PREFIX:  # first finish a killed set of moves: its staged outputs are
        try:                  # such temporaries
            finish_interrupted_publication(parent)
        except PublishError as exc:
            warnings.warn(f"{exc}; its journal is removed", stacklevel=2)
            with _publication_lock(parent):  # unless it became finishable meanwhile
                try:
                    _finish_journal(parent, take_over=False)
                except PublishError:
                    (parent / JOURNAL_NAME).unlink(missing_ok=True)
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


def check_parent_is_a_folder(path: str | os.PathLike) -> None:
    """A :class:`PublishError` when the nearest existing folder above an output ``path`` is a
    file: the command found out only when it wrote, after its work, and said "File exists"
    (read as "pass --overwrite")."""
    for parent in Path(path).absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise PublishError(f"{parent} is a file, not a folder: {path} cannot be made "
                                   "under it")
            return


def refuse_to_replace(path: str | os.PathLike, overwrite: bool, *,
                      suffixes: tuple[str, ...] = ()) -> None:
    """A :class:`PublishError` when a command's output ``path`` exists and ``--overwrite``
    was not given, or (``suffixes``, lower case) when it was but the existing file's name
    does not end with one of them: ``--csv st/catalog.parquet --overwrite`` would have
    replaced the command's own input; or when a folder it would be made in is a file
    (:func:`check_parent_is_a_folder`). Commands call it before any work."""
    path = Path(path)
    check_parent_is_a_folder(path)
    if not path.exists():
        return
    if not overwrite:
        raise PublishError(f"{path} exists; pass --overwrite to replace it")
    if suffixes and path.suffix.lower() not in suffixes:
        raise PublishError(f"{path} exists and is not a {' or '.join(suffixes)} file; "
                           "--overwrite replaces only those (is it one of the command's "
                           "inputs?), move it away first")


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False,
                       sync_dir: bool = True, crash: str | None = None) -> None:
    """Write ``data`` to ``path`` atomically (temp file, fsync, rename, dir fsync).

    With ``sync_dir=False`` the caller fsyncs the parent folder itself (once for many files)
    before relying on the rename being durable. ``crash``: a :func:`crash_point` between the
    temporary's fsync and its rename (tests kill the writer there)."""
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
        if crash is not None:
            crash_point(crash)
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        _name_file(err, path)
        raise
    if sync_dir:
        fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_directory(target: str | os.PathLike, *, overwrite: bool = False,
                     crash_prefix: str = "publish") -> Iterator[Path]:
    """Build a directory in a temporary sibling and move it into place on success.

    Yields the temporary directory to fill. On an exception the temporary directory is removed
    and ``target`` is untouched. With ``overwrite`` an existing target is replaced: the two
    are swapped in one step where the system can (Linux, :func:`exchange_paths`), else the old
    one is renamed aside and the new one renamed in; then the old one is deleted. The target
    path always holds a complete directory (with the fallback, except for the instant between
    the two renames).
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
        aside = Path(tempfile.mkdtemp(prefix=tmp_prefix(), dir=target.parent))
        _swap_in(tmp, target, aside / "old")  # a swapped old target is left at tmp
        fsync_dir(target.parent)
        shutil.rmtree(aside, ignore_errors=True)
        shutil.rmtree(tmp, ignore_errors=True)
        crash_point(f"{crash_prefix}:after-rename")
    except BaseException as err:
        shutil.rmtree(tmp, ignore_errors=True)
        _name_file(err, target)
        raise


#: Errors of writing that the system reports without a file name: no space, over quota, an
#: I/O error, a file too large, a read-only file system.
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG, errno.EROFS})


def _name_file(err: BaseException, path: Path) -> None:
    """Give a write's operating-system error that names no file (``"No space left on
    device"`` from a write, an I/O error from an fsync) the ``path`` being written, which the
    CLI prints. Other errors keep their own message and file name."""
    if isinstance(err, OSError) and err.filename is None and err.errno in _WRITE_ERRNOS:
        err.filename = str(path)


#: A set of moves in progress (:func:`replace_together`), kept in the targets' folder.
JOURNAL_NAME = ".publish-journal.json"

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
_renameat2: Any = None


def exchange_paths(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Swap two existing paths in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``);
    False, with nothing changed, when that fails for any reason (another system, a file
    system or sandbox without it, a missing path): the caller then renames twice."""
    global _renameat2
    if _renameat2 is None:
        _renameat2 = False  # the flag and AT_FDCWD values below are Linux's
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(None, use_errno=True)
                fn = libc.renameat2
                fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                               ctypes.c_uint]
                fn.restype = ctypes.c_int
                _renameat2 = fn
            except (OSError, AttributeError, TypeError):  # TypeError: CDLL(None) on Windows
                pass
    if not _renameat2:
        return False
    if _renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    # any failure (no such call, a file system without it, a sandbox's EPERM) falls back to
    # two renames, where a real error (a missing path, no permission) shows again
    return False


def _swap_in(new: Path, target: Path, aside: Path) -> bool:
    """Put ``new`` at ``target``; an existing target ends at ``new``'s old path when the two
    could be swapped at once (returns True), else at ``aside`` (renamed away first, and back
    if ``new`` cannot then be renamed in: nothing changed when this raises)."""
    if target.exists():
        if exchange_paths(new, target):
            return True
        os.replace(target, aside)
        try:
            os.replace(new, target)
        except BaseException:
            with contextlib.suppress(OSError):
                os.replace(aside, target)
            raise
        return False
    os.replace(new, target)
    return False


def folder_identity(path: Path) -> str:
    """What tells a staged folder from the one it replaces, wherever a rename puts it: the
    sha256 of its files' relative paths and contents. Inode numbers do not do (vfat and exfat
    renumber them across a remount, some file systems report 0), nor do modification times
    (coarse on vfat, shifted by its local-time clock); two folders of one identity hold the
    same files, so taking one for the other changes nothing."""
    h = hashlib.sha256()
    for dirpath, dirnames, filenames in sorted(os.walk(path)):
        dirnames.sort()
        for name in sorted(filenames):
            p = os.path.join(dirpath, name)
            digest = "link" if os.path.islink(p) else file_sha256(p)
            h.update(f"{os.path.relpath(p, path)}\0{digest}\n".encode())
    return h.hexdigest()


def _is(path: Path, identity: str) -> bool:
    return path.is_dir() and not path.is_symlink() and folder_identity(path) == identity


def _journal_entries(parent: Path, moves: list[tuple[Path, Path]]) -> list[dict[str, Any]]:
    return [{"staged": _staged_name(parent, staged), "target": target.name,
             "identity": folder_identity(staged)} for staged, target in moves]


def _staged_name(parent: Path, staged: Path) -> str:
    """How the journal names a staged folder: relative to ``parent``, ``/``-separated (also
    on Windows), as :func:`_temporary` accepts it; ValueError for a folder it cannot name."""
    try:
        return _temporary(Path(os.path.relpath(staged, parent)).as_posix())
    except ValueError:
        raise ValueError(f"replace_together: {staged} is not a staging folder in {parent} "
                         f"(one or two levels deep, in a {TMP_PREFIX}* temporary)") from None


def _inside(name: object, depth: int = 2) -> str:
    """A journal's relative path, checked: at most ``depth`` plain parts (no ``..``, no
    absolute path), so that a damaged journal cannot move or delete anything elsewhere."""
    parts = str(name).split("/")
    if not 0 < len(parts) <= depth or any(p in ("", ".", "..") or "\\" in p for p in parts):
        raise ValueError(f"unsafe path {name!r}")
    return str(name)


def _temporary(name: object, depth: int = 2) -> str:
    """A journal's path to a staged or set-aside folder, checked: :func:`_inside`, and in a
    ``TMP_PREFIX`` temporary, the only folders a publication deletes, so that a damaged or
    tampered journal cannot delete an output (or anything else) in the folder."""
    if not _inside(name, depth).startswith(TMP_PREFIX):
        raise ValueError(f"{name!r} is not in a {TMP_PREFIX}* temporary")
    return str(name)


def _target(name: object) -> str:
    """A journal's target, checked: one plain name, neither a temporary nor the journal."""
    if _inside(name, depth=1).startswith(TMP_PREFIX) or name == JOURNAL_NAME:
        raise ValueError(f"{name!r} cannot be a published output")
    return str(name)


@contextlib.contextmanager
def _publication_lock(parent: Path) -> Iterator[bool]:
    """An exclusive ``flock`` on the folder ``parent`` itself: a writer holds it from before
    it writes its journal until it has removed it, and whoever finishes a killed writer's
    journal holds it while doing so, so that no two of them move the same folders at once.
    Yields whether it is held: False where ``flock`` is not available (Windows, some network
    file systems), where the journal's process id is all there is to go by."""
    try:
        import fcntl
        fd = os.open(parent, os.O_RDONLY)
    except (ImportError, OSError):
        yield False
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            locked = True
        except OSError:
            locked = False
        yield locked
    finally:
        os.close(fd)  # releases the lock


def replace_together(moves: list[tuple[Path, Path]], *, overwrite: bool = False) -> None:
    """Move finished directories (each staged in a temporary folder on the targets' file
    system) onto their targets, so that a set of outputs made to go together (a site's floor
    bundles and its site bundle) changes as one.

    A crash while the set is being made leaves the old set whole. The moves are listed first
    in a journal (``JOURNAL_NAME`` in the targets' folder): if the process is killed among
    them, the next indoormap that writes to that folder or opens a bundle in it finishes them
    (:func:`finish_interrupted_publication`), so the set is never left mixed. If a move fails
    (or an exception interrupts them) the moves done so far are undone and the old set is
    back. Where the system can swap two paths at once (Linux), a replaced target is never
    missing, even for a moment. Replaced targets are deleted after all moved. Writers into
    one folder take turns (a lock on the folder, where the system has ``flock``; elsewhere a
    second writer meeting a live one's journal raises :class:`PublishError`).
    """
    for _, target in moves:
        if target.exists() and not overwrite:
            raise PublishError(f"{target}: exists; pass overwrite=True (CLI: --overwrite) to "
                               "replace it")
    if not moves:
        return
    parent = moves[0][1].parent
    if any(target.parent != parent for _, target in moves):
        raise ValueError("replace_together: every target must be in one folder")
    for staged, target in moves:
        _staged_name(parent, staged)  # the journal can name it
        _target(target.name)
        if not staged.is_dir():
            raise PublishError(f"{staged}: nothing staged to publish")
    journal = parent / JOURNAL_NAME
    with _publication_lock(parent) as locked:
        found = _read_journal(parent)
        if found is not None and not locked and found.owner != tmp_prefix("") \
                and found.owner_alive():
            raise PublishError(f"{parent}: another indoormap (process "
                               f"{found.owner.split('-')[0]}) is publishing there; try again "
                               "when it is done")
        # under the lock a journal is a killed writer's (live ones hold the lock), or this
        # process's own after an undo that failed
        _finish_journal(parent, take_over=True)
        aside = Path(tempfile.mkdtemp(prefix=tmp_prefix(), dir=parent))
        atomic_write_bytes(journal, json.dumps({
            "format": 1, "owner": tmp_prefix(""), "aside": aside.name,
            "moves": _journal_entries(parent, moves)}, indent=1).encode(), overwrite=True)
        done: list[tuple[Path, Path, bool, bool]] = []  # staged, target, swapped, existed
        try:
            for i, (staged, target) in enumerate(moves):
                existed = target.exists()
                swapped = _swap_in(staged, target, aside / str(i))
                done.append((staged, target, swapped, existed))
                crash_point(f"replace_together:after-{i}")
        except BaseException:
            undone = True
            for i, (staged, target, swapped, existed) in reversed(list(enumerate(done))):
                try:  # undo: the old set comes back
                    if swapped:
                        if not exchange_paths(staged, target):
                            undone = False
                    else:
                        os.replace(target, staged)
                        if existed:
                            os.replace(aside / str(i), target)
                except OSError:
                    undone = False
            if undone:  # else the journal stays, and the next writer or reader finishes it
                with contextlib.suppress(OSError):
                    journal.unlink()
                shutil.rmtree(aside, ignore_errors=True)
            raise
        finally:
            fsync_dir(parent)
        crash_point("replace_together:before-cleanup")
        journal.unlink()
        fsync_dir(parent)
    for staged, _, swapped, _ in done:
        if swapped:  # the old target, swapped to the staging path
            shutil.rmtree(staged, ignore_errors=True)
    shutil.rmtree(aside, ignore_errors=True)


class _Journal(NamedTuple):
    owner: str  # :func:`tmp_prefix` ``("")`` of the process that wrote it
    moves: list[tuple[Path, Path, str]]  # staged, target, the staged folder's identity
    aside: Path

    def owner_alive(self) -> bool:
        """Whether the process that wrote the journal still runs (its token's start mark
        tells it from a later process given its pid)."""
        return _owner_alive(TMP_PREFIX + self.owner, TMP_PREFIX)


def _read_journal(parent: Path) -> _Journal | None:
    """The journal in ``parent`` (paths checked); None when there is none."""
    journal = parent / JOURNAL_NAME
    try:
        text = read_regular(journal, 16 * 1024**2)  # a FIFO is not waited on
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise PublishError(f"{journal}: unreadable publication journal: {exc}") from exc
    try:
        record = json.loads(text)
        owner = str(record["owner"])
        moves = [(parent / _temporary(m["staged"]), parent / _target(m["target"]),
                  str(m["identity"])) for m in record["moves"]]
        aside = parent / _temporary(record["aside"], depth=1)
        for first in {aside, *(parent / staged.relative_to(parent).parts[0]
                               for staged, _, _ in moves)}:
            if first.is_symlink():  # it would lead the moves and deletions elsewhere
                raise ValueError(f"{first.name!r} is a link")
    except (ValueError, KeyError, TypeError) as exc:
        raise PublishError(f"{journal}: damaged publication journal ({exc}); the outputs "
                           f"in {parent} may be a mix of two builds: build them again") from exc
    return _Journal(owner, moves, aside)


def finish_interrupted_publication(parent: str | os.PathLike) -> bool:
    """Finish the moves of a :func:`replace_together` whose process was killed among them
    (its journal in ``parent``), so that the set of outputs is the new one throughout;
    True if there was one to finish. A journal whose process still runs is left alone.
    Two processes finishing one journal take turns (the folder's lock). A journal whose moves
    were all made before the kill is left where this process cannot remove it (a read-only
    mount or copy of the folder): the set is whole and is read as it is.

    Raises
    ------
    PublishError
        The journal is unreadable, or the staged outputs it lists are gone, so the set cannot
        be made whole; the message names the folder.
    """
    parent = Path(parent)
    found = _read_journal(parent)
    if found is None or found.owner_alive():
        return False  # (a live writer: not waited for)
    with _publication_lock(parent):
        return _finish_journal(parent, take_over=False)


def _finish_journal(parent: Path, *, take_over: bool) -> bool:
    """:func:`finish_interrupted_publication` with the folder's lock held: the journal read
    again (another process may have finished it, or its writer removed it, meanwhile), and
    left alone if its process runs unless ``take_over``."""
    found = _read_journal(parent)
    if found is None:
        return False
    if not take_over and found.owner_alive():
        return False
    moves, aside = found.moves, found.aside
    journal = parent / JOURNAL_NAME
    todo = []  # every move checked before any is made: none is made if one cannot be
    for i, (staged, target, identity) in enumerate(moves):
        if _is(target, identity):
            continue  # moved in before the kill (a swapped old target may lie at staged)
        if not _is(staged, identity):
            raise PublishError(f"{journal}: an interrupted publication cannot be finished: "
                               f"{staged} is gone, so {target} would not match the rest of "
                               f"{parent}: build the outputs again")
        todo.append((i, staged, target))
    if not todo:  # every move was made before the kill: the set is whole, only litter is left
        try:
            journal.unlink()
        except OSError:  # a folder this process cannot write (a read-only mount or copy)
            return False  # is read as it is
        fsync_dir(parent)
        for staged, _, _ in moves:
            shutil.rmtree(staged, ignore_errors=True)
        shutil.rmtree(aside, ignore_errors=True)
        return True
    aside.mkdir(exist_ok=True)
    for i, staged, target in todo:
        _swap_in(staged, target, aside / str(i))
    fsync_dir(parent)
    journal.unlink()
    fsync_dir(parent)
    for staged, _, _ in moves:  # every target holds its new folder: what is left is old
        shutil.rmtree(staged, ignore_errors=True)
    shutil.rmtree(aside, ignore_errors=True)
    return True
