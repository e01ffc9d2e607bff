"""Data-driven transport noise for Euler–Zeitlin: the empirical orthogonal functions of the
transport a coarse system misses (Cotter, Crisan, Holm, Pan & Shevchenko 2019; Ephrati,
Cifani, Luesink & Geurts 2023). `docs/data-driven-noise.md` derives the estimator."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._driver.integrate import integrate
from .._methods.base import AbstractMethod
from .._methods.isospectral import IsospectralMidpoint
from .._support.checks import check_count, check_positive
from .._systems.euler_zeitlin import EulerZeitlin
from .._systems.noise import salt_noise


@dataclasses.dataclass(frozen=True)
class TransportNoiseFit:
    r"""What `fit_transport_noise` found.

    - `noise`: `salt_noise(X)` for `EulerZeitlin(N, noise=fit.noise)`, $X_r = -\xi_r$,
      $\xi_r$ the mode $r$ times `std[r]` $/\sqrt{\tau}$ ($\tau$ = `window_time`): its
      transport's variance over a window is the data's.
    - `modes`: `(r, N, N)`, the kept EOFs as stream matrices, orthonormal for
      `zeitlin.inner`.
    - `std`: `(r,)`, each kept EOF's standard deviation over the windows.
    - `explained`: the share of the variance of every EOF (all of them, descending).
    - `traces`: `(K, r)`, each window's coordinate on each kept EOF.
    - `window_time`: $\tau$ = `window * dt`.
    """

    noise: object
    modes: np.ndarray
    std: np.ndarray
    explained: np.ndarray
    traces: np.ndarray
    window_time: float

    def diagnostics(self, max_lag=10):
        """`(cumulative, autocorrelation)`: the variance explained by the first `r` EOFs for
        `r = 1, 2, ...`, and each kept trace's autocorrelation at lags `0 ... max_lag`
        (`(max_lag + 1, r)`; white-noise traces give 1 then about 0)."""
        t = self.traces - self.traces.mean(axis=0)
        lags = min(max_lag, t.shape[0] - 1)
        var = np.sum(t * t, axis=0)
        acf = np.stack([np.sum(t[: t.shape[0] - k] * t[k:], axis=0) / var for k in range(lags + 1)])
        return np.cumsum(self.explained), acf


def fit_transport_noise(
    states,
    *,
    dt,
    N,
    window=1,
    streams=None,
    variance=0.9,
    n_modes=None,
    method: AbstractMethod | None = None,
):
    r"""Transport noise for the coarse system su(N) from snapshots of a finer run.

    For each window $k$ of `window` intervals, the coarse deterministic system restarts from the
    coarse-grained snapshot (`zeitlin.truncate`); the difference between the data's transport
    stream and the coarse system's, integrated over the window (each interval's streams
    averaged over its ends), is $\Delta\Psi_k \approx \sum_r \xi_r\Delta B_{r,k}$: the
    unresolved transport. The EOFs of the $\Delta\Psi_k$ (an SVD of their anomalies in the
    $\ell m$ coefficients, orthonormal in $L^2$) keep the leading modes, each scaled by its
    standard deviation over $\sqrt\tau$, $\tau$ = `window * dt` (`TransportNoiseFit`).

    **Arguments:**

    - `states`: `(K * window + 1, M, M)` vorticity snapshots of su(M), spaced `dt` in time
      (physical seconds, as `EulerZeitlin`), $M \ge N$, $K \ge 2$.
    - `dt`: the snapshots' spacing; `N`: the coarse system's size.
    - `window`: intervals per window (default 1): the time scale at which the white noise's
      variance matches the data's. The missed transport of a smooth flow is correlated in
      time, so a noise fitted over one step is too weak at longer leads: choose a window of
      the order of the forecasts' lead (`docs/data-driven-noise.md`, "Choosing the window").
    - `streams`: `(K * window, M', M')` transport streams $\psi$ over each interval
      ($dW = [\psi, W]\,dt$, so $-\nabla H_0$: $\Delta_{M'}^{-1}W/\hbar$ for Euler–Zeitlin),
      $M' \ge N$; default: the fine system's own, $-\nabla H_0$ of the snapshots averaged over
      each interval's ends. Data whose transport is known (a system driven by known noise)
      passes it here: vorticity alone cannot reveal a noise's stream.
    - `variance`: keep the fewest modes that explain this share (default 0.9); or
    - `n_modes`: keep this many.
    - `method`: the coarse system's integrator (default `IsospectralMidpoint()`).

    Left out: the time correlation of the traces (Ephrati et al. fit Ornstein–Uhlenbeck or
    pdf-matched processes); the noise here is white in time.
    """
    states = np.asarray(states)
    if states.ndim != 3 or states.shape[1] != states.shape[2] or not np.iscomplexobj(states):
        raise ValueError(
            f"fit_transport_noise: states must be complex (K * window + 1, M, M) matrices, got "
            f"shape {states.shape}, dtype {states.dtype}."
        )
    if not np.all(np.isfinite(states)):
        raise ValueError("fit_transport_noise: states must be finite.")
    M = states.shape[-1]
    N = check_count("N", N, 2)
    window = check_count("window", window)
    if N > M:
        raise ValueError(f"fit_transport_noise: N = {N} must not exceed the data's M = {M}.")
    intervals = states.shape[0] - 1
    if intervals % window or intervals // window < 2:
        raise ValueError(
            f"fit_transport_noise: {states.shape[0]} snapshots are not K * window + 1 with "
            f"K >= 2 windows of window = {window}."
        )
    K = intervals // window
    dt = float(np.asarray(check_positive("dt", dt)))
    if n_modes is not None:
        n_modes = check_count("n_modes", n_modes)
        if n_modes > min(K, N * N - 1):
            raise ValueError(
                f"fit_transport_noise: n_modes = {n_modes} exceeds the {min(K, N * N - 1)} "
                f"EOFs that K = {K} windows of su({N}) give."
            )
    elif not 0 < variance <= 1:
        raise ValueError(f"fit_transport_noise: variance must be in (0, 1], got {variance!r}.")
    if streams is None:  # the fine system's own stream, averaged over each interval's ends
        g = -np.asarray(jax.vmap(EulerZeitlin(M).gradient)(jnp.asarray(states)))
        psi = 0.5 * (g[:-1] + g[1:])
    else:
        psi = np.asarray(streams)
        if psi.shape[0] != intervals or psi.ndim != 3 or psi.shape[1] != psi.shape[2]:
            raise ValueError(
                f"fit_transport_noise: streams must have shape ({intervals}, M', M'), one per "
                f"interval, got {psi.shape}."
            )
        if psi.shape[-1] < N or not np.all(np.isfinite(psi)):
            raise ValueError("fit_transport_noise: streams must be finite, of size M' >= N.")
    # A stream matrix of su(M') transports as [psi, W]: the same physical stream in su(N) is
    # its field truncated, times hbar(M') / hbar(N) (the bracket scales with hbar).
    scale = zeitlin.hbar(psi.shape[-1]) / zeitlin.hbar(N)
    psi = scale * np.asarray(zeitlin.truncate(jnp.asarray(psi), N))
    coarse = zeitlin.truncate(jnp.asarray(states[::window]), N)  # (K + 1, N, N)
    system = EulerZeitlin(N)
    method = IsospectralMidpoint() if method is None else method
    zero = jnp.zeros((window, 1), jnp.real(coarse).dtype)
    # (K, window + 1, N, N): each window's coarse deterministic run; a failed step raises
    paths = jax.vmap(lambda w: integrate(system, w, zero, dt, method=method, save_every=1))(
        coarse[:-1]
    )
    g = -np.asarray(jax.vmap(jax.vmap(system.gradient))(paths))
    model_psi = 0.5 * (g[:, :-1] + g[:, 1:])  # (K, window, N, N)
    delta = dt * np.sum(psi.reshape(K, window, N, N) - model_psi, axis=1)
    c = np.asarray(zeitlin.mat2shr(jnp.asarray(delta)))[:, 1:]  # (the l = 0 part is zero)
    c = c - c.mean(axis=0)
    u, s, vt = np.linalg.svd(c, full_matrices=False)
    explained = s**2 / np.sum(s**2)
    if n_modes is None:
        n_modes = int(np.searchsorted(np.cumsum(explained), variance - 1e-12) + 1)
    std = s[:n_modes] / math.sqrt(K - 1)
    tau = window * dt
    coefficients = np.concatenate([np.zeros((n_modes, 1)), vt[:n_modes]], axis=1)
    modes = np.asarray(zeitlin.shr2mat(jnp.asarray(coefficients), N))
    xi = modes * (std / math.sqrt(tau))[:, None, None]
    return TransportNoiseFit(
        noise=salt_noise(-xi),
        modes=modes,
        std=std,
        explained=explained,
        traces=u[:, :n_modes] * s[:n_modes],
        window_time=tau,
    )
