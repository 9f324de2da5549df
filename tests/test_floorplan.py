"""Floor plans: ILC lon/lat GeoJSON, metre GeoJSON, DXF; reachable mask."""

from __future__ import annotations

import hashlib
import re
import json
from pathlib import Path

import ezdxf
import numpy as np
import pytest
import shapely
import shapely.geometry

from mapping.floorplan import FloorPlanError, read_floor_plan
from mapping.grid import grid_for_extent, reachable_mask

SITE = Path(__file__).resolve().parents[1] / "data" / "sample_site"


def test_lonlat_plan_maps_onto_floor_info_metres():
    plan = read_floor_plan(SITE / "F1")
    info = json.loads((SITE / "F1" / "floor_info.json").read_text())["map_info"]
    minx, miny, maxx, maxy = plan.outline.bounds
    assert (minx, miny) == pytest.approx((0, 0), abs=1e-6)
    assert (maxx, maxy) == pytest.approx((info["width"], info["height"]), rel=1e-9)
    assert 0 < plan.reachable.area < plan.outline.area
    # the files read, by name and the sha256 of their bytes, for the bundle's manifest
    assert plan.sources == tuple(
        (name, hashlib.sha256((SITE / "F1" / name).read_bytes()).hexdigest())
        for name in ("geojson_map.json", "floor_info.json"))


@pytest.mark.parametrize("corner, size", [((0.0, 0.0), (40.0, 25.0)),      # metres, near 0
                                           ((120.0, 30.0), (0.6, 0.001)),   # 60 km wide
                                           ((500.0, 10.0), (0.001, 0.001))])  # no longitude
def test_a_plan_beside_floor_info_that_is_no_lonlat_is_refused(tmp_path, corner, size):
    """A plan in metres saved into a floor folder was read as lon/lat and rescaled onto
    floor_info.json's size, silently; now it is refused, naming the file and the reason."""
    (tmp_path / "floor_info.json").write_text(
        (SITE / "F1" / "floor_info.json").read_text())
    (x, y), (w, h) = corner, size
    ring = [[x, y], [x + w, y], [x + w, y + h], [x, y + h], [x, y]]
    (tmp_path / "plan.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon",
                                                           "coordinates": [ring]}}]}))
    with pytest.raises(FloorPlanError, match=r"plan.geojson: read as lon/lat because "
                       r"floor_info.json is beside it, but its outline spans"):
        read_floor_plan(tmp_path / "plan.geojson")
    (tmp_path / "floor_info.json").unlink()
    if w > 1 and h > 1:  # the same file elsewhere is read in metres
        assert read_floor_plan(tmp_path / "plan.geojson").outline.area > 0


def test_metre_geojson_and_mask(tmp_path):
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"role": "outline"},
         "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 4], [0, 4],
                                                          [0, 0]]]}},
        {"type": "Feature", "properties": {"kind": "shop"},
         "geometry": {"type": "Polygon", "coordinates": [[[2, 1], [4, 1], [4, 3], [2, 3],
                                                          [2, 1]]]}}]}
    (tmp_path / "plan.geojson").write_text(json.dumps(fc))
    plan = read_floor_plan(tmp_path / "plan.geojson")
    assert plan.reachable.area == pytest.approx(40 - 4)
    g = grid_for_extent(plan.width_m, plan.height_m, 0.5)
    mask = reachable_mask(g, plan.reachable)
    assert mask.shape == (8, 20) and mask.sum() == 160 - 16
    assert not mask[3, 5] and mask[0, 0]


