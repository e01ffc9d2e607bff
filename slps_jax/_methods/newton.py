"""Newton's method over a named state, with a result code that says why it stopped."""

from __future__ import annotations

from typing import NamedTuple, cast

import jax
import jax.numpy as jnp

from .._algebra.so3 import solve3
from .._support.batching import batched_like
from .._support.solution import RESULTS

_RUNNING = -1  # a result code that is not one: the iteration goes on


class NewtonState(NamedTuple):
    """The state of `newton`, one sample's.

    - `x`: the unknowns, a tuple of `n` arrays (components; under `vmap` each is a vector
      over the batch, so the iteration is element-wise arithmetic on long vectors).
    - `iterations`: updates made, over all continuation stages.
    - `residual`: max-norm of the residual at `x` when last tested.
    - `result`: a `RESULTS` code once stopped (`successful`, `max_iterations_reached`,
      `nonfinite`, `off_branch`, `outside_domain`).
    - `level`, `stage`: the continuation stage: the problem at `lam = (stage + 1) / 2^level`.
    - `updates`: updates made in this stage.
    """

    x: tuple
    iterations: jax.Array
    residual: jax.Array
    result: jax.Array
    level: jax.Array
    stage: jax.Array
    updates: jax.Array


def max_norm(r):
    """Max-norm of a component vector (components may be arrays)."""
    out = jnp.max(jnp.abs(r[0]))
    for ri in r[1:]:
        out = jnp.maximum(out, jnp.max(jnp.abs(ri)))
    return out


def solve_linear(jac, r):
    """Solve `jac x = r` on components (`jac` a tuple of rows): cofactors for 3 unknowns
    (far cheaper than a batched LU under `vmap`), LU otherwise."""
    n = len(r)
    if n == 3:
        return solve3(jac, r)
    mat = jnp.stack([jnp.stack(jnp.broadcast_arrays(*row), axis=-1) for row in jac], axis=-2)
    rhs = jnp.stack(jnp.broadcast_arrays(*r), axis=-1)
    x = jnp.linalg.solve(mat, rhs[..., None])[..., 0]
    return tuple(x[..., i] for i in range(n))


def identity_plus(s, jac):
    """`Id + s jac` for a Jacobian in either form `newton` takes: rows of components, or an
    array."""
    if isinstance(jac, tuple):
        n = len(jac)
        return tuple(
            tuple(s * jac[i][j] + 1.0 if i == j else s * jac[i][j] for j in range(n))
            for i in range(n)
        )
    return jnp.eye(jac.shape[-1], dtype=jac.dtype) + s * jac


