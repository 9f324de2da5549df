"""The normalized survey store: a Parquet dataset of ingested walks, partitioned by site and floor.

Layout (see ``docs/survey_store.md`` for every column)::

    STORE/
      store.json                      format name and schema version
      catalog.parquet                 one row per trace: the commit point of the store
      sensors/site=S/floor=F/<trace_id>-<sha12>.parquet
      wifi/...   ble/...   waypoints/...

Part files are content-addressed by the source file's sha256, so a new version of a trace never
overwrites the live one. Ingest writes part files first, then replaces ``catalog.parquet``
atomically; readers only open the part files the catalog names. A crash therefore leaves either
the old store or the new one, plus unreferenced part files that the next ingest removes.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from localize.names import floor_key, safe_component

from .errors import StoreError

try:
    import fcntl
except ImportError:  # Windows: the pid in the lock file alone keeps writers apart
    fcntl = None  # type: ignore[assignment]
from .publish import TMP_PREFIX, atomic_write_bytes, crash_point, file_sha256, fsync_dir, \
    remove_stale_temporaries
from .regular_files import read_regular
from .trace_format import BLE_COLUMNS, SENSOR_COLUMNS, WAYPOINT_COLUMNS, WIFI_COLUMNS, Trace

STORE_FORMAT = "indoormap-survey-store"
#: Version 2 added ``parts_json`` (each part file's sha256, size and rows) to the catalog.
#: Version 1 stores are still read (their parts are checked by row counts and trace id only)
#: and become version 2 at their next commit.
SCHEMA_VERSION = 2
READABLE_SCHEMA_VERSIONS = (1, 2)
TABLES = ("sensors", "wifi", "ble", "waypoints")
#: The columns of each part file (besides ``trace_id``) and the catalog column counting its rows.
TABLE_COLUMNS = {"sensors": SENSOR_COLUMNS, "wifi": WIFI_COLUMNS, "ble": BLE_COLUMNS,
                 "waypoints": WAYPOINT_COLUMNS}
ROW_COUNT_COLUMNS = {"sensors": "n_sensor_rows", "wifi": "n_wifi_rows", "ble": "n_ble_rows",
                     "waypoints": "n_waypoints"}

CATALOG_COLUMNS = {
    "trace_id": "str", "source_path": "str", "sha256": "str", "size_bytes": "int64",
    "source_format": "str", "site": "str", "floor": "str", "site_id": "str", "site_name": "str",
    "floor_id": "str", "floor_name": "str", "device_brand": "str", "device_model": "str",
    "start_ms": "Int64", "end_ms": "Int64", "n_lines": "int64", "n_header_lines": "int64",
    "n_sensor_rows": "int64", "n_wifi_rows": "int64", "n_scans": "int64", "n_ble_rows": "int64",
    "n_waypoints": "int64", "n_skipped_lines": "int64", "n_bad_lines": "int64",
    "n_dropped_rows": "int64", "records_json": "str", "skipped_json": "str", "bad_json": "str",
    "dropped_json": "str", "messages_json": "str", "header_json": "str", "parts_json": "str",
}


def remove_empty_folders(base: Path) -> None:
    """Remove the folders under ``base`` left empty (partitions whose part files went),
    deepest first; a folder that still holds anything stays."""
    for d in sorted((q for q in base.rglob("*") if q.is_dir()), reverse=True):
        with contextlib.suppress(OSError):
            d.rmdir()


def part_path(table: str, site: str, floor: str, trace_id: str, sha256: str) -> str:
    """Relative path of one trace's part file of ``table``. The trace id is made a safe file
    name (``[A-Za-z0-9_.-]``, at most 80 characters; the content hash keeps it apart from
    others): a walk plan's ``walk_id`` or a long file name cannot leave the store or exceed
    the file system's name limit."""
    name = safe_component(trace_id, "trace")
    return f"{table}/site={site}/floor={floor}/{name}-{sha256[:12]}.parquet"


