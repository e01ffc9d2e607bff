"""What every method provides, and the Newton iteration the implicit ones share."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .. import _so3


class StepInfo(NamedTuple):
    """What one step reports to the driver.

    - `ok`: the step succeeded (for implicit methods: the solve converged to the right root).
    - `iterations`: Newton updates used (0 for explicit methods).
    - `residual`: max-norm of the final residual (0 for explicit methods).
    """

    ok: jax.Array
    iterations: jax.Array
    residual: jax.Array


class AbstractMethod:
    """A one-step method for $dy = f(y)(dt + c \\circ dW)$.

    A method is a small immutable (hashable) object; the driver owns the loop, the noise,
    saving and failure handling. Subclasses implement `step`, and may override `check_initial`
    to reject initial values outside their domain before anything is compiled.
    """

    def step(self, model, y, dt, dW):
        """Advance one sample by one step.

        **Arguments:** `model` (a `RigidBody`), `y` shape `(3,)`, the step `dt` and the
        Brownian increment `dW` (scalars).

        **Returns:** `(y_next, StepInfo)`.
        """
        raise NotImplementedError

    def check_initial(self, model, y0):
        """Raise `ValueError` if the concrete initial value `y0` (NumPy, shape (3,)) is outside
        the method's domain."""


def explicit_info(y):
    """`StepInfo` of an explicit step: ok iff the result is finite."""
    dtype = y.dtype
    return StepInfo(jnp.all(jnp.isfinite(y)), jnp.zeros((), jnp.int32), jnp.zeros((), dtype))


def default_tol(dtype):
    """Residual tolerance in the max-norm: a small multiple of the unit round-off. Residuals of
    these O(1) maps cannot be evaluated more accurately than a few ulps."""
    return 64.0 * float(jnp.finfo(dtype).eps)


def newton(fn, starts, *, tol, max_iter, active=True):
    """Newton's method for a 3-vector unknown, on components, with fallback parameterisations.

    `fn(x, mode) -> (r, J, admissible)` is the residual, its Jacobian in parameterisation
    `mode` (0, 1, ...), started from `starts[mode]`, and whether `x` would be an acceptable
    root (for example on the right branch). Iterates `x <- x - J^{-1} r` until
    `max|r| <= tol` at an admissible root. After `max_iter` updates, a
    non-finite residual, or convergence to a rejected root, the sample restarts in the next
    parameterisation; after the last it gives up. All modes share one loop, so the fallback
    costs nothing unless some sample needs it. Samples with `active=False` do no work. Under
    `vmap` the loop runs until every sample stops; `while_loop`'s batching leaves finished
    samples unchanged.

    **Returns:** `(x, mode, iterations, residual_norm, converged)`; `iterations` counts the
    updates of all modes.
    """
    dtype = starts[0][0].dtype
    last = len(starts) - 1

    def start_of(mode):
        return tuple(
            functools.reduce(lambda acc, m: jnp.where(mode == m, starts[m][i], acc),
                             range(1, last + 1), starts[0][i])
            for i in range(3)
        )

    # State: mode, evaluations in this mode, total updates, iterate, residual, converged,
    # gave up.
    def cond(state):
        return ~(state[5] | state[6])

    def body(state):
        mode, evals, total, x, _, _, _ = state
        r, jac, admissible = fn(x, mode)
        rnorm = jnp.maximum(jnp.maximum(jnp.abs(r[0]), jnp.abs(r[1])), jnp.abs(r[2]))
        small = rnorm <= tol
        good = small & admissible
        exhausted = ~good & ((evals > max_iter) | ~jnp.isfinite(rnorm) | small)
        switch = exhausted & (mode < last)
        dx = _so3.solve3(jac, r)
        step = ~good & ~exhausted
        restart = start_of(jnp.minimum(mode + 1, last))
        x = tuple(jnp.where(switch, s0, jnp.where(step, xi - di, xi))
                  for xi, di, s0 in zip(x, dx, restart))
        return (mode + switch, jnp.where(switch, 0, evals + 1), total + step, x, rnorm,
                good, exhausted & ~switch)

    z = jnp.zeros((), jnp.int32)
    inactive = ~jnp.asarray(active)
    init = (z, z, z, starts[0], jnp.asarray(jnp.inf, dtype), jnp.array(False), inactive)
    mode, _, total, x, rnorm, conv, _ = jax.lax.while_loop(cond, body, init)
    return x, mode, total, rnorm, conv
