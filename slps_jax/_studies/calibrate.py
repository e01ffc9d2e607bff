"""Fit the inertia and the noise (`c`, or a noise family's parameters) to observed ensemble
statistics, with pathwise gradients."""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import _brownian
from .._driver.failures import Failures, check_failures, message
from .._driver.integrate import run_ensemble
from .._driver.plan import (
    check_driver,
    check_levy_option,
    check_method,
    plan_ensemble,
)
from .._methods.base import AbstractMethod
from .._support.checks import check_count, check_option, steps_on_grid
from .._systems.noise import _AbstractParameterNoise
from .._systems.rigid_body import RigidBody


def moments(ys):
    """Default statistic of `calibrate`: the mean of `y` and of `y**2` over the ensemble.

    **Arguments:**

    - `ys`: `(n_samples, 3)`, the ensemble's states at one time (the sample axis first).

    **Returns:** shape `(6,)`: the three means of $y_j$, then the three means of $y_j^2$.
    """
    return jnp.concatenate([jnp.mean(ys, axis=0), jnp.mean(ys**2, axis=0)])


@dataclasses.dataclass(frozen=True, eq=False)
class ObservedStatistics:
    r"""What `calibrate` fits to: statistics of an observed ensemble at a few times.

    **Arguments:**

    - `values`: `(len(times), k)`, the statistics to match.
    - `times`: increasing positive observation times, multiples of the step.
    - `statistic`: `(n_samples, 3) -> (k,)`, how the simulated ensemble's statistics are
      computed from its states at each time; default `moments` (means of `y` and `y**2`).
    - `stderr`: standard errors of `values` (same shape), used as weights and for the
      standard errors of the fit; `None` (default): weights 1, and no standard errors.
    - `n_samples`: the size of the observed ensemble, if known: the standard errors then
      include the sampling error of the simulated statistics too (a factor
      $\sqrt{1 + n_{obs}/n_{samples}}$, the system's statistics having the observed ones'
      variance).
    """

    values: Any
    times: Any
    statistic: Callable[..., Any] = moments
    stderr: Any = None
    n_samples: int | None = None


@dataclasses.dataclass(frozen=True)
class Optimisation:
    """How `calibrate` minimises its loss.

    **Arguments:**

    - `optimizer`: `None` (default) for Levenberg-Marquardt on the weighted residuals: the
      loss is a deterministic, smooth sum of squares, and each step evaluates the residuals
      and their Jacobian (forward mode) with the one compiled program that also checks the
      identifiability at `init` and gives the standard errors, so the fit compiles nothing
      more (and a later fit with the same settings and shapes, other data or another start,
      nothing at all). Or an optax optimiser, minimising the loss with its reverse-mode
      gradient in a compiled step of its own (a line search, as in `optax.lbfgs()`, holds
      the simulation in that step once per place it evaluates the loss); optimisers that
      need the loss value get it.
    - `steps`: at most this many optimiser steps (default 50); stops earlier when the loss
      changes by less than `rtol` relative (default 1e-10).
    - `progress`: print the loss and parameters as it goes (to stderr; default `True`).
    """

    optimizer: Any = None
    steps: int = 50
    rtol: float = 1e-10
    progress: bool = True

    def __post_init__(self):
        object.__setattr__(self, "steps", check_count("Optimisation: steps", self.steps))
        if isinstance(self.rtol, bool) or not (
            isinstance(self.rtol, (int, float)) and self.rtol >= 0
        ):
            raise ValueError(f"Optimisation: rtol must be a number >= 0, got {self.rtol!r}.")
        if not isinstance(self.progress, (bool, np.bool_)):
            raise TypeError(f"Optimisation: progress must be True or False, got {self.progress!r}.")


@dataclasses.dataclass(frozen=True)
class CalibrationResult:
    """What `calibrate` returns.

    - `system`: the fitted `RigidBody`.
    - `loss`: the loss at `init` (`loss[0]`) and at each accepted iterate (`loss[-1]` at the
      fitted parameters).
    - `names`: the parameters, in order: `I_1, I_2, I_3`, then `c`, or the entries of the
      noise family's parameter (`chi[r,j]` for `salt_noise`, `sigma[r,j]` for
      `random_inertia_noise`).
    - `stderr`: delta-method standard errors of the parameters in `names` from the Jacobian of
      the statistics at the fit and the observed `stderr` (`None` if that was not given; 0 for
      the fixed parameters); with the observed ensemble's `n_samples` they include the simulation's own
      sampling error. They treat the statistics as independent: statistics of the same
      paths at several times are correlated, so these can be optimistic (compare the
      spread of fits to independent data sets).
    - `singular_values`: of the weighted Jacobian of the statistics with respect to the
      free parameters (`log I`, `log c`, the noise parameters as they are) at the start;
      their spread says how well the data determine the parameters.
    """

    system: RigidBody
    loss: np.ndarray
    stderr: np.ndarray | None
    singular_values: np.ndarray
    names: tuple = ("I_1", "I_2", "I_3", "c")