def newton(fn, x0, *, tol, max_iter, active=True, admissible=None, continuation=0, unroll=0):
    """Newton's method for `fn(x) = 0` from `x0`, for any number `n` of unknowns.

    **Arguments:**

    - `fn(x) -> (r, J)`: the residual (`n` components) and its Jacobian (`n` rows of `n`);
      with `continuation > 0`, `fn(x, lam) -> (r, J)` for a family of problems whose member
      `lam = 1` is the one to solve and whose member `lam = 0` has the root `x0`. `J` may also be a function
      `J(r) -> dx` that solves with it (a factorisation computed once, a fixed-point map).
    - `x0`: the start, `n` components; or one array of shape `(n,)` (then `r` is an array,
      `J` an `(n, n)` array or a function, and `x` of the result an array): for many
      unknowns, where the component form would trace `n^2` scalar products.
    - `tol`: stop when `max|r| <= tol`; `max_iter`: at most this many updates per stage.
    - `active`: samples with `False` do no work and report `RESULTS.outside_domain`.
    - `admissible(x) -> bool`: the branch of roots sought (for example the sine chart's open
      unit ball). A root outside it ends the attempt with `RESULTS.off_branch`; iterates may
      pass outside on the way (`fn` must stay finite there).
    - `continuation`: a sample whose attempt fails (off the branch, no convergence, a
      non-finite residual) starts again from `x0` and follows the family: `lam = 1/2, 1`,
      then `lam = 1/4, 1/2, 3/4, 1`, ..., each root the start of the next stage, up to
      `2^continuation` stages.
    - `unroll`: the loop's first `unroll` bodies as straight-line code before it: the same
      iterates, and on a CPU somewhat faster, but each is one more copy of `fn` to compile.

    One `while_loop` whose body is one evaluation of `r` and `J`, the test, and one update
    (a linear solve): the continuation is data in the loop state, not code, so `fn` is
    compiled once. Under `vmap` the loop runs until every sample stops; stopped samples stay
    unchanged. Where `J` is given as rows (not a function), the residual's norm and the
    update, every value that reads `r` and `J`, are computed in one kernel on a CPU
    (`one_kernel`).

    **Returns:** the final `NewtonState`; `residual` is that of the returned `x` (for a
    successful sample), and a failed sample reports the reason of its last attempt.
    """
    if not isinstance(x0, tuple):  # one array of unknowns: a tuple of one component
        inner = fn
        fn = lambda x, *lam: _as_component(*inner(x[0], *lam))
        check = admissible
        admissible = None if check is None else (lambda x: check(x[0]))
        s = newton(
            fn,
            (x0,),
            tol=tol,
            max_iter=max_iter,
            active=active,
            admissible=admissible,
            continuation=continuation,
            unroll=unroll,
        )
        return s._replace(x=s.x[0])
    dtype = x0[0].dtype
    zero = jnp.zeros((), jnp.int32)
    init = NewtonState(
        x0,
        zero,
        jnp.asarray(jnp.inf, dtype),
        jnp.where(active, _RUNNING, RESULTS.outside_domain).astype(jnp.int32),
        zero,
        zero,
        zero,
    )
    init = batched_like(init, (x0, active))  # (one pass over `fn` under vmap: `_support.batching`)

    def evaluate(s):
        if continuation:
            return fn(s.x, (s.stage + 1).astype(dtype) / (2**s.level).astype(dtype))
        return fn(s.x)

    def test(s, rnorm):
        inside = jnp.ones((), bool) if admissible is None else admissible(s.x)
        small = rnorm <= tol
        # (nested `where`, elementwise: `jnp.select` is an argmax, a reduce of its own, into
        # which XLA:CPU would copy the residual's graph once more; see `one_kernel`)
        result = _RUNNING
        for cond, code in (
            (s.updates >= max_iter, RESULTS.max_iterations_reached),
            (~jnp.isfinite(rnorm), RESULTS.nonfinite),
            (small, RESULTS.off_branch),
            (small & inside, RESULTS.successful),
        ):  # the last condition that holds wins: the first of `jnp.select`'s order
            result = jnp.where(cond, code, result)
        result = jnp.asarray(result, jnp.int32)
        result = jnp.where(s.result == _RUNNING, result, s.result)
        if continuation:
            done = result == RESULTS.successful
            running = s.result == _RUNNING
            next_stage = running & done & (s.stage + 1 < 2**s.level)  # the next member
            again = running & ~done & (result != _RUNNING) & (s.level < continuation)
            s = s._replace(
                x=tuple(jnp.where(again, a, b) for a, b in zip(x0, s.x)),
                stage=jnp.where(next_stage, s.stage + 1, jnp.where(again, 0, s.stage)),
                level=jnp.where(again, s.level + 1, s.level),
                updates=jnp.where(next_stage | again, 0, s.updates),
            )
            result = jnp.where(next_stage | again, _RUNNING, result)
        return s._replace(
            residual=jnp.where(s.result == _RUNNING, rnorm, s.residual), result=result
        )

    def body(s):
        r, jac = evaluate(s)
        if callable(jac):
            rnorm, delta = max_norm(r), cast(tuple, jac(r))
        else:  # every reader of `r` and `J` in one kernel on a CPU (`one_kernel`)
            rnorm, *delta = one_kernel(max_norm(r), *solve_linear(jac, r))
        t = test(s, rnorm)
        # no update where the test stopped the sample or began a new continuation stage
        # (`r`, `J` belong to the old one)
        go = (t.result == _RUNNING) & (t.level == s.level) & (t.stage == s.stage)
        x = tuple(jnp.where(go, xi - di, xi) for xi, di in zip(t.x, delta))
        return t._replace(x=x, iterations=t.iterations + go, updates=t.updates + go)

    s = init
    for _ in range(unroll):  # straight-line code: XLA fuses it across updates, a loop not
        s = body(s)
    return jax.lax.while_loop(lambda s: s.result == _RUNNING, body, s)