def catalog_row(trace: Trace, *, source_path: str, sha256: str, size_bytes: int,
                source_format: str = "trace", floor_default: str | None = None) -> dict:
    """The catalog row describing one parsed trace; its ``floor`` key is the header's floor
    name or id, else ``floor_default`` (the floor of the folder it came from, say), else
    ``unknown_floor``. The row's ``floor_name`` and ``floor_id`` are the header's."""
    h, r = trace.header, trace.report
    header = {k: v for k, v in vars(h).items() if k not in ("sensors",)}
    header["sensors"] = [vars(s) for s in h.sensors]
    return {
        "trace_id": trace.trace_id, "source_path": source_path, "sha256": sha256,
        "size_bytes": size_bytes, "source_format": source_format,
        "site": safe_component(h.site_id, "unknown_site"),
        "floor": floor_key(h.floor_name or h.floor_id or floor_default),
        "site_id": h.site_id or "", "site_name": h.site_name or "",
        "floor_id": h.floor_id or "", "floor_name": h.floor_name or "",
        "device_brand": h.brand or "", "device_model": h.model or "",
        "start_ms": h.start_ms, "end_ms": h.end_ms, "n_lines": r.lines_total,
        "n_header_lines": r.header_lines, "n_sensor_rows": len(trace.sensors),
        "n_wifi_rows": len(trace.wifi), "n_scans": int(trace.wifi["scan_t_ms"].nunique()),
        "n_ble_rows": len(trace.ble), "n_waypoints": len(trace.waypoints),
        "n_skipped_lines": r.skipped_total, "n_bad_lines": r.bad_total,
        "n_dropped_rows": r.n_dropped(),
        "records_json": json.dumps(r.records, sort_keys=True),
        "skipped_json": json.dumps(r.skipped, sort_keys=True),
        "bad_json": json.dumps(r.bad, sort_keys=True),
        "dropped_json": json.dumps(r.dropped, sort_keys=True),
        "messages_json": json.dumps(r.messages),
        "header_json": json.dumps(header, sort_keys=True, default=str, allow_nan=True),
        "parts_json": "",  # set by write_parts
    }


def read_parquet_checked(path: Path, columns: list[str] | None = None, *,
                         what: str = "part file", expect: Mapping[str, Any] | None = None
                         ) -> pa.Table:
    """A store Parquet file with its page checksums verified; a :class:`StoreError` naming
    the file when it is missing, unreadable or corrupted.

    ``expect`` (``{"sha256", "size", "rows"}``, as :func:`part_record` gives and the catalogs
    keep): the file's bytes must hash to that, so a flip in the Parquet footer (which the page
    checksums do not cover) or a part file swapped for another is refused too."""
    try:
        if expect is None:
            return pq.read_table(path, columns=columns, page_checksum_verification=True)
        # Read into Arrow's own memory, not a Python ``bytes``: the reader's worker threads
        # may drop the last reference to its buffer after the call returns, and releasing a
        # Python object there needs the GIL, which at interpreter exit aborted the process
        # ("terminate called without an active exception", ``store verify`` under load).
        with pa.OSFile(str(path)) as f:
            data = f.read_buffer()
        sha = hashlib.sha256(memoryview(data)).hexdigest()
        if data.size != expect["size"] or sha != expect["sha256"]:
            raise StoreError(f"{path}: {what} changed since it was written ({data.size} bytes, "
                             f"sha256 {sha[:12]}; the catalog has {expect['size']} bytes, "
                             f"{expect['sha256'][:12]})")
        table = pq.read_table(pa.BufferReader(data), columns=columns,
                              page_checksum_verification=True)
    except (OSError, pa.ArrowException) as err:
        raise StoreError(f"{path}: missing, unreadable or corrupted {what} ({err})") from err
    if table.num_rows != expect["rows"]:
        raise StoreError(f"{path}: {what} has {table.num_rows} rows; the catalog has "
                         f"{expect['rows']}")
    return table


