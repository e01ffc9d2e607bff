"""`crps_ensemble` against the CRPS written out as a double loop, against `scoringrules`, and
against the expected CRPS of a normal forecast (the fair estimator is unbiased, the empirical
one is not); `forecast_scores` against exchangeable ensembles (calibrated: flat ranks,
spread/RMSE -> sqrt(m / (m + 1))) and too narrow ones; `paired_comparison`'s intervals cover
a known difference about as often as they say."""

import itertools

import numpy as np
import pytest
import scoringrules

import slps_jax as sj


def crps_double_loop(ens, y, fair):
    """The CRPS written out: every member against the truth, every pair of members."""
    m = ens.shape[0]
    out = np.empty(y.shape)
    for idx in np.ndindex(*y.shape):
        x = [ens[(i, *idx)] for i in range(m)]
        absolute = sum(abs(xi - y[idx]) for xi in x) / m
        pairs = sum(abs(xi - xj) for xi, xj in itertools.product(x, x))
        out[idx] = absolute - 0.5 * pairs / (m * (m - 1) if fair else m * m)
    return out


@pytest.mark.parametrize("fair", [True, False])
def test_crps_ensemble_is_the_double_loop(fair):
    rng = np.random.default_rng(2)
    for _ in range(6):
        m = int(rng.integers(2, 9))
        shape = tuple(int(s) for s in rng.integers(1, 4, size=rng.integers(0, 3)))
        ens, y = rng.normal(size=(m, *shape)), rng.normal(size=shape)
        np.testing.assert_allclose(
            sj.crps_ensemble(ens, y, fair=fair), crps_double_loop(ens, y, fair), rtol=1e-12
        )
    ties = rng.integers(0, 3, size=(6, 4)).astype(float)  # equal members, a member at y
    np.testing.assert_allclose(
        sj.crps_ensemble(ties, ties[0], fair=fair),
        crps_double_loop(ties, ties[0], fair),
        atol=1e-14,
    )


def test_crps_ensemble_is_scoringrules_fair_and_default_estimators():
    rng = np.random.default_rng(3)
    ens, y = rng.normal(size=(9, 4, 5)), rng.normal(size=(4, 5))
    fair = scoringrules.crps_ensemble(y, ens, m_axis=0, estimator="fair", backend="numpy")
    np.testing.assert_allclose(sj.crps_ensemble(ens, y), fair, rtol=1e-12)
    # scoringrules' default ("qd") and its energy form: the empirical distribution's CRPS
    for kwargs in ({}, {"estimator": "nrg"}):
        empirical = scoringrules.crps_ensemble(y, ens, m_axis=0, backend="numpy", **kwargs)
        np.testing.assert_allclose(sj.crps_ensemble(ens, y, fair=False), empirical, rtol=1e-12)


def test_the_fair_crps_is_unbiased_and_the_empirical_one_is_not():
    # E_y CRPS(N(0, 1), y) over y ~ N(0, 1) is 1/sqrt(pi); members drawn from N(0, 1)
    m, reps = 3, 200_000
    rng = np.random.default_rng(4)
    ens, y = rng.normal(size=(m, reps)), rng.normal(size=reps)
    exact = 1 / np.sqrt(np.pi)
    fair = sj.crps_ensemble(ens, y)
    assert abs(fair.mean() - exact) < 4 * fair.std() / np.sqrt(reps), fair.mean()
    # the empirical CRPS: larger by E|X - X'| / (2 m) = (2 / sqrt(pi)) / (2 m)
    empirical = sj.crps_ensemble(ens, y, fair=False)
    bias = (2 / np.sqrt(np.pi)) / (2 * m)
    assert abs(empirical.mean() - exact - bias) < 4 * empirical.std() / np.sqrt(reps)
    assert empirical.mean() - exact > 0.8 * bias  # far outside the sampling error


