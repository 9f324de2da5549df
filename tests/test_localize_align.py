"""Walk alignment (localize.align): the step track fitted to radio fixes and the walls."""

import re

import numpy as np
import pytest
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)

from localize.align import (AlignParams, WalkAligner, WallLookup, _fix_covariance, _Search,
                            distance_from_mask_m, walk_shape)
from localize.baselines import make_localizer
from localize.errors import LocalizationError
from localize.evaluate import step_errors

BIAS_M = 4.0


class _BiasedRadio:
    """Fixes at the walk's true position at each scan, shifted by one bias for the whole walk
    plus 1 m of noise: the correlated error that averaging fixes cannot remove."""

    def __init__(self, walk, angle_deg: float) -> None:
        self.truth = {id(s): xy for s, xy in zip(walk.steps.scans, walk.true_xy)
                      if s is not None}
        a = np.radians(angle_deg)
        self.bias = BIAS_M * np.array([np.cos(a), np.sin(a)])
        self.rng = np.random.default_rng(int(angle_deg))

    def locate(self, scan):
        x, y = self.truth[id(scan)] + self.bias + self.rng.normal(0.0, 1.0, 2)
        return float(x), float(y), 3.0


def _f1_with_scans(walks):
    return [w for w in walks if w.floor == "F1" and any(s is not None for s in w.steps.scans)]


def test_walls_remove_most_of_a_shared_radio_bias(f1_bundle, sim_walks):  # noqa: F811
    """Fixes 4 m off in one direction for a whole walk: shifting the track by its fixes
    would leave about 4 m. Offline, the walls bring it back to a pooled median per-step error
    below 2 m (about 1.75 m on these walks); in real time, below 3 m (about 2.8 m, the early
    steps having fewer walls behind them)."""
    offline, realtime = [], []
    for w in _f1_with_scans(sim_walks):
        for angle in (0, 90, 200, 300):
            for smooth, out in ((True, offline), (False, realtime)):
                track = WalkAligner(f1_bundle, radio=_BiasedRadio(w, angle)).run(
                    w.steps, smooth=smooth)
                assert track.info["smoothed"] is smooth
                out.append(step_errors(track, w.true_xy))
    assert np.median(np.concatenate(offline)) < 0.5 * BIAS_M
    assert np.median(np.concatenate(realtime)) < 0.75 * BIAS_M


def test_spread_is_the_alignment_uncertainty_not_its_grid(f1_bundle, sim_walks):  # noqa: F811
    """spread_m was the RMS of the finest search grid (+-1 step): about 0.5 m whatever the
    error, so on the real floors (where auto runs align) the error exceeded it at 99 % of
    waypoints. It is now the coarse grid's, which spans what the fixes and walls allow (on 15
    held-out real F1 walks: median 3.9 m for a median error of 4.4 m). With fixes 4 m off,
    the error stays within twice the spread; the search's own spread (what a guided filter
    weighs with) is kept apart."""
    errors, spreads = [], []
    for w in _f1_with_scans(sim_walks):
        loc = WalkAligner(f1_bundle, radio=_BiasedRadio(w, 90))
        track = loc.run(w.steps)
        errors.append(step_errors(track, w.true_xy))
        spreads.append(track.spread_m)
        assert 0 < loc.search_spread_m <= 1.0
    e, sp = np.concatenate(errors), np.concatenate(spreads)
    assert 1.0 < np.median(sp) < 6.0 and np.ptp(sp) > 1.0
    assert np.mean(e > 2 * sp) < 0.1


def test_share_wall_term_suits_precise_shapes(f1_bundle, sim_walks):  # noqa: F811
    """The simulated walks' shapes are within 0.14-0.41 m, so the share of the track on the
    mask (``wall_share_weight``) places them better than the squared distance, the default
    chosen on the real traces: offline, the same biased fixes as above end below 1.5 m
    (about 1.33 m) against about 1.75 m."""
    share = AlignParams(wall_weight=0.0, wall_share_weight=40.0)
    errs = [step_errors(WalkAligner(f1_bundle, share, radio=_BiasedRadio(w, angle)).run(
        w.steps, smooth=True), w.true_xy)
        for w in _f1_with_scans(sim_walks) for angle in (0, 90, 200, 300)]
    assert np.median(np.concatenate(errs)) < 1.5


