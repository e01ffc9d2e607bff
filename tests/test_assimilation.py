"""The particle filter's building blocks (`slps_jax._forecasting.assimilation`), each against an
independent fact: the ESS's formula, the tempering rule's guarantee (ESS at or above the
threshold at every stage, and the largest such step), systematic resampling's unbiasedness and
its floor/ceil counts, and pCN's invariance of the increments' law (exact moments)."""

from unittest import mock

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slps_jax._forecasting import assimilation as da


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


def _ou_model(theta=1.0, sigma=0.5, m=8, h=0.05):
    """A linear-Gaussian forecast over m steps of h: x' = a x + sigma sum_j c_j dW_j, the
    Ornstein-Uhlenbeck process's discretisation (exactly Gaussian: a Kalman filter is exact)."""
    a = float(np.exp(-theta * m * h))
    c = np.exp(-theta * h * np.arange(m - 1, -1, -1))
    q = sigma**2 * h * float(np.sum(c * c))
    c = jnp.asarray(c)

    def forecast(states, dw):
        return a * states + sigma * (dw @ c)[:, None]

    return forecast, a, q


def _ou_driven_model(theta=1.0, sigma=0.5, m=8, h=0.05, T=0.3):
    """The same process driven by a smooth Ornstein-Uhlenbeck trace (correlation time T)
    instead of white noise: a particle is a pytree (x, eta), its random numbers the trace's
    exact steps' standard normals (`ou_step`), and the augmented state is still linear-
    Gaussian. Returns the forecast and the interval's transition F and noise covariance Q."""
    from slps_jax._brownian import OrnsteinUhlenbeck, ou_step

    consts = OrnsteinUhlenbeck(T).path(h, 1, jnp.float64).consts
    e = float(np.exp(-theta * h))

    def forecast(states, z):  # states (x (n, 1), eta (n, 1)); z (n, m, 2, 1)
        def one(x, eta, zz):
            def step(c, zj):
                x, eta = c
                eta, increment = ou_step(consts, eta, zj)
                return (e * x + sigma * increment, eta), None

            return jax.lax.scan(step, (x, eta), zz)[0]

        return jax.vmap(one)(states[0], states[1], z)

    a, b, l11, l21, l22 = (float(np.asarray(c)[0]) for c in consts)
    f_step = np.array([[e, sigma * b], [0.0, a]])
    g_step = np.array([[sigma * l21, sigma * l22], [l11, 0.0]])
    big_f, big_q = np.eye(2), np.zeros((2, 2))
    for _ in range(m):
        big_f, big_q = f_step @ big_f, f_step @ big_q @ f_step.T + g_step @ g_step.T
    return forecast, big_f, big_q


