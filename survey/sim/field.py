"""The magnetic field of a floor: a uniform earth field plus anomalies of steel.

The field is expressed in the map/earth frame (E, N, Up; uT). Anomalies are point dipoles:
vertical chains for steel pillars (floor to ceiling), horizontal chains for beams and rebar under
the floor, single dipoles for cabinets and machines inside shops, and deeper dipoles for the floor
below. Sources keep some distance from the walkable area, so along a walk the anomaly varies on a
metre scale with most of its energy below 0.5 cycles/m (papers 000, 001).

The model is a plain list of dipoles and therefore serializable (:meth:`MagneticField.to_dict`):
the ground truth can be recomputed anywhere from ``site.json``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from ..errors import SimulationError
from .floorplan import Floorplan
from .signals import wrap_deg

#: mu0 / (4 pi) in uT m^3 / (A m^2): a dipole of 1 A m^2 gives 0.2 uT at 1 m on its axis.
MU0_4PI = 0.1
#: Phone height above the floor (m) at which the field is evaluated by default.
PHONE_HEIGHT_M = 1.1


@dataclass(frozen=True)
class EarthField:
    """The undisturbed geomagnetic field.

    Attributes
    ----------
    strength_ut : float
        Total intensity (uT).
    inclination_deg : float
        Angle of the field vector from *up* (degrees); 133 means pointing 43 deg below the
        horizon, as measured on the real floors.
    declination_deg : float
        Azimuth of the horizontal component, degrees clockwise from map north (0: map north).
    """

    strength_ut: float = 42.0
    inclination_deg: float = 133.0
    declination_deg: float = 0.0

    def vector_ut(self) -> np.ndarray:
        """The field vector (E, N, U) in uT, shape (3,)."""
        inc = np.radians(self.inclination_deg)
        dec = np.radians(self.declination_deg)
        h = self.strength_ut * np.sin(inc)
        return np.array([h * np.sin(dec), h * np.cos(dec), self.strength_ut * np.cos(inc)])


class MagneticField:
    """Earth field plus dipole anomalies.

    Parameters
    ----------
    earth : EarthField
    source_xyz_m : numpy.ndarray, shape (m, 3)
        Dipole positions (x east, y north, z up from the floor; metres).
    moment_am2 : numpy.ndarray, shape (m, 3)
        Dipole moments (E, N, U components; A m^2).
    phone_height_m : float
        Default height (m above the floor) at which :meth:`field_earth_ut` evaluates.
    """

    def __init__(self, earth: EarthField, source_xyz_m: np.ndarray, moment_am2: np.ndarray,
                 phone_height_m: float = PHONE_HEIGHT_M) -> None:
        self.earth = earth
        self.source_xyz_m = np.asarray(source_xyz_m, dtype=np.float64).reshape(-1, 3)
        self.moment_am2 = np.asarray(moment_am2, dtype=np.float64).reshape(-1, 3)
        if self.source_xyz_m.shape != self.moment_am2.shape:
            raise SimulationError("source positions and moments differ in shape")
        self.phone_height_m = float(phone_height_m)
        self._b0 = earth.vector_ut()

    def anomaly_ut(self, x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray | float | None = None,
                   chunk: int = 64) -> np.ndarray:
        """Field of the dipoles alone, (E, N, U) uT, shape (n, 3)."""
        x = np.atleast_1d(np.asarray(x_m, dtype=np.float64)).ravel()
        y = np.atleast_1d(np.asarray(y_m, dtype=np.float64)).ravel()
        z = np.broadcast_to(np.asarray(self.phone_height_m if z_m is None else z_m,
                                       dtype=np.float64), x.shape)
        pts = np.column_stack([x, y, z])
        out = np.zeros((len(pts), 3))
        if len(self.source_xyz_m) == 0:
            return out
        sx, sy, sz = self.source_xyz_m.T
        mx, my, mz = self.moment_am2.T
        for a in range(0, len(pts), chunk):
            p = pts[a:a + chunk]
            rx = p[:, 0:1] - sx                                   # (c, m)
            ry = p[:, 1:2] - sy
            rz = p[:, 2:3] - sz
            d2 = np.maximum(rx * rx + ry * ry + rz * rz, 0.01)    # 10 cm core
            inv_d2 = 1.0 / d2
            inv_d3 = np.sqrt(inv_d2) * inv_d2
            t = 3.0 * (rx * mx + ry * my + rz * mz) * (inv_d3 * inv_d2)
            out[a:a + chunk, 0] = (t * rx - inv_d3 * mx).sum(axis=1)
            out[a:a + chunk, 1] = (t * ry - inv_d3 * my).sum(axis=1)
            out[a:a + chunk, 2] = (t * rz - inv_d3 * mz).sum(axis=1)
        out *= MU0_4PI
        return out

    def field_earth_ut(self, x_m: np.ndarray, y_m: np.ndarray,
                       z_m: np.ndarray | float | None = None) -> np.ndarray:
        """Total field (E, N, U) in uT at the points, shape (n, 3).

        Parameters
        ----------
        x_m, y_m : numpy.ndarray, shape (n,)
            Positions, metres (x east, y north).
        z_m : float or numpy.ndarray, optional
            Height above the floor (m); default the phone height.
        """
        return self._b0 + self.anomaly_ut(x_m, y_m, z_m)

    def strength_ut(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Field magnitude (uT), shape (n,)."""
        return np.linalg.norm(self.field_earth_ut(x_m, y_m), axis=1)

    def compass_deviation_deg(self, x_m: np.ndarray, y_m: np.ndarray,
                              field_ut: np.ndarray | None = None) -> np.ndarray:
        """Azimuth of the local horizontal field minus that of the undisturbed earth field.

        Degrees, wrapped to [-180, 180); positive when the local field points clockwise (east) of
        the earth field. A compass (and Android's fused heading) reads the true azimuth *minus*
        this deviation. ``field_ut`` may pass an already computed :meth:`field_earth_ut`.
        """
        b = self.field_earth_ut(x_m, y_m) if field_ut is None else np.asarray(field_ut)
        az = np.degrees(np.arctan2(b[:, 0], b[:, 1]))
        az0 = np.degrees(np.arctan2(self._b0[0], self._b0[1]))
        return wrap_deg(az - az0)

    def to_dict(self) -> dict:
        """JSON-able description; :meth:`from_dict` rebuilds an identical model."""
        return {
            "model": "earth+dipoles",
            "units": {"position": "m (x east, y north, z up from floor)", "moment": "A m^2 (E,N,U)",
                      "field": "uT (E,N,U)"},
            "earth": {"strength_ut": self.earth.strength_ut,
                      "inclination_deg": self.earth.inclination_deg,
                      "declination_deg": self.earth.declination_deg},
            "phone_height_m": self.phone_height_m,
            "source_xyz_m": self.source_xyz_m.tolist(),
            "moment_am2": self.moment_am2.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> MagneticField:
        """Inverse of :meth:`to_dict`."""
        e = d["earth"]
        return cls(EarthField(float(e["strength_ut"]), float(e["inclination_deg"]),
                              float(e["declination_deg"])),
                   np.asarray(d["source_xyz_m"], dtype=np.float64).reshape(-1, 3),
                   np.asarray(d["moment_am2"], dtype=np.float64).reshape(-1, 3),
                   float(d.get("phone_height_m", PHONE_HEIGHT_M)))


@dataclass(frozen=True)
class FieldParams:
    """How strong and where the anomalies are.

    Attributes
    ----------
    earth : EarthField
    strength_sd_ut : float
        Standard deviation of the field strength over the walkable area (uT) after scaling
        (the real floors: ~7 uT).
    strength_range_ut : (float, float)
        The total strength over the walkable area is kept inside this range (moments are scaled
        down if needed).
    grid_spacing_m : float
        Structural grid spacing (pillars, beams), metres.
    pillar_clearance_m : float
        Minimum distance of pillars and cabinets from the walkable area (m).
    beam_depth_m : float
        Depth of beams/rebar below the floor (m, positive down).
    group_peak_cap_ut : float
        Largest anomaly (uT) one source group (a pillar, a beam, a cabinet) may add anywhere in
        the walkable area.
    n_cabinets, n_deep : int
        Number of cabinet dipoles (inside shops) and deep dipoles (floor below).
    """

    earth: EarthField = EarthField()
    strength_sd_ut: float = 6.0
    strength_range_ut: tuple[float, float] = (26.0, 64.0)
    grid_spacing_m: float = 8.0
    pillar_clearance_m: float = 0.9
    beam_depth_m: float = 0.5
    group_peak_cap_ut: float = 12.0
    n_cabinets: int = 6
    n_deep: int = 10


def _chain(p0: np.ndarray, p1: np.ndarray, spacing_m: float) -> np.ndarray:
    n = max(2, int(np.ceil(np.linalg.norm(p1 - p0) / spacing_m)) + 1)
    return p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)


