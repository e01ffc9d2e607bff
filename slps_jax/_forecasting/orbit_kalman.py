r"""`ensemble_kalman_filter`: an ensemble Kalman analysis whose increments are applied as
coadjoint actions, so that every member stays on its own coadjoint orbit.

At each observation every member runs the model's forecast (the library's integrators, as in
`particle_filter`). The stochastic ensemble Kalman filter with perturbed observations
(Burgers, van Leeuwen & Evensen 1998) then gives each member a target in the algebra's
coordinates (`kalman_targets`), and each member is moved towards its target by coadjoint
actions alone (`towards_on_orbit`): $W \mapsto a W a^{-1}$, $a$ the Cayley image of $\xi$ with
$[\xi, W] \approx$ the remaining increment (Tikhonov, in $W$'s eigenbasis), a few times over
(Gauss–Newton on the orbit). A member's Casimirs therefore change only through the model's
non-conservative terms. The part of an increment that no coadjoint action produces (the part
that commutes with $W$, which would change a Casimir) is not taken: `KalmanResult.off_orbit`
says how much of the increments was left.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._brownian import AbstractDriver
from .._driver.failures import Failures
from .._support.checks import check_count, check_option, is_real
from .assimilation import (
    Observations,
    _prepare,
    _states_and_ok,
    _take,
    checked_key,
    systematic_resample,
)
from .particle_filter import _setup


@dataclasses.dataclass(frozen=True)
class KalmanAnalysis:
    r"""How `ensemble_kalman_filter` brings each observation in.

    **Arguments:**

    - `inflation`: the forecast anomalies' multiplicative inflation $\lambda \ge 1$ in the
      analysis (default 1: none): each member's target is
      $\bar x + \lambda(x_i - \bar x) + K(y + \epsilon_i - \bar h - \lambda(h_i - \bar h))$.
    - `regularization`: the Tikhonov parameter of the coadjoint solve, as a share of the
      largest squared eigenvalue gap of the member's matrix, > 0 (default 1e-3): it keeps
      the rotations small along nearly degenerate eigenvalues, where the orbit is flat.
    - `iterations`: coadjoint moves per member and observation, an integer >= 1 (default 4):
      each solves for what is left of the increment after the last.
    """

    inflation: float = 1.0
    regularization: float = 1e-3
    iterations: int = 4

    def __post_init__(self):
        if not is_real(self.inflation) or not 1.0 <= float(self.inflation) < np.inf:
            raise ValueError(
                "KalmanAnalysis: inflation must be a finite number >= 1 (the anomalies' "
                f"factor), got {self.inflation!r}."
            )
        if not is_real(self.regularization) or not 0.0 < float(self.regularization) < np.inf:
            raise ValueError(
                "KalmanAnalysis: regularization must be a finite number > 0 (a share of the "
                f"largest squared eigenvalue gap), got {self.regularization!r}."
            )
        object.__setattr__(
            self, "iterations", check_count("KalmanAnalysis: iterations", self.iterations)
        )


class KalmanResult(NamedTuple):
    """What `ensemble_kalman_filter` returns, for `n_obs` observations and `n` members.

    - `particles`: the analysis ensembles, `(n_obs, n, *state)`.
    - `mean`: their means, `(n_obs, *state)`.
    - `off_orbit`: at each observation the members' mean share of their Kalman increment
      (squared, in the algebra's coordinates) that the coadjoint moves left: the part that
      would change a Casimir, and what the regularised moves did not reach; `(n_obs,)`.
    - `replaced`: at each observation the number of members whose forecast failed,
      replaced by copies of members whose forecast succeeded (systematic resampling of
      those), `(n_obs,)`.
    """

    particles: Any
    mean: Any
    off_orbit: Any
    replaced: Any


def kalman_targets(key, x, hx, y, std, inflation=1.0):
    r"""The stochastic ensemble Kalman filter's analysis in a vector space (perturbed
    observations, Burgers, van Leeuwen & Evensen 1998): each member's target
    $\bar x + \lambda A_i + C_{xh}(C_{hh} + R)^{-1}(y + \epsilon_i - \bar h - \lambda B_i)$,
    $A$, $B$ the anomalies of the states and of their observed values, $C_{xh} =
    \lambda^2 A^{\mathsf T}B/(n-1)$, $C_{hh} = \lambda^2 B^{\mathsf T}B/(n-1)$,
    $R = \mathrm{diag}(\sigma^2)$, and $\epsilon_i \sim N(0, R)$ centred over the members
    (the analysis mean is then the Kalman update of the forecast mean).

    **Arguments:** `key`; `x`, `(n, d)` real states; `hx`, `(n, p)` their observed values;
    `y`, `(p,)` the observation; `std`, `(p,)` its errors; `inflation` $\lambda$.

    **Returns:** the targets, `(n, d)`.
    """
    n = x.shape[0]
    xm, hm = jnp.mean(x, 0), jnp.mean(hx, 0)
    a, b = inflation * (x - xm), inflation * (hx - hm)
    eps = std * jax.random.normal(key, hx.shape, hx.dtype)
    eps = eps - jnp.mean(eps, 0)
    c_hh = b.T @ b / (n - 1) + jnp.diag(std * std)
    innovation = y + eps - hm - b
    weights = jnp.linalg.solve(c_hh, innovation.T) / (n - 1)  # (p, n)
    return xm + a + ((a.T @ b) @ weights).T  # (d, p) @ (p, n): nothing of size n^2


def _skew(m):
    return 0.5 * (m - jnp.conj(m).T)


def towards_on_orbit(algebra, state, target, regularization, iterations):
    r"""`state` moved towards `target` by `iterations` coadjoint actions $W \mapsto aWa^{-1}$,
    $a = \mathrm{cay}(\xi/2) = \exp\xi + O(\xi^3)$, each $\xi$ the Tikhonov solution of
    $[\xi, W] = T - W$ (`T` the target's matrix): in $W$'s eigenbasis ($iW = U\mu U^H$) the
    map $\xi \mapsto [\xi, W]$ multiplies the entry $(i, j)$ by $-i(\mu_j - \mu_i)$, so
    $\tilde\xi_{ij} = \overline{d_{ij}}\,\tilde D_{ij}/(|d_{ij}|^2 + \alpha)$ off the kernel
    (gaps below $10^{-10}$ of the largest), $\alpha$ = `regularization` times the largest
    squared gap. $O(n^3)$ per move. Real algebras get a real $\xi$ (the real part: the
    Tikhonov solution of a real problem is real). Every move keeps the state's spectrum,
    hence its Casimirs, to rounding."""
    goal = algebra.to_matrix(target)
    for _ in range(iterations):
        m = algebra.to_matrix(state)
        mu, u = jnp.linalg.eigh(1j * m)
        gap = mu[None, :] - mu[:, None]
        lam = gap * gap
        top = jnp.max(lam)
        keep = lam > 1e-10 * top
        dt = jnp.conj(u).T @ (goal - m) @ u
        xi = jnp.where(keep, 1j * gap * dt / jnp.where(keep, lam + regularization * top, 1.0), 0)
        xi = _skew(u @ xi @ jnp.conj(u).T)
        if not jnp.iscomplexobj(m):
            xi = jnp.real(xi)
        state = algebra.act(algebra.cayley(0.5 * xi.astype(m.dtype)), state)
    return state


@functools.partial(jax.jit, static_argnames=("algebra", "observe", "iterations"))
def _analysis(algebra, observe, key, states, y, std, inflation, regularization, *, iterations):
    """One observation's analysis: the members on their orbits, and the share of the
    increments left."""
    x = algebra.coordinates(states)
    targets = kalman_targets(key, x, jax.vmap(observe)(states), y, std, inflation)
    moved = jax.vmap(lambda s, t: towards_on_orbit(algebra, s, t, regularization, iterations))(
        states, algebra.from_coordinates(targets).astype(states.dtype)
    )
    left = jnp.sum((targets - algebra.coordinates(moved)) ** 2, -1)
    wanted = jnp.sum((targets - x) ** 2, -1)
    return moved, jnp.mean(left / jnp.maximum(wanted, jnp.finfo(wanted.dtype).tiny))


def ensemble_kalman_filter(
    system,
    particles,
    observations: Observations,
    *,
    dt,
    key,
    t0=0.0,
    analysis: KalmanAnalysis = KalmanAnalysis(),
    method: Any = "auto",
    failures: Failures = Failures(),
    chunk_size: int | None = None,
    driver: AbstractDriver | None = None,
):
    r"""Assimilate observations into an ensemble of a stochastic Lie–Poisson system with an
    ensemble Kalman analysis applied as coadjoint actions: every member stays on its own
    coadjoint orbit (this module's docstring). The forecast is `particle_filter`'s (the
    library's integrators, each member with its own noise); the analysis is the stochastic
    ensemble Kalman filter's with perturbed observations (`kalman_targets`) in the
    algebra's coordinates, each member then moved towards its target by coadjoint actions
    (`towards_on_orbit`). Every member keeps equal weight: there is no resampling, and no
    evidence.

    **Arguments:**

    - `system`, `particles`, `observations`, `dt`, `key`, `t0`, `method`, `chunk_size`,
      `driver`: as for `particle_filter` (a matrix algebra: so(3), so(n), su(N)).
    - `analysis`: a `KalmanAnalysis` (inflation, the coadjoint solve's regularisation and
      its moves).
    - `failures`: a `Failures`: its `retry_substeps` as for `simulate`; a member whose
      forecast still fails is replaced by a copy of one that succeeded (`KalmanResult.
      replaced` counts them), so `throw=True` is refused.

    **Returns:** a `KalmanResult`.
    """
    name = "ensemble_kalman_filter"
    analysis = check_option(name, "analysis", analysis, KalmanAnalysis)
    setup = _setup(
        name,
        system,
        particles,
        observations,
        dt=dt,
        t0=t0,
        method=method,
        failures=failures,
        chunk_size=chunk_size,
        sharding=None,
        driver=driver,
        key=key,
    )
    key, x = setup.initial(checked_key(name, key))
    forecast = setup.forecast(system, None)
    run = _prepare(forecast, x, setup.observing(observations), None, name)
    n, (shape, variance) = setup.x.shape[0], setup.innovations
    scale = jnp.sqrt(jnp.asarray(variance, run.real))
    real = lambda v: jnp.asarray(v, run.real)
    analyses, off, replaced = [], [], []
    for k in range(run.ys.shape[0]):
        key, draw, pick, perturb = jax.random.split(key, 4)
        out = forecast(x, scale * jax.random.normal(draw, (n, *shape), run.real))
        x, ok = _states_and_ok(out, n)
        failed = 0 if ok is None else int(n - jnp.sum(ok))
        if failed == n:
            raise RuntimeError(
                f"{name}: every member's forecast to observation {k} failed; a smaller step "
                "(dt) or another method usually helps."
            )
        if ok is not None and failed:
            x = _take(x, systematic_resample(pick, jnp.where(ok, 0.0, -jnp.inf)))
        states, left = _analysis(
            system.algebra,
            observations.observe,
            perturb,
            x[0],
            run.ys[k],
            run.std,
            real(analysis.inflation),
            real(analysis.regularization),
            iterations=analysis.iterations,
        )
        x = (states, x[1])
        analyses.append(states)
        off.append(left)
        replaced.append(failed)
    particles = jnp.stack(analyses)
    return KalmanResult(
        particles, jnp.mean(particles, 1), jnp.stack(off), np.asarray(replaced, np.int64)
    )
