"""Verification of a stochastic forecast system against a truth, as a specialist would: the
ensembles of chosen starts, one amplitude factor of the noise tuned on starts inside the
training period (fair CRPS), and the scores of held-out starts (`paired_comparison`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .._driver.integrate import simulate
from .._support.checks import check_count, check_positive
from .._systems.euler_zeitlin import EulerZeitlin
from .scores import crps_ensemble

FACTORS = 2.0 ** np.arange(-3.0, 3.25, 0.5)  # 1/8 ... 8, ratios of sqrt 2


def scaled_noise(noise, factor):
    """The noise family `noise` with every amplitude (its arrays' leaves) times `factor`."""
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
    driver=None,
    method="auto",
    retry_substeps: int | None = 4,
):
    r"""Each start's ensemble forecast, `(n_starts, members, lead // every, *state)`: the
    states at `every, 2 every, ..., lead` steps of `dt` after the start (`simulate`).

    - `system`: the stochastic system (for example `EulerZeitlin(N, noise=...)`).
    - `starts`: `(n_starts, *state)` initial states (the truth's, coarse-grained).
    - `lead`, `every`: steps to the last lead time, and between saved times (`lead` a
      multiple of `every`); `members`: members per start.
    - `key`: start `s` draws from `fold_in(key, s)`: a start's ensemble does not depend on
      the others, and common random numbers make factors comparable (`tune_amplitude`).
    - `driver`, `method`, `retry_substeps`: as for `simulate` (`driver=OrnsteinUhlenbeck(T)`
      for a noise fitted with `time_model="ou"`).

    A member that fails raises `RuntimeError`: forecasts are not scored with failed members.
    """
    lead, every = check_count("lead", lead), check_count("every", every)
    members = check_count("members", members)
    if lead % every:
        raise ValueError(
            f"forecast_ensembles: lead = {lead} must be a multiple of every = {every}."
        )
    dt = float(np.asarray(check_positive("dt", dt)))
    starts = jnp.asarray(starts)
    out = []
    for s in range(starts.shape[0]):
        sol = simulate(
            system,
            starts[s],
            t1=lead * dt,
            dt=dt,
            n_samples=members,
            key=jax.random.fold_in(key, s),
            method=method,
            save_every=every,
            throw=True,
            retry_substeps=retry_substeps,
            driver=driver,
        )
        out.append(np.asarray(sol.ys)[:, 1:])
    return np.stack(out)


def start_crps(ensembles, truth, observe):
    """Each start's mean fair CRPS over its lead times and observables, `(n_starts,)`:
    `ensembles` `(n_starts, members, T, *state)` (`forecast_ensembles`), `truth`
    `(n_starts, T, *state)`, `observe` states to observables `(..., k)`; the per-start
    scores that `paired_comparison` compares."""
    y = np.asarray(observe(jnp.asarray(truth)))
    x = np.moveaxis(np.asarray(observe(jnp.asarray(ensembles))), 1, 0)  # members first
    return np.mean(crps_ensemble(x, y), axis=tuple(range(1, y.ndim)))


@dataclasses.dataclass(frozen=True)
class AmplitudeTuning:
    """What `tune_amplitude` found: the `factor` of least mean fair CRPS, the `factors`
    tried (ascending) and their `crps`, the mean over starts, lead times and observables
    (`inf` for a factor some of whose members failed)."""

    factor: float
    factors: np.ndarray
    crps: np.ndarray


def tune_amplitude(
    noise,
    starts,
    truth,
    *,
    N,
    observe,
    lead,
    dt,
    every,
    members,
    key,
    factors=None,
    driver=None,
    method="auto",
):
    r"""One amplitude factor of a transport noise, tuned on forecasts: the factor among
    `factors` whose ensembles (`forecast_ensembles` of `EulerZeitlin(N, noise=f * noise)`)
    have the least mean fair CRPS of `observe` against `truth`. Use starts inside the
    training period only, and score the tuned noise on held-out starts.

    - `truth`: `(n_starts, lead // every, N, N)`, the truth at the lead times.
    - `observe`: states `(..., N, N)` to observables `(..., k)`, chosen before scoring.
    - `factors`: the candidates (default `FACTORS`, 1/8 ... 8 in ratios of $\sqrt 2$),
      tried in ascending order until the CRPS has risen above its least value twice in a
      row, or a member fails (then larger factors are not tried); every factor uses the
      same `key` (common random numbers), and failing steps are not retried.
    - `driver`, `method`: as for `simulate`.
    """
    factors = np.asarray(FACTORS if factors is None else factors, dtype=float)
    if factors.ndim != 1 or factors.size < 2 or not np.all(np.isfinite(factors) & (factors > 0)):
        raise ValueError(
            f"tune_amplitude: factors must be 2 or more positive numbers, got {factors}."
        )
    factors, tried, crps = np.sort(factors), [], []
    for f in factors:
        tried.append(f)
        try:
            ens = forecast_ensembles(
                EulerZeitlin(N, noise=scaled_noise(noise, f)),
                starts,
                lead=lead,
                dt=dt,
                every=every,
                members=members,
                key=key,
                driver=driver,
                method=method,
                retry_substeps=None,
            )
        except RuntimeError:  # (a member failed: this factor and larger ones are out)
            crps.append(np.inf)
            break
        crps.append(float(np.mean(start_crps(ens, truth, observe))))
        if len(crps) >= 3 and min(crps[-2:]) > min(crps):
            break
    crps = np.asarray(crps)
    if not np.any(np.isfinite(crps)):
        raise RuntimeError("tune_amplitude: every factor's forecasts had failed members.")
    return AmplitudeTuning(float(tried[int(np.argmin(crps))]), np.asarray(tried), crps)
