"""The validation report: PNG figures (matplotlib, Agg) and one self-contained ``report.html``.

:func:`write_report` writes into a folder::

    report.html      every figure embedded as a base64 PNG data URI; no scripts, no external
                     resources (opens offline, can be mailed as one file)
    metrics.json     :meth:`mapping.validate.ValidationResult.to_json`
    figures/*.png    the same figures as files

Every raster is drawn over the floor plan: the floor image (``floor_image.png`` of the floor
folder, spanning ``[0, width] x [0, height]`` m of ``floor_info.json``) when there is one, the
bundle's reachable mask (non-reachable cells shaded) always. Figures are sized for reading at a
glance: one message per figure, units on every colour bar, problems in red.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import BoundaryNorm, Colormap, ListedColormap, Normalize, TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.image import AxesImage, imread
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from numpy.typing import ArrayLike

from localize.bundle import Grid
from localize.plots import OFF_MASK_GREY
from survey.publish import atomic_write_bytes
from survey.regular_files import read_regular

from .floorplan import MAX_PLAN_FILE_BYTES
from .radio_build import n_floors_text
from .validate import THRESHOLD_DOCS, ValidationResult, write_metrics

DPI = 110
#: Largest floor image drawn (pixels); a bigger one is left out (decoded as float32 RGBA it
#: would take 16 bytes a pixel: a 20000 x 20000 PNG of 438 KB asks for 6.4 GB).
MAX_FLOOR_IMAGE_PIXELS = 25_000_000
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels from a PNG's header, without decoding it.

    Raises
    ------
    ValueError
        Not a PNG (no signature or IHDR chunk first).
    """
    with open(path, "rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise ValueError(f"{path}: not a PNG file")
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
OURS = "indoormap default"


# ----------------------------------------------------------------------------------------------
# drawing helpers

def floor_image(floor_dir: str | Path | None
                ) -> tuple[np.ndarray | None, tuple[float, float, float, float] | None,
                           str | None]:
    """The floor folder's ``floor_image.png`` as a lightened grey image (rows, cols) in [0.55,
    1], its extent ``(0, width_m, 0, height_m)`` from ``floor_info.json`` and a line saying
    where it came from. Without an image: ``(None, None, None)``; with one that cannot be
    used (unreadable, not a PNG, over :data:`MAX_FLOOR_IMAGE_PIXELS`, no usable floor size):
    ``(None, None, "<path> left out (<why>)")``, so that a report says so."""
    path = Path(floor_dir) / "floor_image.png" if floor_dir is not None else None
    if path is None or not path.exists():
        return None, None, None
    try:
        info = json.loads(read_regular(path.parent / "floor_info.json",
                                       MAX_PLAN_FILE_BYTES))["map_info"]
        width_m, height_m = float(info["width"]), float(info["height"])
        if not (math.isfinite(width_m) and math.isfinite(height_m)
                and width_m > 0 and height_m > 0):
            raise ValueError("floor size not positive and finite")
        cols, rows = png_size(path)
        if cols * rows > MAX_FLOOR_IMAGE_PIXELS:  # decoded, it would take cols*rows*16 B
            raise ValueError(f"{cols} x {rows} pixels, over {MAX_FLOOR_IMAGE_PIXELS:,}")
        img = imread(path)
    except (OSError, ValueError, KeyError, TypeError) as err:
        return None, None, f"{path} left out ({err})"
    if img.ndim == 3:
        gray = img[..., :3] @ np.array([0.299, 0.587, 0.114])
        if img.shape[2] == 4:
            gray = np.where(img[..., 3] > 0, gray, 1.0)
        img = gray
    return 0.55 + 0.45 * img, (0.0, width_m, 0.0, height_m), str(path)


class FloorCanvas:
    """Draws the floor (image and reachable mask) under rasters and points."""

    def __init__(self, result: ValidationResult) -> None:
        b = result.bundle
        self.grid = b.grid
        self.mask = np.asarray(b.mask, dtype=bool)
        g = self.grid
        self.extent = (g.x0_m, g.x1_m, g.y0_m, g.y1_m)
        self.image, self.image_extent, self.image_source = floor_image(result.floor_dir)

    @property
    def aspect(self) -> float:
        x0, x1, y0, y1 = self.extent
        return (x1 - x0) / max(y1 - y0, 1e-9)

    def base(self, ax: Axes) -> None:
        if self.image is not None:
            ax.imshow(self.image, extent=self.image_extent, cmap="gray", vmin=0, vmax=1,
                      interpolation="bilinear", zorder=0)
        shade = np.where(self.mask, np.nan, 1.0)
        ax.imshow(shade, origin="lower", extent=self.extent, cmap=ListedColormap([OFF_MASK_GREY]),
                  alpha=0.55 if self.image is not None else 0.8, interpolation="nearest",
                  zorder=1)
        ax.set_xlim(self.extent[0], self.extent[1])
        ax.set_ylim(self.extent[2], self.extent[3])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        ax.locator_params(nbins=6)
        ax.set_xlabel("x (m, east)", fontsize=7)
        ax.set_ylabel("y (m, north)", fontsize=7)

    def raster(self, ax: Axes, values: ArrayLike, grid: Grid | None = None, *,
               cmap: str | Colormap = "viridis", vmin: float | None = None,
               vmax: float | None = None, norm: Normalize | None = None, label: str = "",
               alpha: float = 0.9, cax: Axes | None = None) -> AxesImage:
        g = grid or self.grid
        ext = (g.x0_m, g.x1_m, g.y0_m, g.y1_m)
        values = np.ma.masked_invalid(np.asarray(values, dtype=float))
        im = ax.imshow(values, origin="lower", extent=ext, cmap=cmap,
                       vmin=None if norm else vmin, vmax=None if norm else vmax, norm=norm,
                       interpolation="nearest", alpha=alpha, zorder=2)
        cax = cax if cax is not None else getattr(ax, "_cax", None)
        extend = _clipped(values, im.norm)  # an arrow where cells lie beyond the scale
        cb = ax.figure.colorbar(im, cax=cax, extend=extend) if cax is not None else \
            ax.figure.colorbar(im, ax=ax, fraction=0.035, pad=0.02, extend=extend)
        cb.ax.tick_params(labelsize=7)
        if label:
            cb.set_label(label, fontsize=7)
        return im


def _clipped(values: np.ma.MaskedArray, norm: Normalize) -> str:
    """The colour bar's ``extend`` for values a scale clips: ``"max"`` when some lie above
    its top, ``"min"`` below its bottom, ``"both"``, or ``"neither"``."""
    if values.count() == 0 or norm.vmin is None or norm.vmax is None:
        return "neither"
    under, over = values.min() < norm.vmin, values.max() > norm.vmax
    return {(True, True): "both", (False, True): "max", (True, False): "min"}.get(
        (bool(under), bool(over)), "neither")


# fixed layout (inches): matplotlib's tight/constrained layout dominates the drawing time
_LEFT, _CB_GAP, _CB_W, _CB_LABELS, _TITLE, _BOTTOM = 0.6, 0.08, 0.13, 0.85, 0.55, 0.5


#: Map panels per row: the report's page is 1250 px wide, and a figure of three 6-inch panels
#: at :data:`DPI` was shown at 60 % of its size, its 7-point labels unreadable.
MAX_COLUMNS = 2


def _panels(canvas: FloorCanvas, n: int, panel_w: float = 4.8):
    """A figure of ``n`` map panels, each with a colour-bar axes (``ax._cax``), in rows of
    :data:`MAX_COLUMNS`."""
    ncols = max(1, min(MAX_COLUMNS, n))
    nrows = math.ceil(n / ncols)
    map_w = panel_w
    map_h = map_w / canvas.aspect
    cell_w = _LEFT + map_w + _CB_GAP + _CB_W + _CB_LABELS
    cell_h = _TITLE + map_h + _BOTTOM
    fw, fh = cell_w * ncols, cell_h * nrows
    fig = Figure(figsize=(fw, fh))
    axes = []
    for k in range(n):
        r, c = divmod(k, ncols)
        x0 = c * cell_w + _LEFT
        y0 = fh - (r + 1) * cell_h + _BOTTOM
        ax = fig.add_axes((x0 / fw, y0 / fh, map_w / fw, map_h / fh))
        ax._cax = fig.add_axes(((x0 + map_w + _CB_GAP) / fw, y0 / fh, _CB_W / fw, map_h / fh))
        axes.append(ax)
    return fig, axes


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _short(tid: str) -> str:
    return str(tid)[:8]


def _around_median(values: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Angles (deg) unwrapped around their circular median, and a symmetric half-range."""
    v = np.asarray(values, dtype=float)
    fin = v[np.isfinite(v)]
    if not fin.size:
        return v, 0.0, 1.0
    med = math.degrees(math.atan2(np.mean(np.sin(np.radians(fin))),
                                  np.mean(np.cos(np.radians(fin)))))
    dev = (v - med + 180.0) % 360.0 - 180.0
    half = float(max(5.0, np.nanpercentile(np.abs(dev), 98)))
    return med + dev, med, half


# ----------------------------------------------------------------------------------------------
# figures

def fig_overview(result: ValidationResult, canvas: FloorCanvas, numbers: dict) -> bytes:
    """Where to walk again: every located problem on one map, numbered as in the list."""
    a = result.arrays
    map_w = 9.0
    map_h = map_w / canvas.aspect
    fw, fh = map_w + 0.9, map_h + 0.5 + 1.0
    fig = Figure(figsize=(fw, fh))
    ax = fig.add_axes((0.65 / fw, 0.95 / fh, map_w / fw, map_h / fh))
    canvas.base(ax)
    handles = []
    lab = a.get("unsupported_labels")
    fails = [f for f in result.findings if f.severity == "fail"]
    if lab is not None:
        unsup_fail = {int(round(f.where["x_m"] * 1000)) for f in fails
                      if f.check == "unsupported_region" and f.where}
        sel = np.zeros(lab.shape, dtype=bool)
        regions = result.metrics.get("coverage", {}).get("unsupported_regions", []) or []
        for reg in regions:
            if int(round(reg["x_m"] * 1000)) in unsup_fail:
                sel |= lab == reg["label"]
        small = (lab > 0) & ~sel
        ax.imshow(np.where(small, 1.0, np.nan), origin="lower", extent=canvas.extent,
                  cmap=ListedColormap(["#f4a582"]), alpha=0.6, interpolation="nearest",
                  zorder=2)
        ax.imshow(np.where(sel, 1.0, np.nan), origin="lower", extent=canvas.extent,
                  cmap=ListedColormap(["#d7191c"]), alpha=0.6, interpolation="nearest",
                  zorder=2)
        handles.append(Patch(color="#d7191c", alpha=0.6, label="unsupported area (finding)"))
        handles.append(Patch(color="#f4a582", alpha=0.6, label="unsupported, below threshold"))
    tracks = a.get("tracks", {})
    bad_walks = {f.walk for f in fails if f.check in ("walk_offset", "not_calibrated",
                                                      "bad_lines") and f.walk}
    for tid, (x, y) in tracks.items():
        ax.plot(x, y, "-", color="#2c7bb6", lw=0.6, alpha=0.55, zorder=3)
    if tracks:
        handles.append(Line2D([], [], color="#2c7bb6", lw=1, label="survey walks"))
    for tid in sorted(bad_walks):
        if tid in tracks:
            x, y = tracks[tid]
            ax.plot(x, y, "-", color="#c51b7d", lw=2.2, alpha=0.9, zorder=5)
    if bad_walks & set(tracks):
        handles.append(Line2D([], [], color="#c51b7d", lw=2.2, label="walk that failed a check"))
    fail_legs = {(f.walk, leg) for f in fails if f.check == "leg_flags" and f.where
                 for leg in f.where.get("legs", [])}
    drawn = False
    for tid, leg, _, x, y in a.get("flagged_segments", []):
        if (tid, leg) in fail_legs and len(x):
            ax.plot(x, y, "-", color="#fdae61", lw=3.5, alpha=0.95, zorder=6,
                    solid_capstyle="round")
            drawn = True
    if drawn:
        handles.append(Line2D([], [], color="#fdae61", lw=3.5, label="flagged leg (finding)"))
    wp = a.get("waypoints")
    if wp is not None:
        wx, wy, out = wp
        ax.plot(wx[~out], wy[~out], ".", color="#1a1a1a", ms=2.5, zorder=4)
        handles.append(Line2D([], [], color="#1a1a1a", marker=".", ls="", label="waypoints"))
        if out.any():
            ax.plot(wx[out], wy[out], "x", color="#d7191c", ms=9, mew=2.5, zorder=7)
            handles.append(Line2D([], [], color="#d7191c", marker="x", ls="", mew=2,
                                  label="waypoint outside reachable area"))
    for f in fails:
        if f.check == "disagreement" and f.where:
            for reg in f.where.get("regions", [])[:3]:
                x0, y0, x1, y1 = reg["bbox_m"]
                ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--",
                                       ec="#7b3294", lw=1.5, zorder=6))
    # numbers of the findings at their places
    for f_id, f in numbers.items():
        pos = _finding_xy(f, tracks)
        if pos is None:
            continue
        ax.annotate(str(f_id), pos, fontsize=8, fontweight="bold", color="white", zorder=9,
                    ha="center", va="center",
                    bbox={"boxstyle": "circle,pad=0.25", "fc": "#d7191c", "ec": "white",
                          "lw": 0.8})
    verdict = result.verdict.upper()
    ax.set_title(f"{result.metrics['bundle']['floor_name']}: {verdict} - "
                 f"{len(fails)} problem(s); numbers refer to the list", fontsize=10,
                 color="#b2182b" if verdict == "FAIL" else "#1a9641")
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncol=3,
               fontsize=7.5, frameon=False)
    return _png(fig)


def _finding_xy(f, tracks) -> tuple[float, float] | None:
    if f.where and "x_m" in f.where and f.where["x_m"] is not None:
        return float(f.where["x_m"]), float(f.where["y_m"])
    if f.where and f.where.get("regions"):
        r = f.where["regions"][0]
        return float(r["x_m"]), float(r["y_m"])
    if f.walk and f.walk in tracks:
        x, y = tracks[f.walk]
        if len(x):
            i = len(x) // 2
            return float(x[i]), float(y[i])
    return None


def fig_coverage(result: ValidationResult, canvas: FloorCanvas) -> bytes | None:
    a = result.arrays
    if "walking_distance_m" not in a:
        return None
    cov = result.metrics["coverage"]
    fig, (ax1, ax2) = _panels(canvas, 2)
    canvas.base(ax1)
    d = np.where(np.isinf(a["walking_distance_m"]), 99.0, a["walking_distance_m"])
    lim = cov["unsupported_distance_m"]
    canvas.raster(ax1, d, cmap="magma_r", vmin=0, vmax=2 * lim, label="walking distance (m)")
    ax1.contour(np.where(canvas.mask, d, np.nan), levels=[lim], origin="lower",
                extent=canvas.extent, colors=["#00a2ff"], linewidths=1.2, zorder=4)
    e = cov["euclidean"]
    ax1.set_title(f"walking distance to the nearest sample (blue: {lim:g} m)\n"
                  f"within 1/2/5 m (straight): {100 * e.get('within_1m', 0):.0f} / "
                  f"{100 * e.get('within_2m', 0):.0f} / {100 * e.get('within_5m', 0):.0f} %",
                  fontsize=8.5)
    canvas.base(ax2)
    cnt = np.where(canvas.mask, a["walks_per_cell"], np.nan).astype(float)
    bounds = [-0.5, 0.5, 1.5, 2.5, 3.5, 5.5, 1e9]
    cmap = ListedColormap(["#d7191c", "#fdae61", "#ffffbf", "#a6d96a", "#1a9641", "#006837"])
    im = canvas.raster(ax2, cnt, cmap=cmap, norm=BoundaryNorm(bounds, cmap.N),
                       label="walks within 1 m")
    im.colorbar.set_ticks([0, 1, 2, 3, 4.5, 7])
    im.colorbar.set_ticklabels(["0", "1", "2", "3", "4-5", "6+"])
    w = cov.get("walks_per_cell", {})
    ax2.set_title(f"walks per cell (within {w.get('radius_m', 1):g} m)\n"
                  f"{100 * w.get('share_2_plus', 0):.0f} % of the reachable area has 2+ walks",
                  fontsize=8.5)
    return _png(fig)


def fig_layers(result: ValidationResult, canvas: FloorCanvas, std: bool = False) -> bytes:
    b = result.bundle
    names = list(b.manifest["layers"])
    fig, axes = _panels(canvas, len(names), panel_w=4.6)
    for ax, name in zip(axes, names):
        meta = b.manifest["layers"][name]
        canvas.base(ax)
        v = np.asarray(b.std[name] if std else b.layers[name], dtype=float)
        unit = meta["unit"] if not (std and meta.get("kind") == "angle") else "deg"
        if std:
            fin = v[np.isfinite(v)]
            vmax = float(np.percentile(fin, 98)) if fin.size else 1.0
            canvas.raster(ax, v, cmap="cividis", vmin=0, vmax=vmax, label=unit)
            ax.set_title(f"{name}: uncertainty ({unit})", fontsize=8.5)
        elif meta.get("kind") == "angle":
            vv, med, half = _around_median(v)
            canvas.raster(ax, vv, cmap="coolwarm", vmin=med - half, vmax=med + half,
                          label=f"{unit} (around the median {med:.0f})")
            ax.set_title(f"{name} ({unit})", fontsize=8.5)
        else:
            fin = v[np.isfinite(v)]
            lo, hi = (np.percentile(fin, [1, 99]) if fin.size else (0, 1))
            canvas.raster(ax, v, cmap="viridis", vmin=lo, vmax=hi, label=unit)
            ax.set_title(f"{name} ({unit})", fontsize=8.5)
    return _png(fig)


def fig_consistency(result: ValidationResult, canvas: FloorCanvas) -> bytes | None:
    a = result.arrays
    con = result.metrics.get("consistency")
    if not con or "disagreement_strength" not in a:
        return None
    th = result.thresholds
    thr = th.get("disagreement_ut") or 3.0
    # the map above, the two bar charts below it (side by side the three were 17 inches wide)
    bars_w, bars_h, label_w, gap = 3.3, 3.6, 1.0, 1.6
    fw = label_w + bars_w + gap + bars_w + 0.3
    map_w = min(5.6, fw - _LEFT - _CB_GAP - _CB_W - _CB_LABELS)
    map_h = map_w / canvas.aspect
    bars_row = _TITLE + bars_h + _BOTTOM
    fh = _TITLE + map_h + _BOTTOM + bars_row
    fig = Figure(figsize=(fw, fh))
    y_map = (bars_row + _BOTTOM) / fh
    ax = fig.add_axes((_LEFT / fw, y_map, map_w / fw, map_h / fh))
    ax._cax = fig.add_axes(((_LEFT + map_w + _CB_GAP) / fw, y_map, _CB_W / fw, map_h / fh))
    canvas.base(ax)
    canvas.raster(ax, a["disagreement_strength"], grid=result.report_grid, cmap="YlOrRd",
                  vmin=0, vmax=2 * thr, label="SD between walks (uT)")
    y0, bar_h = _BOTTOM / fh, bars_h / fh
    x_bars = label_w
    d = con["disagreement_strength"]
    ax.set_title(f"where overlapping walks disagree (strength SD)\n"
                 f"{100 * (d['share_above'] or 0):.0f} % of {d['multi_walk_cells']} "
                 f"shared cells above {thr:g} uT", fontsize=8.5)
    ax2 = fig.add_axes((x_bars / fw, y0, bars_w / fw, bar_h))
    offs = [(w, r) for w, r in con["walk_offsets_ut"].items()
            if r.get("offset_ut") is not None]
    offs.sort(key=lambda wr: -wr[1]["offset_ut"])
    offs = offs[:25][::-1]
    t = th.get("walk_offset_max_ut")
    if offs:
        yy = np.arange(len(offs))
        ax2.barh(yy - 0.2, [r["strength"] for _, r in offs], height=0.4, color="#4393c3",
                 label="strength")
        ax2.barh(yy + 0.2, [r["vertical"] for _, r in offs], height=0.4, color="#f4a582",
                 label="vertical")
        ax2.set_yticks(yy, [_short(w) for w, _ in offs], fontsize=6.5)
        if t is not None:
            for s in (-t, t):
                ax2.axvline(s, color="#d7191c", ls="--", lw=1)
        ax2.legend(fontsize=7, loc="lower right")
    else:
        ax2.text(0.5, 0.5, "no walk shares enough cells\nwith other walks", ha="center",
                 va="center", transform=ax2.transAxes, fontsize=8)
    ax2.set_xlabel("median offset from the other walks (uT)", fontsize=7.5)
    ax2.set_title("walk offsets after levelling\n(largest 25; red dashes = threshold)",
                  fontsize=8.5)
    ax2.tick_params(labelsize=7)
    ax3 = fig.add_axes(((x_bars + bars_w + gap) / fw, y0, bars_w / fw, bar_h))
    lev = con.get("levelling", [])
    if lev:
        lev = sorted(lev, key=lambda r: r["norm_ut"])[-25:]
        yy = np.arange(len(lev))
        for k, (comp, col) in enumerate((("r_x_ut", "#1b9e77"), ("r_y_ut", "#d95f02"),
                                         ("r_z_ut", "#7570b3"))):
            ax3.barh(yy + (k - 1) * 0.27, [r[comp] for r in lev], height=0.27, color=col,
                     label=comp[2])
        ax3.set_yticks(yy, [r["session"][:22] for r in lev], fontsize=6)
        ax3.legend(fontsize=7, loc="lower right", title="device axis", title_fontsize=7)
        tl = th.get("levelling_residual_max_ut")
        if tl is not None:
            for s in (-tl, tl):
                ax3.axvline(s, color="#d7191c", ls="--", lw=1)
    ax3.set_xlabel("residual removed (uT, device axes)", fontsize=7.5)
    ax3.set_title("levelling corrections applied\n(per calibration session)", fontsize=8.5)
    ax3.tick_params(labelsize=7)
    return _png(fig)


def fig_heldout_maps(result: ValidationResult, canvas: FloorCanvas) -> bytes | None:
    a = result.arrays
    names = [n for n in ("strength", "vertical", "heading_offset")
             if f"heldout_rms_{n}" in a]
    radio = a.get("radio_error_map_m")
    if not names and radio is None:
        return None
    n = len(names) + (radio is not None)
    fig, axes = _panels(canvas, n, panel_w=5.0)
    if radio is not None:
        canvas.base(axes[-1])
        canvas.raster(axes[-1], radio, grid=result.report_grid, cmap="YlOrRd", vmin=0,
                      vmax=10, label="median error (m)")
        axes[-1].set_title(f"held-out {_kind_name(result.metrics)} error\n(median per "
                           f"{result.report_grid.cell_m:g} m cell)", fontsize=8.5)
    th = result.thresholds
    for ax, name in zip(axes, names):
        canvas.base(ax)
        unit = "deg" if name == "heading_offset" else "uT"
        vmax = 2 * (th.get("heading_offset_shape_rmse_max_deg") or 20) if unit == "deg" else \
            2 * (th.get("heldout_strength_shape_rmse_max_ut") or 4)
        canvas.raster(ax, a[f"heldout_rms_{name}"], grid=result.report_grid, cmap="YlOrRd",
                      vmin=0, vmax=vmax, label=f"RMS shape error ({unit})")
        ax.set_title(f"held-out error: {name}\n(RMS per {result.report_grid.cell_m:g} m cell, "
                     "walk offsets removed)", fontsize=8.5)
    return _png(fig)


def fig_cdfs(result: ValidationResult) -> bytes | None:
    res = result.arrays.get("heldout_abs_residuals", {})
    radio = result.arrays.get("radio_errors_m")
    if not res and radio is None:
        return None
    layers = []
    for _, layer in res:
        if layer not in layers:
            layers.append(layer)
    n = len(layers) + (radio is not None)
    ncols = min(n, MAX_COLUMNS)
    nrows = math.ceil(n / ncols)
    fw, fh = 4.6 * ncols, 3.6 * nrows
    fig = Figure(figsize=(fw, fh))
    grid = fig.subplots(nrows, ncols, squeeze=False)
    fig.subplots_adjust(left=0.6 / fw, right=1 - 0.15 / fw, bottom=0.55 / fh,
                        top=1 - 0.36 / fh, wspace=0.25, hspace=0.45)
    for ax in grid.flat[n:]:  # an odd count's empty last cell
        ax.set_visible(False)
    axes = list(grid.flat[:n])
    colors = {"constant map (floor mean)": "#999999", OURS: "#d7191c"}
    for ax, layer in zip(axes, layers):
        unit = "deg" if layer == "heading_offset" else "uT"
        for (pipe, la), v in res.items():
            if la != layer or not len(v):
                continue
            vs = np.sort(v)
            label = "baseline (linear, no levelling)" if "baseline" in pipe else pipe
            ax.plot(vs, np.arange(1, len(vs) + 1) / len(vs), lw=1.6,
                    color=colors.get(pipe, "#2c7bb6"),
                    label=f"{label}: median {np.median(vs):.1f}, p90 {np.percentile(vs, 90):.1f}")
        tails = [np.percentile(v, 99) for (_, la), v in res.items() if la == layer and len(v)]
        ax.set_xlim(0, max(tails) if tails else None)
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.set_xlabel(f"|held-out error| ({unit}; axis to the largest 99th percentile)",
                      fontsize=8)
        ax.set_ylabel("share of samples", fontsize=8)
        ax.set_title(f"{layer}: error CDF", fontsize=9)
        ax.legend(fontsize=6.5, loc="lower right")
        ax.tick_params(labelsize=7)
    if radio is not None:
        ax = axes[-1]
        a = result.arrays
        kinds = [k for k in ("wifi", "ble") if f"{k}_errors_m" in a] or [None]
        for kind in kinds:  # every kind measured, not only the one the maps above show
            name = "" if kind is None else f"{_KIND_NAMES[kind]} "
            pre = "radio" if kind is None else kind
            curves = ((f"{name}scan by scan", a.get(f"{pre}_errors_m"), "-"),
                      (f"{name}whole walk", a.get(f"{pre}_walk_errors_m"), "--"))
            color = "#2c7bb6" if kind != "ble" else "#1a9641"
            for label, errors, style in curves:
                if errors is None or not len(errors):
                    continue
                vs = np.sort(np.asarray(errors, dtype=float))
                ax.plot(vs, np.arange(1, len(vs) + 1) / len(vs), color=color, ls=style,
                        label=f"{label}: median {np.median(vs):.1f} m, p80 "
                              f"{np.percentile(vs, 80):.1f} m")
        ax.set_xlabel("radio positioning error (m)", fontsize=8)
        ax.set_title(" and ".join(_KIND_NAMES.get(k, "radio") for k in kinds)
                     + " held-out error CDF", fontsize=9)
        ax.legend(fontsize=6.5, loc="lower right")
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    return _png(fig)


_KIND_NAMES = {"wifi": "Wi-Fi", "ble": "BLE"}


def _kind_name(metrics: dict) -> str:
    """The name of the radio kind whose errors the report's maps show (``Wi-Fi``)."""
    return _KIND_NAMES.get((metrics.get("radio") or {}).get("primary_kind"), "radio")


def fig_predicted(result: ValidationResult, canvas: FloorCanvas) -> bytes | None:
    a = result.arrays
    if "magnetic_resolution_m" not in a:
        return None
    pr = result.metrics["predicted"]
    lim = pr["magnetic_resolution_m"]["limit_m"]
    n = 2 + ("radio_bound_m" in a)
    fig, axes = _panels(canvas, n, panel_w=5.4)
    canvas.base(axes[0])
    res = a["magnetic_resolution_m"]
    fin = res[np.isfinite(res)]
    vmax = float(min(max(2 * lim, np.percentile(fin, 75) if fin.size else 0), 20.0))
    canvas.raster(axes[0], res, cmap="RdYlGn_r", norm=TwoSlopeNorm(lim, 0.0, vmax),
                  label="m per noise level")
    fs = pr["magnetic_resolution_m"]["flat_share"]
    axes[0].set_title(f"magnetic resolution (m per noise level)\n{100 * (fs or 0):.0f} % of "
                      f"the mapped area is flat (> {lim:g} m, red)", fontsize=8.5)
    canvas.base(axes[1])
    g = a.get("gradient_strength")
    if g is not None:
        fin = g[np.isfinite(g)]
        canvas.raster(axes[1], g, cmap="viridis", vmin=0,
                      vmax=float(np.percentile(fin, 98)) if fin.size else 1,
                      label="uT / m")
    noise = pr.get("noise_ut", {})
    axes[1].set_title("strength gradient\n(noise levels used: "
                      + ", ".join(f"{k} {v:.1f}" for k, v in noise.items()) + " uT)",
                      fontsize=8.5)
    if "radio_bound_m" in a:
        canvas.base(axes[2])
        canvas.raster(axes[2], a["radio_bound_m"], cmap="RdYlGn_r", vmin=0, vmax=10,
                      label="m")
        axes[2].set_title("radio Cramer-Rao bound", fontsize=8.5)
    return _png(fig)


# ----------------------------------------------------------------------------------------------
# HTML

CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:0;color:#222;
background:#fafafa}
main{max-width:1250px;margin:0 auto;padding:10px 24px 40px}
h1{font-size:22px;margin:14px 0 4px} h2{font-size:18px;border-bottom:2px solid #ddd;
padding-bottom:3px;margin-top:34px} h3{font-size:15px;margin:18px 0 6px}
.verdict{padding:14px 18px;border-radius:6px;color:#fff;font-size:19px;font-weight:600}
.pass{background:#1a9641} .fail{background:#b2182b}
.meta{color:#555;font-size:13px}
table{border-collapse:collapse;font-size:12.5px;margin:6px 0 10px;background:#fff}
th,td{border:1px solid #ddd;padding:3px 7px;text-align:left;vertical-align:top}
th{background:#f0f0f0} td.num{text-align:right;font-variant-numeric:tabular-nums}
.st-fail{color:#b2182b;font-weight:700} .st-pass{color:#1a9641;font-weight:600}
.st-off,.st-notrun{color:#888}
.sev-fail{color:#b2182b;font-weight:700} .sev-warn{color:#b35806;font-weight:600}
.sev-info{color:#555}
ol.problems li{margin:4px 0;font-size:14px} ul.summary li{margin:5px 0;font-size:15px}
img{max-width:100%;height:auto;border:1px solid #ddd;background:#fff;margin:4px 0}
.note{color:#555;font-size:13px;max-width:1000px}
details{margin:6px 0} summary{cursor:pointer;color:#2166ac}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _num(v, fmt="{:.2f}") -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "-" if not math.isfinite(v) else fmt.format(v)
    return _e(v)


def _table(headers: list[str], rows: list[list], numeric: set[int] | None = None,
           limit: int | None = None) -> str:
    numeric = numeric or set()
    head = "".join(f"<th>{_e(h)}</th>" for h in headers)

    def tr(r: list) -> str:
        return "<tr>" + "".join(
            f"<td class='num'>{c}</td>" if i in numeric else f"<td>{c}</td>"
            for i, c in enumerate(r)) + "</tr>"

    body = "".join(tr(r) for r in (rows if limit is None else rows[:limit]))
    out = f"<table><tr>{head}</tr>{body}</table>"
    if limit is not None and len(rows) > limit:
        rest = "".join(tr(r) for r in rows[limit:])
        out += (f"<details><summary>{len(rows) - limit} more rows</summary><table><tr>{head}"
                f"</tr>{rest}</table></details>")
    return out


def _img(data: bytes | None, alt: str, name: str, figures: dict) -> str:
    if data is None:
        return ""
    figures[name] = data
    b64 = base64.b64encode(data).decode("ascii")
    return f"<img alt='{_e(alt)}' src='data:image/png;base64,{b64}'>"


def render_html(result: ValidationResult, figures: dict[str, bytes]) -> str:
    """The report page (figures are added to ``figures`` by name as they are drawn)."""
    m = result.metrics
    b = m["bundle"]
    canvas = FloorCanvas(result)
    fails = [f for f in result.findings if f.severity == "fail"]
    numbers = {i + 1: f for i, f in enumerate(fails)}
    v = result.verdict
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>Map validation: {_e(b['site_id'])}/{_e(b['floor_name'])}</title>"
             f"<style>{CSS}</style></head><body><main>",
             f"<h1>Map validation: floor {_e(b['floor_name'])}</h1>",
             f"<p class='meta'>site {_e(b['site_id'])} &middot; bundle {_e(b['bundle_id'])} "
             f"&middot; built {_e(b.get('build_time'))} from {b['n_walks']} walks &middot; "
             f"grid {b['grid']['width']} x {b['grid']['height']} cells of "
             f"{b['grid']['cell_m']:g} m"
             + (f" &middot; floor image {_e(canvas.image_source)}" if canvas.image_source
                else "") + "</p>",
             f"<div id='verdict' class='verdict {v}'>"
             + _e(result.verdict_text())
             + (": every threshold checked holds" if v == "pass" else
                f": {len(fails)} problem(s) to fix before leaving the building")
             + "</div>"]
    # problems: a line per failed check, the map, then every problem numbered as on the map
    parts.append("<section id='problems'><h2>What to fix</h2>")
    if fails:
        by_check: dict[str, list] = {}
        for i, f in numbers.items():
            by_check.setdefault(f.check, []).append((i, f))
        titles = {c["check"]: c["title"] for c in m.get("checks", [])}
        parts.append("<ul class='summary'>" + "".join(
            f"<li><b>{_e(titles.get(check, check))}</b>: {len(items)} finding(s), "
            f"e.g. #{items[0][0]} {_e(items[0][1].message)}</li>"
            for check, items in by_check.items()) + "</ul>")
    else:
        parts.append("<p>Nothing failed.</p>")
    parts.append(_img(fig_overview(result, canvas, numbers), "overview of problems",
                      "overview", figures))
    if fails:
        items = "".join(f"<li><b>[{_e(f.section)}]</b> {_e(f.message)}</li>" for f in fails)
        parts.append(f"<h3>All problems (numbers as on the map)</h3><ol class='problems'>{items}"
                     "</ol>")
    others = [f for f in result.findings if f.severity != "fail"]
    if others:
        parts.append("<details><summary>warnings and notes ("
                     f"{len(others)})</summary><ul>" + "".join(
                         f"<li><span class='sev-{f.severity}'>{f.severity}</span> "
                         f"[{_e(f.section)}] {_e(f.message)}</li>" for f in others)
                     + "</ul></details>")
    parts.append("</section>")
    # checks
    rows = []
    for c in m.get("checks", []):
        val = c["value"]
        vtxt = _num(val, "{:.3g}") if not isinstance(val, float) or abs(val) >= 1e-3 \
            else _num(val, "{:.2g}")
        st = c["status"]
        t_txt = "off" if c["threshold"] is None else f"{_e(c['op'])} {_e(c['threshold'])}"
        rows.append([_e(c["title"]), t_txt, vtxt,
                     f"<span class='st-{st.replace(' ', '')}'>{_e(st)}</span>",
                     _e(THRESHOLD_DOCS.get(c["threshold_key"], ""))])
    parts.append("<section id='checks'><h2>Checks</h2>"
                 + _table(["check", "threshold", "value", "result", "meaning"], rows, {2})
                 + "<p class='note'>Thresholds: defaults of <code>mapping.validate."
                   "DEFAULT_THRESHOLDS</code>, overridable with <code>--thresholds FILE</code>"
                   " (JSON); <i>off</i> = threshold null.</p></section>")
    parts.append(_section_coverage(result, canvas, figures))
    parts.append(_section_consistency(result, canvas, figures))
    parts.append(_section_heldout(result, canvas, figures))
    parts.append(_section_predicted(result, canvas, figures))
    parts.append(_section_calibration(result))
    parts.append(_section_data_quality(result))
    parts.append(_section_radio(result))
    parts.append("<section id='layers'><h2>Map layers</h2>"
                 + _img(fig_layers(result, canvas), "map layers", "layers", figures)
                 + "<h3>Their uncertainty</h3>"
                 + _img(fig_layers(result, canvas, std=True), "layer uncertainty",
                        "layers_std", figures) + "</section>")
    tm = m.get("timings_s", {})
    parts.append("<section id='parameters'><h2>Parameters</h2><p class='note'>"
                 + _e(json.dumps(m.get("params", {}), sort_keys=True)) + "</p><p class='note'>"
                 + "timings (s): " + _e(", ".join(f"{k} {v}" for k, v in tm.items()))
                 + "</p></section>")
    parts.append("</main></body></html>")
    return "\n".join(parts)


def _section_coverage(result, canvas, figures) -> str:
    cov = result.metrics.get("coverage", {})
    e = cov.get("euclidean", {})
    out = ["<section id='coverage'><h2>1. Coverage</h2>",
           f"<p>Reachable area {cov.get('reachable_area_m2', 0):.0f} m2; mapped (layer defined)"
           f" {100 * cov.get('mapped_share', 0):.0f} %. Within 1 / 2 / 5 m of a sample "
           f"(straight line): {100 * e.get('within_1m', 0):.0f} / "
           f"{100 * e.get('within_2m', 0):.0f} / {100 * e.get('within_5m', 0):.0f} %"]
    w = cov.get("walking")
    if w:
        out.append(f"; by walking distance: {100 * w['within_1m']:.0f} / "
                   f"{100 * w['within_2m']:.0f} / {100 * w['within_5m']:.0f} %.")
    out.append("</p>")
    out.append(_img(fig_coverage(result, canvas), "coverage maps", "coverage", figures))
    regs = cov.get("unsupported_regions") or []
    if regs:
        out.append(f"<h3>Unsupported regions (no sample within "
                   f"{cov['unsupported_distance_m']:g} m walking distance)</h3>")
        out.append(_table(["area (m2)", "centre (m)", "bbox (m)", "connected to survey"],
                          [[_num(r["area_m2"], "{:.1f}"), f"{r['x_m']:.1f}, {r['y_m']:.1f}",
                            ", ".join(f"{v:.0f}" for v in r["bbox_m"]),
                            "no" if r.get("isolated") else "yes"] for r in regs], {0},
                          limit=10))
    zones = cov.get("zones")
    if zones:
        out.append(f"<h3>Walks per zone ({result.metrics['params']['zone_m']:g} m squares, "
                   "fewest first)</h3>")
        out.append(f"<p class='note'>{cov.get('zones_no_walk', 0)} zones without a walk, "
                   f"{cov.get('zones_single_walk', 0)} with a single walk (nothing to "
                   "cross-check them against).</p>")
        out.append(_table(["zone centre (m)", "reachable (m2)", "within 2 m", "walks"],
                          [[f"{z['x_m']:.1f}, {z['y_m']:.1f}", _num(z["reachable_m2"], "{:.0f}"),
                            f"{100 * z['within_2m_share']:.0f} %", z["walks"]] for z in zones],
                          {1, 2, 3}, limit=10))
    out.append("</section>")
    return "".join(out)


def _needs_store(section_id: str, title: str) -> str:
    """A section that cannot be written without the survey store."""
    return (f"<section id='{section_id}'><h2>{title}</h2><p>Needs the survey store "
            "(<code>--store</code>).</p></section>")


def _section_consistency(result, canvas, figures) -> str:
    con = result.metrics.get("consistency")
    if not con:
        return _needs_store("consistency", "2. Consistency (after levelling)")
    out = ["<section id='consistency'><h2>2. Consistency (after levelling)</h2>"]
    out.append("<p class='note'>Each walk's field, levelled with the bundle's per-session "
               f"residuals, averaged per {con['report_cell_m']:g} m cell. A walk's offset is "
               "its median difference from the other walks in the cells they share; the "
               "disagreement map shows the spread between walks after those offsets.</p>")
    out.append(_img(fig_consistency(result, canvas), "consistency", "consistency", figures))
    rows = []
    for la in ("strength", "vertical", "horizontal"):
        d = con.get(f"disagreement_{la}")
        if d:
            rows.append([la, d["multi_walk_cells"], _num(d["median_sd_ut"]),
                         _num(d["p90_sd_ut"]), _num(None if d["share_above"] is None else
                                                    100 * d["share_above"], "{:.0f} %")])
    out.append(_table(["layer", "shared cells", "median SD (uT)", "p90 SD (uT)",
                       "cells above threshold"], rows, {1, 2, 3, 4}))
    lev = con.get("levelling", [])
    if lev:
        out.append("<h3>Levelling residuals per calibration session (device frame, removed)"
                   "</h3>")
        out.append(_table(["session", "r_x", "r_y", "r_z", "|r| (uT)", "pairs", "samples"],
                          [[_e(r["session"]), _num(r["r_x_ut"]), _num(r["r_y_ut"]),
                            _num(r["r_z_ut"]), _num(r["norm_ut"]), r["n_pairs"],
                            r["n_samples"]] for r in sorted(lev, key=lambda r: -r["norm_ut"])],
                          {1, 2, 3, 4, 5, 6}, limit=15))
    out.append("</section>")
    return "".join(out)


def _section_heldout(result, canvas, figures) -> str:
    ho = result.metrics.get("heldout")
    if not ho:
        return _needs_store("heldout", "3. Held-out accuracy (leave one walk out)")
    out = ["<section id='heldout'><h2>3. Held-out accuracy (leave one walk out)</h2>"]
    p = ho["params"]
    out.append(f"<p class='note'>{_e(ho['implementation'])} (the benchmark's implementation): "
               f"every walk predicted by the map of the others; levelling fitted in "
               f"{p['levelling_folds']} folds of walks; every {p['subsample']}th sample; kernel "
               f"bandwidth {p['raster']['bandwidth_m']:g} m. Pipelines are scored on the "
               f"samples they all predict. Shape = each walk's median residual removed; skill "
               f"= 1 - shape RMSE / constant map's; corr = map vs observed change along the "
               f"held-out track. {ho['seconds']:.0f} s.</p>")
    rows = [[_e(r["layer"]), _e(r["pipeline"]), _num(r.get("rmse")), _num(r.get("median_abs")),
             _num(r.get("shape_rmse")), _num(r.get("skill")), _num(r.get("corr_0.7m")),
             _num(r.get("corr_5m")), r.get("n_samples"), r.get("n_walks")]
            for r in ho["table"]]
    hd = ho.get("heading_offset", {})
    if hd.get("rmse") is not None:
        rows.append(["heading_offset (deg)", OURS, _num(hd["rmse"]), _num(hd["median_abs"]),
                     _num(hd["shape_rmse"]), "-", _num(hd.get("corr_0.7m")),
                     _num(hd.get("corr_5m")), hd.get("n_samples"), hd.get("n_walks")])
    out.append(_table(["layer", "pipeline", "RMSE", "median |e|", "shape RMSE", "skill",
                       "corr 0.7 m", "corr 5 m", "samples", "walks"], rows,
                      {2, 3, 4, 5, 6, 7, 8, 9}))
    out.append(_img(fig_cdfs(result), "error CDFs", "heldout_cdf", figures))
    out.append(_img(fig_heldout_maps(result, canvas), "held-out error maps", "heldout_maps",
                    figures))
    pw = ho.get("per_walk", {})
    if pw:
        con = result.metrics.get("consistency", {}).get("walk_offsets_ut", {})
        rows = []
        for w, r in sorted(pw.items(), key=lambda wr: -abs(wr[1].get("strength_median_ut", 0))):
            rows.append([_e(w), r.get("strength_n", 0), _num(r.get("strength_median_ut")),
                         _num(r.get("strength_shape_rmse_ut")), _num(r.get("vertical_median_ut")),
                         _num(r.get("vertical_shape_rmse_ut")),
                         _num((con.get(w) or {}).get("strength")),
                         _num((con.get(w) or {}).get("vertical"))])
        out.append("<h3>Per held-out walk</h3><p class='note'>Held-out medians include what "
                   "levelling could not fit without the walk (a walk alone in its calibration "
                   "session keeps its session's residual); the last two columns are the offsets"
                   " after the bundle's levelling (section 2), which the walk-offset check "
                   "uses.</p>")
        out.append(_table(["walk", "samples", "strength median", "strength shape RMSE",
                           "vertical median", "vertical shape RMSE",
                           "offset after levelling: strength", "vertical"], rows,
                          {1, 2, 3, 4, 5, 6, 7}, limit=15))
    out.append("</section>")
    return "".join(out)


def _section_predicted(result, canvas, figures) -> str:
    pr = result.metrics.get("predicted", {})
    out = ["<section id='predicted'><h2>4. Predicted localization quality</h2>",
           "<p class='note'>Magnetic resolution per cell = 1 / sqrt(sum over strength, "
           "horizontal, vertical of |gradient|^2 / noise^2): the distance over which the map "
           "changes by one noise level (a one-sample Cramer-Rao style bound along the best "
           f"direction). Noise: {_e(pr.get('noise_source', ''))}.</p>"]
    r = pr.get("magnetic_resolution_m")
    if r:
        out.append(f"<p>Median {_num(r['median'])} m, p90 {_num(r['p90'])} m; "
                   f"{100 * (r['flat_share'] or 0):.0f} % of {r['mapped_cells']} mapped cells "
                   f"coarser than {r['limit_m']:g} m.</p>")
    out.append(_img(fig_predicted(result, canvas), "predicted quality", "predicted", figures))
    regs = pr.get("flat_regions", [])
    if regs:
        out.append("<h3>Largest magnetically flat areas (the localizer will struggle)</h3>")
        out.append(_table(["area (m2)", "centre (m)", "bbox (m)"],
                          [[_num(g["area_m2"], "{:.0f}"), f"{g['x_m']:.1f}, {g['y_m']:.1f}",
                            ", ".join(f"{v:.0f}" for v in g["bbox_m"])] for g in regs], {0},
                          limit=8))
    radio = result.metrics.get("radio", {})
    if not radio.get("available"):
        out.append(f"<p class='note'>Radio bound: {_e(radio.get('reason', 'not computed'))}"
                   "</p>")
    out.append("</section>")
    return "".join(out)


def _section_calibration(result) -> str:
    cal = result.metrics.get("calibration", {})
    out = ["<section id='calibration'><h2>5. Calibration</h2>"]
    dec = cal.get("decisions", {})
    out.append("<p>Magnetometer calibration decisions: "
               + (", ".join(f"{_e(k)} {v}" for k, v in dec.items()) or "none") + ".</p>")
    walks = cal.get("walks", [])
    if walks:
        order = sorted(walks, key=lambda w: (w.get("calibration") != "not-calibrated",
                                             w.get("trace_id")))
        out.append(_table(["walk", "device", "session", "status", "calibration", "detail",
                           "step model k", "heading offset (deg)"],
                          [[_e(w["trace_id"]), _e(w.get("device_model", "")),
                            _e(w.get("session", "")), _e(w.get("status", "")),
                            _e(w.get("calibration")), _e(w.get("calibration_detail") or ""),
                            _num(w.get("step_k")), _num(w.get("heading_offset_median_deg"),
                                                        "{:.1f}")] for w in order],
                          {6, 7}, limit=12))
    rs = cal.get("rssi_devices", {})
    if rs.get("rows"):
        keys = list(rs["rows"][0])
        out.append(f"<h3>RSSI per device ({_e(rs['source'])})</h3>")
        out.append(_table(keys, [[_num(r[k]) for k in keys] for r in rs["rows"]]))
    else:
        out.append(f"<p class='note'>RSSI (k, b) per device: "
                   f"{_e(rs.get('note', 'not available'))}.</p>")
    out.append("</section>")
    return "".join(out)


def _section_data_quality(result) -> str:
    dq = result.metrics.get("data_quality")
    if not dq:
        return _needs_store("data-quality", "6. Data quality")
    out = ["<section id='data-quality'><h2>6. Data quality</h2>"]
    lt = dq["lines_total"]
    out.append(f"<p>{lt['n_lines']} lines in {len(dq['lines'])} traces: {lt['n_bad_lines']} "
               f"bad, {lt['n_skipped_lines']} skipped (undocumented record types), "
               f"{lt['n_dropped_rows']} rows dropped (duplicates). {dq['walks_ok']} walks "
               f"processed, {len(dq['walks_skipped'])} skipped; the bundle has "
               f"{dq['walks_in_bundle']} walks"
               + ("" if dq["store_matches_bundle"] else
                  " (<b>the store's walks differ from the bundle's</b>)")
               + (f"; {len(dq['walks_not_in_bundle'])} other walk(s) of the store, not in the "
                  "bundle, are left out of this report"
                  if dq.get("walks_not_in_bundle") else "") + ".</p>")
    bad = [d for d in dq["lines"] if d["n_bad_lines"]]
    if bad:
        out.append(_table(["walk", "lines", "bad", "reasons"],
                          [[_e(d["trace_id"]), d["n_lines"], d["n_bad_lines"],
                            _e(", ".join(f"{k} {v}" for k, v in d["bad"].items()))]
                           for d in sorted(bad, key=lambda d: -d["n_bad_lines"])], {1, 2},
                          limit=10))
    skipped_types: dict[str, int] = {}
    for d in dq["lines"]:
        for k, v in d["skipped"].items():
            skipped_types[k] = skipped_types.get(k, 0) + v
    if skipped_types:
        out.append("<p class='note'>Skipped record types: " + _e(", ".join(
            f"{k} {v}" for k, v in sorted(skipped_types.items(), key=lambda kv: -kv[1])))
            + ".</p>")
    if dq["walks_skipped"]:
        out.append("<h3>Walks not used</h3>" + _table(
            ["walk", "reason"], [[_e(s["trace_id"]), _e(s["reason"])]
                                 for s in dq["walks_skipped"]]))
    out.append(f"<h3>Flagged legs: {dq['legs_flagged']} of {dq['legs_total']}</h3>")
    if dq["flag_counts"]:
        out.append(_table(["flag", "legs"], [[_e(k), v] for k, v in dq["flag_counts"].items()],
                          {1}))
        rows = []
        for w in dq["flagged_legs"]:
            for leg in w["legs"]:
                rows.append([_e(w["trace_id"]), leg["leg"], _e(", ".join(leg["flags"])),
                             _num(leg["waypoint_residual_m"]), _num(leg["speed_mps"]),
                             _num(leg["scale"])])
        out.append(_table(["walk", "leg", "flags", "waypoint residual (m)", "speed (m/s)",
                           "scale"], rows, {1, 3, 4, 5}, limit=12))
    wo = dq["waypoints_outside"]
    out.append(f"<h3>Waypoints outside the reachable area: {len(wo)} of "
               f"{dq['waypoints_total']}</h3>")
    if wo:
        out.append(_table(["walk", "waypoint", "x (m)", "y (m)", "distance (m)"],
                          [[_e(w["trace_id"]), w["waypoint"], _num(w["x_m"], "{:.1f}"),
                            _num(w["y_m"], "{:.1f}"), _num(w["distance_m"], "{:.1f}")]
                           for w in wo], {1, 2, 3, 4}, limit=12))
    out.append("</section>")
    return "".join(out)


def _section_radio(result) -> str:
    radio = result.metrics.get("radio", {})
    out = ["<section id='radio'><h2>7. Radio (Wi-Fi / BLE)</h2>"]
    if not radio.get("available"):
        out.append(f"<p>{_e(radio.get('reason', 'radio: not available'))}</p></section>")
        return "".join(out)
    rows = []
    for kind, k in radio.get("kinds", {}).items():
        if not k.get("available"):
            rows.append([_e(kind), _e(k.get("reason", "")), "", "", "", "", "", ""])
            continue
        bound = k.get("bound_m") or {}
        rows.append([_e(kind), _num(k.get("reference_points"), "{:.0f}"),
                     _num(k.get("transmitters"), "{:.0f}"), _e(k.get("split", "no store")),
                     _num(k.get("median_error_m")), _num(k.get("p80_error_m")),
                     _num(k.get("walk_median_error_m")), _num(bound.get("median"))])
    out.append(_table(["kind", "reference points", "transmitters", "held-out split",
                       "median error (m)", "p80 error (m)", "whole-walk median (m)",
                       "median bound (m)"], rows))
    fm = radio.get("floor_model")
    if fm:
        def pct(v: float | None) -> str:
            return "n/a" if v is None else f"{100 * v:.2f} %"

        out.append(f"<p>Floor model ({_e(fm.get('kind', ''))}, site bundle): "
                   f"{n_floors_text(len(fm.get('floors', [])))}, cross-validated accuracy "
                   f"per scan {pct(fm.get('cv_scan_accuracy'))}, per walk "
                   f"{pct(fm.get('cv_walk_accuracy'))}</p>")
        ble = radio.get("ble_floor_model")
        if ble:
            out.append(f"<p>BLE floor model (site bundle; for walks without Wi-Fi that name no "
                       f"floor): {n_floors_text(len(ble.get('floors', [])))}, cross-validated "
                       f"accuracy per BLE window {pct(ble.get('cv_scan_accuracy'))}, per walk "
                       f"{pct(ble.get('cv_walk_accuracy'))}</p>")
    else:
        out.append(f"<p class='note'>{_e(radio.get('floor_note', 'no floor model'))}</p>")
    out.append("<p class='note'>Errors: fingerprints rebuilt without the held-out walks, "
               "against the processed scan positions (themselves about 1 m off the true path). "
               "Bound: Cramer-Rao style, from the gradients of the mean RSSI fields; real "
               "errors are larger (missed detections, kNN bias). The CDF is with the held-out "
               "figures; the bound map with the predicted quality.</p>")
    out.append("</section>")
    return "".join(out)


def write_report(result: ValidationResult, out_dir: str | Path) -> Path:
    """Write ``report.html``, ``metrics.json`` and ``figures/*.png`` into ``out_dir``; returns
    the report's path."""
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    figures: dict[str, bytes] = {}
    page = render_html(result, figures)
    for name, data in figures.items():
        atomic_write_bytes(out / "figures" / f"{name}.png", data, overwrite=True)
    write_metrics(result, out)
    atomic_write_bytes(out / "report.html", page.encode("utf-8"), overwrite=True)
    return out / "report.html"
