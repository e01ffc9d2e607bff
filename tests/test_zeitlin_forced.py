"""Forced-dissipative Euler–Zeitlin, the rotating sphere and the quasi-geostrophic model, each
against an exact fact: the decay of one degree, the Rossby–Haurwitz wave's exact phase (and
its order of convergence), the Casimirs of the bracket part, the inviscid step bit for bit,
the forcing's steady state, and the quasi-geostrophic operator applied densely."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import slps_jax as sj
from slps_jax import zeitlin as z
from slps_jax._driver.splitting import system_step


def _degree(N, ell, seed=0, scale=1.0):
    """A random state of one degree `ell`."""
    rng = np.random.default_rng(seed)
    om = np.zeros(N * N)
    for m in range(-ell, ell + 1):
        om[z.elm2ind(ell, m)] = scale * rng.normal()
    return z.shr2mat(om, N)


def _rough(N, seed=0):
    """A state with energy at every degree, coefficients N(0, 1)/l."""
    rng = np.random.default_rng(seed)
    om = rng.normal(size=N * N) / np.sqrt(np.repeat(np.arange(N), 2 * np.arange(N) + 1) + 1.0)
    om[0] = 0.0
    return z.shr2mat(om, N)


def _decay(h, ell, nu, p, alpha):
    return np.exp(-h * (nu * (ell * (ell + 1.0) - 2.0) ** p + alpha))


@pytest.mark.parametrize("nu, p, alpha", [(2e-3, 1, 0.0), (1e-6, 3, 0.0), (1e-3, 2, 0.3)])
def test_one_degree_decays_exactly_and_rigid_rotations_are_spared(nu, p, alpha):
    N, h = 16, 0.01
    system = sj.EulerZeitlin(N, nu=nu, p=p, alpha=alpha)
    for ell in (1, 2, 7, 15):
        w = _degree(N, ell, seed=ell)
        # the linear substep: exact for any amplitude
        got = system.linear_flow(w, h)
        want = _decay(h, ell, nu, p, alpha) * np.asarray(w)
        assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(w)), ell
        # the whole step, on a state small enough that the bracket part (whose discrete
        # steady states are not exactly the continuous ones: O(h^2 |W|^2)) moves nothing
        small = 1e-5 * w
        got, info = system_step(sj.IsospectralMidpoint(), system, small, h, jnp.zeros(1))
        assert int(info.result) == 0
        want = _decay(h, ell, nu, p, alpha) * np.asarray(small)
        assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(small)), ell
    assert _decay(h, 1, nu, p, 0.0) == 1.0  # (l = 1: untouched by the viscosity)


def test_constant_forcing_enters_by_variation_of_constants():
    N, h, alpha, nu = 8, 0.05, 0.4, 1e-2
    F = _degree(N, 3, seed=4)
    system = sj.EulerZeitlin(N, nu=nu, alpha=alpha, forcing=F)
    lam = nu * (3 * 4 - 2) + alpha
    w = system.linear_flow(jnp.zeros((N, N), complex), h)
    np.testing.assert_allclose(w, (1 - np.exp(-h * lam)) / lam * np.asarray(F), atol=1e-14)
    # its steady state F / lambda is a fixed point of the whole step (a single degree:
    # the bracket of W with its stream vanishes; small, so that the discrete one does too)
    small = sj.EulerZeitlin(N, nu=nu, alpha=alpha, forcing=1e-5 * F)
    steady = 1e-5 * np.asarray(F) / lam
    y, _ = system_step(sj.IsospectralMidpoint(), small, jnp.asarray(steady), h, jnp.zeros(1))
    assert np.max(np.abs(y - steady)) <= 1e-13 * np.max(np.abs(steady))


def test_rossby_haurwitz_wave_on_the_rotating_sphere():
    N, ell, a, omega = 16, 5, 0.7, 1.3
    T10 = np.asarray(z.shr2mat(np.eye(4)[2], N))
    w_ell = np.asarray(_degree(N, ell, seed=1))
    w0 = a * T10 + w_ell
    f0 = 2 * omega / np.sqrt(3)
    f = np.asarray(z.planetary_vorticity(N, omega))
    assert np.max(np.abs(f - f0 * T10)) < 1e-14  # f = 2 Omega cos(theta) = f0 T_10
    # [P, W + f] = (-a/2 + (a + f0)/(l(l+1))) [T_10, W_l]
    speed = -a / 2 + (a + f0) / (ell * (ell + 1))
    P = np.asarray(sj.EulerZeitlin(N, omega=omega).stream(w0))
    bracket = P @ (w0 + f) - (w0 + f) @ P
    assert np.max(np.abs(bracket - speed * (T10 @ w_ell - w_ell @ T10))) < 1e-14
    # T_10 is diagonal: the exact solution turns each entry of W_l by its own phase (and
    # with viscosity, which commutes with the turning, decays as it turns)
    d = np.diag(T10)
    nu, p, n = 1e-3, 2, 32

    def exact(viscosity, t):
        phase = np.exp((d[:, None] - d[None, :]) * speed * t / z.hbar(N))
        return a * T10 + phase * w_ell * np.exp(-t * viscosity * (ell * (ell + 1) - 2) ** p)

    for viscosity in (0.0, nu):
        system = sj.EulerZeitlin(N, omega=omega, nu=viscosity, p=p)
        # n steps of h = 1/64, 1/128, 1/256 (one compiled program): the phase error grows
        # as t h^2 (times the wave's decay), so the error per unit time falls as h^2
        errors, amplitude = [], []
        for h in (2.0**-6, 2.0**-7, 2.0**-8):
            y = sj.integrate(system, jnp.asarray(w0), jnp.zeros((n, 1)), h)
            want = exact(viscosity, n * h)
            decay = np.exp(-n * h * viscosity * (ell * (ell + 1) - 2) ** p)
            errors.append(np.max(np.abs(y - want)) / (n * h * decay))
            ratio = np.linalg.norm(y - a * T10) / np.linalg.norm(want - a * T10)
            amplitude.append(abs(ratio - 1))
        orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
        assert np.all(np.abs(orders - 2) < 0.1), (viscosity, errors)
        if viscosity == 0:  # the wave's norm is kept to round-off
            assert max(amplitude) < 1e-12, amplitude
        else:  # decayed at the exact rate up to the splitting's error, of order 4 here
            # (the midpoint moves a little of the wave into T_10, which decays otherwise)
            assert amplitude[0] < 1e-7 and amplitude[1] < amplitude[0] / 8, amplitude
            assert amplitude[2] < amplitude[1] / 8, amplitude


def test_with_no_new_term_the_step_is_the_inviscid_one_bit_for_bit():
    N, h = 12, 0.02
    w = _rough(N)
    method = sj.IsospectralMidpoint()
    plain = sj.EulerZeitlin(N)
    off = sj.EulerZeitlin(N, nu=0.0, p=3, alpha=0, forcing=None, omega=None, stream=None)
    assert off.linear is None and off.omega is None and off.tables is None
    y0, _ = method.step(plain, w, h, jnp.zeros(1))
    y1, _ = system_step(method, off, w, h, jnp.zeros(1))
    assert np.array_equal(np.asarray(y0), np.asarray(y1))
    dW = jnp.asarray(np.random.default_rng(0).normal(size=(6, 1)) * np.sqrt(h))
    a = sj.integrate(sj.EulerZeitlin(N, c=0.3), w, dW, h)
    b = sj.integrate(sj.EulerZeitlin(N, c=0.3, nu=0, alpha=0.0), w, dW, h)
    assert np.array_equal(np.asarray(a), np.asarray(b))


def test_dissipation_changes_the_casimirs_only_in_the_linear_substep():
    N, h = 16, 0.01
    system = sj.EulerZeitlin(N, nu=1e-3, p=2, alpha=0.1)
    method = sj.IsospectralMidpoint()
    w = _rough(N, seed=2)
    half = system.linear_flow(w, 0.5 * h)
    inner, _ = method.step(system, half, h, jnp.zeros(1))
    full, info = system_step(method, system, w, h, jnp.zeros(1))
    assert int(info.result) == 0
    np.testing.assert_array_equal(full, system.linear_flow(inner, 0.5 * h))
    c0, c1 = (np.asarray(system.algebra.casimirs(x))[:5] for x in (half, inner))
    scale = np.asarray(
        [np.sum(np.abs(np.linalg.eigvalsh(1j * np.asarray(half))) ** k) for k in range(2, 7)]
    )
    assert np.max(np.abs(c1 - c0) / scale) <= 1e-13
    # and they do change in the linear substep (the enstrophy decays)
    assert np.asarray(system.algebra.casimirs(full))[0] > np.asarray(system.algebra.casimirs(w))[0]


@pytest.mark.parametrize("gamma", [0.5, 10.0])
def test_quasi_geostrophic_stream_solves_its_equation(gamma):
    N = 12
    w = np.asarray(_rough(N, seed=3))
    P = np.asarray(z.solve_poisson(w, gamma=gamma))
    Pscan = np.asarray(z.solve_poisson(w, route="scan", gamma=gamma))
    np.testing.assert_allclose(Pscan, P, atol=1e-13)
    assert abs(np.trace(P)) < 1e-13
    # the operator applied densely, in NumPy: Delta_N P + gamma/2 (Z^2 P + P Z^2) = W up to
    # a multiple of the identity (the trace of the stream, removed)
    s = (N - 1) / 2
    Z = 1j * z.hbar(N) * np.diag(np.arange(N) - s)
    lhs = np.asarray(z.laplacian(P)) + 0.5 * gamma * (Z @ Z @ P + P @ Z @ Z)
    residual = lhs - w
    shift = np.trace(residual) / N
    # (the identity's image: Delta_N I = 0, Z^2 I + I Z^2 = 2 Z^2)
    c = shift / (gamma * np.trace(Z @ Z) / N)
    np.testing.assert_allclose(residual, c * gamma * (Z @ Z), atol=1e-12)
    # an independent solve of the same system (scipy, dense) gives the same stream
    A = np.zeros((N * N, N * N), complex)
    for k in range(N * N):
        e = np.zeros(N * N, complex)
        e[k] = 1
        E = e.reshape(N, N)
        A[:, k] = (np.asarray(z.laplacian(E)) + 0.5 * gamma * (Z @ Z @ E + E @ Z @ Z)).ravel()
    dense = scipy.linalg.solve(A, w.ravel()).reshape(N, N)
    dense = dense - np.trace(dense) / N * np.eye(N)
    np.testing.assert_allclose(P, dense, atol=1e-12 * np.max(np.abs(dense)))
    # the model conserves its energy -1/2 <W, P> and its Casimirs along a run
    system = sj.EulerZeitlin(N, stream=sj.Stream(gamma=gamma))
    y = sj.integrate(system, jnp.asarray(w), jnp.zeros((20, 1)), 0.01, save_every=20)
    e0, e1 = float(system.energy(w)), float(system.energy(y[-1]))
    assert abs(e1 - e0) < 1e-4 * abs(e0)  # (the midpoint rule: O(h^2) energy error)
    c0, c1 = system.algebra.casimirs(w)[0], system.algebra.casimirs(y[-1])[0]
    assert abs(float(c1 - c0)) < 1e-13 * abs(float(c0))


def test_transport_noise_complex64_and_an_ensemble_run_with_every_term():
    N = 8
    X = jnp.stack([_degree(N, el, seed=el) for el in (1, 2, 3)]) * 0.1
    F = _degree(N, 4, seed=9) * 0.5
    kwargs = dict(nu=1e-3, p=2, alpha=0.05, forcing=F, omega=0.5)
    for dtype in (jnp.complex128, jnp.complex64):
        system = sj.EulerZeitlin(N, noise=sj.salt_noise(X), dtype=dtype, **kwargs)
        sol = sj.simulate(system, _rough(N), t1=0.2, dt=0.02, n_samples=3, key=jax.random.key(0))
        assert sol.ys.dtype == dtype and np.all(np.isfinite(np.asarray(sol.ys)))
        # the states stay in su(N) (the linear substep maps su(N) to itself)
        last = np.asarray(sol.ys[:, -1]).astype(np.complex128)
        tol = 1e-12 if dtype == jnp.complex128 else 1e-5
        assert max(system.algebra.distance(x) for x in last) < tol * np.max(np.abs(last))
    assert "nu=0.001" in repr(system) and "omega=0.5" in repr(system) and "p=2" in repr(system)


def test_bad_input_refused_by_name_before_any_work():
    N = 6
    good = np.asarray(_degree(N, 2))
    for kwargs, match in [
        (dict(nu=-1.0), "nu must be"),
        (dict(nu=float("nan")), "nu must be"),
        (dict(alpha=-0.1), "alpha must be"),
        (dict(nu=1e-3, p=0), "p must be a positive integer"),
        (dict(nu=1e-3, p=1.5), "p must be a positive integer"),
        (dict(p=-2), "p must be a positive integer"),
        (dict(forcing=np.zeros((N + 1, N + 1), complex)), "forcing must be an element"),
        (dict(forcing=np.ones((N, N))), "skew-Hermitian"),
        (dict(forcing=good + 1j * np.eye(N)), "traceless"),
        (dict(stream=sj.Stream(gamma=1.0), poisson="eigenbasis"), "gamma > 0"),
        (dict(stream=sj.Stream(gain=np.zeros(N + 1))), "gain has"),
        (dict(alpha=np.ones(N - 1)), "one real number per degree"),
        (dict(alpha=-np.ones(N)), "finite and >= 0"),
        (dict(omega=float("inf")), "omega must be"),
    ]:
        with pytest.raises(ValueError, match=match):
            sj.EulerZeitlin(N, **kwargs)
    for kwargs, match in [
        (dict(gamma=-0.5), "gamma must be"),
        (dict(gain=np.ones((2, N))), "gain must be one real number per degree"),
        (dict(gain=np.full(N, np.nan)), "gain must be finite"),
    ]:
        with pytest.raises(ValueError, match=match):
            sj.Stream(**kwargs)
    with pytest.raises(TypeError, match="stream must be a Stream"):
        sj.EulerZeitlin(N, stream=0.5)
    for band, amplitude, match in [
        ((0, 2), 1.0, "band must be"),
        ((2, N), 1.0, "band"),
        ((3, 2), 1.0, "band must be"),
        ((1, 2), None, "amplitude must be"),
        ((1, 2), [1.0, 2.0, 3.0], "one per degree"),
        ((1, 2), -1.0, "finite and >= 0"),
    ]:
        with pytest.raises(ValueError, match=match):
            sj.EulerZeitlin(N, additive=sj.AdditiveForcing(band, amplitude))
    forced = sj.EulerZeitlin(N, additive=sj.AdditiveForcing((1, 2), 0.1))
    with pytest.raises(ValueError, match="take no Lévy areas"):
        sj.simulate(
            forced,
            good,
            t1=0.1,
            dt=0.05,
            n_samples=1,
            key=jax.random.key(0),
            driver=sj.BrownianMotion(levy_area=True),
        )


def test_additive_forcing_gives_the_schemes_exact_stationary_variance():
    # one degree forced, damped: each coefficient is an Ornstein-Uhlenbeck process (the
    # bracket of a one-degree state vanishes; small, so that the discrete one does too).
    # The splitting L K Phi K L gives w_{n+1} = e^{-ah} w_n + e^{-ah/2} sigma dB: stationary
    # variance sigma^2 h / (2 sinh(ah)), the exact sigma^2 / (2a) times ah / sinh(ah)
    N, ell, sigma, alpha, h = 6, 2, 1e-3, 2.0, 0.5
    system = sj.EulerZeitlin(N, alpha=alpha, additive=sj.AdditiveForcing((ell, ell), sigma))
    assert system.n_noises == 1 + 2 * ell + 1 and system.additive.n_noises == 5
    assert float(system.additive.enstrophy_injection()) == pytest.approx(2.5 * sigma**2)
    n = 2000
    sol = sj.simulate(
        system, jnp.zeros((N, N), complex), t1=4.0, dt=h, n_samples=n, key=jax.random.key(3)
    )
    om = np.asarray(z.mat2shr(sol.ys[:, -1], L=ell + 1))
    band = om[:, ell * ell : (ell + 1) ** 2]  # (n, 5): independent, mean 0
    assert np.max(np.abs(np.delete(om, np.s_[ell * ell : (ell + 1) ** 2], 1))) < 1e-15
    var = np.mean(band**2)  # (the mean is 0)
    # (started at 0: after t = 4 the variance is within e^{-2 alpha t} = 1e-7 of stationary)
    want = sigma**2 * h / (2 * np.sinh(alpha * h))
    se = want * np.sqrt(2.0 / band.size)
    assert abs(var - want) < 4 * se, (var, want, se)
    assert abs(var - sigma**2 / (2 * alpha)) > 4 * se  # (the exact one is 18 % above)
    # with an Ornstein-Uhlenbeck driver the forcing is correlated in time: it runs, every
    # sample stays in su(N), and the forced band alone moves
    ou = sj.simulate(
        system,
        jnp.zeros((N, N), complex),
        t1=1.0,
        dt=h,
        n_samples=2,
        key=jax.random.key(0),
        driver=sj.OrnsteinUhlenbeck(0.5),
    )
    om = np.asarray(z.mat2shr(ou.ys[:, -1], L=ell + 1))
    assert np.all(np.abs(om[:, ell * ell :]) > 0) and np.max(np.abs(om[:, : ell * ell])) < 1e-15


def test_enstrophy_and_energy_budgets_close_at_order_two():
    # W(t) - W(0) against the time integral (trapezoid) of injection - dissipation -
    # damping along the run: they differ by the time discretisation only, O(h^2)
    N, t1 = 12, 1.0
    F = 2.0 * np.asarray(_degree(N, 3, seed=5))
    system = sj.EulerZeitlin(N, nu=2e-3, p=2, alpha=0.3, forcing=F)
    w0 = _rough(N, seed=6)
    gaps = []
    for n in (64, 128, 256):
        h = t1 / n
        ys = sj.integrate(system, w0, jnp.zeros((n, 1)), h, save_every=1)  # (w0 first)
        rates = system.budget(ys)
        gap = []
        for q, total in (("enstrophy", system.enstrophy(ys)), ("energy", system.energy(ys))):
            net = rates[f"{q}_injection"] - rates[f"{q}_dissipation"] - rates[f"{q}_damping"]
            integral = h * (jnp.sum(net) - 0.5 * (net[0] + net[-1]))
            gap.append(abs(float(total[-1] - total[0] - integral)) / abs(float(integral)))
        gaps.append(gap)
    gaps = np.asarray(gaps)
    orders = np.log2(gaps[:-1] / gaps[1:])
    assert np.all(np.abs(orders - 2) < 0.15), (gaps, orders)
    assert np.all(gaps[-1] < 3e-3)  # (relative to the integral, at h = 1/256)


def test_transfer_and_flux_against_the_flow_itself():
    N, h = 12, 1e-3
    system = sj.EulerZeitlin(N)
    w = _rough(N, seed=7)
    T = np.asarray(sj._systems.budgets.transfer(system, w))
    assert np.max(np.abs(T.sum(-1))) < 1e-12 * np.max(np.abs(T))  # (Casimir, Hamiltonian)
    flux = np.asarray(system.flux(w))
    np.testing.assert_allclose(flux, -np.cumsum(T, -1), atol=1e-13)
    # the spectra's rate of change along the integrator's own steps, h forward and back
    method = sj.IsospectralMidpoint(rtol=0)
    fwd, _ = method.step(system, w, h, jnp.zeros(1))
    back, _ = method.step(system, w, -h, jnp.zeros(1))
    dz = (z.enstrophy_spectrum(fwd) - z.enstrophy_spectrum(back)) / (2 * h)
    de = (z.energy_spectrum(fwd) - z.energy_spectrum(back)) / (2 * h)
    np.testing.assert_allclose(dz, T[0], atol=1e-5 * np.max(np.abs(T[0])))
    np.testing.assert_allclose(de, T[1], atol=1e-5 * np.max(np.abs(T[1])))
    # the forced-dissipative run store has the budgets and fluxes, by degree
    pytest.importorskip("zarr")
    system = sj.EulerZeitlin(8, nu=1e-3, alpha=0.1, additive=sj.AdditiveForcing((2, 3), 0.1))
    run = sj.simulate_to_store(
        system,
        _rough(8),
        sj.Store(
            str(pytest.importorskip("pathlib").Path(__import__("tempfile").mkdtemp()) / "run"),
            progress=False,
        ),
        t1=0.2,
        dt=0.05,
        n_samples=2,
        key=jax.random.key(0),
        save_every=2,
    )
    assert run.read("enstrophy_flux").shape == (3, 2, 8)  # (t = 0, 0.1, 0.2)
    assert np.max(np.abs(run.read("energy_flux")[..., -1])) < 1e-12
    injection = run.read("enstrophy_injection")  # (the additive forcing's mean rate alone)
    np.testing.assert_allclose(injection, 0.5 * 0.1**2 * (5 + 7))
    assert np.all(run.read("enstrophy_dissipation") > 0) and np.all(run.read("energy_damping") > 0)


def test_a_run_whose_steps_are_mostly_redone_warns_once_and_names_a_step_that_is_not():
    import warnings

    N = 16
    system = sj.EulerZeitlin(N)
    w = 4.0 * _rough(N, seed=1)  # (every step at h = 0.05 is redone as substeps)
    guide = system.step_guide(w)
    # the guide is quflow's estimate_stepsize in seconds: 0.1 pi hbar / rho(P)
    rho = np.linalg.norm(np.asarray(system.stream(w)), 2)
    assert guide == pytest.approx(0.1 * np.pi * z.hbar(N) / rho, rel=1e-12)
    for h, n_warnings in ((0.05, 1), (guide, 0)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sol = sj.simulate(system, w, t1=8 * h, dt=h, n_samples=1, key=jax.random.key(0))
        redone = [c for c in caught if "redone as substeps" in str(c.message)]
        assert len(redone) == n_warnings, (h, [str(c.message) for c in caught])
        if n_warnings:
            assert int(sol.stats["n_retried_steps"]) == 8
            assert "system.step_guide" in str(redone[0].message)
        else:
            assert int(sol.stats["n_retried_steps"]) == 0
    with pytest.raises(ValueError, match="safety"):
        system.step_guide(w, safety=0)


def test_joined_linear_flows_are_the_strang_steps():
    # The driver joins each step's last half linear flow to the next one's first
    # (L_a L_b = L_{a + b}): the saved states are those of the full Strang steps one by one,
    # through the retry too (a rough start at a large step: every step redone as substeps).
    N = 8
    rng = np.random.default_rng(3)
    forcing = _degree(N, 3, seed=5)
    system = sj.EulerZeitlin(
        N,
        nu=1e-2,
        p=2,
        alpha=0.2,
        forcing=forcing,
        omega=1.5,
        additive=sj.AdditiveForcing((2, 4), 0.3),
    )
    method = sj.IsospectralMidpoint(rtol=0.0)
    step = jax.jit(lambda y, h, w: system_step(method, system, y, h, w))
    for w0, h, n, retried in ((_rough(N), 0.02, 12, False), (6.0 * _rough(N), 0.2, 6, True)):
        dW = jnp.asarray(rng.normal(size=(n, system.n_noises)) * np.sqrt(h))
        got = sj.integrate(
            system, w0, dW, h, method=method, save_every=3, failures=sj.Failures(throw=False)
        )
        y, want = jnp.asarray(w0), [jnp.asarray(w0)]
        for k in range(n):  # (full steps: each with both half flows; substeps as the driver's)
            y = _strang_with_substeps(step, y, h, dW[k])
            if (k + 1) % 3 == 0:
                want.append(y)
        want = np.stack(want)
        assert np.max(np.abs(np.asarray(got) - want)) <= 1e-12 * np.max(np.abs(want)), retried


def _strang_with_substeps(step, y, h, dW, k=4):
    """One step of full Strang steps (`step`), redone as k, k^2 ... substeps where it fails."""
    for m in (1, k, k * k, k**3):
        ys, ok = y, True
        for _ in range(m):
            ys, info = step(ys, h / m, dW / m)
            ok = ok and int(info.result) == 0
        if ok:
            return ys
    raise AssertionError("every attempt failed")


def test_gradient_through_joined_and_retried_steps_matches_finite_differences():
    # d/d(nu) of a functional of simulate's final state, where the first step is redone as
    # substeps (the retry's Jacobians carry the joined linear flows' debt) and the others
    # are not: against central differences.
    N = 8
    base = dict(p=2, alpha=3.0, forcing=_degree(N, 3, seed=4))

    def loss(nu):
        sol = sj.simulate(
            sj.EulerZeitlin(N, nu=nu, **base),
            4.0 * _rough(N),
            t1=0.4,
            dt=0.1,
            n_samples=1,
            key=jax.random.key(1),
            newton_stats=True,
            method=sj.IsospectralMidpoint(rtol=0.0),
        )
        return jnp.sum(jnp.abs(sol.ys) ** 2), sol.stats["n_retried_steps"]

    (_, retried), grad = jax.value_and_grad(loss, has_aux=True)(1e-2)
    assert 0 < int(retried) < 4
    e = 1e-5
    fd = (loss(1e-2 + e)[0] - loss(1e-2 - e)[0]) / (2 * e)
    assert abs(float(grad) - float(fd)) <= 1e-6 * abs(float(fd)), (grad, fd)


def test_step_size_gradient_through_a_retried_step_after_a_joined_one():
    # d/d(dt) of integrate's final state where the second step (a large transport
    # increment) is redone as substeps: its start owes the first step's half linear flow,
    # dt/2, whose derivative the retry's Jacobians carry. Against central differences.
    N = 8
    system = sj.EulerZeitlin(
        N,
        nu=1e-2,
        p=2,
        alpha=1.0,
        forcing=_degree(N, 3, seed=4),
        noise=sj.salt_noise(jnp.stack([_degree(N, 2, seed=7)])),
    )
    dW = jnp.asarray([[0.01], [2.0], [0.01], [0.01]])
    method = sj.IsospectralMidpoint(rtol=0.0)

    def loss(dt):
        return jnp.sum(jnp.abs(sj.integrate(system, _rough(N), dW, dt, method=method)) ** 2)

    step = jax.jit(lambda y, w: system_step(method, system, y, 0.05, w))
    y1, info = step(jnp.asarray(_rough(N)), dW[0])
    assert int(info.result) == 0
    assert int(step(y1, dW[1])[1].result) != 0  # (the second step is redone)
    grad = jax.grad(loss)(0.05)
    e = 1e-6
    fd = (loss(0.05 + e) - loss(0.05 - e)) / (2 * e)
    assert abs(float(grad) - float(fd)) <= 1e-6 * abs(float(fd)), (grad, fd)


def test_a_stream_gain_is_a_modified_hamiltonian_with_the_exact_wave():
    """`Stream(gain=g)`: the stream against its coefficients (`mat2shr`, not the eigenbasis),
    the Hamiltonian's gradient against finite differences, and the two-degree wave
    `a T_10 + W_l`, which turns exactly at the rate `a (s_1 - s_l)`, `s_l = -1/(l(l+1)) + g_l`:
    the step's error falls at order 2 and every Casimir and the modified energy are kept."""
    N, ell, a = 12, 4, 0.25
    rng = np.random.default_rng(5)
    g = rng.normal(size=N) * 0.05
    system = sj.EulerZeitlin(N, stream=sj.Stream(gain=g))
    w = _rough(N, seed=3)
    el = np.repeat(np.arange(N), 2 * np.arange(N) + 1)
    s = np.where(el > 0, -1.0 / np.maximum(el * (el + 1.0), 1) + g[el], 0.0)
    want = z.shr2mat(s * np.asarray(z.mat2shr(w)), N)
    assert np.max(np.abs(system.stream(w) - want)) < 1e-13 * np.max(np.abs(want))
    # the gradient of H0 = N E / (2 hbar), E = -<W, P>/2, by central differences
    v = _rough(N, seed=4)
    eps = 1e-6
    fd = (system.hamiltonian(w + eps * v) - system.hamiltonian(w - eps * v)) / (2 * eps)
    pairing = 0.5 * np.real(np.trace(np.conj(system.gradient(w)).T @ v))
    assert abs(fd - pairing) < 1e-7 * abs(pairing)
    # the wave
    T10 = np.asarray(z.shr2mat(np.eye(4)[2], N))
    w_ell = np.asarray(_degree(N, ell, seed=2))
    w0 = a * T10 + w_ell
    s1, sl = -0.5 + g[1], -1.0 / (ell * (ell + 1)) + g[ell]
    d = np.diag(T10)
    n = 32

    def exact(t):
        return a * T10 + np.exp((d[:, None] - d[None, :]) * a * (s1 - sl) * t / z.hbar(N)) * w_ell

    errors = []
    for h in (2.0**-7, 2.0**-8, 2.0**-9):
        y = sj.integrate(system, jnp.asarray(w0), jnp.zeros((n, 1)), h)
        errors.append(np.max(np.abs(y - exact(n * h))) / (n * h))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 2) < 0.1), errors
    # a rough state: the Casimirs to round-off, the modified energy (not Euler's) to the
    # method's order 2
    drift = []
    for h in (2.0**-7, 2.0**-8):
        y = sj.integrate(system, w, jnp.zeros((n, 1)), h)
        c0, c1 = (np.asarray(system.algebra.casimirs(x))[:4] for x in (w, y))
        assert np.max(np.abs(c1 - c0) / np.abs(c0)) < 1e-12
        drift.append(abs(float(system.energy(y) - system.energy(w))))
    assert drift[0] / drift[1] > 3.5, drift  # (an oscillating error: at least order 2)
    assert abs(system.energy(w) - z.energy(w)) > 1e-3 * abs(z.energy(w))


