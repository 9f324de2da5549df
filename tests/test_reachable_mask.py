"""``mapping.grid.reachable_mask`` (a numpy scanline raster) against ``shapely.contains_xy`` at
every cell centre, the old implementation and the reference for its semantics."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import shapely.affinity
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mapping.grid
from localize.bundle import Grid
from mapping.grid import grid_for_extent, reachable_mask


def contains_at_centres(grid: Grid, geom) -> np.ndarray:
    xc, yc = grid.cell_centers()
    xx, yy = np.meshgrid(xc, yc)
    return shapely.contains_xy(geom, xx, yy)


def assert_same_as_contains(grid: Grid, geom) -> np.ndarray:
    mask = reachable_mask(grid, geom)
    want = contains_at_centres(grid, geom)
    assert mask.shape == grid.shape == want.shape and mask.dtype == bool
    bad = np.argwhere(mask != want)
    assert not len(bad), (f"{len(bad)} cells differ, first (row, col) {bad[:5].tolist()}, "
                          f"grid {grid}, geometry {shapely.to_wkt(geom, rounding_precision=-1)}")
    return mask


def star(rng, cx, cy, r, n) -> shapely.Polygon:
    """A random star-shaped (often concave) simple polygon around (cx, cy)."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = r * rng.uniform(0.2, 1.0, n)
    return shapely.make_valid(shapely.Polygon(np.c_[cx + rad * np.cos(ang),
                                                    cy + rad * np.sin(ang)]))


@st.composite
def grids(draw):
    """Origins that may be negative and are rarely whole (FloorPlan.grid starts at the plan's
    lowest coordinates), cells of sizes with inexact binary fractions."""
    cell = draw(st.sampled_from([0.25, 0.5, 0.37, 1.0, 0.1 * 3, 0.8131]))
    origin = st.floats(-50, 20, allow_nan=False)
    return Grid(draw(origin), draw(origin), cell, draw(st.integers(1, 90)),
                draw(st.integers(1, 90)))


@st.composite
def floors(draw):
    """A grid and an area on it: random stars and boxes united, minus others (holes,
    multipolygons, concave outlines), often reaching over the grid's edges."""
    grid = draw(grids())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    w, h = grid.width * grid.cell_m, grid.height * grid.cell_m
    x0, y0 = grid.x0_m - 0.2 * w, grid.y0_m - 0.2 * h

    def shape():
        cx, cy = x0 + rng.uniform(0, 1.4 * w), y0 + rng.uniform(0, 1.4 * h)
        r = rng.uniform(0.05, 0.6) * max(w, h)
        if rng.random() < 0.4:
            return shapely.box(cx - r, cy - r * rng.uniform(0.1, 1), cx + r * rng.uniform(0.1, 1),
                               cy + r)
        return star(rng, cx, cy, r, int(rng.integers(3, 14)))

    area = shapely.union_all([shape() for _ in range(draw(st.integers(1, 4)))])
    cut = [shape() for _ in range(draw(st.integers(0, 5)))]
    if cut:
        area = shapely.difference(area, shapely.union_all(cut))
    return grid, area


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(floors())
def test_random_areas_match_contains_xy(floor):
    assert_same_as_contains(*floor)


