"""Verification of a stochastic forecast system against a truth, as a specialist would: the
ensembles of chosen starts, one amplitude factor of the noise tuned on starts inside the
training period (fair CRPS), and the scores of held-out starts (`paired_comparison`)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._brownian import BrownianMotion, OrnsteinUhlenbeck, sample_keys
from .._driver.failures import Failures, check_failures
from .._driver.integrate import ensemble
from .._driver.plan import check_driver, check_method, check_system, driver_path
from .._support.checks import check_count, check_option, check_positive
from .scores import crps_ensemble

FACTORS = tuple(2.0 ** np.arange(-3.0, 3.25, 0.5))  # 1/8 ... 8, ratios of sqrt 2


@dataclasses.dataclass(frozen=True)
class AmplitudeSearch:
    r"""The factors `tune_amplitude` tries.

    **Arguments:**

    - `factors`: the candidates (default `FACTORS`, 1/8 ... 8 in ratios of $\sqrt 2$), 2 or
      more positive numbers, tried in ascending order until the CRPS has risen above its
      least value twice in a row, or a member fails (then larger factors are not tried).
    - `refine`: then also try the geometric midpoints between the best factor and its
      neighbours (default `True`: a grid twice as fine near the optimum).
    - `scale`: how a factor acts on the system, `scale(system, factor) -> system` with the
      same structure (default `None`: its noise family times the factor, `scaled_noise`);
      for example `lambda s, f: fit.scaled(f)` for a `ClosureFit`, whose transport and
      additive noises are scaled together.
    """

    factors: tuple = FACTORS
    refine: bool = True
    scale: Callable | None = None

    def __post_init__(self):
        factors = np.asarray(self.factors, dtype=float)
        if (
            factors.ndim != 1
            or factors.size < 2
            or not np.all(np.isfinite(factors) & (factors > 0))
        ):
            raise ValueError(
                f"AmplitudeSearch: factors must be 2 or more positive numbers, got {self.factors}."
            )
        object.__setattr__(self, "factors", tuple(float(f) for f in np.sort(factors)))
        if not isinstance(self.refine, (bool, np.bool_)):
            raise TypeError(f"AmplitudeSearch: refine must be True or False, got {self.refine!r}.")
        if self.scale is not None and not callable(self.scale):
            raise TypeError(
                f"AmplitudeSearch: scale must be a function (system, factor) -> system, got "
                f"{self.scale!r}."
            )


def scaled_noise(noise, factor):
    """The noise family `noise` with every amplitude (its arrays' leaves) times `factor`.

    **Arguments:**

    - `noise`: a noise family, a pytree whose array leaves are its amplitudes (for example
      `salt_noise(X)`, or `TransportNoiseFit.noise`).
    - `factor`: the amplitude factor, a scalar (`tune_amplitude` tunes it).

    **Returns:** a noise family of the same kind, every leaf times `factor` (for
    `salt_noise(X)`: `salt_noise(factor * X)`).
    """
    return jax.tree_util.tree_map(lambda x: factor * x, noise)


def forecast_ensembles(
    system,
    starts,
    *,
    lead,
    dt,
    every,
    members,
    key,
    driver: BrownianMotion | OrnsteinUhlenbeck | None = None,
    method="auto",
    failures: Failures = Failures(),
):
    r"""Each start's ensemble forecast: the states at `every, 2 every, ..., lead` steps of
    `dt` after the start, all starts run as one batched program: what
    `simulate(system, starts[s], ..., key=fold_in(key, s), driver=driver)` gives.

    **Arguments:**

    - `system`: the stochastic system (for example `EulerZeitlin(N, noise=...)`).
    - `starts`: `(n_starts, *state)` initial states (the truth's, coarse-grained).
    - `lead`, `every`: steps to the last lead time, and between saved times (`lead` a
      multiple of `every`); `dt`: the step size (positive); `members`: members per start.
    - `key`: start `s` draws from `fold_in(key, s)`: a start's ensemble does not depend on
      the others, and common random numbers make factors comparable (`tune_amplitude`).
    - `driver`: as for `simulate` (`OrnsteinUhlenbeck(T)` for a noise fitted with
      `time_model="ou"`), but `None` stands for `BrownianMotion(levy_area=False)`:
      forecasts are judged in distribution, where the methods are weak order 1 without the
      areas (of mean zero), and drawing the areas of many noises dominates the cost.
    - `method`, `failures`: as for `simulate`; but a member that fails (even split into
      substeps) raises `RuntimeError` whatever `throw` says: forecasts are not scored with
      failed members.

    **Returns:** a NumPy array `(n_starts, members, lead // every, *state)`.
    """
    run = forecast_setup(
        "forecast_ensembles",
        system,
        starts,
        lead,
        dt,
        every,
        members,
        key,
        driver,
        method,
        failures,
    )
    ys, fail_step = _forecasts(*run.arguments)
    failed = int(np.sum(np.asarray(fail_step) >= 0))
    refuse_failed("forecast_ensembles", failed, fail_step.size, run.failures, "they are not scored")
    return np.asarray(ys)


class ForecastRun(NamedTuple):
    """A checked forecast: `_forecasts`'s arguments (`arguments`), and the failure options."""

    arguments: tuple
    failures: Failures


def forecast_setup(caller, system, starts, lead, dt, every, members, key, driver, method, failures):
    """`forecast_ensembles`'s arguments checked (by name, for `caller`), and the keys, path
    and start states of its program."""
    lead, every = check_count("lead", lead), check_count("every", every)
    members = check_count("members", members)
    if lead % every:
        raise ValueError(f"{caller}: lead = {lead} must be a multiple of every = {every}.")
    dt = float(np.asarray(check_positive("dt", dt)))
    check_system(system)
    method = check_method(method, system)
    failures = check_failures(caller, failures)
    starts = jnp.asarray(starts)
    if starts.ndim != len(system.algebra.shape) + 1 or starts.shape[1:] != system.algebra.shape:
        raise ValueError(
            f"{caller}: starts must be (n_starts, *{system.algebra.shape}), states of "
            f"{system.algebra.name}, got shape {starts.shape}."
        )
    dtype = system.dtype
    drawer = check_driver(BrownianMotion(levy_area=False) if driver is None else driver)
    path = driver_path(drawer, dt, method, system, dtype)
    # start s's member i draws from fold_in(fold_in(key, s), i), as simulate's sample i does
    keys = jax.vmap(lambda s: sample_keys(jax.random.fold_in(key, s), members))(
        jnp.arange(starts.shape[0], dtype=jnp.uint32)
    )
    y0 = starts.astype(system.algebra.state_dtype(dtype))
    arguments = (method, system, y0, keys, path, lead // every, every, failures.retry_substeps)
    return ForecastRun(arguments, failures)


def refuse_failed(caller, failed, total, failures, why):
    """Raise `RuntimeError` if `failed` of `total` members failed: `why` says what that
    stops."""
    if failed:
        raise RuntimeError(
            f"{caller}: {failed} of {total} members failed (their steps could not be "
            f"solved{'' if failures.retried else ', and Failures(retry_substeps=None)'}): "
            f"{why}."
        )


@functools.partial(jax.jit, static_argnames=("method", "n_blocks", "every", "retry"))
def _forecasts(method, system, starts, keys, path, n_blocks, every, retry):
    """Every start's members in one program: `simulate`'s ensemble (the driver's loop, each
    member drawing its steps' noise from its key) under a `vmap` over the starts; the saved
    states after the start and each member's failed step (-1: none)."""

    def start(y0, member_keys):
        ys, fail_step, *_ = ensemble(
            method, system, y0, member_keys, path, n_blocks, every, False, retry
        )
        return ys, fail_step

    return jax.vmap(start)(starts, keys)


def start_crps(ensembles, truth, observe):
    """Each start's mean fair CRPS (`crps_ensemble`, Ferro 2014) over its lead times and
    observables: the per-start scores that `paired_comparison` compares.

    **Arguments:**

    - `ensembles`: `(n_starts, members, T, *state)`, the forecasts (`forecast_ensembles`).
    - `truth`: `(n_starts, T, *state)`, the truth at the same lead times.
    - `observe`: a function from states `(..., *state)` to observables `(..., k)`.

    **Returns:** a NumPy array `(n_starts,)`.
    """
    y = np.asarray(observe(jnp.asarray(truth)))
    x = np.moveaxis(np.asarray(observe(jnp.asarray(ensembles))), 1, 0)  # members first
    return np.mean(crps_ensemble(x, y), axis=tuple(range(1, y.ndim)))


class ModelErrorVariance(NamedTuple):
    """What `model_error_variance` estimates, per lead time and observable `(T, k)`: the
    `variance` of the forecast error that the ensembles' spread does not account for, its
    `stderr` over the starts, and the mean squared error of the ensemble mean (`mse`) and
    mean ensemble variance (`spread`) it is the difference of."""

    variance: np.ndarray
    stderr: np.ndarray
    mse: np.ndarray
    spread: np.ndarray


def model_error_variance(ensembles, truth, observe):
    r"""The variance of forecast errors beyond the ensembles' spread, from forecasts of a
    training period: the error variance an assimilation should add to its observation
    errors (or its forecasts) for its analysis to be calibrated.

    For forecasts whose members and truth are exchangeable (a calibrated ensemble of `m`
    members), the squared error of the ensemble mean $\bar x$ has expectation
    $(1 + 1/m)$ times the expected ensemble variance $s^2$. An error $e$ of the model's
    own, shared by the members and independent of their spread, adds its variance:
    $E|\bar x - x|^2 = \sigma_e^2 + (1 + 1/m)\,E s^2$. So
    $\hat\sigma_e^2 = \overline{(\bar x - x)^2} - (1 + 1/m)\,\overline{s^2}$, means over
    the starts, with $s^2$ the unbiased variance over the members; its standard error is
    that of the per-start differences. It can be negative (an overdispersed ensemble):
    it is not clipped.

    **Arguments:**

    - `ensembles`: `(n_starts, members, T, *state)`, the forecasts (`forecast_ensembles`),
      `n_starts >= 2`, `members >= 2`.
    - `truth`: `(n_starts, T, *state)`, the truth at the same lead times (not observed
      with error: its observation errors would count as the model's).
    - `observe`: a function from states `(..., *state)` to observables `(..., k)`.

    **Returns:** a `ModelErrorVariance`, arrays `(T, k)`.
    """
    y = np.asarray(observe(jnp.asarray(truth)))
    x = np.asarray(observe(jnp.asarray(ensembles)))
    if x.ndim != 4 or y.shape != (x.shape[0], *x.shape[2:]):
        raise ValueError(
            f"model_error_variance: observe(ensembles) must be (n_starts, members, T, k) and "
            f"observe(truth) (n_starts, T, k), got {x.shape} and {y.shape}."
        )
    n, m = x.shape[:2]
    if n < 2 or m < 2:
        raise ValueError(
            f"model_error_variance: needs 2 or more starts and members, got {n} and {m}."
        )
    err2 = (x.mean(1) - y) ** 2
    var = x.var(1, ddof=1)
    d = err2 - (1.0 + 1.0 / m) * var
    return ModelErrorVariance(d.mean(0), d.std(0, ddof=1) / np.sqrt(n), err2.mean(0), var.mean(0))


@dataclasses.dataclass(frozen=True)
class AmplitudeTuning:
    """What `tune_amplitude` found: the `factor` of least mean fair CRPS, the `factors`
    tried (ascending) and their `crps`, the mean over starts, lead times and observables
    (`inf` for a factor some of whose members failed)."""

    factor: float
    factors: np.ndarray
    crps: np.ndarray


def tune_amplitude(
    system,
    starts,
    truth,
    *,
    observe,
    lead,
    dt,
    every,
    members,
    key,
    search: AmplitudeSearch = AmplitudeSearch(),
    driver=None,
    method="auto",
):
    r"""One amplitude factor of a system's noise, tuned on forecasts: the factor among
    `search.factors` whose ensembles (`forecast_ensembles` of `system` with its noise family
    scaled by it, `scaled_noise`) have the least mean fair CRPS of `observe` against
    `truth`. Use starts inside the training period only, and score the tuned noise on
    held-out starts.

    **Arguments:**

    - `system`: the system forecast, whose noise family is scaled (or as `search.scale`
      says), for example `EulerZeitlin(N, noise=fit_transport_noise(...).noise)`.
    - `starts`: `(n_starts, *state_shape)`, the initial states, as for `forecast_ensembles`.
    - `truth`: `(n_starts, lead // every, *state_shape)`, the truth at the lead times.
    - `observe`: states `(..., *state_shape)` to observables `(..., k)`, chosen before
      scoring.
    - `search`: an `AmplitudeSearch`: the candidates and whether to refine near the best.
      Every factor uses the same `key` (common random numbers), and failing steps are not
      retried.
    - `lead`, `dt`, `every`, `members`, `key`: as for `forecast_ensembles`.
    - `driver`, `method`: as for `simulate`.

    **Returns:** an `AmplitudeTuning`: the best `factor`, and every factor tried (ascending)
    with its mean CRPS (`inf` where a member failed). Raises `RuntimeError` if every
    factor's forecasts had failed members.
    """
    check_option("tune_amplitude", "search", search, AmplitudeSearch)
    amplitudes = jax.tree_util.tree_leaves(getattr(system, "noise", None))
    if search.scale is None and not any(np.any(np.asarray(a) != 0) for a in amplitudes):
        raise ValueError(
            f"tune_amplitude: the system has no noise amplitudes to scale (none, or all "
            f"zero): {system!r}."
        )
    factors, refine = np.asarray(search.factors), search.refine
    scale = search.scale or (
        lambda s, f: eqx.tree_at(lambda s: s.noise, s, scaled_noise(s.noise, f))
    )

    def score(f):
        try:
            ens = forecast_ensembles(
                scale(system, f),
                starts,
                lead=lead,
                dt=dt,
                every=every,
                members=members,
                key=key,
                driver=driver,
                method=method,
                failures=Failures(retry_substeps=None),
            )
        except RuntimeError:  # (a member failed)
            return np.inf
        return float(np.mean(start_crps(ens, truth, observe)))

    tried, crps = [], []
    for f in np.sort(factors):
        tried.append(float(f))
        crps.append(score(f))
        if not np.isfinite(crps[-1]):  # (larger factors fail too)
            break
        if len(crps) >= 3 and min(crps[-2:]) > min(crps):
            break
    if not np.any(np.isfinite(crps)):
        raise RuntimeError("tune_amplitude: every factor's forecasts had failed members.")
    if refine:  # the geometric midpoints on either side of the best
        b = int(np.argmin(crps))
        for j in (b - 1, b + 1):
            if 0 <= j < len(tried) and np.isfinite(crps[j]):
                tried.append(float(np.sqrt(tried[b] * tried[j])))
                crps.append(score(tried[-1]))
    order = np.argsort(tried)
    tried, crps = np.asarray(tried)[order], np.asarray(crps)[order]
    return AmplitudeTuning(float(tried[int(np.argmin(crps))]), tried, crps)