@dataclasses.dataclass(frozen=True)
class _Parameters:
    """The parameters of a `RigidBody` as one vector `theta`: `log I`, then `log c` or the
    noise family's parameter array raveled (on its own scale: its entries may have either
    sign)."""

    names: tuple
    theta: jax.Array
    log: np.ndarray  # which entries are logarithms
    family: type | None  # the noise family's type (None: one noise, c)
    shape: tuple  # the shape of its parameter

    @classmethod
    def of(cls, init):
        inertia = [f"I_{i + 1}" for i in range(3)]
        if init.c is not None:  # (one noise proportional to the drift)
            return cls(
                (*inertia, "c"),
                jnp.concatenate([jnp.log(init.inertia), jnp.log(init.c)[None]]),
                np.ones(4, bool),
                None,
                (),
            )
        param, name = init.noise.parameter, init.noise.parameter_name
        entries = [f"{name}[{', '.join(map(str, i))}]" for i in np.ndindex(param.shape)]
        return cls(
            (*inertia, *entries),
            jnp.concatenate([jnp.log(init.inertia), jnp.ravel(param)]),
            np.arange(3 + len(entries)) < 3,
            type(init.noise),
            tuple(param.shape),
        )

    def system(self, theta):
        return _system_at(theta, self.family, self.shape)

    def values(self, theta):
        """The parameters themselves (not their logarithms), as a NumPy array."""
        theta = np.asarray(theta)
        return np.where(self.log, np.exp(theta), theta)

    def describe(self, theta):
        return ", ".join(f"{n} {v:.6g}" for n, v in zip(self.names, self.values(theta)))


def _system_at(theta, family, shape):
    """The `RigidBody` at `theta` (`log I`, then `log c` or the family's parameter)."""
    inertia = jnp.exp(theta[:3])
    if family is None:
        return RigidBody(inertia, jnp.exp(theta[3]))
    return RigidBody(inertia, noise=family(theta[3:].reshape(shape)))


@dataclasses.dataclass(frozen=True)
class _Fit:
    """What the residuals depend on besides their array arguments; hashable, so that fits
    with the same settings and shapes share one compiled program."""

    family: type | None
    shape: tuple
    free: tuple  # the indices of the fitted entries of theta
    y0: Any  # (nested tuples of floats)
    t1: float
    dt: float
    n_samples: int
    every: int
    saved: tuple  # the indices of the observation times among the saved states
    method: object
    driver: object  # a BrownianMotion, its Lévy-area option resolved for the method
    failures: Failures
    statistic: Callable[..., Any]

    def full(self, theta, theta_all):
        """All the parameters: `theta_all` with the free ones set to `theta`."""
        return theta_all.at[np.asarray(self.free)].set(theta)

    def residuals(self, theta, theta_all, observed, weight, key):
        """The weighted residuals of the statistics at the free parameters `theta`, and (aux)
        the number of failed samples (raised by `calibrate`, with its own advice)."""
        system = _system_at(self.full(theta, theta_all), self.family, self.shape)
        p = plan_ensemble(
            "simulate",
            system,
            self.y0,
            t1=self.t1,
            dt=self.dt,
            n_samples=self.n_samples,
            key=key,
            method=self.method,
            save_every=self.every,
            failures=self.failures,
            sharding=None,
            driver=self.driver,
        )
        sol = run_ensemble(p, newton_stats=False, saved=True)
        stats = jax.vmap(self.statistic, in_axes=1)(sol.ys[:, np.asarray(self.saved)])
        return ((stats - observed) * weight).ravel(), jnp.sum(sol.fail_step >= 0)