def test_crps_ensemble_refusals_and_one_member():
    rng = np.random.default_rng(5)
    ens, y = rng.normal(size=(4, 3)), rng.normal(size=3)
    np.testing.assert_allclose(sj.crps_ensemble(ens[:1], y, fair=False), np.abs(ens[0] - y))
    with pytest.raises(ValueError, match="fair CRPS .* at least two members"):
        sj.crps_ensemble(ens[:1], y)
    with pytest.raises(ValueError, match="truth"):
        sj.crps_ensemble(ens, y[:2])
    with pytest.raises(ValueError, match="ensemble must be finite"):
        sj.crps_ensemble(np.where(ens > 0, np.inf, ens), y)
    with pytest.raises(ValueError, match="truth must be finite"):
        sj.crps_ensemble(ens, np.full_like(y, np.nan))
    with pytest.raises(ValueError, match="ensemble must be real"):
        sj.crps_ensemble(ens + 1j, y)
    with pytest.raises(ValueError, match="at least one member"):
        sj.crps_ensemble(ens[:0], y, fair=False)


def test_crps_is_the_kernel_formula_and_a_point_forecast_scores_its_absolute_error():
    rng = np.random.default_rng(0)
    ens, y = rng.normal(size=(7, 5, 3)), rng.normal(size=(5, 3))
    s = sj.forecast_scores(ens, y)
    pairs = np.sum(np.abs(ens[:, None] - ens[None]), axis=(0, 1))
    absolute = np.mean(np.abs(ens - y), axis=0)
    np.testing.assert_allclose(s.crps, absolute - 0.5 * pairs / (7 * 6), rtol=1e-12)  # fair
    empirical = sj.forecast_scores(ens, y, fair=False)
    np.testing.assert_allclose(empirical.crps, absolute - 0.5 * pairs / 7**2, rtol=1e-12)
    np.testing.assert_allclose(s.error, ens.mean(0) - y)
    np.testing.assert_allclose(s.rmse, np.sqrt(np.mean((ens.mean(0) - y) ** 2, axis=-1)))
    for fair in (True, False):
        point = sj.forecast_scores(ens[:1], y, fair=fair)
        np.testing.assert_allclose(point.crps, np.abs(ens[0] - y), rtol=1e-12)
        assert np.all(np.isnan(point.spread))
    single = sj.forecast_scores(ens[:, 0], y[0])  # (m, k) and (k,)
    np.testing.assert_allclose(single.crps[0], s.crps[0])
    with pytest.raises(ValueError, match="same times"):
        sj.forecast_scores(ens, y[:4])
    with pytest.raises(ValueError, match="finite"):
        sj.forecast_scores(ens, np.full_like(y, np.nan))


def test_calibrated_ensembles_have_flat_ranks_and_narrow_ones_do_not():
    m, T, k = 19, 400, 10
    rng = np.random.default_rng(1)
    y = rng.normal(size=(T, k))
    good = sj.forecast_scores(rng.normal(size=(m, T, k)), y)
    counts, expected = good.rank_histogram, T * k / (m + 1)
    assert counts.sum() == T * k
    chi2 = np.sum((counts - expected) ** 2 / expected)  # 19 degrees of freedom
    assert chi2 < 43.8, chi2  # (its 99.9 % quantile)
    ratio = np.mean(good.spread) / np.sqrt(np.mean(good.rmse**2))
    assert abs(ratio - np.sqrt(m / (m + 1))) < 0.03, ratio
    narrow = sj.forecast_scores(0.3 * rng.normal(size=(m, T, k)), y)
    h = narrow.rank_histogram
    assert h[0] + h[-1] > 0.5 * T * k  # U-shaped
    assert np.mean(narrow.spread) / np.sqrt(np.mean(narrow.rmse**2)) < 0.4
    assert np.mean(narrow.crps) > np.mean(good.crps)


