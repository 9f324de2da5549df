"""Speed of the localizer: per-step update time and users per core.

Prints

1. the per-step weight-update time (map lookups + matching + weights) and the full filter step
   (motion, update, resampling, estimate) for N = 300, 1000, 3000 particles, for the
   mass-centered update (papers 000/001) and the Magicol-style DTW update over the raw
   magnetometer samples of the step (100 Hz, 0.67 s step period: 67 samples), and their ratio
   (paper 001: 4.4 ms at N = 300, 18x faster than DTW);
2. users per CPU core of the multi-user engine at N = 300 and a 0.67 s step period (paper 001:
   130 users per core), with the particle memory per user;
3. the real-time walk alignment (``localize.align.WalkAligner``, what ``--method auto`` runs
   on a floor whose magnetic map does not predict held-out walks, as on the real mall): CPU
   time per step over walks of 1-4 minutes with a radio fix every third step (the search
   aligns the last 120 s again at every step), against the filter's full step at N = 300 in
   the same run, and users per core if one user's alignment took a core's share;
4. the multi-user alignment (``localize.align_engine.MultiUserAligner``), and the filter
   engine guided by it (``FilterParams(radio_guide="align")``: ``auto`` on a floor with a good
   magnetic map), in their steady state: users on 2.5-minute loop walks (past the 120 s
   window, so old steps are being forgotten), CPU per tick of all of them, users per core at
   a 0.67 s step period, and the Python memory per user (``tracemalloc``).

Everything runs in this process on one core (BLAS threads pinned to 1) on a synthetic floor
bundle of 80 x 50 m (0.25 m cells, a corridor grid, a smooth random field). Timings are the
median over repeats; the machine's load average is printed with them, since other processes
slow numpy down alike for both methods. Times are CPU time of this process
(``time.process_time``), the median over repeats.

Usage: ``python benchmarks/localize_speed.py [--quick]``
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import gc
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from localize.align import WalkAligner
from localize.align_engine import MultiUserAligner
from localize.bundle import Grid, load_bundle
from localize.engine import MultiUserEngine
from localize.filter import Localizer
from localize.params import FilterParams
from localize.maps import FilterMap
from localize.particles import needed_layers, observe
from localize.stepper import StepInputs
from localize.steps import AttitudeCode, RadioScan, StepSummary
from localize.update import magnetic_update
from mapping.bundle_writer import BundleContent, Layer, write_bundle

STEP_PERIOD_S = 0.67
MAG_RATE_HZ = 100.0


def synthetic_bundle(path: Path, seed: int = 0) -> None:
    """An 80 x 50 m floor: corridors 2.5 m wide every 10 m, a smooth field of ~6 uT SD."""
    g = Grid(0.0, 0.0, 0.25, 320, 200)
    xc, yc = g.cell_centers()
    gx, gy = np.meshgrid(xc, yc)
    mask = ((gx % 10.0) < 2.5) | ((gy % 10.0) < 2.5)
    rng = np.random.default_rng(seed)
    field = np.full(g.shape, 45.0)
    for _ in range(40):
        k = rng.normal(0, 0.6, 2)
        field += rng.normal(0, 1.4) * np.cos(k[0] * gx + k[1] * gy + rng.uniform(0, 6.3))
    polar = 133.0 + 0.2 * (field - 45.0)
    offset = 8.0 * np.sin(gx / 7.0) * np.cos(gy / 5.0)

    def lay(v, unit, kind="scalar"):
        v = np.where(mask, v, np.nan).astype(np.float32)
        return Layer(v, np.where(mask, 1.0, np.nan).astype(np.float32), unit, kind)

    layers = {"strength": lay(field, "uT"), "polar": lay(polar, "deg"),
              "azimuth": lay(np.zeros(g.shape), "deg", "angle"),
              "heading_offset": lay(np.mod(offset, 360.0), "deg", "angle")}
    write_bundle(path, BundleContent("bench-site", "bench-floor", "F1", grid=g, mask=mask,
                                     layers=layers))


def steps_along_corridor(bundle, n_steps: int, seed: int = 0) -> list[StepSummary]:
    """A walk east along the corridor at y = 1.25 m, 0.65 m steps every 0.67 s, with the
    field of the map plus noise, 67 raw magnetometer samples per step."""
    rng = np.random.default_rng(seed)
    out = []
    m = round(STEP_PERIOD_S * MAG_RATE_HZ)
    for i in range(n_steps):
        x0, x1 = 1.0 + 0.65 * i, 1.0 + 0.65 * (i + 1)
        xs = np.linspace(x0, x1, m) % 78.0
        raw = bundle.sample("strength", xs, np.full(m, 1.25)) + rng.normal(0, 0.6, m)
        s = float(np.nanmean(raw))
        off = float(bundle.sample("heading_offset", [x1 % 78.0], [1.25])[0])
        out.append(StepSummary(
            t_ms=1e12 + 670.0 * i, frequency_hz=1.5, delta_acc_ms2=3.0,
            compass_deg=(90.0 + off + rng.normal(0, 3)) % 360.0, turn_deg=0.0,
            strength_ut=s, azimuth_deg=0.0, polar_deg=133.0 + 0.2 * (s - 45.0),
            attitude=int(AttitudeCode.UFH), mag_strength_ut=np.nan_to_num(raw, nan=45.0)))
    return out


def _median_time(fn, repeats: int) -> float:
    """Median CPU time of this process per call (s): what "per core" means, and less
    sensitive than wall time to other processes competing for the CPUs."""
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return float(np.median(times))


#: The paper's full mass-centered update: strength, azimuth and polar angle (001 eq. 12).
ALL_FEATURES = {"strength": {"enabled": True}, "azimuth": {"enabled": True},
                "polar": {"enabled": True}}


def per_step_times(bundle, n: int, mode: str, steps: list[StepSummary], repeats: int,
                   features: dict | None = None) -> tuple[float, float]:
    """(weight update, full step) seconds per step with ``n`` particles."""
    p = FilterParams(n_particles=n, weight_mode=mode, radio_update=False,
                     radio_inject_fraction=0.0, n_particles_start=0)
    if features:
        p = p.with_features(**features)
    loc = Localizer(bundle, p, rng=0)
    loc.start(1.0, 1.25)
    for s in steps[:6]:  # fill the windows
        loc.step(s)
    st, fm = loc.state, loc.fmap
    s = steps[6]
    att = np.array([s.attitude])

    def update():
        st.w = 1.0
        observe(st, fm, p, {"strength": np.array([s.strength_ut]),
                            "azimuth": np.array([s.azimuth_deg]),
                            "polar": np.array([s.polar_deg])})
        magnetic_update(st, fm, p, att, s.mag_strength_ut)

    t_update = _median_time(update, repeats)
    loc2 = Localizer(bundle, p, rng=0)
    loc2.start(1.0, 1.25)
    it = iter(steps * 10)
    t_step = _median_time(lambda: loc2.step(next(it)), repeats)
    return t_update, t_step


def engine_users_per_core(bundle, users: int, ticks: int, dtype, fix_every: int = 0
                          ) -> tuple[float, float, float]:
    """(tick seconds, users per core at the step period, bytes per user).

    Users walk east or west along the east-west corridors (0.62 m steps), their observed
    strength is the map's at their true position plus noise. With ``fix_every`` > 0 every
    user also gets a radio fix (true position plus 4 m noise per axis) at one tick in
    ``fix_every``, staggered across users (a Wi-Fi scan every 2 s is one step in three)."""
    p = FilterParams(n_particles=300, n_particles_start=0)
    eng = MultiUserEngine(bundle, p, rng=0, dtype=dtype)
    rng = np.random.default_rng(1)
    x = rng.uniform(15.0, 65.0, users)
    y = 10.0 * rng.integers(0, 5, users) + 1.25
    east = rng.random(users) < 0.5
    eng.add_users(np.column_stack([x, y]))
    off = bundle.sample("heading_offset", x, y)

    phase = np.arange(users) % max(fix_every, 1)
    count = [0]

    def tick():
        nonlocal x
        x = x + np.where(east, 0.62, -0.62)
        fixes = None
        if fix_every:
            has = phase == count[0] % fix_every
            count[0] += 1
            fixes = np.where(has[:, None], np.column_stack([x, y])
                             + rng.normal(0, 4, (users, 2)), np.nan)
        inp = StepInputs(compass_deg=(np.where(east, 90.0, 270.0) + off
                                      + rng.normal(0, 3, users)) % 360.0,
                         frequency_hz=np.full(users, 1.6), turn_deg=np.zeros(users),
                         strength_ut=bundle.sample("strength", x, y) + rng.normal(0, 0.6, users),
                         azimuth_deg=np.zeros(users), polar_deg=np.full(users, 133.0),
                         attitude=np.full(users, int(AttitudeCode.UFH)))
        eng.tick(None, inp, fixes)

    tick()
    t = _median_time(tick, ticks)
    return t, STEP_PERIOD_S / (t / users), eng.bytes_per_user


class _NoisyFixes:
    """A radio model for the alignment: each scan's fix is the walker's true position (the
    scan's keys hold its index) plus 3 m of noise per axis."""

    def __init__(self, truth_xy: np.ndarray, seed: int = 0) -> None:
        self.fixes = truth_xy + np.random.default_rng(seed).normal(0.0, 3.0, truth_xy.shape)

    def locate(self, scan: RadioScan) -> tuple[float, float, float]:
        x, y = self.fixes[int(scan.keys[0])]
        return float(x), float(y), 3.0


def loop_walk(n_steps: int, seed: int = 0) -> tuple[list[StepSummary], _NoisyFixes]:
    """Steps of 0.65 m every 0.67 s round the 30 x 10 m block between the corridors at
    y = 1.25 and 11.25 m and x = 1.25 and 31.25 m, compass and gyroscope headings with 3 deg
    of noise, a scan every third step; and the radio model that locates those scans."""
    rng = np.random.default_rng(seed)
    corners = np.array([1.25 + 1.25j, 31.25 + 1.25j, 31.25 + 11.25j, 1.25 + 11.25j])
    legs = np.abs(np.diff(np.append(corners, corners[0])))
    at = np.mod(0.65 * np.arange(1, n_steps + 1), legs.sum())
    leg = np.searchsorted(np.cumsum(legs), at, side="right")
    direction = (np.roll(corners, -1) - corners)[leg] / legs[leg]
    pos = corners[leg] + direction * (at - np.concatenate([[0.0], np.cumsum(legs)])[leg])
    heading = np.degrees(np.arctan2(direction.real, direction.imag)) % 360.0  # from north
    steps = []
    for i in range(n_steps):
        scan = (RadioScan(int(1e12 + 670 * i), np.array([str(i)]), np.array([-60.0]))
                if i % 3 == 0 else None)
        steps.append(StepSummary(
            t_ms=1e12 + 670.0 * i, frequency_hz=1.5, delta_acc_ms2=1.7 ** 4,
            compass_deg=float(heading[i] + rng.normal(0, 3)) % 360.0, turn_deg=0.0,
            strength_ut=45.0, azimuth_deg=0.0, polar_deg=133.0,
            attitude=int(AttitudeCode.UFH),
            relative_heading_deg=float(heading[i] + rng.normal(0, 3)), scan=scan))
    return steps, _NoisyFixes(np.column_stack([pos.real, pos.imag]), seed)


def align_step_time(bundle, n_steps: int, repeats: int) -> float:
    """CPU seconds per step of the real-time alignment over a :func:`loop_walk` of
    ``n_steps`` (median over ``repeats`` walks)."""
    steps, radio = loop_walk(n_steps)

    def walk():
        loc = WalkAligner(bundle, radio=radio)
        loc.start(*radio.locate(steps[0].scan)[:2])
        for s in steps:
            loc.step(s)

    walk()  # the bundle's wall tables, once
    return _median_time(walk, repeats) / n_steps


def align_engine_users_per_core(bundle, users: int, warm_steps: int, ticks: int,
                                guided: bool = False) -> tuple[float, float, float]:
    """Seconds of CPU per tick of ``users`` on :func:`loop_walk` walks (one seed each) after
    ``warm_steps`` ticks, users per core at :data:`STEP_PERIOD_S`, and bytes per user of
    Python memory after the warm-up (traced on a quarter of the users, at least 10): of a
    :class:`MultiUserAligner`, or with ``guided`` of a :class:`MultiUserEngine` whose filters
    (N = 300, float32) are guided by the users' alignments (``radio_guide="align"``)."""
    n = warm_steps + ticks
    walks = [loop_walk(n, seed=u) for u in range(users)]
    cols = ("compass_deg", "frequency_hz", "turn_deg", "strength_ut", "azimuth_deg",
            "polar_deg", "attitude", "relative_heading_deg", "delta_acc_ms2")
    inputs = [StepInputs(*(np.array([getattr(w[0][i], c) for w in walks]) for c in cols))
              for i in range(n)]
    fix_xy = np.stack([w[1].fixes for w in walks], axis=1)  # (steps, users, 2)
    fix_xy[np.arange(n) % 3 != 0] = np.nan
    t = np.array([w[0][0].t_ms for w in walks])  # the same times for every user

    params = FilterParams(n_particles=300, n_particles_start=0, radio_guide="align")
    fmap = FilterMap(bundle, *needed_layers(params))  # shared by the users of a floor

    def start(k):
        if not guided:
            eng = MultiUserAligner(bundle)
            return eng, eng.add_users(fix_xy[0, :k], t[:k] - 670.0, sigma_m=3.0)
        eng = MultiUserEngine(bundle, params, rng=0, dtype=np.float32, fmap=fmap)
        return eng, eng.add_users(fix_xy[0, :k], fix_sigma_m=np.full(k, 3.0),
                                  t_ms=t[:k] - 670.0)

    def run(eng, ids, i0, i1):  # ticks i0..i1-1 of the users ids (the first ones)
        k = len(ids)
        for i in range(i0, i1):
            step = StepInputs(*(np.asarray(getattr(inputs[i], c))[:k] for c in cols))
            if guided:
                eng.tick(ids, step, fix_xy[i, :k], t_ms=t[:k] + 670.0 * i)
            else:
                eng.tick(ids, t[:k] + 670.0 * i, step, fix_xy_m=fix_xy[i, :k])

    traced = max(10, users // 4)
    eng, ids = start(traced)  # once untraced: the shared wall tables, one-time caches
    run(eng, ids, 0, 10)
    gc.collect()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    eng, ids = start(traced)
    run(eng, ids, 0, warm_steps)
    gc.collect()
    per_user = (tracemalloc.get_traced_memory()[0] - before) / traced
    tracemalloc.stop()
    eng, ids = start(users)
    run(eng, ids, 0, warm_steps)
    c0 = time.process_time()
    run(eng, ids, warm_steps, n)
    tick = (time.process_time() - c0) / ticks
    return tick, STEP_PERIOD_S / (tick / users), per_user


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats (smoke test)")
    args = ap.parse_args(argv)
    repeats = 5 if args.quick else 25
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_bundle(Path(tmp) / "b")
        bundle = load_bundle(Path(tmp) / "b")
        steps = steps_along_corridor(bundle, 40)
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; "
              f"numpy {np.__version__}; one thread")
        print("\nPer-step update, one user (ms of CPU; median of "
              f"{repeats}; DTW over {len(steps[0].mag_strength_ut)} raw samples per step).")
        print("MC = mass-centered with the default features; MC3 = strength, azimuth and "
              "polar (001 eq. 12).")
        print("'update' = map lookups + matching + weights; 'step' = motion, update, "
              "resampling, estimate.")
        print(f"{'N':>6} {'MC update':>10} {'MC3 upd.':>9} {'DTW upd.':>9} {'ratio':>6} "
              f"{'ratio3':>6}   {'MC step':>8} {'DTW step':>9} {'ratio':>6}")
        for n in (300, 1000, 3000):
            mu, ms = per_step_times(bundle, n, "mass_centered", steps, repeats)
            m3, _ = per_step_times(bundle, n, "mass_centered", steps, repeats, ALL_FEATURES)
            du, ds = per_step_times(bundle, n, "dtw", steps, max(3, repeats // 5))
            print(f"{n:>6} {mu * 1e3:>10.3f} {m3 * 1e3:>9.3f} {du * 1e3:>9.2f} "
                  f"{du / mu:>5.0f}x {du / m3:>5.0f}x   {ms * 1e3:>8.3f} {ds * 1e3:>9.2f} "
                  f"{ds / ms:>5.0f}x")
        print(f"\nMulti-user engine, N = 300 particles per user, step period {STEP_PERIOD_S} s")
        print("(radio: none, or a fix for every user every third step, as Wi-Fi scans every "
              "2 s)")
        print(f"{'users':>7} {'dtype':>8} {'radio':>6} {'tick ms':>9} {'us/user-step':>13} "
              f"{'users/core':>11} {'KB/user':>8}")
        sizes = (300, 1000) if args.quick else (300, 1000, 3000)
        for users in sizes:
            for dtype, fix_every in ((np.float32, 0), (np.float32, 3), (np.float64, 0)):
                t, upc, b = engine_users_per_core(bundle, users, 5 if args.quick else 15,
                                                  dtype, fix_every)
                print(f"{users:>7} {np.dtype(dtype).name:>8} "
                      f"{'1/3' if fix_every else '-':>6} {t * 1e3:>9.1f} "
                      f"{t / users * 1e6:>13.1f} {upc:>11.0f} {b / 1024:>8.1f}")
        print(f"\n(map rasters are shared by all users of a floor: {bundle.grid.width} x "
              f"{bundle.grid.height} cells)")
        _, filter_step = per_step_times(bundle, 300, "mass_centered", steps, repeats)
        print("\nReal-time walk alignment, one user (a fix every third step; ms of CPU per "
              f"step, median of {max(3, repeats // 5)} walks), against the filter's full step "
              f"at N = 300 ({filter_step * 1e3:.3f} ms) in this run")
        print(f"{'steps':>7} {'minutes':>8} {'ms/step':>8} {'x filter':>9} {'users/core':>11}")
        for n_steps in (90, 180, 360):
            t = align_step_time(bundle, n_steps, max(3, repeats // 5))
            print(f"{n_steps:>7} {n_steps * STEP_PERIOD_S / 60:>8.1f} {t * 1e3:>8.2f} "
                  f"{t / filter_step:>8.1f}x {STEP_PERIOD_S / t:>11.0f}")
        warm = 220  # 2.5 minutes: the 120 s window is full and old steps are forgotten
        print(f"\nMulti-user alignment, steady state after {warm} steps of loop walks, a fix "
              "every third step: MultiUserAligner ('align'), and the filter engine guided by "
              "each user's alignment ('guided', N = 300 float32, auto on a good map)")
        print(f"{'users':>7} {'server':>8} {'tick ms':>9} {'us/user-step':>13} "
              f"{'users/core':>11} {'KB/user':>8}")
        for users in ((20,) if args.quick else (50, 200)):
            for guided in (False, True):
                t, upc, b = align_engine_users_per_core(bundle, users, warm,
                                                        5 if args.quick else 20, guided)
                print(f"{users:>7} {'guided' if guided else 'align':>8} {t * 1e3:>9.1f} "
                      f"{t / users * 1e6:>13.1f} {upc:>11.0f} {b / 1024:>8.1f}")


if __name__ == "__main__":
    main()
