"""Plots of localization results (matplotlib's object API: no pyplot state, so a notebook's
backend is left alone).

- :func:`track_figure`: trajectories over a bundle's reachable mask, with waypoints;
- :func:`cdf_figure`: error CDFs per method;
- :func:`draw_floor`: a bundle's floor under a caller's own drawing.

Each figure is a matplotlib ``Figure`` (a notebook shows it); :func:`plot_track` and
:func:`plot_cdfs` write them as PNG files, and return False when matplotlib is missing.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localize.bundle import MapBundle
from localize.evaluate import xy_rows
from localize.track import Track
from survey.publish import atomic_write_bytes

if TYPE_CHECKING:  # annotations only: matplotlib is optional
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["cdf_figure", "draw_floor", "plot_cdfs", "plot_track", "track_figure"]


#: Colour of the cells off a bundle's reachable area, in every figure over a floor.
OFF_MASK_GREY = "#9e9e9e"


def _have_matplotlib() -> bool:
    """Whether matplotlib can be imported (an error inside a figure is not taken for it)."""
    import importlib.util

    return importlib.util.find_spec("matplotlib") is not None


def _save_png(fig, path: str | Path) -> None:
    """The figure as a PNG at ``path``, written whole or not at all (a full disk or a killed
    process leaves the previous file, never a truncated one)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue(), overwrite=True)


def plot_track(path: str | Path, bundle: MapBundle, tracks: Mapping[str, Track],
               waypoints_xy: ArrayLike | None = None, title: str = "", *,
               margin_m: float = 8.0) -> bool:
    """:func:`track_figure` as a PNG at ``path``; False without matplotlib."""
    if not _have_matplotlib():
        return False
    _save_png(track_figure(bundle, tracks, waypoints_xy, title, margin_m=margin_m), path)
    return True


def track_figure(bundle: MapBundle, tracks: Mapping[str, Track],
                 waypoints_xy: ArrayLike | None = None, title: str = "", *,
                 margin_m: float = 8.0) -> Figure:
    """Trajectories over the bundle's reachable mask (cells off it grey), zoomed to the
    tracks and waypoints (``margin_m`` around them, within the floor): start (circle) and end
    (square) of each track, recoveries (x), waypoints with their order. A matplotlib
    ``Figure`` (its object API: a notebook shows it, ``fig.axes[0]`` takes more drawing);
    ImportError without matplotlib.

    ``tracks``: label -> track; ``waypoints_xy``: shape (k, 2), m, in time order."""
    from matplotlib.figure import Figure

    g = bundle.grid
    lines = {name: (np.r_[tr.start.x_m, tr.x_m], np.r_[tr.start.y_m, tr.y_m])
             for name, tr in tracks.items()}  # each track from its start
    pts = [np.column_stack(xy) for xy in lines.values()]
    if waypoints_xy is not None:
        waypoints_xy = xy_rows(waypoints_xy, None, "plot_track waypoints_xy")
        pts.append(waypoints_xy)
    pts = np.concatenate(pts) if pts else np.empty((0, 2))
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = np.array([g.x0_m, g.y0_m]), np.array([g.x1_m, g.y1_m])
    if len(pts):  # every point in view; the margin around them stops at the floor's edge
        p_lo, p_hi = pts.min(axis=0), pts.max(axis=0)
        lo = np.maximum(p_lo - margin_m, np.minimum(lo, p_lo))
        hi = np.minimum(p_hi + margin_m, np.maximum(hi, p_hi))
    span = np.maximum(hi - lo, 1.0)
    fig = Figure(figsize=(8, min(8 * span[1] / span[0], 14) + 1.6))
    ax = fig.subplots()
    draw_floor(ax, bundle)
    for name, tr in tracks.items():
        xs, ys = lines[name]
        (line,) = ax.plot(xs, ys, lw=1.2, label=name)
        ax.plot(xs[0], ys[0], "o", color=line.get_color(), ms=7, mfc="none")
        ax.plot(xs[-1], ys[-1], "s", color=line.get_color(), ms=6)
        if tr.n_recoveries:
            ax.plot(tr.x_m[tr.recovered], tr.y_m[tr.recovered], "x", color=line.get_color(),
                    ms=8, label=f"{name}: all particles died, re-drawn")
    if waypoints_xy is not None and len(waypoints_xy):
        ax.plot(waypoints_xy[:, 0], waypoints_xy[:, 1], "k.--", lw=0.6, ms=5, label="waypoints")
        for (wx, wy), numbers in _waypoint_labels(waypoints_xy):
            ax.annotate(numbers, (wx, wy), textcoords="offset points", xytext=(3, 3),
                        fontsize=6)
    ax.plot([], [], "ko", mfc="none", label="start")
    ax.plot([], [], "ks", label="end")
    ax.plot([], [], "s", color=OFF_MASK_GREY, alpha=0.8, ms=8, label="off the reachable area")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_title("\n".join(textwrap.wrap(title, 95)), fontsize=9)
    # below the map, not over it (loc="best" covered a corridor of the track)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3)
    fig.tight_layout()
    return fig


