"""The implicit midpoint rule, the paper's reference integrator."""

from __future__ import annotations

import dataclasses
import jax.numpy as jnp

from .. import _so3 as so3
from ._checks import check_options
from .base import AbstractMethod, StepInfo, default_tol, newton


@dataclasses.dataclass(frozen=True)
class Midpoint(AbstractMethod):
    r"""The implicit midpoint rule $y_{n+1} = y_n + \tau f(\tfrac12(y_n + y_{n+1}))$,
    $\tau = h + c\Delta W_n$.

    Symmetric and of deterministic order 2, hence strong order 1 for this SDE; it conserves
    every quadratic invariant, here both $|y|^2$ and $H$, up to the solver tolerance. Solved by
    Newton's method from the explicit Euler predictor, with the analytic Jacobian
    $\mathrm{Id} - \tfrac\tau2 f'(m)$, $f'(m) = \hat m I^{-1} - \widehat{I^{-1} m}$.

    **Arguments:** `tol` (default `64 eps`), `max_iter` (default 12).
    """

    tol: float | None = None
    max_iter: int = 12

    def __post_init__(self):
        check_options(self)

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        tau = dt + model.c * dW
        d = model.inverse_inertia()
        y0 = so3.vec(y)

        def f(u):
            return so3.cross(u, so3.mul(d, u))

        def system(y1, mode):
            m = so3.scale(0.5, so3.add(y0, y1))
            fm = f(m)
            r = tuple(a - b - tau * c for a, b, c in zip(y1, y0, fm))
            fprime = so3.madd(so3.diag_right(so3.hat_c(m), d),
                              so3.mscale(-1.0, so3.hat_c(so3.mul(d, m))))
            jac = so3.shift(so3.mscale(-0.5 * tau, fprime), 1.0)
            return r, jac, True

        start = tuple(a + tau * b for a, b in zip(y0, f(y0)))
        y1, _, it, res, ok = newton(system, (start,), tol=tol, max_iter=self.max_iter)
        y_next = so3.unvec(y1).astype(dtype)
        ok = ok & jnp.all(jnp.isfinite(y_next))
        return y_next, StepInfo(ok, it, res.astype(dtype))
