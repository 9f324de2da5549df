"""The waypoint graph of a floor and random survey routes on it.

Nodes are the points a surveyor clicks: walk-line ends, crossings of walk lines, and marker
points spaced at most ``marker_spacing_m`` apart along each line (so walks reuse a limited set of
map points, like the real data). Edges join consecutive nodes along a walk line. A route is a
random walk on this graph that prefers going straight, turns at crossings, and turns back only at
dead ends.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import shapely

from .floorplan import Floorplan


@dataclass(frozen=True)
class WaypointGraph:
    """Undirected graph of click points.

    Attributes
    ----------
    nodes_m : numpy.ndarray, shape (n, 2)
        Node positions, metres.
    neighbors : tuple of tuple of int
        Adjacent node indices per node.
    """

    nodes_m: np.ndarray
    neighbors: tuple[tuple[int, ...], ...]


def build_graph(plan: Floorplan, marker_spacing_m: float = 6.0) -> WaypointGraph:
    """Waypoint graph of ``plan``'s walk lines.

    Parameters
    ----------
    plan : Floorplan
    marker_spacing_m : float
        Largest distance between consecutive click points along a line (m).
    """
    lines = [w.line for w in plan.walk_lines]
    keys: dict[tuple[float, float], int] = {}
    coords: list[tuple[float, float]] = []

    def node(x: float, y: float) -> int:
        k = (round(x, 6), round(y, 6))
        if k not in keys:
            keys[k] = len(coords)
            coords.append(k)
        return keys[k]

    edges: set[tuple[int, int]] = set()
    for i, li in enumerate(lines):
        params = [0.0, li.length]
        for j, lj in enumerate(lines):
            if i == j:
                continue
            inter = li.intersection(lj)
            if isinstance(inter, shapely.Point):
                params.append(li.project(inter))
        key_pts = np.unique(np.round(np.asarray(params), 6))
        ts: list[float] = []
        for a, b in pairwise(key_pts):
            n = max(1, int(np.ceil((b - a) / marker_spacing_m - 1e-9)))
            ts.extend(np.linspace(a, b, n + 1)[:-1].tolist())
        ts.append(float(key_pts[-1]))
        ids = []
        for t in ts:
            p = li.interpolate(t)
            ids.append(node(p.x, p.y))
        for a, b in pairwise(ids):
            if a != b:
                edges.add((min(a, b), max(a, b)))
    nbrs: list[list[int]] = [[] for _ in coords]
    for a, b in sorted(edges):
        nbrs[a].append(b)
        nbrs[b].append(a)
    return WaypointGraph(np.asarray(coords, dtype=np.float64), tuple(tuple(n) for n in nbrs))


def random_route(graph: WaypointGraph, target_length_m: float, rng: np.random.Generator, *,
                 straight_weight: float = 5.0) -> np.ndarray:
    """A random route of at least ``target_length_m`` metres (or until stuck).

    Parameters
    ----------
    graph : WaypointGraph
    target_length_m : float
        Route length to reach (m); the route ends at the first node past it.
    rng : numpy.random.Generator
    straight_weight : float
        Relative weight of continuing straight over turning at a crossing.

    Returns
    -------
    numpy.ndarray, shape (k, 2)
        The route's click points (metres), k >= 2, consecutive points distinct.
    """
    nodes = graph.nodes_m
    degree = np.array([len(n) for n in graph.neighbors])
    start_pool = np.flatnonzero(degree > 0)
    cur = int(rng.choice(start_pool))
    prev = -1
    route = [cur]
    length = 0.0
    for _ in range(10_000):
        if length >= target_length_m:
            break
        options = [n for n in graph.neighbors[cur] if n != prev] or list(graph.neighbors[cur])
        if prev >= 0:
            d_in = nodes[cur] - nodes[prev]
            d_in = d_in / np.linalg.norm(d_in)
            w = []
            for n in options:
                d_out = nodes[n] - nodes[cur]
                d_out = d_out / np.linalg.norm(d_out)
                w.append(straight_weight if float(d_in @ d_out) > 0.9 else 1.0)
            w = np.asarray(w) / np.sum(w)
            nxt = int(options[rng.choice(len(options), p=w)])
        else:
            nxt = int(options[rng.integers(len(options))])
        length += float(np.linalg.norm(nodes[nxt] - nodes[cur]))
        prev, cur = cur, nxt
        route.append(cur)
    return nodes[np.asarray(route)]


def click_points(route_m: np.ndarray, min_spacing_m: float = 4.0,
                 turn_deg: float = 20.0) -> np.ndarray:
    """The route's vertices a surveyor clicks: start, end, every turn, and graph markers at least
    ``min_spacing_m`` from the previous click and half that from the next turn or the end.

    Parameters
    ----------
    route_m : numpy.ndarray, shape (k, 2)
        Route from :func:`random_route`.
    min_spacing_m : float
        Minimum arc distance between a marker click and the previous click (m).
    turn_deg : float
        Direction changes above this count as turns (always clicked).

    Returns
    -------
    numpy.ndarray, shape (j, 2)
        Subset of the route's vertices, in order; the planned polyline of the walk.
    """
    r = np.asarray(route_m, dtype=np.float64)
    if len(r) <= 2:
        return r.copy()
    seg = np.diff(r, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg_len)])
    d = seg / seg_len[:, None]
    cos_turn = np.einsum("ij,ij->i", d[:-1], d[1:])
    is_turn = np.concatenate([[True], cos_turn < np.cos(np.radians(turn_deg)), [True]])
    turn_s = s[is_turn]
    keep = [0]
    for i in range(1, len(r)):
        if is_turn[i]:
            keep.append(i)
            continue
        next_turn = turn_s[np.searchsorted(turn_s, s[i], side="right")]
        if s[i] - s[keep[-1]] >= min_spacing_m and next_turn - s[i] >= 0.5 * min_spacing_m:
            keep.append(i)
    return r[np.asarray(keep)]
