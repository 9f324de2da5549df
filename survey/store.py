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
import json
import os
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from .errors import StoreError

try:
    import fcntl
except ImportError:  # Windows: the pid in the lock file alone keeps writers apart
    fcntl = None  # type: ignore[assignment]
from .publish import TMP_PREFIX, atomic_write_bytes, crash_point, fsync_dir, \
    remove_stale_temporaries
from .trace_format import Trace

STORE_FORMAT = "indoormap-survey-store"
SCHEMA_VERSION = 1
TABLES = ("sensors", "wifi", "ble", "waypoints")

CATALOG_COLUMNS = {
    "trace_id": "str", "source_path": "str", "sha256": "str", "size_bytes": "int64",
    "source_format": "str", "site": "str", "floor": "str", "site_id": "str", "site_name": "str",
    "floor_id": "str", "floor_name": "str", "device_brand": "str", "device_model": "str",
    "start_ms": "Int64", "end_ms": "Int64", "n_lines": "int64", "n_header_lines": "int64",
    "n_sensor_rows": "int64", "n_wifi_rows": "int64", "n_scans": "int64", "n_ble_rows": "int64",
    "n_waypoints": "int64", "n_skipped_lines": "int64", "n_bad_lines": "int64",
    "n_dropped_rows": "int64", "records_json": "str", "skipped_json": "str", "bad_json": "str",
    "dropped_json": "str", "messages_json": "str", "header_json": "str",
}


def _safe_component(value: str | None, fallback: str) -> str:
    """A partition value usable as a folder name (``[A-Za-z0-9_.-]``, not starting with a dot)."""
    text = re.sub(r"[^A-Za-z0-9_.-]", "_", (value or "").strip()) or fallback
    return (("_" + text[1:]) if text.startswith(".") else text)[:80]


def part_path(table: str, site: str, floor: str, trace_id: str, sha256: str) -> str:
    """Relative path of one trace's part file of ``table``. The trace id is made a safe file
    name (``[A-Za-z0-9_.-]``, at most 80 characters; the content hash keeps it apart from
    others): a walk plan's ``walk_id`` or a long file name cannot leave the store or exceed
    the file system's name limit."""
    name = _safe_component(trace_id, "trace")
    return f"{table}/site={site}/floor={floor}/{name}-{sha256[:12]}.parquet"


def catalog_row(trace: Trace, *, source_path: str, sha256: str, size_bytes: int,
                source_format: str = "trace") -> dict:
    """The catalog row describing one parsed trace."""
    h, r = trace.header, trace.report
    header = {k: v for k, v in vars(h).items() if k not in ("sensors",)}
    header["sensors"] = [vars(s) for s in h.sensors]
    return {
        "trace_id": trace.trace_id, "source_path": source_path, "sha256": sha256,
        "size_bytes": size_bytes, "source_format": source_format,
        "site": _safe_component(h.site_id, "unknown_site"),
        "floor": _safe_component(h.floor_name or h.floor_id, "unknown_floor"),
        "site_id": h.site_id or "", "site_name": h.site_name or "",
        "floor_id": h.floor_id or "", "floor_name": h.floor_name or "",
        "device_brand": h.brand or "", "device_model": h.model or "",
        "start_ms": h.start_ms, "end_ms": h.end_ms, "n_lines": r.lines_total,
        "n_header_lines": r.header_lines, "n_sensor_rows": len(trace.sensors),
        "n_wifi_rows": len(trace.wifi), "n_scans": int(trace.wifi["scan_t_ms"].nunique()),
        "n_ble_rows": len(trace.ble), "n_waypoints": len(trace.waypoints),
        "n_skipped_lines": r.skipped_total, "n_bad_lines": r.bad_total,
        "n_dropped_rows": int(sum(r.dropped.values())),
        "records_json": json.dumps(r.records, sort_keys=True),
        "skipped_json": json.dumps(r.skipped, sort_keys=True),
        "bad_json": json.dumps(r.bad, sort_keys=True),
        "dropped_json": json.dumps(r.dropped, sort_keys=True),
        "messages_json": json.dumps(r.messages),
        "header_json": json.dumps(header, sort_keys=True, default=str, allow_nan=True),
    }


