r"""A fitted closure for a coarse Euler–Zeitlin model: the tendency $R$ that a coarse system
misses, fitted jointly as a modified Hamiltonian (a degree-diagonal change of the stream), a
damping per degree, transport noise (the EOFs of the transport that explains what is left)
and additive noise (what no transport of the coarse state can produce).
`docs/data-driven-noise.md` derives it.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.optimize

from .. import zeitlin
from .._brownian import BrownianMotion, OrnsteinUhlenbeck
from .._support.checks import check_positive
from .._systems.additive_forcing import AdditiveForcing
from .._systems.euler_zeitlin import EulerZeitlin
from .._systems.noise import salt_noise
from .._systems.stream_operator import Stream
from .transport_fit import (
    _CHUNK,
    TIME_MODELS,
    TransportNoiseFit,
    _in_eigenbasis,
    _integral_time,
    check_eof_options,
    check_regularization,
    eof_noise,
    in_chunks,
    missed_tendency,
    tikhonov_parameter,
    transport_split,
)

PARTS = ("hamiltonian", "damping", "transport", "additive")
"""The parts of a closure (`fit_closure`'s `parts=`)."""


@functools.cache
def _degree_masks(N):
    """`(N - 1, N^2)`: for each degree $\\ell = 1 \\dots N - 1$, the indicator of its
    coefficients in `mat2shr`'s order."""
    degree = np.repeat(np.arange(N), 2 * np.arange(N) + 1)
    return (degree[None, :] == np.arange(1, N)[:, None]).astype(float)


@jax.jit
def _regressors(wbar, coarse):
    r"""`(k, 2(N - 1), N^2 - 1)`: each snapshot's tendencies of the closure's unit terms, in
    coefficients $\ell \ge 1$: the stream's gain on degree $\ell$, $[\bar W_\ell, \bar W +
    f]/\hbar$, then the damping of degree $\ell$, $-\bar W_\ell$ ($\ell = 1 \dots N - 1$)."""
    N = wbar.shape[-1]
    omega = zeitlin.mat2shr(wbar).astype(jnp.finfo(wbar.dtype).dtype)
    by_degree = omega[:, None, :] * jnp.asarray(_degree_masks(N), omega.dtype)
    parts = zeitlin.shr2mat(by_degree, N).astype(wbar.dtype)  # (k, N - 1, N, N)
    _, f = coarse.bracket_view()
    q = (wbar if f is None else wbar + f.astype(wbar.dtype))[:, None]
    gain = zeitlin.mat2shr((parts @ q - q @ parts) / coarse.hbar)[..., 1:]
    return jnp.concatenate([gain, -by_degree[..., 1:]], axis=1)


@jax.jit
def _normal_sums(wbar, r, weight, coarse):
    """`(X X^T, X r)` over the snapshots of weight 1 (0: a chunk's padding)."""
    x = _regressors(wbar, coarse) * weight[:, None, None]
    return jnp.einsum("kpi,kqi->pq", x, x), jnp.einsum("kpi,ki->p", x, r)


@jax.jit
def _closure_parts(wbar, coarse, coefficients):
    """The closure's tendency `(k, 2, N^2 - 1)` at each snapshot: its Hamiltonian part and
    its damping part."""
    x = _regressors(wbar, coarse)
    n = x.shape[1] // 2
    return jnp.stack(
        [
            jnp.einsum("kpi,p->ki", x[:, :n], coefficients[:n]),
            jnp.einsum("kpi,p->ki", x[:, n:], coefficients[n:]),
        ],
        axis=1,
    )


@jax.jit
def _modes_reduction(wbar, rest, modes):
    r"""For each snapshot, how much of the squared norm of `rest` the kept modes' transport
    can produce there: $\max_x(|\rho|^2 - |\rho - \sum_r x_r[e_r, \bar W]|^2) =
    c^{\mathsf T}G^{-1}c$ ($G$ the Gram matrix of the modes' tendencies, $c$ their inner
    products with $\rho$), in $\bar W$'s eigenbasis."""
    N = wbar.shape[-1]

    def one(w, rho):
        gap, rt, U = _in_eigenbasis(w, rho)
        b = -1j * gap * (jnp.conj(U).T @ modes.astype(w.dtype) @ U)  # (r, N, N)
        G = jnp.real(jnp.einsum("rij,sij->rs", jnp.conj(b), b)) / N
        c = jnp.real(jnp.einsum("rij,ij->r", jnp.conj(b), rt)) / N
        G = G + 1e-12 * jnp.trace(G) / G.shape[0] * jnp.eye(G.shape[0], dtype=G.dtype)
        return c @ jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(G), c)

    return jax.vmap(one)(wbar, rest)