@functools.partial(jax.jit, static_argnums=0)
def _residuals_and_jacobian(fit, theta, theta_all, observed, weight, key):
    """`(J, (r, n_failed))`: the residuals' Jacobian (forward mode), the residuals and the
    number of failed samples, in one program (compiled once for a fit's settings and shapes,
    where eagerly its operations would compile one by one)."""

    def residuals_aux(theta):
        r, n_failed = fit.residuals(theta, theta_all, observed, weight, key)
        return r, (r, n_failed)

    return jax.jacfwd(residuals_aux, has_aux=True)(theta)


def calibrate(
    observed: ObservedStatistics,
    y0,
    *,
    dt,
    n_samples,
    key,
    init,
    fixed=(),
    method: AbstractMethod | str = "auto",
    optimisation: Optimisation = Optimisation(),
    failures: Failures = Failures(),
    driver: _brownian.BrownianMotion | None = None,
):
    r"""Fit `inertia` and the noise (`c`, or a noise family's parameters) of a `RigidBody` to
    observed ensemble statistics.

    Minimises the weighted least-squares misfit
    $L(\theta) = \tfrac12 \sum_{k} |(S_k(\theta) - S^{obs}_k)/\sigma_k|^2$, where
    $S_k(\theta)$ = `observed.statistic` of the simulated ensemble at time `observed.times[k]`
    and $\sigma$ = `observed.stderr` (1 if not given), over $\theta = (\log I_1, \log I_2, \log I_3, \log c)$:
    the parameters stay positive ($c$ and $-c$ give the same law, so only $|c|$ can be
    fitted). For a `RigidBody` with a noise family (`noise=salt_noise(chi)`,
    `random_inertia_noise(sigma)`) $\theta$ is $\log I$ and the family's parameter array as
    it is. Flipping the sign of one noise's row, or mixing the rows by an orthogonal matrix,
    leaves the law unchanged: with several noises, fix all but the entries you can identify.
    The ensemble is simulated with the same `key` at every iteration (common random
    numbers), so $L$ is a smooth deterministic function whose derivatives JAX computes
    exactly (pathwise, through the implicit Newton solves); its minimiser estimates the
    parameters, with a bias of order $1/$`n_samples`.

    Before optimising, the Jacobian of the weighted statistics with respect to the fitted
    parameters is computed at `init`; if it is (nearly) rank deficient, a `ValueError` says
    which combination the statistics do not determine. One such combination is exact for
    the rigid body: adding the same constant to every $1/I_i$ adds a multiple of the Casimir
    to $H$ and leaves the motion unchanged, so the three moments can only be fitted with
    one of them held fixed (`fixed=("I_3",)`).

    **Arguments:**

    - `observed`: an `ObservedStatistics`: the statistics to match, their times (multiples
      of `dt`), how they are computed from an ensemble, their standard errors.
    - `y0`: the initial value.
    - `dt`, `n_samples`, `key`, `method`: as in `simulate`.
    - `failures`: a `Failures`: failing steps are redone as substeps
      (`retry_substeps`); a sample that still fails stops the fit with a `RuntimeError`
      whatever `throw` says (the fit's common random numbers cannot leave it out).
    - `driver`: `None` or `sj.BrownianMotion(...)`, as in `simulate` (its truncation and
      Lévy areas).
    - `init`: a `RigidBody` (with `c=` or with a noise family), the starting guess.
    - `fixed`: names among `"I_1", "I_2", "I_3", "c"` (or the noise family's entries, such
      as `"chi[0, 1]"`; `CalibrationResult.names` lists them) held at their values in `init`.
    - `optimisation`: an `Optimisation`: Levenberg-Marquardt (default) or an optax
      optimiser, the most steps, the tolerance, the progress printout.

    **Returns:** a `CalibrationResult`.

    **Raises:** `RuntimeError` if any sample's Newton solve fails at a point the fit evaluates
    (`init`, each accepted iterate, the fitted parameters): a failed sample is frozen at its
    last good state by `simulate`, and such states are never used as data, so the fit
    refuses rather than leaving the sample out (which would bias the statistics towards the
    samples that survive). The message says how many samples failed and where; a smaller
    `dt`, a method without Newton solves such as `Strang()`, or parameters / `y0` away from
    the failing region avoid it.
    """
    if not isinstance(init, RigidBody):
        raise TypeError(f"init must be a RigidBody, got {type(init).__name__}.")
    if init.c is not None and not float(np.asarray(init.c)) > 0:
        raise ValueError(f"init.c must be positive (c is fitted on a log scale), got {init.c}.")
    if init.c is None and not isinstance(init.noise, _AbstractParameterNoise):
        raise TypeError(
            "calibrate fits the parameters of a noise family (salt_noise, "
            "random_inertia_noise); a noise given as a function has none."
        )
    check_option("calibrate", "observed", observed, ObservedStatistics)
    check_option("calibrate", "optimisation", optimisation, Optimisation)
    failures = check_failures("calibrate", failures)
    statistic, observed_stderr = observed.statistic, observed.stderr
    observed_n_samples, ts = observed.n_samples, observed.times
    optimizer, steps, rtol = optimisation.optimizer, optimisation.steps, optimisation.rtol
    progress = optimisation.progress
    values = observed.values
    params = _Parameters.of(init)
    all_names = params.names
    ts = np.asarray(ts, float)
    if ts.ndim != 1 or len(ts) < 1 or not np.all(np.diff(ts) > 0) or ts[0] <= 0:
        raise ValueError(
            f"calibrate: the observed times must be increasing and positive, got {ts}."
        )
    idx, on_grid = steps_on_grid(ts, dt)
    if not np.all(on_grid):
        raise ValueError(f"calibrate: the observed times must be multiples of dt={dt}, got {ts}.")
    every = math.gcd(*idx.tolist())
    values = jnp.asarray(values)
    if values.ndim != 2 or values.shape[0] != len(ts):
        raise ValueError(
            f"calibrate: the observed values must have shape (len(times), k) = ({len(ts)}, k), "
            f"got {values.shape}."
        )
    weight = (
        jnp.ones_like(values)
        if observed_stderr is None
        else 1.0 / jnp.asarray(observed_stderr, values.dtype)
    )
    if weight.shape != values.shape or not bool(jnp.all(jnp.isfinite(weight) & (weight > 0))):
        raise ValueError(
            "calibrate: the observed stderr must be positive and have the shape of the values."
        )
    key = _brownian.check_key(key)
    unknown = [n for n in fixed if n not in all_names]
    if unknown or len(set(fixed)) == len(all_names):
        raise ValueError(f"fixed must name some (not all) of {all_names}, got {fixed!r}.")
    free = np.array([n not in fixed for n in all_names])
    names = [n for n in all_names if n not in fixed]
    theta_all = params.theta
    method = check_method(method, init)
    brownian = check_driver(driver)
    if brownian.carries_state:
        raise TypeError(
            f"calibrate: driver must be None or sj.BrownianMotion(...), got {driver!r}."
        )
    fit = _Fit(
        params.family,
        params.shape,
        tuple(np.flatnonzero(free).tolist()),
        _as_tuple(y0),
        float(ts[-1]),
        dt,
        n_samples,
        every,
        tuple((idx // every).tolist()),
        method,
        _brownian.BrownianMotion(
            truncate_k=cast(_brownian.BrownianMotion, brownian).truncate_k,
            levy_area=check_levy_option(brownian.levy_area, method, init),
        ),
        failures,
        statistic,
    )

    def full(theta):
        return fit.full(theta, theta_all)

    def residuals(theta):
        return fit.residuals(theta, theta_all, values, weight, key)

    def jacobian(theta):
        return _residuals_and_jacobian(fit, theta, theta_all, values, weight, key)

    def check(n_failed, theta, where):
        n_failed = int(n_failed)
        if n_failed > 0:
            raise RuntimeError(
                message(
                    "calibrate",
                    n_failed,
                    n_samples,
                    f"The fit stops {where}, at {params.describe(full(theta))}: failed samples "
                    f"are frozen at their last good state and never used as data; an init or "
                    f"y0 away from the failing region may help too.",
                    retried=failures.retried,
                )
            )

    theta = theta_all[free]
    # One program for the residuals and their Jacobian: at init (the identifiability check),
    # at every Levenberg-Marquardt trial point, and at the fitted parameters (the standard
    # errors).
    jac, (r, n_failed) = jacobian(theta)
    check(n_failed, theta, "at init")
    sv = _check_identifiable(jac, names, np.asarray(init.inertia))

    def report(i, theta, value):
        if progress:
            print(
                f"calibrate: step {i + 1:3d}  loss {value:.6e}  {params.describe(full(theta))}",
                file=sys.stderr,
            )

    if optimizer is None:
        dtype = theta.dtype
        theta, history, jac = _levenberg_marquardt(
            lambda t: jacobian(jnp.asarray(t, dtype)),
            theta,
            jac,
            r,
            steps=steps,
            rtol=rtol,
            eps=float(jnp.finfo(dtype).eps),
            accept=lambda n, t, i: check(n, t, f"after optimiser step {i}"),
            report=report,
        )
        theta = jnp.asarray(theta, dtype)
    else:
        theta, history, jac = _optax_fit(
            optimizer,
            residuals,
            jacobian,
            theta,
            steps=steps,
            rtol=rtol,
            check=check,
            report=report,
        )

    system = params.system(full(theta))
    stderr = None
    if observed_stderr is not None:
        # Delta method: Cov(theta) = (J^T J)^{-1} with the weighted Jacobian; then the chain
        # rule d exp(theta) = exp(theta) d theta for the logarithms.
        jac = np.asarray(jac)
        cov = np.linalg.pinv(jac.T @ jac)
        stderr = np.zeros(len(all_names))
        scale = np.where(params.log[free], np.exp(np.asarray(theta)), 1.0)
        stderr[free] = np.sqrt(np.diag(cov)) * scale
        if observed_n_samples is not None:
            stderr *= math.sqrt(1.0 + observed_n_samples / n_samples)
    return CalibrationResult(system, np.asarray(history), stderr, sv, tuple(all_names))


def _as_tuple(y0):
    """`y0` as nested tuples of floats (hashable, for `_Fit`); `simulate` checks its shape."""
    return tuple(_as_tuple(v) for v in y0) if np.ndim(y0) else float(y0)


def _levenberg_marquardt(evaluate, theta, jac, r, *, steps, rtol, eps, accept, report):
    r"""Minimise $\tfrac12 |r(\theta)|^2$ by Levenberg-Marquardt from `theta`, where `jac`,
    `r` are the Jacobian and residuals there and `evaluate(theta)` gives
    `(jac, (r, n_failed))`. Marquardt's scaling (the damping term $\mu\,\mathrm{diag}(J^TJ)$,
    so the parameters' units do not matter) and Nielsen's update of $\mu$ (Madsen, Nielsen
    and Tingleff, *Methods for non-linear least squares problems*, 2004, section 3.2).
    `accept(n_failed, theta, i)` is called at each accepted iterate, `report(i, theta, loss)`
    after it; `eps` is the machine epsilon of the evaluations (loss changes and steps below
    its round-off end the fit). **Returns** the last accepted `theta`, the loss at the start
    and at each accepted iterate, and the Jacobian at the last."""
    rtol, step_tol = max(rtol, 4 * eps), max(1e-12, 8 * eps)
    theta, jac, r = (np.asarray(x, np.float64) for x in (theta, jac, r))
    loss = 0.5 * float(r @ r)
    history = [loss]
    mu, nu = 1e-3, 2.0
    for i in range(steps):
        a, g = jac.T @ jac, jac.T @ r
        if not np.all(np.isfinite(g)):
            raise FloatingPointError(
                "calibrate: the Jacobian of the statistics is not finite "
                "at an accepted iterate (try a smaller dt)."
            )
        if not np.max(np.abs(g)) > 0:
            break  # a stationary point
        d = np.maximum(np.diag(a), 1e-12 * max(np.max(np.diag(a)), 1e-300))
        while True:
            step = np.linalg.solve(a + mu * np.diag(d), -g)
            if np.linalg.norm(step) <= step_tol * (np.linalg.norm(theta) + step_tol):
                return theta, np.asarray(history), jac  # no step left to take
            new_jac, (new_r, n_failed) = evaluate(theta + step)
            new_r = np.asarray(new_r, np.float64)
            new_loss = 0.5 * float(new_r @ new_r)
            predicted = 0.5 * float(step @ (mu * d * step - g))
            gain = (loss - new_loss) / predicted if predicted > 0 else -1.0
            if np.isfinite(new_loss) and gain > 0:
                break
            mu, nu = mu * nu, 2.0 * nu
            if nu > 2.0**40:  # every shorter step fails to decrease the loss: converged
                return theta, np.asarray(history), jac
        theta, jac, r = theta + step, np.asarray(new_jac, np.float64), new_r
        accept(n_failed, theta, i)
        mu, nu = mu * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 2.0
        history.append(new_loss)
        report(i, theta, new_loss)
        if loss - new_loss <= rtol * max(loss, 1e-300):
            break
        loss = new_loss
    return theta, np.asarray(history), jac


def _optax_fit(optimizer, residuals, evaluate, theta, *, steps, rtol, check, report):
    r"""Minimise $\tfrac12 |r(\theta)|^2$ with an optax `optimizer` from `theta`; failed
    samples are refused (`check`) at each accepted iterate; `evaluate` is `calibrate`'s
    Jacobian program. **Returns** the last `theta`, the loss at the start and at each accepted
    iterate, and the Jacobian at the last."""
    opt = optax.with_extra_args_support(optimizer)

    def loss_aux(theta):
        r, n_failed = residuals(theta)
        return 0.5 * jnp.dot(r, r), n_failed

    value_and_grad = jax.value_and_grad(loss_aux, has_aux=True)

    def loss(theta):
        # scalar-only view for line searches (`value_fn`), the same traced function
        return loss_aux(theta)[0]

    @jax.jit
    def opt_step(theta, state):
        # One compiled step (a line search evaluates `loss` inside it). The failure count
        # returned is that at `theta`, the accepted point of the previous step; trial points a
        # line search rejects are not checked (they are not used as data).
        (value, n_failed), grad = value_and_grad(theta)
        updates, state = opt.update(grad, state, theta, value=value, grad=grad, value_fn=loss)
        return optax.apply_updates(theta, updates), state, value, n_failed

    # Strong types from the start: optax's initial state has weakly typed scalars that the
    # first update makes strong, which would compile `opt_step` a second time.
    state = jax.tree_util.tree_map(
        lambda x: jnp.array(x, dtype=jnp.result_type(x)), opt.init(theta)
    )
    history, converged = [], False
    for i in range(steps):
        new_theta, state, value, n_failed = opt_step(theta, state)
        check(n_failed, theta, f"after optimiser step {i}" if i else "at init")
        history.append(float(value))  # the loss at theta, before this step
        if i > 0 and abs(history[-2] - history[-1]) <= rtol * max(history[-2], 1e-300):
            converged = True
            break
        theta = new_theta
        report(i, theta, history[-1])
    # the Jacobian at the fit, for the standard errors (the Jacobian program, compiled already)
    jac, (r, n_failed) = evaluate(theta)
    check(n_failed, theta, "at the fitted parameters")
    if not converged:  # the last step's result, evaluated before only inside its line search
        history.append(0.5 * float(jnp.dot(r, r)))
    return theta, np.asarray(history), jac


def _check_identifiable(jac, names, inertia):
    """Raise if the statistics do not determine `(log I, log c)`: a (near) null direction of
    their Jacobian at the start."""
    jac = np.asarray(jac)
    if not np.all(np.isfinite(jac)):
        raise ValueError(
            "calibrate: the statistics' Jacobian at init is not finite; "
            "the initial system fails to simulate (try a smaller dt)."
        )
    n = jac.shape[1]
    _, sv, vt = np.linalg.svd(jac, full_matrices=True)
    sv_full = np.zeros(n)
    sv_full[: min(n, len(sv))] = sv[:n]
    if sv_full[0] == 0 or sv_full[-1] <= 1e-4 * sv_full[0]:
        null = vt[-1]
        combo = " ".join(f"{w:+.2f} log {nm}" for w, nm in zip(null, names) if abs(w) > 0.05)
        why = ""
        moments = [i for i, nm in enumerate(names) if nm.startswith("I_")]
        if len(moments) == 3:
            # d(1/I_i) = k for all i  <=>  d log I_i = -k I_i: the Casimir shift of H
            shift = np.zeros(n)
            shift[moments] = inertia
            if abs(np.dot(null, shift)) > 0.9 * np.linalg.norm(shift):
                why = (
                    " This is the exact symmetry of the rigid body: adding a constant to "
                    "every 1/I_i adds a multiple of the Casimir to H and does not change the "
                    "motion. Hold one moment fixed, e.g. fixed=('I_3',)."
                )
        raise ValueError(
            "calibrate: the parameters are not identifiable from these statistics: changing "
            f"{combo} leaves them (almost) unchanged (singular values of their Jacobian: "
            f"{np.array2string(sv_full, precision=3)}).{why} Otherwise observe more times or "
            "other statistics (the Casimir |y| is conserved and says nothing)."
        )
    return sv_full
