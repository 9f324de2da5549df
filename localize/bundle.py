"""Map bundles: the verified, read-only maps the localizer consumes (numpy and pyarrow only).

A bundle is a folder (see ``docs/bundle_format.md``)::

    manifest.json            format, schema version, bundle id, grid, layers, tables, members
    mask.npy                 uint8 (height, width): 1 = reachable cell
    layers/<name>.npy        float32 (height, width), NaN = no data; <name>_std.npy alongside
    tables/<name>.parquet    fingerprints, devices, floor model, ...

The grid: cell (row i, column j) covers ``x in [x0 + j*cell, x0 + (j+1)*cell)`` and
``y in [y0 + i*cell, ...)`` metres in the map frame (x east, y north; row 0 is the south edge).

:func:`load_bundle` verifies before it returns: format name, schema version, the bundle id (the
sha256 of the canonical manifest without its id), every member's path, size and sha256, no
member missing and no file unlisted, ``.npy`` headers (dtype, shape, size) before reading, and
never unpickles; then the numbers, which checksums cannot vouch for (a buggy writer seals what it
writes): the grid's cell size and cell count, the known layers' units, kinds and value ranges,
and the tables readers rely on (:data:`TABLE_SCHEMAS`: exact columns and types, unique keys,
RSSI, rates and positions in range). Any difference raises :class:`BundleIntegrityError`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import BundleError, BundleIntegrityError, BundleReplaced, RegistryError
from survey.publish import file_sha256, finish_interrupted_publication
from survey.regular_files import NotRegularFile, read_regular

if TYPE_CHECKING:  # an annotation: pyarrow is imported when a table is read
    import pyarrow as pa

BUNDLE_FORMAT = "indoormap-map-bundle"
SCHEMA_VERSION = 1
#: dtypes a bundle array may have.
ALLOWED_DTYPES = frozenset({"<f4", "<f8", "|u1", "<i2", "<i4", "<i8", "|b1"})
#: Largest array a bundle may hold (elements); bigger headers are refused before reading.
MAX_ARRAY_ELEMENTS = 200_000_000
MAX_MEMBERS = 10_000
MAX_MANIFEST_BYTES = 16 * 1024**2

#: Most cells a floor's grid may have, the builder's cap as well (:mod:`mapping.grid`): a
#: float32 layer of them is 80 MB; the build keeps a dozen layers and cross-validates on
#: full grids.
MAX_GRID_CELLS = 20_000_000
#: Cell sizes a grid may have (m): 1 mm to 100 m.
CELL_M_LIMITS = (1e-3, 100.0)
#: Largest coordinate (m) of a grid origin or a reference point (a UTM northing is 1e7 m).
MAX_COORD_M = 1e8
#: RSSI a table may hold (dBm): the values a phone reports, as the trace reader and the radio
#: build (:mod:`mapping.radio_scans`) accept them.
RSSI_RANGE_DBM = (-127.0, 0.0)


def rssi_reading(rssi_dbm: ArrayLike) -> NDArray[np.bool_]:
    """Where RSSI values (dBm) are a phone's reading: within :data:`RSSI_RANGE_DBM` and not
    exactly 0 dBm, which no phone receives (the ILC traces' strongest Wi-Fi row is -7 dBm)
    and drivers report for "no reading". Read as the strongest signal, a third of a walk's
    rows at 0 dBm took its median error from 1.7 to 6.1 m and put it on another floor."""
    rssi = np.asarray(rssi_dbm)
    return (rssi >= RSSI_RANGE_DBM[0]) & (rssi <= RSSI_RANGE_DBM[1]) & (rssi != 0)


#: The layers of a floor bundle by name: (unit, kinds it may have). The polar angle (0 to
#: 180 deg, never wrapping) is an angle layer in built bundles and a scalar one in the
#: simulator's truth bundles; the localizer compares it as a scalar. A layer of another name
#: may be added (readers ignore it); an angle layer is in degrees whatever its name.
KNOWN_LAYERS = {"strength": ("uT", ("scalar",)), "horizontal": ("uT", ("scalar",)),
                "vertical": ("uT", ("scalar",)), "azimuth": ("deg", ("angle",)),
                "polar": ("deg", ("angle", "scalar")), "heading_offset": ("deg", ("angle",))}
#: Largest magnitude of a layer value by unit: no phone magnetometer reads beyond about
#: 4,900 uT per axis; angles lie within one turn either way.
LAYER_LIMITS = {"uT": 10_000.0, "deg": 360.0}
#: Largest uncertainty a layer may give (its unit, or m for the linear interpolator).
MAX_LAYER_STD = 1e6

_INT, _FLOAT, _TEXT = "int64", "double", "text"
_ANY = (-math.inf, math.inf)
_COUNT = (0, math.inf)
#: Tables a reader relies on: column -> (Arrow type, nulls allowed, (low, high)). The types
#: are those the writer gives (pandas' ``int64``, ``float64`` and ``str`` columns; a text
#: column is ``string`` or ``large_string``); numbers must be finite. ``<kind>`` is ``wifi``
#: or ``ble``. Optional columns (``None`` below: older bundles lack them) are in ``_OPTIONAL``.
TABLE_SCHEMAS: dict[str, dict[str, tuple[str, bool, tuple[float, float]]]] = {
    "<kind>_rp": {"rp_id": (_INT, False, _ANY), "x_m": (_FLOAT, False, (-MAX_COORD_M,
                                                                          MAX_COORD_M)),
                  "y_m": (_FLOAT, False, (-MAX_COORD_M, MAX_COORD_M)),
                  "n_scans": (_INT, False, (1, math.inf))},
    "<kind>_fp": {"rp_id": (_INT, False, _ANY), "ap": (_TEXT, False, _ANY),
                  "mean_dbm": (_FLOAT, False, RSSI_RANGE_DBM),
                  # unbiased variance of readings within the RSSI range: below 127^2 / 2
                  "var_db2": (_FLOAT, True, (0.0, 127.0 ** 2)),
                  "n": (_INT, False, (1, math.inf)),
                  "detection_rate": (_FLOAT, False, (0.0, 1.0))},
    "<kind>_meta": {"kind": (_TEXT, False, _ANY), "cell_m": (_FLOAT, False, CELL_M_LIMITS),
                    "max_age_ms": (_FLOAT, True, _COUNT),
                    "format_version": (_INT, False, (1, 1))},
    "devices": {"device_model": (_TEXT, False, _ANY), "k": (_FLOAT, False, (0.01, 100.0)),
                "b": (_FLOAT, False, (-1000.0, 1000.0)), "n_pairs": (_INT, False, _COUNT),
                "residual_sd_db": (_FLOAT, True, (0.0, 1000.0)),
                "method": (_TEXT, False, _ANY)},
    "source_walks": {"trace_id": (_TEXT, False, _ANY), "session": (_TEXT, True, _ANY),
                     "sha256": (_TEXT, True, _ANY), "calibration": (_TEXT, True, _ANY),
                     "heading_offset_median_deg": (_FLOAT, True, (-360.0, 360.0))},
    "levelling": {"session": (_TEXT, False, _ANY),
                  **{f"r_{a}_ut": (_FLOAT, False, (-10_000.0, 10_000.0)) for a in "xyz"},
                  **{f"s_{a}": (_FLOAT, False, (-10.0, 10.0))
                     for a in ("xx", "yy", "zz", "xy", "xz", "yz")},
                  "device": (_TEXT, True, _ANY), "n_samples": (_INT, False, _COUNT),
                  "n_pairs": (_INT, False, _COUNT)},
}
#: Columns of :data:`TABLE_SCHEMAS` a table may lack (levelling before the soft-iron fit).
_OPTIONAL = {"levelling": {"s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz", "device"}}
#: Columns whose values are a table's key (no two rows alike).
_TABLE_KEYS = {"<kind>_rp": ("rp_id",), "<kind>_fp": ("rp_id", "ap"),
               "devices": ("device_model",), "source_walks": ("trace_id",),
               "levelling": ("session",)}
RADIO_KINDS = ("wifi", "ble")


def canonical_json(obj: object) -> bytes:
    """The byte form hashed for the bundle id (sorted keys, no spaces, UTF-8)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False).encode("utf-8")