def part_record(data: bytes, rows: int) -> dict[str, Any]:
    """What a catalog keeps of a written part file: its sha256, size (bytes) and rows."""
    return {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data), "rows": int(rows)}


def files_match(paths: Mapping[str, Path], parts: Mapping[str, Any]) -> bool:
    """Whether every file of ``paths`` (table -> path) is there with the size and sha256
    that ``parts`` (table -> :func:`part_record`) recorded for it."""
    for name, path in paths.items():
        try:
            if (path.stat().st_size != parts[name]["size"]
                    or file_sha256(path) != parts[name]["sha256"]):
                return False
        except (OSError, KeyError):
            return False
    return True


def check_columns(table: pa.Table, expected: Sequence[str], path: Path, what: str) -> None:
    """A :class:`StoreError` naming ``path`` unless ``table`` has every ``expected`` column."""
    missing = [c for c in expected if c not in table.column_names]
    if missing:
        raise StoreError(f"{path}: {what} lacks columns {missing} (damaged or not written "
                         "by indoormap)")


def _parquet_bytes(table: pa.Table) -> bytes:
    """Parquet with page checksums; dictionary encoding only for text (floats gain nothing)."""
    text = [f.name for f in table.schema
            if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)
            or pa.types.is_dictionary(f.type)]
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd", use_dictionary=text,
                   write_page_checksum=True, write_statistics=True)
    return sink.getvalue().to_pybytes()


def trace_tables(trace: Trace) -> dict[str, pa.Table]:
    """The four store tables of a trace as Arrow tables, each with a ``trace_id`` column."""
    out = {}
    for name in TABLES:
        frame = getattr(trace, name)
        ids = pa.DictionaryArray.from_arrays(pa.array(np.zeros(len(frame), dtype=np.int32)),
                                             pa.array([trace.trace_id]))
        columns = {"trace_id": ids, **{c: _arrow_column(frame[c]) for c in frame.columns}}
        out[name] = pa.table(columns)
    return out


def _arrow_column(col: pd.Series) -> pa.Array:
    """A pandas column as Arrow without pandas metadata (numbers zero-copy, category as
    dictionary, text as string)."""
    if isinstance(col.dtype, pd.CategoricalDtype):
        return pa.DictionaryArray.from_arrays(pa.array(col.cat.codes.to_numpy().astype(np.int32)),
                                              pa.array(list(col.cat.categories), pa.string()))
    if col.dtype.kind in "iufb":
        return pa.array(col.to_numpy())
    if isinstance(col.dtype, pd.StringDtype) or col.dtype == object:
        return pa.array(col.array, type=pa.string(), from_pandas=True)
    return pa.array(col, from_pandas=True)  # nullable extension types (e.g. Int64)


def _frame(table: pa.Table) -> pd.DataFrame:
    frame = table.to_pandas()
    frame["trace_id"] = frame["trace_id"].astype("str")
    return frame


def write_parts(root: Path, trace: Trace, row: dict) -> None:
    """Write a trace's part files into the store, each atomically and fsynced, and record
    their sha256, size and rows in ``row["parts_json"]``; their folders are fsynced by the
    commit that makes them live. Idempotent."""
    parts = {}
    for name, table in trace_tables(trace).items():
        rel = part_path(name, row["site"], row["floor"], row["trace_id"], row["sha256"])
        data = _parquet_bytes(table)
        atomic_write_bytes(root / rel, data, overwrite=True, sync_dir=False)
        parts[name] = part_record(data, table.num_rows)
    row["parts_json"] = json.dumps(parts, sort_keys=True)


@dataclass
class IngestOutcome:
    """What happened to one input file."""

    path: str
    trace_id: str
    status: str  # "new", "changed", "repaired", "unchanged", "duplicate", "failed"
    detail: str = ""
    plan: str = ""  #: a walk plan's walk: the plan file, as found (``path`` is its log's)


