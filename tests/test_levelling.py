"""Levelling: per-session hard-iron residuals and per-model soft iron, on a synthetic survey whose
truth is known (mapping.levelling)."""

import numpy as np
import pandas as pd
import pytest

from mapping.levelling import (
    SOFT_IRON_COLUMNS,
    LevellingParams,
    apply_session_residuals,
    fit_session_residuals,
)
from survey.rotation import rotation_matrices
from survey.sim import rotations as rot

#: true soft-iron deviation D (symmetric) and session residuals (device frame, uT) per model
SOFT = {"PhoneA": np.array([[0.05, 0.01, 0.0], [0.01, -0.04, 0.01], [0.0, 0.01, -0.01]]),
        "PhoneB": np.array([[-0.03, 0.0, 0.01], [0.0, 0.04, 0.0], [0.01, 0.0, 0.02]])}
RESIDUAL = {"PhoneA|1,2,3": [1.5, -1.0, 3.0], "PhoneA|9,9,9": [-0.5, 0.8, -2.0],
            "PhoneB|4,5,6": [0.7, 1.2, 2.5], "PhoneB|0,0,0": [-1.2, -0.4, -1.5]}


def true_field(x, y):
    """Earth-frame field (E, N, U; uT) varying by a few uT over metres."""
    return np.column_stack([18 + 4 * np.sin(0.8 * x), 12 + 3 * np.cos(0.6 * x + y),
                            -38 + 3 * np.sin(0.5 * x - 0.7 * y)])


def survey(seed=3, walks_per_session=2, n=400):
    """Walks back and forth along a 3 m x 30 m corridor, phone mostly flat with some tilt."""
    rng = np.random.default_rng(seed)
    parts = []
    for session, r in RESIDUAL.items():
        model = session.split("|")[0]
        for w in range(walks_per_session):
            x = rng.uniform(0, 30, n)
            y = rng.uniform(0, 3, n)
            yaw = np.where(rng.random() < 0.5, 90.0, 270.0) + rng.normal(0, 25, n)
            q = rot.from_yaw_pitch_roll(yaw, rng.normal(-20, 15, n), rng.normal(0, 15, n))
            q = q[:, [3, 0, 1, 2]]  # the simulator's (x, y, z, w) -> the samples' (w, x, y, z)
            r_mat = rotation_matrices(q, quaternion=True)
            b_dev = np.einsum("nba,nb->na", r_mat, true_field(x, y))
            m = b_dev @ (np.eye(3) + SOFT[model]).T + np.asarray(r) \
                + rng.normal(0, 0.3, (n, 3))
            e = np.einsum("nab,nb->na", r_mat, m)
            parts.append(pd.DataFrame({
                "trace_id": f"{session}-{w}", "session": session, "x_m": x, "y_m": y,
                "mag_east_ut": e[:, 0], "mag_north_ut": e[:, 1], "mag_up_ut": e[:, 2],
                "q_w": q[:, 0], "q_x": q[:, 1], "q_y": q[:, 2], "q_z": q[:, 3]}))
    return pd.concat(parts, ignore_index=True)


def strength_error(samples, residuals):
    got = np.linalg.norm(apply_session_residuals(samples, residuals), axis=1)
    truth = np.linalg.norm(true_field(samples["x_m"].to_numpy(), samples["y_m"].to_numpy()),
                           axis=1)
    err = got - truth
    return float(np.sqrt(np.mean((err - np.median(err)) ** 2)))


def test_soft_iron_is_recovered_relative_between_models():
    samples = survey()
    fitted = fit_session_residuals(samples, LevellingParams(subsample=2, soft_iron_prior=0.0))
    assert (fitted["n_pairs"] > 0).all()
    d = {m: fitted.loc[fitted["device"] == m, list(SOFT_IRON_COLUMNS)].iloc[0].to_numpy()
         for m in SOFT}
    # only differences between models (and each model's anisotropy) are observable: compare
    # the fitted difference of the two matrices with the true one, entry by entry
    true_diff = SOFT["PhoneA"] - SOFT["PhoneB"]
    idx = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    np.testing.assert_allclose(d["PhoneA"] - d["PhoneB"], [true_diff[i] for i in idx],
                               atol=0.015)
    # and the levelled strength is far closer to the truth than without the soft iron
    hard_only = fit_session_residuals(samples, LevellingParams(subsample=2, soft_iron="off"))
    assert (hard_only[list(SOFT_IRON_COLUMNS)] == 0).all().all()
    with_soft, without = strength_error(samples, fitted), strength_error(samples, hard_only)
    assert with_soft < 0.6 * without, (with_soft, without)
    assert with_soft < 0.5  # sample noise 0.3 uT per axis