def test_dxf_plan_with_walls_and_obstacles(tmp_path):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4  # millimetres
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (20000, 0), (20000, 8000), (0, 8000)], close=True,
                       dxfattribs={"layer": "Outline"})
    msp.add_lwpolyline([(2000, 2000), (5000, 2000), (5000, 6000), (2000, 6000)], close=True,
                       dxfattribs={"layer": "SHOPS"})
    msp.add_line((10000, 0), (10000, 6000), dxfattribs={"layer": "walls"})
    msp.add_circle((15000, 4000), 500, dxfattribs={"layer": "pillars"})
    msp.add_line((0, 0), (1, 1), dxfattribs={"layer": "text"})  # other layers are ignored
    # a hatched column block with a hole (a light well), its outer loop an arc-edged path
    hatch = msp.add_hatch(dxfattribs={"layer": "COLUMNS"})
    edges = hatch.paths.add_edge_path()
    edges.add_line((16000, 6500), (18000, 6500))
    edges.add_arc((18000, 7000), 500, -90, 90)  # bulges to x = 18.5 m
    edges.add_line((18000, 7500), (16000, 7500))
    edges.add_line((16000, 7500), (16000, 6500))
    hatch.paths.add_polyline_path([(16500, 6800), (17000, 6800), (17000, 7200), (16500, 7200)],
                                  is_closed=True)
    doc.saveas(tmp_path / "plan.dxf")
    plan = read_floor_plan(tmp_path / "plan.dxf")
    assert plan.sources == (("plan.dxf", hashlib.sha256(
        (tmp_path / "plan.dxf").read_bytes()).hexdigest()),)
    assert (plan.width_m, plan.height_m) == pytest.approx((20.0, 8.0))
    hatched = 2 * 1 + np.pi * 0.25 / 2 - 0.5 * 0.4
    expected = 160 - 12 - 0.2 * 6 - np.pi * 0.25 - hatched
    assert plan.reachable.area == pytest.approx(expected, rel=0.01)
    assert not plan.reachable.contains(shapely.Point(10.0, 3.0))  # the wall
    assert not plan.reachable.contains(shapely.Point(18.3, 7.0))  # inside the hatch's arc
    assert plan.reachable.contains(shapely.Point(16.75, 7.0))  # the hatch's hole
    (tmp_path / "bad.dxf").write_text("not a dxf")
    with pytest.raises(FloorPlanError, match="bad.dxf"):
        read_floor_plan(tmp_path / "bad.dxf")


