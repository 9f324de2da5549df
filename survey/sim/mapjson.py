"""A floor's map files as JSON-able dictionaries (the layout of the real data).

- ``geojson_map.json``: FeatureCollection, feature 0 the floor outline (MultiPolygon), the others
  the shop polygons, in longitude/latitude. The metre frame maps *linearly* onto lon/lat around a
  fixed synthetic origin, so the outline's lon/lat bounding box maps onto
  ``[0, width] x [0, height]`` metres exactly as in the real data.
- ``floor_info.json``: ``{"map_info": {"width": W, "height": H}}``.
- ``planned_routes.geojson``: FeatureCollection of the walks' planned routes in *metres*
  (one LineString per walk through its click points; properties ``walk_id`` (= trace id),
  ``start_ms``, ``end_ms``, plus ``floor``, ``device_id`` and ``n_waypoints``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely.geometry import Polygon

from .floorplan import Floorplan


@dataclass(frozen=True)
class GeoOrigin:
    """Linear metre <-> lon/lat mapping around a synthetic origin (the metre frame's 0, 0).

    Attributes
    ----------
    lon_deg, lat_deg : float
        Longitude and latitude of ``x = 0, y = 0``.
    """

    lon_deg: float = 120.0
    lat_deg: float = 30.0

    @property
    def deg_per_m(self) -> tuple[float, float]:
        """(degrees of longitude, degrees of latitude) per metre east / north."""
        return (1.0 / (111_320.0 * math.cos(math.radians(self.lat_deg))), 1.0 / 110_574.0)

    def to_lonlat(self, xy_m: np.ndarray) -> np.ndarray:
        """Metres (n, 2) -> lon/lat degrees (n, 2)."""
        dlon, dlat = self.deg_per_m
        xy = np.asarray(xy_m, dtype=np.float64)
        return np.column_stack([self.lon_deg + xy[:, 0] * dlon, self.lat_deg + xy[:, 1] * dlat])


def _rings(poly: Polygon, origin: GeoOrigin) -> list[list[list[float]]]:
    rings = [poly.exterior] + list(poly.interiors)
    return [origin.to_lonlat(np.asarray(r.coords)).tolist() for r in rings]


def floor_geojson(plan: Floorplan, origin: GeoOrigin) -> dict:
    """``geojson_map.json`` of a floor (lon/lat)."""
    features = [{
        "type": "Feature",
        "geometry": {"type": "MultiPolygon", "coordinates": [_rings(plan.outline, origin)]},
        "properties": {"type": "floor", "category": "floor", "name": plan.name,
                       "floor_num": plan.index + 1},
    }]
    for i, shop in enumerate(plan.obstacles):
        features.append({
            "type": "Feature",
            "geometry": {"type": "Polygon", "coordinates": _rings(shop, origin)},
            "properties": {"id": f"{plan.name}-shop-{i:03d}", "name": f"Shop {plan.name}-{i:03d}",
                           "category": "shop"},
        })
    return {"type": "FeatureCollection", "features": features}


def floor_info(plan: Floorplan) -> dict:
    """``floor_info.json`` of a floor."""
    return {"map_info": {"height": plan.height_m, "width": plan.width_m}}


def planned_routes_geojson(walks: list[dict]) -> dict:
    """``planned_routes.geojson`` (metres).

    Parameters
    ----------
    walks : list of dict
        Each with ``walk_id``, ``start_ms``, ``end_ms``, ``route_m`` ((k, 2) array) and optional
        extra scalar properties (``floor``, ``device_id``, ...).
    """
    features = []
    for w in walks:
        props = {k: v for k, v in w.items() if k != "route_m"}
        features.append({
            "type": "Feature",
            "geometry": {"type": "LineString",
                         "coordinates": np.asarray(w["route_m"], dtype=np.float64).tolist()},
            "properties": props,
        })
    return {"type": "FeatureCollection", "name": "planned_routes",
            "units": "m (x east, y north, floor_info frame)", "features": features}