@jax.jit
def _mode_tendencies(wbar, modes):
    r"""`(k, r)`: $|[e_r, \bar W_n]|^2$ ($L^2$) of each mode at each snapshot."""
    t = modes[None].astype(wbar.dtype) @ wbar[:, None] - wbar[:, None] @ modes[None]
    return zeitlin.inner(t, t)


@dataclasses.dataclass(frozen=True)
class ClosureFit:
    r"""What `fit_closure` found.

    - `system`: the closed coarse model, an `EulerZeitlin` that `simulate`,
      `forecast_ensembles` and `particle_filter` take (with `driver`), and `save` keeps: the
      coarse system with the fitted gain added to its stream (`Stream(gain=)`), the fitted
      damping to its `alpha`, the transport noise as its `noise`, and the additive noise
      in its `additive` (added in variance to the coarse system's own).
    - `scaled(factor)`: the closed system with both fitted noises times `factor`.
    - `driver`: the driver that runs `system`: `BrownianMotion()` (`time_model="white"`) or
      `OrnsteinUhlenbeck(T)`, one correlation time per noise (`"ou"`).
    - `gain`, `damping`: `(N,)`, per degree ($\ell = 0$ unused: 0), the stream's change
      $g_\ell$ and the damping rate $d_\ell \ge 0$ (per second).
    - `transport`: the transport noise's `TransportNoiseFit` (`None` without that part):
      the EOFs of the rest's transports, and their traces' statistics.
    - `transport_scale`: the factor on those traces' amplitudes in `system` (a number; a
      trained closure's, `train_closure`, one per mode `(r,)`): the fit's makes the
      noise's mean-square tendency at the data's states, $\sum_r\sigma_r^2\langle|[e_r,
      \bar W_n]|^2\rangle$, the part of the rest the modes represent (`shares`'s
      `"transport"` times $|R|^2$). The EOFs of the transports overstate it ($\mathrm{ad}_
      {\bar W}$ is ill-conditioned, and a mode acts on every state, not the one it was
      solved at): by 3.9 in mean square on su(32) → su(8) (`docs/data-driven-noise.md`).
    - `additive_std`, `additive_time`: `(N,)`, per degree, the standard deviation of each
      harmonic's off-orbit tendency (per second) and its integral time (s): the additive
      noise's intensity is $2\sigma_\ell^2T_\ell$ (white), or $\sigma_\ell$ with
      correlation time $T_\ell$ (OU). Zero without that part.
    - `shares`: each part's share of the missed tendency $R$ on the data fitted, a dict:
      `"hamiltonian"`, `"damping"` and `"closure"` (both): $1 - |R - C|^2/|R|^2$, $C$ the
      part's tendency (the predictable part; negative where it does worse than nothing);
      `"transport"`: $\sum_n\max_x(|\rho_n|^2 - |\rho_n - \sum_rx_r[e_r, \bar W_n]|^2)
      /|R|^2$, what the kept modes' transport can produce of the rest $\rho = R - C$ at
      each snapshot; `"additive"`: $|\rho_\perp|^2/|R|^2$, the rest's part that no
      transport produces. Shares of the noises say what they represent, not what they
      predict (their means, a bias, are not in the noise). `explained(states)` gives them
      all on held-out snapshots. A trained closure's are `None` (its parts were not fitted
      to $R$): `explained(states)` gives them.
    - `parts`: the parts fitted; `time_model`: the noises' (`"white"` or `"ou"`);
      `regularization`: the transport solve's Tikhonov $\alpha$;
      `fine`, `coarse`: the systems the fit compared.
    - `training`: `None` for a fit; for a closure trained by `train_closure`, the training
      loss (the mean fair CRPS) at its start and after each step.
    """

    gain: np.ndarray
    damping: np.ndarray
    transport: TransportNoiseFit | None
    transport_scale: float | np.ndarray
    additive_std: np.ndarray
    additive_time: np.ndarray
    shares: dict | None
    parts: tuple
    time_model: str
    fine: EulerZeitlin
    coarse: EulerZeitlin
    training: np.ndarray | None = None

    @property
    def regularization(self):
        """The transport solve's Tikhonov $\\alpha$ (`transport.regularization`; 0 without
        that part)."""
        return 0.0 if self.transport is None else self.transport.regularization

    @property
    def system(self):
        """The closed coarse model (an `EulerZeitlin`), the fitted amplitudes as they are."""
        return self._closed(1.0)[0]

    @property
    def driver(self):
        """The driver that runs `system`."""
        return self._closed(1.0)[1]

    def scaled(self, factor):
        r"""The closed system with both fitted noises' amplitudes times `factor` (the
        transport noise's matrices, and the fitted additive noise's $\sigma_\ell$, the
        coarse system's own forcing kept): for tuning one factor,
        `AmplitudeSearch(scale=lambda s, f: fit.scaled(f))`."""
        return self._closed(factor)[0]

    def _closed(self, factor):
        return _closed_system(
            self.coarse,
            self.gain,
            self.damping,
            self.transport,
            self.transport_scale,
            self.additive_std,
            self.additive_time,
            self.parts,
            self.time_model,
            factor,
        )

    def explained(self, states):
        r"""`shares` on other snapshots `states` `(S, M, M)` of the fine system (held-out
        data), with the fitted coefficients and modes (nothing refitted)."""
        states = _checked_states(states, self.fine.N, "ClosureFit.explained")
        coefficients = np.concatenate([self.gain[1:], self.damping[1:]])
        wbar, r = _missed(states, self.fine, self.coarse)
        closure = _closure_tendency(wbar, self.coarse, coefficients)
        rest = r - closure.sum(axis=1)
        _, off = in_chunks(lambda w, x: transport_split(w, x, self.regularization), wbar, rest)
        return _shares(self.transport, self.parts, wbar, r, closure, off)