def test_dxf_curves_blocks_and_outlines_drawn_as_lines(tmp_path):
    """What CAD drawings hold and the reader dropped (a review, session 43): a polyline's arc
    segments (bulges), an obstacle placed as a block reference, an ARC wall, an outline whose
    last point is its first without the closed flag, and one drawn as four LINEs."""
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6
    msp = doc.modelspace()
    # a 20 x 10 m hall whose east side is a half circle (bulge 1 from (20, 0) to (20, 10))
    msp.add_lwpolyline([(0, 0, 0, 0, 0), (20, 0, 0, 0, 1), (20, 10, 0, 0, 0), (0, 10, 0, 0, 0)],
                       format="xyseb", close=True, dxfattribs={"layer": "OUTLINE"})
    kiosk = doc.blocks.new("KIOSK")  # drawn on layer 0: takes the reference's layer
    kiosk.add_lwpolyline([(0, 0), (2, 0), (2, 1), (0, 1)], close=True)
    msp.add_blockref("KIOSK", (4, 4), dxfattribs={"layer": "OBSTACLES"})
    msp.add_blockref("KIOSK", (8, 4), dxfattribs={"layer": "TEXT"})  # another layer: ignored
    msp.add_arc((10, 0), 2, 0, 180, dxfattribs={"layer": "WALLS"})  # a curved wall
    doc.saveas(tmp_path / "curved.dxf")
    plan = read_floor_plan(tmp_path / "curved.dxf")
    assert plan.outline.area == pytest.approx(200 + np.pi * 25 / 2, rel=1e-3)
    assert plan.reachable.contains(shapely.Point(24.0, 5.0))  # inside the half circle
    assert not plan.reachable.contains(shapely.Point(5.0, 4.5))  # the kiosk
    assert plan.reachable.contains(shapely.Point(9.0, 4.5))  # the block on layer TEXT
    assert not plan.reachable.contains(shapely.Point(10.0, 2.0))  # on the arc wall
    assert plan.reachable.contains(shapely.Point(10.0, 1.0))  # within the arc, off the wall
    wall_area = np.pi * 2 * 0.2  # half a circle of radius 2 m (pi * 2 m long), 0.2 m wide
    assert plan.outline.area - plan.reachable.area == pytest.approx(2 + wall_area, rel=0.02)
    # the same hall's outline, ending on its first point, and drawn as lines
    # (and as a 3D polyline, with lines crossing it, overshooting or 0.1 mm short at corners)
    for draw in ("ends_meet", "lines", "partition", "overshoot", "gap", "3d"):
        doc = ezdxf.new()
        msp = doc.modelspace()
        corners = [(0, 0), (20, 0), (20, 10), (0, 10)]
        on = {"layer": "OUTLINE"}
        if draw == "ends_meet":
            msp.add_lwpolyline(corners + [(0, 0)], dxfattribs=on)
        elif draw == "3d":
            msp.add_polyline3d([(x, y, 0) for x, y in corners], close=True, dxfattribs=on)
        else:
            for a, b in zip(corners, corners[1:] + corners[:1]):
                d = np.subtract(b, a) / 20 if draw == "overshoot" else 0 * np.subtract(b, a)
                end = np.add(b, d) - (1e-4 * np.subtract(b, a) / np.hypot(*np.subtract(b, a))
                                      if draw == "gap" else 0)
                msp.add_line(tuple(np.subtract(a, d)), tuple(end), dxfattribs=on)
            if draw == "partition":  # a line across the hall, on the outline layer
                msp.add_line((15, 0), (15, 10), dxfattribs=on)
        doc.saveas(tmp_path / f"{draw}.dxf")
        assert read_floor_plan(tmp_path / f"{draw}.dxf").outline.area == pytest.approx(200.0), \
            draw
    # lines that close no ring: the error says what it found and the drawing's layers
    doc = ezdxf.new()
    doc.layers.add("A-FLOR-OTLN")
    doc.modelspace().add_line((0, 0), (5, 0), dxfattribs={"layer": "OUTLINE"})
    doc.modelspace().add_line((0, 0), (5, 5), dxfattribs={"layer": "A-FLOR-OTLN"})
    doc.saveas(tmp_path / "open.dxf")
    with pytest.raises(FloorPlanError, match=r"no closed outline on layers \['BOUNDARY', "
                       r"'FLOOR', 'OUTLINE'\]: found 1 LINE \(no closed shape, and their "
                       r"lines close no ring\); the drawing's entities are on layers "
                       r"A-FLOR-OTLN, OUTLINE \(name yours: .*--dxf-layer "
                       r"outline=NAME`, read_dxf_floor_plan's outline_layers\)"):
        read_floor_plan(tmp_path / "open.dxf")


def test_dxf_block_references_are_bounded(tmp_path, monkeypatch):
    """A MINSERT of more copies than a plan holds, or blocks nested too deep, are refused
    before they are expanded."""
    import mapping.floorplan_dxf as dxf

    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (20, 0), (20, 10), (0, 10)], close=True,
                       dxfattribs={"layer": "OUTLINE"})
    doc.blocks.new("POST").add_circle((0, 0), 0.2)
    ref = msp.add_blockref("POST", (1, 1), dxfattribs={"layer": "PILLARS"})
    ref.grid(size=(40, 40), spacing=(0.5, 0.5))  # 1,600 posts
    doc.saveas(tmp_path / "posts.dxf")
    assert read_floor_plan(tmp_path / "posts.dxf").obstacles.area > 100
    monkeypatch.setattr(dxf, "MAX_ENTITIES", 1000)
    with pytest.raises(FloorPlanError, match="more than 1,000 entities in its block "
                       r"references \(1,600 copies of block 'POST'\)"):
        read_floor_plan(tmp_path / "posts.dxf")
    # the drawing's own entities do not count, nor blocks on layers the reader ignores
    doc.blocks.new("CHAIR").add_circle((0, 0), 0.2)
    chairs = doc.modelspace().add_blockref("CHAIR", (1, 1), dxfattribs={"layer": "FURNITURE"})
    chairs.grid(size=(100, 100), spacing=(0.1, 0.1))
    for i in range(2000):
        doc.modelspace().add_text(f"{i}", dxfattribs={"layer": "TEXT"})
    doc.modelspace().delete_entity(ref)
    doc.saveas(tmp_path / "furnished.dxf")
    assert read_floor_plan(tmp_path / "furnished.dxf").obstacles.is_empty
    monkeypatch.setattr(dxf, "MAX_BLOCK_DEPTH", 1)
    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (20, 0), (20, 10), (0, 10)], close=True,
                       dxfattribs={"layer": "OUTLINE"})
    doc.blocks.new("INNER").add_circle((0, 0), 0.2)
    doc.blocks.new("OUTER").add_blockref("INNER", (0, 0))
    msp.add_blockref("OUTER", (5, 5), dxfattribs={"layer": "PILLARS"})
    doc.saveas(tmp_path / "nested.dxf")
    with pytest.raises(FloorPlanError, match="block references nested deeper than 1"):
        read_floor_plan(tmp_path / "nested.dxf")


