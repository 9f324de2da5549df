"""Writing map bundles (the reader is :mod:`localize.bundle`; format in docs/bundle_format.md).

A bundle is written into a temporary folder beside the target and moved into place atomically
(:func:`survey.publish.atomic_directory`): a failed or killed build leaves no half bundle. The
same inputs give the same bytes: arrays are plain ``.npy``, tables Parquet without timestamps,
and the manifest canonical JSON whose build time the caller pins.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from localize.bundle import (
    BUNDLE_FORMAT,
    SCHEMA_VERSION,
    Grid,
    bundle_id_of,
    canonical_json,
    check_grid_limits,
    check_heldout_strength,
    check_layer_kind,
    check_layer_values,
    check_tables,
    has_control_character,
    manifest_bytes,
)
from survey import __version__
from survey.errors import BundleError, BundleIntegrityError
from survey.publish import atomic_directory, crash_point, file_sha256


@dataclass
class Layer:
    """A raster layer: values and uncertainty (float32, NaN = no data), unit and kind."""

    values: np.ndarray
    std: np.ndarray
    unit: str
    kind: str = "scalar"  # or "angle" (deg, interpolated as unit vectors)
    description: str = ""


@dataclass
class BundleContent:
    """Everything a bundle holds besides its derived checksums and id."""

    site_id: str
    floor_id: str
    floor_name: str
    kind: str = "floor"  # or "site"
    grid: Grid | None = None
    mask: np.ndarray | None = None
    layers: dict[str, Layer] = field(default_factory=dict)
    tables: dict[str, pa.Table] = field(default_factory=dict)
    build: dict = field(default_factory=dict)  # params, seed, source walks, build_time, ...
    metrics: dict = field(default_factory=dict)

    def __repr__(self) -> str:  # what it holds, not its arrays
        grid = f", {self.grid}" if self.grid is not None else ""
        return (f"BundleContent({self.kind} {self.site_id!r}/{self.floor_name or self.floor_id!r}"
                f"{grid}, layers {', '.join(self.layers) or 'none'}, tables "
                f"{', '.join(self.tables) or 'none'})")


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def _parquet_bytes(table: pa.Table) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(table.replace_schema_metadata(None), sink, compression="zstd",
                   write_page_checksum=True)
    return sink.getvalue().to_pybytes()


def _check(content: BundleContent) -> None:
    """What :func:`localize.bundle.load_bundle` would refuse, refused before writing."""
    if content.kind not in ("floor", "site"):
        raise BundleError(f"bundle kind must be 'floor' or 'site', got {content.kind!r}")
    if (content.grid is None) != (content.kind == "site"):  # as a reader checks
        raise BundleError("a floor bundle needs a grid and a site bundle has none")
    for key in ("site_id", "floor_id", "floor_name"):
        if not isinstance(getattr(content, key), str):
            raise BundleError(f"bundle {key} must be a string, got "
                              f"{getattr(content, key)!r}")
        if has_control_character(getattr(content, key)):
            raise BundleError(f"bundle {key} {getattr(content, key)!r} holds a control "
                              "character (from a trace header?); a reader would refuse it")
    try:  # the tables and numbers a reader checks, with its functions (localize.bundle)
        _check_numbers(content)
    except BundleIntegrityError as err:
        raise BundleError(f"refused before writing: {err}") from err


def _check_numbers(content: BundleContent) -> None:
    """The grid, layers and tables of :func:`_check`."""
    where = f"{content.kind} bundle {content.floor_name!r}"
    check_tables(content.tables, where)
    check_heldout_strength(content.metrics, where)
    if content.grid is None:
        if content.layers:
            raise BundleError("layers need a grid")
        return
    check_grid_limits(content.grid, where)
    shape = content.grid.shape
    if content.mask is None or content.mask.shape != shape:
        raise BundleError(f"mask must have the grid's shape {shape}")
    outside = ~np.asarray(content.mask, dtype=bool)
    for name, layer in content.layers.items():
        check_layer_kind(name, layer.unit, layer.kind, where)
        for key, arr in (("file", layer.values), ("std_file", layer.std)):
            if arr.shape != shape:
                raise BundleError(f"layer {name} {key}: shape {arr.shape} != grid {shape}")
            check_layer_values(np.asarray(arr, dtype=np.float32), where, name, key, layer.unit)
        if np.isfinite(layer.values[outside]).any():
            raise BundleError(f"layer {name}: values outside the reachable mask")


def write_bundle(target: str | os.PathLike, content: BundleContent, *,
                 overwrite: bool = False) -> str:
    """Write ``content`` as a bundle folder at ``target``; returns the bundle id."""
    _check(content)
    target = Path(target)
    files: dict[str, bytes] = {}
    manifest: dict = {"format": BUNDLE_FORMAT, "schema_version": SCHEMA_VERSION,
                      "kind": content.kind, "site_id": content.site_id,
                      "floor_id": content.floor_id, "floor_name": content.floor_name,
                      "map_frame": {"x": "east", "y": "north", "unit": "m"},
                      "software_version": __version__}
    if content.grid is not None:
        manifest["grid"] = content.grid.to_dict()
        manifest["mask"] = "mask.npy"
        files["mask.npy"] = _npy_bytes(content.mask.astype(np.uint8))
        manifest["layers"] = {}
        for name in sorted(content.layers):
            layer = content.layers[name]
            f, s = f"layers/{name}.npy", f"layers/{name}_std.npy"
            files[f] = _npy_bytes(np.asarray(layer.values, dtype=np.float32))
            files[s] = _npy_bytes(np.asarray(layer.std, dtype=np.float32))
            manifest["layers"][name] = {"file": f, "std_file": s, "unit": layer.unit,
                                        "kind": layer.kind, "description": layer.description}
    manifest["tables"] = {}
    for name in sorted(content.tables):
        f = f"tables/{name}.parquet"
        files[f] = _parquet_bytes(content.tables[name])
        manifest["tables"][name] = {"file": f, "rows": content.tables[name].num_rows}
    manifest["build"] = content.build
    manifest["metrics"] = content.metrics
    try:  # a number JSON cannot hold, a string UTF-8 cannot (a lone surrogate), a non-str key
        canonical_json(manifest)
    except (ValueError, TypeError) as err:
        raise BundleError(f"{target}: the manifest cannot be written as JSON ({err})") from err
    with atomic_directory(target, overwrite=overwrite, crash_prefix="bundle") as tmp:
        members = {}
        for name, data in sorted(files.items()):
            p = tmp / name
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
            members[name] = {"sha256": file_sha256(p), "size": len(data)}
            crash_point("bundle:member")
        manifest["members"] = members
        manifest["bundle_id"] = bundle_id_of(manifest)
        (tmp / "manifest.json").write_bytes(manifest_bytes(manifest))
    return manifest["bundle_id"]