def test_from_a_given_start_without_radio(f1_bundle, sim_walks):  # noqa: F811
    """A known start (as a fix of 1 m) and the walls: pooled median below 1.5 m (0.4-1.4 m
    per walk here; the walker's steps are 7-17 % longer than the nominal length)."""
    errs = []
    for w in (v for v in sim_walks if v.floor == "F1"):
        track = WalkAligner(f1_bundle).run(w.steps, start_xy=w.start_xy, smooth=True)
        assert 0.75 <= track.info["scale"] <= 1.25 and track.info["n_fixes"] == 0
        errs.append(step_errors(track, w.true_xy))
    assert np.median(np.concatenate(errs)) < 1.5


def test_shape_matches_the_true_path_up_to_a_similarity(sim_walks):  # noqa: F811
    """Gyroscope heading turned onto the compass, Weinberg step lengths: fitted to the true
    path by one rotation, scale and shift, every F1 walk's shape is within 0.6 m in median
    (0.14-0.41 m here)."""
    for w in (v for v in sim_walks if v.floor == "F1"):
        shape = walk_shape(w.steps)[1:]
        true = w.true_xy[:, 0] + 1j * w.true_xy[:, 1]
        a = np.column_stack([np.ones(len(shape)), shape])
        fit = a @ np.linalg.lstsq(a, true, rcond=None)[0]
        assert np.median(np.abs(fit - true)) < 0.6, w.trace_id


def test_streaming_equals_batch(f1_bundle, sim_walks):  # noqa: F811
    w = _f1_with_scans(sim_walks)[0]
    radio = _BiasedRadio(w, 45)
    batch = WalkAligner(f1_bundle, radio=radio).run(w.steps, start_xy=w.start_xy)
    radio.rng = np.random.default_rng(45)  # the same fixes again
    loc = WalkAligner(f1_bundle, radio=radio)
    loc.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    est = [loc.step(s) for s in w.steps]
    assert np.array_equal([e.x_m for e in est], batch.x_m)
    assert np.array_equal([e.y_m for e in est], batch.y_m)


def test_streaming_from_a_scan_equals_batch(f1_bundle, sim_walks):  # noqa: F811
    """Started from the walk's first scan and stepped over every step (that scan's step
    included), the track is run()'s: the start fix is dated at its scan, and not applied
    twice (it was, before: tracks differed by up to 2.8 m on real walks)."""
    w = _f1_with_scans(sim_walks)[0]
    radio = _BiasedRadio(w, 45)
    batch = WalkAligner(f1_bundle, radio=radio).run(w.steps)
    radio.rng = np.random.default_rng(45)
    loc = WalkAligner(f1_bundle, radio=radio)
    first_scan = next(s for s in w.steps.scans if s is not None)
    start = loc.start(scan=first_scan, t_ms=w.steps.t_ms[0] - 500.0)
    assert (start.x_m, start.y_m) == (batch.start.x_m, batch.start.y_m)
    est = [loc.step(s) for s in w.steps]
    assert np.array_equal([e.x_m for e in est], batch.x_m)
    assert np.array_equal([e.y_m for e in est], batch.y_m)


