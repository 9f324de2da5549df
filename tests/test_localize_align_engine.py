"""Many users' real-time walk alignments (localize.align_engine.MultiUserAligner)."""

import numpy as np
import pytest
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)
from test_localize_align import _BiasedRadio, _f1_with_scans

from localize.align import AlignParams, WalkAligner
from localize.align_engine import MultiUserAligner
from localize.errors import LocalizationError
from localize.stepper import StepInputs

COLUMNS = ("compass_deg", "frequency_hz", "turn_deg", "strength_ut", "azimuth_deg",
           "polar_deg", "attitude", "relative_heading_deg", "delta_acc_ms2")


def _inputs(walks, i):
    """Step ``i`` of each walk as one tick's inputs."""
    return StepInputs(*(np.array([getattr(w.steps, c)[i] for w in walks]) for c in COLUMNS))


class _Fixes:
    """The fixes a radio model gives a walk, per step index (x, y, scan time), computed once
    so that the engine and the single-user aligner see the same ones."""

    def __init__(self, walk, angle_deg):
        radio = _BiasedRadio(walk, angle_deg)
        self.at = {i: (*radio.locate(s)[:2], float(s.t_ms or walk.steps.t_ms[i]))
                   for i, s in enumerate(walk.steps.scans) if s is not None}
        self._of_scan = {id(walk.steps.scans[i]): f for i, f in self.at.items()}

    def locate(self, scan):  # as a radio model for WalkAligner.run
        x, y, _ = self._of_scan[id(scan)]
        return x, y, 3.0


def test_each_user_gets_the_single_user_track(f1_bundle, sim_walks):  # noqa: F811
    """Users of different walks started at different times, ticked together and in subsets,
    some ending earlier: each gets, position by position, what a WalkAligner streaming its
    walk alone gives with the same fixes (a known start for one, its first fix for another);
    removed users are gone and the others go on."""
    walks = _f1_with_scans(sim_walks)[:3]
    p = AlignParams(window_s=30.0)
    fixes = [_Fixes(w, 30 * k) for k, w in enumerate(walks)]
    expected = []
    for k, (w, f) in enumerate(zip(walks, fixes)):
        if k != 1:  # a known start: the batch run
            expected.append(WalkAligner(f1_bundle, p, radio=f).run(
                w.steps, start_xy=w.start_xy).x_m.tolist())
            continue
        # starts at its first fix, at the fix's time (the steps before it are not served)
        loc = WalkAligner(f1_bundle, p)
        first = min(f.at)
        loc.begin(f.at[first][0], f.at[first][1], f.at[first][2], 3.0)
        expected.append([loc.step_values(w.steps.t_ms[i], w.steps.compass_deg[i],
                                         w.steps.relative_heading_deg[i],
                                         w.steps.delta_acc_ms2[i], False,
                                         f.at.get(i) if i != first else None).x_m
                         for i in range(len(w.steps))])
    eng = MultiUserAligner(f1_bundle, p)
    starts = [w.start_xy for w in walks]
    t0 = [w.steps.t_ms[0] - 500.0 for w in walks]
    first = min(fixes[1].at)
    starts[1], t0[1] = fixes[1].at[first][:2], fixes[1].at[first][2]
    ids = eng.add_users(starts, t_ms=t0, sigma_m=[np.nan, 3.0, np.nan])
    got = [[] for _ in walks]
    n = max(len(w.steps) for w in walks)
    for i in range(n):
        live = [k for k, w in enumerate(walks) if i < len(w.steps)]
        if i == 20:
            live = live[::-1]  # any order of ids
        fx = np.array([fixes[k].at.get(i, (np.nan,) * 3) if (k != 1 or i != first)
                       else (np.nan,) * 3 for k in live])
        out = eng.tick(ids[live], [walks[k].steps.t_ms[i] for k in live],
                       _inputs([walks[k] for k in live], i), fix_xy_m=fx[:, :2],
                       fix_t_ms=fx[:, 2])
        for r, k in enumerate(live):
            got[k].append(out.x_m[r])
        for k, w in enumerate(walks):
            if i == len(w.steps) - 1:
                eng.remove_users([ids[k]])
    for k in range(len(walks)):
        assert np.array_equal(got[k], expected[k]), k
    assert eng.n_users == 0


