"""Data-driven transport noise for Euler–Zeitlin: the empirical orthogonal functions of the
transport that explains the tendency a coarse system misses (after Cotter, Crisan, Holm, Pan &
Shevchenko 2019), white or Ornstein–Uhlenbeck in time. `docs/data-driven-noise.md` derives
the estimator."""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._support.checks import check_count, check_positive, user_stacklevel
from .._systems.euler_zeitlin import EulerZeitlin
from .._systems.noise import salt_noise

TIME_MODELS = ("white", "ou")
_CHUNK = 128  # samples per compiled solve (one program for every data set of a given N)


@dataclasses.dataclass(frozen=True)
class TransportNoiseFit:
    r"""What `fit_transport_noise` found.

    - `noise`: `salt_noise(X)` for `EulerZeitlin(N, noise=fit.noise)`, $X_r = -\xi_r$:
      - `time_model="white"`: $\xi_r = e_r\,\sigma_r\sqrt{2T_r}$, driven by Brownian motions
        (`simulate`, `integrate`): its transport has the data's diffusivity
        $2\sigma_r^2T_r$ (`variance_rate`);
      - `time_model="ou"`: $\xi_r = e_r\,\sigma_r$, driven by unit-variance
        Ornstein–Uhlenbeck traces of correlation times `correlation_time`
        (`OrnsteinUhlenbeck(T).increments`).
    - `modes`: `(r, N, N)`, the kept EOFs $e_r$ as stream matrices, orthonormal for
      `zeitlin.inner`.
    - `std`: `(r,)`, $\sigma_r$: each trace's standard deviation, a transport stream per
      second (the stream whose bracket $[\sigma_r e_r, W]$ is a vorticity tendency).
    - `correlation_time`: `(r,)`, $T_r$: each trace's integral time scale
      $\int_0^\infty\rho_r(s)\,ds$ (seconds).
    - `explained`: the share of the variance of every EOF (all of them, descending).
    - `traces`: `(K, r)`, each sample's coordinate on each kept EOF (per second).
    - `window_time`: the samples' spacing, `window * dt` (seconds).
    - `time_model`: `"white"` or `"ou"`.
    - `regularization`: the Tikhonov parameter $\alpha$ of the transport solve (`None`
      with `streams=`: no solve).
    - `unexplained`: the share of the missed tendency's mean square that no transport of
      the coarse state can produce (it changes the coarse Casimirs); `None` with `streams=`.
    """

    noise: object
    modes: np.ndarray
    std: np.ndarray
    correlation_time: np.ndarray
    explained: np.ndarray
    traces: np.ndarray
    window_time: float
    time_model: str
    regularization: float | None
    unexplained: float | None

    @property
    def variance_rate(self):
        r"""`(r,)`: $2\sigma_r^2T_r$, each mode's transport diffusivity (the white-noise
        intensity whose long-time spread matches the traces'): a property of the data, not
        of `window`."""
        return 2.0 * self.std**2 * self.correlation_time

    def diagnostics(self, max_lag=10):
        """`(cumulative, autocorrelation)`: the variance explained by the first `r` EOFs for
        `r = 1, 2, ...`, and each kept trace's autocorrelation at lags `0 ... max_lag`
        (`(max_lag + 1, r)`, lags in samples of `window_time`)."""
        lags = min(max_lag, self.traces.shape[0] - 1)
        return np.cumsum(self.explained), _autocorrelation(self.traces)[: lags + 1]


def _autocorrelation(traces):
    """`(K, r)` traces' autocorrelations at lags `0 ... K - 1` (biased estimator: FFT)."""
    t = traces - traces.mean(axis=0)
    K = t.shape[0]
    f = np.fft.rfft(t, 2 * K, axis=0)
    acov = np.fft.irfft(f * np.conj(f), axis=0)[:K]
    return acov / np.where(acov[:1] > 0, acov[:1], 1.0)


