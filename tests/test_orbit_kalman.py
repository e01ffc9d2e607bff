"""`ensemble_kalman_filter` (`slps_jax._forecasting.orbit_kalman`), each part against an
independent fact: the analysis in a vector space against the Kalman filter's exact mean and
covariance of a Gaussian prior (to Monte Carlo error) and, exactly, the Kalman update of the
ensemble's own moments; the coadjoint moves against points of the orbit made with scipy's
matrix exponential (reached at Gauss–Newton's quadratic rate) and the Casimirs (kept to
rounding); the filter on su(N) against its free ensemble and the orbit, and bad input refused
by name."""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from slps_jax._forecasting.orbit_kalman import kalman_targets, towards_on_orbit


def test_the_analysis_is_the_kalman_update_of_a_gaussian_prior():
    rng = np.random.default_rng(0)
    d, p, n = 4, 2, 40000
    b = rng.standard_normal((d, d))
    P = b @ b.T / d + 0.1 * np.eye(d)
    m = rng.standard_normal(d)
    H = rng.standard_normal((p, d))
    std = np.array([0.3, 0.7])
    y = H @ m + np.array([0.5, -0.4])
    x = m + rng.standard_normal((n, d)) @ np.linalg.cholesky(P).T
    targets = np.asarray(
        kalman_targets(jax.random.key(1), jnp.asarray(x), jnp.asarray(x @ H.T), y, std)
    )
    # exactly: the targets' mean is the Kalman update of the ensemble's mean and covariance
    # (the perturbations are centred)
    C = np.cov(x.T)
    K = C @ H.T @ np.linalg.inv(H @ C @ H.T + np.diag(std**2))
    xm = x.mean(0)
    np.testing.assert_allclose(targets.mean(0), xm + K @ (y - H @ xm), rtol=0, atol=1e-12)
    # to Monte Carlo error: the Kalman filter's mean and covariance of the Gaussian prior
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(std**2))
    Pa = (np.eye(d) - K @ H) @ P
    se = np.sqrt(np.diag(P) / n)
    assert np.all(np.abs(targets.mean(0) - (m + K @ (y - H @ m))) < 5 * se)
    np.testing.assert_allclose(np.cov(targets.T), Pa, rtol=0, atol=0.03 * np.max(np.diag(P)))


def test_inflation_scales_the_anomalies_and_the_gain():
    # with the observations' errors huge, the targets are the inflated forecast
    rng = np.random.default_rng(1)
    x = rng.standard_normal((50, 3))
    out = kalman_targets(jax.random.key(0), x, x[:, :1], np.zeros(1), np.array([1e8]), 1.5)
    np.testing.assert_allclose(out, x.mean(0) + 1.5 * (x - x.mean(0)), rtol=0, atol=1e-7)


def _ensemble(seed=4, n=30, d=5, p=3):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, d)) @ rng.standard_normal((d, d))
    H = rng.standard_normal((p, d))
    return rng, x, x @ H.T, rng.standard_normal(p), np.array([0.3, 0.5, 0.7])[:p]


def test_without_a_taper_the_analysis_is_the_same_in_every_basis():
    from slps_jax import Localization

    rng, x, hx, y, std = _ensemble()
    basis = rng.standard_normal((5, 5))  # (not orthogonal)
    loc = Localization(np.arange(5.0), np.arange(3.0), 1e9, basis)
    b, inv, rho_xh, rho_hh = loc.tapers(jnp.float64)
    key = jax.random.key(2)
    plain = kalman_targets(key, x, hx, y, std, 1.2)
    in_basis = kalman_targets(key, x @ inv, hx, y, std, 1.2, (rho_xh, rho_hh)) @ b
    np.testing.assert_allclose(in_basis, plain, rtol=0, atol=1e-11)