@pytest.mark.parametrize("lag, driven", [(1, False), (3, False), (1, True)])
def test_a_linear_gaussian_model_gives_the_kalman_filter_within_monte_carlo_error(lag, driven):
    # (with lag 3, pCN moves each particle's increments over the last three intervals, re-run
    # from its state three observations back; driven by an Ornstein-Uhlenbeck trace, each
    # particle is a pytree of its state and the trace: the same filtering distributions)
    r, n, n_obs = 0.2**2, 2000, 5
    key0 = jax.random.key(1)
    if driven:
        forecast, f, q = _ou_driven_model()
        m0, p0, shape, dt = np.array([0.5, 0.0]), np.diag([0.3**2, 1.0]), (8, 2, 1), 1.0
        draws = np.asarray(jax.random.normal(key0, (n, 2)))
        x0 = (m0[0] + 0.3 * draws[:, :1], draws[:, 1:])
    else:
        forecast, a, q1 = _ou_model()
        f, q = np.array([[a]]), np.array([[q1]])
        m0, p0, shape, dt = np.array([0.5]), np.array([[0.3**2]]), (8,), 0.05
        x0 = 0.5 + 0.3 * np.asarray(jax.random.normal(key0, (n, 1)))
    rng = np.random.default_rng(5)
    truth, ys = rng.multivariate_normal(m0, p0), []
    for _ in range(n_obs):
        truth = f @ truth + rng.multivariate_normal(np.zeros(len(m0)), q)
        ys.append([truth[0] + rng.normal(0.0, np.sqrt(r))])
    ys = np.asarray(ys)
    res = da.assimilate(
        forecast,
        x0,
        da.Observations(ys, observe=(lambda s: s[0]) if driven else (lambda s: s), std=np.sqrt(r)),
        increments_shape=shape,
        dt=dt,
        key=jax.random.key(2),
        tempering=da.Tempering(ess_threshold=0.5, jitter_steps=5, jitter_rho=0.8, jitter_lag=lag),
    )
    particles = res.particles[0] if driven else res.particles
    m, p, log_z = m0, p0, 0.0
    for k in range(n_obs):
        m, p = f @ m, f @ p @ f.T + q
        s = p[0, 0] + r
        log_z += -0.5 * (np.log(2 * np.pi * s) + (ys[k, 0] - m[0]) ** 2 / s)
        gain = p[:, 0] / s
        m, p = m + gain * (ys[k, 0] - m[0]), p - np.outer(gain, p[0])
        xs = np.asarray(particles[k, :, 0])
        # resampling and jittering correlate the particles: allow an effective size of n/4
        sd = np.sqrt(p[0, 0] / (n / 4))
        assert abs(xs.mean() - m[0]) <= 4 * sd, (k, xs.mean(), m[0])
        assert abs(xs.var(ddof=1) / p[0, 0] - 1) <= 4 * np.sqrt(2 / (n / 4)), (k, xs.var(), p)
        assert float(res.ess[k]) >= 0.5 * n * (1 - 1e-9)
        assert float(res.temperatures[k][-1]) == 1.0
        assert 0.0 < float(jnp.mean(res.acceptance[k])) <= 1.0
    assert abs(float(res.log_evidence[-1]) - log_z) <= 0.2, (float(res.log_evidence[-1]), log_z)


def test_assimilate_refuses_bad_input_by_name():
    forecast, _, _ = _ou_model()
    kw = dict(increments_shape=(8,), dt=0.05, key=jax.random.key(0))
    good, ys = np.zeros((4, 1)), np.zeros((2, 1))

    def observed(values, observe=lambda s: s, std=0.1, **more):
        return da.Observations(values, observe=observe, std=std, **more)

    with pytest.raises(ValueError, match="particles"):
        da.assimilate(forecast, np.zeros((1, 1)), observed(ys), **kw)
    with pytest.raises(ValueError, match="observations' values"):
        da.assimilate(forecast, good, observed(np.array([[np.nan]])), **kw)
    with pytest.raises(ValueError, match="observations' std"):
        da.assimilate(forecast, good, observed(ys, std=0.0), **kw)
    with pytest.raises(ValueError, match="observe"):
        da.assimilate(forecast, good, observed(ys, lambda s: jnp.concatenate([s, s])), **kw)
    with pytest.raises(ValueError, match="without times"):
        da.assimilate(forecast, good, observed(ys, times=[1.0, 2.0]), **kw)
    with pytest.raises(TypeError, match="Observations"):
        da.assimilate(forecast, good, ys, **kw)
    with pytest.raises(ValueError, match="jitter_lag"):
        da.assimilate(forecast, good, observed(ys), **kw, tempering=da.Tempering(jitter_lag=0))


def test_a_forecast_says_which_particles_failed_by_its_type():
    # A state that is itself a pair whose second part is a boolean array (n,) is a state, not a
    # failure mask; a Forecast's ok is one: a particle whose forecast failed (here: not above 0)
    # gets likelihood 0, so no analysis particle is a failed one.
    n, kw = 16, dict(increments_shape=(1,), dt=0.1, key=jax.random.key(0))
    on_x = da.Observations(np.zeros((3, 1)), observe=lambda s: s[0], std=1.0)
    pairs = (jnp.zeros((n, 1)), jnp.ones((n,), bool))
    res = da.assimilate(lambda s, dw: (s[0] + dw, s[1]), pairs, on_x, **kw)
    assert res.particles[1].shape == (3, n) and bool(jnp.all(res.particles[1]))
    x0 = jnp.linspace(-0.5, 0.5, n)[:, None]
    observed = da.Observations(np.zeros((3, 1)), observe=lambda s: s, std=1.0)
    failing = lambda s, dw: da.Forecast(s + dw, (s + dw)[:, 0] > 0)
    res = da.assimilate(failing, x0, observed, **kw)
    assert bool(jnp.all(res.particles > 0)), res.particles
    with pytest.raises(TypeError, match="Forecast.ok"):
        da.assimilate(lambda s, dw: da.Forecast(s + dw, jnp.ones(n)), x0, observed, **kw)


