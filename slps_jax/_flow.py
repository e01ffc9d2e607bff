"""The deterministic flow of a system's drift, for time-change references."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ._checks import check_positive, concrete, numeric_array, real_array
from ._system import check_model


@functools.partial(jax.jit, static_argnames=("n_steps",))
def _rk4(model, y0, times, n_steps):
    f = model.vector_field

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


def deterministic_flow(model, y0, times, *, max_step=2.0**-10):
    r"""$\varphi_t(y_0)$, the flow of the drift $\dot y = B(y)\nabla H_0(y)$, at each of
    `times` (negative times run it backwards).

    With one noise proportional to the drift (`c=`) the solution is a time change of this
    flow, $y(t) = \varphi_{t + cW(t)}(y_0)$, for any Hamiltonian and algebra: the reference
    `strong_convergence(..., reference="flow")` uses. Classical Runge–Kutta with at most
    `max_step` per step (the same number of steps for every time, so the largest `|t|`
    sets it): its error is $O(\text{max\_step}^4)$, about 1e-13 for the default on
    $O(1)$ states and times of a few units (a test compares it with the rigid body's exact
    elliptic flow). It does not keep the Casimirs exactly; it need not.

    **Arguments:** `model` (any system), `y0` (a state), `times` (an array of times, any
    shape), `max_step` (a positive number).

    **Returns:** the states, shape `times.shape + y0.shape`.
    """
    check_model(model)
    check_positive("max_step", max_step)
    alg = model.algebra
    y0 = numeric_array("y0", y0, alg.is_complex).astype(alg.state_dtype(model.dtype))
    y_np = concrete(y0)
    if y_np is not None:
        alg.validate("y0", y_np)
    times = np.asarray(real_array("times", times), np.float64)
    if not np.all(np.isfinite(times)):
        raise ValueError("times must be finite.")
    n_steps = max(1, math.ceil(float(np.max(np.abs(times), initial=0.0)) / float(max_step)))
    flat = jnp.asarray(times.ravel(), model.dtype)
    return _rk4(model, y0, flat, n_steps).reshape(times.shape + y0.shape)