def test_soft_iron_needs_two_models_in_auto_mode():
    samples = survey()
    one_model = samples[samples["session"].str.startswith("PhoneA")]
    fitted = fit_session_residuals(one_model, LevellingParams(subsample=2))
    assert (fitted[list(SOFT_IRON_COLUMNS)] == 0).all().all()
    assert (fitted["device"] == "PhoneA").all()
    # the hard-iron residuals are still fitted (the difference between the two sessions)
    diff = fitted.loc["PhoneA|1,2,3", ["r_x_ut", "r_y_ut", "r_z_ut"]].to_numpy() \
        - fitted.loc["PhoneA|9,9,9", ["r_x_ut", "r_y_ut", "r_z_ut"]].to_numpy()
    true = np.subtract(RESIDUAL["PhoneA|1,2,3"], RESIDUAL["PhoneA|9,9,9"])
    assert np.abs(diff - true).max() < 0.5


def test_the_prior_shrinks_the_soft_iron():
    samples = survey()
    free = fit_session_residuals(samples, LevellingParams(subsample=2, soft_iron_prior=0.0))
    shrunk = fit_session_residuals(samples, LevellingParams(subsample=2, soft_iron_prior=5.0))
    size = lambda t: np.abs(t[list(SOFT_IRON_COLUMNS)].to_numpy()).sum()
    assert size(shrunk) < 0.5 * size(free)


def test_tables_without_soft_iron_columns_apply_the_residual_only():
    samples = survey(n=50)
    fitted = fit_session_residuals(samples, LevellingParams(subsample=1, soft_iron="off"))
    old_table = fitted.drop(columns=list(SOFT_IRON_COLUMNS))
    np.testing.assert_array_equal(apply_session_residuals(samples, old_table),
                                  apply_session_residuals(samples, fitted))


def test_bad_levelling_parameters_raise():
    with pytest.raises(ValueError, match="soft_iron must be one of"):
        LevellingParams(soft_iron="yes")
    with pytest.raises(ValueError, match="soft_iron_prior"):
        LevellingParams(soft_iron_prior=-1.0)


def test_held_out_levelling_uses_the_builds_share_of_samples(monkeypatch):
    """The held-out figures score the build's pipeline: leave_one_walk_out thins the samples
    (``subsample``) and must then level on every ``levelling.subsample``-th sample of the floor
    as the build does, not on every (subsample x levelling.subsample)-th (an old bug: the
    benchmark levelled on a fifth of the build's samples and understated its skill)."""
    from mapping import holdout
    from mapping.grid import grid_for_extent

    samples = survey(n=200)
    calls = []

    def recording(train, params):
        calls.append((len(train), params.subsample))
        return fit_session_residuals(train, params)

    monkeypatch.setattr(holdout, "fit_session_residuals", recording)
    grid = grid_for_extent(30.0, 3.0, 0.5)
    pipes = [holdout.Pipeline("constant", level=False, constant=True),
             holdout.Pipeline("default")]
    # (holdout thinning, levelling.subsample, the fit's stride on the thinned samples)
    for thin, lev, stride in ((5, 5, 1), (2, 4, 2), (1, 3, 3), (4, 2, 1)):
        calls.clear()
        holdout.leave_one_walk_out(samples, grid, np.ones(grid.shape, bool), pipes,
                                   levelling=LevellingParams(subsample=lev),
                                   levelling_folds=2, subsample=thin)
        assert len(calls) == 2  # one fit per levelling fold
        for n_train, fit_stride in calls:
            assert fit_stride == stride
            assert abs(n_train - len(samples) / 2 / thin) <= 4  # half of the 8 walks


def test_held_out_levelling_has_no_empty_folds_and_scores_nothing_as_nan():
    """More levelling folds than walks: one fold per walk (the report used to list folds
    without walks); a layer no walk can be scored on gives NaN figures, not a missing column
    (``validate`` crashed on it with a KeyError)."""
    from mapping import holdout
    from mapping.grid import grid_for_extent

    samples = survey(n=200)
    n_walks = samples["trace_id"].nunique()
    grid = grid_for_extent(30.0, 3.0, 0.5)
    pipes = [holdout.Pipeline("constant", level=False, constant=True),
             holdout.Pipeline("default")]
    said: list[str] = []
    table = holdout.leave_one_walk_out(samples, grid, np.ones(grid.shape, bool), pipes,
                                       levelling_folds=n_walks + 4, progress=said.append)
    assert said.count("default: fold 1") == 1 and f"default: fold {n_walks}" in said
    assert f"default: fold {n_walks + 1}" not in said
    assert np.isfinite(table["shape_rmse"]).all()
    nothing = holdout.metrics([(np.ones(3), np.ones(3), np.zeros(3), np.arange(3.0))])
    assert np.isnan(nothing["shape_rmse"]) and nothing["n_walks"] == 0
    assert set(nothing) == set(holdout.metrics(
        [(np.arange(9.0), np.arange(9.0) + 1, np.zeros(9), np.arange(9.0))]))