def _checked_states(states, M, caller):
    states = np.asarray(states)
    if states.ndim != 3 or states.shape[1:] != (M, M) or not np.iscomplexobj(states):
        raise ValueError(
            f"{caller}: states must be complex (S, {M}, {M}) snapshots of the fine system, "
            f"got shape {states.shape}, dtype {states.dtype}."
        )
    if not np.all(np.isfinite(states)):
        bad = np.flatnonzero(~np.all(np.isfinite(states), axis=(1, 2)))
        raise ValueError(f"{caller}: states must be finite; snapshots {bad[:5].tolist()} are not.")
    return states


def _missed(states, fine, coarse):
    """`(wbar, R)`: each snapshot's coarse state and missed tendency (`missed_tendency`)."""
    return in_chunks(lambda w: missed_tendency(w, fine, coarse), jnp.asarray(states))


def _closure_tendency(wbar, coarse, coefficients):
    """The closure's two parts at each snapshot, `(S, 2, N^2 - 1)` (`_closure_parts`)."""
    c = jnp.asarray(coefficients)
    return in_chunks(lambda w: _closure_parts(w, coarse, c), wbar)


def _shares(transport, parts, wbar, r, closure, off):
    """`ClosureFit.shares` of the snapshots' tendencies."""
    total = float(np.sum(r * r))
    share = lambda c: 1.0 - float(np.sum((r - c) ** 2)) / total
    out = {
        "hamiltonian": share(closure[:, 0]),
        "damping": share(closure[:, 1]),
        "closure": share(closure.sum(axis=1)),
        "transport": 0.0,
        "additive": 0.0,
    }
    if transport is not None:
        rest = r - closure.sum(axis=1)
        modes = jnp.asarray(transport.modes)
        reduction = in_chunks(lambda w, x: _modes_reduction(w, x, modes), wbar, rest)
        out["transport"] = float(np.sum(reduction)) / total
    if "additive" in parts:
        out["additive"] = float(np.sum(off**2)) / total
    return out


