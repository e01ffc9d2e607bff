"""`fit_transport_noise` against data whose transport is known: the coarse model driven by two
known transport noises, its streams given (`docs/data-driven-noise.md`)."""

import jax

jax.config.update("jax_enable_x64", True)

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
    dW = sj.brownian_increments(jax.random.key(1), K, h, n_noises=2)
    ws = np.asarray(sj.integrate(model, w0, dW, h, save_every=1, method=sj.IsospectralMidpoint()))
    drift = -np.asarray(jax.vmap(sj.EulerZeitlin(N).gradient)(ws[:-1]))
    streams = drift + np.einsum("nr,rij->nij", np.asarray(dW), xi) / h
    return dict(N=N, h=h, K=K, xi=xi, ws=ws, streams=streams)


def test_known_transport_noise_is_recovered(synthetic):
    """Span: largest principal angle below 10 degrees; each noise's variance within 15 %."""
    s = synthetic
    fit = sj.fit_transport_noise(s["ws"], dt=s["h"], N=s["N"], streams=s["streams"], n_modes=2)
    assert fit.modes.shape == (2, s["N"], s["N"]) and fit.traces.shape == (s["K"], 2)
    truth = np.asarray(z.mat2shr(s["xi"]))[:, 1:]  # (2, N^2 - 1)
    found = np.asarray(z.mat2shr(fit.modes))[:, 1:]
    q_t, _ = np.linalg.qr(truth.T)
    q_f, _ = np.linalg.qr(found.T)
    cosines = np.linalg.svd(q_t.T @ q_f, compute_uv=False)
    angle = np.degrees(np.arccos(np.clip(cosines.min(), -1, 1)))
    assert angle < 10, angle
    # the fitted noise's matrices: std / sqrt(tau) times orthonormal modes
    xi_fit = -np.asarray(fit.noise.chi)
    fitted = np.sort(np.asarray(z.enstrophy(xi_fit)))  # (1/2)|xi|^2 in L2
    known = np.sort(np.asarray(z.enstrophy(s["xi"])))
    np.testing.assert_allclose(fitted, known, rtol=0.15)
    assert fit.explained[:2].sum() > 0.95
    cumulative, acf = fit.diagnostics(max_lag=3)
    assert cumulative[-1] == pytest.approx(1.0) and np.allclose(acf[0], 1.0)
    assert np.all(np.abs(acf[1:]) < 0.1)  # white traces


def test_default_streams_and_the_variance_rule(synthetic):
    """Without streams the fine model's own transport is used (here it misses the noise, as
    vorticity alone must); `variance` picks the fewest modes; bad input is refused."""
    s = synthetic
    ws = s["ws"][:201]
    fit = sj.fit_transport_noise(ws, dt=s["h"], N=8, variance=0.5)
    assert fit.modes.shape[1:] == (8, 8)
    r = fit.modes.shape[0]
    assert (
        np.cumsum(fit.explained)[r - 1] >= 0.5 > (np.cumsum(fit.explained)[r - 2] if r > 1 else 0)
    )
    model = sj.EulerZeitlin(8, noise=fit.noise)  # ready for a coarse ensemble
    assert model.n_noises == r
    with pytest.raises(ValueError, match="K >= 2"):
        sj.fit_transport_noise(ws[:2], dt=s["h"], N=8)
    with pytest.raises(ValueError, match="must not exceed"):
        sj.fit_transport_noise(ws, dt=s["h"], N=32)
    with pytest.raises(ValueError, match="window"):
        sj.fit_transport_noise(ws, dt=s["h"], N=8, window=3)
    with pytest.raises(ValueError, match="streams"):
        sj.fit_transport_noise(ws, dt=s["h"], N=8, streams=s["streams"][:5])
    with pytest.raises(ValueError, match="dt"):
        sj.fit_transport_noise(ws, dt=-1.0, N=8)


def test_a_flow_both_resolutions_carry_exactly_misses_no_transport():
    """A Rossby–Haurwitz wave (a Y_10 + e Y_22, exact at every N) run at M = 16 and fitted at
    N = 8: the coarse model follows it, so the missed transport is the two runs' O(h^3)
    difference, not a share of the resolved stream (a stream of su(M) transports su(N) times
    hbar(M) / hbar(N))."""
    M, N, h, K = 16, 8, 0.01, 40
    om = np.zeros(M * M)
    om[z.elm2ind(1, 0)], om[z.elm2ind(2, 2)] = 0.8, 0.3
    fine = sj.EulerZeitlin(M)
    ws = sj.integrate(fine, z.shr2mat(om, M), np.zeros((K, 1)), h, save_every=1)
    fit = sj.fit_transport_noise(ws, dt=h, N=N, n_modes=1)
    stream = np.max(np.abs(np.asarray(sj.EulerZeitlin(N).gradient(z.truncate(ws[0], N)))))
    assert fit.std[0] < 1e-6 * stream * h, (fit.std[0], stream * h)  # (without: 2e-4)
