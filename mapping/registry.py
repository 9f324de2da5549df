"""A registry of map bundles: immutable versions per site/floor and a current pointer.

Layout::

    REG/<site>/<floor>/versions/<bundle_id>/   bundles, never modified once published
    REG/<site>/<floor>/history.json            published versions in order: [{seq, bundle_id}]
    REG/<site>/<floor>/CURRENT                 {"bundle_id": ..., "seq": ...}, replaced atomically

A version is copied in with an atomic folder rename, then ``history.json`` and ``CURRENT`` are
replaced atomically, so a reader that follows ``CURRENT`` always finds a complete, verified
bundle; a crash leaves the previous current version in place. Versions only move forward:
pointing ``CURRENT`` at an older version needs ``allow_rollback=True``, and the versions a
rollback withdrew (``CURRENT``'s ``rolled_back_from``) are not made current again by
publishing them again (:class:`~survey.errors.WithdrawnVersion`), only by ``set_current``.
Readers check that ``CURRENT`` is an entry of ``history.json`` (its seq and bundle id) whose
folder exists, so a pointer edited by hand is refused, not followed
(:func:`localize.bundle.registry_current`);
``set_current`` repairs it (anything but the newest version then counts as a rollback).

Writers of one floor take turns: ``publish`` and ``set_current`` hold an exclusive lock on
``REG/<site>/<floor>/.lock`` (``flock``, released by the system if the process dies) while
they read and replace ``history.json`` and ``CURRENT``, so concurrent publishes each get their
own sequence number and none is lost. Readers take no lock. The lock is advisory and local: it
needs a file system with working ``flock`` (not every network share has one), and where the
platform has no ``fcntl`` (Windows) writers are not serialized.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from localize.bundle import (
    MapBundle,
    history_lost,
    load_bundle,
    read_registry_history,
    read_registry_pointer,
    registry_current,
    safe_name,
)
from survey.errors import (BundleError, BundleIntegrityError, RegistryError, RollbackRefused,
                           WithdrawnVersion)
from survey.publish import atomic_directory, atomic_write_bytes, crash_point

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]


SITE_BUNDLE = "_site"
"""Name under which a site's site-level bundle (floor model, device table) is kept, in a
registry and beside the floor bundles of ``indoormap build``."""


def _damaged(version: Path) -> bool:
    """Whether a version folder fails the bundle checks (a member changed, missing or
    added, no manifest: a :class:`~survey.errors.BundleError`) or holds another bundle than
    the one it is named after."""
    try:
        return load_bundle(version).bundle_id != version.name
    except BundleError:
        return True


class Registry:
    """Bundles of many sites and floors under one folder."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)

    def _floor(self, site: str, floor: str) -> Path:
        return self.root / safe_name(site) / safe_name(floor)

    @contextlib.contextmanager
    def _writing(self, site: str, floor: str) -> Iterator[Path]:
        """Hold the floor's writer lock (see the module docstring); yields the floor folder."""
        base = self._floor(site, floor)
        base.mkdir(parents=True, exist_ok=True)
        with open(base / ".lock", "ab") as fh:
            if fcntl is not None:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX)  # released on close, or by the OS
            yield base

    def history(self, site: str, floor: str) -> list[dict]:
        """The published versions in order, ``[{"seq", "bundle_id"}]`` (see
        :func:`localize.bundle.read_registry_history`)."""
        return read_registry_history(self._floor(site, floor))

    def writable_history(self, site: str, floor: str) -> list[dict]:
        """:meth:`history`, refused when it has lost versions (a RegistryError, see
        :func:`localize.bundle.history_lost`): a writer would number a new version as an old
        one, or move the pointer back, taking the newest listed for the newest published."""
        base = self._floor(site, floor)
        history = read_registry_history(base)
        try:
            pointer = read_registry_pointer(base)
        except RegistryError:
            pointer = None  # a damaged pointer: repaired by pointing it at a version
        lost = history_lost(base, history, pointer)
        if lost:
            raise RegistryError(lost)
        return history

    def current(self, site: str, floor: str, history: list[dict] | None = None
                ) -> dict | None:
        """The current version's pointer ``{"bundle_id", "seq"}``, None before any; a
        RegistryError when it is no entry of the history (``history``: as :meth:`history`
        read it already) or its version folder is missing
        (:func:`localize.bundle.registry_current`)."""
        pointer = self._pointer(site, floor, history)
        return None if pointer is None else {k: pointer[k] for k in ("bundle_id", "seq")}

    def _pointer(self, site: str, floor: str, history: list[dict] | None = None
                 ) -> dict | None:
        """:meth:`current`'s pointer as ``CURRENT`` holds it (with ``rolled_back_from``
        after a rollback), read and checked once."""
        found = registry_current(self._floor(site, floor), history)
        return None if found is None else found[1]

    def _withdrawn(self, site: str, floor: str) -> int:
        """The newest version a rollback withdrew (``CURRENT``'s ``rolled_back_from``) of a
        pointer that is no entry of the history, 0 when none is (or the pointer cannot be
        read: it is repaired as a rollback)."""
        try:
            pointer = read_registry_pointer(self._floor(site, floor))
        except RegistryError:
            return 0
        return 0 if pointer is None else pointer.get("rolled_back_from", 0)

    def open(self, site: str, floor: str, bundle_id: str | None = None) -> MapBundle:
        """Load (and verify) the current version, or a given one."""
        if bundle_id is None:
            cur = self.current(site, floor)
            if cur is None:
                raise RegistryError(f"{self.root}: no bundle published for {site}/{floor}")
            bundle_id = cur["bundle_id"]
        path = self._floor(site, floor) / "versions" / safe_name(bundle_id)
        if not path.is_dir():
            raise RegistryError(f"{self.root}: {site}/{floor} has no version {bundle_id}")
        return load_bundle(path)

    def list(self) -> list[dict]:
        """Every (site, floor, version): ``{"site", "floor", "seq", "bundle_id", "current",
        "problem"}``. A floor whose pointer cannot be trusted lists its versions with none
        current and the reason in ``problem``; one whose ``history.json`` cannot be read, or
        lists no version while the floor has a pointer, is one row with ``seq`` and
        ``bundle_id`` None and the reason. The other floors list as
        usual (``problem`` None)."""
        out = []
        for site_dir in sorted(p for p in self.root.iterdir() if p.is_dir()) \
                if self.root.exists() else []:
            for floor_dir in sorted(p for p in site_dir.iterdir() if p.is_dir()):
                where = {"site": site_dir.name, "floor": floor_dir.name}
                history, cur, problem = [], {}, None
                try:  # the pointer before the history, as a publish writes them in the
                    # other order: one landing between the two reads is not taken for damage
                    cur = self.current(site_dir.name, floor_dir.name) or {}
                except RegistryError as err:
                    problem = str(err)
                try:
                    history = self.history(site_dir.name, floor_dir.name)
                except RegistryError as err:  # said by current() too when there is a pointer
                    problem = problem or str(err)
                out += [{**where, **h, "current": h["bundle_id"] == cur.get("bundle_id"),
                         "problem": problem} for h in history] or (
                    [{**where, "seq": None, "bundle_id": None, "current": False,
                      "problem": problem}] if problem else [])
        return out

    def publish(self, bundle_dir: str | os.PathLike, *, make_current: bool = True) -> dict:
        """Copy a verified bundle in as a new version (a version already present is reused;
        one whose copy fails its checks is replaced by this intact one, and ``"repaired":
        True`` is added to the result) and, by default, make it current. Returns
        ``{"bundle_id", "seq"}``."""
        bundle = load_bundle(bundle_dir)  # verify before anything is copied
        source = bundle.path  # the bundle itself, also when bundle_dir is a registry floor
        site = bundle.site_id  # strings: load_bundle checked them
        floor = SITE_BUNDLE if bundle.manifest["kind"] == "site" else bundle.manifest["floor_name"]
        with self._writing(site, floor) as base:
            history = self.writable_history(site, floor)  # writers hold the lock: it stays so
            target = base / "versions" / bundle.bundle_id
            damaged = target.exists() and _damaged(target)
            if not target.exists() or damaged:
                # a damaged copy of this very bundle (its id is its content's hash) is replaced
                # by the intact one given: publishing it again is the repair
                with atomic_directory(target, overwrite=True, crash_prefix="registry") as tmp:
                    for src in sorted(source.rglob("*")):
                        rel = src.relative_to(source)
                        if src.is_dir():
                            (tmp / rel).mkdir(parents=True, exist_ok=True)
                        else:
                            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
                            shutil.copyfile(src, tmp / rel)
                # the copy is intact, as the bundle given was: load_bundle raises what is not
                if load_bundle(target).bundle_id != target.name:
                    raise BundleIntegrityError(f"{target}: holds another bundle than "
                                               f"{target.name}")
            crash_point("registry:after-copy")
            entry = next((h for h in history if h["bundle_id"] == bundle.bundle_id), None)
            published_before = entry is not None
            if entry is None:
                entry = {"seq": (history[-1]["seq"] + 1) if history else 1,
                         "bundle_id": bundle.bundle_id}
                history.append(entry)
                atomic_write_bytes(base / "history.json", json.dumps(history, indent=1).encode(),
                                   overwrite=True)
            crash_point("registry:after-history")
            if make_current:
                self._point(site, floor, bundle.bundle_id, allow_rollback=False, verify=False,
                            history=history, refuse_withdrawn=published_before)
        return {**entry, "repaired": True} if damaged else entry

    def set_current(self, site: str, floor: str, bundle_id: str, *,
                    allow_rollback: bool = False) -> None:
        """Point ``CURRENT`` at a published version (verified first). Moving to an older
        sequence number is a rollback and is refused unless ``allow_rollback``."""
        if not self._floor(site, floor).is_dir():
            raise RegistryError(f"{self.root}: nothing published for {site}/{floor}")
        with self._writing(site, floor):
            self._point(site, floor, bundle_id, allow_rollback=allow_rollback, verify=True)

    def _point(self, site: str, floor: str, bundle_id: str, *, allow_rollback: bool,
               verify: bool, history: list[dict] | None = None,
               refuse_withdrawn: bool = False) -> None:
        """``set_current`` under the writer lock; ``verify=False`` for the version ``publish``
        has just verified, and its ``history`` as it has just written it (None: read it).
        ``refuse_withdrawn`` (a publish of a version published before): a
        :class:`WithdrawnVersion` when it is newer than the current one and a rollback moved
        the pointer back from it (the pointer's ``rolled_back_from``); a publish that crashed
        before pointing at it is finished, and a damaged pointer repaired."""
        if history is None:
            history = self.writable_history(site, floor)
        entry = next((h for h in history if h["bundle_id"] == bundle_id), None)
        if entry is None:
            raise RegistryError(f"{site}/{floor}: version {bundle_id} is not published")
        try:
            cur = self._pointer(site, floor, history)
            withdrawn = 0 if cur is None else cur.get("rolled_back_from", 0)
            known = True
        except RegistryError:
            # a damaged or dangling pointer is repaired by pointing it at a version; which one
            # was current is unknown, so anything but the newest counts as a rollback
            cur, known = {"seq": max(h["seq"] for h in history)}, False
            withdrawn = self._withdrawn(site, floor)
        if refuse_withdrawn and known and cur is not None and \
                cur["seq"] < entry["seq"] <= withdrawn:
            raise WithdrawnVersion(f"{site}/{floor}", bundle_id, seq=entry["seq"],
                                   current_seq=cur["seq"])
        if cur is not None and entry["seq"] < cur["seq"] and not allow_rollback:
            raise RollbackRefused(f"{site}/{floor}", bundle_id, seq=entry["seq"],
                                  current_seq=cur["seq"], current_known=known)
        if verify:
            load_bundle(self._floor(site, floor) / "versions" / bundle_id)  # intact, or refused
        pointer = {"bundle_id": bundle_id, "seq": entry["seq"]}
        # the versions a rollback left stay withdrawn until one of them is chosen again: a
        # publish of the same bytes (a nightly build) does not make them current
        withdrawn = max(cur["seq"] if cur is not None and entry["seq"] < cur["seq"] else 0,
                        withdrawn)
        if withdrawn > entry["seq"]:
            pointer["rolled_back_from"] = withdrawn
        atomic_write_bytes(self._floor(site, floor) / "CURRENT", json.dumps(pointer).encode(),
                           overwrite=True)
