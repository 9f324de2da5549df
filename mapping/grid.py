"""Raster grids over a floor and the reachable-area mask."""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray

from localize.bundle import Grid


#: Most cells a floor's grid may have (a float32 layer of them is 80 MB; the build keeps a
#: dozen layers and cross-validates on full grids).
MAX_GRID_CELLS = 20_000_000


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


def reachable_mask(grid: Grid, reachable: shapely.Geometry) -> NDArray[np.bool_]:
    """Cells whose centre lies in the reachable area, shape (height, width); vectorized."""
    xc, yc = grid.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    shapely.prepare(reachable)
    return shapely.contains_xy(reachable, xx, yy)