def test_a_refused_step_leaves_the_stream_going(f1_bundle, sim_walks, monkeypatch):  # noqa: F811
    """A step without a compass heading (NaN, inf, text), or with a fix in other units or
    stamped after it, is refused with a LocalizationError and not taken: the next steps give
    the track of a stream that never saw it (a NaN compass used to poison the window, and
    every later step of the user failed with an IndexError). So does a step whose alignment
    fails."""
    from dataclasses import replace

    import localize.align as align

    w = _f1_with_scans(sim_walks)[0]
    ref = WalkAligner(f1_bundle)
    ref.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    want = [ref.step(s) for s in w.steps]
    loc = WalkAligner(f1_bundle)
    loc.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    got = [loc.step(w.steps[i]) for i in range(3)]
    for compass in (np.nan, np.inf):
        with pytest.raises(LocalizationError, match="no compass heading"):
            loc.step(replace(w.steps[3], compass_deg=compass))
    with pytest.raises(LocalizationError, match="compass_deg must be a number"):
        loc.step(replace(w.steps[3], compass_deg="north"))
    s = w.steps[3]
    with pytest.raises(LocalizationError, match="more than 200 m off the floor's map"):
        loc.step_values(s.t_ms, s.compass_deg, s.relative_heading_deg, s.delta_acc_ms2,
                        fix=(1e6, 1e6, s.t_ms))
    # a scan or fix stamped an hour after its step (another clock, a receipt time) was held
    # by the alignment for the rest of the walk, pulling every later position
    scan = next(x for x in w.steps.scans[3:] if x is not None)
    late = replace(scan, t_ms=int(s.t_ms) + 3_600_000)
    with pytest.raises(LocalizationError, match=r"its scan is stamped \d+ ms, 3.6e\+03 s after "
                                                r"the step .* the step was not taken"):
        loc.step(replace(s, scan=late))
    with pytest.raises(LocalizationError, match="its scan time -5 is no Unix time in ms"):
        loc.step(replace(s, scan=replace(scan, t_ms=-5)))
    with pytest.raises(LocalizationError, match=r"fix is stamped .* after the step"):
        loc.step_values(s.t_ms, s.compass_deg, s.relative_heading_deg, s.delta_acc_ms2,
                        fix=(*w.start_xy, s.t_ms + 3_600_000))
    real = align.WalkAligner._align_window
    monkeypatch.setattr(align.WalkAligner, "_align_window",
                        lambda self, local: (_ for _ in ()).throw(MemoryError("no room")))
    with pytest.raises(MemoryError):
        loc.step(w.steps[3])
    monkeypatch.setattr(align.WalkAligner, "_align_window", real)
    got += [loc.step(w.steps[i]) for i in range(3, len(w.steps))]
    assert [(e.x_m, e.y_m) for e in got] == [(e.x_m, e.y_m) for e in want]
    # a run (either kind) starts the stream anew: its steps are checked against its start,
    # not against the last step streamed before it
    assert loc.stepped and loc.last_t_ms == w.steps.t_ms[-1]
    for smooth in (True, False):
        loc.run(w.steps, start_xy=w.start_xy, smooth=smooth)
        assert loc.last_t_ms == (w.steps.t_ms[0] - 500.0 if smooth else w.steps.t_ms[-1])
    fresh = WalkAligner(f1_bundle)
    fresh.run(w.steps, start_xy=w.start_xy, smooth=True)
    assert not fresh.stepped and np.isfinite(fresh.step(w.steps[0]).x_m)
    pdr = make_localizer("pdr", f1_bundle)
    pdr.start(*w.start_xy)
    with pytest.raises(LocalizationError, match="no compass heading"):
        pdr.step(replace(w.steps[0], compass_deg=np.nan))
    assert np.isfinite(pdr.step(w.steps[0]).x_m)  # it went on NaN for ever, before