def _so4_setup():
    import slps_jax as sj

    rng = np.random.default_rng(0)
    b = rng.standard_normal((4, 4))
    y0 = 0.8 * (b - b.T) / np.linalg.norm(b - b.T, 2)
    chi = rng.standard_normal((3, 4, 4))
    system = sj.GeneralisedRigidBody(
        [0.6, 1.1, 1.7, 2.3], noise=sj.salt_noise(0.3 * (chi - chi.transpose(0, 2, 1)))
    )
    return sj, system, y0


_H = 2.0**-5


def _observe(y):  # three entries of an so(4) state
    return y[0, 1:]


def _so4_filter(system, y0, ys, n, obs_times, *, key, **options):
    """`particle_filter` on so(4) from `n` copies of `y0`, observing `_observe` with errors of
    0.05, at step `_H`."""
    import slps_jax as sj

    return sj.particle_filter(
        system,
        np.broadcast_to(y0, (n, 4, 4)),
        sj.Observations(ys, times=obs_times, observe=_observe, std=0.05),
        dt=_H,
        key=jax.random.key(key),
        **options,
    )


_TIMES = [0.25, 0.5, 0.75]
_STORED = dict(key=3, tempering=da.Tempering(jitter_steps=2, jitter_lag=2))


@pytest.fixture(scope="module")
def so4_run():
    """so(4), 16 particles, three observations, pCN over two intervals: in memory."""
    sj, system, y0 = _so4_setup()
    truth = sj.integrate(system, y0, 0.1 * np.ones((16, 3)), _H)
    ys = np.stack([_observe(truth)] * 3) + 0.01
    return sj, system, y0, ys, _so4_filter(system, y0, ys, 16, _TIMES, **_STORED)


def test_every_analysis_particle_stays_on_its_coadjoint_orbit(so4_run):
    # so(4) with three transport noises, IsospectralMidpoint (the default there): resampling
    # copies states and jittering re-runs a parent's state (over two intervals here), so every
    # particle keeps the initial Casimirs
    sj, _, y0, _, res = so4_run
    n = 16
    c0 = np.asarray(sj.so(4).casimirs(y0))
    cs = np.asarray(sj.so(4).casimirs(res.particles))
    assert res.particles.shape == (3, n, 4, 4) and cs.shape == (3, n, 2)
    assert np.max(np.abs(cs / c0 - 1)) < 1e-12
    assert np.all(np.asarray(res.ess) >= 0.5 * n * (1 - 1e-9))