def _integral_time(traces, spacing):
    r"""Each trace's integral time scale $\int_0^\infty\rho$: the trapezoidal sum of its
    autocorrelation up to the first lag where it is not positive (the sum of a white trace's
    is half a spacing: the trace is then an interval's mean, and $2\sigma^2T$ its
    diffusivity)."""
    rho = _autocorrelation(traces)
    out = []
    for j in range(rho.shape[1]):
        stop = np.flatnonzero(rho[:, j] <= 0)
        k = stop[0] if stop.size else rho.shape[0]
        out.append(spacing * (np.sum(rho[:k, j]) - 0.5))
    return np.asarray(out)


def _in_eigenbasis(w, r):
    r"""For one sample: the gaps $\mu_j - \mu_i$ of the eigenvalues of $iW$ (`(N, N)`), the
    tendency with coefficients `r` ($\ell \ge 1$) in $W$'s eigenbasis, and that basis $U$.
    In it $\xi \mapsto [\xi, W]$ multiplies the entry $(i, j)$ by $\lambda_j - \lambda_i =
    -i(\mu_j - \mu_i)$ ($W$ is normal): the map is diagonal, its kernel the matrices that
    commute with $W$, its singular values the gaps."""
    N = w.shape[-1]
    R = zeitlin.shr2mat(jnp.concatenate([jnp.zeros_like(r[:1]), r]), N).astype(w.dtype)
    mu, U = jnp.linalg.eigh(1j * w)
    return mu[None, :] - mu[:, None], jnp.conj(U).T @ R @ U, U


def _kept(lam):
    r"""The squared singular values of $\xi \mapsto [\xi, \bar W]$ off its kernel (the
    functions of $\bar W$), over the last axis."""
    return lam > 1e-10 * jnp.max(lam, axis=-1, keepdims=True)


@jax.jit
def _spectra(wbar, r):
    r"""`(lambda, c)` of each sample, `(k, N^2)`: the squared singular values of
    $\xi \mapsto [\xi, \bar W]$ in the $\ell m$ coefficients (orthonormal in $L^2$), one per
    real dimension (the entry $(i, j)$, $i < j$, for a pair's real part, $(j, i)$ for its
    imaginary part; 0 on the diagonal), and $c = V^{\mathsf T}A^{\mathsf T}r$, each
    singular value times `r`'s coordinate on its direction (for the L-curve and the
    Tikhonov terms)."""

    def one(w, rr):
        gap, rt, _ = _in_eigenbasis(w, rr)
        N = w.shape[-1]
        upper = jnp.triu(jnp.ones((N, N), bool), 1)
        part = jnp.where(upper, jnp.real(rt), jnp.imag(rt).T)
        return (gap**2).ravel(), (jnp.abs(gap) * jnp.sqrt(2.0 / N) * part).ravel()

    return jax.vmap(one)(wbar, r)


@jax.jit
def transport_split(wbar, r, alpha):
    r"""For each sample, in coefficients $\ell \ge 1$: the Tikhonov transport
    $\xi_\alpha = \arg\min|[\xi, \bar W] - r|^2 + \alpha|\xi|^2$ (zero on the kernel),
    and the part of `r` that no transport produces (its projection on the matrices that
    commute with $\bar W$). $O(N^3)$ per sample: one Hermitian eigen-decomposition of
    $\bar W$."""

    def one(w, rr):
        gap, rt, U = _in_eigenbasis(w, rr)
        lam = gap**2
        keep = _kept(lam.ravel()).reshape(lam.shape)
        d = -1j * gap  # (lambda_j - lambda_i)
        xi = jnp.where(keep, jnp.conj(d) * rt / jnp.where(keep, lam + alpha, 1.0), 0.0)
        off = jnp.where(keep, 0.0, rt)
        back = lambda x: jnp.real(zeitlin.mat2shr(U @ x @ jnp.conj(U).T))[1:]
        return back(xi), back(off)

    return jax.vmap(one)(wbar, r)