def test_bad_ticks_move_nobody(f1_bundle, sim_walks):  # noqa: F811
    w = _f1_with_scans(sim_walks)[0]
    eng = MultiUserAligner(f1_bundle)
    ids = eng.add_users([w.start_xy, w.start_xy], t_ms=w.steps.t_ms[0] - 500.0)
    t = w.steps.t_ms[0]
    good = _inputs([w, w], 0)
    with pytest.raises(LocalizationError, match="appears twice"):
        eng.tick([ids[0], ids[0]], [t, t], good)
    with pytest.raises(LocalizationError, match=r"unknown user ids in tick: \[99\]"):
        eng.tick([ids[0], 99], [t, t], good)
    with pytest.raises(LocalizationError, match=f"user {ids[1]}: step at .* comes before the "
                       "start .* skip the steps before it.*; nobody was advanced"):
        eng.tick(ids, [t, w.steps.t_ms[0] - 1000.0], good)  # the second is back in time
    with pytest.raises(LocalizationError, match="fix_t_ms has shape"):
        eng.tick(ids, [t, t], good, fix_xy_m=[[1.0, 2.0], [1.0, 2.0]], fix_t_ms=[1.0, 2.0, 3.0])
    with pytest.raises(LocalizationError, match="shape"):
        eng.tick(ids, [t, t], _inputs([w], 0))
    with pytest.raises(LocalizationError, match="fix_xy_m has shape"):
        eng.tick(ids, [t, t], good, fix_xy_m=[[1.0, 2.0]])
    # a fix in other units, for another floor or half missing would drag its user's track
    # off the map (it was taken, and the user placed 500 km away with a 0.5 m spread)
    for fix in ([1e6, 1e6], [w.start_xy[0] * 1000.0, w.start_xy[1] * 1000.0 + 1e4],
                [np.inf, 5.0], [np.nan, 5.0]):
        with pytest.raises(LocalizationError, match=rf"users \[{ids[1]}\]: fix_xy_m .* not "
                           "two finite numbers within 200 m .*nobody was advanced"):
            eng.tick(ids, [t, t], good, fix_xy_m=[[np.nan, np.nan], fix])
    # fixes dated an hour ahead, ten years ahead or before 1970 were held for good; every
    # user with one is named
    near = [list(w.start_xy)] * 2
    for late in ([t + 3.6e6, t + 3.15e11], [-5.0, np.inf]):
        with pytest.raises(LocalizationError, match=rf"users \[{ids[0]}, {ids[1]}\]: "
                                                    r"fix_t_ms: .*nobody was advanced"):
            eng.tick(ids, [t, t], good, fix_xy_m=near, fix_t_ms=late)
    bad = StepInputs(**{**{c: getattr(good, c) for c in COLUMNS},
                        "frequency_hz": np.array(["1.8", "x"])})
    with pytest.raises(LocalizationError, match="frequency_hz is not numeric"):
        eng.tick(ids, [t, t], bad)
    assert all(a.last_t_ms == w.steps.t_ms[0] - 500.0 for a in eng._aligners.values())
    out = eng.tick(None, [t, t], good)  # every user
    assert np.array_equal(out.x_m[:1], out.x_m[1:])  # the same walk, the same estimate
    with pytest.raises(LocalizationError, match="more than 200 m off the floor's map"):
        eng.add_users([[1e6, 0.0]], t_ms=t)
    with pytest.raises(LocalizationError, match="start time"):
        eng.add_users([w.start_xy], t_ms=np.nan)
    with pytest.raises(LocalizationError, match="sigma_m is negative"):
        eng.add_users([w.start_xy], t_ms=t, sigma_m=-3.0)
    assert eng.n_users == 2  # the refused adds added nobody
    # removals are checked as ticks are: 1.7 removed user 1, and an unknown id or a user
    # removed twice went unnoticed (the filter engine refuses them too)
    with pytest.raises(LocalizationError, match=r"whole numbers .*got \[1.7\]; nobody was "
                                                r"removed"):
        eng.remove_users([1.7])
    with pytest.raises(LocalizationError, match=r"unknown user ids in remove_users: \[999\]; "
                                                r"nobody was removed"):
        eng.remove_users([ids[0], 999])
    assert eng.n_users == 2
    eng.remove_users([ids[0]])
    with pytest.raises(LocalizationError, match=rf"unknown user ids in remove_users: "
                                                rf"\[{ids[0]}\]"):
        eng.remove_users([ids[0]])
    assert eng.user_ids.tolist() == [ids[1]]


