"""Speed and memory of ``mapping.grid.reachable_mask`` (numpy scanlines) against the
``shapely.contains_xy`` at every cell centre it replaced, and whether their masks are equal.

    python benchmarks/reachable_mask.py [--quick]

Floors: a synthetic 2,000 x 1,000 m mall (an outline with notches and a courtyard, 4,000
rectangular shops and 3,000 round columns of 24 vertices, none aligned with the cells) at
0.5 m cells (8 M cells) and at 0.32 m cells (19.5 M, near ``MAX_GRID_CELLS``), a copy of it
drawn on the cell-centre lattice (every edge through a row or column of centres: the
boundary re-tests at their most), and the sample site's floors (``data/sample_site``,
simulated when missing) at 0.5 and 0.25 m cells. ``--quick`` drops the 19.5 M-cell floor.

Both run in this process on one core, each on a fresh copy of the geometry (the old code
prepared it in place, and ``FloorPlan.reachable`` is a new geometry per call). Times are wall
milliseconds, the median of repeats (one for the old code on the big floors, five for the new;
21 each on the sample floors); peak MB is tracemalloc's peak in one more call (numpy and
shapely's arrays, not GEOS's own memory; on the big floors the old code's one call is that
call). The machine's load average is printed, since other processes slow both alike.

Measured when the scanline raster replaced ``contains_xy`` (2-core machine, load average 2.2):

    floor                           cells vertices   old ms  new ms  ratio  old MB  new MB
    mall 2000x1000 m, 0.5 m     8,000,000    58391   6253.7    58.8 106.4x   136.0    42.1
    mall 2000x1000 m, 0.32 m   19,531,250    58391  15303.1    95.3 160.5x   332.1    80.5
    mall on centres, 0.5 m      8,000,000    29837   5507.6   320.2  17.2x   136.0    39.8
    sample F1, 0.5 m                4,000       83      0.3     0.2   1.5x     0.1     0.1
    sample F1, 0.25 m              16,000       83      1.1     0.2   4.8x     0.3     0.1
    sample F2, 0.5 m                4,000       78      0.3     0.2   1.3x     0.1     0.1
    sample F2, 0.25 m              16,000       78      1.1     0.2   4.7x     0.3     0.1

with equal masks on every floor.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import shapely

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from localize.bundle import Grid  # noqa: E402
from mapping.floorplan import read_floor_plan  # noqa: E402
from mapping.grid import grid_for_extent, reachable_mask  # noqa: E402


def contains_xy_mask(grid: Grid, reachable: shapely.Geometry) -> np.ndarray:
    """The implementation before the scanline raster (the baseline)."""
    xc, yc = grid.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    shapely.prepare(reachable)
    return shapely.contains_xy(reachable, xx, yy)


def synthetic_mall(seed: int = 0, lattice_m: float | None = None) -> shapely.Geometry:
    """A 2,000 x 1,000 m floor's reachable area; with ``lattice_m``, every coordinate is
    rounded to ``lattice_m / 2 + k * lattice_m`` (the centres of cells of that size)."""
    rng = np.random.default_rng(seed)
    outline = shapely.Polygon([(0, 0), (2000, 0), (2000, 400), (1900, 400), (1900, 600),
                               (2000, 600), (2000, 1000), (1200, 1000), (1100, 900),
                               (900, 900), (800, 1000), (0, 1000)],
                              [[(600, 300), (1400, 300), (1400, 700), (600, 700)]])
    corner = rng.uniform([5, 5], [1980, 980], (4000, 2))
    size = rng.uniform([4, 4], [25, 18], (4000, 2))
    shops = shapely.box(corner[:, 0], corner[:, 1], *(corner + size).T)
    columns = shapely.buffer(shapely.points(rng.uniform([5, 5], [1995, 995], (3000, 2))),
                             rng.uniform(0.3, 0.8, 3000), quad_segs=6)
    obstacles = np.concatenate([shops, columns])
    if lattice_m is not None:
        def snap(xy):
            return (np.round(xy / lattice_m - 0.5) + 0.5) * lattice_m
        outline = shapely.transform(outline, snap)
        obstacles = shapely.make_valid(shapely.transform(obstacles, snap))
    return shapely.difference(outline, shapely.union_all(obstacles))


def timed(fn, grid: Grid, wkb: bytes, repeats: int) -> tuple[float, float, np.ndarray]:
    """(median seconds, peak MB, mask) of ``fn(grid, fresh geometry)``: ``repeats`` timed
    calls and one under tracemalloc (timed too when ``repeats`` is 0: its overhead is per
    allocation, small for the big floors but not for the sample's)."""
    times = []
    for _ in range(repeats):
        geom = shapely.from_wkb(wkb)
        t = time.perf_counter()
        fn(grid, geom)
        times.append(time.perf_counter() - t)
    geom = shapely.from_wkb(wkb)
    tracemalloc.start()
    t = time.perf_counter()
    mask = fn(grid, geom)
    traced = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return statistics.median(times or [traced]), peak / 1e6, mask


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="skip the 19.5 M-cell floor")
    args = ap.parse_args(argv)

    cases = []  # (name, grid, reachable)
    mall = synthetic_mall()
    cases.append(("mall 2000x1000 m, 0.5 m", grid_for_extent(2000, 1000, 0.5), mall))
    if not args.quick:
        cases.append(("mall 2000x1000 m, 0.32 m", grid_for_extent(2000, 1000, 0.32), mall))
    cases.append(("mall on centres, 0.5 m", grid_for_extent(2000, 1000, 0.5),
                  synthetic_mall(lattice_m=0.5)))
    from survey.sim.site import ensure_sample_site
    site = ensure_sample_site(REPO / "data" / "sample_site")
    for floor in ("F1", "F2"):
        plan = read_floor_plan(Path(site) / floor)
        for cell in (0.5, 0.25):
            cases.append((f"sample {floor}, {cell} m", plan.grid(cell), plan.reachable))

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'floor':<26} {'cells':>10} {'vertices':>8} {'old ms':>8} {'new ms':>7} "
          f"{'ratio':>6} {'old MB':>7} {'new MB':>7} {'equal':>6}")
    all_equal = True
    for name, grid, geom in cases:
        wkb = shapely.to_wkb(geom)
        cells = grid.width * grid.height
        old_s, old_mb, old = timed(contains_xy_mask, grid, wkb, 0 if cells > 2e6 else 21)
        new_s, new_mb, new = timed(reachable_mask, grid, wkb, 5 if cells > 2e6 else 21)
        equal = bool(np.array_equal(old, new))
        all_equal &= equal
        print(f"{name:<26} {cells:>10,} {shapely.get_num_coordinates(geom):>8} "
              f"{old_s * 1e3:>8.1f} {new_s * 1e3:>7.1f} {old_s / new_s:>5.1f}x {old_mb:>7.1f} "
              f"{new_mb:>7.1f} {str(equal):>6}")
    print("masks equal on every floor" if all_equal else "MASKS DIFFER")
    return 0 if all_equal else 1


if __name__ == "__main__":
    sys.exit(main())
