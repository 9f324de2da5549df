"""Synthetic floor plans: an outline, shop blocks, corridors and the survey's walk lines.

Coordinates are metres, ``x`` east and ``y`` north, with the outline's bounding box exactly
``[0, width] x [0, height]`` (the frame of the real data's waypoints). Corridors run wall to wall
in both directions; the rectangles between them are filled with shops (the obstacles), so the
walkable area is the union of the corridors. Every corridor gets a walk line on its axis; wide
corridors get two more lines parallel to it, as in the survey of paper 001.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon, box
from shapely.ops import unary_union

from ..errors import SimulationError

#: Walk lines end this far (m) from the floor outline.
WALK_LINE_INSET_M = 0.6
#: Corridors at least this wide (m) get parallel walk lines beside the axis line.
WIDE_CORRIDOR_M = 2.4


@dataclass(frozen=True)
class Corridor:
    """A straight corridor running wall to wall.

    Attributes
    ----------
    orientation : str
        ``"ew"`` (runs east-west, centred on ``y = center_m``) or ``"ns"`` (runs north-south,
        centred on ``x = center_m``).
    center_m, width_m : float
        Axis position and width, metres.
    """

    orientation: str
    center_m: float
    width_m: float


@dataclass(frozen=True)
class WalkLine:
    """A straight survey line along a corridor.

    Attributes
    ----------
    line : shapely.LineString
        Two-point line, metres.
    corridor : int
        Index of the corridor in :attr:`Floorplan.corridors`.
    offset_m : float
        Signed distance from the corridor axis (north/east positive).
    """

    line: LineString
    corridor: int
    offset_m: float


@dataclass(frozen=True)
class Floorplan:
    """One floor: outline, obstacles (shops), corridors and walk lines, all in metres."""

    name: str
    index: int
    width_m: float
    height_m: float
    outline: Polygon
    obstacles: tuple[Polygon, ...]
    corridors: tuple[Corridor, ...]
    walk_lines: tuple[WalkLine, ...]
    _margin_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @cached_property
    def walkable(self) -> Polygon | MultiPolygon:
        """Outline minus the obstacles (the corridors)."""
        geom = self.outline.difference(unary_union(list(self.obstacles)))
        shapely.prepare(geom)
        return geom

    def walkable_with_margin(self, margin_m: float) -> Polygon | MultiPolygon:
        """The walkable area shrunk by ``margin_m`` metres (prepared, cached per margin)."""
        key = round(float(margin_m), 6)
        cache = self._margin_cache
        if key not in cache:
            geom = self.walkable.buffer(-key, join_style="mitre") if key > 0 else self.walkable
            shapely.prepare(geom)
            cache[key] = geom
        return cache[key]

    def is_walkable(self, x_m: np.ndarray, y_m: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """Boolean mask (shape of ``x_m``): points inside the walkable area shrunk by
        ``margin_m`` metres."""
        return shapely.contains_xy(self.walkable_with_margin(margin_m), x_m, y_m)

    def obstacle_labels(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Index of the obstacle containing each point, ``-1`` outside all obstacles."""
        x_m = np.asarray(x_m, dtype=np.float64)
        y_m = np.asarray(y_m, dtype=np.float64)
        labels = np.full(x_m.shape, -1, dtype=np.int32)
        for i, poly in enumerate(self.obstacles):
            minx, miny, maxx, maxy = poly.bounds
            cand = (x_m >= minx) & (x_m <= maxx) & (y_m >= miny) & (y_m <= maxy)
            if cand.any():
                hit = shapely.contains_xy(poly, x_m[cand], y_m[cand])
                idx = np.flatnonzero(cand)[hit]
                labels.flat[idx] = i
        return labels


def place_corridors(length_m: float, widths_m: tuple[float, ...], min_block_m: float,
                    rng: np.random.Generator) -> np.ndarray:
    """Axis positions of corridors across an extent, leaving blocks of at least ``min_block_m``.

    Parameters
    ----------
    length_m : float
        Extent the corridors cross (metres).
    widths_m : tuple of float
        Corridor widths in the order they are placed.
    min_block_m : float
        Minimum depth of the shop blocks between corridors and along the walls.
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray, shape (len(widths_m),)
        Corridor centres (metres, increasing), rounded to 0.05 m.
    """
    widths = np.asarray(widths_m, dtype=np.float64)
    n = len(widths)
    free = length_m - widths.sum() - (n + 1) * min_block_m
    if free < 0:
        raise SimulationError(
            f"{n} corridors of total width {widths.sum():.1f} m and blocks of {min_block_m} m "
            f"do not fit in {length_m} m")
    blocks = min_block_m + free * rng.dirichlet(np.full(n + 1, 4.0))
    starts = np.cumsum(blocks[:n]) + np.concatenate([[0.0], np.cumsum(widths[:-1])])
    return np.round((starts + widths / 2) / 0.05) * 0.05


