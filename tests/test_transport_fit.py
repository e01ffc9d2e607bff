"""`fit_transport_noise` against data whose transport is known (the coarse model driven by two
known transport noises, white or Ornstein–Uhlenbeck, its streams given), and on a fine
deterministic run: the fitted diffusivity does not depend on the window
(`docs/data-driven-noise.md`)."""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z


def _harmonic(N, el, m):
    return z.shr2mat(np.eye(N * N)[z.elm2ind(el, m)], N)


@pytest.fixture(scope="module")
def synthetic():
    """M = N = 16, xi_1 = 0.3 T_{2,1}, xi_2 = 0.15 T_{1,0} (orthogonal: the EOFs are them),
    2000 steps of h = 0.01 from a smooth state; streams -grad H_0(W_n) + sum_r xi_r dB_r / h."""
    N, h, K = 16, 0.01, 2000
    xi = np.stack([0.3 * _harmonic(N, 2, 1), 0.15 * _harmonic(N, 1, 0)])
    model = sj.EulerZeitlin(N, noise=sj.salt_noise(-xi))
    rng = np.random.default_rng(0)
    w0 = z.shr2mat(np.concatenate([[0.0], rng.normal(size=24) / 3]), N)
    dW = sj.BrownianMotion().increments(jax.random.key(1), K, h, n_noises=2)
    ws = np.asarray(sj.integrate(model, w0, dW, h, save_every=1, method=sj.IsospectralMidpoint()))
    drift = -np.asarray(jax.vmap(sj.EulerZeitlin(N).gradient)(ws[:-1]))
    streams = drift + np.einsum("nr,rij->nij", np.asarray(dW), xi) / h
    return dict(N=N, h=h, K=K, xi=xi, ws=ws, streams=streams)


def test_known_transport_noise_is_recovered(synthetic):
    """Span: largest principal angle below 10 degrees; each noise's variance within 15 %."""
    s = synthetic
    fit = sj.fit_transport_noise(s["ws"], dt=s["h"], N=s["N"], streams=s["streams"], n_modes=2)
    assert fit.modes.shape == (2, s["N"], s["N"]) and fit.traces.shape == (s["K"], 2)
    assert fit.time_model == "white" and fit.regularization is None
    truth = np.asarray(z.mat2shr(s["xi"]))[:, 1:]  # (2, N^2 - 1)
    found = np.asarray(z.mat2shr(fit.modes))[:, 1:]
    q_t, _ = np.linalg.qr(truth.T)
    q_f, _ = np.linalg.qr(found.T)
    cosines = np.linalg.svd(q_t.T @ q_f, compute_uv=False)
    angle = np.degrees(np.arccos(np.clip(cosines.min(), -1, 1)))
    assert angle < 10, angle
    # the fitted noise's matrices: std sqrt(2 T) times orthonormal modes (a white trace's
    # integral time is half a spacing: the diffusivity is the variance times dt)
    xi_fit = -np.asarray(fit.noise.chi)
    fitted = np.sort(np.asarray(z.enstrophy(xi_fit)))  # (1/2)|xi|^2 in L2
    known = np.sort(np.asarray(z.enstrophy(s["xi"])))
    np.testing.assert_allclose(fitted, known, rtol=0.15)
    assert fit.explained[:2].sum() > 0.95
    cumulative, acf = fit.diagnostics(max_lag=3)
    assert cumulative[-1] == pytest.approx(1.0) and np.allclose(acf[0], 1.0)
    assert np.all(np.abs(acf[1:]) < 0.1)  # white traces


def test_default_streams_and_the_variance_rule(synthetic):
    """Without streams the missed tendency of the truncated su(16) run is fitted at su(8);
    `variance` picks the fewest modes; bad input is refused before any work."""
    s = synthetic
    ws = s["ws"][:201]
    fit = sj.fit_transport_noise(ws, dt=s["h"], N=8, variance=0.5)
    assert fit.modes.shape[1:] == (8, 8) and fit.regularization > 0
    assert 0 <= fit.unexplained < 1
    r = fit.modes.shape[0]
    assert (
        np.cumsum(fit.explained)[r - 1] >= 0.5 > (np.cumsum(fit.explained)[r - 2] if r > 1 else 0)
    )
    model = sj.EulerZeitlin(8, noise=fit.noise)  # ready for a coarse ensemble
    assert model.n_noises == r
    bad = [
        (dict(states=ws[:3]), "at least 4"),
        (dict(N=32), "must not exceed"),
        (dict(N=16), "resolves everything"),
        (dict(window=60), "at least 4"),
        (dict(streams=s["streams"][:5]), "streams"),
        (dict(dt=-1.0), "dt"),
        (dict(time_model="red"), "time_model"),
        (dict(regularization=-1.0), "regularization"),
        (
            dict(states=np.where(np.arange(201)[:, None, None] == 7, np.nan, ws)),
            "snapshots \\[7\\]",
        ),
        (dict(n_modes=100), "n_modes"),
    ]
    for change, match in bad:
        kwargs = dict(states=ws, dt=s["h"], N=8) | change
        with pytest.raises(ValueError, match=match):
            sj.fit_transport_noise(kwargs.pop("states"), **kwargs)


