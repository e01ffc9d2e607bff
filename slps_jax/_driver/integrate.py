"""The driver: one `lax.scan` over time steps, `vmap`ped over samples."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import _brownian
from .._methods.base import AbstractMethod, finite_result
from .._support.batching import batched_like
from .._support.checks import (
    check_positive,
    check_save_every,
    concrete,
    real_array,
    real_dtype,
)
from .._support.solution import RESULTS, Solution
from .failures import Failures, check_failures, report, report_retries
from .plan import (
    check_levy_area,
    check_method,
    check_system,
    check_y0,
    plan_ensemble,
)
from .retry import robust_step, step_with_history
from .sharding import as_given, automatic, sharded_keys
from .splitting import apply_pending, has_linear_terms


def _highest_precision(fn):
    """`fn` traced with JAX's matrix products at `precision="highest"`: on a GPU the
    default for float32 and complex64 is TF32 (a relative error of 3e-4 in a product),
    which would break the Casimirs in single precision; on the CPU and in float64 it is
    what runs anyway."""

    @functools.wraps(fn)
    def traced(*args, **kwargs):
        with jax.default_matmul_precision("highest"):
            return fn(*args, **kwargs)

    return traced


@functools.partial(jax.jit, static_argnames=("method", "want_stats", "retry"))
@_highest_precision
def _step(method, system, dt, carry, dW, live, *, want_stats, retry):
    """One step of one sample, with the failure bookkeeping of `_path`. `carry = (the
    sample's carry, pending)`, `pending` the linear flow its state owes (`system_step`:
    consecutive steps of a system with linear terms join their half flows), or `None`.

    `live = False` marks a padding slot of the loop layout (`_layout`): the sample idles
    there like a failed one (no state change, no step counted, no failure).

    A jitted function of its own, so that it is traced once per method, dtype and options
    and reused (studies call `_path` once per step size), and `vmap` batches the cached
    jaxpr once. Tracing LiePoisson's solver takes over a second
    (thousands of scalar operations); XLA inlines the call, so the compiled loop is unchanged.
    """
    (y, result, fail_step, n, n_retried, acc, history), pending = carry
    dtype = real_dtype(y.dtype)
    live = jnp.asarray(live)  # (a Python bool under jax.disable_jit)
    act = (result == RESULTS.successful) & live
    if retry is None or not method.can_fail:
        # A failed sample idles at its last good state: with dt = dW = 0 every method's
        # step is trivial, so it costs no Newton iterations.
        h = jnp.where(act, dt, 0.0).astype(dtype)
        y_new, info = step_with_history(
            method, system, y, h, _brownian.where(act, dW), history, pending
        )
        code = finite_result(y_new, info.result)
        it = jnp.where(act, info.iterations, 0)
        res = jnp.where(act & (code == RESULTS.successful), info.residual, 0.0)
        first, new_history = info.result, info.history
        owed = None if pending is None else 0.5 * h
    else:
        y_new, code, it, res, retried, first, new_history, owed = robust_step(
            method, system, y, dt, dW, act, retry, history, pending
        )
        n_retried = n_retried + retried.astype(jnp.int32)
    ok = code == RESULTS.successful
    fail_step = jnp.where(act & ~ok, n, fail_step)
    result = jnp.where(act & ~ok, code, result)
    if want_stats:  # (updates, most updates, largest residual, steps that used max_iter)
        at_max = act & (first == RESULTS.max_iterations_reached)
        acc = (
            acc[0] + it,
            jnp.maximum(acc[1], it),
            jnp.maximum(acc[2], res),
            acc[3] + at_max.astype(jnp.int32),
        )
    y = jnp.where(act & ok, y_new, y)
    history, pending = jax.tree_util.tree_map(
        lambda new, old: jnp.where(act & ok, new, old), (new_history, owed), (history, pending)
    )
    return (y, result, fail_step, n + live.astype(n.dtype), n_retried, acc, history), pending


def _path(method, system, y0, dt, draws, n_blocks, block_len, want_stats, retry=None, like=()):
    """Integrate one sample: `n_blocks` blocks of `block_len` steps, saving after each block.

    `draws` is the sample's noise (`_brownian.AbstractDraws`: a Brownian path's, drawn by step
    index; an Ornstein–Uhlenbeck path's, carrying its traces; or given increments). With a
    Python-int `block_len` the time loop is a `lax.scan` (reverse-mode differentiable,
    checkpointed: see `_checkpointed_loop`); with a traced one it is a `while_loop`, so one
    compilation serves every step count
    (convergence studies). With `retry = k`, a step that fails is redone as `k`, then
    `k^2`, ... equal substeps (`_retry_step`, a `while_loop`: no reverse mode) before the
    sample is given up.

    `like`: the arrays that tell the sample apart (its key, or its `y0` and increments): the
    loop's carry starts batched where they are (`_support.batching`).

    Returns the saved states `(n_blocks, *state_shape)`, the step of failure (-1 if none), the number
    of retried steps, and the Newton statistics `(iterations sum, iterations max, residual
    max)` or `()`.
    """
    if method.flow_in_time is not None:
        acc0 = _initial_stats(y0, want_stats)
        return _time_change_path(method, system, y0, dt, draws, n_blocks, block_len, acc0, like)
    carry0 = initial_carry(method, system, y0, draws, want_stats, like)
    ((_, result, fail_step, _, n_retried, acc, _), _), ys = run_blocks(
        method, system, dt, draws, carry0, n_blocks, block_len, want_stats, retry
    )
    return ys, fail_step, result, n_retried, acc


def _initial_stats(y0, want_stats):
    """The Newton statistics before any step: `(updates, most updates, largest residual,
    steps at max_iter)`, or `()`."""
    zero, zero_i = jnp.zeros((), real_dtype(y0.dtype)), jnp.zeros((), jnp.int32)
    return (zero, zero_i, zero, zero_i) if want_stats else ()


def initial_carry(method, system, y0, draws, want_stats, like=()):
    """The time loop's carry before the first step of one sample (`run_blocks`): `((y,
    result, fail_step, step, n_retried, stats, the method's history), the driver's state)`.
    The step counter stays unbatched: every sample is at the same step."""
    y0, result0, fail0, n_retried0, acc0, history0 = batched_like(
        (
            y0,
            jnp.array(RESULTS.successful, jnp.int32),
            jnp.array(-1, jnp.int32),
            jnp.array(0, jnp.int32),
            _initial_stats(y0, want_stats),
            method.initial_history(system, y0),
        ),
        like,
    )
    return (y0, result0, fail0, jnp.array(0, jnp.int32), n_retried0, acc0, history0), draws.init


def run_blocks(method, system, dt, draws, carry0, n_blocks, block_len, want_stats, retry):
    """`n_blocks` blocks of `block_len` steps of one sample from `carry0` (`initial_carry`,
    or the carry a previous call returned: the loop goes on from its step counter, the
    increments drawn by absolute step, so a run cut into calls is the run in one).

    **Returns:** `(carry, states after each block)`."""

    def steps(carry, length, n_live):
        # `length` (a Python int) slots from the carry's step counter, the first `n_live`
        # of them steps, their increments drawn first as one vector. Drawing inside the
        # step instead lets XLA's CPU backend fuse the random-number generator into the
        # method's arithmetic, which it then re-evaluates many times over (Strang in
        # `simulate`: 150x slower).
        # A system with linear terms: the steps of the block join their half linear flows
        # (`system_step`'s `pending`), settled at its end, so that a state leaves the block
        # whole (`apply_pending`).
        inner, state = carry
        state, dWs = draws.block(state, inner[3], length, n_live)
        y = inner[0]
        pending = jnp.zeros_like(jnp.real(y[(0,) * y.ndim])) if has_linear_terms(system) else None
        inner, pending = jax.lax.fori_loop(
            0,
            length,
            lambda i, c: _step(
                method,
                system,
                dt,
                c,
                _index(dWs, i),
                i < n_live,
                want_stats=want_stats,
                retry=retry,
            ),
            (inner, pending),
        )
        if pending is not None:
            inner = (apply_pending(system, inner[0], pending), *inner[1:])
        return inner, state

    def block(carry, _):
        carry = _checkpointed_loop(steps, block_len, carry)
        return carry, carry[0][0]

    return jax.lax.scan(block, carry0, None, length=n_blocks)


def _time_change_path(method, system, y0, dt, draws, n_blocks, block_len, acc0, like):
    """`_path` for a method whose steps compose in time (`flow_in_time`): the step with
    increments `(h, dW)` is the flow for the random time `h + c dW`, so between two saved
    states only the sum of the step times is needed. The loop draws the same increments
    and adds up the times; the flow is evaluated once per saved state (once in all for the
    final state only). It cannot fail (explicit), so the failure outputs are constant."""
    tau0 = batched_like(jnp.zeros((), y0.dtype), like)  # (built once, outside the loops)
    state0 = draws.init

    def steps(carry, length, n_live):
        tau, n0, state = carry
        state, dWs = draws.block(state, n0, length, n_live)
        times = jax.vmap(lambda w: dt + system.noise_time(w))(dWs)
        live = jnp.arange(length) < n_live
        n = n0 + jnp.minimum(length, n_live)
        return tau + jnp.sum(jnp.where(live, times, 0.0)), n, state

    def block(carry, _):
        y, n, state = carry
        tau, n, state = _checkpointed_loop(steps, block_len, (tau0, n, state))
        y = method.flow_in_time(system, y, tau).astype(y.dtype)
        return (y, n, state), y

    _, ys = jax.lax.scan(block, (y0, jnp.array(0, jnp.int32), state0), None, length=n_blocks)
    return (
        ys,
        jnp.array(-1, jnp.int32),
        jnp.array(RESULTS.successful, jnp.int32),
        jnp.array(0, jnp.int32),
        acc0,
    )


_DRAW_BLOCK = 32  # most steps whose increments are drawn together (memory per sample)


@functools.cache
def _layout(n):
    """`(n_chunks, m, b)`: `n` steps as `n_chunks` chunks of `m` draw blocks of `b` steps.

    The slots `n_chunks m b >= n` are as few as the constraints allow (usually exactly
    `n`); the steps fill the first `n` slots and the rest are padding (`_step`'s `live`).
    A draw block holds at most `_DRAW_BLOCK` steps (its increments are held in memory) and at
    least half that; a chunk holds about `sqrt(n)` steps, the unit of reverse-mode
    checkpointing (`_checkpointed_loop`). One layout, not a main loop and a remainder loop,
    keeps a single copy of the step in the compiled program: LiePoisson's step takes
    seconds to compile.
    """
    if n <= _DRAW_BLOCK:
        return 1, 1, n
    root = math.sqrt(n)
    best = None
    for b in range(_DRAW_BLOCK // 2, _DRAW_BLOCK + 1):
        for m in range(max(1, math.floor(root / (2 * b))), math.ceil(2 * root / b) + 1):
            n_chunks = -(-n // (m * b))
            # fewest slots; then the larger draw block (the same memory at every n that
            # allows it); then chunks closest to sqrt(n)
            key = (n_chunks * m * b - n, -b, abs(math.log(m * b / root)))
            if best is None or key < best[0]:
                best = key, (n_chunks, m, b)
    assert best is not None
    return best[1]


def _checkpointed_loop(steps, n, carry):
    """`n` steps arranged so that reverse mode stores O(sqrt n) carries.

    With a Python-int `n` the loop runs as chunks of about `sqrt(n)` steps (`_layout`), each
    under `jax.checkpoint`: the backward pass keeps the carry at chunk boundaries and
    recomputes one chunk at a time, so the memory of `jax.grad` grows like `sqrt(n_steps)`,
    not `n_steps`. Without differentiation this is the plain loop. A traced `n` (one
    compilation for every step count) gives a `while_loop` over draw blocks of
    `_DRAW_BLOCK` slots, the last one padded, which has no reverse mode.
    `steps(carry, length, n_live)` runs `length` slots of which the first `n_live` are steps.
    """
    if not isinstance(n, int):
        n_blocks = (n + _DRAW_BLOCK - 1) // _DRAW_BLOCK
        return jax.lax.fori_loop(
            0, n_blocks, lambda k, c: steps(c, _DRAW_BLOCK, n - k * _DRAW_BLOCK), carry
        )
    n_chunks, m, b = _layout(n)

    def chunk(i, c):
        return jax.lax.fori_loop(0, m, lambda k, c: steps(c, b, n - (i * m + k) * b), c)

    if n_chunks == 1:
        return chunk(0, carry)
    return jax.lax.fori_loop(0, n_chunks, jax.checkpoint(chunk, prevent_cse=False), carry)


def _index(dWs, i):
    """Step `i` of a block of steps' noises."""
    return jax.tree_util.tree_map(lambda x: x[i], dWs)


@functools.partial(jax.jit, static_argnames=("method", "save_every", "want_stats", "retry"))
def path_of_noise(method, system, y0, dWs, dt, save_every, want_stats, retry=None):
    """One sample's path for given increments, jitted: the driver's loop under `integrate`, and the
    documented door to it for the other subpackages (the filter's forecasts, the
    verification's reruns). `dWs` is a `BrownianStep` with one row per step (areas or
    `None`); `save_every` divides the number of steps; `want_stats` adds the Newton
    statistics; `retry` is `check_retry`'s.

    **Returns:** `(ys, fail_step, result, n_retried, stats)` as `_path` gives them: the saved
    states, the step of failure (-1 if none), its `RESULTS` code, the retried steps and the
    Newton statistics (`()` without `want_stats`)."""
    return _path(
        method,
        system,
        y0,
        dt,
        _brownian.IndexedDraws(lambda n: _index(dWs, n)),
        dWs.dW.shape[0] // save_every,
        save_every,
        want_stats,
        retry,
        like=(y0, dWs),
    )


def ensemble(method, system, y0, keys, path, n_blocks, block_len, want_stats, retry=None):
    """Each sample asks the Brownian path (`_brownian.BrownianPath`) for its steps' noise, from
    its key; the driver's step is `path.dt`."""

    def one(key):
        return _path(
            method,
            system,
            y0,
            path.dt,
            path.draws(key),
            n_blocks,
            block_len,
            want_stats,
            retry,
            like=jax.random.key_data(key),
        )

    return jax.vmap(one)(keys)


ensemble_jit = jax.jit(
    ensemble, static_argnames=("method", "n_blocks", "block_len", "want_stats", "retry")
)
# Step count traced (and the path's fine steps): one compilation for every step size of a study.
ensemble_dynamic_jit = jax.jit(
    ensemble, static_argnames=("method", "n_blocks", "want_stats", "retry")
)


# --------------------------------------------------------------------------------------
# Public API.


def integrate(
    system,
    y0,
    dW,
    dt,
    *,
    areas=None,
    method: AbstractMethod | str = "auto",
    save_every=None,
    failures: Failures = Failures(throw=True),
):
    r"""Integrate one path of a stochastic Lie–Poisson system,
    $dy = [y, \nabla H_0]\,dt + \sum_r [y, \nabla H_r]\circ dW_r$ (with `c=`,
    $dy = f(y)(dt + c\circ dW)$), with the given increments.

    Uses `dW` exactly as given (no truncation). Works under `jax.jit`, `jax.vmap` and
    `jax.grad` (a failure then raises through a callback, or with `Failures(throw=False)` not).

    **Arguments:**

    - `system`: a `RigidBody` or a `LiePoissonSystem`; its dtype is the computation's (`y0`,
      `dW` are cast to it).
    - `y0`: initial value, shape `(3,)` (so(3)*), a skew `(n, n)` matrix (so(n)*), or a
      traceless skew-Hermitian complex `(N, N)` matrix (su(N)*, `EulerZeitlin`).
    - `dW`: Brownian increments, shape `(n_steps, n_noises)` (one column per noise;
      `(n_steps,)` for a system with one noise).
    - `dt`: the step size.
    - `areas`: `None` (default), or the Lévy areas of the steps, shape
      `(n_steps, s, s)`, antisymmetric: `A[n, q, r]` $= \tfrac12(J_{qr} - J_{rq})$,
      $J_{qr} = \int_{t_n}^{t_{n+1}} (W_q(t) - W_q(t_n)) \circ dW_r(t)$
      (`BrownianMotion().increments(..., levy_area=True)` draws them). With them a method that
      `uses_levy_area` has strong order 1 for several non-commuting noises; refused for
      one that does not.
    - `method`: a method instance, or `"auto"` (default): `Midpoint()` on so(3)*,
      `IsospectralMidpoint()` on so(n)* and su(N)* (`default_method`; `LiePoisson()` is
      the paper's scheme (42)).
    - `save_every`: `None` for the final state only; `k` for the states at steps
      `0, k, 2k, ..., n_steps` (`k` must divide `n_steps`).
    - `failures`: a `Failures`; here by default `Failures(throw=True)`: a step that fails
      is redone as 4, 16, then 64 substeps of `(dt, dW)`, and if it still fails,
      `RuntimeError` quotes the reason (a `RESULTS` message). With `throw=False` a failed
      path is frozen at its last good state. Differentiable (forward and reverse mode)
      through retried steps too.

    **Returns:** the final state (the shape of `y0`), or `(n_steps // save_every + 1, *y0.shape)`.
    """
    check_system(system)
    method = check_method(method, system)
    failures = check_failures("integrate", failures)
    y0 = check_y0(y0, method, system)
    dW = real_array("dW", dW)
    s = system.n_noises
    if dW.ndim == 1 and s == 1:
        dW = dW[:, None]
    if dW.ndim != 2 or dW.shape[0] < 1 or dW.shape[1] != s:
        raise ValueError(
            f"dW must have shape (n_steps, {s}) (one column per noise"
            + ("; (n_steps,) for one noise" if s == 1 else "")
            + f"), got shape {dW.shape}"
            + ("; for several paths use jax.vmap over integrate." if dW.ndim >= 2 else ".")
        )
    dt_np = check_positive("dt", dt)
    dW_np = concrete(dW)
    if dW_np is not None and not np.all(np.isfinite(dW_np)):
        bad = np.flatnonzero(~np.all(np.isfinite(dW_np), axis=1))
        raise ValueError(f"dW must be finite; entries {bad[:5].tolist()} are not.")
    n_steps = dW.shape[0]
    area = check_levy_area(areas, n_steps, s, method)
    k = check_save_every(save_every, n_steps)
    retry = failures.retry_substeps
    dtype = real_dtype(y0.dtype)
    dt = jnp.asarray(dt if dt_np is None else float(dt_np), dtype)
    dWs = _brownian.BrownianStep(dW.astype(dtype), None if area is None else area.astype(dtype))
    ys, fail_step, result, _, _ = path_of_noise(method, system, y0, dWs, dt, k, False, retry)
    if failures.throw:
        report("integrate", True, failures.retried, fail_step, result)
    if save_every is None:
        return ys[-1]
    return jnp.concatenate([y0[None], ys], axis=0)


def simulate(
    system,
    y0,
    *,
    t1,
    dt,
    n_samples,
    key,
    method: AbstractMethod | str = "auto",
    save_every=None,
    newton_stats=False,
    failures: Failures = Failures(),
    sharding=None,
    driver: _brownian.BrownianMotion | _brownian.OrnsteinUhlenbeck | None = None,
):
    r"""Simulate an ensemble of paths of a stochastic Lie–Poisson system on $[0, t_1]$,
    $dy = [y, \nabla H_0]\,dt + \sum_r [y, \nabla H_r]\circ dW_r$ (with `c=`,
    $dy = f(y)(dt + c\circ dW)$).

    Sample `i` draws its increments from `fold_in(key, i)` inside the time loop (by
    default Brownian increments truncated as
    $\Delta\hat W = \sqrt h\,\mathrm{clip}(\xi, \pm\sqrt{2k|\ln h|})$, Milstein, Repin &
    Tretyakov 2002: `driver`). Nothing of size `n_steps` is stored when only the final state is saved,
    and a sample's path does not depend on `n_samples`.

    **Arguments:**

    - `system`: a `RigidBody` or a `LiePoissonSystem`, whose dtype is the computation's;
      `y0`: the initial value (`(3,)` on so(3)*, `(n, n)` skew on so(n)*, `(N, N)`
      traceless skew-Hermitian complex on su(N)*), shared by all samples
      (cast to the system's dtype).
    - `t1`: final time, a multiple of `dt`; `dt`: step size.
    - `n_samples`: number of Brownian samples; `key`: a `jax.random.key` (a legacy
      `jax.random.PRNGKey`, `uint32[2]`, is accepted too; a plain integer is not).
    - `method`: as for `integrate` (default `"auto"`).
    - `save_every`: `None` (final state only) or `k` (states at steps `0, k, ..., n`).
    - `newton_stats`: also report Newton iteration counts and residuals in `stats`.
    - `failures`: a `Failures` (default `Failures()`): a step that fails is redone as 4,
      16, then 64 substeps before the sample is given up; a sample that still failed is
      returned flagged (`Solution.ok`, `result`: a `RESULTS` code per sample,
      `fail_step`) and a `RuntimeWarning` says how many failed, why and where
      (`Failures(throw=True)`: `RuntimeError` instead).
    - `sharding`: `None` (default), `"auto"` (the context mesh of `jax.set_mesh` when one
      is set, else all local devices, when there are several), or a
      `jax.sharding.Sharding` of the sample axis, such as
      `NamedSharding(jax.make_mesh((jax.device_count(),), ("samples",)),
      PartitionSpec("samples"))`; the mesh's axes may be explicit (`jax.make_mesh`'s
      default) or automatic. The samples are split over the devices by JAX's SPMD
      partitioner and the arrays of the `Solution` come back sharded along their first
      axis, on the given mesh; the paths are the same as without. `n_samples` must be a
      multiple of the number of shards.
    - `driver`: what draws the steps' noise. `None` (default) or `sj.BrownianMotion(...)`:
      Brownian motions, with its options `truncate_k` (the `k` of the truncation, default 4,
      the paper's; `None` for none) and `levy_area` (`"auto"`, the default: each step's
      Lévy areas drawn for a method that `uses_levy_area` when the system has several
      noises, which makes such a method strong order 1 for non-commuting noise; `True`,
      `False`). `sj.OrnsteinUhlenbeck(T)`: smooth unit Ornstein–Uhlenbeck traces of
      correlation times `T` (one per noise), each step's increment their integral over the
      step, drawn exactly (no truncation, no Lévy areas; `sj.OrnsteinUhlenbeck(T).increments`
      gives the same increments for `integrate`).

    **Returns:** a `Solution`.
    """
    p = plan_ensemble(
        "simulate",
        system,
        y0,
        t1=t1,
        dt=dt,
        n_samples=n_samples,
        key=key,
        method=method,
        save_every=save_every,
        failures=failures,
        sharding=sharding,
        driver=driver,
    )
    sol = run_ensemble(p, newton_stats=newton_stats, saved=save_every is not None)
    report("simulate", p.failures.throw, p.failures.retried, sol.fail_step, sol.result)
    report_retries("simulate", sol, p.system, p.y0, p.dt, p.n_steps)
    return sol


def run_ensemble(p, *, newton_stats, saved):
    """The ensemble of a checked plan (`plan_ensemble`) as a `Solution`, without the failure
    report (`simulate`, and `calibrate`, which reports failures its own way); `saved`: the
    states at every `p.save_every` steps, not only the final ones."""
    system = p.system
    method, y0, dt, n_steps, k, dtype = p.method, p.y0, p.dt, p.n_steps, p.save_every, p.dtype
    with automatic(p.sharding, (system, y0, p.key)) as (sharding, (system, y0, key)):
        keys = (
            _brownian.sample_keys(key, p.n_samples)
            if sharding is None
            else sharded_keys(key, p.n_samples, sharding)
        )
        ys, fail_step, result, n_retried, acc = ensemble_jit(
            method,
            system,
            y0,
            keys,
            p.path,
            n_steps // k,
            k,
            bool(newton_stats),
            retry=p.retry,
        )
        sol = _solution(
            y0,
            ys,
            fail_step,
            result,
            n_retried,
            acc,
            jnp.asarray(dt, dtype),
            jnp.asarray([n_steps * dt], dtype),
            n_steps=n_steps,
            save_every=k if saved else None,
            retried=p.retry is not None,
            newton_stats=bool(newton_stats),
        )
    return as_given(sol, p.sharding)


@functools.partial(jax.jit, static_argnames=("n_steps", "save_every", "retried", "newton_stats"))
def _solution(
    y0, ys, fail_step, result, n_retried, acc, dt, t1, *, n_steps, save_every, retried, newton_stats
):
    """`simulate`'s `Solution` from the ensemble's outputs: one program, not one for each of
    these operations at every new shape."""
    if save_every is None:
        ts = t1
    else:
        ys = jnp.concatenate([jnp.broadcast_to(y0, (ys.shape[0], 1, *y0.shape)), ys], axis=1)
        ts = jnp.arange(0, n_steps + 1, save_every, dtype=dt.dtype) * dt
    stats = {"n_failed": jnp.sum(fail_step >= 0)}
    if retried:
        stats["n_retried_steps"] = jnp.sum(n_retried)
    if newton_stats:
        stats["newton_iterations_mean"] = jnp.sum(acc[0]) / (fail_step.shape[0] * n_steps)
        stats["newton_iterations_max"] = jnp.max(acc[1])
        stats["residual_max"] = jnp.max(acc[2])
        stats["max_iter_share"] = jnp.sum(acc[3]) / (fail_step.shape[0] * n_steps)
    return Solution(ts=ts, ys=ys, result=result.astype(jnp.int8), fail_step=fail_step, stats=stats)
