"""A step that is redone as substeps when it fails, traced once and differentiable.

The driver calls `robust_step` for every step when `retry_substeps = k` (the default, 4) and
the method can fail (`can_fail`; not exact flows and compositions of exact rotations).
A step that fails is redone from its start as `k` equal substeps of `(dt/k, dW/k)` (and
areas `A/k`: `_brownian.scale_noise`, which joined by Chen's relation give the step's), then
`k^2`, then `k^3`, before the sample is given up. The substeps are the scheme run on a finer
grid through the same point `W(t_{n+1})`: for a system whose noise is proportional to the
drift, the flow of the time `tau = dt + c dW` is a group, `phi_tau = phi_{tau/m}^m`, so `m`
substeps approximate the same thing as one step, more accurately; for several noises they
are the scheme with the increments split evenly, a path of the same Brownian bridge family.

**One traced copy of the step.** The attempts are one `while_loop` whose body is the method's
step at the size `dt/m` of the current attempt: a step that succeeds at once runs the body
exactly once, with `m = 1`, so its arithmetic is that of a plain step, and the compiled
program holds the step once (LiePoisson's step takes seconds to compile).

**Differentiation.** A `while_loop` has no reverse mode, so `robust_step` is a
`jax.custom_jvp` function. Its tangent is that of the plain step where the step succeeded at
once (the method's own derivative, for implicit methods by the implicit function theorem),
and for a retried sample the derivative of the `m` substeps actually taken, accumulated as
Jacobian matrices inside a loop that runs only while some sample of the batch was retried.
The tangent is then a matrix product outside any loop: linear, hence transposable, so
`jax.grad` works through retried steps and costs nothing extra where no step was retried.
"""

from __future__ import annotations

import functools
from typing import cast

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from .. import _brownian
from .._methods.base import finite_result
from .._support.batching import batched_like
from .._support.checks import real_dtype
from .._support.solution import RESULTS
from .._systems.system import differentiable_leaves
from .splitting import system_step

# A failed step is split into k, k^2, ..., k^RETRY_LEVELS equal parts before giving up.
RETRY_LEVELS = 3


def step_with_history(method, system, y, dt, dW, history, pending=None):
    """The system's step by `method` (`system_step`), given the method's `history` where it
    keeps one (`AbstractMethod.initial_history`), and the linear flow `y` owes (`pending`)."""
    if not jax.tree_util.tree_leaves(history):
        history = ()
    return system_step(method, system, y, dt, dW, history, pending)


def _attempts(method, system, y, dt, dW, act, k, m0, history=(), jacobians=False, pending=None):
    """Step `y` by `(dt, dW)` where `act`, as `m0` substeps; on failure as `k` times as many,
    up to `k^RETRY_LEVELS`. The method's `history` serves the first attempt of one step
    (`m0 = 1`); substeps start without it. With `pending` (the linear flow `y` owes:
    `system_step`), each substep joins its first half linear flow to the debt before it,
    and the result owes half a substep.

    **Returns:** `(y_next, code, iterations, residual, retried, first, history, J, pending,
    m)`: `code` the `RESULTS` code of the last failure if every attempt failed; the
    iterations of every attempt; the largest residual of a successful substep; `retried`:
    the first attempt failed; `first`: the first attempt's code; `history` the method's after
    the step, reset (`initial_history`) where it was retried; `pending` what `y_next` owes
    (`None` without `pending`); `m` the substeps of the last attempt. With `jacobians`, `J`
    is the derivative of the substeps that succeeded with respect to `(y, dt, dW, the
    system's inexact leaves, pending)`, as matrices with the state flattened (see
    `_jacobian_tools`); else `()`.
    """
    dtype = real_dtype(y.dtype)
    m_max = k**RETRY_LEVELS
    zero_i = jnp.zeros((), jnp.int32)
    cold = method.initial_history(system, y)
    substep, j0, chain = (
        _jacobian_tools(method, system, y, dW, pending)
        if jacobians
        else (
            lambda ys, h, w, hist, owed: (
                *step_with_history(method, system, ys, h, w, hist, owed),
                (),
            ),
            (),
            None,
        )
    )

    def body(s):
        i, m, yc, code, its, res, going, jac, first, hist, owed = s
        mf = m.astype(dtype)
        once = (m == 1) & (i == 0)  # the step itself, not a substep
        h = jnp.where(going, dt / mf, 0.0).astype(dtype)
        # (dt/m, dW/m, A/m): the step's noise split evenly (`_brownian.scale_noise`)
        y2, info, d = substep(
            yc,
            h,
            _brownian.where(going, _brownian.scale_noise(dW, 1.0 / mf)),
            jax.tree_util.tree_map(lambda a, b: jnp.where(once, a, b), history, cold),
            owed,
        )
        c2 = finite_result(y2, info.result)
        ok = going & (c2 == RESULTS.successful)
        fail = going & ~ok
        refine = fail & (m < m_max)
        first = jnp.where(once & going, c2, first)
        hist = jax.tree_util.tree_map(
            lambda new, old: jnp.where(once & ok, new, old), info.history, hist
        )
        its = its + jnp.where(going, info.iterations, 0)
        res = jnp.maximum(res, jnp.where(ok, info.residual, 0.0).astype(dtype))
        if jacobians:  # chained where a substep succeeded, restarted where it is refined
            assert chain is not None
            jac = jax.tree_util.tree_map(
                lambda new, start, old: jnp.where(ok, new, jnp.where(refine, start, old)),
                chain(jac, d, mf, i == 0),
                j0,
                jac,
            )
        i = jnp.where(ok, i + 1, jnp.where(refine, 0, i))
        yc = jnp.where(ok, y2, jnp.where(refine, y, yc))
        owed = jax.tree_util.tree_map(
            lambda start, old: jnp.where(ok, 0.5 * h, jnp.where(refine, start, old)), pending, owed
        )
        m = jnp.where(refine, m * k, m)
        code = jnp.where(fail & ~refine, c2, code)
        going = going & ~(fail & ~refine) & (i < m)
        return i, m, yc, code, its, res, going, jac, first, hist, owed

    init = batched_like(
        (
            zero_i,
            jnp.asarray(m0, jnp.int32),
            y,
            jnp.asarray(RESULTS.successful, jnp.int32),
            zero_i,
            jnp.zeros((), dtype),
            jnp.asarray(act),
            j0,
            jnp.asarray(RESULTS.successful, jnp.int32),
            cold,
            pending,
        ),
        (y, act, history),
    )
    _, m, y_next, code, its, res, _, jac, first, hist, owed = jax.lax.while_loop(
        lambda s: s[6], body, init
    )
    retried = act & ((m > m0) | (code != RESULTS.successful))
    return y_next, code, its, res, retried, first, hist, jac, owed, m