def test_guided_engine_users_get_the_single_user_guided_filter(f1_bundle, sim_walks):  # noqa: F811
    """``radio_guide="align"`` (auto's filter on a floor with a good magnetic map): users
    started from a fix are weighted towards their own alignment's position, and each gets
    the single-user guided filter's track with the same seed (one user) or close to it (the
    engine draws for all users at once, so with several users the draws differ; the tracks
    stay within the filter's own spread of the truth); a user started at a known position
    takes its fixes as the unguided engine does."""
    from localize.engine import MultiUserEngine
    from localize.evaluate import step_errors
    from localize.filter import Localizer
    from localize.params import FilterParams

    p = FilterParams(n_particles_start=0, radio_guide="align")
    walks = _f1_with_scans(sim_walks)[:3]
    fixes = [_Fixes(w, 30 * k) for k, w in enumerate(walks)]
    single = [Localizer(f1_bundle, p, radio=f, rng=9) for f in fixes]
    ref = [loc.run(w.steps) for loc, w in zip(single, walks)]
    assert all(loc.guided for loc in single)

    def starts(ws, fs):
        first = [f.at[min(f.at)] for f in fs]
        return (np.array([f[:2] for f in first]), [w.steps.t_ms[0] - 500.0 for w in ws])

    def run(eng, ws, fs, ids):
        n = min(len(w.steps) for w in ws)
        est = []
        for i in range(n):
            fx = np.array([f.at.get(i, (np.nan,) * 3) for f in fs])
            given = fx.copy()
            out = eng.tick(ids, _inputs(ws, i), fx[:, :2], t_ms=[w.steps.t_ms[i] for w in ws],
                           fix_t_ms=fx[:, 2])
            assert np.array_equal(fx, given, equal_nan=True)  # the caller's fixes untouched
            est.append(np.column_stack([out.x_m, out.y_m]))
        return np.stack(est, axis=1)  # (users, steps, 2)

    eng = MultiUserEngine(f1_bundle, p, rng=9)
    xy, t0 = starts(walks[:1], fixes[:1])
    ids = eng.add_users(xy, fix_sigma_m=[3.0], t_ms=t0)
    one = run(eng, walks[:1], fixes[:1], ids)
    assert np.allclose(one[0, :, 0], ref[0].x_m) and np.allclose(one[0, :, 1], ref[0].y_m)
    # several users, one of them started at its true position (not guided)
    eng = MultiUserEngine(f1_bundle, p, rng=9)
    xy, t0 = starts(walks, fixes)
    xy[2] = walks[2].start_xy
    ids = eng.add_users(xy, fix_sigma_m=[3.0, 3.0, np.nan], t_ms=t0)
    assert eng.guide.n_users == 2 and list(eng.guide_ids) == [0, 1, -1]
    many = run(eng, walks, fixes, ids)
    for k, w in enumerate(walks[:2]):
        n = many.shape[1]
        err, ref_err = (np.median(np.hypot(*(e - w.true_xy[:n]).T)) for e in (
            many[k], np.column_stack([ref[k].x_m[:n], ref[k].y_m[:n]])))
        assert err < max(2.0 * ref_err, 2.0), (k, err, ref_err)
    assert np.median(step_errors(ref[0], walks[0].true_xy)) < 5.0
    eng.remove_users(ids[:1])
    assert eng.guide.n_users == 1 and list(eng.guide_ids) == [1, -1]
    with pytest.raises(LocalizationError, match="need their step times"):
        eng.tick(ids[1:2], _inputs(walks[1:2], 0))
    t_next = eng.guide.aligners_of(eng.guide_ids[:1])[0].last_t_ms + 600.0
    with pytest.raises(LocalizationError, match=rf"users \[{ids[1]}\]: fix_t_ms: the first's "
                                                r"fix is stamped .* after the step"):
        eng.tick(ids[1:2], _inputs(walks[1:2], 0), fix_xy_m=[walks[1].start_xy],
                 t_ms=[t_next], fix_t_ms=[t_next + 3.6e6])
    drawn = eng.rng.bit_generator.state
    with pytest.raises(LocalizationError, match="need their start times"):
        eng.add_users(xy[:1], fix_sigma_m=[3.0])
    with pytest.raises(LocalizationError, match=r"t_ms has shape \(3,\), expected \(1,\)"):
        eng.add_users(xy[:1], fix_sigma_m=[3.0], t_ms=[1.0, 2.0, 3.0])
    with pytest.raises(LocalizationError, match="more than 200 m off"):
        eng.add_users([[1e6, 0.0]], fix_sigma_m=[3.0], t_ms=[t0[0]])
    # refused calls drew nothing (later users get what they would have) and added nobody
    assert eng.rng.bit_generator.state == drawn
    assert eng.guide.n_users == 1 and eng.n_users == 2
    # a guided user's bad step time is named by its engine id (its alignment's id differs)
    late, = eng.add_users(xy[:1], fix_sigma_m=[3.0], t_ms=[t0[0]])
    assert eng.guide_ids[-1] != late
    with pytest.raises(LocalizationError, match=f"^user {late}: .*nobody was advanced"):
        eng.tick([late], _inputs(walks[:1], 0), t_ms=[t0[0] - 1000.0])


