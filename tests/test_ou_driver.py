"""The Ornstein–Uhlenbeck driver: its increments against their exact moments, and `simulate`
with it against `integrate` with the same increments."""

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z


def test_ornstein_uhlenbeck_increments_have_the_exact_moments():
    r"""For a stationary unit OU trace of correlation time T the increments I_n over steps h
    have Var I = 2T^2 (h/T - 1 + e^{-h/T}) and Cov(I_n, I_{n+1}) = T^2 (1 - e^{-h/T})^2
    (integrals of the autocorrelation e^{-|s|/T}); 20000 paths, within 4 standard errors."""
    T, h, n = np.array([0.5, 2.0]), 0.1, 30
    d = np.asarray(sj.OrnsteinUhlenbeck(T).increments(jax.random.key(0), n, h, n_samples=20000))
    assert d.shape == (20000, n, 2)
    a = np.exp(-h / T)
    var = 2 * T**2 * (h / T - 1 + a)
    lag = T**2 * (1 - a) ** 2
    for step in (0, n - 2):  # stationary from the first step on
        x, y = d[:, step], d[:, step + 1]
        se_var = np.std(x * x, axis=0) / np.sqrt(len(x))
        assert np.all(np.abs(np.mean(x * x, axis=0) - var) < 4 * se_var)
        se_lag = np.std(x * y, axis=0) / np.sqrt(len(x))
        assert np.all(np.abs(np.mean(x * y, axis=0) - lag) < 4 * se_lag)
    assert abs(np.mean(d[:, 0, 0] * d[:, 0, 1])) < 4 * np.sqrt(var[0] * var[1] / 20000)
    # one noise: no last axis, as BrownianMotion's; n_noises=1 or a scalar time for s keeps it
    one = np.asarray(sj.OrnsteinUhlenbeck(0.5).increments(jax.random.key(0), n, h))
    assert one.shape == (n,)
    kept = sj.OrnsteinUhlenbeck(0.5).increments(jax.random.key(0), n, h, n_noises=1)
    np.testing.assert_array_equal(np.asarray(kept)[:, 0], one)
    three = sj.OrnsteinUhlenbeck(0.5).increments(jax.random.key(0), n, h, n_noises=3)
    assert np.asarray(three).shape == (n, 3)
    with pytest.raises(ValueError, match="Lévy areas"):
        sj.OrnsteinUhlenbeck(0.5).increments(jax.random.key(0), n, h, n_noises=2, levy_area=True)
    with pytest.raises(ValueError, match="correlation_time"):
        sj.OrnsteinUhlenbeck([0.5, -1.0]).increments(jax.random.key(0), n, h)
    for bad in ("0.5", ["0.5"], True):  # (a string converts to a number: refused as not one)
        with pytest.raises(TypeError, match="correlation_time must be numbers"):
            sj.OrnsteinUhlenbeck(bad)
    with pytest.raises(ValueError, match="dt"):
        sj.OrnsteinUhlenbeck(0.5).increments(jax.random.key(0), n, 0.0)


def test_simulate_with_an_ornstein_uhlenbeck_driver_is_integrate_with_its_increments():
    """`simulate(..., driver=OrnsteinUhlenbeck(T))` runs exactly what `integrate` runs with
    `OrnsteinUhlenbeck(T).increments` of the same key, whatever the loop's blocking (45 steps, final state;
    save_every=4) and in `ensemble_statistics`' chunks; a rigid body with `c=` through a
    flow-in-time method too; bad drivers are refused."""
    N, h = 6, 0.05
    xi = np.stack(
        [
            0.4 * z.shr2mat(np.eye(36)[z.elm2ind(2, 1)], N),
            0.3 * z.shr2mat(np.eye(36)[z.elm2ind(3, -2)], N),
        ]
    )
    system = sj.EulerZeitlin(N, noise=sj.salt_noise(-xi))
    w0 = z.shr2mat(np.r_[0, np.random.default_rng(0).normal(size=15)], N)
    drv, T = sj.OrnsteinUhlenbeck([0.3, 0.7]), [0.3, 0.7]
    inc = sj.OrnsteinUhlenbeck(T).increments(jax.random.key(5), 45, h, n_samples=3)
    ref = jax.vmap(lambda d: sj.integrate(system, w0, d, h, save_every=5))(inc)
    final = sj.simulate(system, w0, t1=45 * h, dt=h, n_samples=3, key=jax.random.key(5), driver=drv)
    np.testing.assert_allclose(final.ys[:, -1], ref[:, -1], rtol=0, atol=1e-13)
    saved = sj.simulate(
        system, w0, t1=45 * h, dt=h, n_samples=3, key=jax.random.key(5), driver=drv, save_every=5
    )
    np.testing.assert_allclose(saved.ys, ref, rtol=0, atol=1e-13)
    stats = sj.ensemble_statistics(
        system,
        w0,
        t1=45 * h,
        dt=h,
        n_samples=3,
        key=jax.random.key(5),
        driver=drv,
        chunks=sj.Chunks(2, progress=False),
        statistics=sj.Statistics(observable=lambda ys: z.mat2shr(ys)),
    )
    np.testing.assert_allclose(stats.mean[-1], np.mean(z.mat2shr(ref[:, -1]), axis=0), atol=1e-13)
    body = sj.RigidBody.paper()
    d = sj.OrnsteinUhlenbeck(0.5).increments(jax.random.key(1), 32, 2**-5, n_samples=2)
    exact = jax.vmap(lambda w: sj.exact_solution(body, sj.PAPER_Y0, 1.0, w.sum()))(d)
    # Strang: its error at h = 2^-5; Exact: the time-change loop, to round-off
    for method, atol in ((sj.Strang(), 1e-3), (sj.Exact(), 1e-12)):
        y = sj.simulate(
            body,
            sj.PAPER_Y0,
            t1=1.0,
            dt=2**-5,
            n_samples=2,
            key=jax.random.key(1),
            driver=sj.OrnsteinUhlenbeck(0.5),
            method=method,
        ).ys[:, -1]
        np.testing.assert_allclose(y, exact, atol=atol)
    with pytest.raises(ValueError, match="2 correlation times"):
        sj.simulate(
            sj.EulerZeitlin(N, noise=sj.salt_noise(-xi[:1])),
            w0,
            t1=h,
            dt=h,
            n_samples=1,
            key=jax.random.key(0),
            driver=drv,
        )
    with pytest.raises(TypeError, match="driver"):
        sj.simulate(system, w0, t1=h, dt=h, n_samples=1, key=jax.random.key(0), driver="ou")
    with pytest.raises(ValueError, match="correlation_time"):
        sj.OrnsteinUhlenbeck(0.0)