def _write_meta(root: Path) -> None:
    """Write ``store.json`` (format and this version's schema number), atomically."""
    meta = {"format": STORE_FORMAT, "schema_version": SCHEMA_VERSION}
    atomic_write_bytes(root / "store.json", json.dumps(meta, indent=2).encode(), overwrite=True)


class SurveyStore:
    """A survey store folder. Open an existing one with :meth:`open`, make one with
    :meth:`create`; write through :meth:`writer` (one writer at a time, enforced by a lock)."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)

    def __repr__(self) -> str:  # where, and what it holds by site and floor
        try:
            counts = self.catalog().groupby(["site", "floor"], observed=True).size()
            held = ", ".join(f"{s}/{f} {n}" for (s, f), n in counts.items()) or "none"
        except Exception as err:  # noqa: BLE001  a repr does not raise (a damaged catalog)
            held = f"unreadable: {err}"
        return f"SurveyStore({str(self.root)!r}, walks: {held})"

    # ---- opening ----------------------------------------------------------------------------

    @classmethod
    def create(cls, root: str | os.PathLike) -> SurveyStore:
        """Open ``root`` as a store, creating an empty one if the folder is empty or missing."""
        root = Path(root)
        if root.exists() and any(root.iterdir()) and not (root / "store.json").exists():
            raise StoreError(f"{root}: exists and is not a survey store (no store.json)")
        root.mkdir(parents=True, exist_ok=True)
        if not (root / "store.json").exists():
            _write_meta(root)
        return cls.open(root)

    @classmethod
    def open(cls, root: str | os.PathLike) -> SurveyStore:
        """The survey store at ``root`` (as ``indoormap ingest --store`` made it).

        Raises
        ------
        StoreError
            No ``store.json`` there, or one unreadable, of another format or of a schema
            version this indoormap does not read.
        """
        root = Path(root)
        meta_path = root / "store.json"
        if not meta_path.exists():
            raise StoreError(f"{root}: not a survey store (missing store.json); "
                             "create one with `indoormap ingest ... --store DIR`")
        try:
            meta = _read_store_json(meta_path)
        except (OSError, ValueError) as err:
            raise StoreError(f"{meta_path}: unreadable ({err})") from err
        if not isinstance(meta, dict):
            raise StoreError(f"{meta_path}: not a JSON object (format and schema_version)")
        if meta.get("format") != STORE_FORMAT:
            raise StoreError(f"{meta_path}: format {meta.get('format')!r} is not {STORE_FORMAT}")
        if meta.get("schema_version") not in READABLE_SCHEMA_VERSIONS:
            raise StoreError(f"{meta_path}: schema version {meta.get('schema_version')!r} is not "
                             f"supported (this indoormap reads versions "
                             f"{', '.join(map(str, READABLE_SCHEMA_VERSIONS))})")
        return cls(root)

    def _finish_upgrade(self) -> None:
        """Mark the store version 2 if a writer killed between writing a version 2 catalog
        (with ``parts_json``) and :meth:`upgrade_schema` left ``store.json`` at version 1
        (an older indoormap would otherwise drop the part hashes at its next commit)."""
        path = self.root / "catalog.parquet"
        if self.schema_version() < SCHEMA_VERSION and path.exists():
            try:
                names = pq.read_schema(path).names
            except (OSError, pa.ArrowException):
                return  # a damaged catalog: the writer's own read reports it
            if "parts_json" in names:
                self.upgrade_schema()

    def upgrade_schema(self) -> None:
        """Mark a version 1 store as version 2 once its catalog has been written by this
        version (rows of version 1 keep an empty ``parts_json``)."""
        if self.schema_version() != SCHEMA_VERSION:
            _write_meta(self.root)

    # ---- reading ----------------------------------------------------------------------------

    def catalog(self) -> pd.DataFrame:
        """One row per ingested trace (columns in :data:`CATALOG_COLUMNS`), checked: every
        column present, one row per trace id, a 64-digit sha256 each."""
        path = self.root / "catalog.parquet"
        if not path.exists():
            # a store's first commit writes the catalog; processing comes after, so a processed
            # catalog without it means the catalog was lost, not that nothing was ingested
            if (self.root / "processed" / "catalog.parquet").exists():
                raise StoreError(f"{path}: missing, but the store has processed walks: "
                                 "damaged store (ingest the traces into a new store)")
            return pd.DataFrame({c: pd.Series([], dtype=t) for c, t in CATALOG_COLUMNS.items()})
        table = read_parquet_checked(path, what="catalog")
        if "parts_json" not in table.column_names:
            if self.schema_version() >= 2:  # a damaged footer must not turn the hashes off
                raise StoreError(f"{path}: damaged catalog: no parts_json column in a schema "
                                 "version 2 store")
            table = table.append_column("parts_json", pa.array([""] * table.num_rows))
        check_columns(table, list(CATALOG_COLUMNS), path, "catalog")
        cat = table.to_pandas()
        problems = []
        counts = cat["trace_id"].value_counts()
        if (counts > 1).any():
            problems.append(f"trace id {counts.index[0]!r} has {counts.iloc[0]} rows")
        bad_sha = ~cat["sha256"].astype(str).str.fullmatch(r"[0-9a-f]{64}")
        if bad_sha.any():
            problems.append(f"trace {cat['trace_id'][bad_sha].iloc[0]!r} has no valid sha256")
        if problems:
            raise StoreError(f"{path}: damaged catalog: {'; '.join(problems)}")
        return cat

    def traces(self, site: str | None = None, floor: str | None = None) -> pd.DataFrame:
        """Catalog rows, optionally of one site and/or floor (partition names or ids)."""
        cat = self.catalog()
        if site is not None:
            cat = cat[(cat["site"] == site) | (cat["site_id"] == site)]
        if floor is not None:
            cat = cat[(cat["floor"] == floor) | (cat["floor_id"] == floor)
                      | (cat["floor_name"] == floor)]
        return cat.reset_index(drop=True)

    def table(self, name: str, *, site: str | None = None, floor: str | None = None,
              trace_ids: str | list[str] | None = None) -> pd.DataFrame:
        """Rows of one table (``sensors``, ``wifi``, ``ble``, ``waypoints``) for the selected
        traces (``trace_ids``: one id or a list), with a ``trace_id`` column, in catalog
        order then time order. The processed tables (positions and calibrated field of every
        sample, steps, legs, positioned scans) are read by
        :func:`survey.process_store.processed_table`."""
        if name not in TABLES:
            from .process_store import PROCESSED_TABLES

            hint = (f"; the processed {name!r} is read by survey.process_store."
                    f"processed_table(store, {name!r})" if name in PROCESSED_TABLES else "")
            raise StoreError(f"unknown table {name!r}; expected one of {TABLES}{hint}")
        cat = self.traces(site, floor)
        if trace_ids is not None:
            if isinstance(trace_ids, str):  # one id, not its characters
                trace_ids = [trace_ids]
            cat = cat[cat["trace_id"].isin(list(trace_ids))]
        parts = [self._read_part(name, row) for row in cat.itertuples(index=False)]
        if not parts:
            raise StoreError(f"{self.root}: no traces match site={site!r} floor={floor!r}"
                             + ("" if trace_ids is None else f" trace_ids={trace_ids!r}"))
        return _frame(pa.concat_tables(parts, promote_options="permissive"))

    def part(self, name: str, row: Any, columns: list[str] | None = None) -> pd.DataFrame:
        """Rows of one table for one trace, ``row`` being its catalog row (a named tuple or
        mapping with ``site``, ``floor``, ``trace_id``, ``sha256``), in time order. Reading walk
        by walk keeps memory bounded by the largest walk, not by the store."""
        if name not in TABLES:
            raise StoreError(f"unknown table {name!r}; expected one of {TABLES}")
        if isinstance(columns, str):  # one column, not its characters
            columns = [columns]
        if columns is not None:  # a typo is the caller's, not a damaged part file
            unknown = [c for c in columns if c != "trace_id" and c not in TABLE_COLUMNS[name]]
            if unknown:
                raise StoreError(f"the {name} table has no column {', '.join(map(repr, unknown))}"
                                 f"; it has {', '.join(TABLE_COLUMNS[name])}")
        return _frame(self._read_part(name, row, columns))

    def _read_part(self, name: str, row, columns: list[str] | None = None) -> pa.Table:
        """One part file, checked against its catalog row: sha256 and size (stores of schema
        version 2), rows, columns and trace id."""
        get = row.get if isinstance(row, Mapping) else lambda k: getattr(row, k)  # or a Series
        path = self.root / part_path(name, get("site"), get("floor"), get("trace_id"),
                                     get("sha256"))
        parts = json.loads(get("parts_json") or "{}")
        expect = parts.get(name)
        want = None if columns is None else ["trace_id", *[c for c in columns if c != "trace_id"]]
        table = read_parquet_checked(path, want, expect=expect)
        check_columns(table, want or ["trace_id", *TABLE_COLUMNS[name]], path, f"{name} part")
        rows = int(get(ROW_COUNT_COLUMNS[name]))
        ids = pc.unique(table.column("trace_id").cast(pa.string())).to_pylist()
        if table.num_rows != rows or (rows and ids != [get("trace_id")]):
            raise StoreError(f"{path}: holds {table.num_rows} rows of {ids[:3]}; the catalog has "
                             f"{rows} rows of {get('trace_id')!r} (a part file swapped or "
                             "damaged)")
        return table

    def verify(self, progress: Callable[[int, int], None] | None = None
               ) -> dict[str, str]:
        """Read every part file the catalog names, with all the checks a read makes; returns
        ``{trace_id: problem}`` of the traces that fail (empty: the store is whole)."""
        cat = self.catalog()
        problems = {}
        for i, row in enumerate(cat.itertuples(index=False)):
            try:
                for name in TABLES:
                    self._read_part(name, row)
            except StoreError as err:
                problems[row.trace_id] = str(err)
            if progress:
                progress(i + 1, len(cat))
        return problems

    def stray_files(self, catalog: pd.DataFrame | None = None) -> list[Path]:
        """Files under the part folders that ``catalog`` (default: the store's) does not name,
        or temporaries of crashed writes: what an interrupted ingest leaves (or a running one
        has not committed yet); the next writer deletes them
        (:meth:`_StoreWriter.collect_garbage`). A folder removed while listed is skipped."""
        catalog = self.catalog() if catalog is None else catalog
        live = {part_path(t, r.site, r.floor, r.trace_id, r.sha256)
                for r in catalog.itertuples(index=False) for t in TABLES}
        found = []
        for table in TABLES:
            for folder, _, names in os.walk(self.root / table):  # errors (gone): skipped
                for name in names:
                    p = Path(folder) / name
                    if name.startswith(TMP_PREFIX) or str(p.relative_to(self.root)) not in live:
                        found.append(p)
        return sorted(found)

    def schema_version(self) -> int:
        """The store's schema version (``store.json``, checked by :meth:`open`)."""
        try:
            return int(_read_store_json(self.root / "store.json")["schema_version"])
        except (OSError, ValueError, TypeError, KeyError) as err:
            raise StoreError(f"{self.root / 'store.json'}: unreadable ({err})") from err

    # ---- writing ----------------------------------------------------------------------------

    @contextlib.contextmanager
    def writer(self) -> Iterator[_StoreWriter]:
        """Exclusive write access: takes the lock, cleans leftovers of crashed ingests, and
        commits the catalog when the body completes. If the body raises, nothing is committed:
        the store keeps its previous catalog, and part files already written become garbage
        that the next writer removes."""
        lock = self.root / ".lock"
        fd = _take_lock(lock, self.root)
        try:
            self._finish_upgrade()
            w = _StoreWriter(self)
            w.collect_garbage()
            yield w
            w.commit()
        finally:
            lock.unlink(missing_ok=True)  # still ours: a waiting writer then sees a new file
            os.close(fd)


def _take_lock(lock: Path, root: Path) -> int:
    """Create and hold ``lock`` holding this process's pid; returns its descriptor. With
    ``fcntl`` the lock is an ``flock`` (released by the OS if the process dies; a file left by
    a dead writer is simply taken), checked to still be the file at ``lock`` after locking;
    without it, exclusive creation, and a file whose pid is gone is taken over."""
    if fcntl is not None:
        while True:
            fd = os.open(lock, os.O_CREAT | os.O_RDWR, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                pid = _read_pid(lock)
                raise StoreError(f"{root}: locked by running process "
                                 f"{pid if pid is not None else '(unknown pid)'}") from None
            try:
                ours = os.fstat(fd).st_ino == os.stat(lock).st_ino
            except FileNotFoundError:  # its holder removed it as we locked it
                ours = False
            if ours:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
    else:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            pid = _read_pid(lock)
            if pid is not None and _pid_alive(pid):
                raise StoreError(f"{root}: locked by running process {pid}") from None
            lock.unlink(missing_ok=True)  # stale lock of a crashed ingest
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    os.write(fd, str(os.getpid()).encode())
    return fd


def _read_store_json(path: Path) -> Any:
    """``store.json``'s content: a regular file of at most 1 MiB (a FIFO is not waited on)."""
    return json.loads(read_regular(path, 1024**2))


def _read_pid(path: Path) -> int | None:
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class _StoreWriter:
    """Adds traces to a store; the new catalog is written by :meth:`commit`."""

    def __init__(self, store: SurveyStore) -> None:
        self.store = store
        self.root = store.root
        self.cat = store.catalog()
        self.pending: dict[str, dict] = {}
        self.repairing: set[str] = set()  # stored traces whose part files are written again
        self.hashed: dict[str, str] = {}  # schema-1 rows checked now: trace id -> parts_json
        self._whole: dict[tuple[str, str], bool] = {}  # (trace id, sha256) -> parts whole

    def known(self, trace_id: str, sha256: str, floor_default: str | None = None
              ) -> IngestOutcome | None:
        """The outcome for a file that needs no work (same content already stored, whole),
        or None. Stored content that this run replaces (its trace id is pending with other
        content) does not count: a file is never a "duplicate" of content about to go, nor of
        a trace whose part files are damaged. A stored trace whose part files are missing or
        changed needs work (it is ``repaired``); one stored without part hashes (schema 1)
        gets them once its parts pass the read checks. A walk that records no floor, stored
        under another floor than ``floor_default`` (given: the floor its input is now said to
        be, :func:`catalog_row`), needs work too: it is stored again under that floor."""
        cat = self.cat
        leaving = [t for t, r in self.pending.items() if r["sha256"] != sha256]
        hit = cat[(cat["sha256"] == sha256) & ~cat["trace_id"].isin(leaving)]
        same = hit[hit["trace_id"] == trace_id]
        if len(same):
            row = same.iloc[0]
            if (floor_default is not None and not row["floor_name"] and not row["floor_id"]
                    and row["floor"] != floor_key(floor_default)):
                return None  # add_row: "changed"; its old parts are collected at the commit
            if self._parts_whole(row):
                return IngestOutcome("", trace_id, "unchanged")
            self.repairing.add(trace_id)
            return None
        pending = [t for t, r in self.pending.items() if r["sha256"] == sha256]
        whole = [r["trace_id"] for _, r in hit.iterrows() if self._parts_whole(r)]
        others = [t for t in [*whole, *pending] if t != trace_id]
        if others:
            return IngestOutcome("", trace_id, "duplicate", f"same content as {others[0]}")
        return None

    def _parts_whole(self, row: pd.Series) -> bool:
        """Whether every part file of a catalog row is there with its recorded sha256 (rows
        without hashes: passes the read checks, and then gets them at the commit). Hashed
        once per run and trace."""
        key = (row["trace_id"], row["sha256"])
        if key not in self._whole:
            self._whole[key] = self._check_parts(row)
        return self._whole[key]

    def _check_parts(self, row: pd.Series) -> bool:
        parts = json.loads(row["parts_json"] or "{}")
        paths = {name: self.root / part_path(name, row["site"], row["floor"], row["trace_id"],
                                             row["sha256"]) for name in TABLES}
        if not parts:
            try:
                rows = {name: self.store._read_part(name, row).num_rows for name in TABLES}
            except StoreError:
                return False
            self.hashed[row["trace_id"]] = json.dumps(
                {name: part_record(path.read_bytes(), rows[name]) for name, path in paths.items()},
                sort_keys=True)
            return True
        return files_match(paths, parts)

    def add_row(self, row: dict) -> str:
        """Register a trace whose part files are written; returns ``new``, ``changed`` or
        ``repaired`` (same content, its part files were missing or damaged)."""
        existed = (self.cat["trace_id"] == row["trace_id"]).any() or row["trace_id"] in \
            self.pending
        self.pending[row["trace_id"]] = row
        if row["trace_id"] in self.repairing:
            return "repaired"
        return "changed" if existed else "new"

    def stored_source(self, trace_id: str) -> tuple[str, int] | None:
        """The source file and line count the catalog holds for ``trace_id`` as committed,
        for an outcome that replaces it; None when it holds none."""
        old = self.cat[self.cat["trace_id"] == trace_id]
        if not len(old):
            return None
        return str(old["source_path"].iloc[0]), int(old["n_lines"].iloc[0])

    def commit(self) -> None:
        if not self.pending and not self.hashed:
            return
        for folder in {(self.root / part_path(t, r["site"], r["floor"], "x", "0")).parent
                       for r in self.pending.values() for t in TABLES}:
            fsync_dir(folder)  # the renames of the new part files are durable before the commit
        crash_point("ingest:before-catalog")
        keep = self.cat[~self.cat["trace_id"].isin(list(self.pending))].copy()
        hashed = keep["trace_id"].map(self.hashed)
        keep["parts_json"] = hashed.where(hashed.notna(), keep["parts_json"])
        new = pd.DataFrame(list(self.pending.values()))
        cat = pd.concat([keep, new], ignore_index=True) if len(keep) else new
        cat = cat.sort_values(["site", "floor", "trace_id"], kind="stable").reset_index(drop=True)
        cat = cat.astype(CATALOG_COLUMNS)[list(CATALOG_COLUMNS)]
        table = pa.Table.from_pandas(cat, preserve_index=False).replace_schema_metadata(None)
        atomic_write_bytes(self.root / "catalog.parquet", _parquet_bytes(table), overwrite=True)
        crash_point("ingest:after-catalog")
        self.store.upgrade_schema()
        self.cat = cat
        self.pending, self.hashed = {}, {}
        self.collect_garbage()

    def collect_garbage(self) -> int:
        """Delete part files the catalog does not name and temporaries of crashed writes."""
        removed = remove_stale_temporaries(self.root)
        for p in self.store.stray_files(self.cat):
            p.unlink()
            removed += 1
        for table in TABLES:
            base = self.root / table
            if not base.exists():
                continue
            remove_empty_folders(base)
        fsync_dir(self.root)
        return removed
