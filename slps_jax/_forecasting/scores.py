"""Forecast scores of an ensemble against a truth: error, spread, CRPS, ranks; and the
paired comparison of two forecast systems' scores over the same starts."""

from __future__ import annotations

import dataclasses

import numpy as np


def _real_array(name, value, where):
    """`value` as a float array, or a ValueError naming `name` if it is not finite real."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise ValueError(
            f"{where}: {name} must be real numbers, got an array of dtype {arr.dtype}."
        )
    arr = arr.astype(float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: {name} must be finite (it has NaN or infinite values).")
    return arr


def crps_ensemble(ensemble, truth, *, fair=True):
    """The continuous ranked probability score (CRPS) of an ensemble against the truth.

    $\\frac1m \\sum_i |x_i - y| - \\frac12 S$ for the members $x_1 \\ldots x_m$ and the
    truth $y$, with $S = \\sum_{i,j} |x_i - x_j| / (m(m-1))$ (`fair=True`) or $/ m^2$
    (`fair=False`).

    - `fair=True`: the fair CRPS (Ferro 2014), an unbiased estimate, for every `m`, of the
      CRPS of the distribution the members are drawn from: scores of ensembles of different
      sizes are comparable. `scoringrules.crps_ensemble`'s `"fair"` (and `"pwm"`) estimator.
    - `fair=False`: the CRPS of the ensemble's empirical distribution (`m` equally likely
      values), larger in expectation by $E|X - X'| / (2m)$ for members drawn i.i.d.
      `scoringrules`' `"qd"` (its default), `"nrg"` and `"int"` estimators.

    The pair sum is computed in $O(m \\log m)$ from the sorted members:
    $\\sum_{i,j} |x_i - x_j| = 2 \\sum_k (2k - m + 1) x_{(k)}$.

    **Arguments:**

    - `ensemble`: `(m, ...)`, the members first.
    - `truth`: `(...)`, the shape of one member.
    - `fair`: which estimator (above); the fair CRPS needs `m >= 2`. With `fair=False` and
      `m = 1` the score is the absolute error.

    Real and finite. **Returns:** `(...)`, the score of each entry.
    """
    where = "crps_ensemble"
    ens = _real_array("ensemble", ensemble, where)
    y = _real_array("truth", truth, where)
    if ens.ndim < 1 or y.shape != ens.shape[1:]:
        raise ValueError(
            f"{where}: ensemble must be (m, ...) with the members first and truth (...) the "
            f"shape of one member, got {np.shape(ensemble)} and {np.shape(truth)}."
        )
    m = ens.shape[0]
    if m < 1:
        raise ValueError(f"{where}: ensemble must have at least one member, got m = 0.")
    if fair and m < 2:
        raise ValueError(
            f"{where}: the fair CRPS (fair=True) needs at least two members, got m = {m}; "
            "fair=False gives the absolute error of one member."
        )
    absolute = np.mean(np.abs(ens - y), axis=0)
    if m == 1:
        return absolute
    weights = 2.0 * np.arange(m) - m + 1  # sum_{i,j} |x_i - x_j| = 2 sum_k w_k x_(k)
    pair_sum = 2.0 * np.tensordot(weights, np.sort(ens, axis=0), axes=(0, 0))
    spread = pair_sum / (m * (m - 1) if fair else m * m)
    return absolute - 0.5 * spread


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
      (`crps_ensemble`): the fair CRPS by default (`fair=True`: unbiased for the CRPS of the
      distribution the members are drawn from, comparable across ensemble sizes), the CRPS
      of the members' empirical distribution with `fair=False`; for one member the absolute
      error either way.
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


def forecast_scores(ensemble, truth, *, fair=True):
    """Scores of an ensemble forecast of observables against the truth.

    **Arguments:**

    - `ensemble`: `(m, T, k)` (members, times, observables) or `(m, k)`: for example the
      ℓ = 1…3 coefficients (`zeitlin.mat2shr`), energy, enstrophy, or the field at chosen
      points (`zeitlin.field`) of each member's saved states.
    - `truth`: `(T, k)` or `(k,)`, the same observables of the truth.
    - `fair`: the CRPS estimator (`crps_ensemble`): the fair CRPS (default) or that of the
      members' empirical distribution (`False`). Ignored for one member (absolute error).

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
    if m < 1:
        raise ValueError("forecast_scores: ensemble must have at least one member, got m = 0.")
    error = ens.mean(axis=0) - y
    rmse = np.sqrt(np.mean(error**2, axis=-1))
    spread = (
        np.sqrt(np.mean(ens.var(axis=0, ddof=1), axis=-1)) if m > 1 else np.full_like(rmse, np.nan)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = spread / rmse
    crps = crps_ensemble(ens, y, fair=bool(fair) and m > 1)
    # ties (a member equal to the truth) split at random would need a key: count them low
    ranks = np.sum(ens < y, axis=0)
    histogram = np.bincount(ranks.ravel(), minlength=m + 1)
    return ForecastScores(error, rmse, spread, ratio, crps, ranks, histogram)


@dataclasses.dataclass(frozen=True)
class PairedComparison:
    """What `paired_comparison` computed: system `a` against system `b` over `n` starts.

    - `n`: the number of starts.
    - `mean_a`, `mean_b`: the mean score of each system over the starts.
    - `difference`: `mean_a - mean_b` (negative: `a` scores lower, better for a CRPS or an
      error), and `difference_ci`, its `(low, high)` percentile-bootstrap interval.
    - `relative`: `difference / mean_b`, and `relative_ci`, the interval of
      `mean(a*) / mean(b*) - 1` over the same resamples. NaN (both) when a resampled mean
      of `b` is zero or the means of `b` change sign: the ratio then means nothing (scores
      of one sign, like a CRPS or an RMSE, are what it is for).
    - `standard_error`: the bootstrap standard deviation of the difference.
    - `level`, `n_boot`: the intervals' confidence level and the number of resamples.

    `str()` gives the relative difference with its interval, e.g.
    `-5.1 % [-5.6, -4.7] (90 % CI, 16 starts, paired bootstrap)` (the difference itself
    when the relative one is NaN).
    """

    n: int
    mean_a: float
    mean_b: float
    difference: float
    difference_ci: tuple[float, float]
    relative: float
    relative_ci: tuple[float, float]
    level: float
    n_boot: int
    standard_error: float

    def __str__(self):
        tail = f"({100 * self.level:g} % CI, {self.n} starts, paired bootstrap)"
        if np.isnan(self.relative):
            lo, hi = self.difference_ci
            return f"difference {self.difference:.3g} [{lo:.3g}, {hi:.3g}] {tail}"
        lo, hi = self.relative_ci
        return f"{100 * self.relative:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] {tail}"


def paired_comparison(a, b, *, level=0.9, n_boot=10000, seed=0):
    """Compare the scores of two forecast systems over the same starts: the mean difference
    and the relative one, with paired percentile-bootstrap intervals.

    The starts are resampled with replacement, each start's pair of scores kept together,
    so the intervals account for how the two systems' scores vary together from start to
    start (most of the variation, usually: some starts are hard for both).

    **Arguments:**

    - `a`, `b`: `(n_starts,)` or `(n_starts, ...)`, the scores of each system (for example
      `forecast_scores(...).crps` per start) over the same starts in the same order; trailing
      axes are averaged per start first. Same shape, real and finite, `n_starts >= 2`.
    - `level`: the confidence level of the intervals, in `(0, 1)`.
    - `n_boot`: the number of bootstrap resamples, at least 100.
    - `seed`: the seed of the resampling (`numpy.random.default_rng`).

    **Returns:** `PairedComparison` (`str()` of it reads
    `-5.1 % [-5.6, -4.7] (90 % CI, 16 starts, paired bootstrap)`).
    """
    where = "paired_comparison"
    if np.shape(a) != np.shape(b):
        raise ValueError(
            f"{where}: a and b must be the scores of the same starts with the same shape, got "
            f"{np.shape(a)} and {np.shape(b)}."
        )
    if np.ndim(a) < 1 or np.shape(a)[0] < 2:
        raise ValueError(
            f"{where}: a and b must be (n_starts, ...) with n_starts >= 2, got shape {np.shape(a)}."
        )
    if isinstance(level, bool) or not isinstance(level, (int, float, np.integer, np.floating)):
        raise ValueError(f"{where}: level must be a number in (0, 1), got {level!r}.")
    if not 0.0 < float(level) < 1.0:
        raise ValueError(f"{where}: level must be in (0, 1), got {level!r}.")
    if isinstance(n_boot, bool) or not isinstance(n_boot, (int, np.integer)) or n_boot < 100:
        raise ValueError(f"{where}: n_boot must be an integer >= 100, got {n_boot!r}.")
    x = _real_array("a", a, where)
    z = _real_array("b", b, where)
    n = x.shape[0]
    x = x.reshape(n, -1).mean(axis=1)
    z = z.reshape(n, -1).mean(axis=1)
    level, n_boot = float(level), int(n_boot)

    rng = np.random.default_rng(seed)
    boot_a, boot_b = np.empty(n_boot), np.empty(n_boot)
    chunk = max(1, 2**22 // n)  # bound the (resamples, n) index array's memory
    for start in range(0, n_boot, chunk):
        stop = min(start + chunk, n_boot)
        idx = rng.integers(0, n, size=(stop - start, n))
        boot_a[start:stop] = x[idx].mean(axis=1)
        boot_b[start:stop] = z[idx].mean(axis=1)
    tails = [(1.0 - level) / 2, (1.0 + level) / 2]
    boot_diff = boot_a - boot_b
    diff_lo, diff_hi = np.quantile(boot_diff, tails)

    mean_a, mean_b = float(x.mean()), float(z.mean())
    if np.all(boot_b > 0) or np.all(boot_b < 0):
        relative = (mean_a - mean_b) / mean_b
        rel_lo, rel_hi = np.quantile(boot_a / boot_b - 1.0, tails)
    else:  # a resampled mean of b is zero, or they change sign: said in PairedComparison
        relative = rel_lo = rel_hi = np.nan
    return PairedComparison(
        n=n,
        mean_a=mean_a,
        mean_b=mean_b,
        difference=mean_a - mean_b,
        difference_ci=(float(diff_lo), float(diff_hi)),
        relative=float(relative),
        relative_ci=(float(rel_lo), float(rel_hi)),
        level=level,
        n_boot=n_boot,
        standard_error=float(np.std(boot_diff, ddof=1)),
    )