def test_a_flow_both_resolutions_carry_exactly_misses_no_transport():
    """A Rossby–Haurwitz wave (a Y_10 + e Y_22, exact at every N) run at M = 16 and fitted at
    N = 8: the coarse model follows it, so the missed transport is the two runs' O(h^3)
    difference, not a share of the resolved stream (a stream of su(M) transports su(N) times
    hbar(M) / hbar(N))."""
    M, N, h, K = 16, 8, 0.01, 8
    om = np.zeros(M * M)
    om[z.elm2ind(1, 0)], om[z.elm2ind(2, 2)] = 0.8, 0.3
    fine = sj.EulerZeitlin(M)
    ws = sj.integrate(fine, z.shr2mat(om, M), np.zeros((K, 1)), h, save_every=1)
    fit = sj.fit_transport_noise(ws, dt=h, N=N, n_modes=1)
    stream = np.max(np.abs(np.asarray(sj.EulerZeitlin(N).gradient(z.truncate(ws[0], N)))))
    assert fit.std[0] < 1e-6 * stream, (fit.std[0], stream)


def test_ornstein_uhlenbeck_transport_is_recovered():
    """su(16) driven by two known orthogonal streams with unit Ornstein–Uhlenbeck traces of
    correlation time 0.5 s (`OrnsteinUhlenbeck.increments`), 1000 s at h = 0.05: the fit recovers each
    correlation time within 25 % and each variance within 15 %; over the 2e4 steps the
    Casimirs drift by less than 1e-10 of their scale (the default step, isospectral to its
    solver's tolerance in float64)."""
    N, h, K, T = 16, 0.05, 20000, 0.5
    xi = np.stack([0.3 * _harmonic(N, 2, 1), 0.15 * _harmonic(N, 1, 0)])
    model = sj.EulerZeitlin(N, noise=sj.salt_noise(-xi))
    rng = np.random.default_rng(2)
    w0 = z.shr2mat(np.concatenate([[0.0], rng.normal(size=24) / 3]), N)
    drive = sj.OrnsteinUhlenbeck([T, T]).increments(jax.random.key(3), K, h)
    ws = np.asarray(sj.integrate(model, w0, drive, h, save_every=1))
    drift = -0.5 * np.asarray(jax.vmap(sj.EulerZeitlin(N).gradient)(ws[:-1] + ws[1:]))
    streams = drift + np.einsum("nr,rij->nij", np.asarray(drive), xi) / h
    fit = sj.fit_transport_noise(ws, dt=h, N=N, streams=streams, n_modes=2, time_model="ou")
    order = np.argsort(-np.asarray(z.enstrophy(xi)))  # the EOFs come by variance
    np.testing.assert_allclose(fit.correlation_time, T, rtol=0.25)
    # the unit traces' variance, seen through the interval means (1 - h / (3 T) of it)
    variance = np.asarray(2 * z.enstrophy(xi))[order] * (1 - h / (3 * T))
    np.testing.assert_allclose(fit.std**2, variance, rtol=0.15)
    xi_fit = -np.asarray(fit.noise.chi)  # time_model="ou": sigma_r e_r
    np.testing.assert_allclose(2 * np.asarray(z.enstrophy(xi_fit)), fit.std**2, rtol=1e-12)
    c = np.asarray(model.algebra.casimirs(ws))  # tr W^k, k = 2..N, against sum |lambda|^k
    scale = np.sum(np.abs(np.linalg.eigvals(ws[0]))[:, None] ** np.arange(2, N + 1), axis=0)
    assert np.max(np.abs(c - c[0]) / scale) < 1e-10


