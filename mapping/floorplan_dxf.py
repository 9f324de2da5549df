"""DXF floor plans (walls and obstacles by layer), read with ezdxf.

Closed polylines (LWPOLYLINE, POLYLINE), circles and hatches (their loops even-odd: an inner
loop is a hole) on the outline layer make the floor outline (the largest one if several); closed
shapes on obstacle layers are obstacles; open polylines and LINE entities on wall layers become
walls of ``wall_width_m`` (a hatch there is taken as the wall's area). Reachable area = outline
minus obstacles minus walls. Coordinates are taken in metres, scaled by the drawing's
``$INSUNITS`` when it says millimetres, centimetres or feet.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import shapely

from .floorplan import FloorPlan, FloorPlanError, checked_size, made_valid

_UNIT_TO_M = {0: 1.0, 1: 0.0254, 2: 0.3048, 4: 0.001, 5: 0.01, 6: 1.0}


def read_dxf_floor_plan(path: str | os.PathLike, *,
                        outline_layers: tuple[str, ...] = ("OUTLINE", "FLOOR", "BOUNDARY"),
                        obstacle_layers: tuple[str, ...] = ("OBSTACLES", "SHOPS", "ROOMS",
                                                            "COLUMNS", "PILLARS"),
                        wall_layers: tuple[str, ...] = ("WALLS", "WALL"),
                        wall_width_m: float = 0.2) -> FloorPlan:
    """Read a DXF floor plan; layer names are matched case-insensitively.

    Raises
    ------
    FloorPlanError
        Unreadable DXF, no closed outline on the outline layers.
    """
    import ezdxf
    from ezdxf import recover

    path = Path(path)
    try:
        doc, _auditor = recover.readfile(str(path))
    except (OSError, ezdxf.DXFStructureError) as err:
        raise FloorPlanError(f"{path}: not a readable DXF file ({err})") from err
    scale = _UNIT_TO_M.get(int(doc.header.get("$INSUNITS", 0)), 1.0)
    upper = {k: {n.upper() for n in v} for k, v in (("outline", outline_layers),
                                                     ("obstacle", obstacle_layers),
                                                     ("wall", wall_layers))}
    shapes: dict[str, list] = {"outline": [], "obstacle": [], "wall": []}
    repairs: list[str] = []
    for e in doc.modelspace():
        layer = e.dxf.layer.upper()
        role = next((r for r, names in upper.items() if layer in names), None)
        if role is None:
            continue
        where = f"{path}: {e.dxftype()} #{e.dxf.handle} on layer {e.dxf.layer}"
        geom = _entity_geometry(e, scale, wall_width_m if role == "wall" else None,
                                lambda g, where=where: made_valid(g, where, repairs))
        if geom is not None and not geom.is_empty:
            shapes[role].append(geom)
    polygons = [g for g in shapes["outline"] if g.geom_type in ("Polygon", "MultiPolygon")]
    if not polygons:
        raise FloorPlanError(f"{path}: no closed outline on layers {sorted(upper['outline'])}")
    outline = max(polygons, key=lambda g: g.area)
    obstacles = shapely.union_all(shapes["obstacle"] + shapes["wall"]) \
        if shapes["obstacle"] or shapes["wall"] else shapely.Polygon()
    minx, miny, maxx, maxy = outline.bounds
    if minx < 0 or miny < 0:  # the map frame starts at the outline's lower-left corner
        outline = shapely.affinity.translate(outline, -minx, -miny)
        obstacles = shapely.affinity.translate(obstacles, -minx, -miny)
        minx, miny, maxx, maxy = outline.bounds
    return FloorPlan(outline, obstacles, *checked_size(path, maxx, maxy), tuple(repairs))


def _entity_geometry(e, scale: float, wall_width_m: float | None, valid: Callable):
    """The area (or None) of entity ``e``: its polygons are passed through ``valid``."""
    kind = e.dxftype()
    if kind == "LINE":
        line = shapely.LineString([(e.dxf.start.x * scale, e.dxf.start.y * scale),
                                   (e.dxf.end.x * scale, e.dxf.end.y * scale)])
        return line.buffer(wall_width_m / 2, cap_style="flat") if wall_width_m else None
    if kind in ("LWPOLYLINE", "POLYLINE"):
        pts = [(p[0] * scale, p[1] * scale) for p in
               (e.get_points("xy") if kind == "LWPOLYLINE" else
                [(v.dxf.location.x, v.dxf.location.y) for v in e.vertices])]
        closed = e.closed if kind == "LWPOLYLINE" else e.is_closed
        if closed and len(pts) >= 3:
            poly = valid(shapely.Polygon(pts))
            return poly if wall_width_m is None else poly.boundary.buffer(wall_width_m / 2)
        if len(pts) >= 2 and wall_width_m:
            return shapely.LineString(pts).buffer(wall_width_m / 2, cap_style="flat")
        return None
    if kind == "CIRCLE":
        c = e.dxf.center
        return shapely.Point(c.x * scale, c.y * scale).buffer(e.dxf.radius * scale)
    if kind == "HATCH":
        return _hatch_area(e, scale, valid)
    return None


def _hatch_area(hatch, scale: float, valid: Callable):
    """The area a hatch fills: its boundary loops (arcs and splines flattened to within 0.01
    drawing units) combined even-odd, so that an inner loop is a hole; None without loops."""
    from ezdxf import path

    area = None
    for loop in path.from_hatch(hatch):
        pts = [(v.x * scale, v.y * scale) for v in loop.flattening(0.01)]
        if len(pts) < 3:
            continue
        poly = valid(shapely.Polygon(pts))
        area = poly if area is None else shapely.symmetric_difference(area, poly)
    return area