@pytest.mark.parametrize("field,bad,said", [
    ("compass_deg", None, "compass_deg must be a number (NaN when unknown), not None"),
    ("delta_acc_ms2", None, "delta_acc_ms2 must be a number"),
    ("relative_heading_deg", None, "relative_heading_deg must be a number"),
    ("strength_ut", "41.0", "strength_ut must be a number"),
    ("frequency_hz", True, "frequency_hz must be a number"),
    ("attitude", 1.7, "attitude must be one of the AttitudeCode values"),
    ("attitude", 9, "attitude must be one of the AttitudeCode values"),
    ("mag_strength_ut", np.zeros((2, 2)), "mag_strength_ut must be None or a 1-D array"),
    ("scan", (0, ["ab"], [-50.0]), "scan must be None or a RadioScan, not tuple"),
])
def test_a_step_with_a_field_of_the_wrong_kind_is_refused_and_the_stream_goes_on(
        f1_bundle, sim_walks, field, bad, said):  # noqa: F811
    """A streamed step whose field is None, text, a bool, or an array of the wrong shape: a
    LocalizationError naming the field, before any of it is taken, for every method. A
    compass of None passed ``check_next`` (None meant "a method that walks without it") and
    the filter moved its particles to NaN before it failed with a TypeError; every later
    step of the user then failed with an IndexError. The alignment broke the same way on a
    None swing or gyroscope heading."""
    from dataclasses import replace

    w = _f1_with_scans(sim_walks)[0]
    for method in ("indoormap", "align", "pdr", "pf_no_mag", "magicol_dtw", "auto"):
        ref = make_localizer(method, f1_bundle, rng=5)
        ref.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
        want = [ref.step(w.steps[i]) for i in range(8)]
        loc = make_localizer(method, f1_bundle, rng=5)
        loc.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
        got = [loc.step(w.steps[np.int64(i)]) for i in range(4)]
        with pytest.raises(LocalizationError, match=re.escape(said)):
            loc.step(replace(w.steps[4], **{field: bad}))
        got += [loc.step(w.steps[i]) for i in range(4, 8)]
        assert [(e.x_m, e.y_m) for e in got] == [(e.x_m, e.y_m) for e in want], method
    # what a method does not read may be None: the radio alone reads the time and the scan
    radio = make_localizer("radio", f1_bundle, radio=_BiasedRadio(w, 0))
    radio.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    assert np.isfinite(radio.step(replace(w.steps[0], compass_deg=None)).x_m)
    zero_d = make_localizer("indoormap", f1_bundle, rng=5)  # a 0-d array is a number
    zero_d.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    assert np.isfinite(zero_d.step(replace(w.steps[0], compass_deg=np.array(10.0))).x_m)
    aligner = WalkAligner(f1_bundle)  # the values API of the multi-user aligner
    aligner.start(*w.start_xy, t_ms=w.steps.t_ms[0] - 500.0)
    s = w.steps[0]
    with pytest.raises(LocalizationError, match="delta_acc_ms2 must be a number"):
        aligner.step_values(s.t_ms, s.compass_deg, s.relative_heading_deg, None)
    assert np.isfinite(aligner.step_values(s.t_ms, s.compass_deg, s.relative_heading_deg,
                                           s.delta_acc_ms2).x_m)


def test_a_stream_from_a_scan_starts_at_its_time(f1_bundle, sim_walks):  # noqa: F811
    """Without a start time, start(scan=...) starts at the scan's time (it started at 0)."""
    w = _f1_with_scans(sim_walks)[0]
    scan = next(s for s in w.steps.scans if s is not None)
    for method in ("align", "indoormap", "pdr"):
        loc = make_localizer(method, f1_bundle, radio=_BiasedRadio(w, 45), rng=0)
        assert loc.start(scan=scan).t_ms == scan.t_ms
        assert loc.start(*w.start_xy).t_ms == 0.0  # a given position: as before


def test_real_time_forgets_what_no_window_reaches_and_keeps_the_track(
        f1_bundle, sim_walks, monkeypatch):  # noqa: F811
    """The steps and fixes behind the real-time window are dropped (memory and work per step
    bounded for a user who walks for hours): with a 5 s window and forgetting every 4 steps,
    the track is the one of an aligner that keeps everything, position by position, with a
    given start and without one (the start fix forgotten too)."""
    import localize.align as align

    class FirstFixes(_BiasedRadio):  # then the radio goes quiet: windows with no fix
        def locate(self, scan):
            self.n = getattr(self, "n", 0) + 1
            return super().locate(scan) if self.n <= 3 else None

    p = AlignParams(window_s=5.0)
    walks = _f1_with_scans(sim_walks)[:2]
    for w, start_xy, radio in ((walks[0], None, _BiasedRadio),
                               (walks[1], walks[1].start_xy, _BiasedRadio),
                               (walks[0], None, FirstFixes)):
        tracks, kept = [], []
        for forget in (4, 10 ** 9):
            monkeypatch.setattr(align, "_FORGET_STEPS", forget)
            loc = WalkAligner(f1_bundle, p, radio=radio(w, 45))
            tracks.append(loc.run(w.steps, start_xy=start_xy))
            kept.append((len(loc._t), len(loc._fix_t)))
        assert kept[1][0] == len(w.steps) + 1 and kept[0][0] <= 30 < len(w.steps)
        assert kept[0][1] < kept[1][1] or kept[0][1] == 1
        assert np.array_equal(tracks[0].x_m, tracks[1].x_m)
        assert np.array_equal(tracks[0].y_m, tracks[1].y_m)
        assert np.array_equal(tracks[0].spread_m, tracks[1].spread_m)