def draw_floor(ax: Axes, bundle: MapBundle) -> None:
    """The bundle's floor on ``ax``: cells off its reachable area grey (as in the validation
    report's figures), axes in metres (x east, y north), equal aspect."""
    from matplotlib.colors import ListedColormap

    g = bundle.grid
    ax.imshow(np.where(np.asarray(bundle.mask, dtype=bool), np.nan, 1.0), origin="lower",
              cmap=ListedColormap([OFF_MASK_GREY]), alpha=0.8, interpolation="nearest",
              extent=(g.x0_m, g.x1_m, g.y0_m, g.y1_m))
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_aspect("equal")


def _waypoint_labels(waypoints_xy: NDArray[np.float64], within_m: float = 0.5
                     ) -> list[tuple[tuple[float, float], str]]:
    """The waypoints' order numbers (from 1) to write beside them: one label per place, those
    of waypoints within ``within_m`` (m) of an earlier one joined ("3, 5"), whose numbers
    were drawn over each other."""
    places: list[tuple[tuple[float, float], list[str]]] = []
    for i, (wx, wy) in enumerate(waypoints_xy):
        near = next((p for p in places if np.hypot(p[0][0] - wx, p[0][1] - wy) <= within_m),
                    None)
        if near is None:
            places.append(((float(wx), float(wy)), [str(i + 1)]))
        else:
            near[1].append(str(i + 1))
    return [(xy, ", ".join(numbers)) for xy, numbers in places]


def plot_cdfs(path: str | Path, errors: Mapping[str, NDArray[np.float64]], title: str = ""
              ) -> bool:
    """:func:`cdf_figure` as a PNG at ``path``; False without matplotlib."""
    if not _have_matplotlib():
        return False
    _save_png(cdf_figure(errors, title), path)
    return True


def cdf_figure(errors: Mapping[str, NDArray[np.float64]], title: str = "") -> Figure:
    """Error CDFs per method (``errors``: label -> errors in m, NaN ignored), a matplotlib
    ``Figure``; ImportError without matplotlib."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    # distinct line styles: a curve equal to another (auto and what it ran) shows through it
    styles = ("-", "--", ":", "-.")
    for i, (name, e) in enumerate(errors.items()):
        e = np.sort(np.asarray(e)[np.isfinite(e)])
        if e.size:
            ax.plot(e, np.arange(1, e.size + 1) / e.size, label=name,
                    linestyle=styles[i % len(styles)])
    ax.set_xlabel("error at the waypoints (m)")
    ax.set_ylabel("share of waypoints")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("\n".join(textwrap.wrap(title, 70)), fontsize=9)
    fig.tight_layout()
    return fig
