"""Symmetric compositions of the first-order generating-function step of scheme (42)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .. import _so3 as so3
from .._solution import RESULTS
from .._checks import check_options
from .base import AbstractMethod, StepInfo, default_tol, finite_result
from .composition import TRIPLE_JUMP, combine
from .lie_poisson import branch_rotation, solve_on_branch


def sine_chart_in_map_general(v, y, model, tau, jacobian=True):
    r"""The $\kappa = 0$ in-map of any Hamiltonian, $R(A) = v(A) + \tau\,\mathrm{vee}(
    \mathrm{skew}(A^T\hat\omega)) - y$ with $\omega = \nabla H(v(A))$ (the in-map of the
    generating function $\tfrac12\operatorname{tr}A - \tau H(v(A))$), in the sine chart
    $A = A(v)$ of `branch_rotation`, and $dR/dv$.

    $R(v) = v + \tau\, Q\,\omega - y$ with $\omega = \nabla H(v)$,
    $Q x = \tfrac12((1+c)x - v\times x - g(v\cdot x)v)$, $c = \sqrt{1-|v|^2}$, $g = 1/(1+c)$
    (`docs/scheme.md`), and
    $dR/dv = \mathrm{Id} + \tau(\partial_v(Q)\,\omega + Q\,\nabla^2 H(v))$, where
    $\partial_v(Qx) = \tfrac12(x\,\nabla c^T + \hat x - v\,\nabla(g\,v\cdot x)^T
    - g(v\cdot x)\mathrm{Id})$ at fixed $x$, $\nabla c = -v/c$, $\nabla g = g^2 v/c$.
    For the rigid body this is `sine_chart_in_map` with $\kappa = 0$.
    """
    s2 = so3.dot(v, v)
    c = jnp.sqrt(jnp.maximum(1.0 - s2, 0.0))
    opc = 1.0 + c
    g = 1.0 / opc
    if jacobian:
        w, hess = model.gradient_hessian_c(v)
    else:
        w = model.gradient_c(v)
    s = so3.dot(v, w)
    vxw = so3.cross(v, w)
    qw = tuple(0.5 * (opc * wi - ci - g * s * vi) for wi, ci, vi in zip(w, vxw, v))
    r = tuple(vi + tau * qi - yi for vi, qi, yi in zip(v, qw, y))
    if not jacobian:
        return r
    ic = 1.0 / jnp.maximum(c, jnp.finfo(c.dtype).tiny)
    grad_c = so3.scale(-ic, v)
    grad_gs = tuple(s * g * g * ic * vi + g * wi for vi, wi in zip(v, w))
    dq = so3.mscale(0.5, so3.shift(so3.madd(
        so3.outer(w, grad_c), so3.hat_c(w), so3.mscale(-1.0, so3.outer(v, grad_gs))), -g * s))
    qm = so3.mscale(0.5, so3.madd(so3.shift(so3.mscale(-1.0, so3.hat_c(v)), opc),
                                  so3.mscale(-g, so3.outer(v, v))))
    jac = so3.shift(so3.mscale(tau, so3.madd(dq, so3.mm(qm, hess))), 1.0)
    return r, jac


def _solve_rotation(model, y, tau, tol, max_iter, active):
    """The rotation `A` (branch `theta < pi/2`) that solves the `kappa = 0` in-map at `y`,
    `tau`, by `LiePoisson`'s solver (`solve_on_branch`: Newton in the sine chart with
    continuation, implicit derivatives), with $\nabla H$ and $\nabla^2 H$ from the model."""
    def sine_fn(v, lam, jacobian=True):
        return sine_chart_in_map_general(v, y, model, lam * tau, jacobian)

    v, result, iterations, res = solve_on_branch(sine_fn, y, tol=tol, max_iter=max_iter,
                                                 feasible=active)
    return branch_rotation(v)[0], StepInfo(result, iterations, res)


def _composition(model, y, tau, weights, tol, max_iter, info):
    """`Phi_{w_k tau} o ... o Phi_{w_1 tau}` with `Phi_s = psi_{s/2} o psi*_{s/2}`, on
    components, for samples whose `info` is ok.

    psi*_s(z) = (psi_{-s})^{-1}(z) = A^T z with A solving the out-map `z = out(A; -s)`.
    With `B = A^T` the kappa = 0 out-map is minus the in-map of `B` (the `v` and `tau`
    terms both change sign under transposition), so `B` solves the in-map at `-z`, `-s`
    (branch `tr B = tr A > 1`), and psi*_s(z) = B z. Every solve is one round of one loop
    (`u <- R u`, `R` solving the in-map at `sign u`, `sign w_k tau / 2`, the sign `-` for the
    adjoint half), so the solver is compiled once whatever the number of substeps.
    """
    gammas = jnp.asarray(weights, jnp.asarray(tau).dtype)

    def body(k, carry):
        u, info = carry
        sign = jnp.where(k % 2 == 0, -1.0, 1.0)
        s = sign * 0.5 * gammas[k // 2] * tau
        r, new = _solve_rotation(model, so3.scale(sign, u), s, tol, max_iter, info.ok)
        return so3.mv(r, u), combine([info, new])

    return jax.lax.fori_loop(0, 2 * len(weights), body, (y, info))


def _check_unit_ball(name, y0):
    norm = float((y0 ** 2).sum() ** 0.5)
    if norm >= 1.0:
        raise ValueError(
            f"{name} needs |y0| < 1 (its in-maps have no solution on the branch theta < pi/2 "
            f"otherwise), got |y0| = {norm:.6g}. |y| is conserved; for the rigid body use "
            f"LiePoisson(scale=s) with s > {norm:.6g}, or Strang4 or Midpoint, which have no "
            f"such limit.")


class _SymmetricLiePoisson(AbstractMethod):
    def __post_init__(self):
        check_options(self)

    def check_initial(self, model, y0):
        _check_unit_ball(type(self).__name__, y0)

    _substeps = (1.0,)

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        tau = dt + model.noise_time(dW)
        yc = so3.vec(y)
        inside = jnp.where(so3.dot(yc, yc) < 1.0, RESULTS.successful, RESULTS.outside_domain)
        info0 = StepInfo(inside.astype(jnp.int32), jnp.zeros((), jnp.int32),
                         jnp.zeros((), dtype))
        yc, info = _composition(model, yc, tau, self._substeps, tol, self.max_iter, info0)
        y_next = so3.unvec(yc).astype(dtype)
        return y_next, StepInfo(finite_result(y_next, info.result), info.iterations,
                                info.residual.astype(dtype))


@dataclasses.dataclass(frozen=True)
class LiePoissonSym2(_SymmetricLiePoisson):
    r"""The symmetric composition of the generating-function step of scheme (42) with its
    adjoint: strong order 1, and a Poisson map that keeps the Casimir $|y|$ to round-off.

    $$y_{n+1} = \psi_{\tau_n/2} \circ \psi^*_{\tau_n/2}(y_n), \qquad \tau_n = h + c\,\Delta W_n,$$

    where $\psi_\tau$ is scheme (42) with $\kappa = 0$ (solve the in-map
    $y = v(A) + \tau\,\mathrm{vee}(\mathrm{skew}(A^T\hat\omega(A)))$ for $A \in SO(3)$, return
    $Ay$), first order, and $\psi^*_\tau = (\psi_{-\tau})^{-1}$ its adjoint (solve the out-map
    with $-\tau$ for $A$ given $z$, return $A^T z$). The composition is symmetric and of
    deterministic order 2. The noise multiplies the drift's own vector field, so the SDE is
    the deterministic flow run to the random time $t + cW(t)$, and a deterministic order-$p$
    step applied with $\tau_n$ has strong order $\lfloor p/2 \rfloor$ (Cohen, Debrabant &
    Rößler): here 1, with no $\kappa$ term needed.

    Each half step is one Newton solve in the sine chart of $SO(3)$ with continuation in the
    step, as in `LiePoisson`. Works for the `RigidBody` (analytic Jacobian) and any
    `LiePoissonSystem` (Jacobian from the Hessian of $H$ by autodiff). Needs $|y_0| < 1$.
    A step that does not converge is reported through `StepInfo`, never as NaN.

    **Arguments:** `tol` (max-norm residual tolerance, default `64 eps`), `max_iter` (Newton
    updates per parameterisation, default 12).

    **Reference:** Q. Liu and L. Wang, *Lie–Poisson numerical method for a class of
    stochastic Lie–Poisson systems*, scheme (42); E. Hairer, C. Lubich, G. Wanner, *Geometric
    Numerical Integration* (2006), II.3 (adjoint methods, symmetric composition);
    D. Cohen, K. Debrabant, A. Rößler, arXiv:2004.12887.
    """

    tol: float | None = None
    max_iter: int = 12


@dataclasses.dataclass(frozen=True)
class LiePoissonSym4(_SymmetricLiePoisson):
    r"""Yoshida's triple jump of `LiePoissonSym2`: deterministic order 4, strong order 2.

    $$y_{n+1} = \Phi_{\gamma_1\tau_n} \circ \Phi_{\gamma_0\tau_n} \circ
    \Phi_{\gamma_1\tau_n}(y_n), \qquad \gamma_1 = \frac{1}{2 - 2^{1/3}},\
    \gamma_0 = 1 - 2\gamma_1,$$

    with $\Phi$ the `LiePoissonSym2` step and $\tau_n = h + c\,\Delta W_n$ ($\gamma_0 < 0$: the
    middle step runs backwards). Six Newton solves per step; a Poisson map that keeps $|y|$
    to round-off. Works for `RigidBody` and `LiePoissonSystem`; needs $|y_0| < 1$.

    **Arguments:** `tol` (default `64 eps`), `max_iter` (default 12), as `LiePoissonSym2`.

    **Reference:** H. Yoshida, "Construction of higher order symplectic integrators",
    Phys. Lett. A 150 (1990), 262–268; D. Cohen, K. Debrabant, A. Rößler, arXiv:2004.12887.
    """

    tol: float | None = None
    max_iter: int = 12
    _substeps = TRIPLE_JUMP
