"""Symmetric compositions of the first-order generating-function step of scheme (42)."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from .._algebra import so3 as comp
from .._brownian import scale_noise
from .._support.batching import batched_like
from .._support.checks import check_options
from .._support.solution import RESULTS
from .._systems.capabilities import SO3_VECTORS
from .base import AbstractMethod, StepInfo, StrongOrders, default_tol, finite_result
from .composition import TRIPLE_JUMP, combine
from .lie_poisson import branch_rotation, member_fields, sine_chart_in_map, solve_on_branch


def _solve_rotation(system, y, dt, dW, sign, tol, max_iter, active):
    """The rotation `A` (branch `theta < pi/2`) that solves the first-order in-map at `y` of
    the step Hamiltonian `x -> sign K(sign x)`, `K = dt H_0 + sum_r dW_r H_r` (fields from
    the system), by `LiePoisson`'s solver (`solve_on_branch`: Newton in the sine chart with
    continuation, implicit derivatives)."""

    def sine_fn(v, lam, jacobian=True):
        def fields(u):  # the first-order in-map of u -> sign K(sign u)
            x = comp.scale(sign, u)
            k, hk, _, _ = system.step_fields(x, dt, dW, False)
            return member_fields(lam, (k, comp.scale_any(sign, hk), None, None))

        return sine_chart_in_map(v, y, fields, jacobian)

    v, result, iterations, res = solve_on_branch(
        sine_fn, y, tol=tol, max_iter=max_iter, feasible=active
    )
    return branch_rotation(v)[0], StepInfo(result, iterations, res)


def _composition(system, y, dt, dW, weights, tol, max_iter, info):
    """`Phi_{w_k} o ... o Phi_{w_1}` with `Phi_w = psi_{w/2} o psi*_{w/2}`, `psi_w` the
    first-order step of the step Hamiltonian `w K`, on components, for samples whose `info`
    is ok.

    psi*_s(z) = (psi_{-s})^{-1}(z) = A^T z with A solving the out-map
    `z = v(A) - s vee(skew(hat(k(v(A))) A^T))`, `k = grad K`. With `B = A^T`,
    `v(A) = -v(B)` and `skew(hat(k) A^T) = skew(B^T hat(k))`, so `B` solves the in-map at
    `-z` of `x -> -s K(-x)` (branch `tr B = tr A > 1`), and psi*_s(z) = B z. (For an even
    `K`, such as the rigid body's, that is the in-map of `-s K`; docs/several-noises.md.)
    Every solve is one round of one loop (`u <- R u`, `R` solving the in-map at `sign u` of
    `x -> sign w_k K(sign x) / 2`, the sign `-` for the adjoint half), so the solver is
    compiled once whatever the number of stages.
    """
    gammas = jnp.asarray(weights, jnp.asarray(dt).dtype)

    def body(k, carry):
        u, info = carry
        sign = jnp.where(k % 2 == 0, -1.0, 1.0)
        w = 0.5 * gammas[k // 2]
        r, new = _solve_rotation(
            system, comp.scale(sign, u), w * dt, scale_noise(dW, w), sign, tol, max_iter, info.ok
        )
        return comp.mv(r, u), combine([info, new])

    return jax.lax.fori_loop(0, 2 * len(weights), body, (y, batched_like(info, y)))


def _check_unit_ball(name, y0):
    norm = float((y0**2).sum() ** 0.5)
    if norm >= 1.0:
        raise ValueError(
            f"{name} needs |y0| < 1 (its in-maps have no solution on the branch theta < pi/2 "
            f"otherwise), got |y0| = {norm:.6g}. |y| is conserved; for the rigid body use "
            f"LiePoisson(scale=s) with s > {norm:.6g}, or Strang4 or Midpoint, which have no "
            f"such limit."
        )


class _AbstractSymmetricLiePoisson(AbstractMethod):
    """The symmetric compositions of scheme (42)'s first-order map: each concrete method
    gives its options and the weights of its stages (`_stages`, a step's fractions)."""

    requires = frozenset({SO3_VECTORS})  # (the sine chart of so(3); so(n): LiePoisson)
    # (each stage with weight w gets the increments and areas times w: `_brownian.scale_noise`)
    strong_orders = StrongOrders(one=1.0, increments=0.5, areas=1.0)
    poisson = True
    tol: eqx.AbstractVar[float | None]
    max_iter: eqx.AbstractVar[int]
    _stages: eqx.AbstractClassVar[tuple[float, ...]]

    def __post_init__(self):
        check_options(self)

    def check_initial(self, system, y0):
        _check_unit_ball(type(self).__name__, y0)

    def step(self, system, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        yc = comp.vec(y)
        inside = jnp.where(comp.dot(yc, yc) < 1.0, RESULTS.successful, RESULTS.outside_domain)
        info0 = StepInfo(inside.astype(jnp.int32), jnp.zeros((), jnp.int32), jnp.zeros((), dtype))
        yc, info = _composition(system, yc, dt, dW, self._stages, tol, self.max_iter, info0)
        y_next = comp.unvec(yc).astype(dtype)
        return y_next, StepInfo(
            finite_result(y_next, info.result), info.iterations, info.residual.astype(dtype)
        )


class LiePoissonSym2(_AbstractSymmetricLiePoisson):
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
    step, as in `LiePoisson`. Works for any system: with several noises $\tau_n H$ becomes the
    step Hamiltonian $K_n = hH_0 + \sum_r\Delta W_{r,n}H_r$ (`docs/several-noises.md`), and
    with non-commuting noise fields the strong order is 1/2, like every method that uses
    only the increments, and 1 with the Lévy areas (their term in $K_n$, scaled with the
    stages; measured 1.06, `docs/levy-area.md`). Needs $|y_0| < 1$.
    A step that does not converge is reported through `StepInfo`, never as NaN.

    **Arguments:** `tol` (max-norm residual tolerance, default `64 eps`), `max_iter` (Newton
    updates per parameterisation, default 12).

    **Reference:** Q. Liu and L. Wang, *Lie–Poisson numerical method for a class of
    stochastic Lie–Poisson systems*, scheme (42); E. Hairer, C. Lubich, G. Wanner, *Geometric
    Numerical Integration* (2006), II.3 (adjoint methods, symmetric composition);
    D. Cohen, K. Debrabant, A. Rößler, arXiv:2004.12887.
    """

    tol: float | None = eqx.field(default=None, static=True)
    max_iter: int = eqx.field(default=12, static=True)
    _stages: ClassVar[tuple[float, ...]] = (1.0,)


class LiePoissonSym4(_AbstractSymmetricLiePoisson):
    r"""Yoshida's triple jump of `LiePoissonSym2`: deterministic order 4, strong order 2.

    $$y_{n+1} = \Phi_{\gamma_1\tau_n} \circ \Phi_{\gamma_0\tau_n} \circ
    \Phi_{\gamma_1\tau_n}(y_n), \qquad \gamma_1 = \frac{1}{2 - 2^{1/3}},\
    \gamma_0 = 1 - 2\gamma_1,$$

    with $\Phi$ the `LiePoissonSym2` step and $\tau_n = h + c\,\Delta W_n$ ($\gamma_0 < 0$: the
    middle step runs backwards). Six Newton solves per step; a Poisson map that keeps $|y|$
    to round-off. Works for any system; needs $|y_0| < 1$. The strong order 2 needs the
    noise proportional to the drift (the time change); with several non-commuting noises it
    is 1/2 (measured), and 1 with the Lévy areas (measured 0.98): the three times larger
    cost buys nothing there.

    **Arguments:** `tol` (default `64 eps`), `max_iter` (default 12), as `LiePoissonSym2`.

    **Reference:** H. Yoshida, "Construction of higher order symplectic integrators",
    Phys. Lett. A 150 (1990), 262–268; D. Cohen, K. Debrabant, A. Rößler, arXiv:2004.12887.
    """

    tol: float | None = eqx.field(default=None, static=True)
    max_iter: int = eqx.field(default=12, static=True)
    _stages: ClassVar[tuple[float, ...]] = TRIPLE_JUMP
    strong_orders = StrongOrders(one=2.0, increments=0.5, areas=1.0)
