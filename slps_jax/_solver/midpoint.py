"""The implicit midpoint rule, the paper's reference integrator."""

from __future__ import annotations

import dataclasses
import jax.numpy as jnp

from .. import _so3 as so3
from .._model import RigidBody
from .._system import gradient_c, gradient_hessian_c
from ._checks import check_options
from .base import AbstractMethod, StepInfo, default_tol, implicit_root, newton


@dataclasses.dataclass(frozen=True)
class Midpoint(AbstractMethod):
    r"""The implicit midpoint rule $y_{n+1} = y_n + \tau f(\tfrac12(y_n + y_{n+1}))$,
    $\tau = h + c\Delta W_n$.

    Symmetric and of deterministic order 2, hence strong order 1 for this SDE; it conserves
    every quadratic invariant, here both $|y|^2$ and (for the rigid body) $H$, up to the
    solver tolerance. Solved by Newton's method from the explicit Euler predictor, with the
    Jacobian $\mathrm{Id} - \tfrac\tau2 f'(m)$,
    $f'(m) = \hat m\, \nabla^2 H(m) - \widehat{\nabla H(m)}$: analytic for the `RigidBody`
    ($\nabla^2 H = I^{-1}$), by autodiff of $H$ for a `LiePoissonSystem`.

    **Arguments:** `tol` (default `64 eps`), `max_iter` (default 12).
    """

    tol: float | None = None
    max_iter: int = 12
    general_hamiltonian = True  # works for RigidBody and LiePoissonSystem

    def __post_init__(self):
        check_options(self)

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        tau = dt + model.c * dW
        y0 = so3.vec(y)
        rigid = isinstance(model, RigidBody)

        def f(u):
            return so3.cross(u, gradient_c(model, u))

        def residual(y1):
            m = so3.scale(0.5, so3.add(y0, y1))
            return tuple(a - b - tau * c for a, b, c in zip(y1, y0, f(m)))

        def system(y1, mode):
            m = so3.scale(0.5, so3.add(y0, y1))
            if rigid:  # the Hessian is diagonal: I^{-1}
                d = model.inverse_inertia()
                g, hess_part = so3.mul(d, m), so3.diag_right(so3.hat_c(m), d)
            else:
                g, hess = gradient_hessian_c(model, m)
                hess_part = so3.mm(so3.hat_c(m), hess)
            r = tuple(a - b - tau * c for a, b, c in zip(y1, y0, so3.cross(m, g)))
            fprime = so3.madd(hess_part, so3.mscale(-1.0, so3.hat_c(g)))
            jac = so3.shift(so3.mscale(-0.5 * tau, fprime), 1.0)
            return r, jac, True

        def solve():
            start = tuple(a + tau * b for a, b in zip(y0, f(y0)))
            y1, _, it, res, ok = newton(system, (start,), tol=tol, max_iter=self.max_iter)
            return y1, ok & jnp.isfinite(res), (it, res)

        # Derivatives by the implicit function theorem at the root, not through Newton.
        y1, ok, (it, res) = implicit_root(residual, solve, y0)
        y_next = so3.unvec(y1).astype(dtype)
        ok = ok & jnp.all(jnp.isfinite(y_next))
        return y_next, StepInfo(ok, it.astype(jnp.int32), res.astype(dtype))
