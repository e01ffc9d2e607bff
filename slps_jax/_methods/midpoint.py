"""The implicit midpoint rule, the paper's reference integrator."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._support.checks import check_options, real_dtype
from .._support.solution import RESULTS
from .base import AbstractMethod, StepInfo, StrongOrders, default_tol, finite_result
from .newton import identity_plus, implicit_root, jacobian_mode, newton


class Midpoint(AbstractMethod):
    r"""The implicit midpoint rule $y_{n+1} = y_n + F_n(\tfrac12(y_n + y_{n+1}))$ with
    $F_n(y) = y \times \nabla K_n(y)$, $K_n = hH_0 + \sum_r \Delta W_{r,n} H_r$ (for one noise
    $H_1 = cH_0$: $F_n = \tau f$, $\tau = h + c\Delta W_n$).

    Symmetric; with one noise proportional to the drift it has deterministic order 2, hence
    strong order 1; with several non-commuting noises strong order 1/2, weak order 1. It
    conserves every quadratic invariant, here $|y|^2$ and (with one noise, for the rigid body)
    $H$, up to the solver tolerance. Solved by Newton's method from the explicit Euler
    predictor, with the Jacobian $\mathrm{Id} - \tfrac12 F_n'(m)$,
    $F_n'(m) = \hat m\, \nabla^2 K_n(m) - \widehat{\nabla K_n(m)}$: from the system (analytic
    for the `RigidBody` and the noise families, by autodiff of a Hamiltonian function).
    Works for any system. On so(n) ($F_n(Y) = [Y, \nabla K_n(Y)]$) it keeps
    $\operatorname{tr}Y^2$ (quadratic) but not the higher Casimirs $\operatorname{tr}Y^{2k}$,
    $k \ge 2$: what `IsospectralMidpoint` is for. There it is solved on the `n(n-1)/2`
    entries, by Newton (Jacobian by autodiff) up to so(5), by fixed-point iteration above.

    **Arguments:** `tol` (default `64 eps`), `max_iter` (default `None`: 12; on so(n) above
    so(5), where the fixed-point iteration $Y_{n+1} = Y_n + F_n(M)$ replaces Newton, 48).
    """

    strong_orders = StrongOrders(one=1.0, increments=0.5, areas=1.0)
    poisson = True

    tol: float | None = eqx.field(default=None, static=True)
    max_iter: int | None = eqx.field(default=None, static=True)

    def __post_init__(self):
        check_options(self)

    def step(self, system, y, dt, dW):
        alg = system.algebra
        tol = default_tol(y.dtype) if self.tol is None else self.tol
        # Newton with the field's Jacobian (written out on so(3), by autodiff otherwise) up to
        # so(5); above, the fixed-point iteration
        newton_mode = jacobian_mode("auto", alg.dim, large="identity") == "newton"
        max_iter = self.max_iter if self.max_iter is not None else (12 if newton_mode else 48)
        # The unknowns: the real coordinates of y_{n+1}'s local form (components on so(3),
        # the n(n-1)/2 entries on so(n)), and arithmetic that works on either.
        u0 = alg.local_coordinates(alg.local(y))
        tmap = jax.tree_util.tree_map

        def mid(u1):
            return tmap(lambda a, b: 0.5 * (a + b), u0, u1)

        def minus(u1, f):
            return tmap(lambda a, b, c: a - b - c, u1, u0, f)

        def residual(u1):
            return minus(u1, system.coordinate_field(mid(u1), dt, dW))

        def linearised(u1):
            f, jf = system.coordinate_field_jacobian(mid(u1), dt, dW)
            return minus(u1, f), identity_plus(-0.5, jf)

        def fixed_point(u1):
            return residual(u1), lambda r: r

        def solve():
            start = tmap(jnp.add, u0, system.coordinate_field(u0, dt, dW))
            s = newton(
                linearised if newton_mode else fixed_point, start, tol=tol, max_iter=max_iter
            )
            return s.x, s.result == RESULTS.successful, (s.result, s.iterations, s.residual)

        # Derivatives by the implicit function theorem at the root, not through Newton.
        u1, _, (result, it, res) = implicit_root(residual, solve, u0)
        y_next = alg.from_local(alg.from_local_coordinates(u1)).astype(y.dtype)
        return y_next, StepInfo(
            finite_result(y_next, result.astype(jnp.int32)),
            it.astype(jnp.int32),
            res.astype(real_dtype(y.dtype)),
        )