def _closure_coefficients(wbar, r, coarse, parts):
    """The gain and damping coefficients `(2(N - 1),)` by least squares over every
    snapshot's coarse state `wbar` and missed tendency `r` (the damping's bounded below by
    0; a part not fitted is 0)."""
    n = coarse.N - 1
    active = np.r_[np.full(n, "hamiltonian" in parts), np.full(n, "damping" in parts)]
    out = np.zeros(2 * n)
    if not active.any():
        return out
    G, b, Z = np.zeros((2 * n, 2 * n)), np.zeros(2 * n), np.zeros(n + 1)
    S = wbar.shape[0]
    for start in range(0, S, _CHUNK):  # (chunks of one compiled size, the last padded)
        idx = np.minimum(np.arange(start, start + _CHUNK), S - 1)
        weight = jnp.asarray((np.arange(start, start + _CHUNK) < S) * 1.0)
        w = jnp.asarray(wbar[idx])
        g, c = _normal_sums(w, jnp.asarray(r[idx]), weight, coarse)
        G, b = G + np.asarray(g), b + np.asarray(c)
        Z += np.asarray(weight @ zeitlin.enstrophy_spectrum(w))
    diag = np.diag(G)
    for block in (slice(0, n), slice(n, 2 * n)):  # (a degree the data lack keeps 0)
        active[block] &= diag[block] > 1e-20 * max(float(np.max(diag[block])), 1e-300)
    gains = np.flatnonzero(active[:n])
    if coarse.omega is None and gains.size:  # (a stream c W moves nothing: the gain is
        # fixed by sum_l g_l Z_l = 0, at no cost in the fit)
        z_l = Z[1:][gains] / np.sum(Z[1:][gains])
        G[np.ix_(gains, gains)] += np.trace(G[np.ix_(gains, gains)]) * np.outer(z_l, z_l)
    if not active.any():
        return out
    G, b = G[np.ix_(active, active)], b[active]
    scale = np.sqrt(np.maximum(np.diag(G), 1e-300))  # (columns scaled to unit norm)
    Gs = G / np.outer(scale, scale) + 1e-12 * np.eye(len(b))
    L = scipy.linalg.cholesky(Gs, lower=True)
    lower = np.where(np.r_[np.zeros(n), np.ones(n)][active] > 0, 0.0, -np.inf)
    y = scipy.linalg.solve_triangular(L, b / scale, lower=True)
    size = max(float(np.linalg.norm(y)), 1e-300)  # (a unit right-hand side: the solver's
    # tolerances are absolute)
    solution = scipy.optimize.lsq_linear(L.T, y / size, bounds=(lower, np.inf), method="bvls")
    out[active] = solution.x * size / scale
    return out


def _per_degree(x, N):
    r"""The mean over each degree $\ell = 1 \dots N - 1$ of `x` `(N^2 - 1,)`; `(N,)`, 0 at
    $\ell = 0$."""
    return np.r_[0.0, (_degree_masks(N)[:, 1:] @ x) / (2 * np.arange(1, N) + 1)]


def _additive(off, dt, N):
    """`(std, time)` per degree of the off-orbit rest `off` `(S, N^2 - 1)`: the harmonics'
    mean variance, and their integral times weighted by their variances."""
    anomalies = off - off.mean(axis=0)
    variance = anomalies.var(axis=0, ddof=1)
    times = np.maximum(_integral_time(anomalies, dt), 0.5 * dt)
    var = _per_degree(variance, N)
    weighted = _per_degree(variance * times, N)
    return np.sqrt(var), np.divide(weighted, var, out=np.zeros(N), where=var > 0)


