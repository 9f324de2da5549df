"""Raster grids over a floor and the reachable-area mask."""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray

from localize.bundle import MAX_GRID_CELLS, Grid


def grid_for_extent(width_m: float, height_m: float, cell_m: float = 0.5, *,
                    x0_m: float = 0.0, y0_m: float = 0.0) -> Grid:
    """A grid covering ``[x0, x0 + width] x [y0, y0 + height]`` metres with square cells.

    Raises
    ------
    ValueError
        A cell size that is not positive and finite, or a grid of more than
        :data:`MAX_GRID_CELLS` cells.
    """
    if not (np.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell size must be positive and finite, got {cell_m}")
    cols, rows = np.ceil(width_m / cell_m), np.ceil(height_m / cell_m)  # inf for 1e-320 m
    if not cols * rows <= MAX_GRID_CELLS:
        raise ValueError(f"a {width_m:g} x {height_m:g} m floor at {cell_m:g} m cells is "
                         f"{cols * rows:,.0f} cells, over the limit of {MAX_GRID_CELLS:,}")
    return Grid(float(x0_m), float(y0_m), float(cell_m), int(cols), int(rows))


#: Crossings (edge x row pairs) per chunk of :func:`reachable_mask`'s scan (about 100 MB of
#: temporaries at most, 124 MB peak measured on a tall grid, however long the outline and tall
#: the grid), and cells per block of its sums.
_CROSSINGS_PER_CHUNK = 1 << 20

_COLLECTION_TYPES = (4, 5, 6, 7)  # Multi* and GeometryCollection (shapely.get_type_id)


def reachable_distance_raster_m(grid: Grid, mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Distance (m, in whole cells) from each cell to the nearest reachable cell of ``mask``,
    the grid's shape (0 on the mask)."""
    from scipy import ndimage

    return ndimage.distance_transform_edt(~mask) * grid.cell_m


def distance_to_reachable_m(grid: Grid, mask: NDArray[np.bool_], x_m: NDArray,
                            y_m: NDArray) -> NDArray[np.float64]:
    """Distance (m, in whole cells) from each position ``(x_m, y_m)`` (shape (n,)) to the
    nearest reachable cell of ``mask`` (the grid's shape); inf off the grid, 0 on the mask.
    For several lookups on one mask, :func:`reachable_distance_raster_m` once."""
    dist = reachable_distance_raster_m(grid, mask)
    row, col, inside = grid.cell_of(x_m, y_m)
    return np.where(inside, dist[row, col], np.inf)


def reachable_mask(grid: Grid, reachable: shapely.Geometry) -> NDArray[np.bool_]:
    """Cells whose centre lies in the reachable area, shape (height, width); vectorized.

    Equal to ``shapely.contains_xy(reachable, x, y)`` at the cell centres
    (:meth:`Grid.cell_centers`; row 0 the south edge): a centre on the boundary is not in
    the area. The polygons are rastered by scanlines in numpy instead (every ring edge is
    crossed with the rows of centres in its half-open y range, winding numbers summed along x;
    0.1 s for a 20 M-cell floor where ``contains_xy`` at every centre took ~14 s), and the few
    centres within ~1e-9 m of the boundary (a crossing, a vertex, a horizontal edge on a row)
    are tested with ``shapely.contains_xy``. Memory: an int16 array of the grid's shape (int32
    when a row is crossed 32768 times or more) and the boolean mask, plus temporaries that grow
    with the area's vertices, not with the grid.

    Polygons of a collection are united (a centre in any of them is in the area; holes subtract
    from their own polygon only), as GEOS does for a ``GeometryCollection`` and as the polygons
    of a valid ``MultiPolygon`` are; points and lines have no area and only centres on them
    count. Invalid polygons (a self-intersecting ring, overlapping polygons of a
    ``MultiPolygon``, overlapping holes) may differ from GEOS, whose answer there is undefined:
    rings count by winding number, so only one loop of a bow-tie is in, and overlapping
    polygons are united where GEOS alternates. :func:`mapping.floorplan.read_floor_plan`
    repairs such polygons, and ``FloorPlan.reachable`` is an overlay's valid output.
    """
    xc, yc = grid.cell_centers()
    parts = np.atleast_1d(shapely.get_parts(reachable))
    while parts.size and np.isin(shapely.get_type_id(parts), _COLLECTION_TYPES).any():
        parts = shapely.get_parts(parts)
    kind = shapely.get_type_id(parts)
    polygons, lines = parts[kind == 3], parts[(kind == 1) | (kind == 2)]
    coords = shapely.get_coordinates(parts)
    if not len(coords):
        return np.zeros(grid.shape, dtype=bool)
    # a crossing or vertex this close to a centre is re-tested exactly (x_cross is a few ulps off)
    tol = 1e-9 * max(1.0, float(np.abs(coords).max()) / 1e3)

    rings, of_polygon = shapely.get_rings(polygons, return_index=True)
    exterior = np.ones(len(rings), dtype=bool)
    exterior[1:] = of_polygon[1:] != of_polygon[:-1]
    # +1 inside a shell, -1 inside a hole, however the rings turn
    turn = np.where(exterior, 1, -1) * np.where(shapely.is_ccw(rings), 1, -1)
    ends_p, ring_of = shapely.get_coordinates(rings, return_index=True)
    ends_l, line_of = shapely.get_coordinates(lines, return_index=True)
    ends = np.concatenate([ends_p, ends_l])
    path_of = np.concatenate([ring_of, line_of + len(rings)])
    weight = np.concatenate([turn, np.zeros(len(lines), dtype=turn.dtype)])  # lines: no area
    edge = np.flatnonzero(path_of[1:] == path_of[:-1])
    (x1, y1), (x2, y2) = ends[edge].T, ends[edge + 1].T
    # a ring turning counterclockwise goes down (y2 < y1) on its area's west side
    w = (weight[path_of[edge]] * np.sign(y1 - y2)).astype(np.int16)

    candidates = [_near_centres(xc, yc, coords[:, 0], coords[:, 1], tol)]
    horizontal = y1 == y2  # crosses no row; only the centres on it are re-tested
    candidates.append(_horizontal_edge_centres(xc, yc, x1[horizontal], x2[horizontal],
                                               y1[horizontal], tol))
    keep = ~horizontal
    x1, y1, x2, y2, w = x1[keep], y1[keep], x2[keep], y2[keep], w[keep]
    # rows whose centre y is in [min(y1, y2), max(y1, y2)): the same rows as a ray test
    lo = np.searchsorted(yc, np.minimum(y1, y2), side="left")
    hi = np.searchsorted(yc, np.maximum(y1, y2), side="left")
    n = hi - lo
    # Winding-number steps, summed along each row. int16 wraps harmlessly while every partial
    # sum of a row stays within +-32767, i.e. while no row is crossed 32768 times or more (a
    # collection of that many overlapping polygons, or such a self-intersecting ring); else
    # int32 (twice the memory).
    deepest = len(lo)  # no row is crossed by more edges than there are
    if deepest >= 1 << 15:
        deepest = int(np.cumsum(np.bincount(lo, minlength=grid.height + 1)
                                - np.bincount(hi, minlength=grid.height + 1)).max())
    acc = np.zeros(grid.shape, dtype=np.int16 if deepest < 1 << 15 else np.int32)
    slope = (x2 - x1) / (y2 - y1)
    end = np.cumsum(n)  # crossings of edges [0, e]
    total = int(end[-1]) if len(end) else 0
    for start in range(0, total, _CROSSINGS_PER_CHUNK):
        k = np.arange(start, min(start + _CROSSINGS_PER_CHUNK, total))
        e = np.searchsorted(end, k, side="right")  # the edge of crossing k
        row = lo[e] + k - (end[e] - n[e])
        x = x1[e] + (yc[row] - y1[e]) * slope[e]
        col = np.searchsorted(xc, x, side="right")  # first centre east of the crossing
        on_grid = col < grid.width
        np.add.at(acc, (row[on_grid], col[on_grid]), w[e[on_grid]])
        west, east = xc[np.maximum(col - 1, 0)], xc[np.minimum(col, grid.width - 1)]
        near = ((col > 0) & (west >= x - tol)) | (on_grid & (east <= x + tol))
        candidates.append(_near_centres(xc, yc, x[near], yc[row[near]], tol))
    mask = np.empty(grid.shape, dtype=bool)
    step = max(1, _CROSSINGS_PER_CHUNK // grid.width)  # rows summed at a time: no full copy
    for a in range(0, grid.height, step):
        mask[a:a + step] = np.cumsum(acc[a:a + step], axis=1, dtype=acc.dtype) > 0
    del acc
    rc = np.unique(np.concatenate(candidates))
    if len(rc):
        i, j = np.divmod(rc, grid.width)
        if len(rc) > 64:
            shapely.prepare(reachable)
        mask[i, j] = shapely.contains_xy(reachable, xc[j], yc[i])
    return mask


def _near_centres(xc: NDArray[np.float64], yc: NDArray[np.float64], x: NDArray[np.float64],
                  y: NDArray[np.float64], tol: float) -> NDArray[np.int64]:
    """Flat indices of the centres within ``tol`` (m) of the points in x and in y."""
    j, i = _near_index(xc, x, tol), _near_index(yc, y, tol)
    both = (j >= 0) & (i >= 0)
    return i[both] * len(xc) + j[both]


def _near_index(c: NDArray[np.float64], v: NDArray[np.float64], tol: float) -> NDArray[np.int64]:
    """Index into the ascending ``c`` of the value nearest each ``v``, -1 where over ``tol``."""
    k = np.searchsorted(c, v)
    below, above = np.maximum(k - 1, 0), np.minimum(k, len(c) - 1)
    k = np.where(np.abs(c[below] - v) < np.abs(c[above] - v), below, above)
    return np.where(np.abs(c[k] - v) <= tol, k, -1)


def _horizontal_edge_centres(xc: NDArray[np.float64], yc: NDArray[np.float64],
                             x1: NDArray[np.float64], x2: NDArray[np.float64],
                             y: NDArray[np.float64], tol: float) -> NDArray[np.int64]:
    """Flat indices of the centres on (within ``tol`` of) horizontal edges."""
    i = _near_index(yc, y, tol)
    on_row = i >= 0
    i, x1, x2 = i[on_row], x1[on_row], x2[on_row]
    a = np.searchsorted(xc, np.minimum(x1, x2) - tol, side="left")
    b = np.searchsorted(xc, np.maximum(x1, x2) + tol, side="right")
    k = b - a
    e = np.repeat(np.arange(len(k)), k)
    j = a[e] + np.arange(len(e)) - np.repeat(np.cumsum(k) - k, k)
    return i[e] * len(xc) + j