def test_the_filter_on_disk_resumes_and_extends_bit_for_bit(so4_run, tmp_path, monkeypatch, capsys):
    # two observations to a store, then all three resumed from it: the analyses, ESS and
    # evidence of the filter run in memory, bit for bit (the windows, key and evidence are
    # the store's carry); other observations or options are refused. Watched (as on a
    # terminal), the first shows its progress and the second, progress=False, does not.
    from slps_jax._support import progress as _progress

    monkeypatch.setattr(_progress, "interactive", lambda: True)
    sj, system, y0, ys, res = so4_run
    path = tmp_path / "filter"
    kw = dict(_STORED, key=jax.random.key(_STORED["key"]), dt=_H)

    def observed(values):
        return sj.Observations(values, times=_TIMES[: len(values)], observe=_observe, std=0.05)

    x = np.broadcast_to(y0, (16, 4, 4))
    first = sj.particle_filter_to_store(system, x, observed(ys[:2]), sj.Store(path), **kw)
    assert len(first) == 2 and "2/2" in capsys.readouterr().err
    resume = sj.Store(path, resume=True, progress=False)
    run = sj.particle_filter_to_store(system, x, observed(ys), resume, **kw)
    assert capsys.readouterr().err == ""
    assert np.array_equal(run.read("state"), np.asarray(res.particles))
    assert np.array_equal(run.read("ess"), np.asarray(res.ess))
    assert np.array_equal(run.read("log_evidence"), np.asarray(res.log_evidence))
    assert np.array_equal(run.read("observation"), ys) and np.allclose(run.times, _TIMES)
    with pytest.raises(ValueError, match="observations differ"):
        sj.particle_filter_to_store(system, x, observed(ys + 1e-3), resume, **kw)
    with pytest.raises(ValueError, match="options"):
        other = {**kw, "tempering": sj.Tempering(jitter_steps=1, jitter_lag=2)}
        sj.particle_filter_to_store(system, x, observed(ys), resume, **other)
    with pytest.raises(ValueError, match="simulate_to_store's"):
        sj.particle_filter_to_store(
            system, x, observed(ys), sj.Store(path, resume=True, save_states=False), **kw
        )
    again = r"particle_filter_to_store\(\.\.\., Store\(\.\.\., resume=True\)\)"
    with pytest.raises(FileExistsError, match=again):
        sj.particle_filter_to_store(system, x, observed(ys), sj.Store(path), **kw)


def test_particle_filter_refuses_bad_times_and_particles_by_name():
    sj, system, y0 = _so4_setup()
    x, ys = np.broadcast_to(y0, (4, 4, 4)), np.zeros((2, 3))
    kw = dict(dt=0.25, key=jax.random.key(0))

    def observed(times):
        return sj.Observations(ys, times=times, observe=lambda y: y[0, 1:], std=0.1)

    for times, what in [
        ([0.5, 0.5], "increasing"),
        ([0.5, 0.25], "increasing"),
        ([0.3, 0.6], "grid"),
        ([0.5, 1.25], "equally spaced"),
    ]:
        with pytest.raises(ValueError, match=f"observation times must be .*{what}"):
            sj.particle_filter(system, x, observed(times), **kw)
    good = observed([0.5, 1.0])
    with pytest.raises(ValueError, match="need their times"):
        sj.particle_filter(
            system, x, sj.Observations(ys, observe=lambda y: y[0, 1:], std=0.1), **kw
        )
    with pytest.raises(ValueError, match="particles"):
        sj.particle_filter(system, x[:1], good, **kw)
    with pytest.raises(ValueError, match="y0"):  # a particle that is not a state
        sj.particle_filter(system, np.ones((4, 4, 4)), good, **kw)
    one = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    with pytest.raises(ValueError, match="chunk_size or sharding"):
        sj.particle_filter(system, x, good, chunk_size=2, sharding=one, **kw)
    with pytest.raises(ValueError, match="throw=True"):
        sj.particle_filter(system, x, good, failures=sj.Failures(throw=True), **kw)
    with pytest.raises(ValueError, match="jitter_lag"):
        sj.particle_filter(system, x, good, **kw, tempering=sj.Tempering(jitter_lag=0))


def test_complex_states_get_real_increments_and_keep_their_orbit():
    # su(N) states are complex: the increments and the weights stay real
    import slps_jax as sj
    from slps_jax import zeitlin as z

    N, n, h = 4, 8, 0.05
    w0 = z.shr2mat(np.eye(N * N)[2] + 0.5 * np.eye(N * N)[5], N)
    system = sj.EulerZeitlin(N, noise=sj.salt_noise(0.1 * z.shr2mat(np.eye(N * N)[[1, 2, 3]], N)))
    observe = lambda w: jnp.real(z.mat2shr(w))[4:7]
    ys = np.stack([np.asarray(observe(w0))] * 2) + 0.01
    res = sj.particle_filter(
        system,
        np.broadcast_to(w0, (n, N, N)),
        sj.Observations(ys, times=[0.2, 0.4], observe=observe, std=0.05),
        dt=h,
        key=jax.random.key(0),
        tempering=sj.Tempering(jitter_steps=1),
    )
    assert res.particles.shape == (2, n, N, N) and jnp.iscomplexobj(res.particles)
    assert not jnp.iscomplexobj(res.ess) and not jnp.iscomplexobj(res.log_evidence)
    c0 = np.asarray(sj.su(N).casimirs(w0))
    cs = np.asarray(sj.su(N).casimirs(res.particles))
    assert np.max(np.abs(cs[..., ::2] / c0[::2] - 1)) < 1e-12  # tr W^2, tr W^4


