"""Fast raster lookups for the particle filter: the needed layers in one interleaved array.

:meth:`MapBundle.sample` is general; the filter looks up the same few layers at up to millions
of points per tick, so :class:`FilterMap` packs them once into a channel-major array over the
padded grid and does one 4-corner bilinear gather for all of them:

- a scalar layer is stored as ``value x validity`` and divided by the interpolated validity of
  its support (layers sharing a support share that channel);
- an angle layer is stored as ``sin x validity`` and ``cos x validity`` (``atan2`` needs no
  normalisation).

The result follows :meth:`MapBundle.sample`: NaN where the point's own cell is off the mask or
without data, neighbour cells without data drop out (weights renormalised), angles are
interpolated as unit vectors.

Reachability is the bundle mask, looked up per cell. :meth:`FilterMap.segment_free` tests points
at most one cell apart along each straight move (a wall at least one cell thick along the move
stops it; a move may still clip the corner of a wall diagonally).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass
from weakref import WeakKeyDictionary

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import MapBundle
from localize.errors import LocalizationError

__all__ = ["FilterMap", "LayerSpec", "mean_heading_offset_deg"]

#: Padding (cells) around the grid: points this far outside still index without clipping.
PAD = 8


@dataclass(frozen=True)
class LayerSpec:
    """Where a packed quantity lives."""

    name: str
    kind: str    # "scalar" or "angle"
    first: int   # channel of value*valid (scalar) or of sin*valid (angle; cos is first + 1)
    norm: int    # channel of the interpolated support (scalar layers), -1 for angles
    support: int  # index of the layer's support in FilterMap._supports


def _floats(a) -> NDArray:
    """float32 and float64 arrays as they are, anything else as float64."""
    a = np.asarray(a)
    return a if a.dtype in (np.float32, np.float64) else a.astype(np.float64)


#: Per bundle: its :func:`mean_heading_offset_deg`, computed once (the multi-user servers
#: make an aligner per user, the CLI a filter map, an aligner and a compass check per walk).
_OFFSET_CACHE: WeakKeyDictionary[MapBundle, float] = WeakKeyDictionary()


def mean_heading_offset_deg(bundle: MapBundle) -> float:
    """The floor's heading offset (deg, compass heading minus walking direction): the circular
    mean of its ``heading_offset`` layer over the reachable cells (0 without one). The map's
    turn from magnetic north and the declination, a few degrees on ILC site1 (lon/lat plans)
    and any angle for a plan drawn along its building."""
    if bundle not in _OFFSET_CACHE:
        offset = 0.0
        if "heading_offset" in bundle.layers:
            v = np.asarray(bundle.layers["heading_offset"], dtype=np.float64)
            v = np.radians(v[np.asarray(bundle.mask, dtype=bool) & np.isfinite(v)])
            if v.size:
                offset = float(np.degrees(np.arctan2(np.sin(v).sum(), np.cos(v).sum())))
        _OFFSET_CACHE[bundle] = offset
    return _OFFSET_CACHE[bundle]


class FilterMap:
    """Packed layers of a floor bundle for vectorized lookups in metres.

    Parameters
    ----------
    bundle : MapBundle
        A floor bundle (with a grid and a mask).
    layers : sequence of str
        Layers to pack; layers missing from the bundle are skipped (:meth:`has` tells).
    std_layers : sequence of str
        Layers whose uncertainty raster is also packed (key ``"<name>_std"``).
    dtype : numpy dtype
        Channel dtype; float32 halves the memory traffic of a lookup.
    """

    def __init__(self, bundle: MapBundle, layers=("strength", "azimuth", "polar",
                                                   "heading_offset"),
                 std_layers=(), dtype=np.float32) -> None:
        if bundle.grid is None or bundle.mask is None:
            raise LocalizationError(f"{bundle.path}: a site-level bundle has no rasters; open "
                                    "a floor bundle")
        g = bundle.grid
        self.grid = g
        self.x0, self.y0, self.cell = float(g.x0_m), float(g.y0_m), float(g.cell_m)
        self.height, self.width = g.height, g.width
        self.dtype = np.dtype(dtype)
        mask = np.asarray(bundle.mask, dtype=bool)
        ph, pw = g.height + 2 * PAD, g.width + 2 * PAD
        self._row_stride = pw
        self._shape_padded = (ph, pw)
        self._mask_flat = self._pad(mask, False).ravel()

        channels: list[np.ndarray] = []
        supports: list[np.ndarray] = []
        support_norm: list[int] = []
        self.specs: dict[str, LayerSpec] = {}
        wanted = [(n, False) for n in layers] + [(n, True) for n in std_layers]
        for name, is_std in wanted:
            src = bundle.std if is_std else bundle.layers
            if name not in src:
                continue
            meta = bundle.manifest["layers"][name]
            values = np.asarray(src[name], dtype=np.float64)
            valid = mask & np.isfinite(values)
            s_id = next((i for i, s in enumerate(supports) if np.array_equal(s, valid)), -1)
            if s_id < 0:
                supports.append(valid)
                support_norm.append(-1)
                s_id = len(supports) - 1
            key = f"{name}_std" if is_std else name
            kind = "angle" if (meta.get("kind") == "angle" and not is_std) else "scalar"
            first = len(channels)
            if kind == "angle":
                r = np.radians(np.where(valid, values, 0.0))
                channels += [np.sin(r) * valid, np.cos(r) * valid]
                norm = -1
            else:
                channels.append(np.where(valid, values, 0.0))
                if support_norm[s_id] < 0:
                    channels.append(valid.astype(np.float64))
                    support_norm[s_id] = len(channels) - 1
                norm = support_norm[s_id]
            self.specs[key] = LayerSpec(key, kind, first, norm, s_id)
        c = max(len(channels), 1)
        packed = np.zeros((c, ph, pw), dtype=self.dtype)
        for k, ch in enumerate(channels):
            packed[k] = self._pad(ch, 0.0)
        self.n_channels = c
        self._packed = packed.reshape(c, -1)
        self._supports = [self._pad(s, False).ravel() for s in supports]
        # the fallback where the raster has no data
        self.mean_heading_offset_deg = mean_heading_offset_deg(bundle)
        ys, xs = np.nonzero(mask.T)[::-1]  # ordered by column: x bands by searchsorted
        self.reachable_cells_xy = np.column_stack([self.x0 + (xs + 0.5) * self.cell,
                                                   self.y0 + (ys + 0.5) * self.cell])
        self._inv = 1.0 / self.cell

    def _pad(self, a: np.ndarray, fill) -> np.ndarray:
        out = np.full(self._shape_padded, fill, dtype=np.asarray(a).dtype)
        out[PAD:PAD + self.height, PAD:PAD + self.width] = a
        return out

    # ----------------------------------------------------------------------------------------
    def has(self, key: str) -> bool:
        """Whether a layer (or ``"<layer>_std"``) was packed."""
        return key in self.specs

    @property
    def nbytes(self) -> int:
        return int(self._packed.nbytes + self._mask_flat.nbytes
                   + sum(s.nbytes for s in self._supports))

    def _own_index(self, x: NDArray, y: NDArray) -> NDArray[np.intp]:
        """Flat index into the padded arrays of each point's own cell (clipped to the
        padding, which is unreachable and without data)."""
        # truncation = floor for values >= 0; float32 input stays float32 (ample for cells)
        col = ((x - self.x0) * self._inv + PAD).astype(np.intp)
        row = ((y - self.y0) * self._inv + PAD).astype(np.intp)
        np.minimum(col, self._row_stride - 1, out=col)
        np.maximum(col, 0, out=col)
        np.minimum(row, self._shape_padded[0] - 1, out=row)
        np.maximum(row, 0, out=row)
        row *= self._row_stride
        row += col
        return row

    def reachable(self, x_m: NDArray, y_m: NDArray) -> NDArray[np.bool_]:
        """Whether each point lies in a reachable cell (any shape)."""
        return self._mask_flat[self._own_index(_floats(x_m), _floats(y_m))]

    def segment_free(self, x0: NDArray, y0: NDArray, x1: NDArray, y1: NDArray,
                     max_len_m: float | None = None) -> NDArray[np.bool_]:
        """Whether the straight segments from (x0, y0) to (x1, y1) stay on reachable cells.

        The end point and points at most one cell apart along the segment are tested (the
        start is assumed reachable). ``max_len_m`` bounds the segment length (computed when
        omitted); only segments whose end is reachable are tested further.
        """
        x0, y0, x1, y1 = (_floats(a) for a in (x0, y0, x1, y1))
        ok = self.reachable(x1, y1)
        if max_len_m is None:
            max_len_m = float(np.max(np.hypot(x1 - x0, y1 - y0), initial=0.0))
        k = int(np.ceil(max_len_m / self.cell))
        if k <= 1:
            return ok
        sel = np.flatnonzero(ok.ravel())
        if len(sel) == 0:
            return ok
        a0, b0 = x0.ravel()[sel], y0.ravel()[sel]
        dx, dy = x1.ravel()[sel] - a0, y1.ravel()[sel] - b0
        f = (np.arange(1, k) / k).astype(a0.dtype)[:, None]
        inner = self.reachable(a0 + f * dx, b0 + f * dy).all(axis=0)
        flat = ok.ravel().copy()
        flat[sel] = inner
        return flat.reshape(ok.shape)

    def lookup(self, x_m: NDArray, y_m: NDArray) -> NDArray:
        """Bilinear interpolation of every channel at points (flattened).

        Returns
        -------
        ndarray, shape (C, n), dtype of the map
            Interpolated channels; turn them into layer values with :meth:`values`.
        """
        x = _floats(x_m).ravel()
        y = _floats(y_m).ravel()
        n = len(x)
        fx = (x - self.x0) * self._inv + (PAD - 0.5)
        fy = (y - self.y0) * self._inv + (PAD - 0.5)
        np.clip(fx, 0.0, self._row_stride - 2.0, out=fx)
        np.clip(fy, 0.0, self._shape_padded[0] - 2.0, out=fy)
        j0 = fx.astype(np.intp)
        i0 = fy.astype(np.intp)
        wx = (fx - j0).astype(self.dtype)
        wy = (fy - i0).astype(self.dtype)
        s = self._row_stride
        base = i0 * s + j0
        corners = np.concatenate([base, base + 1, base + s, base + s + 1])
        g = np.take(self._packed, corners, axis=1).reshape(self.n_channels, 4, n)
        ux, uy = 1.0 - wx, 1.0 - wy
        w4 = np.concatenate([ux * uy, wx * uy, ux * wy, wx * wy]).reshape(4, n)
        return np.einsum("ckn,kn->cn", g, w4)

    def values(self, acc: NDArray, own_valid: NDArray[np.bool_], key: str) -> NDArray:
        """A layer's values (deg for angles, in [-180, 180]) from :meth:`lookup` output
        ``acc`` (C, n); ``own_valid`` (n,) is the layer's support at each point's own cell."""
        spec = self.specs[key]
        if spec.kind == "angle":
            out = np.degrees(np.arctan2(acc[spec.first], acc[spec.first + 1]))
            good = own_valid
        else:
            wsum = acc[spec.norm]
            good = own_valid & (wsum > 1e-6)
            with np.errstate(invalid="ignore", divide="ignore"):
                out = acc[spec.first] / wsum
        return np.where(good, out, np.float32(np.nan))

    def sample(self, key: str, x_m: ArrayLike, y_m: ArrayLike) -> NDArray[np.float64]:
        """One layer at points (convenience; the filter batches layers with
        :meth:`sample_many`)."""
        return np.asarray(self.sample_many([key], x_m, y_m)[key], dtype=np.float64)

    def vector(self, acc: NDArray, own_valid: NDArray[np.bool_], key: str
               ) -> tuple[NDArray, NDArray]:
        """An angle layer as the unit vector ``(sin, cos)`` of the interpolated angle (NaN where
        undefined); cheaper than :meth:`values` when the caller needs sin and cos anyway."""
        spec = self.specs[key]
        s, c = acc[spec.first], acc[spec.first + 1]
        norm = np.sqrt(s * s + c * c)
        good = own_valid & (norm > 1e-6)
        inv = np.where(good, 1.0 / np.where(good, norm, 1.0), np.nan).astype(s.dtype)
        return s * inv, c * inv

    def sample_many(self, keys: Iterable[str], x_m: ArrayLike, y_m: ArrayLike,
                    vectors: Collection[str] = ()) -> dict:
        """Several layers at once; each result has the broadcast shape of ``x_m, y_m``.
        Angles in degrees, NaN where undefined (as :meth:`MapBundle.sample`); angle layers
        named in ``vectors`` come as a ``(sin, cos)`` pair instead (see :meth:`vector`)."""
        x = _floats(x_m)
        y = _floats(y_m)
        shape = np.broadcast(x, y).shape
        x = np.broadcast_to(x, shape).ravel()
        y = np.broadcast_to(y, shape).ravel()
        acc = self.lookup(x, y)
        own = self._own_index(x, y)
        support_cache: dict[int, NDArray[np.bool_]] = {}
        out = {}
        for k in keys:
            spec = self.specs[k]
            if spec.support not in support_cache:
                support_cache[spec.support] = self._supports[spec.support][own]
            valid = support_cache[spec.support]
            if k in vectors and spec.kind == "angle":
                s, c = self.vector(acc, valid, k)
                out[k] = (s.reshape(shape), c.reshape(shape))
            else:
                out[k] = self.values(acc, valid, k).reshape(shape)
        return out

    def random_reachable(self, rng: np.random.Generator, n: int, cx: float, cy: float,
                         half_width_m: float) -> tuple[NDArray, NDArray] | None:
        """``n`` points uniform on the reachable part of the square of half-width
        ``half_width_m`` around (cx, cy); None when that part is empty.

        Cells are chosen uniformly among reachable cells inside the square, then a uniform
        point inside the cell (so the draw does not depend on rejection luck).
        """
        c = self.reachable_cells_xy
        lo, hi = np.searchsorted(c[:, 0], [cx - half_width_m, cx + half_width_m + 1e-9])
        band = c[lo:hi]
        cand = band[np.abs(band[:, 1] - cy) <= half_width_m]
        if len(cand) == 0:
            return None
        pick = cand[rng.integers(0, len(cand), n)]
        off = (rng.random((n, 2)) - 0.5) * self.cell
        return pick[:, 0] + off[:, 0], pick[:, 1] + off[:, 1]
