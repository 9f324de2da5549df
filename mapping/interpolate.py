"""Interpolating survey samples onto the reachable-area raster.

Samples are first reduced to per-(walk, cell) means, so a walker who lingers does not outweigh
one who walks past, and each cell's observation is the mean over the walks that crossed it.
Two interpolators work from those cell values:

- ``"kernel"``: Gaussian normalised convolution with shrinkage to the floor mean,
  ``(sum_c K w_c v_c + lambda mu) / (sum_c K w_c + lambda)``. The bandwidth matches the field's
  spatial spectrum and the positions' uncertainty (the papers: >98 % of the energy lies below
  0.5 cycles/m; survey positions are uncertain by 1-2 m, measured as FINDINGS describe), and the
  shrinkage keeps sparsely surveyed cells near the mean instead of fitting one walk's noise.
  This is the posterior mean of a Gaussian-process-like smoother whose prior mean is the floor
  mean; its uncertainty raster combines the local spread of walks with the prior variance.
- ``"local_linear"`` (default): the same kernel, shrinkage and uncertainty, but each cell fits
  a plane to the cells around it (kernel-weighted least squares, first-order normalised
  convolution) instead of a constant, with a ridge ``slope_ridge`` pulling the slope to zero
  where the support cannot determine it (along a single path). A local constant is biased
  wherever the field slopes and the support is one-sided: at the edge of a corridor, beside a
  path, and over any bandwidth wide enough to average the positions' errors. The plane removes
  that first-order bias, so a wide kernel keeps the field's gradients (site1/F1 held-out strength
  shape RMSE 4.64 -> 4.43 uT at 3 m in a 10-fold trial; docs/processing_and_mapping.md).
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


@dataclass(frozen=True)
class RasterParams:
    """Interpolation parameters (lengths in m)."""

    method: str = "local_linear"
    bandwidth_m: float = 3.0
    prior_walks: float = 2.0  # shrinkage lambda, in units of walk-cells at full kernel weight
    max_distance_m: float = 3.0
    #: ``local_linear`` only: ridge on the local slope, in walk-cells at full kernel weight
    #: times m^2 (0 = plain local plane; large = the ``kernel`` method's local constant)
    slope_ridge: float = 1.0

    def __post_init__(self) -> None:
        if self.method not in INTERPOLATORS:
            raise ValueError(f"unknown interpolator {self.method!r}; expected one of "
                             f"{sorted(INTERPOLATORS)}")
        for name in ("bandwidth_m", "prior_walks", "max_distance_m", "slope_ridge"):
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
        if self.method == "local_linear":
            text += f", slope ridge {self.slope_ridge}"
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


@dataclass(frozen=True)
class KernelSums:
    """Gaussian-smoothed walk counts, sums and sums of squares (grid shape) of one bandwidth:
    everything :func:`kernel_raster` needs but the shrinkage and slope ridge, which are cheap
    to vary (:func:`kernel_mean`, :func:`kernel_std`).

    ``covered``: the reachable cells within ``max_distance_m`` of a surveyed cell (the others
    are NaN). ``moments`` (local-linear sums only), shape (7, height, width): the
    kernel-weighted ``sum w dx``, ``sum w dy``, ``sum w dx^2``, ``sum w dx dy``, ``sum w dy^2``,
    ``sum w v dx``, ``sum w v dy`` around each cell (offsets ``dx, dy`` in m)."""

    n: NDArray[np.float64]
    s: NDArray[np.float64]
    q: NDArray[np.float64]
    peak: float  # kernel weight of a single cell at its centre
    covered: NDArray[np.bool_]
    moments: NDArray[np.float64] | None = None


def kernel_sums(grid: Grid, mask: NDArray[np.bool_], stats: CellStats, bandwidth_m: float,
                max_distance_m: float, *, local_linear: bool = False) -> KernelSums:
    """Smooth ``stats`` within the reachable area (normalised convolution, mask as weight);
    ``local_linear`` adds the first-order moments a local plane needs."""
    sigma = bandwidth_m / grid.cell_m
    m = mask.astype(np.float64)

    def smooth(a: NDArray) -> NDArray:
        return ndimage.gaussian_filter(a * m, sigma, mode="constant", truncate=3.0)

    k_n, k_s, k_q = (smooth(a) for a in (stats.n, stats.s, stats.q))
    moments = None
    if local_linear:
        # sum_c K w_c (c - p) = G[w c] - p G[w]; coordinates centred on the grid to keep the
        # cancellation in the squares small
        xc, yc = grid.cell_centers()
        x = np.broadcast_to((xc - xc.mean())[None, :], grid.shape)
        y = np.broadcast_to((yc - yc.mean())[:, None], grid.shape)
        n, s = stats.n, stats.s
        g_nx, g_ny, g_sx, g_sy = smooth(n * x), smooth(n * y), smooth(s * x), smooth(s * y)
        g_nxx, g_nxy, g_nyy = smooth(n * x * x), smooth(n * x * y), smooth(n * y * y)
        moments = np.stack([
            g_nx - x * k_n,
            g_ny - y * k_n,
            g_nxx - 2 * x * g_nx + x * x * k_n,
            g_nxy - x * g_ny - y * g_nx + x * y * k_n,
            g_nyy - 2 * y * g_ny + y * y * k_n,
            g_sx - x * k_s,
            g_sy - y * k_s])
    covered = mask & _distance_ok(grid, (stats.n > 0) & mask, max_distance_m)
    return KernelSums(k_n, k_s, k_q, 1.0 / (2 * np.pi * sigma * sigma), covered, moments)


def _local_plane_intercept(sums: KernelSums, lam: float, mu: float, ridge: float
                           ) -> NDArray[np.float64]:
    """Intercept ``a`` of the kernel-weighted plane ``a + g . (c - p)`` at the covered cells,
    minimising ``sum K w (v - a - g . d)^2 + lam (a - mu)^2 + ridge |g|^2`` (Cramer's rule on
    the symmetric 3 x 3 normal equations, all cells at once)."""
    cells = sums.covered
    mom = sums.moments[:, cells]
    a = sums.n[cells] + lam
    b, c = mom[0], mom[1]
    d, e, f = mom[2] + ridge, mom[3], mom[4] + ridge
    r0, r1, r2 = sums.s[cells] + lam * mu, mom[5], mom[6]
    m00, m01, m02 = d * f - e * e, r1 * f - e * r2, r1 * e - d * r2
    det = a * m00 - b * (b * f - e * c) + c * (b * e - d * c)
    return (r0 * m00 - b * m01 + c * m02) / np.maximum(det, 1e-300)


def kernel_mean(sums: KernelSums, prior_walks: float, prior_mean: float,
                slope_ridge: float | None = None) -> NDArray[np.float32]:
    """Values from :func:`kernel_sums` (NaN off the covered cells), shrunk towards
    ``prior_mean`` with the weight of ``prior_walks`` walk-cells at full kernel weight.

    With ``slope_ridge`` (sums made with ``local_linear=True``) each value is the intercept of
    a local plane whose slope is ridged by ``slope_ridge`` walk-cells x m^2 at full kernel
    weight; else the local constant."""
    lam = prior_walks * sums.peak
    if slope_ridge is None:
        mean = (sums.s + lam * prior_mean) / np.maximum(sums.n + lam, 1e-12)
    else:
        if sums.moments is None:
            raise ValueError("kernel_mean: slope_ridge needs sums made with local_linear=True")
        mean = np.full(sums.n.shape, np.nan)
        mean[sums.covered] = _local_plane_intercept(sums, lam, prior_mean,
                                                    slope_ridge * sums.peak)
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
    local_linear = params.method == "local_linear"
    sums = kernel_sums(grid, mask, stats, params.bandwidth_m, params.max_distance_m,
                       local_linear=local_linear)
    return (kernel_mean(sums, params.prior_walks, prior[0],
                        params.slope_ridge if local_linear else None),
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
                 "linear": linear_raster}
#: methods with a kernel bandwidth and shrinkage
KERNEL_METHODS = ("kernel", "local_linear")


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
