"""Zeitlin's model on the sphere: the quantised basis, the Laplacian, fields, and the
Euler–Zeitlin system, each against an exact fact (spectra, a steady state, the exact phase
speed of a Rossby–Haurwitz wave, conservation laws, finite differences)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z


def _spin(N):
    """Spin-(N-1)/2 matrices S_x, S_y, S_z (Hermitian, [S_x, S_y] = i S_z), built here."""
    s = (N - 1) / 2
    mu = s - np.arange(N)
    sp = np.zeros((N, N))
    for i in range(1, N):  # S_+ |mu_i> = sqrt(s(s+1) - mu_i(mu_i + 1)) |mu_i + 1>
        sp[i - 1, i] = math.sqrt(s * (s + 1) - mu[i] * (mu[i] + 1))
    return (sp + sp.T) / 2, (sp - sp.T) / 2j, np.diag(mu)


def _coefficients(N, degrees, seed=0):
    rng = np.random.default_rng(seed)
    om = np.zeros(N * N)
    for el in degrees:
        for m in range(-el, el + 1):
            om[z.elm2ind(el, m)] = rng.normal()
    return om


@pytest.mark.parametrize("N", [4, 5, 8, 12])
def test_laplacian_spectrum_and_spin_casimir(N):
    E = np.eye(N * N).reshape(N * N, N, N).astype(complex)
    lap = np.stack([np.asarray(z.laplacian(e)).ravel() for e in E], 1)
    expect = np.concatenate([[-el * (el + 1)] * (2 * el + 1) for el in range(N)])
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(lap).real), np.sort(expect), atol=1e-9)
    # the same operator as -sum_a [S_a, [S_a, .]] by dense matrix products
    P = np.random.default_rng(1).normal(size=(N, N)) + 1j * np.random.default_rng(2).normal(
        size=(N, N)
    )
    ref = -sum(s @ (s @ P - P @ s) - (s @ P - P @ s) @ s for s in _spin(N))
    np.testing.assert_allclose(z.laplacian(P), ref, atol=1e-11)


@pytest.mark.parametrize("route", z.ROUTES)
@pytest.mark.parametrize("N", [5, 16, 33])
def test_solve_poisson_inverts_the_laplacian_on_traceless_matrices(N, route):
    alg = sj.su(N)
    W = jnp.stack([alg.random_state(k) for k in jax.random.split(jax.random.PRNGKey(N), 3)])
    P = z.solve_poisson(W, route=route)  # batched
    np.testing.assert_allclose(z.laplacian(P), W, atol=1e-12 * N)
    for p in P:
        alg.validate("P", np.asarray(p))


def test_poisson_routes_agree_to_round_off_at_research_size():
    """N = 256: every route solves Delta_N P = W to 1e-12 N (the residual through `laplacian`,
    an independent O(N^2) stencil) and they agree to round-off (the eigenbasis's dense
    products to 1e-12 relative: eps times the blocks' condition number, N^2 / 2, would allow
    7e-12), one state and a batch; in complex64 (tables computed in float64) to its
    precision."""
    N = 256
    W = sj.su(N).random_state(jax.random.key(0))
    P = {r: z.solve_poisson(W, route=r) for r in z.ROUTES}
    for p in P.values():
        assert float(jnp.max(jnp.abs(z.laplacian(p) - W))) < 1e-12 * N
    scale = float(jnp.max(jnp.abs(P["scan"])))
    assert float(jnp.max(jnp.abs(P["sweep"] - P["scan"]))) < 1e-13 * scale
    assert float(jnp.max(jnp.abs(P["eigenbasis"] - P["scan"]))) < 1e-12 * scale
    batch = jnp.stack([W, 2 * W])
    for r in z.ROUTES:
        np.testing.assert_allclose(z.solve_poisson(batch, route=r)[1], 2 * P[r], atol=1e-13 * scale)
    W32 = W.astype(jnp.complex64)
    for route in (*z.ROUTES, "auto"):
        p = z.solve_poisson(W32, route=route)
        assert p.dtype == jnp.complex64
        assert float(jnp.max(jnp.abs(p - P["scan"]))) < 1e-5 * scale, route
    with pytest.raises(ValueError, match="route"):
        z.solve_poisson(W, route="fft")


def test_quantised_harmonics_are_orthonormal_eigenvectors_and_invert():
    N = 6
    T = z.shr2mat(np.eye(N * N), N)  # (N^2, N, N): T_lm
    gram = z.inner(T[:, None], T[None, :])
    np.testing.assert_allclose(gram, np.eye(N * N), atol=1e-12)
    for el in range(N):
        for m in range(-el, el + 1):
            t = T[z.elm2ind(el, m)]
            np.testing.assert_allclose(z.laplacian(t), -el * (el + 1) * t, atol=1e-11)
            np.testing.assert_allclose(t, -np.conj(t).T, atol=1e-15)
    om = _coefficients(N, range(1, N), seed=3)
    np.testing.assert_allclose(z.mat2shr(z.shr2mat(om, N)), om, atol=1e-13)
    # l = 1 harmonics are spin matrices: T_10 = -i sqrt(3) hbar S_z (unit norm: the factor;
    # the sign is quflow's orientation, compared with quflow itself in benchmarks/zeitlin.py)
    np.testing.assert_allclose(
        T[z.elm2ind(1, 0)], -1j * math.sqrt(3) * z.hbar(N) * _spin(N)[2], atol=1e-13
    )


def test_fields_are_the_real_spherical_harmonics():
    theta, phi = z.grid(24, 48)
    f = z.field(np.eye(4)[1:4], theta, phi)  # l = 1: m = -1, 0, 1
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    r3 = math.sqrt(3)
    np.testing.assert_allclose(f[1], r3 * np.cos(th), atol=1e-13)
    np.testing.assert_allclose(f[2], r3 * np.sin(th) * np.cos(ph), atol=1e-13)
    np.testing.assert_allclose(f[0], -r3 * np.sin(th) * np.sin(ph), atol=1e-13)
    # mean square one and orthogonal, by Gauss-Legendre quadrature in cos(theta)
    L = 7
    x, wq = np.polynomial.legendre.leggauss(2 * L)
    phi = 2 * np.pi * np.arange(2 * L + 1) / (2 * L + 1)
    F = np.asarray(z.field(np.eye(L * L), np.arccos(x), phi)).reshape(L * L, -1)
    w = np.repeat(wq, phi.size) / (2 * (2 * L + 1))
    np.testing.assert_allclose((F * w) @ F.T, np.eye(L * L), atol=1e-12)


@pytest.fixture(scope="module")
def body():
    return sj.EulerZeitlin(8)


def test_hamiltonian_gradient_and_scales(body):
    N = body.N
    W = z.shr2mat(_coefficients(N, [1, 2, 3], seed=4), N)
    V = sj.su(N).random_state(jax.random.PRNGKey(5))
    g = body.gradient(W)
    np.testing.assert_allclose(g, -z.solve_poisson(W) / z.hbar(N), atol=1e-13)
    eps = 1e-6
    fd = (body.hamiltonian(W + eps * V) - body.hamiltonian(W - eps * V)) / (2 * eps)
    np.testing.assert_allclose(float(sj.su(N).pairing(g, V)), float(fd), rtol=1e-8)
    # H_0 = N E / (2 hbar) with quflow's energy E = -<W, P>/2 (its L2 inner product)
    np.testing.assert_allclose(body.hamiltonian(W), N * body.energy(W) / (2 * z.hbar(N)))
    assert float(body.energy(W)) > 0 and float(body.enstrophy(W)) > 0
    # the field equation in physical time: dW/dt = [P, W] / hbar
    P = body.stream(W)
    np.testing.assert_allclose(body.vector_field(W), (P @ W - W @ P) / z.hbar(N), atol=1e-12)


def test_a_single_degree_state_is_steady(body):
    N = body.N
    for el in (1, 3):
        W = z.shr2mat(_coefficients(N, [el], seed=el), N)
        assert float(jnp.max(jnp.abs(body.vector_field(W)))) < 1e-12
        np.testing.assert_allclose(sj.drift_flow(body, W, np.array([1.0]))[0], W, atol=1e-12)
        # (a step of the implicit midpoint rule is steady at a steady state too; the
        # isospectral rule's is not, to O(h^3): its midpoint has other degrees)
        sol = sj.simulate(
            body,
            W,
            t1=0.25,
            dt=2.0**-5,
            n_samples=1,
            key=jax.random.PRNGKey(0),
            method=sj.Midpoint(),
        )
        np.testing.assert_allclose(sol.ys[0, -1], W, atol=1e-12)


def test_rossby_haurwitz_wave_turns_at_its_exact_speed(body):
    """omega = a Y_10 + e Y_22: the l = 1 part is a solid-body rotation at
    alpha = a sqrt(3)/2 and the l = 2 wave travels east at 2 alpha / 3 = a / sqrt(3)
    (exact for the sphere, and for every N in Zeitlin's model)."""
    N, a, e, t = body.N, 0.8, 0.3, 1.5
    om = np.zeros(N * N)
    om[z.elm2ind(1, 0)], om[z.elm2ind(2, 2)] = a, e
    W = sj.drift_flow(body, z.shr2mat(om, N), np.array([t]))[0]
    out = np.asarray(z.mat2shr(W))
    angle = 2 * (a / math.sqrt(3)) * t  # cos 2(phi - c t) in Y_22 ~ cos 2phi, Y_2-2 ~ -sin 2phi
    np.testing.assert_allclose(
        out[[z.elm2ind(2, 2), z.elm2ind(2, -2)]],
        [e * math.cos(angle), -e * math.sin(angle)],
        atol=1e-10,
    )
    np.testing.assert_allclose(out[z.elm2ind(1, 0)], a, atol=1e-12)


def test_energy_and_casimirs_conserved_by_the_exact_flow(body):
    N = body.N
    W0 = z.shr2mat(_coefficients(N, [1, 2, 3, 4], seed=6), N) * 0.5
    Ws = sj.drift_flow(body, W0, np.array([0.5, 1.0]))
    # the flow moves the state, and keeps E and every tr W^k
    assert float(jnp.max(jnp.abs(Ws[-1] - W0))) > 1e-2
    np.testing.assert_allclose(body.energy(Ws), body.energy(W0), rtol=1e-11)
    np.testing.assert_allclose(
        body.algebra.casimirs(Ws),
        np.broadcast_to(body.algebra.casimirs(W0), (2, N - 1)),
        atol=1e-10,
    )


def test_bad_input_refused_by_name():
    for bad in (1, 4.0, True):
        with pytest.raises(ValueError, match="N >= 2"):
            sj.EulerZeitlin(bad)
    body = sj.EulerZeitlin(4)
    with pytest.raises(ValueError, match="skew-Hermitian"):
        sj.simulate(
            body,
            np.eye(4) * 1j + np.ones((4, 4)),
            t1=1.0,
            dt=0.1,
            n_samples=1,
            key=jax.random.PRNGKey(0),
            method=sj.Heun(),
        )
    with pytest.raises(TypeError, match="IsospectralMidpoint"):  # names what works
        sj.simulate(
            body,
            np.zeros((4, 4)),
            t1=1.0,
            dt=0.1,
            n_samples=1,
            key=jax.random.PRNGKey(0),
            method=sj.Strang(),
        )


def test_complex64_model_casts_its_input_and_keeps_the_casimirs_to_its_round_off():
    """`EulerZeitlin(N, dtype=complex64)` with float64 enabled: a complex128 state and float64
    increments are cast, not refused; an ensemble with transport noise and Lévy areas keeps
    tr W^2, tr W^3, tr W^4 to 10 eps_32 sqrt(steps) (measured: 3e-7 to 9e-7 over 200 steps,
    against 2e-14 in complex128), and stays within float32's accuracy of the complex128 run
    on the same paths."""
    N, steps = 16, 200
    X = 0.2 * z.shr2mat(np.eye(N * N)[[1, 2, 3]], N)
    w0 = z.shr2mat(
        np.concatenate([[0.0], np.random.default_rng(0).normal(size=24), np.zeros(N * N - 25)]), N
    )  # complex128
    kw = dict(
        t1=steps * 0.01,
        dt=0.01,
        n_samples=8,
        key=jax.random.key(1),
        save_every=20,
        method=sj.IsospectralMidpoint(),
    )
    runs = {
        dt: sj.simulate(sj.EulerZeitlin(N, noise=sj.salt_noise(X), dtype=dt), w0, **kw)
        for dt in (jnp.complex64, jnp.complex128)
    }
    assert runs[jnp.complex64].ys.dtype == jnp.complex64
    c = np.asarray(sj.su(N).casimirs(runs[jnp.complex64].ys.astype(jnp.complex128)))
    drift = np.max(np.abs(c / c[:, :1] - 1)[..., :3])
    assert drift < 10 * np.finfo(np.float32).eps * math.sqrt(steps), drift
    # the same increments (float64, cast by the complex64 model) over 50 steps
    dW, A = sj.BrownianMotion().increments(jax.random.key(2), 50, 0.01, n_noises=3, levy_area=True)
    y = {
        dt: sj.integrate(
            sj.EulerZeitlin(N, noise=sj.salt_noise(X), dtype=dt),
            w0,
            dW,
            0.01,
            areas=A,
            method=sj.IsospectralMidpoint(),
        )
        for dt in (jnp.complex64, jnp.complex128)
    }
    assert y[jnp.complex64].dtype == jnp.complex64
    gap = float(jnp.max(jnp.abs(y[jnp.complex64] - y[jnp.complex128])))
    assert gap < 1e-5 * float(jnp.max(jnp.abs(w0))), gap
    with pytest.raises(ValueError, match="complex64 or complex128"):
        sj.EulerZeitlin(N, dtype=jnp.float32)


def _observe(ys):
    # energy, the l = 1 coefficients and the Casimirs of each saved state
    return jnp.concatenate(
        [sj.zeitlin.energy(ys)[:, None], z.mat2shr(ys)[:, 1:4], sj.su(4).casimirs(ys)], axis=-1
    )


def test_ensemble_statistics_of_observables_match_the_paths():
    """Streamed moments of observables equal those of simulate's paths (the same samples);
    the isospectral rule keeps each path's Casimirs, so their variance is round-off."""
    X = 0.3 * z.shr2mat(np.eye(16)[[1, 6]], 4)
    body = sj.EulerZeitlin(4, noise=sj.salt_noise(X))
    w0 = z.shr2mat(0.5 * _coefficients(4, [1, 2, 3], seed=7), 4)
    run = dict(
        t1=0.5, dt=2.0**-5, n_samples=12, key=jax.random.key(3), method=sj.IsospectralMidpoint()
    )
    st = sj.ensemble_statistics(
        body,
        w0,
        **run,
        chunks=sj.Chunks(5, progress=False),
        statistics=sj.Statistics(observable=_observe),
    )
    sol = sj.simulate(body, w0, **run)
    ref = np.asarray(jax.vmap(_observe)(sol.ys))[:, -1]  # (samples, k) at t1
    np.testing.assert_allclose(st.mean[-1], ref.mean(0), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(st.var[-1], ref.var(0, ddof=1), rtol=1e-9, atol=1e-22)
    assert st.var[-1][0] > 1e-6  # the noise moves the energy
    assert np.all(st.var[-1][4:] < 1e-24)  # and not the Casimirs
    with pytest.raises(TypeError, match="complex"):
        sj.ensemble_statistics(body, w0, **run, chunks=sj.Chunks(5))


def _weighted_square(y, p):  # H = 1/2 sum_ij p_ij |Y_ij|^2: the same function on so(n), su(n)
    return 0.5 * jnp.sum(p * jnp.abs(y) ** 2)


def test_lie_poisson_on_the_unitary_group_equals_so_n_on_real_states():
    """Scheme (42) on U(N) (conjugate transposes, Hermitian parts) restricted to real skew
    states is scheme (42) on SO(n)."""
    n, dt = 4, 2.0**-5
    p = jnp.asarray(1.0 + np.add.outer(np.arange(n), np.arange(n)) % 3)
    a = np.random.default_rng(2).normal(size=(n, n))
    y0 = 0.6 * (a - a.T) / np.linalg.norm(a - a.T, 2)
    dW = sj.BrownianMotion().increments(jax.random.key(4), 32, dt)
    real = sj.integrate(
        sj.LiePoissonSystem(_weighted_square, p, c=0.4, algebra=sj.so(n)),
        y0,
        dW,
        dt,
        method=sj.LiePoisson(),
    )
    unitary = sj.integrate(
        sj.LiePoissonSystem(_weighted_square, p, c=0.4, algebra=sj.su(n)),
        y0,
        dW,
        dt,
        method=sj.LiePoisson(),
    )
    assert unitary.dtype == jnp.complex128
    np.testing.assert_allclose(unitary, real, atol=1e-12)
    assert float(jnp.max(jnp.abs(real - y0))) > 0.1  # (the state moved)


def test_isospectral_step_is_modin_viviani_with_the_midpoint_in_u_n():
    """One step against the scheme written out here in NumPy (quflow's form, a dense
    pseudo-inverse of the spin Laplacian): X = W + e[P, X] + e^2 P X P, P = Delta^+ X,
    W_1 = W + 2e[P, X], e = h / (2 hbar). Its midpoint X has a trace (tr X = tr(e^2 P^2 X)):
    solved on su(N) alone the step would differ by about 1e-9 here."""
    N, h = 6, 0.05
    lap = np.stack(
        [
            (-sum(s @ (s @ b - b @ s) - (s @ b - b @ s) @ s for s in _spin(N))).ravel()
            for b in np.eye(N * N).reshape(N * N, N, N)
        ],
        1,
    )
    inv = np.linalg.pinv(lap)
    w0 = np.asarray(z.shr2mat(_coefficients(N, [1, 2, 3, 4], seed=8), N))
    e = h / (2 * z.hbar(N))
    x = w0.copy()
    for _ in range(100):
        p = e * (inv @ x.ravel()).reshape(N, N)
        x = w0 + (p @ x - x @ p) + p @ x @ p
    p = e * (inv @ x.ravel()).reshape(N, N)
    ref = w0 + 2 * (p @ x - x @ p)
    assert abs(np.trace(x)) > 1e-6
    ours = sj.integrate(
        sj.EulerZeitlin(N), w0, np.zeros((1, 1)), h, method=sj.IsospectralMidpoint()
    )
    np.testing.assert_allclose(ours, ref, atol=1e-13)


def test_gradients_through_complex_states_and_retried_steps_match_finite_differences():
    """d/da of the mean energy at t1, the transport noise's amplitude a, through su(4)
    states: plain steps, and steps the solver fails at once (a budget of 8 updates) and the
    driver redoes as substeps (the retry's Jacobians, on the states' real coordinates)."""
    w0 = z.shr2mat(0.3 * np.arange(16) / 16, 4)
    e = z.shr2mat(np.eye(16)[[1, 6]], 4)

    def mean_energy(a, method):
        body = sj.EulerZeitlin(4, noise=sj.salt_noise(a * e))
        sol = sj.simulate(
            body, w0, t1=0.25, dt=2.0**-3, n_samples=4, key=jax.random.key(0), method=method
        )
        return jnp.mean(z.energy(sol.ys[:, -1])), (
            sol.stats["n_retried_steps"],
            sol.stats["n_failed"],
        )

    for method, retried in (
        (sj.IsospectralMidpoint(), False),
        (sj.IsospectralMidpoint(max_iter=8), True),
    ):
        value = lambda a: mean_energy(a, method)[0]
        n_retried, n_failed = mean_energy(0.3, method)[1]
        assert (int(n_retried) > 0) == retried and int(n_failed) == 0
        g = jax.grad(value)(0.3)
        fd = (value(0.3 + 1e-5) - value(0.3 - 1e-5)) / 2e-5
        np.testing.assert_allclose(float(g), float(fd), rtol=1e-6)


def test_conversions_of_the_low_degrees_alone_agree_with_the_full_ones():
    """`shr2mat` of L^2 coefficients and `mat2shr(W, L)` build tables of N L^2 numbers
    (selected eigenvectors of each block) and agree with the full N^3 conversion; too many
    coefficients or a bad L are refused."""
    N, L = 33, 6
    om = np.random.default_rng(5).normal(size=N * N)
    W = z.shr2mat(om, N)
    np.testing.assert_allclose(z.mat2shr(W, L=L), z.mat2shr(W)[: L * L], atol=1e-12)
    low = np.where(np.arange(N * N) < L * L, om, 0.0)
    np.testing.assert_allclose(z.shr2mat(om[: L * L], N), z.shr2mat(low, N), atol=1e-12)
    np.testing.assert_allclose(
        z.shr2mat(om[: L * L - 3], N),
        z.shr2mat(np.where(np.arange(N * N) < L * L - 3, om, 0.0), N),
        atol=1e-12,
    )
    with pytest.raises(ValueError, match="degrees"):
        z.shr2mat(np.zeros(N * N + 1), N)
    with pytest.raises(ValueError, match="L must be"):
        z.mat2shr(W, L=N + 1)


def test_final_updates_agree_at_the_root_and_the_default_follows_the_precision():
    """The explicit final update W_n + 2[A, X] and the Cayley rotation Q W_n Q^H agree to the
    solver's tolerance in complex128 (one noisy step at N = 16: sqrt(eps) of the increment
    by default, round-off with rtol = 0); the default is the Cayley rotation wherever the
    solve stops short of round-off (the default rtol, and single precision), the explicit
    update where it does not; a bad value is refused."""
    N = 16
    X = 0.2 * z.shr2mat(np.eye(N * N)[[1, 2, 3]], N)
    w0 = z.shr2mat(np.concatenate([[0.0], np.random.default_rng(3).normal(size=24)]), N)
    dW, A = sj.BrownianMotion().increments(jax.random.key(4), 3, 0.01, n_noises=3, levy_area=True)
    model = sj.EulerZeitlin(N, noise=sj.salt_noise(X))
    y = {
        f: sj.integrate(model, w0, dW, 0.01, areas=A, method=sj.IsospectralMidpoint(final_update=f))
        for f in ("explicit", "cayley", "auto")
    }
    # (the same root to rtol = sqrt(eps) of the increment: the two updates differ by about
    # that times the increment)
    assert 0 < float(jnp.max(jnp.abs(y["explicit"] - y["cayley"]))) < 1e-9
    np.testing.assert_array_equal(y["auto"], y["cayley"])
    exact = {
        f: sj.integrate(
            model,
            w0,
            dW,
            0.01,
            areas=A,
            method=sj.IsospectralMidpoint(rtol=0.0, final_update=f),
        )
        for f in ("explicit", "cayley", "auto")
    }
    # solved to round-off, the default is the explicit update, and agrees with the rotation
    np.testing.assert_array_equal(exact["auto"], exact["explicit"])
    assert float(jnp.max(jnp.abs(exact["explicit"] - exact["cayley"]))) < 1e-13
    method = sj.IsospectralMidpoint()
    system = sj.EulerZeitlin(4)
    assert method._cayley(system, jnp.complex64) and method._cayley(system, jnp.complex128)
    assert not sj.IsospectralMidpoint(rtol=0.0)._cayley(system, jnp.complex128)
    with pytest.raises(ValueError, match="final_update"):
        sj.IsospectralMidpoint(final_update="exact")


def test_truncate_keeps_the_low_degrees_between_resolutions():
    """`truncate(W, N)` is `shr2mat` of the first N^2 coefficients (M = 24 to N = 9, a batch);
    through a finer resolution and back it is the identity on su(N); upwards it pads the
    coefficients with zeros; a bad N is refused."""
    M, N = 24, 9
    om = np.random.default_rng(6).normal(size=(2, M * M))
    om[:, 0] = 0.0
    W = z.shr2mat(om, M)
    low = z.truncate(W, N)
    assert low.shape == (2, N, N)
    np.testing.assert_allclose(low, z.shr2mat(z.mat2shr(W)[:, : N * N], N), atol=1e-12)
    np.testing.assert_allclose(z.truncate(z.truncate(low, M), N), low, atol=1e-12)
    up = z.mat2shr(z.truncate(low, M))
    np.testing.assert_allclose(up[:, : N * N], om[:, : N * N], atol=1e-12)
    np.testing.assert_allclose(up[:, N * N :], 0.0, atol=1e-12)
    for p in low:
        sj.su(N).validate("W", np.asarray(p))
    with pytest.raises(ValueError, match="N must be"):
        z.truncate(W, 1)


def test_a_model_on_the_eigenbasis_route_steps_and_differentiates_as_the_default():
    """`EulerZeitlin(N, poisson="eigenbasis")` carries its table as a leaf that derivatives
    skip: its paths and its gradients through retried steps (the retry's Jacobians
    with respect to the model's leaves) equal the default route's, against finite
    differences too; a route it does not know is refused."""
    from slps_jax._systems.system import Tables, differentiable_leaves

    w0 = z.shr2mat(0.3 * np.arange(16) / 16, 4)
    e = z.shr2mat(np.eye(16)[[1, 6]], 4)

    def mean_energy(a, poisson):
        body = sj.EulerZeitlin(4, noise=sj.salt_noise(a * e), poisson=poisson)
        sol = sj.simulate(
            body,
            w0,
            t1=0.25,
            dt=2.0**-3,
            n_samples=4,
            key=jax.random.key(0),
            method=sj.IsospectralMidpoint(max_iter=8),
        )
        return jnp.mean(z.energy(sol.ys[:, -1])), sol

    body = sj.EulerZeitlin(4, noise=sj.salt_noise(e), poisson="eigenbasis")
    leaves, _, idx = differentiable_leaves(body)
    assert any(isinstance(leaf, Tables) for leaf in leaves)
    assert all(not isinstance(leaves[i], Tables) for i in idx) and idx
    (_, sol), (_, ref) = mean_energy(0.3, "eigenbasis"), mean_energy(0.3, "auto")
    assert int(sol.stats["n_retried_steps"]) > 0
    np.testing.assert_allclose(sol.ys, ref.ys, atol=1e-13)
    g = jax.grad(lambda a: mean_energy(a, "eigenbasis")[0])(0.3)
    fd = (mean_energy(0.3 + 1e-5, "auto")[0] - mean_energy(0.3 - 1e-5, "auto")[0]) / 2e-5
    np.testing.assert_allclose(float(g), float(fd), rtol=1e-6)
    with pytest.raises(ValueError, match="route"):
        sj.EulerZeitlin(4, poisson="fft")
    with pytest.raises(ValueError, match="N >= 2"):
        z.poisson_eigenbasis(1)
