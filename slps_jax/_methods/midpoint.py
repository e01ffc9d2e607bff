"""The implicit midpoint rule, the paper's reference integrator."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from .. import _components as comp
from .._algebra import SO3_VECTORS
from .._checks import check_options, real_dtype
from .._newton import implicit_root, jacobian_mode, newton, solve_array
from .._solution import RESULTS
from .base import AbstractMethod, StepInfo, StrongOrders, default_tol, finite_result


@dataclasses.dataclass(frozen=True)
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

    tol: float | None = None
    max_iter: int | None = None

    def __post_init__(self):
        check_options(self)

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        if SO3_VECTORS not in model.structure:
            return self._step_coordinates(model, y, dt, dW, tol)
        # so(3)'s fast path: Newton on components with the analytic Jacobian
        y0 = comp.vec(y)

        def f(u):  # the step's increment field y x grad K(y), K = h H_0 + sum_r dW_r H_r
            return comp.cross(u, model.step_gradient_components(u, dt, dW))

        def residual(y1):
            m = comp.scale(0.5, comp.add(y0, y1))
            return tuple(a - b - c for a, b, c in zip(y1, y0, f(m)))

        def system(y1):
            m = comp.scale(0.5, comp.add(y0, y1))
            g, hess = model.step_gradient_hessian_components(m, dt, dW)
            r = tuple(a - b - c for a, b, c in zip(y1, y0, comp.cross(m, g)))
            fprime = comp.madd(comp.mm(comp.hat(m), hess), comp.mscale(-1.0, comp.hat(g)))
            return r, comp.shift(comp.mscale(-0.5, fprime), 1.0)

        def solve():
            start = comp.add(y0, f(y0))
            s = newton(
                system, start, tol=tol, max_iter=12 if self.max_iter is None else self.max_iter
            )
            return s.x, s.result == RESULTS.successful, (s.result, s.iterations, s.residual)

        # Derivatives by the implicit function theorem at the root, not through Newton.
        y1, _, (result, it, res) = implicit_root(residual, solve, y0)
        y_next = comp.unvec(y1).astype(dtype)
        return y_next, StepInfo(
            finite_result(y_next, result.astype(jnp.int32)), it.astype(jnp.int32), res.astype(dtype)
        )

    def _step_coordinates(self, model, y, dt, dW, tol):
        """Any algebra: the solve on the state's real coordinates."""
        alg = model.algebra
        x0 = alg.coordinates(y)

        def f(u):
            return alg.bracket(u, model.step_gradient(u, dt, dW))

        def residual(x, lam):
            m = 0.5 * (y + alg.from_coordinates(x))
            return x - x0 - alg.coordinates(f(m))

        x, result, it, res = solve_array(
            residual,
            x0 + alg.coordinates(f(y)),
            x0,
            tol=tol,
            max_iter=self.max_iter,
            jacobian=jacobian_mode("auto", alg.dim, large="identity"),
        )
        y_next = alg.from_coordinates(x).astype(y.dtype)
        return y_next, StepInfo(finite_result(y_next, result), it, res.astype(real_dtype(y.dtype)))