def test_registered_as_a_method(f1_bundle):  # noqa: F811
    assert isinstance(make_localizer("align", f1_bundle), WalkAligner)


def test_bad_calls(f1_bundle, sim_walks):  # noqa: F811
    w = sim_walks[0]
    loc = WalkAligner(f1_bundle)
    with pytest.raises(LocalizationError, match="no start position given and no scan of the walk located"):
        loc.run(w.steps)
    with pytest.raises(LocalizationError, match="call start"):
        WalkAligner(f1_bundle).step(w.steps[0])
    no_gyro = w.steps.with_columns(relative_heading_deg=np.full(len(w.steps), np.nan))
    track = loc.run(no_gyro, start_xy=w.start_xy, smooth=True)  # the compass alone
    assert len(track) == len(w.steps) and np.isfinite(track.x_m).all()
    with pytest.raises(LocalizationError, match="scale_range"):
        AlignParams(scale_range=(1.2, 0.8))
    with pytest.raises(LocalizationError, match="must be positive"):
        AlignParams(shift_step_m=0.0)
    with pytest.raises(LocalizationError, match="finite"):
        AlignParams(wall_weight=float("nan"))


def test_distance_from_mask_against_brute_force():
    """0 on the mask, never below the Euclidean distance to the nearest mask cell and at most
    8.3 % above it (8-neighbour chamfer), capped."""
    rng = np.random.default_rng(3)
    mask = np.zeros((40, 50), bool)
    mask[5:9, 3:45] = True
    mask[rng.integers(0, 40, 6), rng.integers(0, 50, 6)] = True
    d = distance_from_mask_m(mask, 0.5, cap_m=6.0)
    rows, cols = np.nonzero(mask)
    r, c = np.mgrid[:40, :50]
    exact = 0.5 * np.sqrt((r[..., None] - rows) ** 2 + (c[..., None] - cols) ** 2).min(axis=-1)
    assert np.all(d[mask] == 0.0)
    assert np.all(d >= np.minimum(exact, 6.0) - 1e-12)
    assert np.all(d <= np.minimum(1.083 * exact, 6.0) + 1e-12)
    assert d.max() == 6.0
    assert np.all(distance_from_mask_m(np.zeros((3, 4), bool), 0.5, 2.0) == 2.0)


def _reference_walls(bundle, off_mask, p, pts):
    """Wall penalty of tracks ``pts`` (shifts, positions), complex m: each position looked
    up in its grid cell, the cap off the grid; the definition the search's tables follow."""
    return _reference_wall_terms(p, _reference_off2(bundle, off_mask, p, pts))


def _reference_off2(bundle, off_mask, p, pts):
    """The squared distance from the mask (m^2) of each position of ``pts``, cell by cell."""
    row, col, on_grid = bundle.grid.cell_of(pts.real, pts.imag)
    return np.where(on_grid, off_mask[row, col], p.wall_cap_m) ** 2


def _reference_wall_terms(p, off2):
    return p.wall_weight * np.mean(off2, axis=1), np.mean(off2 == 0.0, axis=1)