def manifest_bytes(manifest: dict) -> bytes:
    """The exact bytes of ``manifest.json`` (sorted keys, one-space indent, ASCII, final
    newline). A manifest is read back only if its file is these bytes of what it parses to, so
    no byte of it can change unnoticed, not even white space."""
    return (json.dumps(manifest, sort_keys=True, indent=1, allow_nan=False) + "\n").encode()


def bundle_id_of(manifest: dict) -> str:
    """Content hash of a manifest: sha256 of its canonical JSON without ``bundle_id``."""
    body = {k: v for k, v in manifest.items() if k != "bundle_id"}
    return hashlib.sha256(canonical_json(body)).hexdigest()


@dataclass(frozen=True)
class Grid:
    """Raster geometry in the map frame (metres)."""

    x0_m: float
    y0_m: float
    cell_m: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.x0_m) and math.isfinite(self.y0_m)
                and math.isfinite(self.cell_m) and self.cell_m > 0):
            raise BundleError(f"grid: finite origin and a positive cell size needed, got {self}")
        if self.width < 1 or self.height < 1:
            raise BundleError(f"grid: width and height must be positive, got {self}")

    @property
    def x1_m(self) -> float:
        """East edge of the grid (m)."""
        return self.x0_m + self.width * self.cell_m

    @property
    def y1_m(self) -> float:
        """North edge of the grid (m)."""
        return self.y0_m + self.height * self.cell_m

    @classmethod
    def from_dict(cls, d: dict) -> Grid:
        try:
            if not all(type(d[k]) is int for k in ("width", "height")):  # not true
                raise ValueError("width and height must be whole numbers of cells")
            return cls(float(d["x0_m"]), float(d["y0_m"]), float(d["cell_m"]), d["width"],
                       d["height"])
        except (KeyError, TypeError, ValueError) as err:
            raise BundleError(f"manifest grid is malformed: {err}") from err

    def to_dict(self) -> dict:
        return {"x0_m": self.x0_m, "y0_m": self.y0_m, "cell_m": self.cell_m,
                "width": self.width, "height": self.height}

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def cell_centers(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """x (width,) and y (height,) of the cell centres (m)."""
        return (self.x0_m + (np.arange(self.width) + 0.5) * self.cell_m,
                self.y0_m + (np.arange(self.height) + 0.5) * self.cell_m)

    def cell_of(self, x_m: ArrayLike, y_m: ArrayLike) -> tuple[NDArray[np.int64],
                                                              NDArray[np.int64],
                                                              NDArray[np.bool_]]:
        """(row, col, inside) of the cells holding the points."""
        col = np.floor((np.asarray(x_m, dtype=np.float64) - self.x0_m) / self.cell_m)
        row = np.floor((np.asarray(y_m, dtype=np.float64) - self.y0_m) / self.cell_m)
        inside = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return (np.where(inside, row, 0).astype(np.int64),
                np.where(inside, col, 0).astype(np.int64), inside)


def _safe_member(name: str, root: Path) -> Path:
    p = PurePosixPath(name)
    if (not name or p.is_absolute() or ".." in p.parts or "\\" in name or "\0" in name
            or name.startswith("./")):
        raise BundleIntegrityError(f"{root}: member name {name!r} is not a plain relative path")
    path = root.joinpath(*p.parts)
    if path.is_symlink() or any(q.is_symlink() for q in path.parents if q != root.parent
                                and root in q.parents):
        raise BundleIntegrityError(f"{root}: member {name!r} is a link")
    return path


def read_npy_checked(path: Path, *, mmap: bool = True) -> np.ndarray:
    """Load a ``.npy`` after checking its header: allowed dtype, 1-3 dims, size cap; never
    unpickles. Memory-mapped (read-only) by default."""
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise BundleIntegrityError(f"{path}: unsupported .npy version {version}")
            offset = fh.tell()
    except (ValueError, OSError, EOFError) as err:
        raise BundleIntegrityError(f"{path}: not a valid .npy file ({err})") from err
    if dtype.hasobject or dtype.str not in ALLOWED_DTYPES:
        raise BundleIntegrityError(f"{path}: dtype {dtype.str} is not allowed in a bundle")
    if (not (1 <= len(shape) <= 3) or min(shape) < 0
            or math.prod(shape) > MAX_ARRAY_ELEMENTS):
        raise BundleIntegrityError(f"{path}: shape {shape} is not allowed in a bundle")
    expected = offset + math.prod(shape) * dtype.itemsize
    if path.stat().st_size != expected:
        raise BundleIntegrityError(f"{path}: {path.stat().st_size} bytes, header implies "
                                   f"{expected}")
    if mmap:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    return np.load(path, allow_pickle=False)


class MapBundle:
    """A verified map bundle of one floor (or a site-level bundle without rasters).

    Attributes
    ----------
    path : Path
    manifest : dict
    grid : Grid or None
    mask : ndarray of bool (height, width) or None
    layers : dict of name -> ndarray float32 (height, width), read-only
    std : dict of name -> ndarray float32 (height, width): each layer's uncertainty
    tables : dict of name -> pyarrow Table: the tables read and checked at load
        (:func:`read_checked_tables`); :meth:`table` reads the others when asked
    """

    def __init__(self, path: Path, manifest: dict, grid: Grid | None, mask, layers, std,
                 tables: dict[str, pa.Table] | None = None):
        self.path = path
        self.manifest = manifest
        self.grid = grid
        self.mask = mask
        self.layers = layers
        self.std = std
        self.tables = tables if tables is not None else {}
        self._source_walk_ids: frozenset[str] | None = None

    def __repr__(self) -> str:  # what the bundle is, not its arrays
        if self.grid is None:
            what = f"site bundle of {self.site_id!r}"
        else:
            g = self.grid
            layers = ", ".join(f"{name} ({meta.get('unit', '?')})"
                               for name, meta in self.manifest.get("layers", {}).items())
            what = (f"floor {self.manifest.get('floor_name') or self.floor_id!r} of site "
                    f"{self.site_id!r}, {g.width} x {g.height} cells of {g.cell_m:g} m, "
                    f"layers {layers or 'none'}")
        tables = ", ".join(self.manifest.get("tables", {})) or "none"
        return (f"MapBundle({str(self.path)!r}, {what}, tables {tables}, id "
                f"{self.bundle_id[:16]})")

    @property
    def bundle_id(self) -> str:
        return self.manifest["bundle_id"]

    @property
    def site_id(self) -> str:
        return self.manifest.get("site_id", "")

    @property
    def floor_id(self) -> str:
        return self.manifest.get("floor_id", "")

    def layer_unit(self, name: str) -> str:
        """The unit of layer ``name`` (``uT``, ``deg``); a BundleError naming the layers
        the bundle has for another name."""
        return self._layer_meta(name)["unit"]

    def _layer_meta(self, name: str) -> dict:
        """Layer ``name``'s manifest entry; a BundleError for a site bundle (no rasters), a
        name that is not text, or a layer the bundle does not have."""
        if self.grid is None:
            raise BundleError(f"{self.path}: a site-level bundle has no floor map layers; "
                              "give a floor bundle")
        meta = self.manifest["layers"].get(name) if isinstance(name, str) else None
        if meta is None:
            raise BundleError(f"{self.path}: no layer {name!r}; has {sorted(self.layers)}")
        return meta

    def verify(self) -> None:
        """Re-check the folder against the manifest loaded: its ``manifest.json`` (whose id
        is its content's hash) and every member (a :class:`BundleIntegrityError` for any
        change). A folder that now holds another bundle (``build --overwrite`` since it was
        loaded) raises :class:`BundleReplaced` instead, naming both ids: the arrays loaded
        are intact, and it is a deployment, not damage (it was reported as a member not
        matching its checksum)."""
        try:
            on_disk = read_manifest(self.path)
        except BundleIntegrityError:
            raise
        except BundleError as err:  # moved or deleted since it was loaded: its members are gone
            raise BundleIntegrityError(f"{self.path}: the bundle's folder no longer holds it "
                                       f"({err})") from err
        if on_disk.get("bundle_id") != self.bundle_id:
            raise BundleReplaced(f"{self.path}: now holds bundle "
                                 f"{str(on_disk.get('bundle_id'))[:16]}, not the "
                                 f"{self.bundle_id[:16]} loaded from it (rebuilt or replaced "
                                 "since; what was loaded is unchanged in memory): load it "
                                 "again to use the new bundle")
        verify_bundle_dir(self.path, self.manifest)

    def table(self, name: str) -> pa.Table:
        """A bundle table as a pyarrow Table (verified on load; the tables
        :data:`TABLE_SCHEMAS` describes are the ones checked at load, not read again)."""
        tables = self.manifest.get("tables", {})
        if name not in tables:
            raise BundleError(f"{self.path}: no table {name!r}; has {sorted(tables)}")
        if name in self.tables:
            return self.tables[name]
        return read_table_file(self.path, name, tables[name]["file"])[0]

    def has_table(self, name: str) -> bool:
        return name in self.manifest.get("tables", {})

    def source_walk_ids(self) -> frozenset[str]:
        """Trace ids of the walks the bundle was built from (its ``source_walks`` table;
        empty without one): errors measured on them flatter the map. Read once per bundle
        (every localized walk asks)."""
        if self._source_walk_ids is None:
            self._source_walk_ids = frozenset(
                self.table("source_walks").column("trace_id").to_pylist()
                if self.has_table("source_walks") else ())
        return self._source_walk_ids

    def reachable(self, x_m: ArrayLike, y_m: ArrayLike) -> NDArray[np.bool_]:
        """Whether each point lies in a reachable cell."""
        if self.grid is None:
            raise BundleError(f"{self.path}: a site-level bundle has no reachable-area mask; "
                              "give a floor bundle")
        row, col, inside = self.grid.cell_of(*_coordinates(x_m, y_m))
        return inside & self.mask[row, col]

    def sample(self, layer: str, x_m: ArrayLike, y_m: ArrayLike, *,
               std: bool = False) -> NDArray[np.float64]:
        """Bilinear lookup of a layer (or its uncertainty) at points in metres.

        NaN where the point's own cell is off the mask or has no data. Neighbour cells without
        data are left out of the interpolation (weights renormalised), so values next to walls
        stay defined. Angle layers (``kind == "angle"``, deg) are interpolated as unit vectors
        and come back in [0, 360) (the filter's :class:`localize.maps.LayerSampler` gives
        [-180, 180]). ``x_m`` and ``y_m`` broadcast against each other as numpy arrays do (one
        x with many y samples a column); the result has their broadcast shape.

        Examples
        --------
        >>> b.sample("strength", [10.0, 1e6], [5.0, 5.0])  # doctest: +SKIP
        array([43.1, nan])
        """
        meta = self._layer_meta(layer)
        x_m, y_m = _coordinates(x_m, y_m)
        values = self.std[layer] if std else self.layers[layer]
        return sample_grid(self.grid, self.mask, values, x_m, y_m,
                           angle=meta.get("kind") == "angle" and not std)


def _coordinates(x_m: ArrayLike, y_m: ArrayLike) -> tuple[NDArray, NDArray]:
    """Points' coordinates (m) as numeric arrays; a BundleError naming them for text, None
    or objects (None was read as NaN, text failed inside numpy)."""
    out = []
    for name, v in (("x_m", x_m), ("y_m", y_m)):
        arr = np.asarray(v)
        if arr.dtype.kind not in "iuf":
            raise BundleError(f"{name} must be numbers (m), got {arr.dtype} "
                              f"({np.ravel(arr)[:3].tolist()})")
        out.append(arr)
    return out[0], out[1]


def sample_grid(grid: Grid, mask: NDArray[np.bool_], values: NDArray, x_m: ArrayLike,
                y_m: ArrayLike, *, angle: bool = False) -> NDArray[np.float64]:
    """Bilinear lookup of a raster at points (m); see :meth:`MapBundle.sample`.

    Parameters
    ----------
    grid : Grid
    mask : ndarray of bool (height, width)
    values : ndarray (height, width); NaN = no data
    x_m, y_m : array_like, broadcastable
    angle : bool
        Values are angles in degrees: interpolate unit vectors, return [0, 360).
    """
    return BilinearLookup.at(grid, mask, x_m, y_m)(values, angle=angle)


@dataclass(frozen=True)
class BilinearLookup:
    """:func:`sample_grid` at fixed points for any raster of one grid and mask: the cells and
    weights are found once (a cross-validation reads hundreds of candidate rasters at the
    same held-out points).

    Per point (n of them, flattened): ``own`` its flat cell index and ``own_ok`` whether that
    cell is on the grid and the mask; ``corner`` (n, 4) the flat indices of the four cells
    around it, ``weight`` (n, 4) their bilinear weights and ``valid`` (n, 4) whether each is
    on the grid and the mask; ``shape`` the points' broadcast shape."""

    own: NDArray[np.int64]
    own_ok: NDArray[np.bool_]
    corner: NDArray[np.int64]
    weight: NDArray[np.float64]
    valid: NDArray[np.bool_]
    shape: tuple[int, ...]

    @classmethod
    def at(cls, grid: Grid, mask: NDArray[np.bool_], x_m: ArrayLike, y_m: ArrayLike
           ) -> BilinearLookup:
        """The lookup at the points ``x_m``, ``y_m`` (m, broadcastable)."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        shape = np.broadcast(x, y).shape
        x, y = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
        g = grid
        row, col, inside = g.cell_of(x, y)
        own_ok = inside & mask[row, col]
        # Off-grid and non-finite points (NaN: no position) are held just off the grid, so
        # that every corner is invalid and the integer cast below is defined.
        fx = np.nan_to_num(np.clip((x - g.x0_m) / g.cell_m - 0.5, -2.0, g.width + 1.0),
                           nan=-2.0)
        fy = np.nan_to_num(np.clip((y - g.y0_m) / g.cell_m - 0.5, -2.0, g.height + 1.0),
                           nan=-2.0)
        j0, i0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
        wx, wy = fx - j0, fy - i0
        corner, weight, valid = [], [], []
        for di, dj, w in ((0, 0, (1 - wy) * (1 - wx)), (0, 1, (1 - wy) * wx),
                          (1, 0, wy * (1 - wx)), (1, 1, wy * wx)):
            i, j = i0 + di, j0 + dj
            ic, jc = np.clip(i, 0, g.height - 1), np.clip(j, 0, g.width - 1)
            corner.append(ic * g.width + jc)
            weight.append(w)
            valid.append((i >= 0) & (i < g.height) & (j >= 0) & (j < g.width) & mask[ic, jc])
        return cls(row * g.width + col, own_ok, np.stack(corner, 1), np.stack(weight, 1),
                   np.stack(valid, 1), shape)

    def cells(self, grid: Grid) -> NDArray[np.bool_]:
        """The cells the lookup reads (grid shape): the points' own and their corners."""
        out = np.zeros(grid.shape, dtype=bool)
        out.flat[self.own[self.own_ok]] = True
        out.flat[self.corner[self.valid & self.own_ok[:, None]]] = True
        return out

    def __call__(self, values: NDArray, *, angle: bool = False) -> NDArray[np.float64]:
        """Bilinear values of the raster ``values`` (the grid's shape; NaN = no data) at the
        points: NaN off the mask and where the point's own cell has no value; angles (deg)
        as unit vectors with ``angle=True``."""
        flat = np.asarray(values).ravel()
        n = len(self.own)
        own = np.full(n, np.nan)
        own[self.own_ok] = flat[self.own[self.own_ok]]
        ok = self.own_ok & np.isfinite(own)
        acc = np.zeros((n, 2 if angle else 1))
        wsum = np.zeros(n)
        for c in range(4):
            v = flat[self.corner[:, c]].astype(np.float64)
            valid = ok & self.valid[:, c] & np.isfinite(v)
            w = np.where(valid, self.weight[:, c], 0.0)
            v = np.where(valid, v, 0.0)
            if angle:
                acc[:, 0] += w * np.sin(np.radians(v))
                acc[:, 1] += w * np.cos(np.radians(v))
            else:
                acc[:, 0] += w * v
            wsum += w
        out = np.full(n, np.nan)
        good = ok & (wsum > 0)
        if angle:
            out[good] = np.mod(np.degrees(np.arctan2(acc[good, 0], acc[good, 1])), 360.0)
        else:
            out[good] = acc[good, 0] / wsum[good]
        return out.reshape(self.shape)


def read_manifest(path: Path) -> dict:
    mpath = path / "manifest.json"
    try:
        if mpath.is_symlink() or not stat.S_ISREG(mpath.stat().st_mode):
            raise BundleIntegrityError(f"{mpath}: the manifest must be a regular file, not a "
                                       "link, pipe or device")
        with open(mpath, "rb") as fh:  # read at most the limit: the size may change
            text = fh.read(MAX_MANIFEST_BYTES + 1)
        if len(text) > MAX_MANIFEST_BYTES:
            raise BundleIntegrityError(f"{mpath}: manifest too large")
        manifest = json.loads(text.decode("utf-8"), parse_constant=_refuse_constant,
                              parse_float=_finite_float)
    except FileNotFoundError as err:
        if not path.exists():
            raise BundleError(f"{path}: no such file or folder") from err
        members = [name for name in _BUNDLE_MEMBERS if (path / name).exists()]
        if members:
            raise BundleIntegrityError(f"{path}: manifest.json is missing, but the folder holds "
                                       f"a bundle's {', '.join(members)}: a damaged bundle "
                                       "(build or publish it again)") from err
        if is_registry_floor_dir(path):
            raise BundleError(f"{path}: a registry floor folder with no current version "
                              "(published with --no-current, or its CURRENT deleted): make one "
                              "current with indoormap bundle use REGISTRY SITE/FLOOR VERSION "
                              "(indoormap bundle list REGISTRY lists them)") from err
        try:  # a hint only: a folder that cannot be listed is no bundle all the same
            inner = [q.name for q in _bundles_in(path)] if path.is_dir() else []
        except OSError:
            inner = []
        floors = [n for n in inner if n != "_site"]  # the site bundle is no floor's
        raise BundleError(f"{path}: not a map bundle (no manifest.json)" + (
            f"; it is a folder of bundles ({', '.join(inner)}): give one of them, e.g. "
            f"{path / (floors or inner)[0]}" if inner else "")) from err
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise BundleIntegrityError(f"{mpath}: unreadable manifest ({err})") from err
    if not isinstance(manifest, dict) or manifest.get("format") != BUNDLE_FORMAT:
        raise BundleError(f"{mpath}: not an {BUNDLE_FORMAT} manifest")
    version = manifest.get("schema_version")
    if type(version) is not int or version != SCHEMA_VERSION:  # not True, not 1.0
        raise BundleError(f"{mpath}: schema version {version!r} is not "
                          f"supported (this indoormap reads version {SCHEMA_VERSION})")
    try:
        same_id = manifest.get("bundle_id") == bundle_id_of(manifest)
    except (ValueError, TypeError) as err:  # a lone surrogate escape cannot be UTF-8
        raise BundleIntegrityError(f"{mpath}: unreadable manifest ({err})") from err
    if not same_id:
        raise BundleIntegrityError(f"{mpath}: bundle id does not match the manifest content")
    if text != manifest_bytes(manifest):
        raise BundleIntegrityError(f"{mpath}: the manifest's bytes are not the ones indoormap "
                                   "writes for its content (edited after the build?)")
    check_manifest_layout(manifest, mpath)
    return manifest


def _refuse_constant(name: str) -> float:
    raise ValueError(f"non-finite number {name}")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):  # 1e999
        raise ValueError(f"non-finite number {text}")
    return value