def _sum_pairs(a, b):
    return tuple(x + y for x, y in zip(a, b))


def _through_one_reduce(*xs):
    xs = jnp.broadcast_arrays(*xs)  # (the pairs' axis first: see `one_kernel`)
    if len({x.dtype for x in xs if jnp.issubdtype(x.dtype, jnp.inexact)}) > 1:
        return tuple(xs)  # (XLA allows one floating-point precision per reduce)
    # (-0.0, not 0.0, for floats: x + (-0.0) is x for every x, x = -0.0 included)
    zeros = [jnp.asarray(-0.0 if jnp.issubdtype(x.dtype, jnp.inexact) else 0, x.dtype) for x in xs]
    pairs = [jnp.stack([x, jnp.broadcast_to(z, x.shape)]) for x, z in zip(xs, zeros)]
    return tuple(jax.lax.reduce(pairs, zeros, _sum_pairs, (0,)))


def one_kernel(*xs):
    """`xs` unchanged, computed on a CPU as the outputs of one variadic reduce.

    XLA:CPU has no multi-output loop fusion: values that share one graph (a residual and its
    Jacobian) and are read by several elementwise consumers (the test's norm and each
    component of the update) get a copy of that graph fused into each consumer, so a Newton
    update is evaluated once per consumer. A variadic `lax.reduce` is one kernel with several
    outputs: with every consumer among its inputs, the shared graph is fused into it once.
    Each value is paired with a zero and the pair summed, which leaves it unchanged (`x + (-0.0)
    = x`, signed zeros, NaN and infinities included). The pair's axis comes first, so that
    under `vmap` the batch is the reduce's contiguous axis and XLA:CPU emits vector code.
    (Its values are floats of one precision: integers inside it made XLA:CPU's elemental
    emitter at optimisation level 0 compile a float32 loop that never ended.)
    Elsewhere (GPUs fuse several outputs) the values pass as they are.
    `benchmarks/newton_fusion.py` measures the loops with and without it, and watches that
    the kernel stays one.
    """
    return jax.lax.platform_dependent(*xs, cpu=_through_one_reduce, default=lambda *xs: xs)


def _as_component(r, jac):
    """An array residual and its Jacobian (a matrix or a solver) as one component."""
    if callable(jac):
        return (r,), lambda rr: (jac(rr[0]),)
    return (r,), lambda rr: (jnp.linalg.solve(jac, rr[0]),)