def test_the_fitted_diffusivity_does_not_depend_on_the_window():
    """A fine deterministic run (su(32) -> su(8), 20 s at h = 0.01 from a random state of
    degrees 1..10): the sum of 2 sigma_r^2 T_r over the kept modes changes by less than 30 %
    between windows of 1, 10 and 50 steps (a window-integrated forecast error changes by
    orders of magnitude). Ensembles with the fitted noise keep every member's Casimirs to
    1e-12 over a 4 s forecast, white (`simulate`) or Ornstein–Uhlenbeck (`OrnsteinUhlenbeck.increments`)."""
    M, N, h, steps = 32, 8, 0.01, 2000
    rng = np.random.default_rng(0)
    om = np.zeros(121)
    for el in range(1, 11):
        om[el * el : (el + 1) ** 2] = rng.normal(size=2 * el + 1) / el
    ws = sj.integrate(sj.EulerZeitlin(M), z.shr2mat(om, M), np.zeros((steps, 1)), h, save_every=1)
    fits = {w: sj.fit_transport_noise(ws, dt=h, N=N, window=w) for w in (1, 10, 50)}
    rates = [fit.variance_rate.sum() for fit in fits.values()]
    assert max(rates) < 1.3 * min(rates), rates
    fit, ou = fits[1], sj.fit_transport_noise(ws, dt=h, N=N, time_model="ou")
    np.testing.assert_allclose(ou.std, fit.std, rtol=1e-12)
    w0, n, members = z.truncate(ws[-1], N), 400, 4
    white = sj.simulate(
        sj.EulerZeitlin(N, noise=fit.noise),
        w0,
        t1=n * h,
        dt=h,
        n_samples=members,
        key=jax.random.key(0),
    ).ys[:, -1]
    drive = sj.OrnsteinUhlenbeck(ou.correlation_time).increments(
        jax.random.key(1), n, h, n_samples=members
    )
    system = sj.EulerZeitlin(N, noise=ou.noise)
    red = jax.vmap(lambda d: sj.integrate(system, w0, d, h))(drive)
    scale = np.sum(np.abs(np.linalg.eigvals(w0))[:, None] ** np.arange(2, N + 1), axis=0)
    c0 = np.asarray(system.algebra.casimirs(w0))
    for final in (white, red):
        assert np.max(np.abs(np.asarray(system.algebra.casimirs(final)) - c0) / scale) < 1e-12
        assert np.max(np.abs(np.asarray(final) - np.asarray(w0))) > 1e-2  # (the noise moved them)


def test_the_transport_solve_in_the_eigenbasis_is_the_dense_least_squares():
    """`transport_split` (one eigen-decomposition of W per sample, O(N^3)) against the
    dense Tikhonov solve in the lm coefficients (the matrix of xi -> [xi, W] on the
    quantised harmonics, an SVD by NumPy): the same transport, the same off-orbit rest
    (the residual of the least-squares solve), and `_spectra`'s Tikhonov terms."""
    from slps_jax._forecasting import transport_fit as tf

    N = 6
    rng = np.random.default_rng(7)
    w = np.asarray(z.shr2mat(np.r_[0.0, rng.normal(size=(N * N - 1))], N))
    r = rng.normal(size=N * N - 1)
    basis = np.asarray(z.shr2mat(np.eye(N * N)[1:], N))
    a = np.asarray(z.mat2shr(basis @ w - w @ basis))[:, 1:].T  # column j: [T_j, w]
    u, sv, vt = np.linalg.svd(a)
    keep = sv**2 > 1e-10 * sv[0] ** 2
    assert np.sum(~keep) == N - 1  # (the kernel: the powers of w, traceless)
    for alpha in (0.0, 0.3):
        ut_r = u[:, keep].T @ r
        want = vt[keep].T @ (sv[keep] * ut_r / (sv[keep] ** 2 + alpha))
        xi, off = tf.transport_split(jnp.asarray(w)[None], jnp.asarray(r)[None], alpha)
        np.testing.assert_allclose(np.asarray(xi)[0], want, atol=1e-11)
        rest = r - u[:, keep] @ ut_r
        np.testing.assert_allclose(np.asarray(off)[0], rest, atol=1e-11)
        lam, c = (np.asarray(x) for x in tf._spectra(jnp.asarray(w)[None], jnp.asarray(r)[None]))
        reduction, norm = tf._tikhonov_terms(lam, c, alpha)
        assert reduction == pytest.approx(r @ r - np.sum((a @ want - r) ** 2), rel=1e-10)
        assert norm == pytest.approx(want @ want, rel=1e-10)