@jax.jit
def missed_tendency(w, fine, coarse):
    r"""`(W̄, R)`: the snapshots `w` `(k, M, M)` of the system `fine` truncated to the
    `coarse` one's su(N), and the tendency the coarse system misses,
    $R = \mathrm{truncate}(F_M(W)) - F_N(\bar W)$, in coefficients $\ell \ge 1$ ($F$ each
    system's deterministic tendency, `EulerZeitlin.tendency`)."""
    wbar = zeitlin.truncate(w, coarse.N)
    fine_tendency = zeitlin.truncate(jax.vmap(fine.tendency)(w), coarse.N)
    return wbar, zeitlin.mat2shr(fine_tendency - jax.vmap(coarse.tendency)(wbar))[:, 1:]


@functools.partial(jax.jit, static_argnames="N")
def _known_samples(psi, w0, w1, scale, N):
    r"""The samples of known transport streams `psi` over intervals from `w0` to `w1`: the
    truncated stream times `scale` minus the coarse drift's stream averaged over the ends."""
    coarse = EulerZeitlin(N)
    drift = -0.5 * (
        jax.vmap(coarse.gradient)(zeitlin.truncate(w0, N))
        + jax.vmap(coarse.gradient)(zeitlin.truncate(w1, N))
    )
    return zeitlin.mat2shr(scale * zeitlin.truncate(psi, N) - drift)[:, 1:]


def in_chunks(f, *arrays):
    """`f` over the leading axis of `arrays`, `_CHUNK` samples a call (the last one padded
    with copies of the last sample): one compiled program for every length."""
    n = arrays[0].shape[0]
    outs = []
    for start in range(0, n, _CHUNK):
        idx = np.minimum(np.arange(start, start + _CHUNK), n - 1)
        out, count = f(*(a[idx] for a in arrays)), min(_CHUNK, n - start)
        outs.append(jax.tree_util.tree_map(lambda x, count=count: np.asarray(x)[:count], out))
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *outs)


def _tikhonov_terms(lam, c, alpha):
    """`(residual, norm)`: the summed squared residual reduction and solution norm of the
    Tikhonov solutions at `alpha` (`residual` is what is subtracted from |r|^2)."""
    keep = np.asarray(_kept(lam))
    d = np.where(keep, lam + alpha, 1.0)
    c2 = np.where(keep, c * c, 0.0)
    reduction = np.sum(c2 * (2.0 / d - np.where(keep, lam, 0.0) / d**2))
    return reduction, np.sum(c2 / d**2)


def _l_curve(lam, c, r2):
    r"""The Tikhonov parameter at the L-curve's corner (Hansen): the point of largest
    curvature of $(\log\|A\xi_\alpha - r\|^2, \log\|\xi_\alpha\|^2)$, pooled over the
    samples, on a grid of 61 values over twelve decades below and above the typical
    $\|A\|^2$."""
    ref = float(np.median(np.max(lam, axis=-1)))
    alphas = ref * np.logspace(-10, 2, 61)
    terms = np.array([_tikhonov_terms(lam, c, a) for a in alphas])
    residual = np.maximum(r2 - terms[:, 0], 1e-300 * r2)
    x, y, t = np.log(residual), np.log(np.maximum(terms[:, 1], 1e-300)), np.log(alphas)
    dx, dy = np.gradient(x, t), np.gradient(y, t)
    ddx, ddy = np.gradient(dx, t), np.gradient(dy, t)
    curvature = (dx * ddy - ddx * dy) / np.maximum((dx * dx + dy * dy) ** 1.5, 1e-300)
    return float(alphas[1 + int(np.argmax(curvature[1:-1]))])