def _real(x):
    """`x` flattened to real numbers: complex arrays (su(N) states, their noise parameters)
    as their real parts followed by their imaginary parts, so that the Jacobians below are
    real matrices (`jacfwd` differentiates real inputs only)."""
    x = jnp.reshape(x, -1)
    return jnp.concatenate([jnp.real(x), jnp.imag(x)]) if jnp.iscomplexobj(x) else x


def _unreal(v, like):
    """`_real`'s inverse, to the shape and dtype of `like`."""
    if jnp.iscomplexobj(like):
        n = v.shape[0] // 2
        v = v[:n] + 1j * v[n:]
    return jnp.reshape(v, jnp.shape(like)).astype(like.dtype)


def _jacobian_tools(method, system, y, dW, pending=None):
    """For `_attempts` with Jacobians: `substep(ys, h, w, history, owed) -> (y_next, info,
    derivatives)` (one `jacfwd` of the step with respect to `(ys, h, w, the system's inexact
    leaves, owed)`, `owed` the linear flow `ys` owes or `None`), the Jacobians of no step at
    all (the identity in `y`), and `chain(J, derivatives, m, first)`, the Jacobians after one
    more substep of `(dt/m, dW/m)`, the `first` of its attempt where `owed` is the step's
    `pending` (after it, half the substep before, `dt/2m`)."""
    leaves, treedef, idx = differentiable_leaves(system)
    p0 = [leaves[i] for i in idx]
    # (on real coordinates: a complex state or leaf as its real and imaginary parts)
    dtype, d = real_dtype(y.dtype), _real(y).size
    # the step's noise (increments, and areas when present) as one flat vector
    w0, unravel = ravel_pytree(dW)

    def step(yr, h, w, pr, owed):
        full = list(leaves)
        for i, leaf in zip(idx, pr):
            full[i] = _unreal(leaf, leaves[i])
        y2, info = system_step(
            method, treedef.unflatten(full), _unreal(yr, y), h, unravel(w), (), owed
        )
        return _real(y2), (y2, info)

    def substep(ys, h, w, history=(), owed=None):  # (substeps start without the history)
        owing = pending is not None
        derivatives, (y2, info) = jax.jacfwd(
            step, argnums=(0, 1, 2, 3, 4) if owing else (0, 1, 2, 3), has_aux=True
        )(
            _real(ys),
            h,
            ravel_pytree(w)[0],
            [_real(p) for p in p0],
            jnp.asarray(owed, dtype) if owing else None,
        )
        # (its history: the one given, unchanged; only a step's first attempt learns, and
        # the derivatives are taken for retried steps alone)
        info = info._replace(history=history)
        return y2, info, derivatives if owing else (*derivatives, None)

    def chain(jac, derivatives, mf, first):
        jy, jdt, jdw, jp, jo = jac
        a, b, c, e, o = derivatives
        a = a.reshape(d, d)
        # (h, w) = (dt/m, dW/m): d/d(dt) = (d/dh) / m; the debt: the step's `pending` at
        # the first substep of an attempt, dt/2m after it
        o = None if o is None else o.reshape(d)
        return (
            a @ jy,
            a @ jdt
            + b.reshape(d) / mf
            + (0.0 if o is None else jnp.where(first, 0.0, o / (2 * mf))),
            a @ jdw + c.reshape(d, -1) / mf,
            [a @ j + ei.reshape(d, -1) for j, ei in zip(jp, e)],
            None if o is None else a @ jo + jnp.where(first, o, 0.0),
        )

    j0 = (
        jnp.eye(d, dtype=dtype),
        jnp.zeros(d, dtype),
        jnp.zeros((d, w0.size), dtype),
        [jnp.zeros((d, _real(p).size), dtype) for p in p0],
        None if pending is None else jnp.zeros(d, dtype),
    )
    return substep, j0, chain


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 6))
def robust_step(method, system, y, dt, dW, act, k, history=(), pending=None):
    """One step of one sample where `act`, redone as `k, k^2, k^3` substeps if it fails.
    **Returns** `(y_next, code, iterations, residual, retried, first, history, pending)`
    (see `_attempts`; `pending`: what `y_next` owes of the linear flow, `None` without).
    The method's history is data, not a variable: no derivative flows through it (it only
    starts an iteration whose root does not depend on the start)."""
    out = _attempts(method, system, y, dt, dW, act, k, 1, history, pending=pending)
    return (*out[:7], out[8])


