"""Raster grids over a floor and the reachable-area mask."""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray

from localize.bundle import Grid


def grid_for_extent(width_m: float, height_m: float, cell_m: float = 0.5, *,
                    x0_m: float = 0.0, y0_m: float = 0.0) -> Grid:
    """A grid covering ``[x0, x0 + width] x [y0, y0 + height]`` metres with square cells."""
    if cell_m <= 0:
        raise ValueError(f"cell size must be positive, got {cell_m}")
    return Grid(float(x0_m), float(y0_m), float(cell_m), int(np.ceil(width_m / cell_m)),
                int(np.ceil(height_m / cell_m)))


def reachable_mask(grid: Grid, reachable: shapely.Geometry) -> NDArray[np.bool_]:
    """Cells whose centre lies in the reachable area, shape (height, width); vectorized."""
    xc, yc = grid.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    shapely.prepare(reachable)
    return shapely.contains_xy(reachable, xx, yy)
