"""A small simulated floor for the validation tests, clean or with three deliberate problems.

``clean_site(dir)`` simulates one 50 x 24 m floor with two east-west and two north-south
corridors, walked by 10 walks of two phones (one calibration session each), so that every
corridor is walked several times. ``spoil_site(clean, dir)`` copies it and makes:

1. an **offset walk**: a constant (6, -5, 10) uT added to the x, y, z of every calibrated and
   uncalibrated magnetometer row of one walk (the phone's reported bias left alone, so the walk
   stays in its calibration session with the other walks of that phone and levelling cannot
   absorb the offset);
2. a **wrong waypoint**: one middle waypoint of another walk moved by 6 m along its corridor;
3. a **corridor never walked**: a 2.2 m wide east-west corridor cut through a shop block in the
   floor plan (GeoJSON), from one north-south corridor to the next; no walk enters it.

``build(site_dir, work_dir)`` ingests, processes and builds the floor bundle (returns bundle and
store paths).
"""

from __future__ import annotations

import gzip
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import shapely
from shapely.geometry import box, mapping, shape

from survey.sim.site import SiteParams, simulate_site

SEED = 4
OFFSET_UT = (6.0, -5.0, 10.0)
WAYPOINT_SHIFT_M = 6.0


def site_params(seed: int = SEED) -> SiteParams:
    return SiteParams.preset_params(
        "sample", seed=seed, n_floors=1, width_m=50.0, height_m=24.0,
        ew_corridor_widths_m=(2.5, 2.0), ns_corridor_widths_m=(2.5, 2.0), walks_per_floor=10,
        walk_duration_s=(45.0, 60.0), sessions_per_device=1, walks_without_wifi=0)


def clean_site(out: Path, seed: int = SEED) -> Path:
    simulate_site(site_params(seed), out, overwrite=True)
    return out


@dataclass
class Spoiled:
    site: Path
    offset_walk: str
    waypoint_walk: str
    waypoint_index: int
    waypoint_from: tuple[float, float]
    waypoint_to: tuple[float, float]
    corridor_m: tuple[float, float, float, float]  # x0, y0, x1, y1 of the carved corridor


def _rewrite_trace(path: Path, edit) -> None:
    lines = gzip.decompress(path.read_bytes()).decode("utf-8").split("\n")
    path.write_bytes(gzip.compress("\n".join(edit(lines)).encode("utf-8"), mtime=0))


def _fmt(v: float) -> str:
    return f"{v:.4f}"