def make_field(plan: Floorplan, params: FieldParams, rng: np.random.Generator) -> MagneticField:
    """A random field for ``plan``.

    Returns
    -------
    MagneticField
        Source positions rounded to 1 mm and moments to 1e-4 A m^2, so that the serialized model
        is the model itself.
    """
    b0 = params.earth.vector_ut()
    b0_unit = b0 / np.linalg.norm(b0)
    g = params.grid_spacing_m
    walkable = plan.walkable
    obstacles_union = shapely.union_all(list(plan.obstacles))
    shapely.prepare(obstacles_union)
    pos: list[np.ndarray] = []
    mom: list[np.ndarray] = []

    # steel pillars on a structural grid, where they stand inside shops away from corridors
    ox, oy = rng.uniform(0.0, g, 2)
    gx = np.arange(ox, plan.width_m, g)
    gy = np.arange(oy, plan.height_m, g)
    px, py = (a.ravel() for a in np.meshgrid(gx, gy))
    pts = shapely.points(px, py)
    ok = shapely.contains(obstacles_union, pts) & (
        shapely.distance(walkable, pts) >= params.pillar_clearance_m)
    for x, y in zip(px[ok], py[ok]):
        chain = _chain(np.array([x, y, -0.3]), np.array([x, y, 4.2]), 0.5)
        induced = rng.uniform(20.0, 60.0) * b0_unit
        remanent = rng.normal(0.0, 15.0, 3)
        m = (induced + remanent) * (1.0 + 0.3 * rng.standard_normal((len(chain), 1)))
        pos.append(chain)
        mom.append(m)

    # beams / rebar under the floor along the structural grid lines
    depth = -abs(params.beam_depth_m)
    for y in gy:
        chain = _chain(np.array([0.0, y, depth]), np.array([plan.width_m, y, depth]), 0.75)
        base = rng.normal(0.0, 6.0, 3) + rng.uniform(0.0, 6.0) * b0_unit
        wiggle = rng.normal(0.0, 3.0, (len(chain), 3))
        pos.append(chain)
        mom.append(base + wiggle)
    for x in gx:
        chain = _chain(np.array([x, 0.0, depth]), np.array([x, plan.height_m, depth]), 0.75)
        base = rng.normal(0.0, 6.0, 3) + rng.uniform(0.0, 6.0) * b0_unit
        wiggle = rng.normal(0.0, 3.0, (len(chain), 3))
        pos.append(chain)
        mom.append(base + wiggle)

    # cabinets / machines inside shops, near but not in the corridors
    minx, miny, maxx, maxy = 0.0, 0.0, plan.width_m, plan.height_m
    cand = rng.uniform([minx, miny], [maxx, maxy], size=(400, 2))
    cpts = shapely.points(cand[:, 0], cand[:, 1])
    dist = shapely.distance(walkable, cpts)
    good = shapely.contains(obstacles_union, cpts) & (dist >= params.pillar_clearance_m + 0.3) \
        & (dist <= 3.0)
    chosen = cand[good][:params.n_cabinets]
    for x, y in chosen:
        pos.append(np.array([[x, y, rng.uniform(0.3, 1.0)]]))
        mom.append(rng.normal(0.0, 40.0, (1, 3)))

    # deep sources (machinery of the floor below)
    deep = np.column_stack([rng.uniform(0, plan.width_m, params.n_deep),
                            rng.uniform(0, plan.height_m, params.n_deep),
                            rng.uniform(-4.0, -2.0, params.n_deep)])
    deep_m = rng.normal(0.0, 150.0, (params.n_deep, 3))
    for i in range(params.n_deep):
        pos.append(deep[i:i + 1])
        mom.append(deep_m[i:i + 1])

    # evaluate every source group on a walkable grid; scale the groups together so that the
    # strength varies with the requested SD, capping any single group's peak (no 100 uT spots)
    xs = np.arange(0.25, plan.width_m, 0.5)
    ys = np.arange(0.25, plan.height_m, 0.5)
    gxx, gyy = (a.ravel() for a in np.meshgrid(xs, ys))
    inside = plan.is_walkable(gxx, gyy, margin_m=0.2)
    gxx, gyy = gxx[inside], gyy[inside]
    group_fields = [MagneticField(params.earth, p, q).anomaly_ut(gxx, gyy)
                    for p, q in zip(pos, mom)]
    group_peak = np.array([np.linalg.norm(a, axis=1).max() for a in group_fields])
    weights = np.ones(len(pos))

    def strength(scale: float) -> np.ndarray:
        return np.linalg.norm(b0 + scale * total, axis=1)

    def scale_for_sd() -> float:
        lo_s, hi_s = 0.0, 1.0
        while strength(hi_s).std() < params.strength_sd_ut and hi_s < 1e6:
            hi_s *= 2.0
        for _ in range(40):
            mid = 0.5 * (lo_s + hi_s)
            lo_s, hi_s = (mid, hi_s) if strength(mid).std() < params.strength_sd_ut else (lo_s, mid)
        return lo_s

    total = np.einsum("g,gnk->nk", weights, np.asarray(group_fields))
    scale = scale_for_sd()
    for _ in range(4):
        weights = np.minimum(weights, params.group_peak_cap_ut
                             / np.maximum(scale * group_peak, 1e-9))
        total = np.einsum("g,gnk->nk", weights, np.asarray(group_fields))
        scale = scale_for_sd()
    lo, hi = params.strength_range_ut
    for _ in range(60):
        s = strength(scale)
        if s.min() >= lo and s.max() <= hi:
            break
        scale *= 0.95
    src = np.concatenate(pos)
    m = np.concatenate([w * q for w, q in zip(weights, mom)])
    m = np.round(m * scale, 4)
    return MagneticField(params.earth, np.round(src, 3), m)
