"""Fit the inertia and `c` to observed ensemble statistics, with pathwise gradients."""

from __future__ import annotations

import dataclasses
import math
import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax

from . import _noise
from ._integrate import simulate
from ._model import RigidBody
from ._solver.lie_poisson import LiePoisson


def moments(ys):
    """Default statistic: the mean of `y` and of `y**2` over the ensemble, shape `(6,)`."""
    return jnp.concatenate([jnp.mean(ys, axis=0), jnp.mean(ys ** 2, axis=0)])


@dataclasses.dataclass(frozen=True)
class CalibrationResult:
    """What `calibrate` returns.

    - `model`: the fitted `RigidBody`.
    - `loss`: the loss after each optimiser step (`loss[0]` at the start).
    - `stderr`: delta-method standard errors of `(I_1, I_2, I_3, c)` from the Jacobian of the
      statistics at the fit and `observed_stderr` (`None` if that was not given).
    - `singular_values`: of the weighted Jacobian of the statistics with respect to
      `(log I, log c)` at the start; their spread says how well the data determine the
      parameters.
    """

    model: RigidBody
    loss: np.ndarray
    stderr: np.ndarray | None
    singular_values: np.ndarray


def _unpack(theta):
    return RigidBody(jnp.exp(theta[:3]), jnp.exp(theta[3]))