@st.composite
def aligned_floors(draw):
    """Areas whose vertices lie on cell centres and cell edges: many centres on the boundary
    (on vertices, on horizontal, vertical and diagonal edges), which contains_xy leaves out."""
    grid = draw(grids())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    half = grid.cell_m / 2

    def lattice(n, size):
        return rng.integers(-4, 2 * size + 4, n) * half

    def shape():
        xs, ys = grid.x0_m + lattice(2, grid.width), grid.y0_m + lattice(2, grid.height)
        if rng.random() < 0.5 and xs[0] != xs[1] and ys[0] != ys[1]:
            return shapely.box(xs.min(), ys.min(), xs.max(), ys.max())
        tri = shapely.Polygon(np.c_[grid.x0_m + lattice(3, grid.width),
                                    grid.y0_m + lattice(3, grid.height)])
        return shapely.make_valid(tri)

    area = shapely.union_all([shape() for _ in range(draw(st.integers(1, 4)))])
    return grid, shapely.difference(area, shapely.union_all([shape() for _ in range(2)]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(aligned_floors())
def test_centres_on_the_boundary_are_out_as_in_contains_xy(floor):
    assert_same_as_contains(*floor)


def test_boundary_centres_are_left_out():
    g = Grid(0.0, 0.0, 1.0, 6, 5)  # centres at 0.5, 1.5, ...
    square = shapely.box(0.5, 0.5, 3.5, 2.5)  # every edge through a row or column of centres
    mask = assert_same_as_contains(g, square)
    want = np.zeros(g.shape, bool)
    want[1, 1:3] = True  # only centres (1.5, 1.5) and (2.5, 1.5) are inside
    assert (mask == want).all()
    diamond = shapely.Polygon([(2.5, 0.5), (4.5, 2.5), (2.5, 4.5), (0.5, 2.5)])
    mask = assert_same_as_contains(g, diamond)
    assert mask.sum() == 5 and mask[2, 2] and not mask[0, 2] and not mask[2, 4]


def test_row_order_is_south_first():
    """Row 0 is the south edge (y0): an area only in the south-west corner."""
    g = Grid(-2.0, 10.0, 0.5, 8, 6)  # x -2 .. 2, y 10 .. 13
    corner = shapely.Polygon([(-2, 10), (0, 10), (-2, 11)])  # a right triangle, south-west
    mask = assert_same_as_contains(g, corner)
    assert mask[0, 0] and mask[0, 1] and not mask[-1, 0] and not mask[0, -1]
    # centres at y 10.25 west of x -0.5 and at y 10.75 west of x -1.5
    rows, cols = np.nonzero(mask)
    assert set(zip(rows.tolist(), cols.tolist())) == {(0, 0), (0, 1), (0, 2), (1, 0)}
    flipped = reachable_mask(g, shapely.affinity.scale(corner, 1, -1, origin=(0, 11.5)))
    assert (flipped == mask[::-1]).all()  # mirrored about the grid's middle row


def test_collections_unite_their_parts():
    g = Grid(0.0, 0.0, 0.5, 20, 12)
    a, b = shapely.box(1, 1, 6, 5), shapely.box(4, 2, 9, 5.5)  # overlapping
    ring = shapely.box(0.2, 0.2, 9.8, 5.8).difference(shapely.box(0.7, 0.7, 9.3, 5.3))
    gc = shapely.GeometryCollection([a, b, ring, shapely.Polygon(),
                                     shapely.LineString([(0.25, 3.25), (3.25, 3.25)]),
                                     shapely.Point(7.25, 0.25),
                                     shapely.MultiPolygon([shapely.box(1.5, 1.5, 2.5, 2.5)])])
    mask = assert_same_as_contains(g, gc)
    assert mask[6, 10] and mask[0, 14]  # in both boxes; the point
    reversed_b = shapely.Polygon(b.exterior.coords[::-1])  # clockwise: still united
    assert_same_as_contains(g, shapely.GeometryCollection([a, reversed_b]))
    holey = shapely.Polygon(shapely.box(0, 0, 10, 6).exterior.coords[::-1],
                            [shapely.box(2, 2, 4, 4).exterior.coords])  # both rings reversed
    mask = assert_same_as_contains(g, holey)
    assert not mask[5, 5] and mask[1, 1]


@pytest.mark.parametrize("geom", [
    shapely.Polygon(), shapely.MultiPolygon(), shapely.GeometryCollection(), None,
    shapely.LineString([(0, 0), (3, 3)]), shapely.LineString([(0.25, 0.75), (3.25, 0.75)]),
    shapely.MultiPoint([(0.25, 0.25), (1.0, 1.0)]),
    shapely.Polygon([(0, 0), (3, 3), (6, 6)]),  # no area
    shapely.box(-100, -100, 100, 100),  # covers the grid
    shapely.box(-100, -100, -50, 100),  # west of the grid: its crossings cancel
    shapely.box(50, -100, 100, 100), shapely.box(-100, 20, 100, 100),
    shapely.box(-100, -100, 100, 100).difference(shapely.box(-50, -50, 50, 50)),  # a hole
])
def test_degenerate_and_off_grid_areas(geom):
    g = Grid(-0.5, 0.0, 0.5, 12, 10)
    assert_same_as_contains(g, geom)


@pytest.mark.parametrize("shape", [(1, 1), (1, 40), (40, 1)])
def test_one_row_or_column_grids(shape):
    h, w = shape
    g = Grid(0.0, 0.0, 0.5, w, h)
    for geom in (shapely.box(0.1, 0.1, 7, 9), shapely.box(0.25, 0.25, 7, 9),
                 star(np.random.default_rng(3), 5, 5, 6, 9)):
        assert_same_as_contains(g, geom)


def test_chunks_give_the_same_mask(monkeypatch):
    g = grid_for_extent(60, 40, 0.25, x0_m=-7.5, y0_m=-3.25)
    rng = np.random.default_rng(5)
    area = shapely.box(-7, -3, 52, 36).difference(shapely.union_all(
        [star(rng, *rng.uniform([-7, -3], [52, 36]), 4, 12) for _ in range(40)]))
    whole = assert_same_as_contains(g, area)
    monkeypatch.setattr(mapping.grid, "_CROSSINGS_PER_CHUNK", 7)
    assert (reachable_mask(g, area) == whole).all()


def test_sample_site_plans_match_contains_xy():
    from pathlib import Path

    from mapping.floorplan import read_floor_plan
    site = Path(__file__).resolve().parents[1] / "data" / "sample_site"
    for floor in ("F1", "F2"):
        plan = read_floor_plan(site / floor)
        for cell in (0.5, 0.25):
            assert_same_as_contains(plan.grid(cell), plan.reachable)


def test_winding_sums_beyond_int16_do_not_wrap():
    """A collection of 32768 overlapping squares: the winding number at their centre is 32768,
    which an int16 sum wrapped to -32768 (out); the squares' cells are in, as contains_xy says."""
    grid = Grid(0.0, 0.0, 1.0, 12, 10)
    square = shapely.box(2.2, 2.2, 7.8, 7.8)
    for copies in (32767, 32768, 65536 + 1):
        area = shapely.GeometryCollection([square] * copies)
        mask = reachable_mask(grid, area)
        assert mask.sum() == 36 and np.array_equal(mask, reachable_mask(grid, square)), copies
