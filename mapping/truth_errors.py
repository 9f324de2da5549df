"""Built maps against a known (simulated) field: the errors on the cells a survey walked.

Pure computation, used by the build tests and ``benchmarks/map_truth.py``. ``field`` is any
object with ``field_earth_ut(x_m, y_m) -> (n, 3)`` (uT, east, north, up) and
``compass_deviation_deg(x_m, y_m) -> (n,)`` (deg), e.g. :func:`survey.sim.site.load_field`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localize.bundle import Grid, sample_grid
from survey.field_features import wrap_deg

__all__ = ["TruthErrors", "surveyed_cells", "truth_errors"]


def surveyed_cells(grid: Grid, true_xy_m: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Cells of ``grid`` that the true positions (n, 2) (m) pass through, shape ``grid.shape``."""
    xy = np.asarray(true_xy_m, dtype=np.float64).reshape(-1, 2)
    row, col, inside = grid.cell_of(xy[:, 0], xy[:, 1])
    out = np.zeros(grid.shape, bool)
    out[row[inside], col[inside]] = True
    return out


@dataclass(frozen=True)
class TruthErrors:
    """Map minus truth on the surveyed cells where the layer has a value.

    Attributes
    ----------
    strength_ut : ndarray, shape (n,)
        Strength layer minus the true field's strength (uT).
    heading_offset_deg : ndarray, shape (m,)
        Heading-offset layer plus the true compass deviation, wrapped to [-180, 180) (deg): the
        layer is compass minus true heading, i.e. minus the deviation.
    surveyed : int
        Surveyed cells (with or without a map value).
    strength_walked_ut : ndarray, shape (k,)
        The strength layer looked up bilinearly at the true positions themselves (as
        :meth:`localize.bundle.MapBundle.sample` reads it) minus the true strength there, at
        the positions where the lookup has a value (uT).
    """

    strength_ut: NDArray[np.float64]
    heading_offset_deg: NDArray[np.float64]
    surveyed: int
    strength_walked_ut: NDArray[np.float64]


def truth_errors(grid: Grid, layers: dict, field: Any, true_xy_m: NDArray[np.float64]
                 ) -> TruthErrors:
    """Errors of the ``strength`` and ``heading_offset`` layers (objects with ``values`` of the
    grid's shape, e.g. :class:`mapping.bundle_writer.Layer`) on the cells the true positions
    (n, 2) (m) cross (cell values against the truth at the cell centres), and of the strength
    looked up at those positions."""
    surveyed = surveyed_cells(grid, true_xy_m)
    xc, yc = grid.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    strength = layers["strength"].values
    sel = surveyed & np.isfinite(strength)
    true_strength = np.linalg.norm(field.field_earth_ut(xx[sel], yy[sel]), axis=1)
    offset = layers["heading_offset"].values
    hsel = surveyed & np.isfinite(offset)
    herr = wrap_deg(offset[hsel] + field.compass_deviation_deg(xx[hsel], yy[hsel]))
    xy = np.asarray(true_xy_m, dtype=np.float64).reshape(-1, 2)
    walked = sample_grid(grid, np.isfinite(strength), strength, xy[:, 0], xy[:, 1])
    ok = np.isfinite(walked)
    walked_err = walked[ok] - np.linalg.norm(field.field_earth_ut(xy[ok, 0], xy[ok, 1]), axis=1)
    return TruthErrors(strength[sel] - true_strength, np.asarray(herr, dtype=np.float64),
                       int(surveyed.sum()), walked_err)
