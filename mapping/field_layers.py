"""The magnetic layers of a floor from the processed store, read walk by walk.

:func:`mapping.build.build_floor` never holds the floor's samples at once. It reads them twice,
one walk at a time and only the columns it needs:

1. :func:`levelling_samples`: every n-th sample (``LevellingParams.subsample``; 50 Hz is far
   denser than the field varies), the input of the session levelling;
2. :func:`reduce_field`: each walk's samples are levelled, turned into the layer values and
   reduced to per-(walk, cell) means at once (:func:`mapping.interpolate.walk_cell_means`);
   only those means, a support mask and every n-th sample's strength (for the bandwidth
   cross-validation) are kept.

Memory is then bounded by the grid, the walks' cell counts and the subsamples, not by the
samples (a floor surveyed ten times over: see ``benchmarks/build_memory.py``). The rows are
taken in the same order as from one concatenated table, so the layers equal those of
:func:`mapping.interpolate.raster` on the whole floor's samples bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from localize.bundle import Grid
from survey.process_store import processed_part
from survey.store import SurveyStore

from .holdout import BANDWIDTH_SUBSAMPLE, layer_values
from .interpolate import RasterParams, angle_raster, cell_stats, raster_from_stats, \
    walk_cell_means
from .levelling import apply_session_residuals

__all__ = ["FIELD_LAYERS", "SAMPLE_COLUMNS", "STEP_COLUMNS", "FieldReduction",
           "field_layer_values", "field_rasters", "floor_steps", "levelling_samples",
           "reduce_field"]

#: processed step columns the heading-offset layer needs
STEP_COLUMNS = ("x_m", "y_m", "heading_offset_deg", "heading_offset_local_deg")
#: processed sample columns the magnetic layers need
SAMPLE_COLUMNS = ("x_m", "y_m", "mag_east_ut", "mag_north_ut", "mag_up_ut",
                  "q_w", "q_x", "q_y", "q_z")

#: layer -> (unit, kind, description)
FIELD_LAYERS = {
    "strength": ("uT", "scalar", "field strength"),
    "horizontal": ("uT", "scalar", "horizontal component"),
    "vertical": ("uT", "scalar", "vertical component (up positive)"),
    # the rotation vector takes north from the sensed field, so in its frame the field points
    # north wherever the phone is (the sample site's layers: 5-95 % within -2..2 deg); the
    # field's direction on the map is in heading_offset, with the opposite sign
    "azimuth": ("deg", "angle", "direction of the horizontal field in the frame of the phone's "
                "rotation vector, clockwise from its north (near 0: that frame's north is the "
                "sensed field's; the direction on the map is -heading_offset)"),
    "polar": ("deg", "angle", "angle between the field and up"),
}


def field_layer_values(field_enu: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """Per-sample values of :data:`FIELD_LAYERS` from the map-frame field (n, 3) (uT, east,
    north, up): strength, horizontal, vertical (uT, :func:`mapping.holdout.layer_values`);
    azimuth, polar (deg)."""
    out = layer_values(field_enu)
    e, n, u = np.asarray(field_enu, dtype=np.float64).T
    out["azimuth"] = np.mod(np.degrees(np.arctan2(e, n)), 360.0)
    out["polar"] = np.degrees(np.arccos(np.clip(u / np.maximum(out["strength"], 1e-9), -1, 1)))
    return out


def _walk_samples(store: SurveyStore, walk: pd.Series) -> pd.DataFrame:
    s = processed_part(store, "samples", walk, columns=SAMPLE_COLUMNS)
    s.insert(0, "trace_id", walk["trace_id"])
    s["session"] = walk["session"]
    return s


def levelling_samples(store: SurveyStore, walks: pd.DataFrame, subsample: int
                      ) -> pd.DataFrame:
    """Every ``subsample``-th sample of ``walks`` (processed-catalog rows, in order), counted
    over the walks as if their tables were concatenated; columns ``trace_id``, ``session`` and
    :data:`SAMPLE_COLUMNS`."""
    parts, offset = [], 0
    for _, walk in walks.iterrows():
        s = _walk_samples(store, walk)
        parts.append(s.iloc[(-offset) % subsample::subsample].copy())  # not a view of s
        offset += len(s)
    if not parts:
        return pd.DataFrame(columns=["trace_id", *SAMPLE_COLUMNS, "session"])
    return pd.concat(parts, ignore_index=True)


def floor_steps(store: SurveyStore, walks: pd.DataFrame) -> pd.DataFrame:
    """The steps of ``walks`` (processed-catalog rows): ``trace_id`` and
    :data:`STEP_COLUMNS`."""
    parts = []
    for _, walk in walks.iterrows():
        st = processed_part(store, "steps", walk, columns=STEP_COLUMNS)
        st.insert(0, "trace_id", walk["trace_id"])
        parts.append(st)
    return pd.concat(parts, ignore_index=True)


@dataclass
class FieldReduction:
    """What the magnetic layers need of a floor's samples.

    Attributes
    ----------
    walk_means : dict
        Value -> (flat cell index, mean) per (walk, cell) pair, walks in trace-id order.
        Values: the scalar layers and ``<angle>_sin``/``<angle>_cos`` of the angle layers.
    support : ndarray of bool, shape grid.shape
        Cells holding at least one sample.
    n_samples : int
    cv_x_m, cv_y_m, cv_strength_ut, cv_walk : ndarray
        Every ``cv_subsample``-th sample (counted over the walks in catalog order): position
        (m), levelled strength (uT), walk (rank of its trace id). The bandwidth
        cross-validation's input.
    """

    walk_means: dict[str, tuple[NDArray[np.int64], NDArray[np.float64]]]
    support: NDArray[np.bool_]
    n_samples: int
    cv_x_m: NDArray[np.float64]
    cv_y_m: NDArray[np.float64]
    cv_strength_ut: NDArray[np.float64]
    cv_walk: NDArray[np.int64]


#: what is averaged per (walk, cell): the scalar layers, and the angle layers as unit vectors
VALUE_NAMES = tuple(v for name, (_, kind, _) in FIELD_LAYERS.items()
                    for v in ((f"{name}_sin", f"{name}_cos") if kind == "angle" else (name,)))


def _per_walk_values(field_enu: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    out = {}
    for name, value in field_layer_values(field_enu).items():
        if FIELD_LAYERS[name][1] == "angle":
            rad = np.radians(value)
            out[f"{name}_sin"], out[f"{name}_cos"] = np.sin(rad), np.cos(rad)
        else:
            out[name] = value
    return out


def reduce_field(store: SurveyStore, walks: pd.DataFrame, grid: Grid,
                 residuals: pd.DataFrame | None, *,
                 cv_subsample: int = BANDWIDTH_SUBSAMPLE,
                 progress: Callable[[int, int], None] | None = None) -> FieldReduction:
    """Read ``walks`` (processed-catalog rows with ``session``) one at a time, level each
    (``residuals`` per session, see :func:`mapping.levelling.fit_session_residuals`; None =
    not levelled) and reduce it to per-(walk, cell) means. ``progress(done, total)``."""
    per_walk: dict[str, dict[str, tuple]] = {}
    order = sorted(str(t) for t in walks["trace_id"])
    rank = {t: i for i, t in enumerate(order)}
    support = np.zeros(grid.shape, dtype=bool)
    cv: list[tuple] = []
    offset = 0
    for i, (_, walk) in enumerate(walks.iterrows()):
        s = _walk_samples(store, walk)
        x, y = s["x_m"].to_numpy(np.float64), s["y_m"].to_numpy(np.float64)
        field_enu = (apply_session_residuals(s, residuals) if residuals is not None else
                     s[["mag_east_ut", "mag_north_ut", "mag_up_ut"]].to_numpy(np.float64))
        values = _per_walk_values(field_enu)
        code = np.zeros(len(s), dtype=np.int64)
        per_walk[str(walk["trace_id"])] = {
            name: walk_cell_means(grid, x, y, v, code)[1:] for name, v in values.items()}
        row, col, inside = grid.cell_of(x, y)
        support[row[inside], col[inside]] = True
        take = slice((-offset) % cv_subsample, None, cv_subsample)
        cv.append((x[take].copy(), y[take].copy(), values["strength"][take].copy(),  # not views
                   np.full(len(x[take]), rank[str(walk["trace_id"])], dtype=np.int64)))
        offset += len(s)
        if progress is not None:
            progress(i + 1, len(walks))
    walk_means = {
        name: (np.concatenate([per_walk[t][name][0] for t in order] or [np.zeros(0, np.int64)]),
               np.concatenate([per_walk[t][name][1] for t in order] or [np.zeros(0)]))
        for name in VALUE_NAMES}
    if cv:
        cx, cy, cs, cw = (np.concatenate(part) for part in zip(*cv))
    else:
        cx, cy, cs, cw = np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int64)
    return FieldReduction(walk_means, support, offset, cx, cy, cs, cw)


def field_rasters(grid: Grid, mask: NDArray[np.bool_], reduction: FieldReduction,
                  params: RasterParams) -> dict[str, tuple[NDArray[np.float32],
                                                           NDArray[np.float32]]]:
    """(values, uncertainty) rasters of :data:`FIELD_LAYERS`, as
    :func:`mapping.interpolate.raster` makes them from the samples."""
    def one(name: str) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        cell, mean = reduction.walk_means[name]
        return raster_from_stats(grid, mask, cell_stats(grid, cell, mean), params)

    out = {}
    for name, (_, kind, _) in FIELD_LAYERS.items():
        out[name] = (angle_raster(one(f"{name}_sin")[0], one(f"{name}_cos")[0])
                     if kind == "angle" else one(name))
    return out