def calibrate(observed, y0, *, ts, dt, n_samples, key, init, statistic=moments,
              observed_stderr=None, method=LiePoisson(), optimizer=None, steps=50,
              truncate_k=4, rtol=1e-10, progress=True):
    r"""Fit `inertia` and `c` of a `RigidBody` to observed ensemble statistics.

    Minimises the weighted least-squares misfit
    $L(\theta) = \tfrac12 \sum_{k} |(S_k(\theta) - S^{obs}_k)/\sigma_k|^2$, where
    $S_k(\theta)$ = `statistic` of the simulated ensemble at time `ts[k]` and $\sigma$ =
    `observed_stderr` (1 if not given), over $\theta = (\log I_1, \log I_2, \log I_3, \log c)$:
    the parameters stay positive ($c$ and $-c$ give the same law, so only $|c|$ can be
    fitted). The ensemble is simulated with the same `key` at every iteration (common random
    numbers), so $L$ is a smooth deterministic function whose gradient `jax.grad` computes
    exactly (pathwise, through the implicit Newton solves); its minimiser estimates the
    parameters, with a bias of order $1/$`n_samples`.

    Before optimising, the Jacobian of the weighted statistics with respect to $\theta$ is
    computed at `init`; if it is rank deficient (a combination of parameters the statistics
    do not depend on), a `ValueError` says which.

    **Arguments:**

    - `observed`: array `(len(ts), k)`, the statistics to match.
    - `y0`: the initial value; `ts`: increasing observation times, multiples of `dt`.
    - `dt`, `n_samples`, `key`, `method`, `truncate_k`: as in `simulate`.
    - `init`: a `RigidBody`, the starting guess.
    - `statistic`: `(n_samples, 3) -> (k,)`; default `moments` (means of `y` and `y**2`).
    - `observed_stderr`: standard errors of `observed` (same shape), used as weights and for
      the standard errors of the fit.
    - `optimizer`: an optax optimiser; default `optax.lbfgs()` (the loss is deterministic and
      smooth). Optimisers that need the loss value (line searches) get it.
    - `steps`: at most this many optimiser steps; stops earlier when the loss changes by
      less than `rtol` relative.
    - `progress`: print the loss and parameters as it goes (to stderr).

    **Returns:** a `CalibrationResult`.
    """
    if not isinstance(init, RigidBody):
        raise TypeError(f"init must be a RigidBody, got {type(init).__name__}.")
    if not float(init.c) > 0:
        raise ValueError(f"init.c must be positive (c is fitted on a log scale), got {init.c}.")
    ts = np.asarray(ts, float)
    if ts.ndim != 1 or len(ts) < 1 or not np.all(np.diff(ts) > 0) or ts[0] <= 0:
        raise ValueError(f"ts must be increasing positive times, got {ts}.")
    idx = np.rint(ts / dt).astype(int)
    if not np.allclose(idx * dt, ts, rtol=1e-9, atol=0):
        raise ValueError(f"ts must be multiples of dt={dt}, got {ts}.")
    every = math.gcd(*idx.tolist())
    observed = jnp.asarray(observed)
    if observed.ndim != 2 or observed.shape[0] != len(ts):
        raise ValueError(f"observed must have shape (len(ts), k) = ({len(ts)}, k), got "
                         f"{observed.shape}.")
    weight = (jnp.ones_like(observed) if observed_stderr is None
              else 1.0 / jnp.asarray(observed_stderr, observed.dtype))
    if weight.shape != observed.shape or not bool(jnp.all(jnp.isfinite(weight) & (weight > 0))):
        raise ValueError("observed_stderr must be positive and have the shape of observed.")
    key = _noise.check_key(key)

    def statistics(theta):
        sol = simulate(_unpack(theta), y0, t1=float(ts[-1]), dt=dt, n_samples=n_samples,
                       key=key, method=method, save_every=every, truncate_k=truncate_k,
                       throw=False)
        ys = sol.ys[:, idx // every]  # (n_samples, len(ts), 3)
        return jax.vmap(statistic, in_axes=1)(ys)

    def residuals(theta):
        return ((statistics(theta) - observed) * weight).ravel()

    def loss(theta):
        r = residuals(theta)
        return 0.5 * jnp.dot(r, r)

    theta = jnp.concatenate([jnp.log(init.inertia), jnp.log(init.c)[None]])
    sv = _check_identifiable(jax.jacfwd(residuals)(theta))

    opt = optax.with_extra_args_support(optax.lbfgs() if optimizer is None else optimizer)
    state = opt.init(theta)
    loss = jax.jit(loss)
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    value, grad = value_and_grad(theta)
    history = [float(value)]
    for i in range(steps):
        updates, state = opt.update(grad, state, theta, value=value, grad=grad, value_fn=loss)
        theta = optax.apply_updates(theta, updates)
        value, grad = value_and_grad(theta)
        history.append(float(value))
        if progress:
            m = _unpack(theta)
            print(f"calibrate: step {i + 1:3d}  loss {history[-1]:.6e}  inertia "
                  f"{np.round(np.asarray(m.inertia), 6)}  c {float(m.c):.6f}", file=sys.stderr)
        if abs(history[-2] - history[-1]) <= rtol * max(history[-2], 1e-300):
            break

    model = _unpack(theta)
    stderr = None
    if observed_stderr is not None:
        # Delta method: Cov(theta) = (J^T J)^{-1} with the weighted Jacobian; then the chain
        # rule d exp(theta) = exp(theta) d theta.
        jac = np.asarray(jax.jacfwd(residuals)(theta))
        cov = np.linalg.pinv(jac.T @ jac)
        stderr = np.sqrt(np.diag(cov)) * np.exp(np.asarray(theta))
    return CalibrationResult(model, np.asarray(history), stderr, sv)


_NAMES = ("I_1", "I_2", "I_3", "c")


def _check_identifiable(jac):
    """Raise if the statistics do not determine `(log I, log c)`: a (near) null direction of
    their Jacobian at the start."""
    jac = np.asarray(jac)
    if not np.all(np.isfinite(jac)):
        raise ValueError("calibrate: the statistics' Jacobian at init is not finite; "
                         "the initial model fails to simulate (try a smaller dt).")
    _, sv, vt = np.linalg.svd(jac, full_matrices=True)
    sv_full = np.zeros(4)
    sv_full[:len(sv)] = sv[:4]
    if sv_full[0] == 0 or sv_full[-1] <= 1e-8 * sv_full[0]:
        null = vt[-1]
        combo = " + ".join(f"{w:+.2f} log {n}" for w, n in zip(null, _NAMES) if abs(w) > 0.05)
        raise ValueError(
            "calibrate: the parameters are not identifiable from these statistics: changing "
            f"{combo} leaves them unchanged (singular values of their Jacobian: "
            f"{np.array2string(sv_full, precision=3)}). Observe more times or other "
            "statistics (the Casimir |y| is conserved and says nothing).")
    return sv_full