def test_the_tapered_analysis_is_the_schur_product_kalman_update():
    # Houtekamer & Mitchell (2001): K = (rho_xh o C_xh)(rho_hh o C_hh + R)^-1, written here
    # with numpy's covariances; a coordinate far from every observation is not moved
    from slps_jax import Localization

    rng, x, hx, y, std = _ensemble(n=12)
    positions, observed = np.array([0.0, 1.0, 2.0, 3.0, 50.0]), np.array([0.0, 1.5, 3.0])
    loc = Localization(positions, observed, 1.3)
    _, _, rho_xh, rho_hh = loc.tapers(jnp.float64)
    targets = np.asarray(kalman_targets(jax.random.key(3), x, hx, y, std, 1.0, (rho_xh, rho_hh)))
    C = np.cov(np.c_[x, hx].T)
    c_xh, c_hh = C[:5, 5:], C[5:, 5:]
    taper = lambda a, b: np.exp(-0.5 * np.subtract.outer(a, b) ** 2 / 1.3**2)
    K = (taper(positions, observed) * c_xh) @ np.linalg.inv(
        taper(observed, observed) * c_hh + np.diag(std**2)
    )
    np.testing.assert_allclose(
        targets.mean(0), x.mean(0) + K @ (y - hx.mean(0)), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(targets[:, 4], x[:, 4], rtol=0, atol=1e-12)
    # (the same localisation refuses ill-formed pieces by name)
    for bad, match in [
        (dict(length=0.0), "length must be a finite number > 0"),
        (dict(positions=np.zeros((2, 2))), "positions must be a non-empty 1-d array"),
        (dict(observed=[np.nan]), "observed must be a non-empty 1-d array of finite"),
        (dict(basis=np.eye(4)), r"basis must be \(5, 5\)"),
        (dict(basis=np.ones((5, 5))), "basis must be finite and invertible"),
        (dict(positions="ab"), "positions must be real numbers"),
    ]:
        kw = dict(positions=positions, observed=observed, length=1.3) | bad
        with pytest.raises((ValueError, TypeError), match=f"^Localization: {match}"):
            Localization(**kw)


def test_the_degree_localization_is_in_the_spherical_harmonics():
    import slps_jax as sj
    from slps_jax import zeitlin as z

    N = 6
    loc = sj.Localization.by_degree(N, [1, 1, 1, 2], 1.0)
    c = np.random.default_rng(5).standard_normal(N * N - 1)
    # the basis' rows are the harmonics' coordinates: mat2shr reads the coefficients back
    w = sj.su(N).from_coordinates(c @ loc.basis)
    np.testing.assert_allclose(np.asarray(z.mat2shr(w))[1:], c, rtol=0, atol=1e-12)
    degrees = [z.elm2ind(ell, m) for ell in (1, 4, 5) for m in (-ell, ell)]
    assert loc.positions[np.asarray(degrees) - 1].tolist() == [1, 1, 4, 4, 5, 5]


def _orbit_point(w, xi, eps):
    a = scipy.linalg.expm(eps * xi)
    return a @ w @ a.conj().T


@pytest.mark.parametrize("algebra", ["su(6)", "so(5)", "so(3)"])
def test_the_moves_reach_a_point_of_the_orbit_quadratically_and_keep_the_casimirs(algebra):
    import slps_jax as sj

    rng = np.random.default_rng(2)
    if algebra == "su(6)":
        alg = sj.su(6)
        b = rng.standard_normal((6, 6)) + 1j * rng.standard_normal((6, 6))
    else:
        alg = sj.so(5) if algebra == "so(5)" else sj.SO3
        b = rng.standard_normal((5 if algebra == "so(5)" else 3,) * 2)
    w = np.asarray(alg.project(b))
    xi = np.asarray(alg.to_matrix(alg.project(rng.standard_normal(b.shape))))
    xi = xi / np.linalg.norm(xi)
    goal = np.asarray(alg.project(_orbit_point(np.asarray(alg.to_matrix(w)), xi, 0.2)))
    size = np.linalg.norm(goal - w)
    errors = [
        float(jnp.linalg.norm(towards_on_orbit(alg, w, goal, 1e-8, k) - goal)) / size
        for k in (1, 2, 3, 4)
    ]
    # (Gauss–Newton's quadratic rate, down to rounding)
    assert errors[0] < 0.2 and errors[1] < 5 * errors[0] ** 2
    assert errors[2] < max(5 * errors[1] ** 2, 1e-13)
    assert errors[3] < 1e-11
    moved = towards_on_orbit(alg, w, w + 0.3 * size * rng.standard_normal(w.shape), 1e-3, 4)
    c0 = np.asarray(alg.casimirs(w))
    assert np.max(np.abs(np.asarray(alg.casimirs(moved)) - c0)) < 1e-12 * np.max(np.abs(c0))
    assert np.isrealobj(moved) == np.isrealobj(w)


def _twin(N=5, n=16, n_obs=6, every=10, h=0.02):
    """An su(N) twin: the truth one run of a model with three transport noises, its degrees
    1..2 observed with errors 0.02; the members a spread-out start."""
    import slps_jax as sj
    from slps_jax import zeitlin as z

    rng = np.random.default_rng(3)
    chi = z.shr2mat(np.eye(N * N)[[4, 5, 9]], N)
    system = sj.EulerZeitlin(N, noise=sj.salt_noise(0.3 * chi))
    w0 = z.shr2mat(np.r_[0, rng.standard_normal(N * N - 1) / np.arange(1, N * N) ** 0.5], N)
    truth = sj.simulate(
        system,
        w0,
        t1=n_obs * every * h,
        dt=h,
        n_samples=1,
        key=jax.random.key(4),
        save_every=every,
        driver=sj.BrownianMotion(levy_area=False),
    ).ys[0]
    obs = np.arange(1, 9)  # degrees 1..2
    observe = lambda w: jnp.real(z.mat2shr(w))[obs]
    ys = np.asarray(jax.vmap(observe)(truth[1:])) + 0.02 * rng.standard_normal((n_obs, obs.size))
    members = sj.simulate(
        system,
        w0,
        t1=0.4,
        dt=h,
        n_samples=n,
        key=jax.random.key(5),
        driver=sj.BrownianMotion(levy_area=False),
    ).ys[:, -1]
    times = h * every * np.arange(1, n_obs + 1)
    return sj, system, members, sj.Observations(ys, observe=observe, std=0.02, times=times), truth


@pytest.fixture(scope="module")
def twin_runs():
    sj, system, members, observations, truth = _twin()
    kw = dict(dt=0.02, key=jax.random.key(6))
    filtered = sj.ensemble_kalman_filter(system, members, observations, **kw)
    free = sj.ensemble_kalman_filter(
        system,
        members,
        sj.Observations(
            observations.values, observe=observations.observe, std=1e9, times=observations.times
        ),
        **kw,
    )
    return sj, system, members, observations, truth, filtered, free


def test_the_filter_follows_the_observed_truth_on_every_members_orbit(twin_runs):
    sj, system, members, observations, truth, filtered, free = twin_runs
    error = lambda res: np.sqrt(
        np.mean(
            (
                np.asarray(jax.vmap(observations.observe)(res.mean))
                - np.asarray(jax.vmap(observations.observe)(truth[1:]))
            )
            ** 2,
            1,
        )
    )
    # the free ensemble (errors of 1e9: no increment) against the filter, same members and key
    assert np.mean(error(filtered)) < 0.5 * np.mean(error(free))
    # every member keeps its Casimirs: the model conserves them, the moves are coadjoint
    c0 = np.asarray(sj.su(5).casimirs(members))
    cs = np.asarray(sj.su(5).casimirs(filtered.particles))
    assert np.max(np.abs(cs - c0) / np.max(np.abs(c0), 0)) < 1e-12
    assert filtered.particles.shape == (6, 16, 5, 5) and np.all(filtered.replaced == 0)
    # the increments that a coadjoint action cannot take (they change a Casimir) stay out
    assert 0 < float(np.max(filtered.off_orbit)) < 1


def test_the_localised_filter_keeps_the_orbits_and_is_the_filter_without_a_taper(twin_runs):
    sj, system, members, observations, truth, filtered, free = twin_runs
    degrees = np.floor(np.sqrt(np.arange(1, 9)))  # (the observed values' degrees)
    kw = dict(dt=0.02, key=jax.random.key(6))
    run = lambda length: sj.ensemble_kalman_filter(
        system,
        members,
        observations,
        analysis=sj.KalmanAnalysis(localization=sj.Localization.by_degree(5, degrees, length)),
        **kw,
    )
    # an infinite taper: the filter in the harmonics' basis is the filter itself
    np.testing.assert_allclose(run(1e9).particles, filtered.particles, rtol=0, atol=1e-9)
    with _compiles() as events:  # (another length: the tapers are traced)
        local = run(0.5)
    assert events == []
    c0 = np.asarray(sj.su(5).casimirs(members))
    cs = np.asarray(sj.su(5).casimirs(local.particles))
    assert np.max(np.abs(cs - c0) / np.max(np.abs(c0), 0)) < 1e-12
    observed = lambda res: np.asarray(jax.vmap(observations.observe)(res.mean))
    truth_obs = np.asarray(jax.vmap(observations.observe)(truth[1:]))
    assert np.mean((observed(local) - truth_obs) ** 2) < 0.25 * np.mean(
        (observed(free) - truth_obs) ** 2
    )


def test_chunking_the_members_does_not_change_the_filter(twin_runs):
    sj, system, members, observations, _, filtered, _ = twin_runs
    chunked = sj.ensemble_kalman_filter(
        system, members, observations, dt=0.02, key=jax.random.key(6), chunk_size=5
    )
    np.testing.assert_allclose(chunked.particles, filtered.particles, rtol=0, atol=1e-10)
    # another inflation and regularisation (traced) compile nothing again (the first run
    # here: the fixture's programs may be gone, when the suite frees its caches between tests)
    run = lambda analysis: sj.ensemble_kalman_filter(
        system, members, observations, dt=0.02, key=jax.random.key(7), analysis=analysis
    )
    run(sj.KalmanAnalysis())
    with _compiles() as events:
        run(sj.KalmanAnalysis(inflation=1.1, regularization=1e-2))
    assert events == []


@contextlib.contextmanager
def _compiles():
    """The XLA compilations inside the block, listed."""
    events = []
    listener = lambda name, seconds, **kw: events.append(kw) if "backend_compile" in name else None
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield events
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


BAD = [
    (dict(analysis=None), TypeError, "analysis must be a KalmanAnalysis"),
    (dict(failures="throw"), TypeError, "failures"),
    (dict(dt=-0.1), ValueError, "dt must be positive"),
    (dict(std=-1.0), ValueError, "std must be positive"),
    (dict(key=0), TypeError, r"pass jax.random.key\(0\)"),
    (
        dict(analysis="localization"),  # (one observed value's position for 8 values)
        ValueError,
        "the localization has 24 positions and 1 observed ones; the algebra has dimension 24 "
        "and each observation 8 values",
    ),
]


@pytest.mark.parametrize("bad,exc,match", BAD)
def test_the_filter_refuses_bad_calls_by_name_before_any_forecast(bad, exc, match):
    from unittest import mock

    sj, system, members, observations, _ = _twin(n_obs=2)
    if "std" in bad:
        observations = sj.Observations(
            observations.values,
            observe=observations.observe,
            std=bad.pop("std"),
            times=observations.times,
        )
    if bad.get("analysis") == "localization":
        loc = sj.Localization.by_degree(5, [1.0], 1.0)
        bad = dict(analysis=sj.KalmanAnalysis(localization=loc))
    kw = dict(dt=0.02, key=jax.random.key(0)) | bad

    def boom(*args, **kwargs):
        raise AssertionError("a forecast ran before the arguments were checked")

    with mock.patch("slps_jax._forecasting.particle_filter._forecast", boom):
        with pytest.raises(exc, match=f"ensemble_kalman_filter: .*{match}"):
            sj.ensemble_kalman_filter(system, members, observations, **kw)


@pytest.mark.parametrize(
    "bad,match",
    [
        (dict(inflation=0.9), "inflation must be a finite number >= 1"),
        (dict(regularization=0.0), "regularization must be a finite number > 0"),
        (dict(iterations=0), "iterations"),
        (dict(localization=1.5), "localization must be a Localization"),
    ],
)
def test_the_analysis_options_are_refused_by_name(bad, match):
    import slps_jax as sj

    with pytest.raises((ValueError, TypeError), match=f"^KalmanAnalysis: {match}"):
        sj.KalmanAnalysis(**bad)


def test_a_member_whose_forecast_failed_is_replaced_not_used():
    from unittest import mock

    from slps_jax._forecasting import particle_filter as pf

    sj, system, members, observations, _ = _twin(n_obs=2)
    real = pf._forecast

    def first_fails(*args, **kwargs):  # (member 0's forecast fails, its state is NaN)
        out = real(*args, **kwargs)
        (states, driver), ok = out
        return sj.Forecast((states.at[0].set(jnp.nan), driver), ok.at[0].set(False))

    def all_fail(*args, **kwargs):
        out = real(*args, **kwargs)
        return sj.Forecast(out.states, jnp.zeros_like(out.ok))

    kw = dict(dt=0.02, key=jax.random.key(0))
    with mock.patch.object(pf, "_forecast", first_fails):
        res = sj.ensemble_kalman_filter(system, members, observations, **kw)
    assert res.replaced.tolist() == [1, 1]
    assert bool(jnp.all(jnp.isfinite(res.particles)))
    with mock.patch.object(pf, "_forecast", all_fail):
        with pytest.raises(RuntimeError, match="every member's forecast to observation 0 failed"):
            sj.ensemble_kalman_filter(system, members, observations, **kw)
