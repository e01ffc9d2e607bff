r"""The flow of a system's drift, $\varphi_t(y_0)$, and through it the exact solution
$y(t) = \varphi_{t + cW(t)}(y_0)$ of a system whose one noise is proportional to the drift."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._support.checks import check_positive, concrete, numeric_array, real_array
from .capabilities import NOISE_PROPORTIONAL_TO_DRIFT, RIGID_BODY
from .elliptic_flow import _check_real, rigid_body_flow
from .system import check_system


@functools.partial(jax.jit, static_argnames=("n_steps",))
def _rk4(system, y0, times, n_steps):
    f = system.vector_field

    def one(t):
        h = t / n_steps

        def step(_, y):
            k1 = f(y)
            k2 = f(y + 0.5 * h * k1)
            k3 = f(y + 0.5 * h * k2)
            k4 = f(y + h * k3)
            return y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

        return jax.lax.fori_loop(0, n_steps, step, y0)

    return jax.vmap(one)(times)


def _runge_kutta_flow(system, y0, times, max_step):
    """The drift's flow by classical Runge–Kutta, at most `max_step` per step."""
    check_system(system)
    check_positive("max_step", max_step)
    alg = system.algebra
    y0 = numeric_array("y0", y0, alg.is_complex).astype(alg.state_dtype(system.dtype))
    y_np = concrete(y0)
    if y_np is not None:
        alg.validate("y0", y_np)
    times_np = concrete(real_array("times", times))
    if times_np is None:
        raise TypeError(
            "drift_flow needs concrete times for a system without a closed-form flow (the "
            "number of Runge–Kutta steps depends on them): call it outside jax.jit."
        )
    times = np.asarray(times_np, np.float64)
    if not np.all(np.isfinite(times)):
        raise ValueError("times must be finite.")
    n_steps = max(1, math.ceil(float(np.max(np.abs(times), initial=0.0)) / float(max_step)))
    flat = jnp.asarray(times.ravel(), system.dtype)
    return _rk4(system, y0, flat, n_steps).reshape(times.shape + y0.shape)


def drift_flow(system, y0, times, *, max_step=2.0**-10):
    r"""$\varphi_t(y_0)$, the flow of the drift $\dot y = B(y)\nabla H_0(y)$, at each of
    `times` (negative times run it backwards).

    - A `RigidBody` (any noise): the free rigid body's exact flow in closed form, with
      Jacobi elliptic functions (Celledoni, Fassò, Säfström & Zanna 2008). It works under
      `jit`, `vmap` and `grad` (in `y0`, `times` and `inertia`, finite everywhere); its error
      is round-off times the flow's conditioning, which grows like $t/(1-m)$ towards the
      separatrix: measured ~1e-15 relative off it, ~3e-11 at relative distance 1e-6
      (float64, $|t| \le 50$), ~1e-5 in float32.
    - Any other system: classical Runge–Kutta with at most `max_step` per step (the same
      number of steps for every time, so the largest `|t|` sets it; the times must be
      concrete). Its error is $O(\text{max\_step}^4)$, about 1e-13 for the default on $O(1)$
      states and times of a few units (a test compares it with the rigid body's closed
      form). It does not keep the Casimirs exactly; it need not.

    With one noise proportional to the drift (`c=`) the solution is a time change of this
    flow, $y(t) = \varphi_{t + cW(t)}(y_0)$ (`exact_solution`), the reference of
    `strong_convergence(..., reference="exact")` and the `Exact` method.

    **Arguments:** `system` (any system), `y0` (a state), `times` (a time or an array of
    times, any shape), `max_step` (a positive number: the Runge–Kutta step).

    **Returns:** the states, shape `times.shape + y0.shape`.
    """
    check_system(system)
    if not RIGID_BODY(system):
        return _runge_kutta_flow(system, y0, times, max_step)
    times = real_array("times", times)
    t_np = concrete(times)
    if t_np is not None and not np.all(np.isfinite(t_np)):
        raise ValueError("times must be finite.")
    _check_real("y0", y0, (3,), "; use jax.vmap for a batch of initial values")
    flat = jnp.ravel(times)
    ys = jax.vmap(lambda t: rigid_body_flow(system, y0, t))(flat)
    return ys.reshape(times.shape + ys.shape[1:])


def exact_solution(system, y0, t, W_t):
    r"""The exact solution of a system whose one noise is proportional to the drift,

    $$dy = B(y)\nabla H_0(y)\,(dt + c \circ dW_t):$$

    the noise multiplying the drift's own vector field, it is the drift's flow run to the
    random time $t + c W_t$: $y(t) = \varphi_{t + c W_t}(y_0)$ (`drift_flow`: in closed form
    for the rigid body, by Runge–Kutta otherwise).

    **Arguments:**

    - `system`: a system with `c=` (one noise proportional to the drift), e.g. a
        `RigidBody(inertia, c)`.
    - `y0`: the initial value, a state.
    - `t`: the time, a scalar.
    - `W_t`: the Brownian motion at time `t` (started at 0), a scalar.

    **Returns:** $y(t)$, the shape of `y0`. Use `jax.vmap` for several paths (the rigid body;
    other systems take arrays of times in `drift_flow`).
    """
    check_system(system)
    if not NOISE_PROPORTIONAL_TO_DRIFT(system):
        raise ValueError(
            "exact_solution needs a system with one noise proportional to the drift (c=); "
            "this one has noises of its own (noise=): it has no time-change solution."
        )
    t = _check_real("t", t, (), "; use jax.vmap for several times")
    W_t = _check_real("W_t", W_t, (), "; use jax.vmap for several paths")
    return drift_flow(system, y0, t + system.c * W_t)