def has_control_character(text: str) -> bool:
    """Whether ``text`` holds a control character (below U+0020, or DEL): refused in the ids
    and names that become registry folder names and printed lines."""
    return any(ord(c) < 32 or ord(c) == 127 for c in text)


def _member_entry(value, what: str, mpath: Path, members: dict) -> None:
    if not isinstance(value, str) or value not in members:
        raise BundleIntegrityError(f"{mpath}: {what} {value!r} is not a listed member")


#: The top-level fields of a schema-1 manifest: all of them in a floor bundle, all but the
#: raster ones (:data:`RASTER_FIELDS`) in a site bundle. A writer that adds one changes the
#: schema version; within a version, new tables and layers are what a writer may add.
MANIFEST_FIELDS = frozenset({"format", "schema_version", "kind", "site_id", "floor_id",
                             "floor_name", "map_frame", "software_version", "grid", "mask",
                             "layers", "tables", "build", "metrics", "members", "bundle_id"})
RASTER_FIELDS = frozenset({"grid", "mask", "layers"})
#: ``metrics.heldout_strength``: field -> whether a count (int) or a score (number or null).
#: ``localize --method auto`` chooses its method by ``corr_5m``.
HELDOUT_FIELDS = {"shape_rmse_ut": False, "constant_shape_rmse_ut": False, "skill": False,
                  "corr_0.7m": False, "corr_5m": False, "n_samples": True, "n_walks": True,
                  "folds": True}