def test_a_self_intersecting_outline_is_repaired_and_said(tmp_path):
    bow_tie = [[0, 0], [10, 4], [10, 0], [0, 4], [0, 0]]  # two triangles touching at (5, 2)
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {},
         "geometry": {"type": "Polygon", "coordinates": [bow_tie]}},
        {"type": "Feature", "properties": {},
         "geometry": {"type": "Polygon", "coordinates": [[[1, 1], [2, 1], [2, 3], [1, 3],
                                                          [1, 1]]]}}]}
    (tmp_path / "plan.geojson").write_text(json.dumps(fc))
    plan = read_floor_plan(tmp_path / "plan.geojson")
    assert plan.outline.area == pytest.approx(20.0)  # the two triangles, 10 m2 each
    assert len(plan.repairs) == 1
    assert "plan.geojson: feature 0 (the outline)" in plan.repairs[0]
    assert "Self-intersection" in plan.repairs[0]
    assert read_floor_plan(SITE / "F1").repairs == ()  # a valid plan has nothing to say

    doc = ezdxf.new()
    doc.modelspace().add_lwpolyline([(0, 0), (10, 4), (10, 0), (0, 4)], close=True,
                                    dxfattribs={"layer": "OUTLINE"})
    doc.saveas(tmp_path / "plan.dxf")
    plan = read_floor_plan(tmp_path / "plan.dxf")
    assert plan.outline.area == pytest.approx(20.0)
    assert len(plan.repairs) == 1 and "LWPOLYLINE" in plan.repairs[0]
    assert "layer OUTLINE" in plan.repairs[0] and "Self-intersection" in plan.repairs[0]


def _plan(tmp_path: Path, *geometries: dict) -> Path:
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": g} for g in geometries]}
    path = tmp_path / "plan.geojson"
    path.write_text(json.dumps(fc))
    return path


def _square(x0: float, y0: float, side: float) -> dict:
    return {"type": "Polygon", "coordinates": [[[x0, y0], [x0 + side, y0],
                                                [x0 + side, y0 + side], [x0, y0 + side],
                                                [x0, y0]]]}


@pytest.mark.parametrize("geometries, match", [
    ([_square(0, 0, 10), {"type": "Blob", "coordinates": []}], "feature 1 has an invalid"),
    ([_square(0, 0, 10), {"type": "LineString", "coordinates": [[1, 1]]}],
     "feature 1 has an invalid geometry .*point array"),
    ([{"type": "Polygon", "coordinates": [[[0, 0], [10 ** 400, 0], [0, 5], [0, 0]]]}],
     "feature 0 has an invalid geometry"),
    ([{"type": "Polygon", "coordinates": [[[0, 0], [10, 10], [0, 0], [0, 0]]]}],
     "the outline has no area"),
    ([_square(121.3, 31.2, 1e-3)], "needs its floor_info.json"),  # lon/lat, no floor_info
    ([_square(-1000, -1000, 30000)], "floor size 30000 x 30000 m is over 20000 m"),
    ([_square(0, 0, 10), _square(-1, -1, 12)], "the obstacles cover the whole outline"),
    ([{"type": "MultiPolygon", "coordinates": []}], "feature 0 .the outline. is an empty"),
    ([{"type": "Polygon", "coordinates": [[]]}], "feature 0 .the outline. is an empty"),
])
def test_plans_that_cannot_hold_a_walk_are_refused_when_read(tmp_path, geometries, match):
    """Each used to pass (and fail late in the build, or be cut silently) or to escape as a
    shapely/OverflowError traceback."""
    with pytest.raises(FloorPlanError, match=match):
        read_floor_plan(_plan(tmp_path, *geometries))


