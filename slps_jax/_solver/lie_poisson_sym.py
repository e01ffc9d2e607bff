"""Symmetric compositions of the first-order generating-function step of scheme (42)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .. import _so3 as so3
from .._model import RigidBody
from .._system import gradient_c, gradient_hessian_c
from ._checks import check_options
from .base import AbstractMethod, StepInfo, default_tol, newton
from .composition import TRIPLE_JUMP, combine
from .lie_poisson import _branch_start, _rotation_and_chain, branch_rotation, solve_in_map


def in_map_general(a, y, model, tau, jacobian=True):
    r"""Residual of the $\kappa = 0$ in-map for a general Hamiltonian, and its Jacobian.

    $R(A) = v(A) + \tau\,\mathrm{vee}(\mathrm{skew}(A^T \hat\omega)) - y$ with
    $v = \mathrm{vee}(\mathrm{skew} A)$ and $\omega = \nabla H(v)$: the in-map of the generating
    function $\tfrac12 \operatorname{tr} A - \tau H(v(A))$ (for the rigid body $\omega = I^{-1}v$,
    and this is `in_map` with $\kappa = 0$). With $T = \operatorname{tr} A$,
    $P = \tfrac12(T - A^T)$, $Q = \tfrac12(T - A)$ the residual is $v + \tau Q\omega - y$ and
    the right-trivialised Jacobian ($R(A\exp\hat\delta) = R + J\delta + O(\delta^2)$) is

    $J = P + \tau\,(-\omega v^T + \tfrac12 A\hat\omega) + \tau\, Q\, \nabla^2H(v)\, P$.

    All arguments are component tuples or scalars; `model` supplies $\nabla H$, $\nabla^2 H$.
    """
    t = so3.trace(a)
    v = so3.vee_skew(a)
    if jacobian:
        w, hess = gradient_hessian_c(model, v)
    else:
        w = gradient_c(model, v)
    qw = so3.scale(0.5, so3.sub(so3.scale(t, w), so3.mv(a, w)))
    r = tuple(vi + tau * qi - yi for vi, qi, yi in zip(v, qw, y))
    if not jacobian:
        return r, None
    pm = so3.mscale(0.5, so3.shift(so3.mscale(-1.0, so3.transpose(a)), t))
    qm = so3.mscale(0.5, so3.shift(so3.mscale(-1.0, a), t))
    direct = so3.madd(so3.mscale(-1.0, so3.outer(w, v)), so3.mscale(0.5, so3.mat_hat(a, w)))
    jac = so3.madd(pm, so3.mscale(tau, direct), so3.mscale(tau, so3.mm(so3.mm(qm, hess), pm)))
    return r, jac


def _tangent_starts(y, residual):
    """The tangent predictor of `LiePoisson` (see `_predictor`) for any in-map residual: from
    the rotation about `y` by `arcsin|y|`, one step with the `tau = 0` Jacobian `P`."""
    starts = []
    for mode, x0 in enumerate(_branch_start(y), start=1):  # 1: exponential, 2: Cayley
        a0, chain = _rotation_and_chain(x0, mode)
        r, _ = residual(a0)
        t = so3.trace(a0)
        p0 = so3.mscale(0.5, so3.shift(so3.mscale(-1.0, so3.transpose(a0)), t))
        dx = so3.solve3(so3.mm(p0, chain), r)
        starts.append(tuple(xi - di for xi, di in zip(x0, dx)))
    return tuple(starts)


def _solve_rotation(model, y, tau, tol, max_iter, active):
    """The rotation `A` (branch `tr A > 1`) that solves the `kappa = 0` in-map at `y`, `tau`.

    The rigid body uses `LiePoisson`'s solver (`solve_in_map` with `kappa = 0`: the sine
    chart, exp and Cayley fallbacks, implicit derivatives). Other Hamiltonians: Newton on
    `A = exp(hat x)` with the Cayley fallback, on `in_map_general`.
    """
    if isinstance(model, RigidBody):
        v, ok, iterations, res = solve_in_map(y, model.inverse_inertia(), tau, 0.0, tol=tol,
                                              max_iter=max_iter, feasible=active)
        return branch_rotation(v)[0], StepInfo(ok, iterations, res)

    def residual(a, jacobian=True):
        return in_map_general(a, y, model, tau, jacobian)

    starts = _tangent_starts(y, lambda a: residual(a, jacobian=False))

    def system(x, mode):
        a, chain = _rotation_and_chain(x, mode + 1)  # mode 0: exponential, 1: Cayley
        r, jac = residual(a)
        return r, so3.mm(jac, chain), so3.trace(a) > 1.0  # the branch theta < pi/2

    x, mode, iterations, res, ok = newton(system, starts, tol=tol, max_iter=max_iter,
                                          active=active)
    a, _ = _rotation_and_chain(x, mode + 1)
    return a, StepInfo(ok, iterations, res)


def _sym2(model, y, tau, tol, max_iter, active):
    """`psi_{tau/2} o psi*_{tau/2}` on components.

    psi*_s(z) = (psi_{-s})^{-1}(z) = A^T z with A solving the out-map `z = out(A; -s)`.
    With `B = A^T` the kappa = 0 out-map is minus the in-map of `B` (the `v` and `tau`
    terms both change sign under transposition), so `B` solves the in-map at `-z`, `-s`
    (branch `tr B = tr A > 1`), and psi*_s(z) = B z.
    """
    half = 0.5 * tau
    b, info_adj = _solve_rotation(model, so3.scale(-1.0, y), -half, tol, max_iter, active)
    z = so3.mv(b, y)
    a, info = _solve_rotation(model, z, half, tol, max_iter, active & info_adj.ok)
    return so3.mv(a, z), combine([info_adj, info])


def _check_unit_ball(name, y0):
    norm = float((y0 ** 2).sum() ** 0.5)
    if norm >= 1.0:
        raise ValueError(
            f"{name} needs |y0| < 1 (its in-maps have no solution on the branch theta < pi/2 "
            f"otherwise), got |y0| = {norm:.6g}. |y| is conserved; for the rigid body use "
            f"LiePoisson(scale=s) with s > {norm:.6g}, or Strang4 or Midpoint, which have no "
            f"such limit.")


class _SymmetricLiePoisson(AbstractMethod):
    general_hamiltonian = True  # works for RigidBody and LiePoissonSystem

    def __post_init__(self):
        check_options(self)

    def check_initial(self, model, y0):
        _check_unit_ball(type(self).__name__, y0)

    _substeps = (1.0,)

    def step(self, model, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        tau = dt + model.c * dW
        yc = so3.vec(y)
        active = so3.dot(yc, yc) < 1.0
        if len(self._substeps) == 1:
            yc, info = _sym2(model, yc, tau, tol, self.max_iter, active)
        else:
            # A loop over the substeps rather than three inlined copies: one Sym2 to
            # compile (a third of the compile time), the same numbers.
            gammas = jnp.asarray(self._substeps, jnp.asarray(tau).dtype)

            def body(i, carry):
                u, info = carry
                u, new = _sym2(model, u, gammas[i] * tau, tol, self.max_iter, info.ok)
                return u, combine([info, new])

            zero = jnp.zeros((), dtype)
            info0 = StepInfo(active, jnp.zeros((), jnp.int32), zero)
            yc, info = jax.lax.fori_loop(0, len(self._substeps), body, (yc, info0))
        y_next = so3.unvec(yc).astype(dtype)
        ok = info.ok & jnp.all(jnp.isfinite(y_next))
        return y_next, StepInfo(ok, info.iterations, info.residual.astype(dtype))


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

    Each half step is one Newton solve on $SO(3)$ (exponential coordinates, Cayley fallback,
    tangent predictor), as in `LiePoisson`. Works for the `RigidBody` (analytic Jacobian) and
    any `LiePoissonSystem` (Jacobian from the Hessian of $H$ by autodiff). Needs $|y_0| < 1$.
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
