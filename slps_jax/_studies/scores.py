"""Forecast scores of an ensemble against a truth: error, spread, CRPS, ranks."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class ForecastScores:
    """What `forecast_scores` computed, for `T` times and `k` observables.

    - `error`: `(T, k)`, the ensemble mean minus the truth.
    - `rmse`: `(T,)`, the ensemble mean's root-mean-square error over the observables.
    - `spread`: `(T,)`, the root of the ensemble variance (`ddof=1`), averaged over the
      observables.
    - `ratio`: `spread / rmse` (about 1 for an ensemble whose spread matches its error:
      $\\sqrt{m/(m+1)}$ for `m` members drawn like the truth).
    - `crps`: `(T, k)`, the continuous ranked probability score of the ensemble
      (`scoringrules.crps_ensemble`; for one member the absolute error).
    - `ranks`: `(T, k)`, the rank of the truth among the members, `0 ... m`.
    - `rank_histogram`: `(m + 1,)`, how often each rank occurs (flat for a calibrated
      ensemble; U-shaped if it is too narrow, peaked if too wide).
    """

    error: np.ndarray
    rmse: np.ndarray
    spread: np.ndarray
    ratio: np.ndarray
    crps: np.ndarray
    ranks: np.ndarray
    rank_histogram: np.ndarray


def forecast_scores(ensemble, truth):
    """Scores of an ensemble forecast of observables against the truth.

    **Arguments:**

    - `ensemble`: `(m, T, k)` (members, times, observables) or `(m, k)`: for example the
      ℓ = 1…3 coefficients (`zeitlin.mat2shr`), energy, enstrophy, or the field at chosen
      points (`zeitlin.field`) of each member's saved states.
    - `truth`: `(T, k)` or `(k,)`, the same observables of the truth.

    Real and finite; `m >= 1` (the spread needs `m >= 2`: NaN otherwise, said in the
    result). **Returns:** `ForecastScores` (times first; `T = 1` for `(m, k)` input).
    """
    ens = np.asarray(ensemble, dtype=float)
    y = np.asarray(truth, dtype=float)
    if ens.ndim == 2:
        ens = ens[:, None]
    if y.ndim == 1:
        y = y[None]
    if ens.ndim != 3 or y.shape != ens.shape[1:]:
        raise ValueError(
            f"forecast_scores: ensemble must be (m, T, k) or (m, k) and truth (T, k) or (k,) "
            f"of the same times and observables, got {np.shape(ensemble)} and {np.shape(truth)}."
        )
    if not (np.all(np.isfinite(ens)) and np.all(np.isfinite(y))):
        raise ValueError("forecast_scores: the ensemble and the truth must be finite.")
    m = ens.shape[0]
    error = ens.mean(axis=0) - y
    rmse = np.sqrt(np.mean(error**2, axis=-1))
    spread = (
        np.sqrt(np.mean(ens.var(axis=0, ddof=1), axis=-1)) if m > 1 else np.full_like(rmse, np.nan)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = spread / rmse
    import scoringrules  # (here: with numba installed it takes seconds to import)

    crps = np.asarray(scoringrules.crps_ensemble(y, ens, m_axis=0, backend="numpy"))
    # ties (a member equal to the truth) split at random would need a key: count them low
    ranks = np.sum(ens < y, axis=0)
    histogram = np.bincount(ranks.ravel(), minlength=m + 1)
    return ForecastScores(error, rmse, spread, ratio, crps, ranks, histogram)