def tikhonov_parameter(wbar, r, regularization):
    r"""The Tikhonov $\alpha$ of the transport solve for tendencies `r` at states `wbar`:
    `regularization` itself, or for `"l-curve"` the corner of the L-curve (chosen on at
    most 512 samples spread over the data)."""
    if regularization != "l-curve":
        return float(regularization)
    pick = np.unique(np.linspace(0, len(r) - 1, min(len(r), 512)).astype(int))
    lam, c = in_chunks(_spectra, wbar[pick], r[pick])
    return _l_curve(lam, c, float(np.sum(r[pick] ** 2)))


def _missed_transport(states, N, regularization):
    r"""`(xi, alpha, unexplained)`: for each snapshot, the su(N) transport stream
    $\xi_n$ (coefficients $\ell \ge 1$) with $[\xi_n, \bar W_n] \approx R_n$, the tendency
    the coarse system misses, by Tikhonov-regularised least squares."""
    fine, coarse = EulerZeitlin(states.shape[-1]), EulerZeitlin(N)
    wbar, r = in_chunks(lambda w: missed_tendency(w, fine, coarse), jnp.asarray(states))
    r2 = float(np.sum(r * r))
    alpha = tikhonov_parameter(wbar, r, regularization)
    xi, off = in_chunks(lambda w, rr: transport_split(w, rr, alpha), wbar, r)
    floor = float(np.sum(off * off))  # (no transport does better)
    return xi, alpha, (floor / r2 if r2 > 0 else 0.0)


def check_regularization(caller, regularization):
    """Refuse a Tikhonov choice other than `"l-curve"` or a finite number >= 0."""
    ok = (
        regularization == "l-curve"
        if isinstance(regularization, str)
        else not isinstance(regularization, bool)
        and np.ndim(regularization) == 0
        and bool(np.isfinite(regularization))
        and regularization >= 0
    )
    if not ok:
        raise ValueError(
            f"{caller}: regularization must be 'l-curve' or a number >= 0, got {regularization!r}."
        )


def check_eof_options(caller, n_modes, variance, samples, N, source):
    """`n_modes` checked (at most the `samples - 1` EOFs that `source` give in su(N)), or
    else `variance` in (0, 1]; **returns** `n_modes` (an int, or `None`)."""
    if n_modes is not None:
        n_modes = check_count("n_modes", n_modes)
        if n_modes > min(samples - 1, N * N - 1):
            raise ValueError(
                f"{caller}: n_modes = {n_modes} exceeds the {min(samples - 1, N * N - 1)} "
                f"EOFs that {source} of su({N}) give."
            )
    elif isinstance(variance, bool) or not (np.ndim(variance) == 0 and 0 < variance <= 1):
        raise ValueError(f"{caller}: variance must be in (0, 1], got {variance!r}.")
    return n_modes


