r"""The building blocks of a particle filter on the coadjoint orbit (Cotter, Crisan, Holm, Pan &
Shevchenko 2020, arXiv:1907.11884): the effective sample size, adaptive tempering of the
likelihood, systematic resampling, and the preconditioned Crank–Nicolson (pCN) move on a
particle's Brownian increments. Each acts on weights or on increments only, never on states:
resampling copies states, and a pCN move re-runs a particle from its parent's state with new
increments, so that a filter built from them moves particles only along coadjoint orbits.

`assimilate` composes them for any forecast that is a function of a state and its increments;
`particle_filter.py` for the library's systems with its integrators as the forecast.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._brownian import check_key
from .._support.checks import check_count, check_option, is_int, is_real


def effective_sample_size(log_weights):
    r"""$\mathrm{ESS} = (\sum_i w_i)^2 / \sum_i w_i^2$ of unnormalised log-weights, computed
    stably (shifted by their maximum).

    **Arguments:** `log_weights`, shape `(n,)`, finite or `-inf` (a particle of weight 0).

    **Returns:** a scalar in `[1, n]` (`n` for equal weights, 1 for one particle alone).
    """
    lw = jnp.asarray(log_weights)
    w = jnp.exp(lw - jnp.max(lw))
    return jnp.sum(w) ** 2 / jnp.sum(w * w)


@functools.partial(jax.jit, static_argnames="bisections")
def next_temperature(log_likelihood, beta, threshold, *, bisections=50):
    r"""The next exponent $\beta' \in (\beta, 1]$ of adaptive tempering: the largest for which
    the incremental weights $\exp((\beta' - \beta)\,\ell_i)$ keep
    $\mathrm{ESS} \ge$ `threshold` $\cdot n$, or 1 when the whole remaining step does (Jasra,
    Stephens, Doucet & Tsagaris 2011). Found by bisection on $\beta' - \beta$: the ESS of
    $\exp(\delta\ell)$ decreases in $\delta$ (it is $n$ at $\delta = 0$).

    **Arguments:**

    - `log_likelihood`: $\ell_i$, shape `(n,)`, each particle's log-likelihood of the
      observation (finite).
    - `beta`: the current exponent, in `[0, 1)`.
    - `threshold`: the least ESS allowed, as a share of `n`, in `(0, 1)`.
    - `bisections`: the bisection's steps (50: the exponent to about $10^{-15}$).

    **Returns:** $\beta'$, a scalar: 1, or a value whose stage keeps the ESS at or above the
    threshold (the bisection keeps its lower end feasible).
    """
    ell = jnp.asarray(log_likelihood)
    beta = jnp.asarray(beta, ell.dtype)
    n = ell.shape[0]
    target = threshold * n
    remaining = 1.0 - beta

    def ok(delta):
        return effective_sample_size(delta * ell) >= target

    def body(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        good = ok(mid)
        return jnp.where(good, mid, lo), jnp.where(good, hi, mid)

    lo, _ = jax.lax.fori_loop(0, bisections, body, (jnp.zeros_like(beta), remaining))
    return jnp.where(ok(remaining), 1.0, beta + lo)


def systematic_resample(key, log_weights):
    r"""Systematic resampling (Kitagawa 1996): one uniform $U$, the points $(i + U)/n$ against
    the cumulative normalised weights. Unbiased (particle $i$ is copied $n w_i$ times in
    expectation) and of low variance: every count is $\lfloor n w_i\rfloor$ or
    $\lceil n w_i\rceil$.

    **Arguments:** `key`, a JAX key; `log_weights`, shape `(n,)`, unnormalised.

    **Returns:** the parents' indices, shape `(n,)`, in increasing order.
    """
    lw = jnp.asarray(log_weights)
    n = lw.shape[0]
    w = jnp.exp(lw - jax.scipy.special.logsumexp(lw))
    edges = jnp.cumsum(w)
    edges = edges.at[-1].set(1.0)  # (rounding: the last edge is exactly 1)
    u = (jnp.arange(n, dtype=w.dtype) + jax.random.uniform(key, (), w.dtype)) / n
    return jnp.minimum(jnp.searchsorted(edges, u, side="right"), n - 1)


def pcn_proposal(key, increments, rho, dt):
    r"""A preconditioned Crank–Nicolson proposal for Brownian increments of step `dt`:
    $\Delta W' = \rho\,\Delta W + \sqrt{1 - \rho^2}\,\sqrt{h}\,\xi$, $\xi \sim N(0, I)$. It keeps
    the increments' law $N(0, hI)$ exactly (Cotter, Roberts, Stuart & White 2013), so that a
    Metropolis step accepts it with the likelihood's ratio alone.

    **Arguments:** `key`; `increments`, any shape (a particle's increments since the last
    observation); `rho` in `[0, 1]` (1: no move); `dt`, the step $h$.

    **Returns:** the proposed increments, the shape and dtype of `increments`.
    """
    dw = jnp.asarray(increments)
    xi = jax.random.normal(key, dw.shape, dw.dtype)
    return rho * dw + jnp.sqrt(1.0 - rho * rho) * jnp.sqrt(jnp.asarray(dt, dw.dtype)) * xi


def pcn_accept(key, log_likelihood_new, log_likelihood_old, beta):
    r"""The Metropolis test of a pCN move at tempering exponent $\beta$: accept with
    probability $\min(1, \exp(\beta(\ell' - \ell)))$ (the prior's ratio is 1 for pCN).

    **Arguments:** `key`; `log_likelihood_new`, `log_likelihood_old`, shape `(n,)`; `beta`.

    **Returns:** a boolean mask, shape `(n,)`: the particles whose move is accepted.
    """
    new, old = jnp.asarray(log_likelihood_new), jnp.asarray(log_likelihood_old)
    log_u = jnp.log(jax.random.uniform(key, new.shape, new.dtype))
    return log_u < beta * (new - old)


class FilterResult(NamedTuple):
    """What `assimilate` returns, for `n_obs` observations and `n` particles.

    - `particles`: the analysis ensembles, shape `(n_obs, n, *state)` (equally weighted: the
      last tempering stage resamples).
    - `mean`: their means, shape `(n_obs, *state)`.
    - `ess`: at each observation the smallest ESS of a tempering stage's weights before its
      resampling, shape `(n_obs,)`: at least `ess_threshold * n` unless one stage's exponent
      step could not be made small enough (the bisection's floor).
    - `temperatures`: each observation's tempering exponents, a list of arrays ending in 1.
    - `acceptance`: each observation's pCN acceptance rates, one per stage and jitter step.
    - `log_evidence`: the estimate of $\\log p(y_{1:k})$ after each observation, shape
      `(n_obs,)` (the product over stages of the mean incremental weight).
    """

    particles: Any
    mean: Any
    ess: Any
    temperatures: list
    acceptance: list
    log_evidence: Any


MAX_STAGES = 500  # tempering stages per observation before `assimilate` gives up


class Forecast(NamedTuple):
    """What a filter's forecast may return instead of the states alone: the states and which
    particles' forecasts succeeded (a failed one gets likelihood 0: it is never resampled,
    and a pCN move to it is rejected).

    **Arguments:**

    - `states`: the forecast states, `(n, *state)` (or a pytree of such arrays).
    - `ok`: a boolean array `(n,)`.
    """

    states: Any
    ok: Any


def check_filter_options(caller, ess_threshold, jitter_steps, jitter_rho):
    """The tempering's and the jittering's options, refused by name before any work:
    `ess_threshold` in (0, 1], `jitter_steps` an integer >= 0, `jitter_rho` in [0, 1]."""
    if not is_real(ess_threshold) or not 0.0 < float(ess_threshold) <= 1.0:
        raise ValueError(
            f"{caller}: ess_threshold must be a number in (0, 1] (the least share of effective "
            f"particles a tempering stage keeps), got {ess_threshold!r}."
        )
    if not is_int(jitter_steps) or int(jitter_steps) < 0:
        raise ValueError(
            f"{caller}: jitter_steps must be an integer >= 0 (pCN moves per stage), got "
            f"{jitter_steps!r}."
        )
    if not is_real(jitter_rho) or not 0.0 <= float(jitter_rho) <= 1.0:
        raise ValueError(
            f"{caller}: jitter_rho must be a number in [0, 1] (pCN's correlation of the new "
            f"increments with the old: 1 leaves them), got {jitter_rho!r}."
        )


@dataclasses.dataclass(frozen=True, eq=False)
class Observations:
    r"""What a filter assimilates: observed quantities of the states with independent
    Gaussian errors.

    **Arguments:**

    - `values`: `(n_obs, n_y)`, finite.
    - `observe(state) -> (n_y,)`: one state's observed quantities (JAX-traceable).
    - `std`: the errors' standard deviation, a positive scalar or `(n_y,)`; none below
      $\sqrt\epsilon$ of the observations' scale (a point-mass likelihood, which no
      ensemble meets, is refused before any forecast).
    - `times`: `(n_obs,)`, the observation times: increasing, equally spaced, after the
      particles' time, each on the grid of the step from it (`particle_filter`); `None`
      for `assimilate`, whose forecast goes to the next observation whatever its time.
    """

    values: Any
    observe: Callable[..., Any]
    std: Any
    times: Any = None


@dataclasses.dataclass(frozen=True)
class Tempering:
    r"""How a filter brings each observation in: adaptive tempering of the likelihood with
    pCN jittering at every stage (`assimilate`).

    **Arguments:**

    - `ess_threshold`: the least share of effective particles a tempering stage keeps
      before its resampling, in (0, 1] (default 0.5).
    - `jitter_steps`: pCN moves per stage, an integer >= 0 (default 5).
    - `jitter_rho`: pCN's $\rho$, the new increments' correlation with the old, in [0, 1]
      (default 0.9; 1 leaves the increments as they are).
    - `jitter_lag`: the pCN moves' window, in observation intervals (default 1: the
      increments since the last observation). With $L > 1$ a move changes a particle's
      increments over the last $L$ intervals (fewer at the start) and re-runs it from its
      state $L$ observations back, accepted by the window's earlier likelihoods whole and
      the current one tempered: the same filtering distributions, with resampled copies
      that diverge from further back, at $L$ times the cost of a move.
    """

    ess_threshold: float = 0.5
    jitter_steps: int = 5
    jitter_rho: float = 0.9
    jitter_lag: int = 1

    def __post_init__(self):
        check_filter_options("Tempering", self.ess_threshold, self.jitter_steps, self.jitter_rho)
        object.__setattr__(
            self, "jitter_lag", check_count("Tempering: jitter_lag", self.jitter_lag)
        )


def check_tempering(caller, tempering) -> Tempering:
    return check_option(caller, "tempering", tempering, Tempering)


def check_observations(caller, observations, *, timed) -> Observations:
    """`observations` an `Observations`, with times (`timed`) or without."""
    if not isinstance(observations, Observations):
        raise TypeError(
            f"{caller}: observations must be an Observations(values, observe=..., std=..."
            f"{', times=...' if timed else ''}), got {type(observations).__name__}."
        )
    if timed and observations.times is None:
        raise ValueError(f"{caller}: the Observations need their times (times=...).")
    if not timed and observations.times is not None:
        raise ValueError(
            f"{caller}: the forecast goes to the next observation whatever its time: give "
            "Observations without times."
        )
    if not callable(observations.observe):
        raise TypeError(
            f"{caller}: Observations.observe must be a function of one state, got "
            f"{observations.observe!r}."
        )
    return observations


def assimilate(
    forecast,
    particles,
    observations: Observations,
    *,
    increments_shape,
    dt,
    key,
    tempering: Tempering = Tempering(),
):
    r"""A bootstrap particle filter with adaptive tempering, systematic resampling and pCN
    jittering of each particle's Brownian increments (Cotter, Crisan, Holm, Pan & Shevchenko
    2020), for any forecast that is a function of a state and its increments.

    At each observation $y_k$: every particle runs `forecast` from its parent's state with
    its own increments; with $\ell_i$ the Gaussian log-density of $y_k$ given
    $\mathrm{observe}(x_i)$,
    the likelihood is brought in by exponents $0 = \beta_0 < \beta_1 < \dots < 1$
    (`next_temperature`); at each stage the particles are resampled (`systematic_resample`)
    and moved by `jitter_steps` pCN steps on their increments, re-run from the parent's state
    and accepted at the stage's exponent (`pcn_proposal`, `pcn_accept`), which leave the
    tempered posterior invariant (`jitter_lag` widens the moves' window to several
    intervals). States are only ever produced by `forecast` from a parent's
    state: a structure-preserving forecast keeps every particle on its parent's orbit.

    **Arguments:**

    - `forecast(states, increments) -> states` (jitted here unless it is, or is a
      `functools.partial` of, a jitted function): one batch, states `(n, *state)` and standard
      Brownian increments `(n, *increments_shape)` of step `dt`, to the next observation time;
      or `-> Forecast(states, ok)`, `ok` a boolean array `(n,)`: a failed forecast gets
      likelihood 0 (it is never resampled, and a pCN move to it is rejected). A state may be a pytree of
      arrays with the particles first, such as a system's state and a driver's traces.
    - `particles`: the initial ensemble, `(n, *state)` (or a pytree of such arrays), `n >= 2`.
    - `observations`: an `Observations` (values, `observe`, `std`; without times).
    - `increments_shape`: the shape of one particle's increments between observations.
    - `dt`: the step of the increments (their variance).
    - `key`: a JAX key.
    - `tempering`: a `Tempering` (default `Tempering()`): the stages' least ESS share, and
      the pCN moves' number, $\rho$ and window.

    **Returns:** a `FilterResult`.
    """
    return _assimilate(
        "assimilate",
        forecast,
        particles,
        check_observations("assimilate", observations, timed=False),
        increments_shape=increments_shape,
        dt=dt,
        key=key,
        tempering=check_tempering("assimilate", tempering),
    )


def _assimilate(caller, forecast, particles, observations, *, increments_shape, dt, key, tempering):
    """`assimilate`, its errors naming `caller` (the function the user called)."""
    key = checked_key(caller, key)
    run = _prepare(forecast, particles, observations, tempering, caller)
    analyses, esses, temperatures, acceptance, evidence = [], [], [], [], []
    for cycle in run.cycles(_start(run, key), increments_shape=increments_shape, dt=dt):
        analyses.append(cycle.analysis)
        esses.append(cycle.ess)
        temperatures.append(jnp.asarray(cycle.temperatures))
        acceptance.append(jnp.asarray(cycle.acceptance))
        evidence.append(cycle.state.log_z)
    analyses = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *analyses)
    return FilterResult(
        analyses,
        _map(lambda a: jnp.mean(a, axis=1), analyses),
        jnp.asarray(esses),
        temperatures,
        acceptance,
        jnp.asarray(evidence),
    )


class _State(NamedTuple):
    """Where a filter stands after `k` observations: each particle's window (its state
    `anchor` at the window's start, `lag` observations back or the initial particles; its
    increments `dws`, states `xs` and log-likelihoods `ells` over the window's intervals, the
    last at observation `k - 1`), the random key, and the log evidence so far."""

    k: int
    anchor: Any
    dws: Any
    xs: Any
    ells: Any
    key: Any
    log_z: float


class _Cycle(NamedTuple):
    """One observation's assimilation: the analysis ensemble, the least stage ESS, the
    tempering exponents, pCN's acceptance rates, and the filter's state after it."""

    analysis: Any
    ess: float
    temperatures: list
    acceptance: list
    state: _State


class _Run(NamedTuple):
    """A filter's checked inputs (`_prepare`): the particles, observations, errors, the
    tempering (`None` for a filter without, `ensemble_kalman_filter`), the real dtype, and
    `advance`: the jitted forecast with its likelihoods."""

    x: Any
    ys: Any
    std: Any
    tempering: Tempering | None
    real: Any
    advance: Any

    @property
    def lag(self) -> int:
        """The pCN window in observation intervals (0 without tempering: no window)."""
        return 0 if self.tempering is None else self.tempering.jitter_lag

    def cycles(self, state, *, increments_shape, dt):
        """The assimilation of observations `state.k`, `state.k + 1`, ... (a generator of
        `_Cycle`s)."""
        return _cycles(self, state, increments_shape, dt)


def checked_key(caller, key):
    """`key` as a typed JAX key (`_brownian.check_key`), its errors naming `caller`."""
    try:
        return check_key(key)
    except (TypeError, ValueError) as e:
        raise type(e)(f"{caller}: {e}") from None


def _prepare(forecast, particles, observations, tempering, caller):
    """`assimilate`'s inputs checked, by name, before any work (`_Run`); errors name
    `caller`."""
    observe = observations.observe
    x = _map(jnp.asarray, particles)
    ys = jnp.asarray(observations.values)
    first = jax.tree_util.tree_leaves(x)[0]
    n = first.shape[0]
    if n < 2:
        raise ValueError(f"{caller}: particles must hold at least 2 particles, got {n}.")
    if ys.ndim != 2 or not bool(jnp.all(jnp.isfinite(ys))):
        raise ValueError(
            f"{caller}: the observations' values must be a finite (n_obs, n_y) array, got "
            f"shape {ys.shape}."
        )
    real = jnp.zeros((), first.dtype).real.dtype  # (complex states: real increments, weights)
    std = _check_obs_std(caller, observations.std, ys, real)
    got = jax.eval_shape(jax.vmap(observe), x).shape
    if got != (n, ys.shape[1]):
        raise ValueError(
            f"{caller}: observe(state) must return shape ({ys.shape[1]},), the observations' "
            f"n_y; got {got[1:]}."
        )
    # (a function jitted already, or a partial of one, keeps its own cache of programs)
    if not hasattr(getattr(forecast, "func", forecast), "lower"):
        forecast = jax.jit(forecast)

    def advance(states, dw, y):
        """The forecast's states and their log-likelihoods (`-inf` where it failed)."""
        states, ok = _states_and_ok(forecast(states, dw), n)
        ell = _log_likelihood(observe, states, y, std)
        return states, ell if ok is None else jnp.where(ok, ell, -jnp.inf)

    return _Run(x, ys, std, tempering, real, advance)


