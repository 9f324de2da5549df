"""Floor plans: read GeoJSON plans into the map frame (metres) and derive the reachable area.

Two GeoJSON flavours are read:

- the ``../shared/ilc`` kind: ``geojson_map.json`` in longitude/latitude whose feature 0 is the
  floor outline; its lon/lat bounding box maps linearly onto [0, width] x [0, height] metres
  given by ``floor_info.json`` (x east, y north);
- plain GeoJSON already in metres (a FeatureCollection whose features with property
  ``role: "outline"`` are the outline, united; without any, feature 0, which then has no
  role).

Reachable (walkable) area = outline minus obstacles. A feature's ``role`` property says what
it is (:data:`GEOJSON_ROLES`): a polygon without one is an obstacle (``obstacle_filter``
selects among them by properties), ``role: "wall"`` lines are walls :data:`WALL_WIDTH_M`
thick, ``role: "walkable"`` (or ``corridor``, ``open``, ``passage``) polygons are open floor
cut out of the obstacles, and ``role: "ignore"`` features are left out. Lines without a wall
role are left out too, said in :attr:`FloorPlan.repairs`. A GeoJSON export of several floors
(features tagged by a :data:`LEVEL_PROPERTIES` property such as ``level``) is read one floor
at a time, named by ``level``; outline features that overlap are warned of (two floors
stacked). DXF drawings are read by :mod:`mapping.floorplan_dxf` (``read_floor_plan``
dispatches on the ``.dxf`` suffix).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import shapely
import shapely.errors
from shapely.geometry import shape

from localize.bundle import MAX_COORD_M, Grid
from localize.names import floor_key
from mapping.grid import grid_for_extent
from survey.errors import IndoormapError
from survey.regular_files import read_regular


class FloorPlanError(IndoormapError, ValueError):
    """A floor plan cannot be read or makes no sense."""


#: Largest floor-plan file (GeoJSON, floor_info.json or DXF) read, bytes: a floor's drawing is
#: a few MB; a FIFO or a link to /dev/zero is refused before anything is read.
MAX_PLAN_FILE_BYTES = 512 * 2**20
#: Largest floor side (m) a plan may have.
MAX_FLOOR_SIDE_M = 20_000.0
#: Thickness (m) of a wall drawn as a line (GeoJSON ``role: "wall"``, DXF wall layers).
WALL_WIDTH_M = 0.2
#: GeoJSON ``role`` property values (case-insensitive) -> what the feature is. Features
#: without a role: polygons are obstacles, lines are left out (with a note), points ignored.
GEOJSON_ROLES = {"outline": "outline", "obstacle": "obstacle", "wall": "wall",
                 "walkable": "walkable", "corridor": "walkable", "open": "walkable",
                 "passage": "walkable", "ignore": "ignore"}
#: Feature properties (keys case-insensitive, first found) saying which floor a feature of a
#: GeoJSON plan is on, as a building's export of all its floors in one file tags them. An
#: outline feature naming its floor (``type`` or ``category`` ``"floor"``, with a ``name``)
#: is on that floor.
LEVEL_PROPERTIES = ("level", "floor", "floor_name", "level_name", "storey")
#: Share of the smallest outline feature that outline features of a plan may overlap by
#: before the reader warns (two floors' outlines stacked in one file).
OUTLINE_OVERLAP_WARN = 0.5


@dataclass(frozen=True)
class FloorPlan:
    """A floor plan in the map frame (metres, x east, y north).

    Attributes
    ----------
    outline : shapely geometry
        The floor outline.
    obstacles : shapely geometry
        Union of obstacle polygons (shops, walls, pillars).
    width_m, height_m : float
        Extent of the map frame, from ``(x0_m, y0_m)``.
    repairs : tuple of str
        What the reader mended or left out: one line per invalid polygon (a self-intersecting
        outline, say) that was made valid, naming the feature and GEOS's reason, and one for
        the GeoJSON lines left out for want of ``role: "wall"``. Worth showing the user: a
        bow-tie outline is built as the two triangles it encloses.
    sources : tuple of (str, str)
        The files the plan was read from, as ``(file name, sha256 hex)`` of the bytes read
        (``geojson_map.json`` and ``floor_info.json``, or the DXF drawing); the build records
        them in the bundle's manifest. Empty for a plan made in code.
    x0_m, y0_m : float
        Lower-left corner of the map frame: 0 for a lon/lat plan; for a plan in metres
        (GeoJSON, DXF), its lowest coordinates rounded down to whole metres. Plans are never
        moved: walks are recorded in the plan's own coordinates.
    floor_name : str
        The floor the plan says it is of: the ``name`` of a GeoJSON outline feature whose
        ``type`` or ``category`` is ``"floor"`` (the ILC plans' and the simulator's feature
        0, e.g. ``"F2"``); empty when it says none (DXF drawings, plain outlines).
    """

    outline: shapely.Geometry
    obstacles: shapely.Geometry
    width_m: float
    height_m: float
    repairs: tuple[str, ...] = ()
    x0_m: float = 0.0
    y0_m: float = 0.0
    sources: tuple[tuple[str, str], ...] = ()
    floor_name: str = ""

    def grid(self, cell_m: float) -> Grid:
        """The raster grid over the map frame with ``cell_m`` (m) cells."""
        return grid_for_extent(self.width_m, self.height_m, cell_m, x0_m=self.x0_m,
                               y0_m=self.y0_m)

    @property
    def reachable(self) -> shapely.Geometry:
        """Outline minus obstacles."""
        return shapely.difference(self.outline, self.obstacles)


def wall_band(line: shapely.Geometry, width_m: float = WALL_WIDTH_M) -> shapely.Geometry:
    """A wall line as the band it blocks: ``width_m`` wide (m), flat at its ends."""
    return shapely.buffer(line, width_m / 2, cap_style="flat")


def made_valid(geom: shapely.Geometry, what: str, repairs: list[str]) -> shapely.Geometry:
    """``geom`` made valid by shapely; when it was not, a line naming ``what`` and GEOS's
    reason (e.g. ``Self-intersection[3 4]``) is appended to ``repairs``."""
    if shapely.is_valid(geom):
        return geom
    repairs.append(f"{what} is not a valid polygon ({shapely.is_valid_reason(geom)}); "
                   "repaired by shapely's make_valid")
    return shapely.make_valid(geom)


def read_plan_bytes(path: Path, what: str, sources: list[tuple[str, str]]) -> bytes:
    """The bytes of a plan file (not a FIFO or device, at most :data:`MAX_PLAN_FILE_BYTES`),
    with ``(file name, sha256)`` appended to ``sources``; a :class:`FloorPlanError` naming the
    file when it cannot be read."""
    try:
        data = read_regular(path, MAX_PLAN_FILE_BYTES)
    except OSError as err:
        raise FloorPlanError(f"{path}: cannot read {what} ({err})") from err
    sources.append((path.name, hashlib.sha256(data).hexdigest()))
    return data


def _read_json(path: Path, what: str, sources: list[tuple[str, str]]) -> object:
    """The content of a JSON file; a :class:`FloorPlanError` naming the file (and the line of
    a syntax error) when it cannot be read or parsed."""
    try:
        text = read_plan_bytes(path, what, sources).decode("utf-8")
    except UnicodeDecodeError as err:
        raise FloorPlanError(f"{path}: cannot read {what} ({err})") from err
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise FloorPlanError(f"{path}:{err.lineno}: not valid JSON ({err.msg}: column "
                             f"{err.colno})") from err
    except RecursionError as err:  # absurdly deep nesting
        raise FloorPlanError(f"{path}: not {what} (nested too deeply)") from err


def _features(path: Path, sources: list[tuple[str, str]]) -> list[dict]:
    data = _read_json(path, "a GeoJSON floor plan", sources)
    feats = data.get("features") if isinstance(data, dict) else None
    if not feats or not isinstance(feats, list):
        raise FloorPlanError(f"{path}: a floor plan needs a FeatureCollection with features")
    for i, f in enumerate(feats):
        if not isinstance(f, dict) or not isinstance(f.get("properties") or {}, dict):
            raise FloorPlanError(f"{path}: feature {i} is not a GeoJSON feature (an object "
                                 "with an object of properties)")
    return feats


def checked_size(path: Path, width_m: float, height_m: float) -> tuple[float, float]:
    """``(width_m, height_m)`` of a floor, refused unless finite, positive and at most
    :data:`MAX_FLOOR_SIDE_M` (a floor_info.json typo would otherwise ask for a raster of
    terabytes)."""
    if not (np.isfinite(width_m) and np.isfinite(height_m) and width_m > 0 and height_m > 0):
        raise FloorPlanError(f"{path}: floor size {width_m} x {height_m} m is not a positive, "
                             "finite size")
    if max(width_m, height_m) > MAX_FLOOR_SIDE_M:
        raise FloorPlanError(f"{path}: floor size {width_m:g} x {height_m:g} m is over "
                             f"{MAX_FLOOR_SIDE_M:g} m on a side")
    return float(width_m), float(height_m)


#: Widest outline (deg of longitude or latitude, about 55 km) a lon/lat plan may have: a
#: plan in metres beside a ``floor_info.json`` would otherwise be silently rescaled to it.
MAX_LONLAT_SPAN_DEG = 0.5


def plan_floor_name(path: str | os.PathLike) -> str:
    """The floor a floor plan (`process --floor-plan`, `build --plan`) is for: a folder's name, the
    name of the folder holding a ``geojson_map.json``, else the file's name without its suffix
    (``plans/F2.dxf``: F2)."""
    file = plan_file(path)
    return file.parent.resolve().name if file.name == "geojson_map.json" else file.stem


def plan_file(path: str | os.PathLike) -> Path:
    """The file a floor plan path names: a floor folder's ``geojson_map.json``, else the
    path itself."""
    path = Path(path)
    return path / "geojson_map.json" if path.is_dir() else path


def read_floor_plan(floor_dir_or_geojson: str | os.PathLike, *,
                    obstacle_filter: Callable[[dict], bool] | None = None,
                    dxf_layers: dict[str, tuple[str, ...]] | None = None,
                    level: str | None = None) -> FloorPlan:
    """Read a floor plan.

    Parameters
    ----------
    floor_dir_or_geojson : path-like
        A floor folder holding ``geojson_map.json`` (+ ``floor_info.json`` for lon/lat plans),
        or a GeoJSON file. With ``floor_info.json`` next to it the plan is taken to be in
        lon/lat; without, in metres.
    obstacle_filter : callable(properties) -> bool, optional
        Which polygons without a ``role`` (or with ``role: "obstacle"``) are obstacles
        (default: all). Roles are in :data:`GEOJSON_ROLES`; an unknown role is refused.
    dxf_layers : dict, optional
        For a DXF drawing: role (``outline``, ``obstacle``, ``wall``) -> layer names, in
        place of that role's defaults (:func:`mapping.floorplan_dxf.read_dxf_floor_plan`).
    level : str, optional
        The floor to read from a GeoJSON plan whose features are of several floors (tagged
        by a :data:`LEVEL_PROPERTIES` property): its features and those without a floor are
        read, the others left out. A plan of several floors read without the name of one of
        them is refused, naming its floors; ``level`` is not used for a plan of one floor
        (a floor folder's name or ``build --floor`` is passed for every plan).
    """
    p = Path(floor_dir_or_geojson)
    if p.suffix.lower() == ".dxf":
        from .floorplan_dxf import read_dxf_floor_plan

        return read_dxf_floor_plan(p, **{f"{role}_layers": tuple(names)
                                         for role, names in (dxf_layers or {}).items()})
    geo = plan_file(p)
    info = geo.parent / "floor_info.json"
    sources: list[tuple[str, str]] = []
    feats = _features(geo, sources)
    repairs: list[str] = []
    on_floor, floor_name = _features_of_level(feats, level, geo, repairs)
    roles = [_role(f, geo, i) if mine else "ignore"
             for i, (f, mine) in enumerate(zip(feats, on_floor))]
    first = on_floor.index(True)
    if floor_name:  # a floor picked from several: its outline is the one naming it
        first = next((i for i, mine in enumerate(on_floor)
                      if mine and _named_floor(feats[i])), first)
    outline_at = [i for i, r in enumerate(roles) if r == "outline"] or [first]  # union of them
    if "outline" not in roles and roles[first] is not None:
        raise FloorPlanError(f"{geo}: no feature has role 'outline', and feature {first} (the "
                             f"outline of a plan without roles) has role {roles[first]!r}")
    geoms = []
    for i, f in enumerate(feats):
        try:
            geoms.append(shape(f["geometry"]) if f.get("geometry") else None)
        except (KeyError, ValueError, TypeError, AttributeError, OverflowError,
                shapely.errors.ShapelyError) as err:  # an unknown type, a 1-point line, 1e400
            raise FloorPlanError(f"{geo}: feature {i} has an invalid geometry "
                                 f"({str(err).strip()})") from err
    for i, g in enumerate(geoms):
        if g is not None and not np.isfinite(shapely.get_coordinates(g)).all():
            raise FloorPlanError(f"{geo}: feature {i} has non-finite coordinates")
    for i in outline_at:
        if geoms[i] is None or geoms[i].geom_type not in ("Polygon", "MultiPolygon"):
            raise FloorPlanError(f"{geo}: feature {i} (the outline) is not a polygon")
        if geoms[i].is_empty:
            raise FloorPlanError(f"{geo}: feature {i} (the outline) is an empty polygon")
    if info.exists():
        meta = _read_json(info, "a floor_info file", sources)
        try:
            meta = meta["map_info"]
            width, height = float(meta["width"]), float(meta["height"])
        except (ValueError, KeyError, TypeError) as err:
            raise FloorPlanError(f"{info}: needs map_info.width and map_info.height ({err})") \
                from err
        width, height = checked_size(info, width, height)
        x0 = y0 = 0.0
        lon0, lat0, lon1, lat1 = shapely.total_bounds([geoms[i] for i in outline_at])
        if lon1 <= lon0 or lat1 <= lat0:
            raise FloorPlanError(f"{geo}: degenerate outline bounds")
        if (max(abs(lon0), abs(lon1)) > 180 or max(abs(lat0), abs(lat1)) > 90
                or lon1 - lon0 > MAX_LONLAT_SPAN_DEG or lat1 - lat0 > MAX_LONLAT_SPAN_DEG):
            raise FloorPlanError(
                f"{geo}: read as lon/lat because {info.name} is beside it, but its outline "
                f"spans {lon1 - lon0:.6g} x {lat1 - lat0:.6g} (from {lon0:.6g}, {lat0:.6g}), "
                "no building in degrees; a plan in metres must not sit beside "
                f"{info.name} (move it, or pass it from another folder)")
        sx, sy = width / (lon1 - lon0), height / (lat1 - lat0)

        def to_m(coords: np.ndarray) -> np.ndarray:
            return np.column_stack([(coords[:, 0] - lon0) * sx, (coords[:, 1] - lat0) * sy])

        geoms = [None if g is None else shapely.transform(g, to_m) for g in geoms]
    parts = [made_valid(geoms[i], f"{geo}: feature {i} (the outline)", repairs)
             for i in outline_at]
    outline = parts[0] if len(parts) == 1 else shapely.union_all(parts)
    if len(parts) > 1:
        _warn_overlapping_outlines(geo, parts, outline_at, outline, repairs)
    if not info.exists():
        x0, y0, width, height = metre_frame(geo, outline)
    keep = obstacle_filter or (lambda props: True)
    obstacles, walkable, lines_left_out = [], [], []
    for i, (g, f, role) in enumerate(zip(geoms, feats, roles)):
        if i in outline_at or g is None or role == "ignore":
            continue
        if g.geom_type in ("LineString", "MultiLineString", "LinearRing"):
            if role == "wall":
                obstacles.append(wall_band(g))
            else:
                lines_left_out.append(i)
        elif g.geom_type in ("Polygon", "MultiPolygon"):
            polygon = made_valid(g, f"{geo}: feature {i}", repairs)
            if role == "walkable":
                walkable.append(polygon)
            elif role == "wall" or keep(f.get("properties") or {}):
                obstacles.append(polygon)
        elif role is not None:  # a point or a collection said to be part of the plan
            lines_left_out.append(i)
    if lines_left_out:
        shown = ", ".join(map(str, lines_left_out[:5])) + (", ..." if len(lines_left_out) > 5
                                                            else "")
        repairs.append(f"{geo}: {len(lines_left_out)} feature(s) left out (feature {shown}): "
                       "a line is a wall only with property \"role\": \"wall\", and points "
                       "and geometry collections are not read")
    obstacle_union = shapely.union_all(obstacles) if obstacles else shapely.Polygon()
    if walkable:
        obstacle_union = shapely.difference(obstacle_union, shapely.union_all(walkable))
    return checked_plan(FloorPlan(outline, obstacle_union, width, height, tuple(repairs),
                                  x0, y0, tuple(sources),
                                  floor_name or next((n for i in outline_at
                                                      if (n := _named_floor(feats[i]))), "")),
                        geo)


def feature_level(feature: dict) -> str:
    """The floor a GeoJSON feature is tagged with: its first :data:`LEVEL_PROPERTIES`
    property (a text or a number); empty without one."""
    props = feature.get("properties") or {}
    by_key = {str(k).lower(): v for k, v in props.items()}
    for key in LEVEL_PROPERTIES:
        value = by_key.get(key)
        if isinstance(value, (str, int, float)) and not isinstance(value, bool) \
                and str(value).strip():
            return str(value).strip()
    return ""


def plan_levels(path: str | os.PathLike) -> list[str]:
    """The floors a GeoJSON plan's features name, sorted (as :func:`read_floor_plan` reads
    them by ``level``; one for a plan tagged with one floor); empty for a plan naming none
    and for a DXF drawing."""
    file = plan_file(path)
    if file.suffix.lower() == ".dxf":
        return []
    return sorted(set(_floor_tags(_features(file, []))) - {""})


def _floor_tags(feats: list[dict]) -> list[str]:
    """Each feature's floor: its :data:`LEVEL_PROPERTIES` tag, or in a plan without any,
    the name of a floor outline (``type`` or ``category`` ``"floor"``); empty for none."""
    levels = [feature_level(f) for f in feats]
    return levels if any(levels) else [_named_floor(f) for f in feats]


def _features_of_level(feats: list[dict], level: str | None, path: Path,
                       repairs: list[str]) -> tuple[list[bool], str]:
    """Which features are read (all, or for a plan of several floors those of ``level``
    and those of no floor) and the floor they were picked for (empty when all are read);
    a :class:`FloorPlanError` for a plan of several floors without one of them named.

    A plan's floors are its features' :data:`LEVEL_PROPERTIES` tags; in a plan without
    any, the names of its floor outlines (``type`` or ``category`` ``"floor"``). The two are
    not mixed: an outline named ``F1`` among shops tagged ``level: 1`` is one floor."""
    levels = _floor_tags(feats)
    named = sorted(set(levels) - {""})
    if len(named) < 2:
        return [True] * len(feats), ""
    wanted = None if level is None else floor_key(level)
    picked = [lv for lv in named if wanted is not None and floor_key(lv) == wanted]
    if not picked:
        shown = ", ".join(named[:10]) + (", ..." if len(named) > 10 else "")
        asked = "" if level is None else f", and none is {level!r}, the one it is read for"
        raise FloorPlanError(
            f"{path}: its features are of {len(named)} floors ({shown}), tagged by "
            f"{'/'.join(LEVEL_PROPERTIES)} or a floor outline's name; a floor's plan is of "
            f"one floor{asked}: name the floor to read (`indoormap build TRACES --plan FILE "
            "--floor NAME`, a floor folder named after it, `read_floor_plan(..., level=NAME)`)")
    mine = [lv in ("", *picked) for lv in levels]
    untagged = [i for i, lv in enumerate(levels) if not lv and feats[i].get("geometry")]
    said = (f"{path}: read for floor {picked[0]} of {', '.join(named)}: "
            f"{mine.count(False)} feature(s) of the other floors left out")
    if untagged:
        shown = ", ".join(map(str, untagged[:5])) + (", ..." if len(untagged) > 5 else "")
        said += (f", {len(untagged)} naming no floor (feature {shown}) read as part of "
                 f"{picked[0]}")
    repairs.append(said)
    return mine, picked[0]


def _warn_overlapping_outlines(path: Path, parts: list[shapely.Geometry], at: list[int],
                               union: shapely.Geometry, repairs: list[str]) -> None:
    """A line in ``repairs`` when the outline features overlap by more than
    :data:`OUTLINE_OVERLAP_WARN` of the smallest: two floors' outlines in one file, whose
    union is no floor and whose shops would all be cut out of it."""
    areas = shapely.area(np.asarray(parts, dtype=object))
    overlap = float(areas.sum() - union.area)
    if overlap > OUTLINE_OVERLAP_WARN * float(areas.min()):
        shown = ", ".join(map(str, at[:5])) + (", ..." if len(at) > 5 else "")
        repairs.append(f"{path}: the outline features ({shown}) overlap by {overlap:.0f} m^2, "
                       f"{overlap / areas.min():.0%} of the smallest: two floors' outlines in "
                       "one file? Their union is read as the outline and every other polygon "
                       "cut out of it; give each floor its own plan, or tag the features with "
                       "their floor (property \"level\") and name it")


def _named_floor(feature: dict) -> str:
    """The floor name a feature saying it is a floor (``type`` or ``category``
    ``"floor"``) gives as its ``name``; empty for any other."""
    props = feature.get("properties") or {}
    name = props.get("name")
    if "floor" in (props.get("type"), props.get("category")) and isinstance(name, str):
        return name.strip()
    return ""


def _role(feature: dict, path: Path, index: int) -> str | None:
    """The :data:`GEOJSON_ROLES` meaning of a feature's ``role`` property (None without one);
    a :class:`FloorPlanError` naming the feature for a role indoormap does not know."""
    role = (feature.get("properties") or {}).get("role")
    if role is None:
        return None
    meaning = GEOJSON_ROLES.get(str(role).strip().lower())
    if meaning is None:
        raise FloorPlanError(f"{path}: feature {index} has role {role!r}, not one indoormap "
                             f"knows ({', '.join(sorted(GEOJSON_ROLES))})")
    return meaning


def metre_frame(path: Path, outline: shapely.Geometry) -> tuple[float, float, float, float]:
    """``(x0_m, y0_m, width_m, height_m)`` of the map frame of a plan in metres: from the
    outline's lowest coordinates, rounded down to whole metres (so the cells of a 0.25, 0.5
    or 1 m grid have round edges), to its largest. A plan in a local or projected CRS
    (a site grid at (3000, 3000), UTM eastings) gets a frame of the floor's own size; the
    walks and the plan keep their coordinates."""
    minx, miny, maxx, maxy = outline.bounds
    if max(abs(minx), abs(miny), abs(maxx), abs(maxy)) > MAX_COORD_M:
        raise FloorPlanError(f"{path}: the outline reaches ({minx:g}, {miny:g}) .. ({maxx:g}, "
                             f"{maxy:g}) m, beyond the {MAX_COORD_M:g} m a map's coordinates "
                             "may have (not metres?)")
    x0, y0 = math.floor(minx), math.floor(miny)
    width, height = checked_size(path, maxx - x0, maxy - y0)
    return float(x0), float(y0), width, height


def checked_plan(plan: FloorPlan, source: Path) -> FloorPlan:
    """``plan`` if it can hold a walk: an outline with area, at least 1 m on a side, not all
    of it covered by obstacles; else a :class:`FloorPlanError` naming ``source``."""
    outline = plan.outline
    if outline.geom_type == "GeometryCollection":  # a repaired spike: a polygon and a line
        outline = shapely.union_all([g for g in shapely.get_parts(outline)
                                     if g.geom_type in ("Polygon", "MultiPolygon")])
        plan = replace(plan, outline=outline)
    if outline.geom_type not in ("Polygon", "MultiPolygon") or not outline.area > 0:
        raise FloorPlanError(f"{source}: the outline has no area (a {outline.geom_type} "
                             "after repair)")
    minx, miny, maxx, maxy = outline.bounds
    if max(maxx - minx, maxy - miny) < 1.0:
        raise FloorPlanError(f"{source}: the outline is {maxx - minx:.3g} x {maxy - miny:.3g} m, "
                             "too small for a floor (a plan in lon/lat needs its floor_info.json "
                             "beside it)")
    if not plan.reachable.area > 0:
        raise FloorPlanError(f"{source}: the obstacles cover the whole outline; nothing is "
                             "reachable")
    return plan
