"""DXF floor plans (walls and obstacles by layer), read with ezdxf.

Closed shapes (LWPOLYLINE and POLYLINE with their arcs (bulges), CIRCLE, closed ELLIPSE and
SPLINE, and HATCH, whose loops combine even-odd: an inner loop is a hole) on the outline layer
make the floor outline (the largest one if several; a polyline whose last point is its first
counts as closed). Without one, the outline layer's lines (LINE, ARC, open polylines) are
joined into rings (``shapely.polygonize``): an outline drawn as four LINEs. Closed shapes on
obstacle layers are obstacles; lines on wall layers (LINE, ARC, open polylines and splines)
become walls of ``wall_width_m`` (a hatch there is taken as the wall's area). Block
references (INSERT, MINSERT) are expanded, nested ones too; an entity of a block on layer
``0`` takes the layer of the reference, as CAD programs draw it. Curves are flattened to
within :data:`FLATTEN_TOLERANCE_M`. Reachable area = outline minus obstacles minus walls.
Coordinates are taken in metres, scaled by the drawing's ``$INSUNITS`` (millimetres,
centimetres, feet, ...; unknown codes are refused), and kept where they are: the map frame is
the drawing's, from (0, 0) or from its lowest coordinates if they are negative, so walks
recorded in the drawing's coordinates fit it. Other entities (TEXT, DIMENSION, ...) are
ignored.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import shapely
import shapely.errors

from .floorplan import (MAX_FLOOR_SIDE_M, WALL_WIDTH_M, FloorPlan, FloorPlanError, checked_plan,
                        made_valid, metre_frame, read_plan_bytes, wall_band)

_UNIT_TO_M = {0: 1.0, 1: 0.0254, 2: 0.3048, 3: 1609.344, 4: 0.001, 5: 0.01, 6: 1.0,
              7: 1000.0, 10: 0.9144, 13: 1e-6, 14: 0.1, 15: 10.0, 16: 100.0,
              21: 1200 / 3937}  # 21: US survey feet
FLATTEN_TOLERANCE_M = 0.005  # curves to within 5 mm, far below a 0.25 m cell
#: Most entities a plan's block references may expand to (on the layers it reads), and the
#: deepest nesting of block references: a drawing's columns and kiosks are far below; a
#: MINSERT of 10^6 copies, or a block that holds itself, would take memory and time without
#: bound.
MAX_ENTITIES = 200_000
MAX_BLOCK_DEPTH = 8
#: Ends of an open polyline within this distance (m) close it (CAD users end on the start).
CLOSE_GAP_M = 1e-3
#: The roles of a plan's layers (``read_dxf_floor_plan``'s ``<role>_layers``).
DXF_ROLES = ("outline", "obstacle", "wall")


def read_dxf_floor_plan(path: str | os.PathLike, *,
                        outline_layers: tuple[str, ...] = ("OUTLINE", "FLOOR", "BOUNDARY"),
                        obstacle_layers: tuple[str, ...] = ("OBSTACLES", "SHOPS", "ROOMS",
                                                            "COLUMNS", "PILLARS"),
                        wall_layers: tuple[str, ...] = ("WALLS", "WALL"),
                        wall_width_m: float = WALL_WIDTH_M) -> FloorPlan:
    """Read a DXF floor plan; layer names are matched case-insensitively.

    Raises
    ------
    FloorPlanError
        Unreadable DXF, no closed outline on the outline layers.
    """
    import ezdxf
    from ezdxf import recover

    path = Path(path)
    sources: list[tuple[str, str]] = []
    data = read_plan_bytes(path, "a DXF drawing", sources)
    try:
        doc, _auditor = recover.read(io.BytesIO(data))
    except ezdxf.DXFStructureError as err:
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
    outline_lines: list = []
    seen: dict[str, int] = {}  # entity kinds on the outline layers, for the error
    repairs: list[str] = []
    used_layers: set[str] = set()
    role_of: dict[str, str] = {}  # upper-case layer name -> role (the first role naming it)
    for role, names in upper.items():
        for name in names:
            role_of.setdefault(name, role)
    for e, layer in _expanded(doc.modelspace(), path, lambda name: name.upper() in role_of):
        used_layers.add(layer)
        role = role_of.get(layer.upper())
        if role is None:
            continue
        kind = e.dxftype()
        where = f"{path}: {kind} #{e.dxf.handle or 'of a block'} on layer {layer}"
        try:
            geom, line = _entity_geometry(e, scale, wall_width_m if role == "wall" else None,
                                          lambda g, where=where: made_valid(g, where, repairs))
        except (ValueError, shapely.errors.ShapelyError) as err:  # NaN radius, NaN vertex
            raise FloorPlanError(f"{where}: not a usable geometry ({str(err).strip()})") \
                from err
        if geom is not None and not geom.is_empty:
            shapes[role].append(geom)
        if role == "outline":
            seen[kind] = seen.get(kind, 0) + 1
            if line is not None:
                outline_lines.append(line)
    polygons = [g for g in shapes["outline"] if g.geom_type in ("Polygon", "MultiPolygon")]
    if not polygons and outline_lines:  # an outline drawn as lines that meet end to end
        polygons = _joined(outline_lines, path, repairs)
    if not polygons:
        found = (", ".join(f"{n} {k}" for k, n in sorted(seen.items())) + " (no closed shape, "
                 "and their lines close no ring)") if seen else "nothing"
        raise FloorPlanError(f"{path}: no closed outline on layers {sorted(upper['outline'])}:"
                             f" found {found}; the drawing's entities are on layers "
                             f"{', '.join(sorted(used_layers)) or '(none)'} "
                             "(name yours: `indoormap build --dxf-layer outline=NAME`, "
                             "read_dxf_floor_plan's outline_layers)")
    outline = max(polygons, key=lambda g: g.area)
    obstacles = shapely.union_all(shapes["obstacle"] + shapes["wall"]) \
        if shapes["obstacle"] or shapes["wall"] else shapely.Polygon()
    x0, y0, width, height = metre_frame(path, outline)
    return checked_plan(FloorPlan(outline, obstacles, width, height, tuple(repairs), x0, y0,
                                  tuple(sources)), path)


def _finite(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    if not np.isfinite(np.asarray(points, dtype=float)).all():
        raise ValueError("non-finite coordinates")
    return points


def _joined(lines: list, path: Path, repairs: list[str]) -> list:
    """The area an outline drawn as lines encloses: the lines snapped to
    :data:`CLOSE_GAP_M` (ends that nearly meet), noded where they cross (corners drawn
    overshooting), the faces they close merged (a partition line drawn on the outline layer
    does not split the floor); [] when they close none."""
    noded = shapely.union_all(shapely.set_precision(shapely.GeometryCollection(lines),
                                                    CLOSE_GAP_M))
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(noded)))
    if not len(faces):
        return []
    return [made_valid(shapely.union_all(faces), f"{path}: outline joined from lines",
                       repairs)]


def _expanded(entities, path: Path, relevant: Callable[[str], bool], layer: str | None = None,
              depth: int = 0, count: list[int] | None = None, memo: dict | None = None):
    """``(entity, layer)`` of ``entities`` with block references expanded (an entity of a
    block on layer ``0`` takes the reference's ``layer``). References whose layer and block
    hold nothing on a ``relevant`` layer (furniture, title blocks) are not expanded. A
    FloorPlanError past :data:`MAX_ENTITIES` entities from blocks or :data:`MAX_BLOCK_DEPTH`
    levels."""
    count = [0] if count is None else count
    memo = {} if memo is None else memo
    for e in entities:
        own = e.dxf.layer if layer is None or e.dxf.layer != "0" else layer
        if e.dxftype() != "INSERT":
            if depth:
                count[0] += 1
                if count[0] > MAX_ENTITIES:
                    raise FloorPlanError(f"{path}: more than {MAX_ENTITIES:,} entities in "
                                         "its block references")
            yield e, own
            continue
        block = e.block()
        if block is None or not (relevant(own) or _block_matters(block, relevant, memo)):
            continue
        if depth >= MAX_BLOCK_DEPTH:
            raise FloorPlanError(f"{path}: block references nested deeper than "
                                 f"{MAX_BLOCK_DEPTH} (a block that holds itself?)")
        copies = max(int(getattr(e, "mcount", 1)), 1)
        if count[0] + copies * max(len(block), 1) > MAX_ENTITIES:  # before they are made
            raise FloorPlanError(f"{path}: more than {MAX_ENTITIES:,} entities in its block "
                                 f"references ({copies:,} copies of block {e.dxf.name!r})")
        try:  # a MINSERT: each copy of its grid
            parts = [part for copy in (e.multi_insert() if copies > 1 else [e])
                     for part in copy.virtual_entities()]
        except Exception as err:  # ezdxf raises several kinds for a broken block
            raise FloorPlanError(f"{path}: INSERT #{e.dxf.handle} of block {e.dxf.name!r} "
                                 f"cannot be expanded ({err})") from err
        yield from _expanded(parts, path, relevant, own, depth + 1, count, memo)


def _block_matters(block, relevant: Callable[[str], bool], memo: dict, depth: int = 0) -> bool:
    """Whether ``block`` holds an entity on a ``relevant`` layer of its own (not ``0``),
    itself or in the blocks it references (``memo``: block name -> answer)."""
    if block.name in memo:
        return memo[block.name]
    memo[block.name] = False  # a block that holds itself adds nothing through the cycle
    found = False
    for e in block:
        if e.dxf.layer != "0" and relevant(e.dxf.layer):
            found = True
        elif e.dxftype() == "INSERT" and depth < MAX_BLOCK_DEPTH:
            inner = e.block()
            found = inner is not None and _block_matters(inner, relevant, memo, depth + 1)
        if found:
            break
    memo[block.name] = found
    return found


def _curve_points(curve, scale: float) -> list[tuple[float, float]]:
    """An ezdxf path flattened to within :data:`FLATTEN_TOLERANCE_M`, in metres. Raises
    ValueError for a curve wider than a floor can be (its flattening would take memory and
    time without bound: an arc of radius 1e9 took 342 MB)."""
    corners = _finite([(v.x * scale, v.y * scale) for v in curve.control_vertices()])
    if not corners:
        return []
    span_m = float(np.ptp(np.asarray(corners), axis=0).max())
    if span_m > MAX_FLOOR_SIDE_M:
        raise ValueError(f"a curve spans {span_m:.3g} m, more than a floor's "
                         f"{MAX_FLOOR_SIDE_M:g} m: drawn in other units than $INSUNITS says "
                         "(unset is taken as metres)?")
    return _finite([(v.x * scale, v.y * scale)
                    for v in curve.flattening(FLATTEN_TOLERANCE_M / scale)])


#: Entities read as curves (ezdxf's paths): their arcs and bulges flattened.
_CURVES = ("LWPOLYLINE", "POLYLINE", "ARC", "ELLIPSE", "SPLINE")


def _entity_geometry(e, scale: float, wall_width_m: float | None, valid: Callable):
    """``(area, line)`` of entity ``e``: the area it encloses (a closed shape; a wall's
    band on a wall layer, ``wall_width_m`` wide) or None, its polygons passed through
    ``valid``; and its linework when open (for an outline drawn as lines) or None. Raises
    ValueError on a non-finite coordinate or size."""
    kind = e.dxftype()
    if kind == "LINE":
        line = shapely.LineString(_finite([(e.dxf.start.x * scale, e.dxf.start.y * scale),
                                           (e.dxf.end.x * scale, e.dxf.end.y * scale)]))
        return (wall_band(line, wall_width_m) if wall_width_m else None,
                line)
    if kind in _CURVES:
        from ezdxf import path as ezpath

        if kind == "POLYLINE" and (e.is_poly_face_mesh or e.is_polygon_mesh):
            return None, None  # a mesh: no floor outline (a 3D polyline is read in x, y)
        pts = _curve_points(ezpath.make_path(e), scale)
        if len(pts) < 2:
            return None, None
        flagged = (e.closed if kind == "LWPOLYLINE" else e.is_closed if kind == "POLYLINE"
                   else bool(e.dxf.get("flags", 0) & 1) if kind == "SPLINE"
                   else kind == "ELLIPSE" and abs(e.dxf.end_param - e.dxf.start_param
                                                  - 2 * np.pi) < 1e-9)
        ends_meet = np.hypot(pts[0][0] - pts[-1][0], pts[0][1] - pts[-1][1]) <= CLOSE_GAP_M
        if (flagged or ends_meet) and len(pts) >= 3:
            poly = valid(shapely.Polygon(pts))
            return (poly if wall_width_m is None else poly.boundary.buffer(wall_width_m / 2),
                    None)
        line = shapely.LineString(pts)
        return (wall_band(line, wall_width_m) if wall_width_m else None,
                line)
    if kind == "CIRCLE":
        (cx, cy), = _finite([(e.dxf.center.x * scale, e.dxf.center.y * scale)])
        return shapely.Point(cx, cy).buffer(e.dxf.radius * scale), None
    if kind == "HATCH":
        return _hatch_area(e, scale, valid), None
    return None, None


def _hatch_area(hatch, scale: float, valid: Callable):
    """The area a hatch fills: its boundary loops (flattened by :func:`_curve_points`)
    combined even-odd, so that an inner loop is a hole; None without loops."""
    from ezdxf import path

    area = None
    for loop in path.from_hatch(hatch):
        pts = _curve_points(loop, scale)
        if len(pts) < 3:
            continue
        poly = valid(shapely.Polygon(pts))
        area = poly if area is None else shapely.symmetric_difference(area, poly)
    return area
