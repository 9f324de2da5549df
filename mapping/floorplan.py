"""Floor plans: read GeoJSON plans into the map frame (metres) and derive the reachable area.

Two GeoJSON flavours are read:

- the ``../shared/ilc`` kind: ``geojson_map.json`` in longitude/latitude whose feature 0 is the
  floor outline; its lon/lat bounding box maps linearly onto [0, width] x [0, height] metres
  given by ``floor_info.json`` (x east, y north);
- plain GeoJSON already in metres (a FeatureCollection whose feature 0, or the feature with
  property ``role: "outline"``, is the outline).

Reachable (walkable) area = outline minus obstacle polygons (by default every other polygon
feature; ``obstacle_filter`` selects by properties). DXF drawings are read by
:mod:`mapping.floorplan_dxf` (``read_floor_plan`` dispatches on the ``.dxf`` suffix).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import shapely
import shapely.errors
from shapely.geometry import shape

from localize.bundle import Grid
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
        What the reader mended: one line per invalid polygon (a self-intersecting outline, say)
        that was made valid, naming the feature and GEOS's reason. Worth showing the user: a
        bow-tie outline is built as the two triangles it encloses.
    x0_m, y0_m : float
        Lower-left corner of the map frame: 0, or the plan's lowest coordinate where a plan in
        metres (GeoJSON, DXF) reaches below 0. Plans are never moved: walks are recorded in
        the plan's own coordinates.
    """

    outline: shapely.Geometry
    obstacles: shapely.Geometry
    width_m: float
    height_m: float
    repairs: tuple[str, ...] = ()
    x0_m: float = 0.0
    y0_m: float = 0.0

    def grid(self, cell_m: float) -> Grid:
        """The raster grid over the map frame with ``cell_m`` (m) cells."""
        return grid_for_extent(self.width_m, self.height_m, cell_m, x0_m=self.x0_m,
                               y0_m=self.y0_m)

    @property
    def reachable(self) -> shapely.Geometry:
        """Outline minus obstacles."""
        return shapely.difference(self.outline, self.obstacles)


def made_valid(geom: shapely.Geometry, what: str, repairs: list[str]) -> shapely.Geometry:
    """``geom`` made valid by shapely; when it was not, a line naming ``what`` and GEOS's
    reason (e.g. ``Self-intersection[3 4]``) is appended to ``repairs``."""
    if shapely.is_valid(geom):
        return geom
    repairs.append(f"{what} is not a valid polygon ({shapely.is_valid_reason(geom)}); "
                   "repaired by shapely's make_valid")
    return shapely.make_valid(geom)


def _read_json(path: Path, what: str) -> object:
    """The content of a JSON file; a :class:`FloorPlanError` naming the file (and the line of
    a syntax error) when it cannot be read or parsed."""
    try:
        text = read_regular(path, MAX_PLAN_FILE_BYTES).decode("utf-8")  # not a FIFO/device
    except (OSError, UnicodeDecodeError) as err:
        raise FloorPlanError(f"{path}: cannot read {what} ({err})") from err
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise FloorPlanError(f"{path}:{err.lineno}: not valid JSON ({err.msg})") from err
    except RecursionError as err:  # absurdly deep nesting
        raise FloorPlanError(f"{path}: not {what} (nested too deeply)") from err


def _features(path: Path) -> list[dict]:
    data = _read_json(path, "a GeoJSON floor plan")
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
                             f"{MAX_FLOOR_SIDE_M:g} m on a side (the map frame runs from (0, 0) "
                             "to the plan's largest coordinates: a plan in metres, near the "
                             "origin?)")
    return float(width_m), float(height_m)


#: Widest outline (deg of longitude or latitude, about 55 km) a lon/lat plan may have: a
#: plan in metres beside a ``floor_info.json`` would otherwise be silently rescaled to it.
MAX_LONLAT_SPAN_DEG = 0.5


def read_floor_plan(floor_dir_or_geojson: str | os.PathLike, *,
                    obstacle_filter: Callable[[dict], bool] | None = None,
                    dxf_layers: dict[str, tuple[str, ...]] | None = None) -> FloorPlan:
    """Read a floor plan.

    Parameters
    ----------
    floor_dir_or_geojson : path-like
        A floor folder holding ``geojson_map.json`` (+ ``floor_info.json`` for lon/lat plans),
        or a GeoJSON file. With ``floor_info.json`` next to it the plan is taken to be in
        lon/lat; without, in metres.
    obstacle_filter : callable(properties) -> bool, optional
        Which non-outline features are obstacles (default: all polygons).
    dxf_layers : dict, optional
        For a DXF drawing: role (``outline``, ``obstacle``, ``wall``) -> layer names, in
        place of that role's defaults (:func:`mapping.floorplan_dxf.read_dxf_floor_plan`).
    """
    p = Path(floor_dir_or_geojson)
    if p.suffix.lower() == ".dxf":
        from .floorplan_dxf import read_dxf_floor_plan

        return read_dxf_floor_plan(p, **{f"{role}_layers": tuple(names)
                                         for role, names in (dxf_layers or {}).items()})
    geo = p / "geojson_map.json" if p.is_dir() else p
    info = geo.parent / "floor_info.json"
    feats = _features(geo)
    outline_idx = next((i for i, f in enumerate(feats)
                        if (f.get("properties") or {}).get("role") == "outline"), 0)
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
    outline = geoms[outline_idx]
    if outline is None or outline.geom_type not in ("Polygon", "MultiPolygon"):
        raise FloorPlanError(f"{geo}: feature {outline_idx} (the outline) is not a polygon")
    if outline.is_empty:
        raise FloorPlanError(f"{geo}: feature {outline_idx} (the outline) is an empty polygon")
    if info.exists():
        meta = _read_json(info, "a floor_info file")
        try:
            meta = meta["map_info"]
            width, height = float(meta["width"]), float(meta["height"])
        except (ValueError, KeyError, TypeError) as err:
            raise FloorPlanError(f"{info}: needs map_info.width and map_info.height ({err})") \
                from err
        width, height = checked_size(info, width, height)
        x0 = y0 = 0.0
        lon0, lat0, lon1, lat1 = outline.bounds
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
        outline = geoms[outline_idx]
    else:
        x0, y0, width, height = metre_frame(geo, outline)
    keep = obstacle_filter or (lambda props: True)
    repairs: list[str] = []
    outline = made_valid(outline, f"{geo}: feature {outline_idx} (the outline)", repairs)
    obstacles = [made_valid(g, f"{geo}: feature {i}", repairs)
                 for i, (g, f) in enumerate(zip(geoms, feats))
                 if i != outline_idx and g is not None
                 and g.geom_type in ("Polygon", "MultiPolygon")
                 and keep(f.get("properties") or {})]
    obstacle_union = shapely.union_all(obstacles) if obstacles else shapely.Polygon()
    return checked_plan(FloorPlan(outline, obstacle_union, width, height, tuple(repairs),
                                  x0, y0), geo)


def metre_frame(path: Path, outline: shapely.Geometry) -> tuple[float, float, float, float]:
    """``(x0_m, y0_m, width_m, height_m)`` of the map frame of a plan in metres: from (0, 0),
    or from the outline's lowest coordinates where they are below 0, to its largest."""
    minx, miny, maxx, maxy = outline.bounds
    x0, y0 = min(0.0, float(minx)), min(0.0, float(miny))
    width, height = checked_size(path, maxx - x0, maxy - y0)
    return x0, y0, width, height


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
