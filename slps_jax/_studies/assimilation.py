r"""The building blocks of a particle filter on the coadjoint orbit (Cotter, Crisan, Holm, Pan &
Shevchenko 2020, arXiv:1907.11884): the effective sample size, adaptive tempering of the
likelihood, systematic resampling, and the preconditioned Crank–Nicolson (pCN) move on a
particle's Brownian increments. Each acts on weights or on increments only, never on states:
resampling copies states, and a pCN move re-runs a particle from its parent's state with new
increments, so that a filter built from them moves particles only along coadjoint orbits.

All functions are pure and jit-able, one filter cycle's arrays at a time; the filter that
composes them (`particle_filter`) is not built yet.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def effective_sample_size(log_weights):
    r"""$\mathrm{ESS} = (\sum_i w_i)^2 / \sum_i w_i^2$ of unnormalised log-weights, computed
    stably (shifted by their maximum).

    **Arguments:** `log_weights`, shape `(n,)`, finite or `-inf` (a particle of weight 0).

    **Returns:** a scalar in `[1, n]` (`n` for equal weights, 1 for one particle alone).
    """
    lw = jnp.asarray(log_weights)
    w = jnp.exp(lw - jnp.max(lw))
    return jnp.sum(w) ** 2 / jnp.sum(w * w)


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