@robust_step.defjvp
def _robust_step_jvp(method, k, primals, tangents):
    system, y, dt, dW, act, history, pending = primals
    t_model, t_y, t_dt, t_dW, _, _, t_pending = tangents
    dtype = real_dtype(y.dtype)
    h, w = jnp.where(act, dt, 0.0).astype(dtype), _brownian.where(act, dW)
    (y1, info), (t_y1, _) = jax.jvp(
        lambda mdl, ys, h, w, owed: step_with_history(method, mdl, ys, h, w, history, owed),
        (system, y, h, w, pending),
        (t_model, t_y, jnp.where(act, t_dt, 0.0), _brownian.where(act, t_dW), t_pending),
    )
    code1 = finite_result(y1, info.result)
    need = act & (code1 != RESULTS.successful)
    # Retried samples: the attempts again (a loop that runs only while some sample of the
    # batch needs it), now with the Jacobians of the substeps that succeed.
    y2, code2, its2, res2, _, _, _, jacobians, owed2, m2 = _attempts(
        method, system, y, dt, dW, need, k, k, history, jacobians=True, pending=pending
    )
    jy, jdt, jdw, jp, jo = cast(tuple, jacobians)
    leaves, idx = differentiable_leaves(t_model)[0], differentiable_leaves(system)[2]
    t_re = jy @ _real(t_y) + jdt * t_dt + jdw @ ravel_pytree(t_dW)[0]
    for i, j in zip(idx, jp):
        t_re = t_re + j @ _real(leaves[i]).astype(dtype)
    if pending is not None:  # (the debt: the step's, then half of a substep)
        t_re = t_re + jo * t_pending
        owed = jnp.where(need, cast(jax.Array, owed2), jnp.where(act, 0.5 * h, pending))
        t_owed = jnp.where(
            need, 0.5 * t_dt / m2.astype(dtype), jnp.where(act, 0.5 * t_dt, t_pending)
        )
    y_next = jnp.where(need, y2, y1)
    cold = method.initial_history(system, y)
    out = (
        y_next,
        jnp.where(need, code2, code1),
        jnp.where(act, info.iterations, 0) + its2,
        jnp.where(need, res2, jnp.where(act, info.residual, 0.0)).astype(dtype),
        need,
        jnp.where(act, code1, RESULTS.successful).astype(jnp.int32),
        jax.tree_util.tree_map(
            lambda new, old, c: jnp.where(need, c, jnp.where(act, new, old)),
            info.history,
            history,
            cold,
        ),
        None if pending is None else owed,
    )
    tangents = _zero_tangents(out[:-1], jnp.where(need, _unreal(t_re, y), t_y1))
    return out, (*tangents, None if pending is None else t_owed)


def _zero_tangents(out, t_y):
    """The tangents of `robust_step`'s outputs: `t_y` for the state, zero for the rest."""

    def zero(x):
        x = jnp.asarray(x)
        if jnp.issubdtype(x.dtype, jnp.inexact):
            return jnp.zeros_like(x)
        return jnp.zeros(x.shape, jax.dtypes.float0)

    return (t_y, *jax.tree_util.tree_map(zero, out[1:]))
