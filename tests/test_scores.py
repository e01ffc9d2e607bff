"""`forecast_scores` against the CRPS written out, and against exchangeable ensembles
(calibrated: flat ranks, spread/RMSE -> sqrt(m / (m + 1))) and too narrow ones."""

import numpy as np
import pytest

import slps_jax as sj


def test_crps_is_the_kernel_formula_and_a_point_forecast_scores_its_absolute_error():
    rng = np.random.default_rng(0)
    ens, y = rng.normal(size=(7, 5, 3)), rng.normal(size=(5, 3))
    s = sj.forecast_scores(ens, y)
    ref = np.mean(np.abs(ens - y), axis=0) - 0.5 * np.mean(
        np.abs(ens[:, None] - ens[None]), axis=(0, 1)
    )
    np.testing.assert_allclose(s.crps, ref, rtol=1e-12)
    np.testing.assert_allclose(s.error, ens.mean(0) - y)
    np.testing.assert_allclose(s.rmse, np.sqrt(np.mean((ens.mean(0) - y) ** 2, axis=-1)))
    point = sj.forecast_scores(ens[:1], y)
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
