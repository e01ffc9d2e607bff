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

With a `Localization` the analysis runs in a basis of the user's choice (the sphere's
spherical harmonics, for `EulerZeitlin`), and its covariances between a basis vector and an
observed value are tapered by their distance (the Schur-product localisation of Houtekamer &
Mitchell 2001): an observation of the large scales then moves the small ones only through
correlations the ensemble can support.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._algebra import su
from .._brownian import AbstractDriver
from .._driver.failures import Failures
from .._support.checks import check_count, check_option, is_real, real_array
from .assimilation import (
    Observations,
    _prepare,
    _states_and_ok,
    _take,
    checked_key,
    systematic_resample,
)
from .particle_filter import _setup


def _float64(name, v):
    """`v` checked as real numbers, and kept in float64 whatever JAX's default precision."""
    real_array(name, v)
    return np.asarray(v, np.float64)


@dataclasses.dataclass(frozen=True, eq=False)
class Localization:
    r"""A localisation of `ensemble_kalman_filter`'s analysis: the analysis runs in a basis,
    and its covariances are tapered by distance, $\rho(\Delta) = \exp(-\Delta^2/2L^2)$,
    $\Delta$ the distance between two positions: $C_{xh}$ entrywise by $\rho$ between each
    basis vector and each observed value, $C_{hh}$ between observed values (Houtekamer &
    Mitchell 2001). Without a taper ($L \to \infty$) the analysis is the same in every
    basis. `Localization.by_degree` builds one for `EulerZeitlin`.

    **Arguments:**

    - `positions`: each basis vector's position, `(d,)` (`d` the algebra's dimension).
    - `observed`: each observed value's position, `(p,)`.
    - `length`: the taper's length $L > 0$, in the positions' units.
    - `basis`: `(d, d)`, row $k$ the $k$-th basis vector in the algebra's coordinates
      (`algebra.coordinates`), invertible; default: the coordinates themselves.
    """

    positions: Any
    observed: Any
    length: float
    basis: Any = None

    def __post_init__(self):
        name = "Localization"
        real = lambda label, v: _float64(f"{name}: {label}", v)
        positions, observed = real("positions", self.positions), real("observed", self.observed)
        for label, v in (("positions", positions), ("observed", observed)):
            if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)):
                raise ValueError(
                    f"{name}: {label} must be a non-empty 1-d array of finite numbers, got "
                    f"shape {v.shape}."
                )
        if not is_real(self.length) or not 0.0 < float(self.length) < np.inf:
            raise ValueError(f"{name}: length must be a finite number > 0, got {self.length!r}.")
        d = positions.size
        basis = np.eye(d) if self.basis is None else real("basis", self.basis)
        if basis.shape != (d, d):
            raise ValueError(
                f"{name}: basis must be ({d}, {d}) (a row per position), got {basis.shape}."
            )
        if not np.all(np.isfinite(basis)) or np.linalg.cond(basis) > 1e12:
            raise ValueError(f"{name}: basis must be finite and invertible.")
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "observed", observed)
        object.__setattr__(self, "length", float(self.length))
        object.__setattr__(self, "basis", basis)

    @classmethod
    def by_degree(cls, N, observed, length):
        r"""A localisation by spherical-harmonic degree for `EulerZeitlin(N)` (su(N)):
        the basis the real spherical harmonics $T_{\ell m}$, $1 \le \ell < N$, each at its
        degree $\ell$ (`zeitlin.shr2mat`'s), so $\Delta = |\ell - \ell'|$.

        **Arguments:**

        - `N`: the matrix size.
        - `observed`: each observed value's degree, `(p,)`: for values
          `zeitlin.mat2shr(W)[idx]`, `floor(sqrt(idx))`.
        - `length`: the taper's length in degrees.
        """
        from .. import zeitlin

        N = check_count("Localization.by_degree: N", N, minimum=2)
        harmonics = zeitlin.shr2mat(np.eye(N * N)[1:], N)
        basis = np.asarray(su(N).coordinates(harmonics), np.float64)
        degrees = np.floor(np.sqrt(np.arange(1, N * N)))
        return cls(degrees, observed, length, basis)

    def tapers(self, dtype):
        """The analysis' arrays in `dtype`: the basis, its inverse, and the tapers of
        $C_{xh}$ `(d, p)` and $C_{hh}$ `(p, p)`."""
        rho = lambda a, b: np.exp(-0.5 * ((a[:, None] - b[None, :]) / self.length) ** 2)
        arrays = (
            self.basis,
            np.linalg.inv(self.basis),
            rho(self.positions, self.observed),
            rho(self.observed, self.observed),
        )
        return tuple(jnp.asarray(a, dtype) for a in arrays)


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
    - `localization`: a `Localization`, or `None` (default: none).
    """

    inflation: float = 1.0
    regularization: float = 1e-3
    iterations: int = 4
    localization: Localization | None = None

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
        if self.localization is not None:
            check_option("KalmanAnalysis", "localization", self.localization, Localization)


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


def kalman_targets(key, x, hx, y, std, inflation=1.0, tapers=None):
    r"""The stochastic ensemble Kalman filter's analysis in a vector space (perturbed
    observations, Burgers, van Leeuwen & Evensen 1998): each member's target
    $\bar x + \lambda A_i + C_{xh}(C_{hh} + R)^{-1}(y + \epsilon_i - \bar h - \lambda B_i)$,
    $A$, $B$ the anomalies of the states and of their observed values, $C_{xh} =
    \lambda^2 A^{\mathsf T}B/(n-1)$, $C_{hh} = \lambda^2 B^{\mathsf T}B/(n-1)$,
    $R = \mathrm{diag}(\sigma^2)$, and $\epsilon_i \sim N(0, R)$ centred over the members
    (the analysis mean is then the Kalman update of the forecast mean). With `tapers`
    $(\rho_{xh}, \rho_{hh})$, `(d, p)` and `(p, p)`, the covariances are replaced by their
    entrywise products with them.

    **Arguments:** `key`; `x`, `(n, d)` real states; `hx`, `(n, p)` their observed values;
    `y`, `(p,)` the observation; `std`, `(p,)` its errors; `inflation` $\lambda$; `tapers`.

    **Returns:** the targets, `(n, d)`.
    """
    n = x.shape[0]
    xm, hm = jnp.mean(x, 0), jnp.mean(hx, 0)
    a, b = inflation * (x - xm), inflation * (hx - hm)
    eps = std * jax.random.normal(key, hx.shape, hx.dtype)
    eps = eps - jnp.mean(eps, 0)
    rho_xh, rho_hh = (1.0, 1.0) if tapers is None else tapers
    c_hh = rho_hh * (b.T @ b) / (n - 1) + jnp.diag(std * std)
    innovation = y + eps - hm - b
    weights = jnp.linalg.solve(c_hh, innovation.T) / (n - 1)  # (p, n)
    return xm + a + ((rho_xh * (a.T @ b)) @ weights).T  # (d, p) @ (p, n): nothing n^2


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
def _analysis(
    algebra, observe, key, states, y, std, inflation, regularization, localized, *, iterations
):
    """One observation's analysis: the members on their orbits, and the share of the
    increments left. `localized`: `None`, or `Localization.tapers`."""
    x = algebra.coordinates(states)
    hx = jax.vmap(observe)(states)
    if localized is None:
        targets = kalman_targets(key, x, hx, y, std, inflation)
    else:
        basis, inverse, rho_xh, rho_hh = localized
        c = x @ inverse
        targets = kalman_targets(key, c, hx, y, std, inflation, (rho_xh, rho_hh)) @ basis
    moved = jax.vmap(lambda s, t: towards_on_orbit(algebra, s, t, regularization, iterations))(
        states, algebra.from_coordinates(targets).astype(states.dtype)
    )
    left = jnp.sum((targets - algebra.coordinates(moved)) ** 2, -1)
    wanted = jnp.sum((targets - x) ** 2, -1)
    return moved, jnp.mean(left / jnp.maximum(wanted, jnp.finfo(wanted.dtype).tiny))


def _localized(name, localization, algebra, run):
    """`localization`'s arrays for the analysis, its sizes checked against the algebra's and
    the observations'."""
    if localization is None:
        return None
    d, p = algebra.dim, run.ys.shape[-1]
    if localization.positions.size != d or localization.observed.size != p:
        raise ValueError(
            f"{name}: the localization has {localization.positions.size} positions and "
            f"{localization.observed.size} observed ones; the algebra has dimension {d} and "
            f"each observation {p} values."
        )
    return localization.tapers(run.real)


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
    localized = _localized(name, analysis.localization, system.algebra, run)
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
            localized,
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