def _check_obs_std(caller, obs_std, ys, real):
    """`obs_std` as `(n_y,)` errors: positive and finite, a scalar or one per observed
    quantity, and none so small against the observations' scale that the likelihood is a
    point mass there (below sqrt(eps) of it): no ensemble meets one, and the tempering would
    spend its stages on it (quantities that the dynamics conserve, such as the l = 1
    coefficients of Euler–Zeitlin, have no spread to take 10 % of)."""
    std = np.asarray(obs_std, dtype=float)
    n_y = ys.shape[1]
    if std.shape not in ((), (n_y,)):
        raise ValueError(
            f"{caller}: the observations' std must be a scalar or one error per observed "
            "quantity, shape "
            f"({n_y},); got shape {std.shape}."
        )
    if not np.all(np.isfinite(std) & (std > 0)):
        raise ValueError(
            f"{caller}: the observations' std must be positive and finite, got {obs_std!r}."
        )
    std = np.broadcast_to(std, (n_y,))
    scale = max(float(np.max(np.abs(np.asarray(ys)), initial=0.0)), float(np.max(std)))
    floor = math.sqrt(float(jnp.finfo(real).eps)) * scale
    tiny = np.flatnonzero(std < floor)
    if tiny.size:
        raise ValueError(
            f"{caller}: the observations' std is {float(np.min(std[tiny])):.1e} at observed "
            "quantities "
            f"{tiny[:8].tolist()}{' ...' if tiny.size > 8 else ''}, below {floor:.1e} (sqrt(eps) "
            f"of the observations' scale {scale:.2g}): the likelihood is a point mass there, "
            "which no ensemble meets (a quantity the dynamics conserve has no spread to take a "
            "share of). Give those quantities a larger error, or leave them out of observe."
        )
    return jnp.asarray(std, real)