def fit_closure(
    states,
    *,
    dt,
    fine,
    coarse,
    parts=PARTS,
    variance=0.9,
    n_modes=None,
    time_model="white",
    regularization="l-curve",
):
    r"""A closure for the coarse Euler–Zeitlin system `coarse` from snapshots of a finer run.

    At each snapshot $W_n$ the coarse system misses the tendency
    $R_n = \mathrm{truncate}(F_M(W_n)) - F_N(\bar W_n)$ ($\bar W_n$ = `zeitlin.truncate(W_n,
    N)`, $F$ each system's deterministic tendency: bracket, rotation and linear terms,
    `EulerZeitlin.tendency`). It is fitted, in this order, as

    1. a **modified Hamiltonian** and a **damping** (`"hamiltonian"`, `"damping"`), jointly,
       by least squares over every snapshot: $R_n \approx \sum_\ell g_\ell[\bar W_{n,\ell},
       \bar W_n + f]/\hbar - \sum_\ell d_\ell\bar W_{n,\ell}$, $\bar W_\ell$ the
       degree-$\ell$ part ($\ell = 1 \dots N - 1$): a change $g_\ell$ of the stream of each
       degree (it keeps every Casimir and commutes with rotations) and a damping rate
       $d_\ell \ge 0$ per degree (a bounded least-squares solve). On a sphere at rest a
       constant gain moves nothing ($[c\bar W, \bar W] = 0$): the fit returns the gain
       with $\sum_\ell g_\ell\bar Z_\ell = 0$, $\bar Z_\ell$ the data's mean enstrophy
       of degree $\ell$ (the Hamiltonian's change has mean zero over the data). A degree
       the data lack keeps $g_\ell = d_\ell = 0$;
    2. **transport noise** (`"transport"`) on what is left, $R_n - C(\bar W_n)$: its
       Tikhonov-regularised transport $\xi_n$, $[\xi_n, \bar W_n] \approx R_n -
       C(\bar W_n)$, their EOFs, traces' standard deviations and integral times (as
       `fit_transport_noise`, one sample per snapshot);
    3. **additive noise** (`"additive"`): the part of what is left that no transport of
       $\bar W_n$ can produce (it changes the Casimirs), isotropic within each degree (each
       degree's mean variance and integral time), on every degree the missed tendency moves
       (not $\ell = 1$ on a sphere at rest, whose angular momentum both systems keep).

    The means of the noises' samples (a bias) are left out.

    **Arguments:**

    - `states`: `(S, M, M)` snapshots of `fine`, spaced `dt` seconds (at least 8).
    - `dt`: their spacing (seconds).
    - `fine`, `coarse`: `EulerZeitlin` systems, su(M) and su(N) with $N < M$: the run's
      system and the coarse one to close. Their deterministic parts are compared; give
      both the terms the coarse model keeps (linear terms, forcing, rotation). The closed
      system is `coarse` with the fitted parts added; its own transport noise is replaced
      where `"transport"` is fitted, and its own additive forcing kept.
    - `parts`: which of `PARTS` to fit (default all).
    - `variance`, `n_modes`, `time_model`, `regularization`: the transport noise's, as in
      `fit_transport_noise`; `time_model` also sets the additive noise's (white, or
      Ornstein–Uhlenbeck with each degree's correlation time).

    **Returns:** a `ClosureFit`: the closed `system` and its `driver`, the fitted parts,
    and each part's share of $R$ (`shares`; `explained(states)` on held-out snapshots).

    **References:** the missed tendency and its transport: `fit_transport_noise` (after
    Cotter, Crisan, Holm, Pan & Shevchenko 2019); `docs/data-driven-noise.md` derives the
    closure.
    """
    if not isinstance(fine, EulerZeitlin) or not isinstance(coarse, EulerZeitlin):
        raise TypeError(
            f"fit_closure: fine and coarse must be EulerZeitlin systems, got "
            f"{type(fine).__name__} and {type(coarse).__name__}."
        )
    M, N = fine.N, coarse.N
    if N >= M:
        raise ValueError(
            f"fit_closure: the coarse system's N = {N} must be below the fine one's M = {M}."
        )
    states = _checked_states(states, M, "fit_closure")
    S = states.shape[0]
    if S < 8:
        raise ValueError(
            f"fit_closure: {S} snapshots; the fit needs at least 8 (a correlation time "
            f"needs several)."
        )
    dt = float(np.asarray(check_positive("dt", dt)))
    if isinstance(parts, str) or not parts or any(p not in PARTS for p in parts):
        raise ValueError(f"fit_closure: parts must be some of {PARTS}, got {parts!r}.")
    parts = tuple(p for p in PARTS if p in parts)
    if time_model not in TIME_MODELS:
        raise ValueError(
            f"fit_closure: time_model must be one of {TIME_MODELS}, got {time_model!r}."
        )
    n_modes = check_eof_options("fit_closure", n_modes, variance, S, N, f"{S} snapshots")
    check_regularization("fit_closure", regularization)
    if time_model == "ou" and "transport" not in parts:
        raise ValueError(
            "fit_closure: time_model='ou' drives the fitted noises by OU traces; it needs the "
            "'transport' part (the coarse system's own noise has no correlation time)."
        )
    if time_model == "ou" and "additive" in parts and coarse.additive is not None:
        raise ValueError(
            "fit_closure: time_model='ou' with an additive part: the coarse system's own "
            "additive forcing would be driven by the fit's OU traces; give a coarse system "
            "without one, or time_model='white'."
        )

    wbar, r = _missed(states, fine, coarse)
    coefficients = _closure_coefficients(wbar, r, coarse, parts)
    closure = _closure_tendency(wbar, coarse, coefficients)
    rest = r - closure.sum(axis=1)
    alpha = tikhonov_parameter(wbar, rest, regularization) if "transport" in parts else 0.0
    xi, off = in_chunks(lambda w, rr: transport_split(w, rr, alpha), wbar, rest)
    transport = None
    if "transport" in parts:
        transport = eof_noise(
            xi,
            window=1,
            dt=dt,
            variance=variance,
            n_modes=n_modes,
            time_model=time_model,
            regularization=alpha,
            unexplained=float(np.sum(off**2) / max(np.sum(rest**2), 1e-300)),
        )
    shares = _shares(transport, parts, wbar, r, closure, off)
    scale = 1.0
    if transport is not None:  # (the traces' variances made to give, at the data's states,
        # the tendency the modes represent: the EOFs of xi overstate it, ad W being
        # ill-conditioned)
        modes = jnp.asarray(transport.modes)
        per_mode = np.mean(in_chunks(lambda w: _mode_tendencies(w, modes), wbar), axis=0)
        represented = shares["transport"] * float(np.sum(r * r)) / S
        scale = float(np.sqrt(represented / np.sum(transport.std**2 * per_mode)))
    std, time = _additive(off, dt, N) if "additive" in parts else (np.zeros(N), np.zeros(N))
    missed = _per_degree(np.mean(r * r, axis=0), N)  # (no noise on a degree R never moves,
    # as l = 1 on a sphere at rest: both systems keep its angular momentum)
    lacking = missed <= 1e-20 * np.max(missed)
    std, time = np.where(lacking, 0.0, std), np.where(lacking, 0.0, time)
    gain, damping = np.r_[0.0, coefficients[: N - 1]], np.r_[0.0, coefficients[N - 1 :]]
    fit = ClosureFit(
        gain=gain,
        damping=damping,
        transport=transport,
        additive_std=std,
        additive_time=time,
        shares=shares,
        transport_scale=scale,
        parts=parts,
        time_model=time_model,
        fine=fine,
        coarse=coarse,
    )
    fit._closed(1.0)  # (the closed system is built, and checked, here)
    return fit