def is_json_number(value: object) -> bool:
    """A JSON number (int or float, not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_manifest_layout(manifest: dict, mpath: Path) -> None:
    """The manifest has the fields of its kind and no other (:data:`MANIFEST_FIELDS`), with the
    types every reader relies on, and every file it points at (mask, layers, tables) is one of
    its checksummed members.

    Raises
    ------
    BundleIntegrityError
        Naming the first field that is missing or malformed.
    """
    def need(ok: bool, field: str) -> None:
        if not ok:
            raise BundleIntegrityError(f"{mpath}: field {field!r} is missing or malformed")

    unknown = sorted(set(manifest) - MANIFEST_FIELDS)
    if unknown:
        raise BundleIntegrityError(f"{mpath}: unknown field(s) {', '.join(map(repr, unknown))}"
                                   f" (a schema {SCHEMA_VERSION} manifest has none)")
    need(manifest.get("kind") in ("floor", "site"), "kind")
    wanted = MANIFEST_FIELDS - (RASTER_FIELDS if manifest["kind"] == "site" else set())
    for key in sorted(wanted - set(manifest)):
        need(False, key)
    if manifest["kind"] == "site" and RASTER_FIELDS & set(manifest):
        raise BundleIntegrityError(f"{mpath}: a site bundle has no grid, mask or layers")
    for key in ("site_id", "floor_id", "floor_name", "software_version"):
        need(isinstance(manifest.get(key), str), key)
    for key in ("site_id", "floor_id", "floor_name"):  # registry folder names, printed
        if has_control_character(manifest[key]):
            raise BundleIntegrityError(f"{mpath}: field {key!r} holds a control character "
                                       f"({manifest[key]!r})")
    build = manifest.get("build")
    need(isinstance(build, dict) and isinstance(build.get("params", {}), dict), "build")
    need(isinstance(manifest.get("metrics"), dict), "metrics")
    check_heldout_strength(manifest["metrics"], mpath)
    walks = build.get("source_walks", [])
    need(isinstance(walks, list) and all(isinstance(w, dict) and isinstance(
        w.get("trace_id"), str) for w in walks), "build.source_walks")
    members = manifest.get("members")
    need(isinstance(members, dict) and all(
        isinstance(m, dict) and isinstance(m.get("size"), int)
        and isinstance(m.get("sha256"), str) for m in members.values()), "members")
    tables = manifest["tables"]
    need(isinstance(tables, dict) and all(isinstance(t, dict) and isinstance(t.get("rows"), int)
                                          for t in tables.values()), "tables")
    for name, meta in tables.items():
        _member_entry(meta.get("file"), f"table {name!r} file", mpath, members)
        # each table and layer in its own file, as the writer names them: a layer pointed at
        # another's file (re-sealed) would load another quantity under its name
        need(meta.get("file") == f"tables/{name}.parquet", f"tables.{name}.file")
    if manifest["kind"] == "site":
        return
    need(isinstance(manifest["grid"], dict) and all(
        is_json_number(manifest["grid"].get(k)) for k in ("x0_m", "y0_m", "cell_m")), "grid")
    try:
        grid = Grid.from_dict(manifest["grid"])  # finite, positive, whole numbers of cells
    except BundleError as err:
        raise BundleIntegrityError(f"{mpath}: {err}") from err
    check_grid_limits(grid, mpath)
    _member_entry(manifest.get("mask"), "mask", mpath, members)
    layers = manifest.get("layers")
    need(isinstance(layers, dict) and all(
        isinstance(m, dict) and isinstance(m.get("unit"), str)
        and m.get("kind") in ("scalar", "angle") for m in layers.values()), "layers")
    for name, meta in layers.items():
        check_layer_kind(name, meta["unit"], meta["kind"], mpath)
        for key, own in (("file", f"layers/{name}.npy"),
                         ("std_file", f"layers/{name}_std.npy")):
            _member_entry(meta.get(key), f"layer {name!r} {key}", mpath, members)
            need(meta[key] == own, f"layers.{name}.{key}")


def check_heldout_strength(metrics: dict, where: object) -> None:
    """``metrics.heldout_strength``, when present, has every field of :data:`HELDOUT_FIELDS`
    with its type (``localize --method auto`` chooses its method by ``corr_5m``); else a
    :class:`BundleIntegrityError` naming ``where`` and the field."""
    held = metrics.get("heldout_strength")
    if held is None:
        return
    bad = [""] if not isinstance(held, dict) else [
        f".{key}" for key, count in HELDOUT_FIELDS.items()
        if key not in held or not (type(held[key]) is int if count
                                   else held[key] is None or is_json_number(held[key]))]
    if bad:
        raise BundleIntegrityError(f"{where}: field 'metrics.heldout_strength{bad[0]}' is "
                                   "missing or malformed")


def check_layer_kind(name: str, unit: str, kind: str, where: object) -> None:
    """A known layer (:data:`KNOWN_LAYERS`) with its unit and kind, any angle layer in
    degrees; else a :class:`BundleIntegrityError` naming ``where`` and the layer."""
    want, kinds = KNOWN_LAYERS.get(name, ("deg" if kind == "angle" else unit, (kind,)))
    if unit != want or kind not in kinds:
        raise BundleIntegrityError(
            f"{where}: layer {name!r} must have unit {want!r} and kind "
            f"{' or '.join(map(repr, kinds))}, not {unit!r} and {kind!r}")


def check_grid_limits(grid: Grid, where: object) -> None:
    """A grid a localizer can use: cells of :data:`CELL_M_LIMITS`, at most
    :data:`MAX_GRID_CELLS` of them, an origin within :data:`MAX_COORD_M`; else a
    :class:`BundleIntegrityError` naming ``where`` and the field."""
    lo, hi = CELL_M_LIMITS
    if not lo <= grid.cell_m <= hi:
        raise BundleIntegrityError(f"{where}: grid cell_m {grid.cell_m:g} m is outside "
                                   f"{lo:g}-{hi:g} m")
    if grid.width * grid.height > MAX_GRID_CELLS:
        raise BundleIntegrityError(f"{where}: grid width x height is {grid.width} x "
                                   f"{grid.height} cells, over the limit of "
                                   f"{MAX_GRID_CELLS:,}")
    if max(abs(grid.x0_m), abs(grid.y0_m)) > MAX_COORD_M:
        raise BundleIntegrityError(f"{where}: grid origin x0_m, y0_m ({grid.x0_m:g}, "
                                   f"{grid.y0_m:g}) lies beyond {MAX_COORD_M:g} m")


def verify_bundle_dir(path: Path, manifest: dict) -> None:
    """Every listed member present with its size and sha256; nothing else in the folder."""
    members = manifest.get("members")
    if not isinstance(members, dict) or len(members) > MAX_MEMBERS:
        raise BundleIntegrityError(f"{path}: manifest members missing or too many")
    listed = set()
    for name, meta in members.items():
        p = _safe_member(name, path)
        try:
            st = p.stat()
        except FileNotFoundError as err:
            raise BundleIntegrityError(f"{path}: member {name} is missing") from err
        not_regular = f"{path}: member {name} is not a regular file"
        if not stat.S_ISREG(st.st_mode):
            raise BundleIntegrityError(not_regular)
        try:
            same = st.st_size == meta.get("size") and file_sha256(p) == meta.get("sha256")
        except NotRegularFile as err:  # swapped since the stat
            raise BundleIntegrityError(not_regular) from err
        except OSError as err:
            raise BundleIntegrityError(f"{path}: member {name} cannot be read "
                                       f"({err.strerror or err})") from err
        if not same:
            raise BundleIntegrityError(f"{path}: member {name} does not match its checksum "
                                       "(changed or corrupted)")
        listed.add(os.path.normpath(p))
    folders = {os.path.normpath(q) for m in listed for q in Path(m).parents}
    for dirpath, dirnames, filenames in os.walk(path):
        for d in dirnames:
            if Path(dirpath, d).is_symlink():
                raise BundleIntegrityError(f"{path}: link {Path(dirpath, d)} in bundle")
            sub = os.path.normpath(os.path.join(dirpath, d))
            if sub not in folders:
                raise BundleIntegrityError(f"{path}: folder {os.path.relpath(sub, path)} holds "
                                           "no member of the manifest")
        for f in filenames:
            q = os.path.normpath(os.path.join(dirpath, f))
            if q != os.path.normpath(path / "manifest.json") and q not in listed:
                raise BundleIntegrityError(f"{path}: file {os.path.relpath(q, path)} is not "
                                           "listed in the manifest")


def safe_name(name: str) -> str:
    """``name`` if it can name one folder (a site, floor or version); else a RegistryError."""
    if not name or "/" in name or "\\" in name or name in (".", "..") or name.startswith("."):
        raise RegistryError(f"invalid site or floor name {name!r}")
    return name


def read_registry_record(path: Path) -> Any:
    """A registry JSON file's content (``CURRENT``, ``history.json``: regular files of at
    most :data:`MAX_MANIFEST_BYTES`, as the registry writes them); a :class:`RegistryError`
    naming it when damaged, a link, a FIFO or device (never waited on) or too large."""
    try:
        if path.is_symlink():  # a pointer into another floor's or site's folder
            raise NotRegularFile("a link, not the file the registry writes")
        return json.loads(read_regular(path, MAX_MANIFEST_BYTES).decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise RegistryError(f"{path}: damaged registry file ({err})") from err


def read_registry_history(floor_dir: str | os.PathLike) -> list[dict]:
    """The published versions of a registry's floor folder (``REG/<site>/<floor>``, from its
    ``history.json``) in order: ``[{"seq", "bundle_id"}]``, empty before any.

    Raises
    ------
    RegistryError
        A damaged history: not a list of versions with a bundle id and a whole sequence
        number, or two entries with one sequence number or one bundle id.
    """
    path = Path(floor_dir) / "history.json"
    if not path.exists():
        return []
    history = read_registry_record(path)
    if not isinstance(history, list) or not all(
            isinstance(h, dict) and isinstance(h.get("bundle_id"), str)
            and type(h.get("seq")) is int for h in history):
        raise RegistryError(f"{path}: not a registry history (a list of versions with "
                            "bundle_id and seq)")
    if len({h["seq"] for h in history}) != len(history) \
            or len({h["bundle_id"] for h in history}) != len(history):
        raise RegistryError(f"{path}: not a registry history (two entries share a seq or a "
                            "bundle_id)")
    return history


def read_registry_pointer(floor_dir: str | os.PathLike) -> dict | None:
    """A registry floor folder's ``CURRENT`` pointer as written, ``{"bundle_id", "seq"}``
    (and ``rolled_back_from``, the newest version a rollback withdrew, after one), not yet
    checked against the history (:func:`registry_current` does); None when the folder
    has none.

    Raises
    ------
    RegistryError
        A damaged pointer: not an object with a bundle id and a whole sequence number.
    """
    path = Path(floor_dir) / "CURRENT"
    if not path.exists():
        return None
    cur = read_registry_record(path)
    if not isinstance(cur, dict) or not isinstance(cur.get("bundle_id"), str) \
            or type(cur.get("seq")) is not int \
            or type(cur.get("rolled_back_from", 0)) is not int:
        raise RegistryError(f"{path}: not a registry pointer (an object with bundle_id and "
                            "seq, and a whole rolled_back_from after a rollback)")
    return cur


def registry_current(floor_dir: str | os.PathLike, history: list[dict] | None = None
                     ) -> tuple[Path, dict] | None:
    """The current version of a registry's floor folder (``REG/<site>/<floor>``, which holds
    ``CURRENT``): its bundle folder and the pointer ``{"bundle_id", "seq"}``; None when the
    folder has no ``CURRENT``. The pointer must be an entry of ``history.json`` (the same
    sequence number and bundle id; ``history``: as :func:`read_registry_history` read it
    already), so a pointer edited by hand to an older version (a silent rollback) or to an
    unknown sequence number is refused.

    Raises
    ------
    RegistryError
        A damaged pointer or history, a pointer that is no entry of the history, or one at a
        version the registry does not hold.
    """
    path = Path(floor_dir) / "CURRENT"
    cur = read_registry_pointer(floor_dir)
    if cur is None:
        return None
    bundle_id, seq = cur["bundle_id"], cur["seq"]
    version = path.parent / "versions" / safe_name(bundle_id)
    if history is None:
        history = read_registry_history(path.parent)
    by_seq = {h["seq"]: h["bundle_id"] for h in history}
    by_id = {h["bundle_id"]: h["seq"] for h in history}
    if by_seq.get(seq) != bundle_id:
        lost = history_lost(path.parent, history, cur)
        if lost:
            raise RegistryError(lost)
        if bundle_id not in by_id and seq not in by_seq:
            raise RegistryError(f"{path}: points at version {bundle_id[:16]}, which the "
                                f"registry does not hold (history.json has neither #{seq} "
                                "nor that bundle id)")
        listed = (f"lists #{seq} as {by_seq[seq][:16]}" if seq in by_seq else
                  f"has no #{seq}")
        if bundle_id in by_id:
            listed += f" and {bundle_id[:16]} as #{by_id[bundle_id]}"
        raise RegistryError(f"{path}: names version {bundle_id[:16]} as #{seq}, but "
                            f"history.json {listed} (a pointer edited by hand? `indoormap "
                            "bundle use` sets it)")
    if not version.is_dir():
        raise RegistryError(f"{path}: points at version {bundle_id[:16]}, which the "
                            "registry does not hold (its folder is missing)")
    return version, cur


def history_lost(floor_dir: str | os.PathLike, history: list[dict], pointer: dict | None
                 ) -> str | None:
    """What is wrong when a registry floor's ``history.json`` (read as ``history``) has lost
    versions, else None: its ``CURRENT`` (read as ``pointer``) names a version the history
    does not list, whose folder is there, by a newer sequence number than the history's newest
    (the file deleted, emptied or cut). Publishing then would number a new version as an old
    one and move the pointer back, and ``bundle use`` would take the newest listed for the
    newest published."""
    if pointer is None or any(h["seq"] >= pointer["seq"] or h["bundle_id"] == pointer["bundle_id"]
                              for h in history):
        return None
    floor_dir = Path(floor_dir)
    if not (floor_dir / "versions" / safe_name(pointer["bundle_id"])).is_dir():
        return None  # a pointer at no version: said as such
    path = floor_dir / "history.json"
    said = ("is missing" if not path.exists() else "lists no version" if not history
            else f"ends at #{max(h['seq'] for h in history)}")
    return (f"{path}: {said}, but CURRENT names version {pointer['bundle_id'][:16]} as "
            f"#{pointer['seq']} and versions/ holds it: the history lost versions. Restore "
            "history.json (a list of {seq, bundle_id} in publishing order); until then the "
            "registry refuses to publish to this floor or move its pointer")


def finish_publication(folder: Path) -> None:
    """Finish a build's publication into ``folder`` that was killed midway, so that its
    bundles are all of that build (SQLite's readers likewise finish a hot journal).

    Raises
    ------
    BundleError
        It cannot be finished (no write permission, staged bundles gone).
    """
    try:
        finish_interrupted_publication(folder)
    except OSError as exc:  # PublishError included
        raise BundleError(f"{folder}: a build's publication here was interrupted and cannot "
                          f"be finished: {exc}") from exc


#: Members of a bundle folder besides its manifest: a folder holding one but no manifest is
#: a damaged bundle, named as one (it was passed over as no bundle at all).
_BUNDLE_MEMBERS = ("mask.npy", "layers", "tables")


def is_bundle_dir(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a bundle folder (with ``manifest.json``, or without it but with
    another member of a bundle: a damaged one, for the loader to refuse) or a registry floor
    folder (with ``CURRENT``)."""
    path = Path(path)
    return any((path / name).exists() for name in ("manifest.json", "CURRENT")
               + _BUNDLE_MEMBERS)


def is_registry_floor_dir(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a registry's floor folder (``REG/<site>/<floor>``: with
    ``history.json`` or ``versions/``), current version or not."""
    path = Path(path)
    return (path / "history.json").exists() or (path / "versions").is_dir()


def bundle_dirs(path: str | os.PathLike) -> list[Path]:
    """The bundles ``path`` names: itself when it is one (:func:`is_bundle_dir`), else the
    bundle folders directly in it (a build's output, a registry's site folder), sorted;
    empty when there are none. Hidden folders (``.tmp-*``: a bundle being written, or one
    whose writer was killed) are none of them."""
    path = Path(path)
    if not path.exists():  # a bundle a killed build left between two renames (no swap)
        finish_publication(path.parent)
    if is_bundle_dir(path):
        return [path]
    finish_publication(path)
    return _bundles_in(path) if path.is_dir() else []


def _bundles_in(folder: Path) -> list[Path]:
    """The bundle folders directly in ``folder`` (:func:`is_bundle_dir`), sorted; hidden ones
    (``.tmp-*``) are none."""
    return sorted(q for q in folder.iterdir() if not q.name.startswith(".") and is_bundle_dir(q))


def load_bundle(path: str | os.PathLike) -> MapBundle:
    """Open and verify a map bundle folder, or the current version of a registry's floor folder
    (``REG/<site>/<floor>``). Arrays are read-only (the layers memory-mapped).

    Raises
    ------
    BundleError
        Not a bundle, unknown schema version, malformed grid.
    BundleIntegrityError
        Any member changed, missing, unlisted, unsafe, or with a disallowed array header; a
        grid, layer or table whose numbers or schema are out of bounds (naming the table and
        column).
    RegistryError
        A registry floor folder whose ``CURRENT`` is damaged, is no entry of its
        ``history.json`` or points at no version.
    """
    path = Path(path)
    if path.is_file():  # its manifest.json, say: the folder is the bundle
        raise BundleError(f"{path}: a file; a map bundle is a folder"
                          + (f": give {path.parent}" if path.name == "manifest.json" else ""))
    finish_publication(path.parent)
    pointer = None
    if not (path / "manifest.json").exists():
        current = registry_current(path)
        path, pointer = (path, None) if current is None else current
    if path.is_symlink():
        try:
            real = f"; give the folder it links to, {path.resolve(strict=True)}"
        except (OSError, RuntimeError):  # dangling, or a loop of links
            real = ""
        raise BundleIntegrityError(f"{path}: a bundle folder may not be a link{real}")
    manifest = read_manifest(path)
    if pointer is not None and manifest["bundle_id"] != pointer["bundle_id"]:
        raise BundleIntegrityError(f"{path}: holds bundle {manifest['bundle_id'][:16]}, but the "
                                   f"registry's CURRENT names {pointer['bundle_id'][:16]}")
    verify_bundle_dir(path, manifest)
    grid = Grid.from_dict(manifest["grid"]) if manifest.get("grid") is not None else None
    mask = None
    layers: dict[str, np.ndarray] = {}
    std: dict[str, np.ndarray] = {}
    if grid is not None:
        raw = read_npy_checked(_safe_member(manifest["mask"], path))
        if raw.dtype not in (np.bool_, np.uint8) or (raw.dtype == np.uint8 and raw.max(
                initial=0) > 1):
            raise BundleIntegrityError(f"{path}: the mask must hold 0/1 (bool or uint8), got "
                                       f"dtype {raw.dtype}")
        mask = raw.astype(bool)
        mask.flags.writeable = False  # as the layers: a change would reach every localizer
        if mask.shape != grid.shape:
            raise BundleIntegrityError(f"{path}: mask shape {mask.shape} != grid {grid.shape}")
        for name, meta in manifest.get("layers", {}).items():
            for key, target in (("file", layers), ("std_file", std)):
                arr = read_npy_checked(_safe_member(meta[key], path))
                if arr.shape != grid.shape or arr.dtype != np.float32:
                    raise BundleIntegrityError(f"{path}: layer {name} {key} has shape "
                                               f"{arr.shape} {arr.dtype}, expected {grid.shape}"
                                               " float32")
                check_layer_values(arr, path, name, key, meta["unit"])
                target[name] = arr
    tables = read_checked_tables(path, manifest)
    return MapBundle(path, manifest, grid, mask, layers, std, tables)


def check_layer_values(arr: np.ndarray, path: object, name: str, key: str, unit: str) -> None:
    """No infinite value (NaN is the only nodata), values within :data:`LAYER_LIMITS` of
    their ``unit``, uncertainties within [0, :data:`MAX_LAYER_STD`]: two NaN-skipping reductions,
    no temporary array."""
    low, high = float(np.fmin.reduce(arr, axis=None)), float(np.fmax.reduce(arr, axis=None))
    if math.isinf(low) or math.isinf(high):
        raise BundleIntegrityError(f"{path}: layer {name} {key} holds infinite values (NaN is "
                                   "the only nodata)")
    if key == "std_file":
        limits = (0.0, MAX_LAYER_STD)
    else:
        limit = LAYER_LIMITS.get(unit, math.inf)
        limits = (-limit, limit)
    if low < limits[0] or high > limits[1]:  # False for NaN: a layer without data
        raise BundleIntegrityError(f"{path}: layer {name} {key} holds values from {low:g} to "
                                   f"{high:g}, outside {limits[0]:g} to {limits[1]:g}"
                                   + ("" if key == "std_file" else f" {unit}"))


def _schema_of(name: str) -> str:
    """The :data:`TABLE_SCHEMAS` key of a table name; "" when unchecked."""
    kind, _, rest = name.partition("_")
    if kind in RADIO_KINDS and f"<kind>_{rest}" in TABLE_SCHEMAS:
        return f"<kind>_{rest}"
    return name if name in TABLE_SCHEMAS else ""


def read_checked_tables(path: Path, manifest: dict) -> dict[str, pa.Table]:
    """The bundle's tables that :data:`TABLE_SCHEMAS` describes, read and checked: exact
    columns and types, no null where none may be, numbers finite and within their range, keys
    unique, fingerprint rows of known reference points, a radio kind's three tables together
    and not empty; every table's row count the manifest's. Other tables (a reader ignores a
    table it does not use) are checked for their row count only.

    Raises
    ------
    BundleIntegrityError
        Naming the bundle, the table and the column.
    """
    tables = manifest.get("tables", {})
    if not tables:
        return {}
    out: dict[str, pa.Table] = {}
    for name, meta in tables.items():
        key = _schema_of(name)
        table, rows = read_table_file(path, name, meta["file"], rows_only=not key)
        if rows != meta["rows"]:
            raise BundleIntegrityError(f"{path}: table {name!r} has {rows} rows, the manifest "
                                       f"says {meta['rows']}")
        if key:
            out[name] = table
    check_tables(out, path)
    return out


def read_table_file(path: Path, name: str, file: str, *, rows_only: bool = False
                    ) -> tuple[pa.Table | None, int]:
    """The bundle at ``path``'s table ``name`` from its member ``file`` (Parquet, page
    checksums verified) and its row count; ``rows_only``: the count alone (table None). A
    :class:`BundleIntegrityError` names the bundle and table of a file that cannot be read."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:  # ParquetFile.read: half the time of read_table (no dataset layer; no pandas)
        with pq.ParquetFile(_safe_member(file, path), page_checksum_verification=True) as pf:
            return (None if rows_only else pf.read(use_threads=False)), pf.metadata.num_rows
    except (OSError, pa.ArrowException) as err:
        raise BundleIntegrityError(f"{path}: table {name!r} is not a readable Parquet file "
                                   f"({err})") from err


