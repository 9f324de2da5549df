"""Wi-Fi access points and BLE beacons: placement, path loss, scans and sightings.

Mean RSSI of the reference phone (dBm)::

    rssi = P0 - 10 n log10(d) - walls * wall_loss - floors * floor_loss + shadow(x, y)

with ``d`` the 3-D distance (m, at least 1), ``n`` in 2-4 per access point, ``walls`` the number
of shop walls the straight line crosses, and ``shadow`` a spatially correlated Gaussian field fixed
per access point (random Fourier features rebuilt from the stored ``shadow_seed``, so it is the
same for every walk at the same place). Each observation adds fast fading; the phone distorts
the value (``k * rssi + b``) and reports integers.

A Wi-Fi scan lists every access point the phone has observed recently: each scan sweep observes
an access point with a probability that falls with its RSSI (channel by channel, so last-seen
times lie up to ``sweep_s`` before the scan), and the scan reports the last observation of each
access point seen within ``cache_s`` -- so a share of rows is stale, with the RSSI of an older time
and position. A few rows are duplicated within a scan. BLE: iBeacon sightings (``TYPE_BEACON``)
and the undocumented raw advertisement pairs ``TYPE_BLUE`` / ``TYPE_BLU4`` (returned as text
lines for :func:`survey.trace_writer.write_trace`'s ``extra_lines``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
import shapely

from ..trace_format import (
    BLE_COLUMNS,
    BLE_DTYPES,
    WIFI_COLUMNS,
    WIFI_DTYPES,
    empty_table,
)
from .devices import Device, distort_rssi
from .floorplan import Floorplan
from .rng import child_seed
from .walker import WalkKinematics


@dataclass(frozen=True)
class RadioParams:
    """Radio environment and scanner parameters (dB, dBm, m, s)."""

    n_aps_per_floor: int = 40
    shop_ap_share: float = 0.7
    dual_band_share: float = 0.4
    hidden_ssid_share: float = 0.15
    p0_dbm: tuple[float, float] = (-40.0, -28.0)
    n_exp: tuple[float, float] = (2.0, 4.0)
    shadow_sd_db: tuple[float, float] = (3.0, 6.0)
    shadow_len_m: tuple[float, float] = (2.0, 5.0)
    shadow_features: int = 24
    fading_sd_db: float = 2.5
    wall_loss_db: float = 2.5
    floor_loss_db: float = 18.0
    floor_height_m: float = 5.0
    ap_height_m: float = 2.8
    phone_height_m: float = 1.1
    detect_dbm: float = -95.0
    miss_prob: tuple[float, float] = (0.3, 0.75)
    scan_period_s: tuple[float, float] = (1.7, 2.5)
    sweep_s: float = 1.5
    cache_s: float = 45.0
    warmup_s: float = 50.0
    duplicate_share: float = 0.01
    n_beacons_per_floor: int = 8
    beacon_shared_key_share: float = 0.5
    beacon_rate_hz: float = 0.12
    beacon_detect_dbm: float = -100.0
    n_ble_others_per_floor: int = 8
    ble_raw_rate_hz: float = 0.3


@dataclass(frozen=True)
class AccessPoint:
    """One BSSID (a dual-band router has two)."""

    bssid: str
    ssid: str
    freq_mhz: int
    floor: int
    x_m: float
    y_m: float
    p0_dbm: float
    n_exp: float
    shadow_sd_db: float
    shadow_len_m: float
    shadow_seed: int


@dataclass(frozen=True)
class Beacon:
    """A BLE transmitter. iBeacons have a uuid; other advertisers (phones, wearables) have
    ``uuid == ""`` and only appear in ``TYPE_BLUE`` / ``TYPE_BLU4`` lines."""

    mac: str
    uuid: str
    major: int
    minor: int
    tx_power_dbm: int
    floor: int
    x_m: float
    y_m: float
    n_exp: float
    shadow_sd_db: float
    shadow_seed: int


_OUIS = ("a8:0c:ca", "74:ee:2a", "04:33:89", "12:74:9c", "c8:3a:35", "f4:83:cd", "0c:4b:54",
         "b0:95:8e", "dc:fe:18", "50:bd:5f", "e4:f4:c6", "88:25:93")
_CH24 = (2412, 2417, 2422, 2427, 2432, 2437, 2442, 2447, 2452, 2457, 2462, 2472)
_CH5 = (5180, 5200, 5220, 5240, 5745, 5765, 5785, 5805, 5825)


def _mac(rng: np.random.Generator, oui: str | None = None) -> str:
    tail = rng.integers(0, 256, 3 if oui else 6)
    parts = ([oui] if oui else []) + [f"{int(b):02x}" for b in tail]
    return ":".join(parts)


def _ssid(rng: np.random.Generator, floor_name: str, i: int) -> str:
    kind = rng.random()
    if kind < 0.30:
        return "MallGuest"
    if kind < 0.40:
        return "MallStaff"
    if kind < 0.65:
        return f"Shop{floor_name}-{i:02d}"
    if kind < 0.80:
        return "ChinaNet-" + "".join(rng.choice(list("abcdefghjkmnpqrstuvwxyz23456789"), 4))
    if kind < 0.92:
        return f"IPC-{int(rng.integers(10**10, 10**11))}"
    return f"DIRECT-{int(rng.integers(10, 99))}-HP Printer"


def _random_point_in(poly, rng: np.random.Generator) -> tuple[float, float]:
    minx, miny, maxx, maxy = poly.bounds
    for _ in range(100):
        x, y = rng.uniform(minx, maxx), rng.uniform(miny, maxy)
        if shapely.contains_xy(poly, x, y):
            return float(x), float(y)
    c = poly.representative_point()
    return float(c.x), float(c.y)


def make_access_points(plans: list[Floorplan], params: RadioParams, seed: int,
                       rng: np.random.Generator) -> list[AccessPoint]:
    """Access points of all floors (inside shops and on corridor ceilings).

    ``seed`` is the site seed: each access point's shadowing seed is derived from it.
    """
    aps: list[AccessPoint] = []
    used: set[str] = set()

    def fresh_bssid(oui: str) -> str:
        while True:
            b = _mac(rng, oui)
            if b not in used:
                used.add(b)
                return b

    for plan in plans:
        areas = np.array([p.area for p in plan.obstacles])
        for i in range(params.n_aps_per_floor):
            if rng.random() < params.shop_ap_share and len(plan.obstacles):
                shop = plan.obstacles[int(rng.choice(len(areas), p=areas / areas.sum()))]
                x, y = _random_point_in(shop, rng)
            else:
                line = plan.walk_lines[int(rng.integers(len(plan.walk_lines)))].line
                p = line.interpolate(float(rng.uniform(0.0, line.length)))
                x, y = float(p.x), float(p.y)
            ssid = "" if rng.random() < params.hidden_ssid_share else _ssid(rng, plan.name, i)
            oui = _OUIS[int(rng.integers(len(_OUIS)))]
            bssid = fresh_bssid(oui)
            p0 = float(rng.uniform(*params.p0_dbm))
            n_exp = float(rng.uniform(*params.n_exp))
            sd = float(rng.uniform(*params.shadow_sd_db))
            ln = float(rng.uniform(*params.shadow_len_m))
            dual = rng.random() < params.dual_band_share
            five_only = (not dual) and rng.random() < 0.2
            bands = [("5", bssid)] if five_only else [("2.4", bssid)]
            if dual:
                octets = bssid.split(":")
                twin = ":".join(octets[:3] + [f"{int(octets[3], 16) ^ 0x80:02x}"] + octets[4:])
                if twin in used:
                    twin = fresh_bssid(oui)
                used.add(twin)
                bands.append(("5", twin))
            for band, b in bands:
                if band == "2.4":
                    freq, p0b, nb = int(rng.choice(_CH24)), p0, n_exp
                else:
                    freq, p0b, nb = int(rng.choice(_CH5)), p0 - 5.0, min(n_exp + 0.3, 4.0)
                k = len(aps)
                aps.append(AccessPoint(b, ssid, freq, plan.index, round(x, 3), round(y, 3),
                                       round(p0b, 2), round(nb, 3), round(sd, 2), round(ln, 2),
                                       child_seed(seed, "shadow", "ap", k)))
    return aps


def make_beacons(plans: list[Floorplan], params: RadioParams, seed: int,
                 rng: np.random.Generator) -> list[Beacon]:
    """iBeacons at shop fronts plus other BLE advertisers, per floor."""
    site_uuid = "-".join(rng.bytes(16).hex().upper()[a:b]
                         for a, b in ((0, 8), (8, 12), (12, 16), (16, 20), (20, 32)))
    foreign_uuid = "5A1E0B7C-3D2F-4E6A-9B81-C0FFEE5117E5"  # invented: another operator's beacons
    out: list[Beacon] = []
    minor = 0
    for plan in plans:
        boundary = plan.walkable.boundary
        for _ in range(params.n_beacons_per_floor):
            p = boundary.interpolate(float(rng.uniform(0.0, boundary.length)))
            shared = rng.random() < params.beacon_shared_key_share
            minor += 1
            uuid, major, mn = site_uuid, 0 if shared else plan.index + 1, 0 if shared else minor
            if rng.random() < 0.1:
                uuid, major, mn = foreign_uuid, int(rng.integers(1, 65535)), int(
                    rng.integers(1, 65535))
            out.append(Beacon(_mac(rng, "e0:78:a3").upper(), uuid, major, mn,
                              int(rng.integers(-59, -55)), plan.index, round(float(p.x), 3),
                              round(float(p.y), 3), round(float(rng.uniform(2.0, 2.6)), 3),
                              3.0, child_seed(seed, "shadow", "ble", len(out))))
        pts = rng.uniform([0, 0], [plan.width_m, plan.height_m],
                          size=(4 * params.n_ble_others_per_floor, 2))
        ok = plan.is_walkable(pts[:, 0], pts[:, 1])
        for x, y in pts[ok][:params.n_ble_others_per_floor]:
            kind = rng.random()
            major, mn = (0, 0) if kind < 0.6 else (int(rng.integers(1, 65535)),
                                                   int(rng.integers(1, 65535)))
            out.append(Beacon(_mac(rng).upper(), "", major, mn, int(rng.integers(-70, -58)),
                              plan.index, round(float(x), 3), round(float(y), 3),
                              round(float(rng.uniform(2.0, 3.0)), 3), 4.0,
                              child_seed(seed, "shadow", "ble", len(out))))
    return out


def beacon_distance_m(rssi_dbm: np.ndarray, tx_power_dbm: np.ndarray) -> np.ndarray:
    """The distance estimate the logging app writes (AltBeacon's Android formula)."""
    ratio = np.asarray(rssi_dbm, dtype=np.float64) / np.asarray(tx_power_dbm, dtype=np.float64)
    return np.where(ratio < 1.0, ratio ** 10, 0.89976 * ratio ** 7.7095 + 0.111)


def _shadow_features(seeds: list[int], lengths: np.ndarray, k: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    w = np.empty((len(seeds), k, 2))
    b = np.empty((len(seeds), k))
    for i, (s, ln) in enumerate(zip(seeds, lengths)):
        r = np.random.default_rng(s)
        w[i] = r.normal(0.0, 1.0 / ln, (k, 2))
        b[i] = r.uniform(0.0, 2.0 * np.pi, k)
    return w, b


class RadioEnvironment:
    """Mean RSSI of every transmitter anywhere on the site (reference phone).

    Parameters
    ----------
    plans : list of Floorplan
        Floors, indexed by :attr:`Floorplan.index`.
    aps : list of AccessPoint
    beacons : list of Beacon
    params : RadioParams
    raster_m : float
        Cell size of the wall raster used to count wall crossings (m).
    """

    def __init__(self, plans: list[Floorplan], aps: list[AccessPoint], beacons: list[Beacon],
                 params: RadioParams, raster_m: float = 0.25) -> None:
        self.plans = {p.index: p for p in plans}
        self.aps = aps
        self.beacons = beacons
        self.params = params
        self.raster_m = raster_m
        k = params.shadow_features
        self._ap_xy = np.array([[a.x_m, a.y_m] for a in aps]).reshape(-1, 2)
        self._ap_floor = np.array([a.floor for a in aps], dtype=np.int64)
        self._ap_p0 = np.array([a.p0_dbm for a in aps])
        self._ap_n = np.array([a.n_exp for a in aps])
        self._ap_sd = np.array([a.shadow_sd_db for a in aps])
        self._ap_w, self._ap_b = _shadow_features([a.shadow_seed for a in aps],
                                                  np.array([a.shadow_len_m for a in aps]), k)
        self._bl_xy = np.array([[b.x_m, b.y_m] for b in beacons]).reshape(-1, 2)
        self._bl_floor = np.array([b.floor for b in beacons], dtype=np.int64)
        self._bl_tx = np.array([b.tx_power_dbm for b in beacons], dtype=np.float64)
        self._bl_n = np.array([b.n_exp for b in beacons])
        self._bl_sd = np.array([b.shadow_sd_db for b in beacons])
        self._bl_w, self._bl_b = _shadow_features([b.shadow_seed for b in beacons],
                                                  np.full(len(beacons), 3.0), k)
        self._rasters: dict[int, np.ndarray] = {}

    def _raster(self, floor: int) -> np.ndarray:
        if floor not in self._rasters:
            plan = self.plans[floor]
            nx = int(np.ceil(plan.width_m / self.raster_m))
            ny = int(np.ceil(plan.height_m / self.raster_m))
            cx = (np.arange(nx) + 0.5) * self.raster_m
            cy = (np.arange(ny) + 0.5) * self.raster_m
            gx, gy = np.meshgrid(cx, cy)
            self._rasters[floor] = plan.obstacle_labels(gx, gy)
        return self._rasters[floor]

    def wall_crossings(self, floor: int, xy_m: np.ndarray, tx_xy_m: np.ndarray,
                       n_samples: int | None = None) -> np.ndarray:
        """Number of shop walls on the straight line from each point to each transmitter.

        Parameters
        ----------
        floor : int
        xy_m : numpy.ndarray, shape (n, 2)
        tx_xy_m : numpy.ndarray, shape (a, 2)

        Returns
        -------
        numpy.ndarray, shape (n, a), int
        """
        plan = self.plans[floor]
        lab = self._raster(floor)
        ny, nx = lab.shape
        if n_samples is None:
            n_samples = int(np.ceil(np.hypot(plan.width_m, plan.height_m) / 0.4)) + 2
        u = np.linspace(0.0, 1.0, n_samples)
        out = np.zeros((len(xy_m), len(tx_xy_m)), dtype=np.int64)
        for a0 in range(0, len(xy_m), 64):
            p = xy_m[a0:a0 + 64, None, None, :]
            q = tx_xy_m[None, :, None, :]
            pts = p + (q - p) * u[None, None, :, None]           # (c, a, s, 2)
            ix = np.clip((pts[..., 0] / self.raster_m).astype(np.int64), 0, nx - 1)
            iy = np.clip((pts[..., 1] / self.raster_m).astype(np.int64), 0, ny - 1)
            labels = lab[iy, ix]
            out[a0:a0 + 64] = np.count_nonzero(labels[..., 1:] != labels[..., :-1], axis=-1)
        return out

    def _mean(self, floor: int, xy_m: np.ndarray, tx_xy: np.ndarray, tx_floor: np.ndarray,
              p0: np.ndarray, n_exp: np.ndarray, sd: np.ndarray, w: np.ndarray, b: np.ndarray,
              tx_height: float, walls: bool) -> np.ndarray:
        prm = self.params
        xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        d_xy = xy[:, None, :] - tx_xy[None, :, :]
        dz = (tx_floor[None, :] - floor) * prm.floor_height_m + (tx_height - prm.phone_height_m)
        d = np.sqrt(np.sum(d_xy ** 2, axis=-1) + dz ** 2)
        rssi = p0[None, :] - 10.0 * n_exp[None, :] * np.log10(np.maximum(d, 1.0))
        rssi = rssi - np.abs(tx_floor[None, :] - floor) * prm.floor_loss_db
        phase = np.einsum("nd,akd->nak", xy, w) + b[None, :, :]
        k = w.shape[1]
        rssi = rssi + sd[None, :] * np.sqrt(2.0 / k) * np.cos(phase).sum(axis=-1)
        if walls and prm.wall_loss_db > 0:
            same = tx_floor == floor
            if same.any():
                rssi[:, same] -= prm.wall_loss_db * self.wall_crossings(floor, xy, tx_xy[same])
        return rssi

    def ap_rssi_dbm(self, floor: int, xy_m: np.ndarray) -> np.ndarray:
        """Mean RSSI (dBm, reference phone, no fading) of every access point, shape (n, A)."""
        return self._mean(floor, xy_m, self._ap_xy, self._ap_floor, self._ap_p0, self._ap_n,
                          self._ap_sd, self._ap_w, self._ap_b, self.params.ap_height_m, True)

    def beacon_rssi_dbm(self, floor: int, xy_m: np.ndarray) -> np.ndarray:
        """Mean RSSI (dBm) of every BLE transmitter, shape (n, B); tx power is the RSSI at 1 m."""
        return self._mean(floor, xy_m, self._bl_xy, self._bl_floor, self._bl_tx, self._bl_n,
                          self._bl_sd, self._bl_w, self._bl_b, 1.0, False)

    def to_dict(self) -> dict:
        """Access points, beacons and parameters (JSON-able)."""
        return {"params": asdict(self.params),
                "model": "rssi = p0 - 10 n log10(max(d,1)) - walls*wall_loss - |dfloor|*floor_loss"
                         " + shadow; shadow = sd*sqrt(2/K)*sum(cos(w.x+b)), w ~ N(0, 1/len^2),"
                         " b ~ U(0, 2pi), drawn from default_rng(shadow_seed) (w then b)",
                "access_points": [asdict(a) for a in self.aps],
                "beacons": [asdict(b) for b in self.beacons]}


def scan_times_ms(t_first_ms: int, t_last_ms: int, params: RadioParams,
                  rng: np.random.Generator) -> np.ndarray:
    """Scan completion times covering ``warmup_s`` before ``t_first_ms`` up to ``t_last_ms``."""
    lo, hi = params.scan_period_s
    span = (t_last_ms - t_first_ms) / 1000.0 + params.warmup_s
    n = int(np.ceil(span / lo)) + 2
    periods = np.round(rng.uniform(lo, hi, n) * 1000.0).astype(np.int64)
    first = t_first_ms + int(rng.integers(300, 2000))
    back = first - np.cumsum(periods[: int(np.ceil(params.warmup_s / lo)) + 1])[::-1]
    fwd = first + np.concatenate([[0], np.cumsum(periods)])
    t = np.concatenate([back[back >= t_first_ms - params.warmup_s * 1000], fwd])
    return t[t <= t_last_ms]


def simulate_wifi(env: RadioEnvironment, kin: WalkKinematics, floor: int, device: Device,
                  rng: np.random.Generator) -> pd.DataFrame:
    """Wi-Fi rows of a walk, in file order (by scan time, strongest first).

    Returns
    -------
    pandas.DataFrame
        Columns :data:`~survey.trace_format.WIFI_COLUMNS`.
    """
    prm = env.params
    n_ap = len(env.aps)
    t0, t1 = int(kin.t_ms[0]), int(kin.t_ms[-1])
    scans = scan_times_ms(t0, t1, prm, rng)
    if n_ap == 0 or len(scans) == 0:
        return empty_table(WIFI_COLUMNS, WIFI_DTYPES)
    freqs = np.array([a.freq_mhz for a in env.aps])
    chan_rank = np.argsort(np.argsort(freqs, kind="stable"), kind="stable") / max(n_ap - 1, 1)
    obs_offset_ms = np.round((chan_rank - 1.0) * prm.sweep_s * 1000.0).astype(np.int64)
    obs_ms = scans[:, None] + obs_offset_ms[None, :]                  # (S, A)
    mid_ms = scans - int(prm.sweep_s * 500)
    xy = kin.position_at(mid_ms)
    rssi_ref = env.ap_rssi_dbm(floor, xy) + rng.normal(0.0, prm.fading_sd_db, (len(scans), n_ap))
    rssi = np.round(distort_rssi(rssi_ref, device)).astype(np.int64)
    rssi = np.clip(rssi, -127, -1)
    weak, strong = prm.miss_prob[1], prm.miss_prob[0]
    p_miss = np.interp(rssi, [-92.0, -65.0], [weak, strong])
    detected = (rssi >= prm.detect_dbm) & (rng.random(rssi.shape) >= p_miss)
    idx = np.where(detected, np.arange(len(scans))[:, None], -1)
    last = np.maximum.accumulate(idx, axis=0)                          # (S, A)

    report = scans >= t0
    s_idx, a_idx = np.nonzero(last[report] >= 0)
    s_idx = np.flatnonzero(report)[s_idx]
    li = last[s_idx, a_idx]
    seen = obs_ms[li, a_idx]
    keep = (scans[s_idx] - seen) <= prm.cache_s * 1000.0
    s_idx, a_idx, li, seen = s_idx[keep], a_idx[keep], li[keep], seen[keep]
    vals = rssi[li, a_idx]

    dup = rng.random(len(s_idx)) < prm.duplicate_share
    if dup.any():
        extra_seen = seen[dup] - np.round(rng.uniform(0.5, 6.0, dup.sum()) * 1000).astype(np.int64)
        extra_rssi = np.clip(vals[dup] + rng.integers(-4, 5, dup.sum()),
                             int(np.ceil(prm.detect_dbm)), -1)
        s_idx = np.concatenate([s_idx, s_idx[dup]])
        a_idx = np.concatenate([a_idx, a_idx[dup]])
        seen = np.concatenate([seen, extra_seen])
        vals = np.concatenate([vals, extra_rssi])

    scan_t = scans[s_idx]
    order = np.lexsort((a_idx, -vals, scan_t))
    bssid = np.array([a.bssid for a in env.aps], dtype=object)
    ssid = np.array([a.ssid for a in env.aps], dtype=object)
    df = pd.DataFrame({
        "scan_t_ms": scan_t[order].astype(np.int64),
        "ssid": pd.array(ssid[a_idx[order]], dtype="str"),
        "bssid": pd.array(bssid[a_idx[order]], dtype="str"),
        "rssi_dbm": vals[order].astype(np.int16),
        "freq_mhz": freqs[a_idx[order]].astype(np.int32),
        "last_seen_ms": seen[order].astype(np.int64),
    })
    df["age_ms"] = (df["scan_t_ms"] - df["last_seen_ms"]).astype(np.int64)
    return df[list(WIFI_COLUMNS)].reset_index(drop=True)


def simulate_ble(env: RadioEnvironment, kin: WalkKinematics, floor: int,
                 rng: np.random.Generator) -> tuple[pd.DataFrame, list[str]]:
    """iBeacon rows (:data:`~survey.trace_format.BLE_COLUMNS`, by time) and the undocumented
    ``TYPE_BLUE`` / ``TYPE_BLU4`` line pairs of a walk."""
    prm = env.params
    t0, t1 = int(kin.t_ms[0]), int(kin.t_ms[-1])
    dur_s = (t1 - t0) / 1000.0
    on_floor = [i for i, b in enumerate(env.beacons) if b.floor == floor]
    rows: list[pd.DataFrame] = []
    raw_t: list[np.ndarray] = []
    raw_i: list[np.ndarray] = []
    raw_r: list[np.ndarray] = []
    for kind, rate in (("beacon", prm.beacon_rate_hz), ("raw", prm.ble_raw_rate_hz)):
        counts = rng.poisson(rate * dur_s, len(on_floor))
        tx_i = np.repeat(np.asarray(on_floor, dtype=np.int64), counts)
        if kind == "beacon":
            keep = np.array([env.beacons[i].uuid != "" for i in tx_i], dtype=bool)
            tx_i = tx_i[keep]
        t = np.round(rng.uniform(t0, t1, len(tx_i))).astype(np.int64)
        if len(t) == 0:
            continue
        xy = kin.position_at(t)
        mean = env.beacon_rssi_dbm(floor, xy)[np.arange(len(t)), tx_i]
        rssi = np.round(mean + rng.normal(0.0, 3.0, len(t))).astype(np.int64)
        ok = (rssi >= prm.beacon_detect_dbm) & (rssi <= -20)
        t, tx_i, rssi = t[ok], tx_i[ok], rssi[ok]
        if kind == "raw":
            raw_t.append(t), raw_i.append(tx_i), raw_r.append(rssi)
            continue
        b = [env.beacons[i] for i in tx_i]
        tx = np.array([x.tx_power_dbm for x in b], dtype=np.int64)
        df = pd.DataFrame({
            "t_ms": t, "uuid": pd.array([x.uuid for x in b], dtype="str"),
            "major": np.array([x.major for x in b], dtype=np.int32),
            "minor": np.array([x.minor for x in b], dtype=np.int32),
            "key": pd.array([f"{x.uuid}:{x.major}:{x.minor}" for x in b], dtype="str"),
            "tx_power_dbm": tx.astype(np.int16), "rssi_dbm": rssi.astype(np.int16),
            "distance_m": beacon_distance_m(rssi, tx),
            "mac": pd.array([x.mac for x in b], dtype="str"), "last_seen_ms": t})
        rows.append(df)
    if rows:
        ble = pd.concat(rows, ignore_index=True)
        ble = ble.sort_values(["t_ms", "mac"], kind="stable").reset_index(drop=True)
        ble = ble.astype({k: v for k, v in BLE_DTYPES.items()})
    else:
        ble = empty_table(BLE_COLUMNS, BLE_DTYPES)
    lines: list[str] = []
    if raw_t:
        t = np.concatenate(raw_t)
        i = np.concatenate(raw_i)
        r = np.concatenate(raw_r)
        for k in np.lexsort((i, t)):
            b = env.beacons[int(i[k])]
            lines.append(f"{int(t[k])}\tTYPE_BLUE\t\t{b.mac}\t{int(r[k])}")
            lines.append(f"{int(t[k])}\tTYPE_BLU4\t{b.major}\t{b.minor}\t{int(r[k])}")
    return ble[list(BLE_COLUMNS)], lines