def test_chunking_the_particles_does_not_change_the_filter():
    # each particle's forecast is its own: in chunks of 3 (the last one short) by lax.map,
    # the filter gives what it gives with every particle at once
    _, system, y0 = _so4_setup()
    ys = np.stack([np.asarray(_observe(y0))] * 2) + 0.01
    one_move = da.Tempering(jitter_steps=1)
    run = lambda chunk: _so4_filter(
        system, y0, ys, 8, [0.125, 0.25], key=5, tempering=one_move, chunk_size=chunk
    )
    whole, chunked = run(None), run(3)
    # another filter of the same configuration (other observations) compiles nothing again
    events = []
    listener = lambda name, seconds, **kw: events.append(kw) if "backend_compile" in name else None
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        _so4_filter(system, y0, ys + 0.01, 8, [0.125, 0.25], key=6, tempering=one_move)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert events == []
    assert np.ptp(np.asarray(whole.particles[-1]), axis=0).max() > 1e-4  # (distinct particles)
    np.testing.assert_allclose(chunked.particles, whole.particles, rtol=0, atol=1e-13)
    np.testing.assert_allclose(chunked.ess, whole.ess, rtol=1e-12)
    np.testing.assert_allclose(chunked.log_evidence, whole.log_evidence, rtol=1e-12)
    with pytest.raises(ValueError, match="chunk_size"):
        run(0)


def test_an_ornstein_uhlenbeck_driver_keeps_orbits_and_resumes_from_disk(tmp_path):
    # so(4) driven by smooth Ornstein-Uhlenbeck traces: each particle carries its traces
    # (started from their stationary law), pCN moves the standard normals of their exact
    # steps; the particles keep their Casimirs, and the filter on disk, one observation then
    # both resumed, is the filter in memory bit for bit
    sj, system, y0 = _so4_setup()
    ys = np.stack([np.asarray(_observe(y0))] * 2) + 0.01
    x = np.broadcast_to(y0, (8, 4, 4))
    kw = dict(dt=_H, key=jax.random.key(4), tempering=sj.Tempering(jitter_steps=1))

    def observed(values):
        times = [0.125, 0.25][: len(values)]
        return sj.Observations(values, times=times, observe=_observe, std=0.05)

    driver = sj.OrnsteinUhlenbeck([0.2, 0.3, 0.5])
    res = sj.particle_filter(system, x, observed(ys), driver=driver, **kw)
    assert res.particles.shape == (2, 8, 4, 4) and res.mean.shape == (2, 4, 4)
    c0 = np.asarray(sj.so(4).casimirs(y0))
    assert np.max(np.abs(np.asarray(sj.so(4).casimirs(res.particles)) / c0 - 1)) < 1e-12
    assert np.ptp(np.asarray(res.particles[-1]), axis=0).max() > 1e-4  # (the traces drive)
    path, disk = tmp_path / "ou", dict(kw, driver=driver)
    sj.particle_filter_to_store(system, x, observed(ys[:1]), sj.Store(path, progress=False), **disk)
    resume = sj.Store(path, resume=True, progress=False)
    run = sj.particle_filter_to_store(system, x, observed(ys), resume, **disk)
    assert np.array_equal(run.read("state"), np.asarray(res.particles))
    with pytest.raises(ValueError, match="4 correlation times"):
        sj.particle_filter(
            system, x, observed(ys), **kw, driver=sj.OrnsteinUhlenbeck([1.0, 2.0, 3.0, 4.0])
        )
    # the default is Gaussian Brownian increments: a driver that truncates them or draws
    # Lévy areas is refused (pCN keeps a Gaussian law), and one that does neither is it
    gaussian = sj.BrownianMotion(truncate_k=None, levy_area=False)
    for refused in (sj.BrownianMotion(), sj.BrownianMotion(truncate_k=None, levy_area=True)):
        with pytest.raises(ValueError, match=r"truncate_k=None, levy_area=False"):
            sj.particle_filter(system, x, observed(ys), **kw, driver=refused)
    with pytest.raises(TypeError, match="driver must be None"):
        sj.particle_filter(system, x, observed(ys), **kw, driver="ou")
    plain = sj.particle_filter(system, x, observed(ys[:1]), **kw)
    given = sj.particle_filter(system, x, observed(ys[:1]), **kw, driver=gaussian)
    assert np.array_equal(plain.particles, given.particles)