def test_paired_comparison_intervals_cover_the_true_difference():
    # b ~ 1 + N(0, 0.1^2) per start, a = b + 0.05 + N(0, 0.02^2): the start-to-start
    # variation is shared, so only the pairing makes the difference's interval narrow
    rng = np.random.default_rng(6)
    sets, n, true_difference = 300, 16, 0.05
    true_relative = true_difference / 1.0
    covered = covered_relative = 0
    for seed in range(sets):
        b = 1 + 0.1 * rng.normal(size=n)
        a = b + true_difference + 0.02 * rng.normal(size=n)
        c = sj.paired_comparison(a, b, n_boot=1000, seed=seed)
        covered += c.difference_ci[0] <= true_difference <= c.difference_ci[1]
        covered_relative += c.relative_ci[0] <= true_relative <= c.relative_ci[1]
    assert 0.80 <= covered / sets <= 0.97, covered / sets
    assert 0.80 <= covered_relative / sets <= 0.97, covered_relative / sets


def test_paired_comparison_fields_str_and_trailing_axes():
    rng = np.random.default_rng(7)
    b = 1 + 0.1 * rng.normal(size=(16, 5, 3))
    a = 0.95 * b + 0.01 * rng.normal(size=b.shape)
    c = sj.paired_comparison(a, b)
    per_start_a, per_start_b = a.mean(axis=(1, 2)), b.mean(axis=(1, 2))
    assert c.n == 16 and c.level == 0.9 and c.n_boot == 10000
    np.testing.assert_allclose(c.mean_a, per_start_a.mean())
    np.testing.assert_allclose(c.difference, np.mean(per_start_a - per_start_b))
    np.testing.assert_allclose(c.relative, c.difference / c.mean_b)
    assert c.difference_ci[0] < c.difference < c.difference_ci[1] < 0
    assert c.relative_ci[0] < c.relative < c.relative_ci[1] < 0
    # the bootstrap SD of a mean difference: about the differences' SD / sqrt(n)
    naive = np.std(per_start_a - per_start_b, ddof=1) / np.sqrt(16)
    assert 0.8 * naive < c.standard_error < 1.05 * naive
    lo, hi = c.relative_ci
    assert str(c) == (
        f"{100 * c.relative:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] "
        "(90 % CI, 16 starts, paired bootstrap)"
    )
    assert sj.paired_comparison(a, b, seed=1) != c  # another resampling
    assert sj.paired_comparison(a, b) == c  # the same seed: the same intervals


@pytest.mark.parametrize(
    "a,b,kwargs,match",
    [
        (np.ones(5), np.ones(6), {}, "same shape"),
        (np.ones(1), np.ones(1), {}, "n_starts >= 2"),
        (np.float64(1.0), np.float64(1.0), {}, "n_starts >= 2"),
        (np.ones(5), np.ones(5), {"level": 1.0}, "level"),
        (np.ones(5), np.ones(5), {"level": 0.0}, "level"),
        (np.ones(5), np.ones(5), {"n_boot": 99}, "n_boot"),
        (np.ones(5), np.ones(5), {"n_boot": 1000.0}, "n_boot"),
        (np.array([1.0, np.nan, 1, 1, 1]), np.ones(5), {}, "a must be finite"),
        (np.ones(5), np.array([1.0, np.inf, 1, 1, 1]), {}, "b must be finite"),
    ],
)
def test_paired_comparison_refusals(a, b, kwargs, match):
    with pytest.raises(ValueError, match=match):
        sj.paired_comparison(a, b, **kwargs)


def test_paired_comparison_of_scores_whose_mean_changes_sign_has_no_relative_difference():
    a, b = np.array([1.0, -0.5, 0.2, -0.4]), np.array([0.5, -1.0, 0.1, 0.3])
    c = sj.paired_comparison(a, b, n_boot=200)
    assert np.isnan(c.relative) and np.all(np.isnan(c.relative_ci))
    np.testing.assert_allclose(c.difference, np.mean(a - b))
    assert str(c).startswith(f"difference {c.difference:.3g} [")