def check_tables(tables: dict[str, pa.Table], where: object) -> None:
    """The tables :data:`TABLE_SCHEMAS` describes (others are ignored) as
    :func:`read_checked_tables` checks them, in memory (the bundle writer refuses to write
    what a reader would refuse); a :class:`BundleIntegrityError` naming ``where``, the table
    and the column."""
    for name, table in tables.items():
        key = _schema_of(name)
        if key:
            _check_table(table, where, name, key)
    for kind in RADIO_KINDS:
        _check_radio_tables(tables, where, kind)


def _check_table(table: pa.Table, path: object, name: str, key: str) -> None:
    """One table against its :data:`TABLE_SCHEMAS` entry (see :func:`read_checked_tables`)."""
    import pyarrow as pa

    from localize.arrow_numpy import numeric_column

    schema = TABLE_SCHEMAS[key]
    where = f"{path}: table {name!r}"
    have = table.column_names
    optional = _OPTIONAL.get(key, set())
    missing = [c for c in schema if c not in have and c not in optional]
    extra = [c for c in have if c not in schema]
    if missing or extra or len(set(have)) != len(have):
        raise BundleIntegrityError(f"{where}: columns {have} are not the schema's "
                                   f"{list(schema)} (missing {missing}, unexpected {extra})")
    if table.num_rows == 0:
        return  # an empty pandas column has no type to keep (written as double or null)
    for col in have:
        want, nullable, (low, high) = schema[col]
        column = table.column(col)
        typ = column.type
        ok_type = (pa.types.is_string(typ) or pa.types.is_large_string(typ)) \
            if want == _TEXT else str(typ) == want
        if not ok_type:
            raise BundleIntegrityError(f"{where} column {col!r}: type {typ}, expected "
                                       f"{'string' if want == _TEXT else want}")
        if not nullable and column.null_count:
            raise BundleIntegrityError(f"{where} column {col!r}: {column.null_count} null "
                                       "values")
        if want == _TEXT:
            continue
        values = numeric_column(column).astype(np.float64)  # nulls as NaN
        good = np.isfinite(values) & (values >= low) & (values <= high)
        if nullable:
            good |= np.isnan(values)
        if not good.all():
            bad = values[~good][0]
            raise BundleIntegrityError(
                f"{where} column {col!r}: {int((~good).sum())} values are not finite numbers "
                f"within {low:g} to {high:g} (e.g. {bad:g})")
    keys = _TABLE_KEYS.get(key)
    if keys and _has_duplicates(table, keys):
        raise BundleIntegrityError(f"{where}: duplicate rows for the key {list(keys)}")