@pytest.mark.parametrize("entity", ["nan_vertex", "inf_wall", "nan_circle", "units",
                                    "huge_hatch_arc"])
def test_dxf_entities_with_non_finite_numbers_or_unknown_units_are_named(tmp_path, entity):
    """The huge hatch arc is finite, but flattening it took 342 MB (at radius 1e300 it never
    ended)."""
    doc = ezdxf.new()
    msp = doc.modelspace()
    outline = [(0, 0), (40, 0), (40, 25), (0, 25)]
    if entity == "nan_vertex":
        outline[2] = (float("nan"), 25)
    msp.add_lwpolyline(outline, close=True, dxfattribs={"layer": "OUTLINE"})
    if entity == "inf_wall":
        msp.add_line((10, 0), (float("inf"), 5), dxfattribs={"layer": "WALLS"})
    if entity == "nan_circle":
        msp.add_circle((5, 5), float("nan"), dxfattribs={"layer": "PILLARS"})
    if entity == "units":
        doc.header["$INSUNITS"] = 18  # astronomical units
    if entity == "huge_hatch_arc":
        edges = msp.add_hatch(dxfattribs={"layer": "COLUMNS"}).paths.add_edge_path()
        edges.add_arc((5, 5), 1e9, 0, 180)
        edges.add_line((-1e9, 5), (1e9, 5))
    doc.saveas(tmp_path / "plan.dxf")
    match = {"nan_vertex": "LWPOLYLINE #.* on layer OUTLINE: .*non-finite",
             "inf_wall": "LINE #.* on layer WALLS: .*non-finite",
             "nan_circle": "CIRCLE #.* on layer PILLARS: .*finite",
             "units": r"\$INSUNITS = 18",
             "huge_hatch_arc": "HATCH #.* on layer COLUMNS: .*curve spans 2e\\+09 m"}[entity]
    with pytest.raises(FloorPlanError, match=match):
        read_floor_plan(tmp_path / "plan.dxf")


def test_a_cell_too_small_to_count_is_a_value_error():
    with pytest.raises(ValueError, match="over the limit"):
        grid_for_extent(40.0, 25.0, 1e-320)  # 40 / 1e-320 is infinite


def test_an_outline_with_a_spike_keeps_its_polygon(tmp_path):
    """make_valid turns a zero-width spike into a polygon plus a line; the polygon is the
    outline (it was refused as 'no area' for a moment)."""
    spike = {"type": "Polygon", "coordinates": [[[0, 0], [20, 0], [20, 10], [10, 10],
                                                 [10, 15], [10, 10], [0, 10], [0, 0]]]}
    plan = read_floor_plan(_plan(tmp_path, spike))
    assert plan.outline.geom_type == "Polygon" and plan.outline.area == pytest.approx(200.0)
    assert len(plan.repairs) == 1


def test_dxf_units_stored_as_text_are_read(tmp_path):
    doc = ezdxf.new()
    doc.modelspace().add_lwpolyline([(0, 0), (40000, 0), (40000, 25000), (0, 25000)],
                                    close=True, dxfattribs={"layer": "OUTLINE"})
    doc.saveas(tmp_path / "plan.dxf")
    text = (tmp_path / "plan.dxf").read_text()
    # $INSUNITS as group code 1 (text) with the value 4 (mm), as some writers store it
    text = text.replace("$INSUNITS\n 70\n6\n", "$INSUNITS\n  1\n4\n", 1)
    assert "$INSUNITS\n  1\n4\n" in text
    (tmp_path / "plan.dxf").write_text(text)
    plan = read_floor_plan(tmp_path / "plan.dxf")
    assert (plan.width_m, plan.height_m) == pytest.approx((40.0, 25.0))