def fit_transport_noise(
    states,
    *,
    dt,
    N,
    window=1,
    streams=None,
    variance=0.9,
    n_modes=None,
    time_model="white",
    regularization="l-curve",
):
    r"""Transport noise for the coarse system su(N) from snapshots of a finer run.

    At each snapshot $W_n$ the coarse system misses the tendency
    $R_n = \mathrm{truncate}(F_M(W_n)) - F_N(\bar W_n)$, $\bar W_n$ = `zeitlin.truncate(W_n,
    N)`, $F$ the Euler vector fields. The transport stream $\xi_n$ of su(N) that explains
    it, $[\xi_n, \bar W_n] \approx R_n$, is found by Tikhonov-regularised least squares
    (`regularization`); the samples are averaged over windows of `window` snapshots; the
    EOFs of their anomalies (an SVD in the $\ell m$ coefficients, orthonormal in $L^2$) are
    the noise's modes, each trace's standard deviation $\sigma_r$ and integral time scale
    $T_r$ its amplitude and correlation time (`TransportNoiseFit`). No coarse run is made,
    and the fitted diffusivity $2\sigma_r^2T_r$ is a property of the data, not of `window`.

    **Arguments:**

    - `states`: `(S + 1, M, M)` vorticity snapshots of su(M), spaced `dt` in time
      (physical seconds, as `EulerZeitlin`), $M > N$ (or $M \ge N$ with `streams`).
    - `dt`: the snapshots' spacing; `N`: the coarse system's size.
    - `window`: snapshots (intervals, with `streams`) averaged into one sample (default 1);
      at least 4 windows are needed. Larger windows cost less of the SVD and estimate the
      correlation times more coarsely; the diffusivity stays the same.
    - `streams`: `(S, M', M')` transport streams $\psi$ over each interval
      ($dW = [\psi, W]\,dt$), $M' \ge N$, for data whose transport is known (a system driven
      by known noise: vorticity alone cannot reveal a noise's stream). The samples are then
      $\xi_n = \psi_n\hbar_{M'}/\hbar_N$ (truncated) minus the coarse drift's stream averaged
      over the interval's ends, with no solve.
    - `variance`: keep the fewest modes that explain this share (default 0.9); or
    - `n_modes`: keep this many.
    - `time_model`: `"white"` (default: Brownian drivers, $\xi_r = e_r\sigma_r\sqrt{2T_r}$)
      or `"ou"` ($\xi_r = e_r\sigma_r$ for unit Ornstein–Uhlenbeck drivers, `OrnsteinUhlenbeck`).
    - `regularization`: `"l-curve"` (default: the Tikhonov parameter at the L-curve's
      corner, pooled over the samples) or a number $\alpha \ge 0$ ($0$: the minimum-norm
      least-squares solution).

    Left out: the mean missed transport (a bias, not noise), the part of $R_n$ that no
    transport can produce (`unexplained`), and the non-Gaussian statistics of the traces.

    **Returns:** a `TransportNoiseFit`: the noise (`EulerZeitlin(N, noise=fit.noise)`), its
    modes, amplitudes and correlation times, and what the fit explained.

    **References:** after Cotter, Crisan, Holm, Pan & Shevchenko (2019), SIAM MMS, doi
    10.1137/18M1167929 (EOFs of the missed transport); Hansen (1992), SIAM Review 34 (the
    L-curve). `docs/data-driven-noise.md` derives the estimator.
    """
    states = np.asarray(states)
    if states.ndim != 3 or states.shape[1] != states.shape[2] or not np.iscomplexobj(states):
        raise ValueError(
            f"fit_transport_noise: states must be complex (S + 1, M, M) matrices, got "
            f"shape {states.shape}, dtype {states.dtype}."
        )
    if not np.all(np.isfinite(states)):
        bad = np.flatnonzero(~np.all(np.isfinite(states), axis=(1, 2)))
        raise ValueError(
            f"fit_transport_noise: states must be finite; snapshots {bad[:5].tolist()} are not."
        )
    M = states.shape[-1]
    N = check_count("N", N, 2)
    window = check_count("window", window)
    dt = float(np.asarray(check_positive("dt", dt)))
    if time_model not in TIME_MODELS:
        raise ValueError(
            f"fit_transport_noise: time_model must be one of {TIME_MODELS}, got {time_model!r}."
        )
    check_regularization("fit_transport_noise", regularization)
    if N > M:
        raise ValueError(f"fit_transport_noise: N = {N} must not exceed the data's M = {M}.")
    if N == M and streams is None:
        raise ValueError(
            f"fit_transport_noise: N = M = {M}: the coarse system resolves everything the data "
            f"do, so nothing is missed; give a finer run, or the transport as streams."
        )
    samples = states.shape[0] - 1 if streams is not None else states.shape[0]
    K = samples // window
    if K < 4:
        raise ValueError(
            f"fit_transport_noise: {states.shape[0]} snapshots give {K} windows of "
            f"window = {window}; the fit needs at least 4 (a correlation time needs several)."
        )
    n_modes = check_eof_options("fit_transport_noise", n_modes, variance, K, N, f"K = {K} windows")
    if streams is None:
        xi, alpha, unexplained = _missed_transport(states, N, regularization)
    else:
        xi, alpha, unexplained = _known_transport(states, streams, N), None, None
    return eof_noise(
        xi,
        window=window,
        dt=dt,
        variance=variance,
        n_modes=n_modes,
        time_model=time_model,
        regularization=alpha,
        unexplained=unexplained,
    )


