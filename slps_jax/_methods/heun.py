"""The stochastic Heun method, the standard explicit Stratonovich integrator."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .base import AbstractMethod, StrongOrders, explicit_info


class Heun(AbstractMethod):
    r"""The stochastic Heun method (explicit trapezoidal rule):

    $\tilde y = y_n + F_n(y_n)$, $y_{n+1} = y_n + \tfrac12(F_n(y_n) + F_n(\tilde y))$,
    $F_n(y) = y \times \nabla K_n(y)$, $K_n = hH_0 + \sum_r \Delta W_{r,n} H_r$.

    Consistent with the Stratonovich equation (strong order 1 for one noise or commuting
    noises, 1/2 otherwise; weak order 1) and the usual baseline of SDE libraries (diffrax's
    `Heun`), but not a Poisson map: $|y|$ drifts. Two evaluations of the fields per step.
    Works for any system.

    **Reference:** P. E. Kloeden & E. Platen, *Numerical Solution of Stochastic Differential
    Equations* (1992); W. Rümelin, SIAM J. Numer. Anal. 19 (1982).
    """

    strong_orders = StrongOrders(one=1.0, increments=0.5)

    def step(self, system, y, dt, dW):
        alg = system.algebra
        tmap = jax.tree_util.tree_map

        def f(x):
            return system.local_field(x, dt, dW)

        x = alg.local(y)  # (components on so(3))
        k1 = f(x)
        k2 = f(tmap(jnp.add, x, k1))
        x_next = tmap(lambda a, b, c: a + 0.5 * (b + c), x, k1, k2)
        y_next = alg.from_local(x_next).astype(y.dtype)
        return y_next, explicit_info(y_next)