def test_plans_in_metres_keep_their_coordinates(tmp_path):
    """A DXF drawing reaching below 0 was moved to start at (0, 0), so walks recorded in the
    drawing's coordinates missed it silently; a GeoJSON plan in metres there was refused.
    Both now keep their coordinates; the map frame starts at their lowest ones."""
    doc = ezdxf.new()
    doc.modelspace().add_lwpolyline([(-60, -20), (-20, -20), (-20, 5), (-60, 5)], close=True,
                                    dxfattribs={"layer": "OUTLINE"})
    doc.modelspace().add_circle((-40, -5), 3, dxfattribs={"layer": "OBSTACLES"})
    doc.saveas(tmp_path / "neg.dxf")
    plans = [read_floor_plan(tmp_path / "neg.dxf"),
             read_floor_plan(_plan(tmp_path, _square(-60, -20, 25), _square(-45, -10, 4)))]
    for plan in plans:
        assert plan.outline.bounds[:2] == (-60, -20)  # not moved
        assert (plan.x0_m, plan.y0_m) == (-60, -20)
        grid = plan.grid(0.5)
        assert (grid.x0_m, grid.y0_m) == (-60, -20)
        mask = reachable_mask(grid, plan.reachable)
        xc, yc = grid.cell_centers()
        inside = mask[np.searchsorted(yc, -15.0), np.searchsorted(xc, -55.0)]
        assert inside and mask.sum() * 0.25 == pytest.approx(plan.reachable.area, rel=0.05)
    assert (plans[0].width_m, plans[0].height_m) == (40.0, 25.0)  # -60 .. -20, -20 .. 5


def test_an_empty_outline_in_lonlat_is_refused_by_name(tmp_path):
    """Beside a floor_info.json an empty outline escaped as a GEOSException traceback."""
    import json
    import shutil

    floor = Path(__file__).resolve().parents[1] / "data" / "sample_site" / "F1"  # conftest
    shutil.copy(floor / "floor_info.json", tmp_path / "floor_info.json")
    plan = json.loads((floor / "geojson_map.json").read_text())
    plan["features"][0]["geometry"] = {"type": "MultiPolygon", "coordinates": []}
    (tmp_path / "geojson_map.json").write_text(json.dumps(plan))
    with pytest.raises(FloorPlanError, match="the outline. is an empty polygon"):
        read_floor_plan(tmp_path)


def _feature(geometry_type: str, coordinates, **properties) -> dict:
    return {"type": "Feature", "properties": properties,
            "geometry": {"type": geometry_type, "coordinates": coordinates}}


