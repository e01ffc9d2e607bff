"""Scheme (42) of Liu & Wang: the Lie–Poisson reduction integrator for the rigid body."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from .. import _so3 as so3
from .base import AbstractMethod, StepInfo, default_tol, newton


def in_map(a, y, d, tau, kappa, jacobian=True):
    r"""Residual of the in-map of scheme (42) and its right-trivialised Jacobian.

    $R(A) = v(A) + \tau\, \mathrm{vee}(\mathrm{skew}(A^T W))
            - \kappa\, \mathrm{vee}(\mathrm{skew}(A^T G(A))) - y_n$,
    with $v = \mathrm{vee}(\mathrm{skew} A)$, $\omega = I^{-1} v$, $W = \hat\omega$ and $G$ the
    Frobenius gradient of $S_{11}(A) = \tfrac12(\omega^T A \omega - |\omega|^2 \operatorname{tr} A)$
    (`scheme.md`). Written out with $T = \operatorname{tr} A$, $p = A^T\omega$,
    $m = (\mathrm{sym} A - T)\omega$, $Q = \tfrac12(T - A)$:

    $\mathrm{vee}(\mathrm{skew}(A^T W)) = Q\omega$,
    $\mathrm{vee}(\mathrm{skew}(A^T G)) = \tfrac14\,\omega\times p + \tfrac12|\omega|^2 v + \tfrac12 Q I^{-1} m$.

    The Jacobian is $J$ with $R(A\exp(\hat\delta)) = R(A) + J\delta + O(\delta^2)$, derived by
    hand (tests compare it with autodiff). All arguments are component tuples or scalars.
    """
    t = so3.trace(a)
    v = so3.vee_skew(a)
    w = so3.mul(d, v)
    aw = so3.mv(a, w)
    p = so3.mtv(a, w)
    qw = so3.scale(0.5, so3.sub(so3.scale(t, w), aw))
    m = so3.sub(so3.scale(0.5, so3.add(aw, p)), so3.scale(t, w))
    dm = so3.mul(d, m)
    qdm = so3.scale(0.5, so3.sub(so3.scale(t, dm), so3.mv(a, dm)))
    ww = so3.dot(w, w)
    b = so3.add(so3.add(so3.scale(0.25, so3.cross(w, p)), so3.scale(0.5 * ww, v)),
                so3.scale(0.5, qdm))
    r = tuple(vi + tau * ai - kappa * bi - yi for vi, ai, bi, yi in zip(v, qw, b, y))
    if not jacobian:
        return r, None

    # Differentials along dA = A hat(delta): dv = P delta with P = (T - A^T)/2,
    # dT = -2 v.delta, d omega = I^{-1} P delta, dp = hat(p) delta + A^T d omega. Terms that
    # end in d omega are collected into one product (M I^{-1}) P; the rest are outer products
    # and cheap `A hat(x)` forms. Tests compare the result with autodiff of the residual.
    at = so3.transpose(a)
    pm = so3.mscale(0.5, so3.shift(so3.mscale(-1.0, at), t))
    qm = so3.mscale(0.5, so3.shift(so3.mscale(-1.0, a), t))
    hp = so3.hat_c(p)
    sym_a = so3.mscale(0.5, so3.madd(a, at))
    qd = so3.diag_right(qm, d)  # Q I^{-1}
    # Everything that multiplies d omega: from tau Q omega, from the kappa terms
    # (hat(w) A^T - hat(p))/4, Q I^{-1} (sym A - T)/2 and v w^T (from |w|^2 v / 2).
    m_dw = so3.madd(
        so3.mscale(tau, qm),
        so3.mscale(-0.25 * kappa, so3.madd(so3.hat_mat(w, at), so3.mscale(-1.0, hp))),
        so3.mscale(-0.5 * kappa, so3.mm(qd, so3.shift(sym_a, -t))),
        so3.mscale(-kappa, so3.outer(v, w)),
    )
    dpm = so3.diag_left(d, pm)  # d omega = dpm delta
    # Everything that multiplies delta directly.
    direct = so3.madd(
        so3.mscale(tau, so3.madd(so3.mscale(-1.0, so3.outer(w, v)), so3.mscale(0.5, so3.mat_hat(a, w)))),
        so3.mscale(-0.25 * kappa, so3.shift(so3.outer(p, w), -so3.dot(w, p))),  # hat(w) hat(p)
        so3.mscale(-0.5 * kappa, so3.madd(so3.mscale(-1.0, so3.outer(dm, v)),
                                          so3.mscale(0.5, so3.mat_hat(a, dm)))),
        so3.mscale(-0.25 * kappa, so3.mm(qd, so3.madd(hp, so3.mscale(-1.0, so3.mat_hat(a, w))))),
        so3.mscale(-kappa, so3.outer(so3.mv(qd, w), v)),
    )
    jac = so3.madd(so3.mscale(1.0 - 0.5 * kappa * ww, pm), direct, so3.mm(m_dw, dpm))
    return r, jac


def _branch_start(y):
    """Exponential and Cayley coordinates of the rotation about `y` by `arcsin|y|`.

    It solves the in-map exactly at `tau = kappa = 0` on the branch `theta < pi/2`.
    """
    r2 = so3.dot(y, y)
    small = r2 < 1e-8
    r2s = jnp.where(small, 0.25, r2)
    r = jnp.sqrt(r2s)
    # arcsin(r)/r -> 1 + r^2/6; the double where keeps gradients finite at y = 0.
    f_exp = jnp.where(small, 1.0 + r2 / 6.0, jnp.arcsin(jnp.minimum(r, 1.0)) / r)
    # 2 tan(theta/2)/sin(theta) = 2/(1 + cos theta)
    f_cay = 2.0 / (1.0 + jnp.sqrt(jnp.maximum(1.0 - r2, 0.0)))
    return so3.scale(f_exp, y), so3.scale(f_cay, y)


def _predictor(y, d, tau, kappa):
    """Starting points for Newton in both parameterisations: the tangent predictor.

    `A0`, the rotation about `y` by `arcsin|y|`, solves the in-map at `tau = kappa = 0`.
    One linearised step `x0 - J0^{-1} R(A0)` follows the solution branch to the actual
    `tau, kappa`, with `J0 = P(A0) chain` the Jacobian at `tau = kappa = 0`. Near the fold
    (`|y|` close to 1) the Jacobian at the actual `tau` can be nearly singular at `A0` even
    when the solution itself is well conditioned; `J0` is not (its small eigenvalue is
    `cos theta > 0`), so this start converges where a plain Newton step from `A0` diverges.
    """
    starts = []
    for mode, x0 in enumerate(_branch_start(y)):
        a0, chain = _rotation_and_chain(x0, mode)
        r, _ = in_map(a0, y, d, tau, kappa, jacobian=False)
        t = so3.trace(a0)
        p0 = so3.mscale(0.5, so3.shift(so3.mscale(-1.0, so3.transpose(a0)), t))
        dx = so3.solve3(so3.mm(p0, chain), r)
        starts.append(tuple(xi - di for xi, di in zip(x0, dx)))
    return tuple(starts)


def _rotation_and_chain(x, mode):
    """`A` and the right-trivialised derivative `dA = A hat(chain dx)` of the parameterisation.

    mode 0: `A = exp(hat x)`, chain = the right Jacobian of exp;
    mode 1: `A = cay(hat x)`, chain = `4/(4+|x|^2) (Id - hat(x)/2)`.
    Both are `Id + a X + b X^2` and `e Id - f X + g X^2` with `X = hat x`: one set of matrix
    products, only the scalar coefficients differ.
    """
    theta2 = so3.dot(x, x)
    sa, sb, sc = so3.exp_coefficients(theta2)
    s = 4.0 / (4.0 + theta2)
    cay = mode == 1
    a_coef, b_coef = jnp.where(cay, s, sa), jnp.where(cay, 0.5 * s, sb)
    e_coef, f_coef, g_coef = jnp.where(cay, s, 1.0), jnp.where(cay, 0.5 * s, sb), \
        jnp.where(cay, 0.0, sc)
    xm = so3.hat_c(x)
    x2 = so3.mm(xm, xm)
    a = so3.shift(so3.madd(so3.mscale(a_coef, xm), so3.mscale(b_coef, x2)), 1.0)
    chain = so3.shift(so3.madd(so3.mscale(-f_coef, xm), so3.mscale(g_coef, x2)), e_coef)
    return a, chain


@dataclasses.dataclass(frozen=True)
class LiePoisson(AbstractMethod):
    r"""Scheme (42) of Liu & Wang: the stochastic Lie–Poisson reduction integrator.

    Each step solves the in-map for $A_n \in SO(3)$ and sets $y_{n+1} = A_n y_n$:

    $y_n = v(A) + \tau\,\mathrm{vee}(\mathrm{skew}(A^T W)) - \kappa\,\mathrm{vee}(\mathrm{skew}(A^T G(A)))$,
    $\tau = h + c\Delta W_n$, $\kappa = c^2 \Delta W_n^2$ (conventions of `scheme.md`).

    Newton's method on $\xi$ with $A = \exp(\hat\xi)$, started from the rotation about $y_n$ by
    $\arcsin|y_n|$ and corrected by one tangent-predictor step, with an analytic residual and
    Jacobian; samples whose exponential solve does not converge to the branch
    $\theta < \pi/2$ ($\operatorname{tr} A > 1$) are solved again with the Cayley
    parameterisation $A = \mathrm{cay}(\hat\xi)$. Both keep $|y|$ (the Casimir)
    to round-off, since $A$ is orthogonal. Strong order 1 on the paper's setup (measured).

    **Arguments:**

    - `tol`: max-norm residual tolerance; default `64 eps` of the dtype.
    - `max_iter`: Newton updates allowed per parameterisation (default 12).
    - `scale`: $\lambda > 0$ to integrate $z = y/\lambda$ (time scaled by $\lambda$): needed when
      $|y_0| \ge 1$, where the in-map has no solution; choose $\lambda > |y_0|$. It moves the
      solve away from the fold at $|y| = 1$ but costs accuracy (`scheme.md`).

    Reference: Q. Liu and L. Wang, *Lie–Poisson numerical method for a class of stochastic
    Lie–Poisson systems*, scheme (42).
    """

    tol: float | None = None
    max_iter: int = 12
    scale: float | None = None

    def __post_init__(self):
        if self.tol is not None and not (math.isfinite(self.tol) and self.tol > 0):
            raise ValueError(f"tol must be a positive number, got {self.tol!r}.")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise ValueError(f"max_iter must be a positive integer, got {self.max_iter!r}.")
        if self.scale is not None and not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a positive number or None, got {self.scale!r}.")

    def check_initial(self, model, y0):
        lam = 1.0 if self.scale is None else self.scale
        norm = float((y0 ** 2).sum() ** 0.5)
        if norm / lam >= 1.0:
            raise ValueError(
                f"LiePoisson needs |y0| < 1 (the in-map has no solution on the paper's branch "
                f"otherwise), got |y0| = {norm:.6g}"
                + ("" if self.scale is None else f" with scale={self.scale}")
                + f". Pass LiePoisson(scale=s) with s > {norm:.6g}, for example "
                f"s = {1.5 * norm:.3g}; |y| is conserved, so |y0|/s < 1 suffices."
            )

    def _kappa(self, cdw):
        # The second-order term c^2 dW^2 of the generating function (41); it is what makes
        # the scheme converge to the Stratonovich solution (a test removes it).
        return cdw * cdw

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        lam = 1.0 if self.scale is None else self.scale
        d = model.inverse_inertia()
        cdw = model.c * dW
        tau = lam * (dt + cdw)
        kappa = lam * lam * self._kappa(cdw)
        z = so3.scale(1.0 / lam, so3.vec(y))
        feasible = so3.dot(z, z) < 1.0

        def system(x, mode):
            a, chain = _rotation_and_chain(x, mode)
            r, jac = in_map(a, z, d, tau, kappa)
            return r, so3.mm(jac, chain), so3.trace(a) > 1.0  # the branch theta < pi/2

        x, mode, iterations, residual, ok = newton(
            system, _predictor(z, d, tau, kappa), tol=tol, max_iter=self.max_iter,
            active=feasible)
        a, _ = _rotation_and_chain(x, mode)
        y_next = so3.unvec(so3.mv(a, so3.vec(y))).astype(dtype)
        return y_next, StepInfo(ok, iterations, residual.astype(dtype))
