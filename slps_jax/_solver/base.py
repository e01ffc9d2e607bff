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


def newton(fn, starts, *, tol, max_iter, active=True, aux0=None):
    """Newton's method for a 3-vector unknown, on components, with fallback parameterisations.

    `fn(x, mode) -> (r, J, admissible)` (or `(r, J, admissible, aux)`) is the residual, its
    Jacobian in parameterisation `mode` (0, 1, ...), whether `x` would be an acceptable root
    (for example on the right branch), and optionally anything the caller wants back from
    the evaluation at the final iterate (`aux`, for example the rotation built from `x`).
    Mode `m` starts from `starts[m]`: a component tuple, or for `m >= 1` a zero-argument
    callable, evaluated inside the loop only, so a fallback start costs nothing unless some
    sample needs it. Iterates `x <- x - J^{-1} r` until `max|r| <= tol` at an admissible
    root. After `max_iter` updates, a non-finite residual, or convergence to a rejected root,
    the sample restarts in the next parameterisation; after the last it gives up. All modes
    share one loop. Samples with `active=False` do no work and return `starts[0]` and `aux0`
    unchanged. Under `vmap` the loop runs until every sample stops (zero times if none is
    active); `while_loop`'s batching leaves finished samples unchanged.

    **Returns:** `(x, mode, iterations, residual_norm, converged)`, and `aux` last when `fn`
    returns one; `iterations` counts the updates of all modes.
    """
    x0 = starts[0]
    dtype = x0[0].dtype
    last = len(starts) - 1
    with_aux = aux0 is not None

    def start_of(mode):
        vals = [s() if callable(s) else s for s in starts[1:]]
        return tuple(
            functools.reduce(lambda acc, m: jnp.where(mode == m, vals[m - 1][i], acc),
                             range(2, last + 1), vals[0][i])
            for i in range(3)
        )

    # State: mode, evaluations in this mode, total updates, iterate, residual, converged,
    # gave up, aux.
    def cond(state):
        return ~(state[5] | state[6])

    def body(state):
        mode, evals, total, x, _, _, _, aux = state
        out = fn(x, mode)
        r, jac, admissible = out[:3]
        if with_aux:
            aux = out[3]
        rnorm = max_norm(r)
        small = rnorm <= tol
        good = small & admissible
        exhausted = ~good & ((evals > max_iter) | ~jnp.isfinite(rnorm) | small)
        switch = exhausted & (mode < last)
        dx = _so3.solve3(jac, r)
        step = ~good & ~exhausted
        if last > 0:
            restart = start_of(jnp.minimum(mode + 1, last))
            x = tuple(jnp.where(switch, s0, jnp.where(step, xi - di, xi))
                      for xi, di, s0 in zip(x, dx, restart))
        else:
            x = tuple(jnp.where(step, xi - di, xi) for xi, di in zip(x, dx))
        return (mode + switch, jnp.where(switch, 0, evals + 1), total + step, x, rnorm,
                good, exhausted & ~switch, aux)

    z = jnp.zeros((), jnp.int32)
    inactive = ~jnp.asarray(active)
    init = (z, z, z, x0, jnp.asarray(jnp.inf, dtype), jnp.array(False), inactive,
            aux0 if with_aux else ())
    mode, _, total, x, rnorm, conv, _, aux = jax.lax.while_loop(cond, body, init)
    if with_aux:
        return x, mode, total, rnorm, conv, aux
    return x, mode, total, rnorm, conv


def implicit_root(residual, solve, safe):
    """A root of `residual` found by `solve`, differentiable by the implicit function theorem.

    `residual(x)` (component 3-vectors) may close over anything: the model's parameters, the
    state, the step. `solve() -> (x, ok, aux)` finds the root by any iteration at all;
    derivatives never go through it. With `R(x*, p) = 0`, `dx* = -J^{-1} (dR/dp) dp` at the
    root (`jax.lax.custom_root`), in forward and reverse mode, so a Newton solve costs one
    3x3 solve per step to differentiate, whatever its iteration count, and its while_loop
    (not reverse-differentiable) is never differentiated. Where `ok` is false the root is
    replaced by `safe`, a point where `J` is regular, so that a failed sample (which the
    driver freezes) yields finite, unused derivatives instead of NaNs that would leak through
    `where` into the gradient.

    **Returns:** `(x, ok, aux)`.
    """

    def f(x):
        return _so3.unvec(residual(_so3.vec(x)))

    dtype = safe[0].dtype

    def run(_, __):
        x, ok, aux = solve()
        x = tuple(jnp.where(ok, xi, si) for xi, si in zip(x, safe))
        # custom_root wants floating auxiliary outputs; integers and flags travel as floats
        return _so3.unvec(x), tuple(jnp.asarray(t, dtype) for t in (ok, *aux))

    def tangent_solve(g, b):
        # g is f linearised at the root: its Jacobian, materialised, in a 3x3 solve. Only
        # derivative passes run this.
        jac = jax.jacfwd(g)(b)
        return _so3.unvec(_so3.solve3(_so3.mat(jac), _so3.vec(b)))

    x, aux = jax.lax.custom_root(f, _so3.unvec(safe), run, tangent_solve, has_aux=True)
    aux = jax.lax.stop_gradient(aux)
    return _so3.vec(x), aux[0] > 0.5, aux[1:]


def max_norm(r):
    """Max-norm of a component 3-vector."""
    return jnp.maximum(jnp.maximum(jnp.abs(r[0]), jnp.abs(r[1])), jnp.abs(r[2]))