def test_geojson_roles_walls_walkable_outlines_and_lines_left_out(tmp_path):
    """``role``: a wall line is a 0.2 m wall, a walkable polygon is cut out of the obstacles
    (a passage through a block), two outlines are one floor, an ignored polygon is no
    obstacle; a line without the wall role is left out, and said. Before, a corridor
    polygon was an obstacle and every line vanished without a word."""
    ring = lambda x0, y0, x1, y1: [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]  # noqa
    fc = {"type": "FeatureCollection", "features": [
        _feature("Polygon", ring(0, 0, 20, 10), role="outline"),
        _feature("Polygon", ring(30, 0, 40, 10), role="Outline"),        # a second wing
        _feature("LineString", [[10, 0], [10, 10]], role="wall"),
        _feature("Polygon", ring(2, 2, 8, 8), kind="block"),             # an obstacle ...
        _feature("Polygon", ring(4, 2, 5, 8), role="corridor"),          # ... passage through
        _feature("Polygon", ring(32, 2, 34, 4), role="ignore"),
        _feature("LineString", [[30, 5], [40, 5]], name="route"),        # no role: left out
        _feature("Point", [1, 1], name="label"),                         # a label: quiet
        _feature("Point", [2, 1], role="wall")]}                         # said left out
    (tmp_path / "plan.geojson").write_text(json.dumps(fc))
    plan = read_floor_plan(tmp_path / "plan.geojson")
    assert plan.outline.area == pytest.approx(300)
    wall = 0.2 * 10
    assert plan.reachable.area == pytest.approx(300 - wall - (36 - 6))
    assert not plan.reachable.contains(shapely.Point(10.0, 5.0))       # the wall
    assert plan.reachable.contains(shapely.Point(4.5, 5.0))            # the passage
    assert not plan.reachable.contains(shapely.Point(3.0, 5.0))        # the block
    assert plan.reachable.contains(shapely.Point(33.0, 3.0))           # ignored
    assert plan.reachable.contains(shapely.Point(35.0, 5.0))           # the route is no wall
    assert plan.repairs == (f"{tmp_path / 'plan.geojson'}: 2 feature(s) left out "
                            "(feature 6, 8): a line is a wall only with property \"role\": "
                            "\"wall\", and points and geometry collections are not read",)
    # without an outline role feature 0 is the outline, unless its role says otherwise
    no_outline = {"type": "FeatureCollection", "features": fc["features"][2:]}
    (tmp_path / "no_outline.geojson").write_text(json.dumps(no_outline))
    with pytest.raises(FloorPlanError, match="no feature has role 'outline', and feature 0 "
                                             r"\(the outline of a plan without roles\) has "
                                             "role 'wall'"):
        read_floor_plan(tmp_path / "no_outline.geojson")
    fc["features"][3]["properties"]["role"] = "shop"
    (tmp_path / "plan.geojson").write_text(json.dumps(fc))
    with pytest.raises(FloorPlanError, match=r"plan.geojson: feature 3 has role 'shop', not "
                       r"one indoormap knows \(corridor, ignore, "):
        read_floor_plan(tmp_path / "plan.geojson")


def _features_of(plan, level: str | None, outline_role: bool = True) -> list[dict]:
    """A plan (metres) as GeoJSON features, each tagged ``level`` (when given)."""
    tag = {"level": level} if level is not None else {}
    feats = [{"type": "Feature", "geometry": shapely.geometry.mapping(plan.outline),
              "properties": {"role": "outline"} if outline_role else {}}]
    feats += [{"type": "Feature", "geometry": shapely.geometry.mapping(p), "properties": {}}
              for p in shapely.get_parts(plan.obstacles)]
    for f in feats:
        f["properties"].update(tag)
    return feats


def _collection(path: Path, feats: list[dict]) -> Path:
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    return path


def test_a_plan_of_several_floors_is_read_one_floor_at_a_time(tmp_path):
    """A building's export with every floor in one GeoJSON, each feature tagged with its
    ``level``: it was read as one floor, the outlines united and every floor's shops cut out
    (the sample F1's reachable area fell from 488 to 347 m^2, no warning). Now the floor named
    is read, equal to its own plan; without a name, or with one the file lacks, it is refused
    naming its floors."""
    f1, f2 = read_floor_plan(SITE / "F1"), read_floor_plan(SITE / "F2")
    building = _collection(tmp_path / "building.geojson",
                           _features_of(f1, "F1") + _features_of(f2, "F2"))
    alone = read_floor_plan(_collection(tmp_path / "F1.geojson", _features_of(f1, None)))
    picked = read_floor_plan(building, level="F1")
    assert picked.floor_name == "F1" and picked.repairs == (
        f"{building}: read for floor F1 of F1, F2: {len(_features_of(f2, 'F2'))} feature(s) "
        "of the other floors left out",)
    assert picked.reachable.symmetric_difference(alone.reachable).area < 1e-6
    assert picked.reachable.area == pytest.approx(f1.reachable.area)
    assert read_floor_plan(building, level="F2").reachable.area == \
        pytest.approx(f2.reachable.area)
    with pytest.raises(FloorPlanError, match=r"building.geojson: its features are of 2 floors "
                                             r"\(F1, F2\).*name the floor to read"):
        read_floor_plan(building)
    with pytest.raises(FloorPlanError, match="none is 'F3'"):
        read_floor_plan(building, level="F3")
    # a floor tagged "Level 1" is read for the floor folder "Level_1" (its store key)
    spaced = _collection(tmp_path / "spaced.geojson",
                         _features_of(f1, "Level 1") + _features_of(f2, "Level 2"))
    assert read_floor_plan(spaced, level="Level_1").floor_name == "Level 1"
    # a feature naming no floor is read as part of the floor picked, and said so
    shared = _features_of(f1, "F1") + _features_of(f2, "F2")
    del shared[1]["properties"]["level"]
    plan = read_floor_plan(_collection(tmp_path / "shared.geojson", shared), level="F2")
    assert "feature(s) of the other floors left out, 1 naming no floor (feature 1) read as " \
        "part of F2" in plan.repairs[0]
    assert plan.reachable.area < f2.reachable.area
    # a plan of one tagged floor reads as before, whatever floor is asked for (its tag is
    # not taken for the floor's name: a "floor": 1 would refuse walks of "F1")
    one = read_floor_plan(_collection(tmp_path / "one.geojson", _features_of(f1, "F1")),
                          level="anything")
    assert one.reachable.area == pytest.approx(f1.reachable.area) and one.floor_name == ""


