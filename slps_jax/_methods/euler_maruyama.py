"""The paper's comparison method."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .base import AbstractMethod, StrongOrders, explicit_info


class EulerMaruyama(AbstractMethod):
    r"""$y_{n+1} = y_n + y_n \times \nabla K_n(y_n)$, $K_n = hH_0 + \sum_r \Delta W_{r,n} H_r$
    (for one noise $H_1 = cH_0$: $y_n + f(y_n)(h + c\Delta W_n)$), the paper's comparison
    method.

    Applied to the Stratonovich equation as written, it converges to the Itô equation with the
    same coefficients, not to the Stratonovich solution, and it does not conserve $|y|$.
    Works for any system.
    """

    strong_orders = StrongOrders(one=None, increments=None)  # converges to the Itô equation

    def step(self, system, y, dt, dW):
        alg = system.algebra
        x = alg.local(y)  # (components on so(3))
        x_next = jax.tree_util.tree_map(jnp.add, x, system.local_field(x, dt, dW))
        y_next = alg.from_local(x_next).astype(y.dtype)
        return y_next, explicit_info(y_next)