def test_fix_times_of_users_without_a_fix_and_first_steps_at_the_start(
        f1_bundle, sim_walks):  # noqa: F811
    """A server puts 0 (an int array's "none") in fix_t_ms for users without a fix: the tick
    was refused. And a user's first step at its start's time, which the single-user
    localizers and the aligner take, was refused by the unguided engine as sent twice."""
    from localize.engine import MultiUserEngine

    w = _f1_with_scans(sim_walks)[0]
    t0 = w.steps.t_ms[0]
    aligner = MultiUserAligner(f1_bundle)
    ids = aligner.add_users([w.start_xy] * 2, t_ms=t0 - 500.0)
    fixes = np.array([[np.nan, np.nan], list(w.start_xy)])
    out = aligner.tick(ids, [t0, t0], _inputs([w, w], 0), fix_xy_m=fixes,
                       fix_t_ms=np.array([0, int(t0)]))
    assert np.isfinite(out.x_m).all()
    engine = MultiUserEngine(f1_bundle, {"n_particles": 50}, rng=1)
    ids = engine.add_users([w.start_xy] * 2, t_ms=t0)
    engine.tick(ids, _inputs([w, w], 0), t_ms=[t0, t0])  # the first step at the start time
    with pytest.raises(LocalizationError, match="the same step sent twice"):
        engine.tick(ids, _inputs([w, w], 0), t_ms=[t0, t0])
    with pytest.raises(LocalizationError, match="a start time is not finite"):
        engine.add_users([w.start_xy], t_ms=np.inf)


def test_a_tick_refused_names_every_bad_user_for_a_server(f1_bundle, sim_walks):  # noqa: F811
    """Three of five users resend their last step (a network retry): the tick named only
    the first of them in its text, so a server needed four attempts and had to parse
    English; the unguided filter engine took the step times and ignored them, walking the
    resent steps twice. Every server now refuses with a TickRefused whose user_ids are all
    of them, and the others tick at the next attempt."""
    from localize.engine import MultiUserEngine
    from localize.errors import TickRefused

    w = _f1_with_scans(sim_walks)[0]
    t0 = w.steps.t_ms[0] - 500.0
    for make in (lambda: MultiUserAligner(f1_bundle),
                 lambda: MultiUserEngine(f1_bundle, {"n_particles": 50}, rng=1)):
        eng = make()
        ids = eng.add_users([w.start_xy] * 5, t_ms=t0)
        steps = [_inputs([w] * 5, i) for i in range(2)]

        def tick(who, i):
            rows = np.searchsorted(ids, who)
            inputs = StepInputs(*(getattr(steps[i], c)[rows] for c in COLUMNS))
            t = [w.steps.t_ms[i]] * len(who)
            return (eng.tick(who, t, inputs) if isinstance(eng, MultiUserAligner)
                    else eng.tick(who, inputs, t_ms=t))

        tick(ids, 0)
        resent = ids[[1, 3, 4]]
        mixed = np.concatenate([resent, ids[[0, 2]]])
        with pytest.raises(TickRefused, match=rf"user {resent[0]}: .*the same step sent twice"
                                              r".* \(and 2 more user\(s\)\); nobody was "
                                              r"advanced") as refused:
            # the resent users send step 0 again, the others step 1
            rows = np.searchsorted(ids, mixed)
            inputs = StepInputs(*(getattr(steps[1], c)[rows] for c in COLUMNS))
            t = [w.steps.t_ms[0]] * 3 + [w.steps.t_ms[1]] * 2
            (eng.tick(mixed, t, inputs) if isinstance(eng, MultiUserAligner)
             else eng.tick(mixed, inputs, t_ms=t))
        assert refused.value.user_ids == resent.tolist()
        good = [u for u in mixed.tolist() if u not in refused.value.user_ids]
        out = tick(np.array(good), 1)  # the others, at once
        assert len(out.x_m) == 2
        with pytest.raises(TickRefused) as unknown:
            t = [w.steps.t_ms[1] + 600.0] * 2
            (eng.tick([ids[0], 99], t, _inputs([w] * 2, 1)) if isinstance(eng, MultiUserAligner)
             else eng.tick([ids[0], 99], _inputs([w] * 2, 1), t_ms=t))
        assert unknown.value.user_ids == [99]
