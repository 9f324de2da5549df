"""DXF floor plans (walls and obstacles by layer), read with ezdxf.

Closed polylines (LWPOLYLINE, POLYLINE), circles and hatches (their loops even-odd: an inner
loop is a hole) on the outline layer make the floor outline (the largest one if several); closed
shapes on obstacle layers are obstacles; open polylines and LINE entities on wall layers become
walls of ``wall_width_m`` (a hatch there is taken as the wall's area). Reachable area = outline
minus obstacles minus walls. Coordinates are taken in metres, scaled by the drawing's
``$INSUNITS`` (millimetres, centimetres, feet, ...; unknown codes are refused), and kept where
they are: the map frame is the drawing's, from (0, 0) or from its lowest coordinates if they
are negative, so walks recorded in the drawing's coordinates fit it.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import shapely
import shapely.errors

from survey.regular_files import read_regular

from .floorplan import (MAX_FLOOR_SIDE_M, MAX_PLAN_FILE_BYTES, FloorPlan, FloorPlanError,
                        checked_plan, made_valid, metre_frame)

_UNIT_TO_M = {0: 1.0, 1: 0.0254, 2: 0.3048, 3: 1609.344, 4: 0.001, 5: 0.01, 6: 1.0,
              7: 1000.0, 10: 0.9144, 13: 1e-6, 14: 0.1, 15: 10.0, 16: 100.0,
              21: 1200 / 3937}  # 21: US survey feet
FLATTEN_TOLERANCE_M = 0.005  # hatch curves to within 5 mm, far below a 0.25 m cell


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
        doc, _auditor = recover.read(io.BytesIO(read_regular(path, MAX_PLAN_FILE_BYTES)))
    except (OSError, ezdxf.DXFStructureError) as err:
        raise FloorPlanError(f"{path}: not a readable DXF file ({err})") from err
    units = doc.header.get("$INSUNITS", 0)
    try:  # an int, or a number stored as text or float by some writers
        units = int(float(units))
    except (TypeError, ValueError):
        pass
    if units not in _UNIT_TO_M:
        raise FloorPlanError(f"{path}: drawing units $INSUNITS = {units!r} are not a length "
                             f"indoormap reads (codes {sorted(_UNIT_TO_M)}; 0 = unitless, "
                             "taken as metres)")
    scale = _UNIT_TO_M[units]
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
        try:
            geom = _entity_geometry(e, scale, wall_width_m if role == "wall" else None,
                                    lambda g, where=where: made_valid(g, where, repairs))
        except (ValueError, shapely.errors.ShapelyError) as err:  # NaN radius, NaN vertex
            raise FloorPlanError(f"{where}: not a usable geometry ({str(err).strip()})") \
                from err
        if geom is not None and not geom.is_empty:
            shapes[role].append(geom)
    polygons = [g for g in shapes["outline"] if g.geom_type in ("Polygon", "MultiPolygon")]
    if not polygons:
        raise FloorPlanError(f"{path}: no closed outline on layers {sorted(upper['outline'])}")
    outline = max(polygons, key=lambda g: g.area)
    obstacles = shapely.union_all(shapes["obstacle"] + shapes["wall"]) \
        if shapes["obstacle"] or shapes["wall"] else shapely.Polygon()
    x0, y0, width, height = metre_frame(path, outline)
    return checked_plan(FloorPlan(outline, obstacles, width, height, tuple(repairs), x0, y0),
                        path)


def _finite(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    if not np.isfinite(np.asarray(points, dtype=float)).all():
        raise ValueError("non-finite coordinates")
    return points


def _entity_geometry(e, scale: float, wall_width_m: float | None, valid: Callable):
    """The area (or None) of entity ``e``: its polygons are passed through ``valid``.
    Raises ValueError on a non-finite coordinate or size."""
    kind = e.dxftype()
    if kind == "LINE":
        line = shapely.LineString(_finite([(e.dxf.start.x * scale, e.dxf.start.y * scale),
                                           (e.dxf.end.x * scale, e.dxf.end.y * scale)]))
        return line.buffer(wall_width_m / 2, cap_style="flat") if wall_width_m else None
    if kind in ("LWPOLYLINE", "POLYLINE"):
        pts = _finite([(p[0] * scale, p[1] * scale) for p in
                       (e.get_points("xy") if kind == "LWPOLYLINE" else
                        [(v.dxf.location.x, v.dxf.location.y) for v in e.vertices])])
        closed = e.closed if kind == "LWPOLYLINE" else e.is_closed
        if closed and len(pts) >= 3:
            poly = valid(shapely.Polygon(pts))
            return poly if wall_width_m is None else poly.boundary.buffer(wall_width_m / 2)
        if len(pts) >= 2 and wall_width_m:
            return shapely.LineString(pts).buffer(wall_width_m / 2, cap_style="flat")
        return None
    if kind == "CIRCLE":
        (cx, cy), = _finite([(e.dxf.center.x * scale, e.dxf.center.y * scale)])
        return shapely.Point(cx, cy).buffer(e.dxf.radius * scale)
    if kind == "HATCH":
        return _hatch_area(e, scale, valid)
    return None


def _hatch_area(hatch, scale: float, valid: Callable):
    """The area a hatch fills: its boundary loops (arcs and splines flattened to within
    :data:`FLATTEN_TOLERANCE_M`) combined even-odd, so that an inner loop is a hole; None
    without loops. Raises ValueError for a loop wider than a floor can be (its flattening
    would take memory and time without bound: an arc of radius 1e9 took 342 MB)."""
    from ezdxf import path

    area = None
    for loop in path.from_hatch(hatch):
        corners = _finite([(v.x * scale, v.y * scale) for v in loop.control_vertices()])
        if not corners:
            continue
        span_m = float(np.ptp(np.asarray(corners), axis=0).max())
        if span_m > MAX_FLOOR_SIDE_M:
            raise ValueError(f"a boundary loop spans {span_m:.3g} m, more than a floor's "
                             f"{MAX_FLOOR_SIDE_M:g} m")
        pts = _finite([(v.x * scale, v.y * scale)
                       for v in loop.flattening(FLATTEN_TOLERANCE_M / scale)])
        if len(pts) < 3:
            continue
        poly = valid(shapely.Polygon(pts))
        area = poly if area is None else shapely.symmetric_difference(area, poly)
    return area