def read_parquet_checked(path: Path, columns: list[str] | None = None, *,
                         what: str = "part file") -> pa.Table:
    """A store Parquet file with its page checksums verified; a :class:`StoreError` naming
    the file when it is missing, unreadable or corrupted."""
    try:
        return pq.read_table(path, columns=columns, page_checksum_verification=True)
    except (OSError, pa.ArrowException) as err:
        raise StoreError(f"{path}: missing, unreadable or corrupted {what} ({err})") from err


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
    """Write a trace's part files into the store, each atomically and fsynced; their folders
    are fsynced by the commit that makes them live. Idempotent."""
    for name, table in trace_tables(trace).items():
        rel = part_path(name, row["site"], row["floor"], row["trace_id"], row["sha256"])
        atomic_write_bytes(root / rel, _parquet_bytes(table), overwrite=True, sync_dir=False)


@dataclass
class IngestOutcome:
    """What happened to one input file."""

    path: str
    trace_id: str
    status: str  # "new", "changed", "unchanged", "duplicate", "failed"
    detail: str = ""


class SurveyStore:
    """A survey store folder. Open an existing one with :meth:`open`, make one with
    :meth:`create`; write through :meth:`writer` (one writer at a time, enforced by a lock)."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)

    # ---- opening ----------------------------------------------------------------------------

    @classmethod
    def create(cls, root: str | os.PathLike) -> SurveyStore:
        """Open ``root`` as a store, creating an empty one if the folder is empty or missing."""
        root = Path(root)
        if root.exists() and any(root.iterdir()) and not (root / "store.json").exists():
            raise StoreError(f"{root}: exists and is not a survey store (no store.json)")
        root.mkdir(parents=True, exist_ok=True)
        if not (root / "store.json").exists():
            meta = {"format": STORE_FORMAT, "schema_version": SCHEMA_VERSION}
            atomic_write_bytes(root / "store.json", json.dumps(meta, indent=2).encode())
        return cls.open(root)

    @classmethod
    def open(cls, root: str | os.PathLike) -> SurveyStore:
        root = Path(root)
        meta_path = root / "store.json"
        if not meta_path.exists():
            raise StoreError(f"{root}: not a survey store (missing store.json); "
                             "create one with `indoormap ingest ... --store DIR`")
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, ValueError) as err:
            raise StoreError(f"{meta_path}: unreadable ({err})") from err
        if not isinstance(meta, dict):
            raise StoreError(f"{meta_path}: not a JSON object (format and schema_version)")
        if meta.get("format") != STORE_FORMAT:
            raise StoreError(f"{meta_path}: format {meta.get('format')!r} is not {STORE_FORMAT}")
        if meta.get("schema_version") != SCHEMA_VERSION:
            raise StoreError(f"{meta_path}: schema version {meta.get('schema_version')!r} is not "
                             f"supported (this indoormap reads version {SCHEMA_VERSION})")
        return cls(root)

    # ---- reading ----------------------------------------------------------------------------

    def catalog(self) -> pd.DataFrame:
        """One row per ingested trace (columns in :data:`CATALOG_COLUMNS`)."""
        path = self.root / "catalog.parquet"
        if not path.exists():
            return pd.DataFrame({c: pd.Series([], dtype=t) for c, t in CATALOG_COLUMNS.items()})
        return read_parquet_checked(path, what="catalog").to_pandas()

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
              trace_ids: list[str] | None = None) -> pd.DataFrame:
        """Rows of one table (``sensors``, ``wifi``, ``ble``, ``waypoints``) for the selected
        traces, with a ``trace_id`` column, in catalog order then time order."""
        if name not in TABLES:
            raise StoreError(f"unknown table {name!r}; expected one of {TABLES}")
        cat = self.traces(site, floor)
        if trace_ids is not None:
            cat = cat[cat["trace_id"].isin(list(trace_ids))]
        parts = [self._read_part(name, row) for row in cat.itertuples(index=False)]
        if not parts:
            raise StoreError(f"{self.root}: no traces match site={site!r} floor={floor!r}")
        return _frame(pa.concat_tables(parts, promote_options="permissive"))

    def part(self, name: str, row: Any, columns: list[str] | None = None) -> pd.DataFrame:
        """Rows of one table for one trace, ``row`` being its catalog row (a named tuple or
        mapping with ``site``, ``floor``, ``trace_id``, ``sha256``), in time order. Reading walk
        by walk keeps memory bounded by the largest walk, not by the store."""
        if name not in TABLES:
            raise StoreError(f"unknown table {name!r}; expected one of {TABLES}")
        return _frame(self._read_part(name, row, columns))

    def _read_part(self, name: str, row, columns: list[str] | None = None) -> pa.Table:
        get = row.get if isinstance(row, Mapping) else lambda k: getattr(row, k)  # or a Series
        path = self.root / part_path(name, get("site"), get("floor"), get("trace_id"),
                                     get("sha256"))
        return read_parquet_checked(path, None if columns is None
                                    else ["trace_id", *[c for c in columns if c != "trace_id"]])

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

    def known(self, trace_id: str, sha256: str) -> IngestOutcome | None:
        """The outcome for a file that needs no work (same content already stored)."""
        hit = self.cat[self.cat["sha256"] == sha256]
        pending = [r for r in self.pending.values() if r["sha256"] == sha256]
        if len(hit) or pending:
            other = (hit["trace_id"].iloc[0] if len(hit) else pending[0]["trace_id"])
            status = "unchanged" if other == trace_id else "duplicate"
            detail = "" if status == "unchanged" else f"same content as {other}"
            return IngestOutcome("", trace_id, status, detail)
        return None

    def add_row(self, row: dict) -> str:
        """Register a trace whose part files are written; returns ``new`` or ``changed``."""
        existed = (self.cat["trace_id"] == row["trace_id"]).any() or row["trace_id"] in \
            self.pending
        self.pending[row["trace_id"]] = row
        return "changed" if existed else "new"

    def add(self, trace: Trace, *, source_path: str, sha256: str, size_bytes: int,
            source_format: str = "trace") -> str:
        row = catalog_row(trace, source_path=source_path, sha256=sha256, size_bytes=size_bytes,
                          source_format=source_format)
        write_parts(self.root, trace, row)
        return self.add_row(row)

    def commit(self) -> None:
        if not self.pending:
            return
        for folder in {(self.root / part_path(t, r["site"], r["floor"], "x", "0")).parent
                       for r in self.pending.values() for t in TABLES}:
            fsync_dir(folder)  # the renames of the new part files are durable before the commit
        crash_point("ingest:before-catalog")
        keep = self.cat[~self.cat["trace_id"].isin(list(self.pending))]
        new = pd.DataFrame(list(self.pending.values()))
        cat = pd.concat([keep, new], ignore_index=True) if len(keep) else new
        cat = cat.sort_values(["site", "floor", "trace_id"], kind="stable").reset_index(drop=True)
        cat = cat.astype(CATALOG_COLUMNS)[list(CATALOG_COLUMNS)]
        table = pa.Table.from_pandas(cat, preserve_index=False).replace_schema_metadata(None)
        atomic_write_bytes(self.root / "catalog.parquet", _parquet_bytes(table), overwrite=True)
        crash_point("ingest:after-catalog")
        self.cat = cat
        self.pending = {}
        self.collect_garbage()

    def collect_garbage(self) -> int:
        """Delete part files the catalog does not name and temporaries of crashed writes."""
        live = {part_path(t, r.site, r.floor, r.trace_id, r.sha256)
                for r in self.cat.itertuples(index=False) for t in TABLES}
        live |= {part_path(t, r["site"], r["floor"], r["trace_id"], r["sha256"])
                 for r in self.pending.values() for t in TABLES}
        removed = remove_stale_temporaries(self.root)
        for table in TABLES:
            base = self.root / table
            if not base.exists():
                continue
            for p in base.rglob("*"):
                if p.is_file() and (p.name.startswith(TMP_PREFIX)
                                    or str(p.relative_to(self.root)) not in live):
                    p.unlink()
                    removed += 1
            for d in sorted((q for q in base.rglob("*") if q.is_dir()), reverse=True):
                with contextlib.suppress(OSError):
                    d.rmdir()  # only empty partitions go
        fsync_dir(self.root)
        return removed