def test_floor_outline_names_and_level_tags_are_not_mixed(tmp_path):
    """An outline named F1 (``type: floor``) among shops tagged ``level: 1`` (an export
    numbering its floors) was read as two floors "1" and "F1": read for F1, every shop was
    dropped without a word; read for 1, a shop became the outline. The tags decide; the
    outline naming no tag is read with them. Without tags, the floor outlines' names decide,
    and the picked floor's outline is the one naming it, not the first feature."""
    f1, f2 = read_floor_plan(SITE / "F1"), read_floor_plan(SITE / "F2")
    floor_outline = {"type": "Feature", "geometry": shapely.geometry.mapping(f1.outline),
                     "properties": {"type": "floor", "name": "F1"}}
    shops = _features_of(f1, "1")[1:]
    mixed = read_floor_plan(_collection(tmp_path / "mixed.geojson", [floor_outline, *shops]),
                            level="F1")
    assert mixed.reachable.area == pytest.approx(f1.reachable.area) and not mixed.repairs
    # two ILC-style floors (no roles, no tags), F2's outline and shops first
    f2_outline = {**floor_outline, "geometry": shapely.geometry.mapping(f2.outline),
                  "properties": {"type": "floor", "name": "F2"}}
    ilc = [f2_outline, *_features_of(f2, None)[1:], floor_outline]
    for f in ilc[1:-1]:
        f["properties"] = {}
    plan = read_floor_plan(_collection(tmp_path / "ilc.geojson", ilc), level="F1")
    assert plan.outline.equals(f1.outline)  # not F2's shop 0
    assert "1 feature(s) of the other floors left out" in plan.repairs[0]


def test_stacked_outlines_without_floor_tags_are_warned_of(tmp_path):
    """Two floors' outlines in one file with nothing saying which is which cannot be split,
    but outline features overlapping by more than half the smaller one is said: their
    union is read as the floor, both floors' shops cut out of it."""
    f1, f2 = read_floor_plan(SITE / "F1"), read_floor_plan(SITE / "F2")
    stacked = read_floor_plan(_collection(tmp_path / "stacked.geojson",
                                          _features_of(f1, None) + _features_of(f2, None)))
    assert len(stacked.repairs) == 1
    assert re.search(r"stacked.geojson: the outline features \(0, \d+\) overlap by \d+ m\^2, "
                     r"\d+% of the smallest: two floors' outlines in one file\?",
                     stacked.repairs[0])
    # an outline drawn as two pieces overlapping a little is an outline, not two floors
    pieces = [{"type": "Feature", "properties": {"role": "outline"}, "geometry": g}
              for g in (_square(0, 0, 20), _square(18, 0, 20))]
    assert not read_floor_plan(_collection(tmp_path / "pieces.geojson", pieces)).repairs