def _closed_system(
    coarse, gain, damping, transport, transport_scale, std, time, parts, time_model, factor=1.0
):
    """The coarse system with the fitted parts added, and the driver that runs it."""
    N = coarse.N
    real = jnp.asarray(1.0).dtype  # (float64 where enabled)
    linear = coarse.linear
    own = coarse.stream_operator
    stream = own
    if "hamiltonian" in parts:
        base = np.zeros(N) if own.gain is None else np.asarray(own.gain)
        stream = Stream(gamma=own.gamma, gain=base + gain)
    alpha = 0.0 if linear is None else np.asarray(linear.damping(real))
    if "damping" in parts:
        alpha = alpha + damping
    noise = coarse.noise
    if transport is not None:  # (one factor per mode: a trained closure's are its own)
        per_mode = np.broadcast_to(np.asarray(transport_scale, float) * factor, transport.std.shape)
        noise = salt_noise(np.asarray(transport.noise.chi) * per_mode[:, None, None])
    additive = coarse.additive
    times = [] if transport is None or time_model == "white" else list(transport.correlation_time)
    if "additive" in parts:
        sigma = factor * std * (np.sqrt(2.0 * time) if time_model == "white" else 1.0)
        if additive is not None:  # (independent forcings add in variance)
            l1, l2 = additive.band
            own_sigma = np.zeros(N)
            own_sigma[l1 : l2 + 1] = np.asarray(additive.amplitude)
            sigma = np.sqrt(sigma**2 + own_sigma**2)
        forced = np.flatnonzero(sigma[1:] > 0) + 1
        if forced.size:  # (from the first degree that has any)
            l1 = int(forced[0])
            additive = AdditiveForcing((l1, N - 1), sigma[l1:])
            period = np.where(time > 0, time, 1.0)[l1:]  # (1 s where sigma is 0: unused)
            times += list(np.repeat(period, 2 * np.arange(l1, N) + 1))
    system = EulerZeitlin(
        N,
        noise=noise,
        poisson=coarse.poisson,
        nu=0.0 if linear is None else linear.nu,
        p=1 if linear is None else linear.p,
        alpha=alpha,
        forcing=None if linear is None else linear.forcing,
        omega=coarse.omega,
        stream=stream,
        additive=additive,
    )
    if time_model == "white":
        return system, BrownianMotion()
    times = np.asarray(times)
    if times.size != system.n_noises:  # (a noise of the coarse system kept: white is 0 s)
        raise ValueError(
            "fit_closure: time_model='ou' needs every noise of the closed system fitted "
            "(give parts with 'transport' and without a coarse noise of its own)."
        )
    return system, OrnsteinUhlenbeck(times)