def eof_noise(xi, *, window, dt, variance, n_modes, time_model, regularization, unexplained):
    r"""The `TransportNoiseFit` of transport samples `xi` `(S, N^2 - 1)` (coefficients
    $\ell \ge 1$, a stream per second, spaced `dt`): averaged over windows of `window`,
    their anomalies' EOFs (an SVD), each kept trace's standard deviation and integral time,
    and the noise they make (`fit_transport_noise`; checked arguments)."""
    K = xi.shape[0] // window
    N = math.isqrt(xi.shape[1] + 1)
    xi = xi[: K * window].reshape(K, window, -1).mean(axis=1)
    anomalies = xi - xi.mean(axis=0)
    u, s, vt = np.linalg.svd(anomalies, full_matrices=False)
    total = np.sum(s**2)
    if not total > 0:
        raise ValueError(
            "fit_transport_noise: the data miss no transport at su(N) (every sample is the "
            "same): there is no noise to fit."
        )
    explained = s**2 / total
    if n_modes is None:
        n_modes = int(np.searchsorted(np.cumsum(explained), variance - 1e-12) + 1)
    traces = u[:, :n_modes] * s[:n_modes]
    std = s[:n_modes] / math.sqrt(K - 1)
    spacing = window * dt
    correlation = _integral_time(traces, spacing)
    if np.any(correlation > 0.25 * K * spacing):
        warnings.warn(
            f"fit_transport_noise: a correlation time ({correlation.max():.3g} s) is more than "
            f"a quarter of the data's span ({K * spacing:.3g} s): it is poorly determined; "
            f"give a longer run.",
            RuntimeWarning,
            stacklevel=user_stacklevel(),
        )
    coefficients = np.concatenate([np.zeros((n_modes, 1)), vt[:n_modes]], axis=1)
    modes = np.asarray(zeitlin.shr2mat(jnp.asarray(coefficients), N))
    amplitude = std * (np.sqrt(2.0 * correlation) if time_model == "white" else 1.0)
    return TransportNoiseFit(
        noise=salt_noise(-(modes * amplitude[:, None, None])),
        modes=modes,
        std=std,
        correlation_time=correlation,
        explained=explained,
        traces=traces,
        window_time=spacing,
        time_model=time_model,
        regularization=regularization,
        unexplained=unexplained,
    )


def _known_transport(states, streams, N):
    r"""The samples of data whose transport streams are given: per interval, the truncated
    stream (times $\hbar_{M'}/\hbar_N$: the bracket scales with $\hbar$) minus the coarse
    drift's stream averaged over the interval's ends; coefficients $\ell \ge 1$."""
    psi = np.asarray(streams)
    intervals = states.shape[0] - 1
    if psi.ndim != 3 or psi.shape[0] != intervals or psi.shape[1] != psi.shape[2]:
        raise ValueError(
            f"fit_transport_noise: streams must have shape ({intervals}, M', M'), one per "
            f"interval, got {psi.shape}."
        )
    if psi.shape[-1] < N or not np.all(np.isfinite(psi)):
        raise ValueError("fit_transport_noise: streams must be finite, of size M' >= N.")
    scale = zeitlin.hbar(psi.shape[-1]) / zeitlin.hbar(N)
    return in_chunks(
        lambda p, w0, w1: _known_samples(p, w0, w1, scale, N),
        jnp.asarray(psi),
        jnp.asarray(states[:-1]),
        jnp.asarray(states[1:]),
    )