def implicit_root(residual, solve, safe):
    """A root of `residual` found by `solve`, differentiable by the implicit function theorem.

    `residual(x)` (component vectors) may close over anything: the system's parameters, the
    state, the step. `solve() -> (x, ok, aux)` finds the root by any iteration at all;
    derivatives never go through it. With `R(x*, p) = 0`, `dx* = -J^{-1} (dR/dp) dp` at the
    root (`jax.lax.custom_root`), in forward and reverse mode, so a Newton solve costs one
    linear solve per step to differentiate, whatever its iteration count, and its while_loop
    (not reverse-differentiable) is never differentiated. Where `ok` is false the root is
    replaced by `safe`, a point where `J` is regular, so that a failed sample (which the
    driver freezes) yields finite, unused derivatives instead of NaNs that would leak through
    `where` into the gradient.

    The unknowns are components (a tuple) or one array of shape `(n,)`.

    **Returns:** `(x, ok, aux)`.
    """
    array = not isinstance(safe, tuple)  # one array of unknowns
    n = len(safe)

    def unvec(x):
        return x if array else jnp.stack(jnp.broadcast_arrays(*x), axis=-1)

    def vec(x):
        return x if array else tuple(x[..., i] for i in range(n))

    def f(x):
        return unvec(residual(vec(x)))

    dtype = (safe if array else safe[0]).dtype

    def run(_, __):
        x, ok, aux = solve()
        x = (
            jnp.where(ok, x, safe)
            if array
            else tuple(jnp.where(ok, xi, si) for xi, si in zip(x, safe))
        )
        # custom_root wants inexact auxiliary outputs; integers and flags travel as floats
        return unvec(x), tuple(
            t if jnp.issubdtype(jnp.result_type(t), jnp.inexact) else jnp.asarray(t, dtype)
            for t in (ok, *aux)
        )

    def tangent_solve(g, b):
        # g is f linearised at the root: its Jacobian, materialised, in a linear solve. Only
        # derivative passes run this.
        jac = jax.jacfwd(g)(b)
        if array:
            return jnp.linalg.solve(jac, b)
        return unvec(
            solve_linear(tuple(vec(row) for row in (jac[..., i, :] for i in range(n))), vec(b))
        )

    x, aux = jax.lax.custom_root(f, unvec(safe), run, tangent_solve, has_aux=True)
    aux = jax.lax.stop_gradient(aux)
    return vec(x), aux[0] > 0.5, aux[1:]


def jacobian_mode(jacobian, dim, *, large, largest_newton=10):
    """The mode `"auto"` stands for: Newton with the full Jacobian up to `largest_newton`
    unknowns (so(5)), `large` above (`benchmarks/so_n.py` measures them)."""
    if jacobian != "auto":
        return jacobian
    return "newton" if dim <= largest_newton else large


def solve_array(
    residual, x0, safe, *, tol, max_iter, jacobian, active=True, admissible=None, continuation=0
):
    """A root of `residual(x, lam)` (one array of `n` unknowns, `lam = 1` the problem) by
    `newton` from `x0`, differentiable by the implicit function theorem (`implicit_root`,
    `safe` where a sample failed). With `continuation`, the family `lam` as in `newton`.

    `jacobian`: `"newton"` (the Jacobian by forward-mode autodiff, `n` tangents, at every
    update: quadratic convergence), `"identity"` (a fixed-point iteration, for residuals
    whose Jacobian is the identity up to the step's size), or a function `() -> M` of an
    approximate Jacobian, LU-factorised once and used by every update (a chord iteration:
    linear convergence, no `n`-tangent pass per update). `max_iter=None`: 12 updates for
    `"newton"`, 48 for the linearly converging iterations.

    **Returns:** `(x, result, iterations, residual)`.
    """
    jac = jax.jacfwd(residual)
    if max_iter is None:
        max_iter = 12 if jacobian == "newton" else 48

    def solve():
        if jacobian == "newton":
            fn = lambda x, lam: (residual(x, lam), jac(x, lam))
        elif jacobian == "identity":
            fn = lambda x, lam: (residual(x, lam), lambda r: r)
        else:
            lu = jax.scipy.linalg.lu_factor(jacobian())
            fn = lambda x, lam: (
                residual(x, lam),
                lambda r: jax.scipy.linalg.lu_solve(lu, r),
            )
        s = newton(
            fn if continuation else (lambda x: fn(x, 1.0)),
            x0,
            tol=tol,
            max_iter=max_iter,
            active=active,
            admissible=admissible,
            continuation=continuation,
        )
        return s.x, s.result == RESULTS.successful, (s.result, s.iterations, s.residual)

    x, _, (result, iterations, res) = implicit_root(lambda x: residual(x, 1.0), solve, safe)
    return x, result.astype(jnp.int32), iterations.astype(jnp.int32), res