def _has_duplicates(table: pa.Table, keys: tuple[str, ...]) -> bool:
    """Whether two rows share their ``keys`` values (integer or text columns), vectorized:
    each row's key columns packed into one integer of dense codes (pyarrow's ``group_by``
    takes 100 ms more on an ILC floor's fingerprints)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from localize.arrow_numpy import numeric_column

    code = np.zeros(table.num_rows, dtype=np.int64)
    for col in keys:
        column = table.column(col)
        if pa.types.is_integer(column.type):
            _, values = np.unique(numeric_column(column), return_inverse=True)
        else:  # text: the index of each row's value among the distinct ones, already dense
            values = numeric_column(
                pc.dictionary_encode(column.combine_chunks()).indices).astype(np.int64)
        code = code * (int(values.max(initial=0)) + 1) + values.ravel()
    return len(np.unique(code)) != len(code)


def _check_radio_tables(tables: dict[str, pa.Table], path: object, kind: str) -> None:
    """A radio kind's ``<kind>_rp``, ``<kind>_fp`` and ``<kind>_meta`` together, not empty (a
    floor without rows of the kind has none of its tables), fingerprints of known reference
    points, the meta table one row of its kind."""
    from localize.arrow_numpy import numeric_column

    names = [f"{kind}_{t}" for t in ("rp", "fp", "meta")]
    present = [n for n in names if n in tables]
    if not present:
        return
    if len(present) != len(names):
        raise BundleIntegrityError(f"{path}: tables {present} without "
                                   f"{[n for n in names if n not in present]}")
    rp, fp, meta = (tables[n] for n in names)
    for name, table in zip(names, (rp, fp)):
        if table.num_rows == 0:
            raise BundleIntegrityError(
                f"{path}: table {name!r} has no rows (a floor without {kind} fingerprints has "
                f"no {kind} tables)")
    known = numeric_column(rp.column("rp_id"))
    if not np.isin(numeric_column(fp.column("rp_id")), known).all():
        raise BundleIntegrityError(f"{path}: table {names[1]!r} column 'rp_id' names reference "
                                   f"points that {names[0]!r} lacks")
    if meta.num_rows != 1 or meta.column("kind")[0].as_py() != kind:
        raise BundleIntegrityError(f"{path}: table {names[2]!r} column 'kind' must be one row "
                                   f"{kind!r}")