def _start(run, key):
    """The state of a filter before its first observation: every window empty."""
    n = _count(run.x)
    return _State(
        0,
        run.x,
        None,
        _map(lambda a: jnp.zeros((n, 0, *a.shape[1:]), a.dtype), run.x),
        jnp.zeros((n, 0), run.real),
        key,
        0.0,
    )


def _cycles(run, state, increments_shape, dt):
    """`_Run.cycles`."""
    ys, lag, real = run.ys, run.lag, run.real
    t = run.tempering
    ess_threshold, jitter_steps, jitter_rho = t.ess_threshold, t.jitter_steps, t.jitter_rho
    n = _count(run.x)
    shape = (n, *increments_shape)
    sqrt_dt = jnp.sqrt(jnp.asarray(dt, real))
    _, anchor, dws, xs, ells, key, log_z = state
    if dws is None:
        dws = jnp.zeros((n, 0, *increments_shape), real)

    def run_window(start, dw, k):
        """The states and log-likelihoods over a window of `dw.shape[1]` intervals ending at
        observation `k`, from `start`."""
        width = dw.shape[1]
        states, lls = [], []
        for j in range(width):
            start, ell = run.advance(start, dw[:, j], ys[k - width + 1 + j])
            states.append(start)
            lls.append(ell)
        return jax.tree_util.tree_map(lambda *a: jnp.stack(a, 1), *states), jnp.stack(lls, 1)

    for k in range(state.k, ys.shape[0]):
        if dws.shape[1] == lag:  # (the window moves on by one observation)
            anchor, xs = _map(lambda a: a[:, 0], xs), _map(lambda a: a[:, 1:], xs)
            dws, ells = dws[:, 1:], ells[:, 1:]
        key, draw = jax.random.split(key)
        dw = sqrt_dt * jax.random.normal(draw, shape, real)
        x, ell = run.advance(_map(lambda a: a[:, -1], xs) if dws.shape[1] else anchor, dw, ys[k])
        dws = jnp.concatenate([dws, dw[:, None]], 1)
        xs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b[:, None]], 1), xs, x)
        ells = jnp.concatenate([ells, ell[:, None]], 1)
        if not bool(jnp.any(jnp.isfinite(ell))):
            raise RuntimeError(
                f"assimilate: every particle's forecast to observation {k} failed; a smaller "
                "step (dt) or another method usually helps."
            )
        if not bool(jnp.all(jnp.isfinite(ell))):  # failed forecasts leave first, unweighted
            key, pick = jax.random.split(key)
            idx = systematic_resample(pick, jnp.where(jnp.isfinite(ell), 0.0, -jnp.inf))
            anchor, dws, xs, ells = _take((anchor, dws, xs, ells), idx)
        beta, betas, rates, least = 0.0, [], [], float(n)
        while beta < 1.0:
            new = float(next_temperature(ells[:, -1], beta, ess_threshold))
            if len(betas) >= MAX_STAGES:
                raise RuntimeError(
                    f"assimilate: observation {k} needs more than {MAX_STAGES} tempering stages "
                    "(a likelihood too sharp for the ensemble): raise the observations' std or the "
                    "particles."
                )
            logw = (new - beta) * ells[:, -1]
            least = min(least, float(effective_sample_size(logw)))
            log_z += float(jax.scipy.special.logsumexp(logw) - jnp.log(n))
            key, pick = jax.random.split(key)
            idx = systematic_resample(pick, logw)
            anchor, dws, xs, ells = _take((anchor, dws, xs, ells), idx)
            for _ in range(jitter_steps):
                key, propose, test = jax.random.split(key, 3)
                dws_new = pcn_proposal(propose, dws, jitter_rho, dt)
                xs_new, ells_new = run_window(anchor, dws_new, k)
                # (the window's earlier observations count whole, the current one at `new`)
                ok = pcn_accept(test, _tempered(ells_new, new), _tempered(ells, new), 1.0)
                dws, xs, ells = _where_rows(ok, (dws_new, xs_new, ells_new), (dws, xs, ells))
                rates.append(float(jnp.mean(ok)))
            beta = new
            betas.append(new)
        state = _State(k + 1, anchor, dws, xs, ells, key, log_z)
        yield _Cycle(_map(lambda a: a[:, -1], xs), least, betas, rates, state)


