"""Map bundles from a simulated site's ground truth (tests and benchmarks of the localizer).

The true field of :func:`survey.sim.site.load_field` is sampled at the cell centres of a grid
over the reachable area of the floor plan (``OUT/<floor>/geojson_map.json``), and written as a
floor bundle with :func:`mapping.bundle_writer.write_bundle`. The layers are what a perfect
survey would map, in the frame the phones measure in:

- ``strength``, ``horizontal``, ``vertical`` (uT) and ``polar`` (deg from up) of the true field;
- ``azimuth`` (deg, angle): the field's azimuth in the phone's earth frame. The simulated
  rotation vector, like Android's, takes its north from the local field, so this is the earth
  field's azimuth everywhere (``azimuth="measured"``, the default); ``azimuth="true"`` stores
  the true local azimuth instead;
- ``heading_offset`` (deg, angle): compass heading minus true walking direction
  ``= -compass_deviation``.

Every layer gets a constant uncertainty ``std_ut`` (``std_deg`` for angles).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from localize.bundle import Grid
from mapping.bundle_writer import BundleContent, Layer, write_bundle
from mapping.floorplan import read_floor_plan
from mapping.grid import reachable_mask as grid_mask
from survey.field_features import field_features
from survey.sim.site import load_field

__all__ = ["reachable_mask", "truth_bundle"]


def reachable_mask(site_dir: str | Path, floor: str, cell_m: float) -> tuple[Grid, np.ndarray]:
    """Grid over the floor and the mask of cells whose centre is reachable."""
    plan = read_floor_plan(Path(site_dir) / floor)
    grid = plan.grid(cell_m)
    return grid, grid_mask(grid, plan.reachable)


def truth_bundle(site_dir: str | Path, floor: str, target: str | Path, *, cell_m: float = 0.25,
                 azimuth: str = "measured", std_ut: float = 1.0, std_deg: float = 2.0,
                 field_noise_ut: float = 0.0, seed: int = 0, overwrite: bool = False) -> str:
    """Write the truth bundle of one simulated floor; returns the bundle id.

    Parameters
    ----------
    site_dir : path
        Output folder of :func:`survey.sim.site.simulate_site`.
    floor : str
        Floor name (``"F1"``).
    target : path
        Bundle folder to write.
    cell_m : float
        Grid cell (m).
    azimuth : {"measured", "true"}
        See the module docstring.
    std_ut, std_deg : float
        Constant uncertainty stored with scalar (uT, deg for polar) and angle layers.
    field_noise_ut : float
        SD of white noise added to the field components per cell (a cruder map); 0 = exact.
    seed : int
        Seed of that noise.
    """
    site_dir = Path(site_dir)
    site = json.loads((site_dir / "truth" / "site.json").read_text())
    fl = next(f for f in site["floors"] if f["name"] == floor)
    fld = load_field(site, floor)
    grid, mask = reachable_mask(site_dir, floor, cell_m)
    cx, cy = grid.cell_centers()
    gx, gy = np.meshgrid(cx, cy)
    xs, ys = gx[mask], gy[mask]
    b = fld.field_earth_ut(xs, ys)
    if field_noise_ut > 0:
        b = b + np.random.default_rng(seed).normal(0.0, field_noise_ut, b.shape)
    deviation = fld.compass_deviation_deg(xs, ys, field_ut=b)
    feats = field_features(b)
    az = feats.azimuth_deg if azimuth == "true" else np.mod(feats.azimuth_deg - deviation, 360)

    def raster(v: NDArray[np.float64] | float) -> NDArray[np.float32]:
        """Values on the mask (per reachable cell, or one for all), NaN elsewhere."""
        out = np.full(grid.shape, np.nan, dtype=np.float32)
        out[mask] = v
        return out

    layers = {
        "strength": Layer(raster(feats.strength_ut), raster(std_ut), "uT"),
        "horizontal": Layer(raster(feats.horizontal_ut), raster(std_ut), "uT"),
        "vertical": Layer(raster(feats.vertical_ut), raster(std_ut), "uT"),
        "polar": Layer(raster(feats.polar_deg), raster(std_deg), "deg"),
        "azimuth": Layer(raster(az), raster(std_deg), "deg", kind="angle"),
        "heading_offset": Layer(raster(np.mod(-deviation, 360.0)), raster(std_deg), "deg",
                                kind="angle"),
    }
    content = BundleContent(
        site_id=site["site"]["site_id"], floor_id=fl["floor_id"], floor_name=floor, grid=grid,
        mask=mask, layers=layers,
        build={"source": "simulator truth", "azimuth": azimuth, "cell_m": cell_m,
               "field_noise_ut": field_noise_ut, "seed": seed, "build_time": "sim"})
    return write_bundle(target, content, overwrite=overwrite)
