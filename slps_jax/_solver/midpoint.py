"""The implicit midpoint rule, the paper's reference integrator."""

from __future__ import annotations

import dataclasses
import jax.numpy as jnp

from .. import _so3 as so3
from .._checks import check_options
from .._solution import RESULTS
from .base import AbstractMethod, StepInfo, default_tol, finite_result
from .newton import implicit_root, newton


@dataclasses.dataclass(frozen=True)
class Midpoint(AbstractMethod):
    r"""The implicit midpoint rule $y_{n+1} = y_n + \tau f(\tfrac12(y_n + y_{n+1}))$,
    $\tau = h + c\Delta W_n$.

    Symmetric and of deterministic order 2, hence strong order 1 for this SDE; it conserves
    every quadratic invariant, here both $|y|^2$ and (for the rigid body) $H$, up to the
    solver tolerance. Solved by Newton's method from the explicit Euler predictor, with the
    Jacobian $\mathrm{Id} - \tfrac\tau2 f'(m)$,
    $f'(m) = \hat m\, \nabla^2 H(m) - \widehat{\nabla H(m)}$: from the system
    (analytic for the `RigidBody`, by autodiff of $H$ for a `LiePoissonSystem`).

    **Arguments:** `tol` (default `64 eps`), `max_iter` (default 12).
    """

    tol: float | None = None
    max_iter: int = 12
    def __post_init__(self):
        check_options(self)

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        tau = dt + model.noise_time(dW)
        y0 = so3.vec(y)

        def f(u):
            return so3.cross(u, model.gradient_c(u))

        def residual(y1):
            m = so3.scale(0.5, so3.add(y0, y1))
            return tuple(a - b - tau * c for a, b, c in zip(y1, y0, f(m)))

        def system(y1):
            m = so3.scale(0.5, so3.add(y0, y1))
            g, hess = model.gradient_hessian_c(m)
            r = tuple(a - b - tau * c for a, b, c in zip(y1, y0, so3.cross(m, g)))
            fprime = so3.madd(so3.mm(so3.hat_c(m), hess), so3.mscale(-1.0, so3.hat_c(g)))
            return r, so3.shift(so3.mscale(-0.5 * tau, fprime), 1.0)

        def solve():
            start = tuple(a + tau * b for a, b in zip(y0, f(y0)))
            s = newton(system, start, tol=tol, max_iter=self.max_iter)
            return s.x, s.result == RESULTS.successful, (s.result, s.iterations, s.residual)

        # Derivatives by the implicit function theorem at the root, not through Newton.
        y1, _, (result, it, res) = implicit_root(residual, solve, y0)
        y_next = so3.unvec(y1).astype(dtype)
        return y_next, StepInfo(finite_result(y_next, result.astype(jnp.int32)),
                                it.astype(jnp.int32), res.astype(dtype))