@functools.partial(jax.jit, static_argnums=0)
def _log_likelihood(observe, states, y, std):
    """Each state's Gaussian log-density of the observation `y`, its normalising constant
    included (the evidence needs it); compiled once per `observe` and shapes."""
    const = -jnp.sum(jnp.log(std)) - 0.5 * y.shape[0] * jnp.log(2 * jnp.pi)
    return const - 0.5 * jnp.sum(((jax.vmap(observe)(states) - y) / std) ** 2, axis=-1)


def _tempered(ells, beta):
    """A window's log-likelihood: its earlier observations' whole, the last one's times `beta`."""
    return jnp.sum(ells[:, :-1], axis=1) + beta * ells[:, -1]


def _where_rows(mask, a, b):
    """`a` where `mask` (one entry per row), else `b`: arrays, or pytrees of them alike."""
    return jax.tree_util.tree_map(
        lambda a, b: jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b), a, b
    )


def _map(fn, tree):
    """`fn` on every array of a state's pytree (a state may be an array or a pytree)."""
    return jax.tree_util.tree_map(fn, tree)


def _states_and_ok(out, n):
    """A forecast's `(states, ok)`: a `Forecast`'s parts (`ok` checked), else the output as
    the states, all successful (`ok` `None`): a state that is itself a pair is never taken
    for a `Forecast`."""
    if not isinstance(out, Forecast):
        return out, None
    ok = out.ok
    if getattr(ok, "dtype", None) != jnp.bool_ or getattr(ok, "shape", None) != (n,):
        raise TypeError(
            f"the forecast's Forecast.ok must be a boolean array ({n},), got "
            f"{getattr(ok, 'dtype', type(ok).__name__)} {getattr(ok, 'shape', '')}."
        )
    return out.states, ok


def _take(tree, idx):
    """The particles `idx` of every array of a pytree (resampling)."""
    return jax.tree_util.tree_map(lambda a: a[idx], tree)


def _count(tree):
    """The number of particles: the leading axis of a state's arrays."""
    return jax.tree_util.tree_leaves(tree)[0].shape[0]
