"""Simulate a whole surveyed site: parameters, presets and the on-disk output.

Layout written by :func:`simulate_site` (``OUT`` is published atomically)::

    OUT/F1/floor_info.json              {"map_info": {"width": W, "height": H}}
    OUT/F1/geojson_map.json             outline + shops in lon/lat (real-data layout)
    OUT/F1/planned_routes.geojson       planned routes in metres (walk_id = trace id)
    OUT/F1/path_data_files/<id>.txt.gz  one trace per walk (24-hex trace ids)
    OUT/F2/...
    OUT/truth/site.json                 parameters, devices, sessions, walks, radio, fields
    OUT/truth/F1/<id>.parquet           per-sample truth of a walk
    OUT/truth/F1/<id>.steps.parquet     true steps
    OUT/truth/F1/<id>.waypoints.parquet recorded vs true clicks

Everything follows from ``SiteParams.seed``: the same parameters give byte-identical files.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import PublishError, SimulationError
from ..publish import atomic_directory, atomic_write_bytes
from ..trace_format import WIFI_COLUMNS, WIFI_DTYPES, empty_table
from ..trace_writer import write_trace
from . import assemble
from .devices import (
    DEVICE_MODELS,
    CalibrationSession,
    Device,
    accelerometer,
    gyroscope,
    magnetometer,
    make_device,
    make_sessions,
)
from .field import FieldParams, MagneticField, make_field
from .floorplan import Floorplan, make_floorplan
from .imu import (
    HOLDING_MODES,
    ImuParams,
    angular_rate,
    holding_attitude,
    rotation_vector,
    specific_force,
)
from .mapjson import GeoOrigin, floor_geojson, floor_info, planned_routes_geojson
from .output import json_bytes, parquet_bytes
from .radio import (
    RadioEnvironment,
    RadioParams,
    make_access_points,
    make_beacons,
    simulate_ble,
    simulate_wifi,
)
from .rng import child_rng, hex_id
from .routes import WaypointGraph, build_graph, click_points, random_route
from .walker import WalkerParams, WalkKinematics, simulate_walk

TRUTH_FORMAT = "indoormap-sim-truth/1"


@dataclass(frozen=True)
class SiteParams:
    """Everything that defines a simulated site. Frozen; derive variants with
    :func:`dataclasses.replace` or :meth:`preset` overrides.

    Attributes
    ----------
    preset : str
        Name of the preset these parameters came from (informational).
    seed : int
        The one seed of the whole simulation (non-negative).
    site_name : str
    n_floors : int
        Floors ``F1`` .. ``Fn``.
    width_m, height_m : float
        Size of every floor's bounding box (m).
    ew_corridor_widths_m, ns_corridor_widths_m : tuple of float
        Corridor widths (m) running east-west and north-south (order shuffled per floor).
    marker_spacing_m : float
        Largest distance between click points along a walk line (m).
    click_spacing_m : float
        Minimum distance between a marker click and the previous click within a walk (m).
    walks_per_floor : int
    walk_duration_s : (float, float)
        Range of the planned walk durations (s); the route length follows at ~0.9 m/s.
    devices : tuple of str
        Phone models (keys of :data:`~survey.sim.devices.DEVICE_MODELS`); the first is the
        reference phone (RSSI ``k = 1, b = 0``).
    sessions_per_device : int
        Calibration sessions (survey days) per phone.
    holding_modes : tuple of (str, float)
        Holding modes and their probabilities per walk.
    walks_without_wifi : int
        Walks whose trace has no Wi-Fi rows (like one real walk).
    origin_lonlat : (float, float)
        Synthetic lon/lat of the metre frame's origin.
    epoch_ms : int
        Unix ms of the first survey day's start.
    field, walker, imu, radio
        Component parameters.
    """

    preset: str = "custom"
    seed: int = 0
    site_name: str = "Synthetic Mall"
    n_floors: int = 2
    width_m: float = 40.0
    height_m: float = 25.0
    ew_corridor_widths_m: tuple[float, ...] = (5.0, 3.0, 1.2)
    ns_corridor_widths_m: tuple[float, ...] = (2.5, 4.0, 1.2)
    marker_spacing_m: float = 6.0
    click_spacing_m: float = 4.0
    walks_per_floor: int = 6
    walk_duration_s: tuple[float, float] = (40.0, 60.0)
    devices: tuple[str, ...] = ("SimPhone SIM-A1", "SimPhone SIM-B2")
    sessions_per_device: int = 2
    holding_modes: tuple[tuple[str, float], ...] = (("flat_forward", 1.0),)
    walks_without_wifi: int = 1
    origin_lonlat: tuple[float, float] = (120.0, 30.0)
    epoch_ms: int = 1_678_784_400_000
    field: FieldParams = dc_field(default_factory=FieldParams)
    walker: WalkerParams = dc_field(default_factory=WalkerParams)
    imu: ImuParams = dc_field(default_factory=ImuParams)
    radio: RadioParams = dc_field(default_factory=RadioParams)

    @classmethod
    def preset_params(cls, name: str, seed: int | None = None, **overrides) -> SiteParams:
        """Parameters of a preset (``"sample"`` or ``"default"``), optionally with another
        seed and field overrides."""
        if name not in PRESETS:
            raise SimulationError(f"unknown preset {name!r}; expected one of {sorted(PRESETS)}")
        p = PRESETS[name]
        if seed is not None:
            p = dataclasses.replace(p, seed=int(seed))
        if overrides:
            p = dataclasses.replace(p, **overrides)
        p.validate()
        return p

    def validate(self) -> None:
        """Raise :class:`~survey.errors.SimulationError` on inconsistent parameters."""
        if not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise SimulationError(f"seed must be a non-negative integer, got {self.seed!r}")
        if self.n_floors < 1 or self.walks_per_floor < 1:
            raise SimulationError("need at least one floor and one walk per floor")
        if not self.devices:
            raise SimulationError("need at least one device model")
        unknown = [d for d in self.devices if d not in DEVICE_MODELS]
        if unknown:
            raise SimulationError(f"unknown device models {unknown}; known: "
                                  f"{sorted(DEVICE_MODELS)}")
        if self.sessions_per_device < 1:
            raise SimulationError("sessions_per_device must be >= 1")
        modes = [m for m, _ in self.holding_modes]
        bad = [m for m in modes if m not in HOLDING_MODES]
        if bad or not modes:
            raise SimulationError(f"holding modes must be among {HOLDING_MODES}, got {modes}")
        if sum(w for _, w in self.holding_modes) <= 0:
            raise SimulationError("holding mode weights must sum to > 0")
        lo, hi = self.walk_duration_s
        if not 10.0 <= lo <= hi:
            raise SimulationError(f"walk_duration_s must satisfy 10 <= lo <= hi: {lo}, {hi}")
        if self.walks_without_wifi > self.n_floors * self.walks_per_floor:
            raise SimulationError("walks_without_wifi exceeds the number of walks")
        if self.walks_without_wifi < 0:
            raise SimulationError("walks_without_wifi must be >= 0")
        if not (np.isfinite(self.width_m) and np.isfinite(self.height_m)
                and 10.0 <= min(self.width_m, self.height_m)
                and max(self.width_m, self.height_m) <= 2000.0):
            raise SimulationError(f"floor size {self.width_m} x {self.height_m} m: each side "
                                  "must be 10 to 2000 m")
        corridors = (*self.ew_corridor_widths_m, *self.ns_corridor_widths_m)
        if not corridors or not all(np.isfinite(w) and w > 0 for w in corridors):
            raise SimulationError(f"corridor widths must be positive metres, got "
                                  f"{list(corridors)}")
        if not (self.marker_spacing_m > 0 and self.click_spacing_m >= 0):
            raise SimulationError("marker_spacing_m must be > 0 and click_spacing_m >= 0")
        if not 0 <= self.epoch_ms < 2**53:
            raise SimulationError(f"epoch_ms must be a Unix time in ms, got {self.epoch_ms}")

    def to_dict(self) -> dict:
        """JSON-able form (tuples become lists)."""
        return dataclasses.asdict(self)

    def layout_key(self) -> str:
        """Digest of everything that shapes the site (all but the preset's and the site's
        names): site and floor ids derive from it with the seed, so that two presets with
        one seed are two sites (before, their registries and localizers took them for one)."""
        d = self.to_dict()
        del d["preset"], d["site_name"]
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


PRESETS: dict[str, SiteParams] = {
    # the repository's data/sample_site: 2 floors of 40 x 25 m, 6 walks each, two phones with
    # two calibration sessions each; a few MB
    "sample": SiteParams(preset="sample", seed=7, site_name="Synthetic Mall (sample)",
                         walk_duration_s=(35.0, 50.0)),
    # a bigger site for experiments
    "default": SiteParams(
        preset="default", seed=7, site_name="Synthetic Mall", n_floors=3, width_m=80.0,
        height_m=50.0, ew_corridor_widths_m=(6.0, 3.0, 2.5, 1.2),
        ns_corridor_widths_m=(5.0, 2.5, 3.0, 1.2, 2.5, 4.0), walks_per_floor=16,
        walk_duration_s=(60.0, 120.0),
        devices=("SimPhone SIM-A1", "SimPhone SIM-B2", "SimPhone SIM-C3"), sessions_per_device=4,
        holding_modes=(("flat_forward", 0.9), ("upward_not_flat", 0.05), ("swinging", 0.05)),
        walks_without_wifi=1,
        radio=RadioParams(n_aps_per_floor=100, n_beacons_per_floor=16,
                          n_ble_others_per_floor=12)),
}


@dataclass(frozen=True)
class WalkInfo:
    """One simulated walk (paths relative to the output directory)."""

    trace_id: str
    floor: str
    device_id: str
    session_id: str
    holding_mode: str
    has_wifi: bool
    start_ms: int
    end_ms: int
    n_samples: int
    n_steps: int
    n_waypoints: int
    n_wifi_rows: int
    n_ble_rows: int
    length_m: float
    trace_path: str
    truth_path: str


@dataclass(frozen=True)
class SimulatedSite:
    """What :func:`simulate_site` wrote."""

    out_dir: Path
    params: SiteParams
    site_id: str
    floors: tuple[str, ...]
    walks: tuple[WalkInfo, ...]
    n_files: int
    n_bytes: int


@dataclass
class _Floor:
    plan: Floorplan
    floor_id: str
    field: MagneticField
    graph: WaypointGraph


def _schedule(params: SiteParams, sessions: list[CalibrationSession]) -> list[dict]:
    """Walk -> (floor, index, session, mode, wifi) assignments, balanced over sessions."""
    rng = child_rng(params.seed, "schedule")
    modes = [m for m, _ in params.holding_modes]
    w = np.array([x for _, x in params.holding_modes], dtype=np.float64)
    walks = []
    for f in range(params.n_floors):
        order = rng.permutation(len(sessions))
        reps = np.resize(order, params.walks_per_floor)
        reps = reps[rng.permutation(len(reps))]
        for i in range(params.walks_per_floor):
            walks.append({"floor": f, "index": i, "session": int(reps[i]),
                          "mode": modes[int(rng.choice(len(modes), p=w / w.sum()))],
                          "wifi": True})
    for k in rng.choice(len(walks), params.walks_without_wifi, replace=False):
        walks[int(k)]["wifi"] = False
    return walks


def _truth_tables(kin: WalkKinematics, field_ut: np.ndarray, deviation_deg: np.ndarray,
                  mode: str, q_true: np.ndarray) -> tuple[pd.DataFrame, pd.DataFrame,
                                                          pd.DataFrame]:
    def grid(values: np.ndarray, bits: int) -> np.ndarray:
        # round to a binary grid (2**-bits) so that float32 low mantissa bytes compress away
        return (np.round(np.asarray(values, dtype=np.float64) * 2.0 ** bits)
                / 2.0 ** bits).astype(np.float32)

    samples = pd.DataFrame({
        "t_ms": kin.t_ms.astype(np.int64),
        "x_m": grid(kin.xy_m[:, 0], 12), "y_m": grid(kin.xy_m[:, 1], 12),
        "heading_deg": grid(kin.heading_deg, 10),
        "speed_mps": grid(kin.speed_mps, 12),
        "field_e_ut": grid(field_ut[:, 0], 10),
        "field_n_ut": grid(field_ut[:, 1], 10),
        "field_u_ut": grid(field_ut[:, 2], 10),
        "compass_deviation_deg": grid(deviation_deg, 10),
        "holding_mode": pd.Categorical([mode] * len(kin.t_ms), categories=list(HOLDING_MODES)),
        "qx": grid(q_true[:, 0], 18), "qy": grid(q_true[:, 1], 18),
        "qz": grid(q_true[:, 2], 18), "qw": grid(q_true[:, 3], 18),
    })
    step_heading = np.interp(kin.step_t_ms.astype(np.float64), kin.t_ms.astype(np.float64),
                             np.degrees(np.unwrap(np.radians(kin.heading_deg)))) % 360.0
    step_freq = np.interp(kin.step_t_ms.astype(np.float64), kin.t_ms.astype(np.float64),
                          kin.step_freq_hz)
    steps = pd.DataFrame({
        "step": np.arange(len(kin.step_t_ms), dtype=np.int32),
        "t_ms": kin.step_t_ms.astype(np.int64),
        "length_m": kin.step_length_m,
        "x_m": kin.step_xy_m[:, 0], "y_m": kin.step_xy_m[:, 1],
        "heading_deg": step_heading, "freq_hz": step_freq,
    })
    clicks = pd.DataFrame({
        "waypoint": np.arange(len(kin.clicks_m), dtype=np.int32),
        "t_ms": kin.click_t_ms.astype(np.int64),
        "x_m": kin.clicks_m[:, 0], "y_m": kin.clicks_m[:, 1],
        "true_t_ms": kin.click_true_t_ms.astype(np.int64),
        "true_x_m": kin.click_true_xy_m[:, 0], "true_y_m": kin.click_true_xy_m[:, 1],
    })
    return samples, steps, clicks


def _walk_rng(seed: int, floor: int, index: int, component: str) -> np.random.Generator:
    return child_rng(seed, "walk", floor, index, component)


def simulate_site(params: SiteParams, out_dir: str | Path, *,
                  overwrite: bool = False) -> SimulatedSite:
    """Simulate a site and publish it atomically at ``out_dir``.

    Parameters
    ----------
    params : SiteParams
    out_dir : str or Path
        Target directory; built in a temporary sibling and renamed into place.
    overwrite : bool
        Replace an existing ``out_dir`` (otherwise :class:`~survey.errors.PublishError`).

    Returns
    -------
    SimulatedSite
    """
    params.validate()
    seed = int(params.seed)
    out_dir = Path(out_dir)
    layout = params.layout_key()
    site_id = hex_id(child_rng(seed, "site", layout))
    origin = GeoOrigin(*params.origin_lonlat)

    floors: list[_Floor] = []
    for f in range(params.n_floors):
        plan = make_floorplan(f"F{f + 1}", f, params.width_m, params.height_m,
                              params.ew_corridor_widths_m, params.ns_corridor_widths_m,
                              child_rng(seed, "floor", f, "plan"))
        fld = make_field(plan, params.field, child_rng(seed, "floor", f, "field"))
        floors.append(_Floor(plan, hex_id(child_rng(seed, "floor", f, "id", layout)), fld,
                             build_graph(plan, params.marker_spacing_m)))

    devices: list[Device] = [
        make_device(f"dev{j}", DEVICE_MODELS[name], j == 0, child_rng(seed, "device", j))
        for j, name in enumerate(params.devices)]
    n_dev = len(devices)
    sessions: list[CalibrationSession] = []
    for j, dev in enumerate(devices):
        days = [s * n_dev + j for s in range(params.sessions_per_device)]
        sessions += make_sessions(dev, days, child_rng(seed, "device", j, "sessions"))
    sessions.sort(key=lambda s: (s.day, s.device_id))
    dev_by_id = {d.device_id: d for d in devices}

    plans = [fl.plan for fl in floors]
    aps = make_access_points(plans, params.radio, seed, child_rng(seed, "radio", "aps"))
    beacons = make_beacons(plans, params.radio, seed, child_rng(seed, "radio", "ble"))
    env = RadioEnvironment(plans, aps, beacons, params.radio)

    schedule = _schedule(params, sessions)
    infos: list[WalkInfo] = []
    plan_features: dict[int, list[dict]] = {f: [] for f in range(params.n_floors)}
    speed_guess = 0.9

    with atomic_directory(out_dir, overwrite=overwrite, crash_prefix="simulate") as tmp:
        for g, sess in enumerate(sessions):
            cursor = params.epoch_ms + sess.day * 86_400_000 + int(
                child_rng(seed, "session", g).integers(0, 2 * 3_600_000))
            device = dev_by_id[sess.device_id]
            mine = [w for w in schedule if w["session"] == g]
            for w in sorted(mine, key=lambda w: (w["floor"], w["index"])):
                f, i = w["floor"], w["index"]
                fl = floors[f]
                plan = fl.plan
                dur = _walk_rng(seed, f, i, "duration").uniform(*params.walk_duration_s)
                target = max(8.0, (dur - 4.0) * speed_guess)
                route = click_points(random_route(fl.graph, target,
                                                  _walk_rng(seed, f, i, "route")),
                                     params.click_spacing_m)
                kin = simulate_walk(route, plan, cursor, params.walker,
                                    _walk_rng(seed, f, i, "walker"))
                cursor = kin.end_ms + int(_walk_rng(seed, f, i, "gap").integers(60_000, 240_000))
                trace_id = f"{(kin.start_ms // 1000) & 0xFFFFFFFF:08x}" + hex_id(
                    _walk_rng(seed, f, i, "id"), 16)

                field_ut = fl.field.field_earth_ut(kin.xy_m[:, 0], kin.xy_m[:, 1])
                deviation = fl.field.compass_deviation_deg(kin.xy_m[:, 0], kin.xy_m[:, 1],
                                                           field_ut=field_ut)
                irng = _walk_rng(seed, f, i, "imu")
                q, swing = holding_attitude(kin, w["mode"], irng)
                force = specific_force(kin, q, swing, w["mode"], params.imu, irng)
                rates = angular_rate(kin, q)
                rv = rotation_vector(q, deviation, kin.t_s, params.imu,
                                     _walk_rng(seed, f, i, "rotation_vector"))
                mag = magnetometer(field_ut, q, device, sess, _walk_rng(seed, f, i, "mag"))
                acc_cal, acc_unc, acc_bias = accelerometer(force, device,
                                                           _walk_rng(seed, f, i, "acc"))
                gyr_cal, gyr_unc, gyr_bias = gyroscope(rates, device, sess,
                                                       _walk_rng(seed, f, i, "gyro"))
                sensors = assemble.sensor_table(kin.t_ms, {
                    "accelerometer": (acc_cal, None),
                    "gyroscope": (gyr_cal, None),
                    "magnetic_field": (mag.calibrated_ut, None),
                    "rotation_vector": (rv[:, :3], None),
                    "accelerometer_uncalibrated": (acc_unc, acc_bias),
                    "gyroscope_uncalibrated": (gyr_unc, gyr_bias),
                    "magnetic_field_uncalibrated": (mag.uncalibrated_ut, mag.bias_ut),
                })
                if w["wifi"]:
                    wifi = simulate_wifi(env, kin, f, device, _walk_rng(seed, f, i, "wifi"))
                else:
                    wifi = empty_table(WIFI_COLUMNS, WIFI_DTYPES)
                ble, raw_lines = simulate_ble(env, kin, f, _walk_rng(seed, f, i, "ble"))
                extra = [f"{kin.start_ms + 5}\tTYPE_SENSOR_MAGNETIC_FIELD_ACCURACY_CHANGED\t3"]
                extra += raw_lines
                header = assemble.make_header(kin.start_ms, kin.end_ms, site_id,
                                              params.site_name, fl.floor_id, plan.name, device)
                trace = assemble.build_trace(trace_id, header, sensors, wifi, ble,
                                             assemble.waypoint_table(kin.click_t_ms,
                                                                     kin.clicks_m))
                rel_trace = f"{plan.name}/path_data_files/{trace_id}.txt.gz"
                write_trace(tmp / rel_trace, trace, extra_lines=extra)

                samples, steps, clicks = _truth_tables(kin, field_ut, deviation, w["mode"], q)
                rel_truth = f"truth/{plan.name}/{trace_id}.parquet"
                atomic_write_bytes(tmp / rel_truth, parquet_bytes(samples))
                atomic_write_bytes(tmp / f"truth/{plan.name}/{trace_id}.steps.parquet",
                                   parquet_bytes(steps))
                atomic_write_bytes(tmp / f"truth/{plan.name}/{trace_id}.waypoints.parquet",
                                   parquet_bytes(clicks))
                plan_features[f].append({
                    "walk_id": trace_id, "start_ms": kin.start_ms, "end_ms": kin.end_ms,
                    "floor": plan.name, "device_id": device.device_id,
                    "n_waypoints": len(kin.clicks_m), "route_m": kin.clicks_m})
                infos.append(WalkInfo(
                    trace_id=trace_id, floor=plan.name, device_id=device.device_id,
                    session_id=sess.session_id, holding_mode=w["mode"], has_wifi=w["wifi"],
                    start_ms=kin.start_ms, end_ms=kin.end_ms, n_samples=len(kin.t_ms),
                    n_steps=len(kin.step_t_ms), n_waypoints=len(kin.clicks_m),
                    n_wifi_rows=len(wifi), n_ble_rows=len(ble),
                    length_m=round(float(kin.length_m), 3), trace_path=rel_trace,
                    truth_path=rel_truth))

        for f, fl in enumerate(floors):
            d = tmp / fl.plan.name
            atomic_write_bytes(d / "floor_info.json", json_bytes(floor_info(fl.plan)))
            atomic_write_bytes(d / "geojson_map.json",
                               json_bytes(floor_geojson(fl.plan, origin), compact=True))
            feats = sorted(plan_features[f], key=lambda x: x["start_ms"])
            atomic_write_bytes(d / "planned_routes.geojson",
                               json_bytes(planned_routes_geojson(feats), compact=True))
            (d / "path_data_files").mkdir(parents=True, exist_ok=True)

        infos.sort(key=lambda x: (x.floor, x.start_ms))
        truth = {
            "format": TRUTH_FORMAT,
            "seed": seed,
            "preset": params.preset,
            "params": params.to_dict(),
            "site": {"site_id": site_id, "site_name": params.site_name,
                     "origin_lonlat": list(params.origin_lonlat),
                     "frame": "metres, x east, y north (floor_info frame); z up from the floor",
                     "conventions": {
                         "heading_deg": "walking direction, azimuth clockwise from map north",
                         "compass_deviation_deg": "azimuth of the local horizontal field minus "
                                                  "that of the undisturbed earth field; the "
                                                  "rotation vector's azimuth = true - deviation",
                         "quaternion": "device-to-earth (ENU), x y z w",
                     }},
            "floors": [{
                "name": fl.plan.name, "floor_id": fl.floor_id, "index": fl.plan.index,
                "width_m": fl.plan.width_m, "height_m": fl.plan.height_m,
                "corridors": [dataclasses.asdict(c) for c in fl.plan.corridors],
                "walk_lines": [{"coords_m": [list(p) for p in wl.line.coords],
                                "corridor": wl.corridor, "offset_m": wl.offset_m}
                               for wl in fl.plan.walk_lines],
                "click_points_m": fl.graph.nodes_m.tolist(),
                "field": fl.field.to_dict(),
            } for fl in floors],
            "devices": [d.to_dict() for d in devices],
            "sessions": [s.to_dict() for s in sessions],
            "walks": [dataclasses.asdict(x) for x in infos],
            "radio": env.to_dict(),
        }
        atomic_write_bytes(tmp / "truth" / "site.json", json_bytes(truth))
        files = [p for p in tmp.rglob("*") if p.is_file()]
        n_files = len(files)
        n_bytes = sum(p.stat().st_size for p in files)

    return SimulatedSite(out_dir=out_dir, params=params, site_id=site_id,
                         floors=tuple(fl.plan.name for fl in floors), walks=tuple(infos),
                         n_files=n_files, n_bytes=n_bytes)


def ensure_sample_site(out_dir: str | Path) -> Path:
    """The ``sample`` preset site (seed 7) at ``out_dir``, simulated there unless it is already
    (the repository's ``data/sample_site``, which is generated, not tracked; ~8 s). Publication
    is atomic, so a present ``truth/site.json`` means a complete site; a concurrent caller
    that publishes first wins."""
    out_dir = Path(out_dir)
    # a site generated before the planned routes got their own name is simulated again
    stale = ((out_dir / "truth" / "site.json").exists()
             and not (out_dir / "F1" / "planned_routes.geojson").exists())
    if stale or not (out_dir / "truth" / "site.json").exists():
        try:
            simulate_site(PRESETS["sample"], out_dir, overwrite=stale)
        except PublishError:
            if not (out_dir / "truth" / "site.json").exists():
                raise
    return out_dir


def load_field(site_json: dict, floor: str) -> MagneticField:
    """The magnetic field model of ``floor`` from a loaded ``truth/site.json``."""
    for fl in site_json["floors"]:
        if fl["name"] == floor:
            return MagneticField.from_dict(fl["field"])
    raise SimulationError(f"no floor {floor!r} in site.json")
