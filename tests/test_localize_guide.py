"""The filter guided by the walk alignment (``FilterParams.radio_guide="align"``)."""

import numpy as np
import pytest
from localize_fixtures import f1_bundle, sim_walks, truth_bundles  # noqa: F401  (fixtures)
from test_localize_align import _BiasedRadio, _f1_with_scans

from localize.align import WalkAligner
from localize.errors import LocalizationError
from localize.filter import Localizer
from localize.params import FilterParams

GUIDED = FilterParams(radio_guide="align")


def test_the_guided_filter_follows_the_alignment(f1_bundle, sim_walks):  # noqa: F811
    """Started from the walk's first fix, the guided filter is weighted towards the
    alignment's real-time position at every step (and re-drawn around it when 4 m away): held
    to it by a 1 m Gaussian, its track keeps within a metre of the alignment's; the filter on
    the (4 m biased) fixes, or guided by the default 5 m Gaussian, goes its own way, on the
    magnetic map."""
    params = {"tight": FilterParams(radio_guide="align", guide_sigma_m=1.0, radio_outlier=0.01),
              "align": GUIDED, "fixes": FilterParams()}
    near = {k: [] for k in params}
    for w in _f1_with_scans(sim_walks)[:3]:
        for angle in (0, 200):
            aligned = WalkAligner(f1_bundle, radio=_BiasedRadio(w, angle))
            fix = aligned.first_fix(w.steps)
            aligned.begin(fix[0], fix[1], float(w.steps.t_ms[0]) - 500.0, fix[2])
            ref = [aligned.step(s) for s in w.steps]
            for guide in near:
                loc = Localizer(f1_bundle, params[guide], radio=_BiasedRadio(w, angle), rng=0)
                track = loc.run(w.steps)
                assert (loc.guide is not None) is (guide != "fixes")
                near[guide].append(np.hypot(track.x_m - [e.x_m for e in ref],
                                            track.y_m - [e.y_m for e in ref]))
    tight, default, fixes = (np.median(np.concatenate(near[k])) for k in params)
    assert tight < 1.0 < default < fixes  # 0.43, 2.36, 2.64 m


def test_a_given_start_is_not_guided(f1_bundle, sim_walks):  # noqa: F811
    """From a given start the alignment would hold the start as a 1 m fix, a wrong one for
    its whole window; the filter then uses the fixes, as without the guide (same track)."""
    w = _f1_with_scans(sim_walks)[0]
    wrong = (w.true_xy[0, 0] + 8.0, w.true_xy[0, 1])
    tracks = [Localizer(f1_bundle, p, radio=_BiasedRadio(w, 0), rng=0).run(
        w.steps, start_xy=wrong) for p in (GUIDED, FilterParams())]
    assert np.array_equal(tracks[0].x_m, tracks[1].x_m)
    assert np.array_equal(tracks[0].y_m, tracks[1].y_m)


def test_guide_parameters_are_checked(f1_bundle):  # noqa: F811
    with pytest.raises(LocalizationError, match="radio_guide"):
        FilterParams(radio_guide="waypoints")
    with pytest.raises(LocalizationError, match="guide_sigma_m"):
        FilterParams(guide_sigma_m=0.0)
    assert Localizer(f1_bundle, GUIDED).guide is None  # no radio model: nothing to align
    assert Localizer(f1_bundle, FilterParams.paper_params(radio_guide="align"),
                     radio=object()).guide is None  # radio for the start only



def test_the_guide_starts_where_the_particles_do(f1_bundle, sim_walks):  # noqa: F811
    """The guide begins at the walk's first fix at the start time, as the particles do, and
    takes that scan again at its step (dating it at its scan and taking it once, as
    WalkAligner.run does, measured worse: docs/localize.md, session 42). Streaming (start
    from the scan, then step) gives the guide the same fixes and the same track as run()."""
    from test_localize_align_engine import _Fixes

    w = _f1_with_scans(sim_walks)[0]
    radio = _Fixes(w, 0)  # the same fix for a scan at every call
    t0 = float(w.steps.t_ms[0]) - 500.0
    ref = WalkAligner(f1_bundle, radio=radio)
    ref.run(w.steps)
    loc = Localizer(f1_bundle, GUIDED, radio=radio, rng=0)
    batch = loc.run(w.steps)
    assert loc.guided and loc.guide._fix_t == [t0] + ref._fix_t
    streaming = Localizer(f1_bundle, GUIDED, radio=radio, rng=0)
    streaming.start(t_ms=t0, scan=w.steps.scans[min(radio.at)])
    track = [streaming.step(s) for s in w.steps]
    assert streaming.guide._fix_t == loc.guide._fix_t
    assert np.allclose([e.x_m for e in track], batch.x_m)
    assert np.allclose([e.y_m for e in track], batch.y_m)
