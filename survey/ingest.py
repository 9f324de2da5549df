"""Ingest survey files (real-format traces and walk plans) into a :class:`SurveyStore`.

Pure orchestration: find inputs, skip what the store already holds (same sha256), parse the
rest in batches (optionally in worker processes, each writing its own part files), and commit
the catalog once at the end. Returns an :class:`IngestSummary` that accounts for every line.
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from .errors import StoreError, SurveyFormatError
from .publish import crash_point
from .regular_files import path_list
from .store import IngestOutcome, SurveyStore, catalog_row, write_parts
from .trace_bytes import trace_file_sha256
from .trace_format import n_dropped
from .trace_reader import BATCH_BYTES, ReadFailure, find_trace_files, iter_traces, \
    trace_id_from_path
from .walkline import PlanWalk, WalkLogs, identity_sha256, is_walk_plan, plan_walks


@dataclass
class IngestSummary:
    """Totals of one ingest run."""

    outcomes: list[IngestOutcome] = field(default_factory=list)
    rows: dict[str, int] = field(default_factory=Counter)  # traces, samples, scans, ...
    skipped: dict[str, int] = field(default_factory=Counter)  # undocumented types
    bad: dict[str, int] = field(default_factory=Counter)  # bad lines by reason
    dropped: dict[str, int] = field(default_factory=Counter)
    messages: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[IngestOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    def status_counts(self) -> dict[str, int]:
        return dict(Counter(o.status for o in self.outcomes))

    def __repr__(self) -> str:  # the totals, not every outcome and message
        return (f"IngestSummary(files={self.status_counts()}, rows={dict(self.rows)}, "
                f"bad={sum(self.bad.values())}, skipped={sum(self.skipped.values())}, "
                f"dropped={n_dropped(self.dropped)})")

    def add_row(self, row: dict, max_messages: int = 20) -> None:
        import json

        self.rows["traces"] += 1
        for key in ("n_lines", "n_sensor_rows", "n_scans", "n_wifi_rows", "n_ble_rows",
                    "n_waypoints"):
            self.rows[key[2:]] += int(row[key])
        for name, target in (("skipped_json", self.skipped), ("bad_json", self.bad),
                             ("dropped_json", self.dropped)):
            for k, v in json.loads(row[name]).items():
                target[k] += v
        room = max_messages - len(self.messages)
        if room > 0:
            self.messages.extend(json.loads(row["messages_json"])[:room])


def find_inputs(paths: str | os.PathLike | Iterable[str | os.PathLike]
                ) -> tuple[list[Path], list[Path]]:
    """Split inputs into trace files and walk plans, searching folders. In folders, GeoJSON files
    that are not walk plans (floor plans, planned routes) are ignored; named explicitly, a
    ``.geojson`` file must be a walk plan."""
    traces, plans = [], []
    for p in map(Path, path_list(paths)):
        if p.is_dir():
            plans.extend(q for q in sorted(p.rglob("*.geojson")) if is_walk_plan(q))
            traces.extend(find_trace_files([p]))
        elif p.name.endswith(".geojson"):
            if not p.exists():
                raise SurveyFormatError("no such file", path=str(p), reason="missing")
            plans.append(p)
        else:
            traces.extend(find_trace_files([p]))
    return sorted(set(traces)), sorted(set(plans))


def _parse_and_write(root: str, paths: list[str], shas: list[str], sizes: list[int],
                     floors: list[str | None], strict: bool, batch_bytes: int,
                     on_file: Callable[[], None] | None = None
                     ) -> list[tuple[str, dict | None, str]]:
    """Worker: parse traces, write their part files; returns (path, catalog row, error).
    ``floors`` are the files' floor defaults (:func:`ingest`'s ``floor_names``). ``on_file``
    is called as each file is through (in this process only: progress)."""
    crash_point("ingest:worker")
    out = []
    info = {p: (s, n, f) for p, s, n, f in zip(paths, shas, sizes, floors)}
    for item in iter_traces(paths, strict=strict, batch_bytes=batch_bytes):
        if isinstance(item, ReadFailure):
            out.append((item.path, None, str(item.error)))
        else:
            sha, size, floor = info[item.report.path]
            row = catalog_row(item, source_path=item.report.path, sha256=sha, size_bytes=size,
                              floor_default=floor)
            write_parts(Path(root), item, row)
            out.append((item.report.path, row, ""))
        if on_file:
            on_file()
    return out


def ingest(paths: str | os.PathLike | Iterable[str | os.PathLike], store: str | os.PathLike | SurveyStore, *,
           strict: bool = False, workers: int = 1, batch_bytes: int = BATCH_BYTES,
           progress: Callable[[int, int], None] | None = None,
           floor_names: Mapping[str | os.PathLike, str] | None = None) -> IngestSummary:
    """Ingest trace files, folders and walk plans into ``store`` (created if missing).

    Parameters
    ----------
    paths : iterable of path-like
        Files (``.txt``, ``.txt.gz``, walk plans ``.geojson``) and folders to search.
    store : path-like or SurveyStore
        The store folder.
    strict : bool
        Stop at the first bad line or file without any trace line (raises
        :class:`SurveyFormatError`); nothing of this run is committed then, the store keeps its
        previous state, and a store this call created is removed. Otherwise such a file is a
        ``failed`` outcome with its reason (and a store this call created is removed when
        every file failed).
    workers : int
        Worker processes parsing in parallel (1 = in this process).
    progress : callable(done, total), optional
        Called after each file.
    floor_names : mapping, optional
        Input (one of ``paths``) -> the floor of its walks whose header names none (neither a
        floor name nor an id), e.g. the name of the floor folder they are in; such walks are
        otherwise stored under the floor ``unknown_floor``. A walk the store already holds
        keeps the floor it was stored under.

    Returns
    -------
    IngestSummary
    """
    paths = path_list(paths)
    trace_files, plans = find_inputs(paths)
    if not trace_files and not plans:
        raise SurveyFormatError("no trace files (.txt, .txt.gz) or walk plans (.geojson) found",
                                path=", ".join(map(str, paths)), reason="no-input")
    given = None if isinstance(store, SurveyStore) else Path(store)
    # a new store: no folder yet, or an empty one (which itself stays)
    created = given is not None and (not given.exists() or (
        given.is_dir() and not any(given.iterdir())))
    empty_folder = created and given.exists()
    store = store if isinstance(store, SurveyStore) else SurveyStore.create(store)

    def remove_if_unused() -> None:
        """A store this call made and never committed to leaves nothing behind (one that got
        a catalog, from this call or a concurrent one, stays)."""
        if created and not (store.root / "catalog.parquet").exists():
            for child in (list(store.root.iterdir()) if empty_folder else [store.root]):
                if child.is_dir():
                    shutil.rmtree(child, ignore_errors=True)
                else:
                    child.unlink(missing_ok=True)

    try:
        summary = _ingest_files(store, trace_files, plans, strict, workers, batch_bytes,
                                progress, _floor_defaults(floor_names or {}))
    except BaseException:
        remove_if_unused()
        raise
    remove_if_unused()  # every file failed (lenient): no empty store to mistake for one
    return summary


def _floor_defaults(floor_names: Mapping[str | os.PathLike, str]
                    ) -> Callable[[Path], str | None]:
    """A file's floor default: that of the input in ``floor_names`` it is, or lies under
    (the deepest such input; paths compared absolute, links not followed, as
    :func:`find_inputs` finds them)."""
    roots = sorted(((Path(os.path.abspath(p)), name) for p, name in floor_names.items()),
                   key=lambda item: -len(item[0].parts))

    def floor_of(path: Path) -> str | None:
        path = Path(os.path.abspath(path))
        return next((name for root, name in roots if path.is_relative_to(root)), None)

    return floor_of


def _ingest_files(store: SurveyStore, trace_files: list[Path], plans: list[Path], strict: bool,
                  workers: int, batch_bytes: int,
                  progress: Callable[[int, int], None] | None,
                  floor_of: Callable[[Path], str | None]) -> IngestSummary:
    summary = IngestSummary()
    total = len(trace_files) + len(plans)
    done = 0

    def tick(n: int = 1) -> None:
        nonlocal done
        done += n
        if progress:
            progress(done, total)

    first_of: dict[str, str] = {}   # trace id -> the input that gave it in this run

    def second_input(path: str, trace_id: str) -> bool:
        """Whether an earlier input of this run gave ``trace_id`` (then ``path`` fails: one
        trace id, one input)."""
        if trace_id not in first_of:
            first_of[trace_id] = path
            return False
        err = SurveyFormatError(f"trace id {trace_id!r} also comes from {first_of[trace_id]}; "
                                "give one input per trace id", path=path,
                                reason="duplicate_id")
        if strict:
            raise err
        summary.outcomes.append(IngestOutcome(path, trace_id, "failed", str(err)))
        return True

    with store.writer() as w:
        todo: list[tuple[str, str, int, str | None]] = []  # path, sha, size, floor default
        todo_sha: dict[str, str] = {}   # content hash -> trace id, of this run's files
        # duplicates, checked again before the commit: what they duplicate may be replaced
        # by this run (a file renamed, another put in its place); then they are ingested
        # (outcome index, id, sha, (path, size, floor default))
        deferred: list[tuple[int, str, str, tuple[str, int, str | None]]] = []
        for p in trace_files:
            tid = trace_id_from_path(p)
            if second_input(str(p), tid):
                tick()
                continue
            try:
                sha, size = trace_file_sha256(p)
            except SurveyFormatError as err:  # replaced or removed since it was listed
                if strict:
                    raise
                summary.outcomes.append(IngestOutcome(str(p), tid, "failed", str(err)))
                tick()
                continue
            floor = floor_of(p)
            known = w.known(tid, sha, floor)
            if not known and sha in todo_sha:   # the same content twice in this run
                known = IngestOutcome("", tid, "duplicate", f"same content as {todo_sha[sha]}")
            if known:
                known.path = str(p)
                if known.status == "duplicate":
                    deferred.append((len(summary.outcomes), tid, sha, (str(p), size, floor)))
                summary.outcomes.append(known)
                tick()
            else:
                todo_sha[sha] = tid
                todo.append((str(p), sha, size, floor))
        chunks = _chunks(todo, batch_bytes, max(1, workers))
        results = []
        if workers > 1 and len(chunks) > 1:
            # spawn, not fork: the parent already runs pyarrow's thread pool
            with ProcessPoolExecutor(max_workers=workers,
                                     mp_context=multiprocessing.get_context("spawn")) as pool:
                try:
                    futures = [pool.submit(_parse_and_write, str(store.root), *zip(*c), strict,
                                           batch_bytes) for c in chunks]
                    for fut in futures:
                        res = fut.result()
                        results.extend(res)
                        tick(len(res))
                except BrokenProcessPool as err:
                    pool.shutdown(cancel_futures=True)
                    raise StoreError(
                        f"{store.root}: an ingest worker process died (killed, or out of "
                        "memory); nothing of this run was committed, the store keeps its "
                        "previous state. Run again, with --workers 1 to use less memory"
                    ) from err
                except BaseException:  # a bad file (strict), Ctrl-C, SIGTERM: drop the queue
                    pool.shutdown(cancel_futures=True)
                    raise
        else:
            for c in chunks:  # progress file by file: one chunk holds every file
                results.extend(_parse_and_write(str(store.root), *map(list, zip(*c)), strict,
                                                batch_bytes, on_file=tick))
        summary.outcomes.extend(_add_results(w, summary, results))
        for plan in plans:
            try:
                walks = plan_walks(plan)
            except SurveyFormatError as err:
                if strict:
                    raise
                summary.outcomes.append(IngestOutcome(str(plan), plan.stem, "failed", str(err)))
                tick()
                continue
            floor = floor_of(plan)
            first = len(summary.outcomes)
            for walk in walks:
                try:  # one walk at a time: a missing or bad log fails its walk alone
                    logs = walk.log_bytes()
                except SurveyFormatError as err:
                    if strict:
                        raise
                    summary.outcomes.append(IngestOutcome(walk.where, walk.walk_id, "failed",
                                                          str(err)))
                    continue
                if second_input(logs.source, walk.walk_id):
                    continue
                identity = walk.identity(logs)
                sha = identity_sha256(identity)
                # unchanged: not parsed, as a trace file. (Never a "duplicate": a walk's
                # identity holds its own walk id, so no other walk shares its hash.)
                known = w.known(walk.walk_id, sha, floor)
                if known:
                    known.path = logs.source
                    summary.outcomes.append(known)
                    continue
                summary.outcomes.append(_parse_walk(w, summary, walk, logs, sha,
                                                    len(identity), floor, strict))
            for outcome in summary.outcomes[first:]:
                outcome.plan = str(plan)
            tick()
        # to a fixed point: ingesting one can make another's original go (walks renumbered:
        # w2 -> w1, w3 -> w2, ...)
        while ready := [d for d in deferred if not w.known(d[1], d[2])]:
            index, tid, sha, item = ready[0]
            deferred.remove(ready[0])
            path, size, floor = item  # parse it after all (rare: no progress tick)
            res = _parse_and_write(str(store.root), [path], [sha], [size], [floor], strict,
                                   batch_bytes)
            summary.outcomes[index] = _add_results(w, summary, res)[0]
        for index, tid, sha, _ in deferred:  # what each duplicates in the end
            summary.outcomes[index].detail = w.known(tid, sha).detail
    return summary


def _add_results(w, summary: IngestSummary, results: list[tuple[str, dict | None, str]]
                 ) -> list[IngestOutcome]:
    """Register parsed trace files (their part files written) with the writer ``w``; their
    rows are added to ``summary``, their outcomes returned."""
    out = []
    for path, row, error in results:
        if row is None:
            out.append(IngestOutcome(path, trace_id_from_path(path), "failed", error))
        else:
            out.append(_outcome(w, path, row))
            summary.add_row(row)
    return out


def _outcome(w, path: str, row: dict) -> IngestOutcome:
    """Register a parsed walk's catalog ``row`` with the writer ``w``: its outcome, saying
    what it replaced when it replaced a stored walk of another file (``changed``: another
    file of the walk's name, maybe a cut copy)."""
    was = w.stored_source(row["trace_id"])
    status = w.add_row(row)
    other = status == "changed" and was is not None and was[0] != path
    return IngestOutcome(path, row["trace_id"], status,
                         f"replaced {was[0]}, {was[1]} lines" if other else "")


def _parse_walk(w, summary: IngestSummary, walk: PlanWalk, logs: WalkLogs, sha: str,
                size: int, floor_default: str | None, strict: bool) -> IngestOutcome:
    """Parse one walk of a walk plan (its logs as read) and store it with the writer ``w``;
    its row is added to ``summary``, its outcome returned (failed when a log cannot be
    parsed; raised in strict mode)."""
    source = logs.source
    try:
        trace = walk.parse(logs, strict=strict)
    except SurveyFormatError as err:
        if strict:
            raise
        return IngestOutcome(walk.where, walk.walk_id, "failed", str(err))
    row = catalog_row(trace, source_path=source, sha256=sha, size_bytes=size,
                      source_format="walkline", floor_default=floor_default)
    write_parts(w.root, trace, row)
    summary.add_row(row)
    return _outcome(w, source, row)


def _chunks(todo: list[tuple], batch_bytes: int, workers: int) -> list[list[tuple]]:
    """Split files ``(path, sha, size, ...)`` into about ``2 * workers`` chunks (by compressed
    size) for the pool."""
    if not todo:
        return []
    if workers == 1:
        return [todo]
    total = sum(t[2] for t in todo)
    target = max(total / (2 * workers), 1)
    chunks, cur, size = [], [], 0
    for item in todo:
        cur.append(item)
        size += item[2]
        if size >= target:
            chunks.append(cur)
            cur, size = [], 0
    if cur:
        chunks.append(cur)
    return chunks