def test_a_damping_per_degree_decays_each_degree_at_its_rate_and_closes_its_budget():
    N, h = 10, 0.05
    rng = np.random.default_rng(6)
    alpha = rng.uniform(0, 2, N)
    system = sj.EulerZeitlin(N, alpha=alpha, nu=1e-3)
    w = _rough(N, seed=5)
    el = np.repeat(np.arange(N), 2 * np.arange(N) + 1)
    rate = 1e-3 * np.where(el > 0, el * (el + 1.0) - 2.0, 0.0) + alpha[el]
    want = z.shr2mat(np.exp(-h * rate) * np.asarray(z.mat2shr(w)), N)
    assert np.max(np.abs(system.linear_flow(w, h) - want)) < 1e-13 * np.max(np.abs(want))
    # the budget's damping rates against the coefficients' sums
    om = np.asarray(z.mat2shr(w))
    b = system.budget(w)
    np.testing.assert_allclose(b["enstrophy_damping"], np.sum(alpha[el] * om**2), rtol=1e-12)
    energy = np.sum(np.where(el > 0, alpha[el] * om**2 / np.maximum(el * (el + 1.0), 1), 0))
    np.testing.assert_allclose(b["energy_damping"], energy, rtol=1e-12)
    # and a constant alpha given per degree is the scalar alpha
    same = sj.EulerZeitlin(N, alpha=np.full(N, 0.3))
    np.testing.assert_allclose(
        same.linear_flow(w, h), sj.EulerZeitlin(N, alpha=0.3).linear_flow(w, h), atol=1e-15
    )