def _intervals_between(length_m: float, centers: np.ndarray, widths: np.ndarray
                       ) -> list[tuple[float, float]]:
    edges = [0.0]
    for c, w in zip(centers, widths):
        edges += [c - w / 2, c + w / 2]
    edges.append(length_m)
    return [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]


def _split(lo: float, hi: float, piece_range_m: tuple[float, float],
           rng: np.random.Generator) -> list[tuple[float, float]]:
    cuts = [lo]
    pos = lo
    while True:
        step = rng.uniform(*piece_range_m)
        if hi - (pos + step) < piece_range_m[0] * 0.6:
            break
        pos += step
        cuts.append(pos)
    cuts.append(hi)
    return [(cuts[i], cuts[i + 1]) for i in range(len(cuts) - 1)]


def make_floorplan(name: str, index: int, width_m: float, height_m: float,
                   ew_widths_m: tuple[float, ...], ns_widths_m: tuple[float, ...],
                   rng: np.random.Generator, *, min_block_m: float = 3.0,
                   shop_length_m: tuple[float, float] = (3.0, 8.0),
                   notch: bool = True) -> Floorplan:
    """A random mall-like floor.

    Parameters
    ----------
    name : str
        Floor name (``"F1"``).
    index : int
        Floor index (0 = lowest).
    width_m, height_m : float
        Size of the outline's bounding box, metres.
    ew_widths_m, ns_widths_m : tuple of float
        Widths (m) of the east-west and north-south corridors; their order is shuffled.
    rng : numpy.random.Generator
    min_block_m : float
        Minimum depth of a shop block (m).
    shop_length_m : (float, float)
        Range of shop frontage lengths (m) when a block is split into shops.
    notch : bool
        Cut a corner out of the outline (inside a corner shop block, away from corridors).

    Returns
    -------
    Floorplan
    """
    ew = np.asarray(rng.permutation(np.asarray(ew_widths_m, dtype=np.float64)))
    ns = np.asarray(rng.permutation(np.asarray(ns_widths_m, dtype=np.float64)))
    ew_c = place_corridors(height_m, tuple(ew), min_block_m, rng)
    ns_c = place_corridors(width_m, tuple(ns), min_block_m, rng)
    corridors = tuple([Corridor("ew", float(c), float(w)) for c, w in zip(ew_c, ew)]
                      + [Corridor("ns", float(c), float(w)) for c, w in zip(ns_c, ns)])

    outline = box(0.0, 0.0, width_m, height_m)
    x_blocks = _intervals_between(width_m, ns_c, ns)
    y_blocks = _intervals_between(height_m, ew_c, ew)
    if notch:
        nw = round(min(5.0, 0.6 * (x_blocks[-1][1] - x_blocks[-1][0])), 2)
        nh = round(min(4.0, 0.6 * (y_blocks[-1][1] - y_blocks[-1][0])), 2)
        outline = outline.difference(box(width_m - nw, height_m - nh, width_m, height_m))
        outline = shapely.normalize(outline)

    obstacles: list[Polygon] = []
    for x0, x1 in x_blocks:
        for y0, y1 in y_blocks:
            if x1 - x0 >= y1 - y0:
                pieces = [(a, y0, b, y1) for a, b in _split(x0, x1, shop_length_m, rng)]
            else:
                pieces = [(x0, a, x1, b) for a, b in _split(y0, y1, shop_length_m, rng)]
            for p in pieces:
                shop = box(*p).intersection(outline)
                if isinstance(shop, Polygon) and shop.area >= 1.0:
                    obstacles.append(shapely.normalize(shop))

    inner = outline.buffer(-WALK_LINE_INSET_M, join_style="mitre")
    lines: list[WalkLine] = []
    for ci, c in enumerate(corridors):
        offsets = [0.0]
        if c.width_m >= WIDE_CORRIDOR_M:
            off = round(min(1.5, c.width_m / 2 - 0.6), 2)
            offsets = [-off, 0.0, off]
        for off in offsets:
            pos = c.center_m + off
            if c.orientation == "ew":
                raw = LineString([(0.0, pos), (width_m, pos)])
            else:
                raw = LineString([(pos, 0.0), (pos, height_m)])
            clipped = raw.intersection(inner)
            parts = [g for g in getattr(clipped, "geoms", [clipped])
                     if isinstance(g, LineString) and g.length > 1.0]
            if not parts:
                continue
            best = max(parts, key=lambda g: g.length)
            (xa, ya), (xb, yb) = best.coords[0], best.coords[-1]
            lines.append(WalkLine(LineString([(xa, ya), (xb, yb)]), ci, float(off)))

    return Floorplan(name=name, index=index, width_m=float(width_m), height_m=float(height_m),
                     outline=outline, obstacles=tuple(obstacles), corridors=corridors,
                     walk_lines=tuple(lines))