BAD_FILTER = [
    (dict(times=[0.5, 1.0, 1.5]), ValueError, "have 3 times for 4 values"),
    (dict(key=0), TypeError, r"pass jax.random.key\(0\)"),
    (dict(std=[0.1, 0.1]), ValueError, r"std must be a scalar or one error .*\(3,\)"),
    (dict(std=[0.1, 1e-17, 0.1]), ValueError, r"std is 1.0e-17 at observed quantities \[1\]"),
    (dict(std=-0.1), ValueError, "std must be positive"),
    (dict(particles="one"), ValueError, r"particles must be n >= 2 states .*one state"),
    (dict(tempering=None), TypeError, "tempering must be a Tempering"),
    (dict(observations=np.zeros((4, 3))), TypeError, "observations must be an Observations"),
]


BAD_TEMPERING = [
    (dict(ess_threshold=1.5), ValueError, r"ess_threshold must be a number in \(0, 1\]"),
    (dict(ess_threshold=-0.5), ValueError, "ess_threshold"),
    (dict(jitter_steps=-1), ValueError, "jitter_steps must be an integer >= 0"),
    (dict(jitter_steps=1.5), ValueError, "jitter_steps"),
    (dict(jitter_rho=1.5), ValueError, r"jitter_rho must be a number in \[0, 1\]"),
    (dict(jitter_lag=0), ValueError, "jitter_lag"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_TEMPERING)
def test_tempering_refuses_bad_options_by_name(bad, exc, match):
    with pytest.raises(exc, match=f"^Tempering: {match}"):
        da.Tempering(**bad)


@pytest.mark.parametrize("bad,exc,match", BAD_FILTER)
@pytest.mark.parametrize("caller", ["particle_filter", "particle_filter_to_store"])
def test_particle_filter_refuses_bad_calls_by_name_before_any_forecast(
    tmp_path, caller, bad, exc, match
):
    """Each bad call is refused before any forecast runs (the forecast is replaced by one
    that fails), naming the function called and the argument."""
    sj, system, y0 = _so4_setup()
    observed = dict(times=[0.5, 1.0, 1.5, 2.0], observe=lambda y: y[0, 1:], std=0.1)
    observed.update({k: v for k, v in bad.items() if k in observed})
    kw = dict(
        particles=np.broadcast_to(y0, (4, 4, 4)),
        observations=sj.Observations(np.zeros((4, 3)), **observed),
        dt=0.25,
        key=jax.random.key(0),
    )
    kw.update({k: v for k, v in bad.items() if k not in observed})
    if isinstance(kw["particles"], str):  # (one state where the ensemble goes)
        kw["particles"] = y0

    def boom(*args, **kwargs):
        raise AssertionError("a forecast ran before the arguments were checked")

    args = (system, kw.pop("particles"), kw.pop("observations"))
    with mock.patch("slps_jax._forecasting.particle_filter._forecast", boom):
        with pytest.raises(exc, match=f"^{caller}: .*{match}"):
            if caller == "particle_filter":
                sj.particle_filter(*args, **kw)
            else:
                sj.particle_filter_to_store(*args, sj.Store(tmp_path / "run.zarr"), **kw)
    assert not (tmp_path / "run.zarr").exists()
