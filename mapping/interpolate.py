"""Interpolating survey samples onto the reachable-area raster.

Samples are first reduced to per-(walk, cell) means, so a walker who lingers does not outweigh
one who walks past, and each cell's observation is the mean over the walks that crossed it.
Four interpolators work from those cell values:

- ``"kernel"``: Gaussian normalised convolution with shrinkage to the floor mean,
  ``(sum_c K w_c v_c + lambda mu) / (sum_c K w_c + lambda)``. The bandwidth matches the field's
  spatial spectrum and the positions' uncertainty (the papers: >98 % of the energy lies below
  0.5 cycles/m; survey positions are uncertain by 1-2 m, measured as FINDINGS describe), and the
  shrinkage keeps sparsely surveyed cells near the mean instead of fitting one walk's noise.
  This is the posterior mean of a Gaussian-process-like smoother whose prior mean is the floor
  mean; its uncertainty raster combines the local spread of walks with the prior variance.
- ``"local_linear"``: the same kernel, shrinkage and uncertainty, but each cell fits
  a plane to the cells around it (kernel-weighted least squares, first-order normalised
  convolution) instead of a constant, with a ridge ``slope_ridge`` pulling the slope to zero
  where the support cannot determine it (along a single path). A local constant is biased
  wherever the field slopes and the support is one-sided: at the edge of a corridor, beside a
  path, and over any bandwidth wide enough to average the positions' errors. The plane removes
  that first-order bias, so a wide kernel keeps the field's gradients (site1/F1 held-out strength
  shape RMSE 4.64 -> 4.43 uT at 3 m in a 10-fold trial; docs/processing_and_mapping.md).
- ``"local_quadratic"`` (default): a local quadratic, its second-order terms ridged by
  ``curvature_ridge``. A plane is still biased by the field's curvature, by about
  ``bandwidth^2 / 2`` times the Laplacian: on simulated floors the local plane's error against
  the true field follows the true Laplacian (correlation 0.62-0.66), and the quadratic takes
  the strength RMSE on surveyed cells from 0.88 / 1.11 / 1.20 to 0.75 / 1.05 / 1.14 uT. Its
  cross-validation also tries the plane (an infinite curvature ridge) and keeps it where it
  scores better, as on two of the three real mall floors, whose 3 m kernels average the
  positions' errors.
- ``"linear"``: Delaunay (barycentric) interpolation of the cell values, as in the papers; its
  uncertainty raster is the distance to the nearest surveyed cell (m).

Cells farther than ``max_distance_m`` from any surveyed cell are NaN (never extrapolated), as
are cells off the reachable mask. Angles (deg) are interpolated as unit vectors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.interpolate import LinearNDInterpolator

from localize.bundle import Grid

from .local_fit import ridge_intercepts


@dataclass(frozen=True)
class RasterParams:
    """Interpolation parameters (lengths in m)."""

    method: str = "local_quadratic"
    bandwidth_m: float = 3.0
    prior_walks: float = 2.0  # shrinkage lambda, in units of walk-cells at full kernel weight
    max_distance_m: float = 3.0
    #: ``local_linear``, ``local_quadratic``: ridge on the local slope, in walk-cells at full
    #: kernel weight times m^2 (0 = plain local plane; large = the ``kernel`` method's local
    #: constant)
    slope_ridge: float = 1.0
    #: ``local_quadratic`` only: ridge on the second-order terms, in walk-cells at full kernel
    #: weight times m^4 (large = the local plane)
    curvature_ridge: float = 1.0

    def __post_init__(self) -> None:
        if self.method not in INTERPOLATORS:
            raise ValueError(f"unknown interpolator {self.method!r}; expected one of "
                             f"{sorted(INTERPOLATORS)}")
        for name in ("bandwidth_m", "prior_walks", "max_distance_m", "slope_ridge",
                     "curvature_ridge"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"raster {name} must be a finite number >= 0, got {value!r}")

    @property
    def kernel_based(self) -> bool:
        """Whether the bandwidth and shrinkage apply (and are chosen by cross-validation)."""
        return self.method in KERNEL_METHODS

    def describe(self) -> str:
        """The smoothing in words (progress messages, benchmark headers)."""
        if not self.kernel_based:
            return self.method
        text = f"{self.method} bandwidth {self.bandwidth_m} m, shrinkage {self.prior_walks} walks"
        if DEGREE[self.method] >= 1:
            text += f", slope ridge {self.slope_ridge}"
        if DEGREE[self.method] == 2:
            text += f", curvature ridge {self.curvature_ridge}"
        return text


@dataclass
class CellStats:
    """Per-cell sums over walks of per-walk cell means (arrays of the grid's shape).

    ``n`` counts walks per cell, ``s`` sums their means, ``q`` sums their squares. Sums can be
    subtracted, which makes leave-one-walk-out cheap.
    """

    n: NDArray[np.float64]
    s: NDArray[np.float64]
    q: NDArray[np.float64]

    def __sub__(self, other: CellStats) -> CellStats:
        return CellStats(self.n - other.n, self.s - other.s, self.q - other.q)


def walk_cell_means(grid: Grid, x_m: NDArray, y_m: NDArray, values: NDArray,
                    walk: NDArray) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray]:
    """Mean value per (walk, cell): returns (walk code, flat cell index, mean) per pair."""
    row, col, inside = grid.cell_of(x_m, y_m)
    ok = inside & np.isfinite(values)
    cell = (row * grid.width + col)[ok]
    w = np.asarray(walk)[ok]
    v = np.asarray(values, dtype=np.float64)[ok]
    key = w.astype(np.int64) * (grid.width * grid.height) + cell
    uniq, inv = np.unique(key, return_inverse=True)
    sums = np.bincount(inv, weights=v)
    counts = np.bincount(inv)
    return uniq // (grid.width * grid.height), uniq % (grid.width * grid.height), sums / counts


def cell_stats(grid: Grid, cell: NDArray[np.int64], mean: NDArray) -> CellStats:
    size = grid.width * grid.height
    shape = grid.shape
    return CellStats(np.bincount(cell, minlength=size).reshape(shape).astype(np.float64),
                     np.bincount(cell, weights=mean, minlength=size).reshape(shape),
                     np.bincount(cell, weights=mean * mean, minlength=size).reshape(shape))


def _distance_ok(grid: Grid, support: NDArray[np.bool_], max_distance_m: float) -> NDArray:
    if not support.any():
        return np.zeros_like(support)
    dist = ndimage.distance_transform_edt(~support) * grid.cell_m
    return dist <= max_distance_m


def prior_of(stats: CellStats) -> tuple[float, float]:
    """Floor mean and variance of the walk-cell means: the smoother's prior."""
    total = stats.n.sum()
    if total == 0:
        return float("nan"), float("nan")
    mu = stats.s.sum() / total
    return float(mu), float(max(stats.q.sum() / total - mu * mu, 1e-6))


#: powers (of dx, dy) of the local polynomial's terms: constant, plane, quadratic
_TERMS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
#: degree of the local polynomial of each kernel method
DEGREE = {"kernel": 0, "local_linear": 1, "local_quadratic": 2}
_N_TERMS = {0: 1, 1: 3, 2: 6}


@dataclass(frozen=True)
class KernelSums:
    """Gaussian-smoothed walk counts, sums and sums of squares (grid shape) of one bandwidth:
    everything :func:`kernel_raster` needs but the shrinkage and ridges, which are cheap to
    vary (:func:`kernel_mean`, :func:`kernel_std`).

    ``covered``: the cells that get a value: the reachable cells within ``max_distance_m`` of a
    surveyed cell (the others are NaN), or those of them asked for. For a local polynomial of
    degree 1 or 2 (k = 3 or 6 terms ``1, dx, dy[, dx^2, dx dy, dy^2]``, offsets in m from the
    cell), at the covered cells in row-major order:
    ``gram``, shape (n_covered, k, k), the kernel-weighted ``sum w t_i t_j``, and ``rhs``,
    shape (n_covered, k), the kernel-weighted ``sum w v t_i``."""

    n: NDArray[np.float64]
    s: NDArray[np.float64]
    q: NDArray[np.float64]
    peak: float  # kernel weight of a single cell at its centre
    covered: NDArray[np.bool_]
    gram: NDArray[np.float64] | None = None
    rhs: NDArray[np.float64] | None = None


def _polynomial_kernel(sigma_cells: float, cell_m: float, power: int, truncate: float
                       ) -> NDArray[np.float64]:
    """1-D Gaussian weights (those of ``ndimage.gaussian_filter``) times the offset^power (m)."""
    radius = int(truncate * sigma_cells + 0.5)
    offset = np.arange(-radius, radius + 1)
    k = np.exp(-0.5 * (offset / sigma_cells) ** 2)
    return k / k.sum() * (offset * cell_m) ** power


def kernel_sums(grid: Grid, mask: NDArray[np.bool_], stats: CellStats, bandwidth_m: float,
                max_distance_m: float, *, degree: int = 0,
                cells: NDArray[np.bool_] | None = None) -> KernelSums:
    """Smooth ``stats`` within the reachable area (normalised convolution, mask as weight);
    ``degree`` 1 or 2 adds the moments a local plane or quadratic needs. ``cells`` (grid
    shape): values only there (a cross-validation needs only the cells it looks up)."""
    if degree not in _N_TERMS:
        raise ValueError(f"kernel_sums: degree must be 0, 1 or 2, got {degree!r}")
    truncate = 3.0
    sigma = bandwidth_m / grid.cell_m
    m = mask.astype(np.float64)

    def smooth(a: NDArray) -> NDArray:
        return ndimage.gaussian_filter(a * m, sigma, mode="constant", truncate=truncate)

    def moment(a: NDArray, px: int, py: int) -> NDArray:
        # sum_c K(c - p) a_c dx^px dy^py, separable: exact, no large coordinates cancelling
        t = ndimage.correlate1d(a * m, _polynomial_kernel(sigma, grid.cell_m, px, truncate),
                                axis=1, mode="constant")
        return ndimage.correlate1d(t, _polynomial_kernel(sigma, grid.cell_m, py, truncate),
                                   axis=0, mode="constant")

    k_n, k_s, k_q = (smooth(a) for a in (stats.n, stats.s, stats.q))
    covered = mask & _distance_ok(grid, (stats.n > 0) & mask, max_distance_m)
    if cells is not None:
        covered &= cells
    gram = rhs = None
    if degree > 0:
        terms = _TERMS[:_N_TERMS[degree]]
        weights = {(0, 0): k_n[covered]}
        for px, py in {(a[0] + b[0], a[1] + b[1]) for a in terms for b in terms} - {(0, 0)}:
            weights[(px, py)] = moment(stats.n, px, py)[covered]
        gram = np.stack([np.stack([weights[(a[0] + b[0], a[1] + b[1])] for b in terms], -1)
                         for a in terms], -2)
        rhs = np.stack([k_s[covered]] + [moment(stats.s, *t)[covered] for t in terms[1:]], -1)
    return KernelSums(k_n, k_s, k_q, 1.0 / (2 * np.pi * sigma * sigma), covered, gram, rhs)


def kernel_mean(sums: KernelSums, prior_walks: float, prior_mean: float,
                slope_ridge: float | None = None, curvature_ridge: float = 0.0
                ) -> NDArray[np.float32]:
    """Values from :func:`kernel_sums` (NaN off the covered cells), shrunk towards
    ``prior_mean`` with the weight of ``prior_walks`` walk-cells at full kernel weight.

    With ``slope_ridge`` (sums of degree 1 or 2) each value is the intercept of a local
    polynomial whose slope is ridged by ``slope_ridge`` walk-cells x m^2 and, for a quadratic,
    whose second-order terms by ``curvature_ridge`` walk-cells x m^4, at full kernel weight
    (``inf``: the local plane, from the same sums); else the local constant."""
    lam = prior_walks * sums.peak
    if slope_ridge is None:
        mean = (sums.s + lam * prior_mean) / np.maximum(sums.n + lam, 1e-12)
    else:
        if sums.gram is None:
            raise ValueError("kernel_mean: slope_ridge needs sums of degree 1 or 2")
        k = sums.rhs.shape[1]
        plane = np.isinf(curvature_ridge)  # the quadratic's leading terms alone
        curvature = 0.0 if plane else curvature_ridge
        ridge = np.array([lam] + [slope_ridge * sums.peak] * 2
                         + [curvature * sums.peak] * 3)[:k]
        mean = np.full(sums.n.shape, np.nan)
        mean[sums.covered] = ridge_intercepts(sums.gram, sums.rhs, ridge, lam * prior_mean,
                                              3 if plane else k)
    return np.where(sums.covered, mean, np.nan).astype(np.float32)


def kernel_std(sums: KernelSums, prior_walks: float, prior: tuple[float, float]
               ) -> NDArray[np.float32]:
    """Standard error of the local mean (the value's unit; NaN off the covered cells): the
    local spread of walks where they are, the ``prior`` (mean, variance) elsewhere, the same
    for the local constant and the local plane."""
    k_n, k_s, k_q, peak = sums.n, sums.s, sums.q, sums.peak
    local_var = np.where(k_n > 0, np.maximum(k_q / np.maximum(k_n, 1e-12)
                                             - (k_s / np.maximum(k_n, 1e-12)) ** 2, 0), 0)
    n_eff = k_n / peak
    # spread of one walk's observation: local spread where walks are, the prior elsewhere
    var = (local_var * n_eff + prior_walks * prior[1]) / np.maximum(n_eff + prior_walks, 1e-12)
    std = np.sqrt(var / np.maximum(n_eff + prior_walks, 1.0))
    return np.where(sums.covered, std, np.nan).astype(np.float32)


def kernel_raster(grid: Grid, mask: NDArray[np.bool_], stats: CellStats,
                  params: RasterParams, prior: tuple[float, float] | None = None
                  ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Kernel-smoothed values (a local constant, or a local plane with
    ``method="local_linear"``) and their uncertainty, shape (height, width), NaN off-support.

    ``prior`` (mean, variance) defaults to that of ``stats``; pass the whole floor's when
    ``stats`` covers only a window of it."""
    prior = prior if prior is not None else prior_of(stats)
    if not (stats.n > 0).any() or not np.isfinite(prior[0]):
        nan = np.full(grid.shape, np.nan, dtype=np.float32)
        return nan, nan.copy()
    degree = DEGREE[params.method]
    sums = kernel_sums(grid, mask, stats, params.bandwidth_m, params.max_distance_m,
                       degree=degree)
    return (kernel_mean(sums, params.prior_walks, prior[0],
                        params.slope_ridge if degree else None, params.curvature_ridge),
            kernel_std(sums, params.prior_walks, prior))


def linear_raster(grid: Grid, mask: NDArray[np.bool_], stats: CellStats,
                  params: RasterParams, prior: tuple[float, float] | None = None
                  ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Delaunay-linear values of the surveyed cells; uncertainty = distance to support (m)."""
    support = stats.n > 0
    rows, cols = np.nonzero(support)
    xc, yc = grid.cell_centers()
    out = np.full(grid.shape, np.nan)
    if len(rows) >= 3:
        interp = LinearNDInterpolator(np.column_stack([xc[cols], yc[rows]]),
                                      stats.s[support] / stats.n[support])
        mr, mc = np.nonzero(mask)
        out[mr, mc] = interp(xc[mc], yc[mr])
    dist = ndimage.distance_transform_edt(~support) * grid.cell_m if support.any() else \
        np.full(grid.shape, np.inf)
    ok = mask & (dist <= params.max_distance_m) & np.isfinite(out)
    return (np.where(ok, out, np.nan).astype(np.float32),
            np.where(ok, dist, np.nan).astype(np.float32))


INTERPOLATORS = {"kernel": kernel_raster, "local_linear": kernel_raster,
                 "local_quadratic": kernel_raster, "linear": linear_raster}
#: methods with a kernel bandwidth and shrinkage
KERNEL_METHODS = tuple(DEGREE)


def raster_from_stats(grid: Grid, mask: NDArray[np.bool_], stats: CellStats,
                      params: RasterParams, prior: tuple[float, float] | None = None
                      ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Interpolate with ``params.method`` (``prior``: see :func:`kernel_raster`)."""
    return INTERPOLATORS[params.method](grid, mask, stats, params, prior)


def raster(grid: Grid, mask: NDArray[np.bool_], x_m: NDArray, y_m: NDArray, values: NDArray,
           walk: NDArray, params: RasterParams = RasterParams(), *, angle: bool = False
           ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Raster of samples (values in their unit; angles in deg with ``angle=True``).

    Returns (values, uncertainty), each (height, width) float32 with NaN where there is no data.
    For angles the uncertainty is the circular spread in degrees.
    """
    walk_code = np.unique(np.asarray(walk), return_inverse=True)[1]
    if not angle:
        w, cell, mean = walk_cell_means(grid, x_m, y_m, values, walk_code)
        return raster_from_stats(grid, mask, cell_stats(grid, cell, mean), params)
    rad = np.radians(np.asarray(values, dtype=np.float64))
    parts = []
    for comp in (np.sin(rad), np.cos(rad)):
        w, cell, mean = walk_cell_means(grid, x_m, y_m, comp, walk_code)
        parts.append(raster_from_stats(grid, mask, cell_stats(grid, cell, mean), params)[0])
    return angle_raster(*parts)


def angle_raster(sin_raster: NDArray, cos_raster: NDArray
                 ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Angle (deg in [0, 360)) and circular spread (deg) from interpolated unit-vector
    components (same shape; NaN where there is no data)."""
    r = np.hypot(sin_raster, cos_raster)
    ang = np.mod(np.degrees(np.arctan2(sin_raster, cos_raster)), 360.0).astype(np.float32)
    spread = np.degrees(np.sqrt(np.maximum(-2 * np.log(np.clip(r, 1e-6, 1.0)), 0)))
    return ang, spread.astype(np.float32)