def spoil_site(clean: Path, out: Path) -> Spoiled:
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(clean, out)
    truth = json.loads((out / "truth" / "site.json").read_text())
    floor = truth["floors"][0]
    walks = [w for w in truth["walks"] if w["floor"] == floor["name"]]
    by_session: dict[str, list[dict]] = {}
    for w in walks:
        by_session.setdefault(w["session_id"], []).append(w)
    # 1. offset walk: the longest walk of the largest session (others keep the session anchored)
    session = max(by_session, key=lambda s: len(by_session[s]))
    offset_walk = max(by_session[session], key=lambda w: w["length_m"])

    def add_offset(lines):
        out_lines = []
        for line in lines:
            f = line.split("\t")
            if len(f) > 4 and f[1] in ("TYPE_MAGNETIC_FIELD", "TYPE_MAGNETIC_FIELD_UNCALIBRATED"):
                for k in range(3):
                    f[2 + k] = _fmt(float(f[2 + k]) + OFFSET_UT[k])
                line = "\t".join(f)
            out_lines.append(line)
        return out_lines

    _rewrite_trace(out / offset_walk["trace_path"], add_offset)
    # 2. wrong waypoint: a middle waypoint of another walk (of the other session), moved 6 m
    # along the reachable area
    from mapping.floorplan import read_floor_plan

    plan = read_floor_plan(out / floor["name"])
    reach = plan.reachable
    other = [w for w in walks if w["session_id"] != session] or \
        [w for w in walks if w is not offset_walk]
    wp_walk = max(other, key=lambda w: w["n_waypoints"])
    state: dict = {}

    def move_waypoint(lines):
        idx = [i for i, ln in enumerate(lines) if "\tTYPE_WAYPOINT\t" in ln]
        k = len(idx) // 2
        f = lines[idx[k]].split("\t")
        x, y = float(f[2]), float(f[3])
        for dx, dy in ((WAYPOINT_SHIFT_M, 0), (-WAYPOINT_SHIFT_M, 0), (0, WAYPOINT_SHIFT_M),
                       (0, -WAYPOINT_SHIFT_M)):
            p = shapely.Point(x + dx, y + dy)
            if reach.buffer(-0.5).contains(p):
                break
        else:
            raise RuntimeError("no place to move the waypoint to")
        f[2], f[3] = _fmt(x + dx), _fmt(y + dy)
        lines = list(lines)
        lines[idx[k]] = "\t".join(f)
        state.update(index=k, src=(x, y), dst=(x + dx, y + dy))
        return lines

    _rewrite_trace(out / wp_walk["trace_path"], move_waypoint)
    # 3. a corridor never walked: east-west through the widest block between two
    # north-south corridors (or a corridor and the outline), in the middle of the band
    # between two east-west corridors
    corr = floor["corridors"]
    width, height = floor["width_m"], floor["height_m"]

    def gaps(orientation, extent):
        cs = sorted((c["center_m"] - c["width_m"] / 2, c["center_m"] + c["width_m"] / 2)
                    for c in corr if c["orientation"] == orientation)
        edges = [0.0] + [v for c in cs for v in c] + [extent]
        return [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]

    xg = max(gaps("ns", width)[1:-1] or gaps("ns", width), key=lambda g: g[1] - g[0])
    yg = max(gaps("ew", height)[1:-1] or gaps("ew", height), key=lambda g: g[1] - g[0])
    ym = (yg[0] + yg[1]) / 2
    strip = (xg[0] - 0.3, ym - 1.1, xg[1] + 0.3, ym + 1.1)
    geo_path = out / floor["name"] / "geojson_map.json"
    geo = json.loads(geo_path.read_text())
    outline = shape(geo["features"][0]["geometry"])
    lon0, lat0, lon1, lat1 = outline.bounds
    sx, sy = (lon1 - lon0) / width, (lat1 - lat0) / height
    cut = box(lon0 + strip[0] * sx, lat0 + strip[1] * sy, lon0 + strip[2] * sx,
              lat0 + strip[3] * sy)
    feats = [geo["features"][0]]
    for f in geo["features"][1:]:
        g = shape(f["geometry"]).difference(cut)
        if not g.is_empty:
            feats.append({**f, "geometry": mapping(g)})
    geo["features"] = feats
    geo_path.write_text(json.dumps(geo))
    return Spoiled(out, offset_walk["trace_id"], wp_walk["trace_id"], state["index"],
                   state["src"], state["dst"], strip)


def build(site: Path, work: Path, floor: str = "F1") -> tuple[Path, Path]:
    """Ingest, process and build the floor; returns (bundle, store)."""
    from mapping.build import build_floor
    from mapping.bundle_writer import write_bundle
    from mapping.floorplan import read_floor_plan
    from survey.ingest import ingest
    from survey.process_store import process_store

    store = work / "store"
    ingest([site / floor / "path_data_files"], store)
    plan = read_floor_plan(site / floor)
    from survey.store import SurveyStore

    st = SurveyStore.open(store)
    cat = st.catalog()
    process_store(st, reachable={(s, f): plan.reachable for s, f in
                                 cat[["site", "floor"]].drop_duplicates().itertuples(index=False)})
    bundle = work / "bundle"
    write_bundle(bundle, build_floor(st, plan, floor=floor), overwrite=True)
    return bundle, store


