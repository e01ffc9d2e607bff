"""Newton's method over a named state, with a result code that says why it stopped."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .. import _so3
from .._solution import RESULTS

_RUNNING = -1  # a result code that is not one: the iteration goes on


class NewtonState(NamedTuple):
    """The state of `newton`, one sample's.

    - `x`: the unknowns, a tuple of `n` arrays (components; under `vmap` each is a vector
      over the batch, so the iteration is element-wise arithmetic on long vectors).
    - `iterations`: updates made, over all continuation stages.
    - `residual`: max-norm of the last residual evaluated.
    - `result`: a `RESULTS` code once stopped (`successful`, `max_iterations_reached`,
      `nonfinite`, `off_branch`, `outside_domain`).
    - `level`, `stage`: the continuation stage: the problem at `lam = (stage + 1) / 2^level`.
    """

    x: tuple
    iterations: jax.Array
    residual: jax.Array
    result: jax.Array
    level: jax.Array
    stage: jax.Array
    updates: jax.Array  # in this stage


def max_norm(r):
    """Max-norm of a component vector."""
    out = jnp.abs(r[0])
    for ri in r[1:]:
        out = jnp.maximum(out, jnp.abs(ri))
    return out


def solve_linear(jac, r):
    """Solve `jac x = r` on components (`jac` a tuple of rows): cofactors for 3 unknowns
    (far cheaper than a batched LU under `vmap`), LU otherwise."""
    n = len(r)
    if n == 3:
        return _so3.solve3(jac, r)
    mat = jnp.stack([jnp.stack(jnp.broadcast_arrays(*row), axis=-1) for row in jac], axis=-2)
    rhs = jnp.stack(jnp.broadcast_arrays(*r), axis=-1)
    x = jnp.linalg.solve(mat, rhs[..., None])[..., 0]
    return tuple(x[..., i] for i in range(n))


def newton(fn, x0, *, tol, max_iter, active=True, admissible=None, continuation=0):
    """Newton's method for `fn(x) = 0` from `x0`, for any number `n` of unknowns.

    **Arguments:**

    - `fn(x) -> (r, J)`: the residual (`n` components) and its Jacobian (`n` rows of `n`);
      with `continuation > 0`, `fn(x, lam) -> (r, J)` for a family of problems whose member
      `lam = 1` is the one to solve and whose member `lam = 0` has the root `x0`.
    - `x0`: the start, `n` components; it must be admissible.
    - `tol`: stop when `max|r| <= tol`; `max_iter`: at most this many updates per stage.
    - `active`: samples with `False` do no work and report `RESULTS.outside_domain`.
    - `admissible(x) -> bool`: the branch of roots sought (for example the sine chart's open
      unit ball). A root outside it ends the attempt with `RESULTS.off_branch`; iterates may
      pass outside on the way (`fn` must stay finite there).
    - `continuation`: a sample whose attempt fails (off the branch, no convergence) starts
      again from `x0` and follows the family: `lam = 1/2, 1`, then `lam = 1/4, 1/2, 3/4, 1`,
      ..., each root the start of the next stage, up to `2^continuation` stages.

    One `while_loop` whose body is one update (one evaluation of `r` and `J` and one linear
    solve): the continuation is data in the loop state, not code, so the residual is
    compiled once. Under `vmap` the loop runs until every sample stops, and stopped samples
    stay unchanged.

    **Returns:** the final `NewtonState`; a failed sample reports the reason of its last
    attempt.
    """
    dtype = x0[0].dtype
    x0 = tuple(x0)
    zero = jnp.zeros((), jnp.int32)
    init = NewtonState(x0, zero, jnp.asarray(jnp.inf, dtype),
                       jnp.where(active, _RUNNING, RESULTS.outside_domain).astype(jnp.int32),
                       zero, zero, zero)

    def body(s):
        if continuation:
            lam = (s.stage + 1).astype(dtype) / (2 ** s.level).astype(dtype)
            r, jac = fn(s.x, lam)
        else:
            r, jac = fn(s.x)
        rnorm = max_norm(r)
        x_new = tuple(xi - di for xi, di in zip(s.x, solve_linear(jac, r)))
        inside = jnp.ones((), bool) if admissible is None else admissible(s.x)
        small = rnorm <= tol
        result = jnp.select(
            [small & inside, small, ~jnp.isfinite(rnorm), s.updates >= max_iter],
            [RESULTS.successful, RESULTS.off_branch, RESULTS.nonfinite,
             RESULTS.max_iterations_reached], _RUNNING).astype(jnp.int32)
        go = result == _RUNNING
        x = tuple(jnp.where(go, a, b) for a, b in zip(x_new, s.x))
        level, stage, updates = s.level, s.stage, jnp.where(go, s.updates + 1, 0)
        if continuation:
            done = result == RESULTS.successful
            next_stage = done & (stage + 1 < 2 ** level)  # the next member of the family
            again = ~go & ~done & (level < continuation)  # start over with finer stages
            result = jnp.where(next_stage | again, _RUNNING, result)
            stage = jnp.where(next_stage, stage + 1, jnp.where(again, 0, stage))
            level = jnp.where(again, level + 1, level)
            x = tuple(jnp.where(again, a, b) for a, b in zip(x0, x))
        return s._replace(x=x, iterations=s.iterations + go, residual=rnorm, result=result,
                          level=level, stage=stage, updates=updates)

    return jax.lax.while_loop(lambda s: s.result == _RUNNING, body, init)


def implicit_root(residual, solve, safe):
    """A root of `residual` found by `solve`, differentiable by the implicit function theorem.

    `residual(x)` (component vectors) may close over anything: the model's parameters, the
    state, the step. `solve() -> (x, ok, aux)` finds the root by any iteration at all;
    derivatives never go through it. With `R(x*, p) = 0`, `dx* = -J^{-1} (dR/dp) dp` at the
    root (`jax.lax.custom_root`), in forward and reverse mode, so a Newton solve costs one
    linear solve per step to differentiate, whatever its iteration count, and its while_loop
    (not reverse-differentiable) is never differentiated. Where `ok` is false the root is
    replaced by `safe`, a point where `J` is regular, so that a failed sample (which the
    driver freezes) yields finite, unused derivatives instead of NaNs that would leak through
    `where` into the gradient.

    **Returns:** `(x, ok, aux)`.
    """
    n = len(safe)

    def unvec(x):
        return jnp.stack(jnp.broadcast_arrays(*x), axis=-1)

    def vec(x):
        return tuple(x[..., i] for i in range(n))

    def f(x):
        return unvec(residual(vec(x)))

    dtype = safe[0].dtype

    def run(_, __):
        x, ok, aux = solve()
        x = tuple(jnp.where(ok, xi, si) for xi, si in zip(x, safe))
        # custom_root wants floating auxiliary outputs; integers and flags travel as floats
        return unvec(x), tuple(jnp.asarray(t, dtype) for t in (ok, *aux))

    def tangent_solve(g, b):
        # g is f linearised at the root: its Jacobian, materialised, in a linear solve. Only
        # derivative passes run this.
        jac = jax.jacfwd(g)(b)
        return unvec(solve_linear(tuple(vec(row) for row in
                                        (jac[..., i, :] for i in range(n))), vec(b)))

    x, aux = jax.lax.custom_root(f, unvec(safe), run, tangent_solve, has_aux=True)
    aux = jax.lax.stop_gradient(aux)
    return vec(x), aux[0] > 0.5, aux[1:]