def test_pruned_search_finds_the_exhaustive_best(f1_bundle, sim_walks):  # noqa: F811
    """The branch and bound (tracks placed only for transforms that can still win) returns
    the transform an exhaustive pass over the same grid finds, its wall term looked up cell
    by cell."""
    w = _f1_with_scans(sim_walks)[0]
    radio = _BiasedRadio(w, 120)
    p = AlignParams()
    shape = walk_shape(w.steps, p)
    times = np.concatenate([[w.steps.t_ms[0] - 500.0], w.steps.t_ms])
    fix_t = np.array([w.steps.t_ms[i] for i, s in enumerate(w.steps.scans) if s is not None])
    fix_z = np.array([complex(*radio.locate(s)[:2]) for s in w.steps.scans if s is not None])
    at_fix = np.interp(fix_t, times, shape.real) + 1j * np.interp(fix_t, times, shape.imag)
    ci = np.linalg.inv(_fix_covariance(fix_t / 1000.0, False, p))
    off_mask = distance_from_mask_m(f1_bundle.mask, f1_bundle.grid.cell_m, p.wall_cap_m)
    search = _Search(f1_bundle.grid, WallLookup(off_mask, f1_bundle.grid.cell_m, p.wall_cap_m),
                     p, shape, fix_z, at_fix, ci)
    rot = np.arange(-15.0, 15.1, 2.5)
    scale = np.arange(0.75, 1.251, 0.05)
    best = search._grid(rot, scale, 8.0, 0.5)
    k = np.arange(-16, 17) * 0.5
    grid = (k[None, :] + 1j * k[:, None]).ravel()
    top = -np.inf
    for r in rot:
        for sc in scale:
            a = sc * np.exp(1j * np.radians(r))
            resid = fix_z - a * at_fix            # the fixes' errors for a zero shift
            gls = np.sum(ci @ resid) / ci.sum()
            shifts = gls + grid
            e = resid[None, :] - shifts[:, None]  # (shifts, fixes)
            fix_ll = -0.5 * (np.einsum("sf,fg,sg->s", e.real, ci, e.real)
                             + np.einsum("sf,fg,sg->s", e.imag, ci, e.imag))
            wall, inside = _reference_walls(f1_bundle, off_mask, p,
                                            shifts[:, None] + a * shape[None, :])
            score = fix_ll - wall - 0.5 * (r / p.heading_sd_deg) ** 2 \
                - 0.5 * (np.log(sc) / p.scale_sd) ** 2
            if score.max() > top:
                j = np.argmax(score)
                top, a_top, shift_top, inside_top = score.max(), a, shifts[j], inside[j]
    assert best.score == pytest.approx(top, abs=1e-9)
    assert best.factor == pytest.approx(a_top) and best.shift == pytest.approx(shift_top)
    assert best.inside_share == inside_top


@pytest.mark.parametrize("step_cells", [0.74, 0.25, 0.5, 1.0, 1.5, 2.0])
def test_wall_term_off_the_grid_is_the_cap(f1_bundle, step_cells):  # noqa: F811
    """Tracks that leave the grid on every side, at shifts of whole and half cells (read as
    blocks of a padded table, split into half cells for the latter) and of other fractions of
    a cell (cell by cell): the search's table lookups give the cell-by-cell wall term, and
    positions off the grid count as the cap."""
    p = AlignParams(wall_share_weight=40.0)
    g = f1_bundle.grid
    off_mask = distance_from_mask_m(f1_bundle.mask, g.cell_m, p.wall_cap_m)
    t = np.linspace(-0.3, 1.3, 400)
    centre = complex(g.x0_m + 0.5 * g.width * g.cell_m, g.y0_m + 0.5 * g.height * g.cell_m)
    shape = (t - 0.5) * (g.width * g.cell_m + 1j * g.height * g.cell_m)  # a corner-to-corner line
    walls = WallLookup(off_mask, g.cell_m, p.wall_cap_m)
    search = _Search(g, walls, p, shape, np.array([centre]), np.array([0j]), np.eye(1))
    k, step_m = 6, step_cells * g.cell_m
    off = np.arange(-k, k + 1) * step_m
    shifts = centre + (off[None, :] + 1j * off[:, None]).ravel()
    for a in (1.0, 0.8 * np.exp(0.3j), -1.1):
        off2 = search._wall_values(a, centre, k, step_m)
        reference = _reference_off2(f1_bundle, off_mask, p, shifts[:, None] + a * shape[None, :])
        assert np.array_equal(off2.T, reference)
        wall, inside = _reference_wall_terms(p, reference)
        assert np.allclose(search._walls_of(off2), wall + p.wall_share_weight * (1 - inside))
        assert (inside < 1).all()

