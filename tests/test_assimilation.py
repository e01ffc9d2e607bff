"""The particle filter's building blocks (`slps_jax._studies.assimilation`), each against an
independent fact: the ESS's formula, the tempering rule's guarantee (ESS at or above the
threshold at every stage, and the largest such step), systematic resampling's unbiasedness and
its floor/ceil counts, and pCN's invariance of the increments' law (exact moments)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slps_jax._studies import assimilation as da


def test_effective_sample_size_is_the_formula():
    rng = np.random.default_rng(0)
    lw = rng.normal(size=16) * 3.0
    w = np.exp(lw)
    assert np.isclose(float(da.effective_sample_size(lw)), w.sum() ** 2 / (w * w).sum(), rtol=1e-12)
    assert np.isclose(float(da.effective_sample_size(np.zeros(10))), 10.0)
    one = np.array([0.0, -np.inf, -np.inf])
    assert np.isclose(float(da.effective_sample_size(one)), 1.0)
    # shifted log-weights far from 0 give the same ESS (no overflow)
    assert np.isclose(
        float(da.effective_sample_size(lw + 800.0)), float(da.effective_sample_size(lw))
    )


@pytest.mark.parametrize("threshold", [0.3, 0.5, 0.8])
def test_tempering_keeps_the_ess_above_the_threshold_at_every_stage_and_reaches_one(threshold):
    rng = np.random.default_rng(1)
    n = 64
    ell = -0.5 * (rng.normal(size=n) / 0.05) ** 2  # a sharp likelihood: several stages
    step = jax.jit(da.next_temperature, static_argnums=(2,))
    beta, stages = 0.0, []
    while beta < 1.0 and len(stages) < 200:
        new = float(step(ell, beta, threshold))
        assert new > beta
        ess = float(da.effective_sample_size((new - beta) * ell))
        assert ess >= threshold * n * (1 - 1e-9), (beta, new, ess)
        if new < 1.0:  # the largest such step: a little more would break the threshold
            more = float(da.effective_sample_size((new - beta + 1e-6) * ell))
            assert more < threshold * n
        stages.append(new)
        beta = new
    assert beta == 1.0 and len(stages) >= 3
    # a flat likelihood takes the whole step at once
    assert float(step(np.full(n, -3.0), 0.0, threshold)) == 1.0


def test_systematic_resampling_is_unbiased_with_floor_or_ceil_counts():
    n, trials = 8, 4000
    w = np.array([0.30, 0.01, 0.14, 0.05, 0.20, 0.10, 0.15, 0.05])
    keys = jax.random.split(jax.random.key(0), trials)
    idx = np.asarray(jax.vmap(lambda k: da.systematic_resample(k, jnp.log(w)))(keys))
    assert idx.shape == (trials, n) and np.all(np.diff(idx, axis=1) >= 0)
    counts = np.stack([np.bincount(row, minlength=n) for row in idx])
    expected = n * w
    assert np.all(counts >= np.floor(expected - 1e-12)) and np.all(
        counts <= np.ceil(expected + 1e-12)
    )
    mean, se = counts.mean(0), counts.std(0, ddof=1) / np.sqrt(trials)
    assert np.all(np.abs(mean - expected) <= 4 * se + 1e-12), (mean, expected, se)


def test_pcn_keeps_the_increments_law_and_accepts_everything_without_likelihood():
    dt, rho, m = 0.01, 0.7, 200_000
    key0, key1, key2 = jax.random.split(jax.random.key(3), 3)
    dw = jnp.sqrt(dt) * jax.random.normal(key0, (m,), jnp.float64)
    new = np.asarray(da.pcn_proposal(key1, dw, rho, dt))
    dw = np.asarray(dw)
    # exact moments of the stationary pair: mean 0, variance h, covariance rho h
    for value, exact, var in [
        (new.mean(), 0.0, dt / m),
        ((new * new).mean(), dt, 2 * dt * dt / m),
        ((new * dw).mean(), rho * dt, (1 + rho * rho) * dt * dt / m),
    ]:
        assert abs(value - exact) <= 5 * np.sqrt(var), (value, exact)
    ell = np.zeros(64)
    assert bool(jnp.all(da.pcn_accept(key2, ell, ell, 0.7)))
    assert bool(jnp.all(da.pcn_accept(key2, ell - 5.0, ell, 0.0)))  # beta = 0: no likelihood
    assert not bool(jnp.any(da.pcn_accept(key2, ell - 1e3, ell, 1.0)))
    assert np.array_equal(np.asarray(da.pcn_proposal(key1, dw, 1.0, dt)), dw)  # rho = 1: no move
