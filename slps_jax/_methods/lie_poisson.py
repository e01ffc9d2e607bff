"""Scheme (42) of Liu & Wang: the Lie–Poisson reduction integrator for the rigid body."""

from __future__ import annotations

import functools
import operator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._algebra import adjoint
from .._algebra import so3 as comp
from .._brownian import scale_noise
from .._support.checks import check_options, real_dtype
from .._support.solution import RESULTS
from .._systems.capabilities import QUADRATIC, SO3_VECTORS
from .base import AbstractMethod, StepInfo, StrongOrders, default_tol, finite_result
from .newton import implicit_root, newton, solve_array


def branch_rotation(v):
    r"""The rotation on the branch $\theta < \pi/2$ whose sine vector is `v`.

    For a rotation by $\theta$ about the unit axis $u$, $v(A) = \mathrm{vee}(\mathrm{skew} A)
    = \sin\theta\, u$; on the branch $\cos\theta = \sqrt{1 - |v|^2} > 0$ this determines $A$:
    $A = c\,\mathrm{Id} + \hat v + v v^T/(1 + c)$, $c = \sqrt{1 - |v|^2}$. Algebraic (one square
    root, no trigonometry) and orthogonal to round-off for every $|v| < 1$.

    **Returns:** `(A, c, g)` with `g = 1/(1 + c)`.
    """
    s2 = comp.dot(v, v)
    c = jnp.sqrt(jnp.maximum(1.0 - s2, 0.0))
    g = 1.0 / (1.0 + c)
    a = comp.madd(comp.shift(comp.hat(v), c), comp.outer(comp.scale(g, v), v))
    return a, c, g


def sine_chart_in_map(v, y, fields, jacobian=True):
    r"""Scheme (42)'s in-map in the sine chart of the branch, and $dR/dv$.

    The generating function of a step with increments $(h, \Delta W_1, \dots, \Delta W_s)$ is
    $\bar S(A) = \tfrac12\operatorname{tr}A - K(v) + \tfrac14(u^T A u - \operatorname{tr}A\,|u|^2)$
    with $v = v(A)$, the step's Hamiltonian $K = hH_0 + \sum_r \Delta W_r H_r$ and
    $u = \sum_r \Delta W_r \nabla H_r(v)$: the last term is
    $\tfrac12\sum_{r,q}\Delta W_r\Delta W_q S_{rq}(A)$; for the rigid body's one noise
    $H_1 = cH_0$ it is the $\kappa$ term of (42) (`docs/several-noises.md`). Its in-map, with
    $A = A(v)$ of `branch_rotation`:

    $R(v) = v + Q\nabla K - \tfrac14 u\times p - \tfrac12|u|^2 v - \tfrac12 Q J_u^T m - y_n$,
    $p = A^T u = c\,u - v\times u + g(v\cdot u)v$,
    $m = (\mathrm{sym}A - \operatorname{tr}A)\,u = g(v\cdot u)v - (1+c)u$,
    $J_u = \partial u/\partial v$, $Qx = \tfrac12((1+c)x - v\times x - g(v\cdot x)v)$,
    $c = \sqrt{1-|v|^2}$, $g = 1/(1+c)$. In this chart $v(A)$ is the unknown itself, so
    $dR/dv = \mathrm{Id} + O(h)$: the fold of the branch ($c \to 0$) enters only through
    the small terms.

    `fields(v)` returns $(\nabla K, \nabla^2 K, u, J_u)$ on components
    (`LiePoissonSystem.step_fields`): $u = $ `None` drops the second-order term (the
    first-order in-map $v + Q\nabla K - y$), $J_u = $ `None` means $J_u = 0$ (linear noise),
    and a diagonal matrix (`is_diagonal`) stays diagonal. $dR/dv$ by forward-mode autodiff
    of $R$ (three tangents, which skip whatever does not depend on $v$), so `fields` must be
    differentiable; where $J_u$ is diagonal, hence constant (the rigid body with `c=`), it
    is written out instead (`_written_out_jacobian`), which is faster there. Tests compare
    residual and Jacobian with autodiff of the generating function.
    """

    def residual(v):
        k, _, u, ju = fields(v)
        return _in_map(v, y, k, u, ju)

    if not jacobian:
        return residual(v)
    k, hk, u, ju = fields(v)
    if ju is not None and comp.is_diagonal(ju) and comp.is_diagonal(hk):
        return _in_map(v, y, k, u, ju), _written_out_jacobian(v, k, hk, u, ju)
    r, lin = jax.linearize(residual, v)
    zero, one = jnp.zeros_like(r[0]), jnp.ones_like(r[0])
    cols = [lin(tuple(one if i == j else zero for i in range(3))) for j in range(3)]
    return r, tuple(tuple(cols[j][i] for j in range(3)) for i in range(3))


def _chart(v):
    """`c = sqrt(1 - |v|^2)`, `1 + c` and `g = 1/(1 + c)` of the sine chart at `v`."""
    # (tiny, not 0: off the ball the derivative stays finite and the iterate is flagged)
    c = jnp.sqrt(jnp.maximum(1.0 - comp.dot(v, v), jnp.finfo(v[0].dtype).tiny))
    return c, 1.0 + c, 1.0 / (1.0 + c)


def _noise_terms(v, u, c, opc, g):
    """`v.u`, `p = A^T u` and `m = (sym A - tr A) u` at `A = A(v)`."""
    vu = comp.dot(v, u)
    p = tuple(c * ui - ci + g * vu * vi for ui, ci, vi in zip(u, comp.cross(v, u), v))
    m = tuple(g * vu * vi - opc * ui for ui, vi in zip(u, v))
    return vu, p, m


def _in_map(v, y, k, u, ju):
    """The residual of `sine_chart_in_map` for the step's fields at `v`."""
    c, opc, g = _chart(v)

    def q(x):
        vx = comp.dot(v, x)
        return tuple(
            0.5 * (opc * xi - ci - g * vx * vi) for xi, ci, vi in zip(x, comp.cross(v, x), v)
        )

    if u is None:
        return tuple(vi + qi - yi for vi, qi, yi in zip(v, q(k), y))
    vu, p, m = _noise_terms(v, u, c, opc, g)
    n2 = comp.dot(u, u)
    if ju is not None:  # Q k - Q J_u^T m / 2 = Q (k - J_u^T m / 2)
        k = tuple(ki - 0.5 * xi for ki, xi in zip(k, comp.mtv_any(ju, m)))
    return tuple(
        vi + qi - 0.25 * a - 0.5 * n2 * vi - yi
        for vi, qi, a, yi in zip(v, q(k), comp.cross(u, p), y)
    )


def _written_out_jacobian(v, k, h, u, d):
    r"""$dR/dv$ of `sine_chart_in_map` for diagonal $\nabla^2 K = \mathrm{diag}(h)$ and
    $J_u = \mathrm{diag}(d)$ (constant: the rigid body with `c=`), written out entry by entry.

    With $x = J_u^Tm$ and $w = \nabla K - \tfrac12 x$, $R = v + Qw - \tfrac14 u\times p
    - \tfrac12|u|^2v - y$, and by the product rule, with $\nabla c = -v/c$ and
    $\nabla g = g^2v/c$,
    $dR/dv = (1 - \tfrac12|u|^2)\mathrm{Id} + \partial_v(Q)w + Q(\nabla^2K - \tfrac12J_u^Tm')
    + \tfrac14(\hat pJ_u - \hat u p') - v(J_u^Tu)^T$,
    $\partial_v(Q)w = \tfrac12(w\nabla c^T + \hat w - v\nabla(g\,v\cdot w)^T - g(v\cdot w)\mathrm{Id})$
    at fixed $w$, $p' = u\nabla c^T + \hat u + vG^T + g(v\cdot u)\mathrm{Id} + (c\,\mathrm{Id} - \hat v)J_u$,
    $m' = vG^T - u\nabla c^T + g(v\cdot u)\mathrm{Id} - (1+c)J_u$, $G = \nabla(g\,v\cdot u)
    = (v\cdot u)\nabla g + g(u + J_u^Tv)$."""
    c, opc, g = _chart(v)
    vu, p, m = _noise_terms(v, u, c, opc, g)
    # Off the ball (|v| >= 1) 1/c is 1/tiny, as with the unclamped c: the update overflows,
    # and the attempt stops at once (`nonfinite`, then the continuation) instead of
    # wandering for `max_iter` updates, which a whole batch would wait for
    tiny = jnp.finfo(c.dtype).tiny
    ic = jnp.where(1.0 - comp.dot(v, v) >= tiny, 1.0 / c, 1.0 / tiny)
    dg = g * g * ic  # grad g = dg v, grad c = -ic v
    w = tuple(ki - 0.5 * di * mi for ki, di, mi in zip(k, d, m))
    vw = comp.dot(v, w)
    gvu = g * vu
    big_g = tuple(vu * dg * vi + g * (ui + di * vi) for vi, ui, di in zip(v, u, d))
    hv, hu, hw, hp = _hat(v), _hat(u), _hat(w), _hat(p)
    rng = range(3)

    def diag(i, j, x):
        return x if i == j else 0.0

    # d(Q w)/dv at fixed w, and Q
    dqw = [
        [
            _sum(
                -ic * w[i] * v[j],
                hw[i][j],
                -v[i] * (vw * dg * v[j] + g * w[j]),
                diag(i, j, -g * vw),
            )
            for j in rng
        ]
        for i in rng
    ]
    qm = [[_sum(diag(i, j, opc), -hv[i][j], -g * v[i] * v[j]) for j in rng] for i in rng]
    # p', and 2 (H - J_u^T m' / 2)
    dp = [
        [
            _sum(
                -ic * u[i] * v[j],
                hu[i][j],
                v[i] * big_g[j],
                diag(i, j, gvu + c * d[j]),
                _mul(-hv[i][j], d[j]),
            )
            for j in rng
        ]
        for i in rng
    ]
    a = [
        [
            _sum(
                -d[i] * (v[i] * big_g[j] + ic * u[i] * v[j]),
                diag(i, j, 2.0 * h[i] - d[i] * (gvu - opc * d[i])),
            )
            for j in rng
        ]
        for i in rng
    ]
    du = comp.mul(d, u)
    one = 1.0 - 0.5 * comp.dot(u, u)
    # (the halves of d(Qw), Q and a, and the quarters, gathered)
    return tuple(
        tuple(
            _sum(
                diag(i, j, one),
                0.5 * dqw[i][j],
                0.25 * _sum(*(_mul(qm[i][n], a[n][j]) for n in rng)),
                _mul(0.25 * hp[i][j], d[j]),
                -0.25 * _sum(*(_mul(hu[i][n], dp[n][j]) for n in rng)),
                -v[i] * du[j],
            )
            for j in rng
        )
        for i in rng
    )


def _hat(x):
    """`hat(x)` with Python zeros on the diagonal (`_sum` and `_mul` skip them)."""
    return ((0.0, -x[2], x[1]), (x[2], 0.0, -x[0]), (-x[1], x[0], 0.0))


def _is_zero(x):
    return isinstance(x, float) and x == 0.0


def _mul(a, b):
    return 0.0 if _is_zero(a) or _is_zero(b) else a * b


def _sum(*terms):
    """The sum of the terms that are not the Python zero (traced at no cost)."""
    terms = [t for t in terms if not _is_zero(t)]
    return functools.reduce(operator.add, terms) if terms else 0.0


def member_fields(lam, fields):
    """The fields of the step scaled by `lam` (the continuation's member `lam`): every one
    is linear in the step `(h, dW, A)`. Scaling them, not the step, keeps what depends on
    the step alone (a linear noise's area term) out of the Newton loop: with the step
    scaled inside it, SALT's `LiePoisson` ran 18 % slower."""
    return tuple(None if f is None else comp.scale_any(lam, f) for f in fields)


# Continuation levels of the sine-chart Newton: a failed solve restarts along
# lam = 1/2, 1, then quarters, eighths and sixteenths of the step (see `newton`).
CONTINUATION = 4


def solve_on_branch(sine_fn, z, *, tol, max_iter, feasible=True, unroll=0):
    """The root `A` on the branch `theta < pi/2` of an in-map at `z`, as its sine vector `v`
    (`A = branch_rotation(v)`).

    `sine_fn(v, lam, jacobian=True)` is the residual in the sine chart (and `dR/dv`) of the
    in-map with its step scaled by `lam` (`tau -> lam tau`, `kappa -> lam^2 kappa`), whose
    root at `lam = 0` is `v = z`. Newton in the sine chart from `v = z`: one loop whose body
    is one update (usually three updates, and the fourth residual passes the test); its first
    `unroll` bodies before it as straight-line code (`newton`).
    A sample whose attempt fails (no convergence in `max_iter` updates, a non-finite
    residual, or a root off the chart `|v| < 1`, near the fold at large steps) starts again
    and follows the roots from `lam = 0` to `lam = 1` in 2, 4, 8, then 16 stages (`newton`'s
    continuation: data in the same loop, so the residual is compiled once). Derivatives
    follow the implicit function theorem (`implicit_root`).

    **Returns:** `(v, result, iterations, residual)`.
    """

    def solve():
        s = newton(
            sine_fn,
            z,
            tol=tol,
            max_iter=max_iter,
            active=feasible,
            admissible=lambda v: comp.dot(v, v) < 1.0,
            continuation=CONTINUATION,
            unroll=unroll,
        )
        return s.x, s.result == RESULTS.successful, (s.result, s.iterations, s.residual)

    # Derivatives (with respect to the system's parameters, y and dW) by the implicit
    # function theorem at the root, never through the iterations; v = 0 (A = Id) where it
    # failed.
    zero = comp.scale(0.0, z)
    v, _, (result, iterations, residual) = implicit_root(
        lambda v: sine_fn(v, 1.0, jacobian=False), solve, zero
    )
    return v, result.astype(jnp.int32), iterations.astype(jnp.int32), residual


def branch_point(y):
    r"""$A_0 = Y + (I + Y^2)^{1/2}$ for a skew matrix $Y$ with $\|Y\|_2 < 1$: orthogonal
    (since $Y$ commutes with $(I + Y^2)^{1/2}$), with $\mathrm{skew}\,A_0 = Y$ and
    positive definite symmetric part: the root of scheme (42)'s in-map for a step of size 0,
    on the branch. For $n = 3$ it is `branch_rotation`. Also returns the smallest eigenvalue
    $1 - \|Y\|_2^2$ of $I + Y^2$ (the distance to the fold)."""
    eye = jnp.eye(y.shape[-1], dtype=y.dtype)
    m = eye + y @ y
    w, q = jnp.linalg.eigh(0.5 * (m + adjoint(m)))
    return y + (q * jnp.sqrt(jnp.maximum(w, 0.0))) @ adjoint(q), w[0]


def group_in_map(system, a, dt, dW, second):
    r"""Scheme (42)'s in-map on SO(n), $-2\,\mathrm{skew}(A^T \partial\bar S/\partial A)$, for
    the truncated generating function
    $\bar S(A) = \tfrac12\operatorname{tr}A - K(V) - \tfrac14\operatorname{tr}(A\,u^Tu)$,
    $V = \mathrm{skew}A$, $K = hH_0 + \sum_r\Delta W_rH_r$, $u = \sum_r \Delta W_r\nabla H_r(V)$
    (`second` times: 0 drops the second-order term). For $n = 3$ and $A$ a rotation, the
    last term is $\tfrac14(u^TAu - \operatorname{tr}A|u|^2)$ of so(3)
    (`docs/so-n.md`); $\partial\bar S/\partial A$ by reverse-mode autodiff."""

    alg = system.algebra

    def sbar(a):
        v = alg.project(a)
        u = second * system.noise_gradient(v, dW)
        return (
            0.5 * jnp.real(jnp.trace(a))
            - system.step_hamiltonian(v, dt, dW)
            - 0.25 * jnp.real(jnp.trace(a @ adjoint(u) @ u))
        )

    # (the gradient for Re tr(X^H Y): the conjugate of JAX's for complex A)
    m = adjoint(a) @ jnp.conj(jax.grad(sbar)(a))
    return adjoint(m) - m


class LiePoisson(AbstractMethod):
    r"""Scheme (42) of Liu & Wang: the stochastic Lie–Poisson reduction integrator.

    Each step solves the in-map for $A_n \in SO(3)$ and sets $y_{n+1} = A_n y_n$:

    $y_n = v(A) + \tau\,\mathrm{vee}(\mathrm{skew}(A^T W)) - \kappa\,\mathrm{vee}(\mathrm{skew}(A^T G(A)))$,
    $\tau = h + c\Delta W_n$, $\kappa = c^2 \Delta W_n^2$ (conventions of `docs/scheme.md`).

    Any system: each step solves the in-map of the generating function
    $\tfrac12\operatorname{tr}A - K_n(v) + \tfrac14(u^TAu - \operatorname{tr}A|u|^2)$,
    $K_n = hH_0 + \sum_r\Delta W_r H_r$, $u = \sum_r \Delta W_r\nabla H_r(v)$
    (`docs/several-noises.md`), which for the rigid body's one noise $H_1 = cH_0$ is (42).
    On so(3), Newton's method in the *sine chart* of the branch $\theta < \pi/2$,
    $A = A(v)$ with $v = \mathrm{vee}(\mathrm{skew} A)$ (see `branch_rotation`), on one
    closed-form residual (`sine_chart_in_map`), with its Jacobian written out for the rigid
    body with `c=` and by forward-mode autodiff otherwise, started from $v = y_n$ (the
    exact solution at $h = \Delta W = 0$). In this chart $v(A)$ is the unknown itself, so
    the Jacobian is $\mathrm{Id} + O(h)$ and the fold at $|y| = 1$ only enters through the
    small terms; the chart is algebraic (no trigonometry) and lies on the branch by
    construction. On the paper's setup three updates reach the tolerance for almost every
    sample-step. A sample whose attempt fails (near the fold at large steps) starts again
    and follows the roots along the step, $\lambda h$ and $\lambda\Delta W$ for
    $\lambda = 1/2, 1$, then $1/4, \dots, 1$ and finer: data in the same loop, so the solver
    is compiled once (`solve_on_branch`). On so(n) and su(N), Newton in Cayley coordinates
    about the branch point (`_step_group`). With several non-commuting noises the strong
    order is 1/2 (measured), as for every method that uses only the increments; with their
    Lévy areas, 1.

    A sample it cannot solve is flagged with the reason (`StepInfo.result`, a `RESULTS`
    code); the driver keeps its last good state. The chart gives an orthogonal $A$, so $|y|$ (the
    Casimir) is kept to round-off. Strong order 1 on the paper's setup (measured).

    **Arguments:**

    - `tol`: max-norm residual tolerance; default `64 eps` of the dtype.
    - `max_iter`: Newton updates allowed per continuation stage (default `None`: 12; on
      so(n) 48 for the chord iteration, which converges linearly).
    - `scale` (quadratic Hamiltonians with `c=` only, such as the `RigidBody`'s):
      $\lambda > 0$ to integrate $z = y/\lambda$ (time scaled by $\lambda$): needed when
      $|y_0| \ge 1$, where the in-map has no solution; choose $\lambda > |y_0|$. It moves the
      solve away from the fold at $|y| = 1$ but costs accuracy (`docs/scheme.md`).
    - `iteration` (so(n) only): how the in-map is solved. `"chord"` (the default,
      `"auto"`): a chord iteration with the Jacobian of the chart at the start of the step
      (the in-map of a step of size 0), factorised once per step: linear convergence at a
      rate $O(h^{1/2})$, about 8 updates, with no autodiff Jacobian; `"newton"`: the full
      Jacobian by forward-mode autodiff at every update (quadratic convergence, 3 updates,
      but `n(n-1)/2` tangents each: 3–8x slower per step, measured in
      `benchmarks/so_n.py`).
    - `second_order`: keep the second-order terms of the generating function, $c^2\Delta W^2$
      of (41) for one noise and the $S_{rq}$ terms for several (default `True`). They make
      the scheme converge to the Stratonovich solution; `False` shows their effect, a bias
      that does not shrink with the step (`tests/test_several_noises.py`).
    - `unroll`: the Newton loop's first bodies made as straight-line code before it (default
      0): the same iterates and results, at about twice the compile time. On a CPU it does
      not pay any more: 8 % slower than the loop (`benchmarks/newton_fusion.py`).

    Reference: Q. Liu and L. Wang, *Lie–Poisson numerical method for a class of stochastic
    Lie–Poisson systems*, scheme (42).
    """

    strong_orders = StrongOrders(one=1.0, increments=0.5, areas=1.0)
    poisson = True

    tol: float | None = eqx.field(default=None, static=True)
    max_iter: int | None = eqx.field(default=None, static=True)
    scale: float | None = eqx.field(default=None, static=True)
    unroll: int = eqx.field(default=0, static=True)
    iteration: str = eqx.field(default="auto", static=True)
    second_order: bool = eqx.field(default=True, static=True)

    def __post_init__(self):
        check_options(self)
        if not isinstance(self.second_order, (bool, np.bool_)):
            raise TypeError(
                f"LiePoisson: second_order must be True or False, got {self.second_order!r}."
            )
        if self.iteration not in ("auto", "chord", "newton"):
            raise ValueError(
                f"LiePoisson: iteration must be 'auto', 'chord' or 'newton', got "
                f"{self.iteration!r}."
            )

    def check_initial(self, system, y0):
        if self.scale is not None and not QUADRATIC(system):
            raise ValueError(
                "LiePoisson(scale=...) needs quadratic Hamiltonians with one noise proportional "
                "to the drift (c=), such as the rigid body's: scaling y is a time change only "
                "then; this system has not."
            )
        lam = 1.0 if self.scale is None else self.scale
        norm = system.algebra.spectral_norm(y0)
        if norm / lam >= 1.0:
            raise ValueError(
                f"LiePoisson needs the spectral norm of y0 (||Y0||_2; |y0| on so(3)) below 1 "
                f"(the in-map has no solution on the paper's branch otherwise), got {norm:.6g}"
                + ("" if self.scale is None else f" with scale={self.scale}")
                + f". Pass LiePoisson(scale=s) with s > {norm:.6g}, for example "
                f"s = {1.5 * norm:.3g}; the norm is conserved, so it suffices at the start."
            )

    def step(self, system, y, dt, dW):
        tol = default_tol(y.dtype) if self.tol is None else self.tol
        if SO3_VECTORS(system):  # Newton on the sine vector: the in-map in closed form
            return self._step_sine(system, y, dt, dW, tol)
        return self._step_group(system, y, dt, dW, tol)  # Cayley coordinates: SO(n), U(N)

    def _step_sine(self, system, y, dt, dW, tol):
        r"""The step on so(3)* (3-vectors): Newton on the sine vector of $A_n$, the in-map of
        the generating function in closed form (`sine_chart_in_map`)."""
        dtype = y.dtype
        # scale: z = y / lam at time scaled by lam (a time change for quadratic Hamiltonians)
        lam_s = 1.0 if self.scale is None else self.scale
        z = comp.scale(1.0 / lam_s, comp.vec(y))
        dt_s, dW_s = lam_s * dt, scale_noise(dW, lam_s)

        def sine_fn(v, lam, jacobian=True):
            def fields(v):
                step = system.step_fields(v, dt_s, dW_s, second=self.second_order)
                return member_fields(lam, step)

            return sine_chart_in_map(v, z, fields, jacobian)

        feasible = comp.dot(z, z) < 1.0
        v, result, iterations, residual = solve_on_branch(
            sine_fn,
            z,
            tol=tol,
            max_iter=12 if self.max_iter is None else self.max_iter,
            feasible=feasible,
            unroll=self.unroll,
        )
        a, _, _ = branch_rotation(v)
        y_next = comp.unvec(comp.mv(a, comp.vec(y))).astype(dtype)
        return y_next, StepInfo(finite_result(y_next, result), iterations, residual.astype(dtype))

    def _step_group(self, system, y, dt, dW, tol):
        r"""The step on SO(n) and U(N): Newton in Cayley coordinates
        $A = A_0\,\mathrm{cay}(X)$ about the branch point $A_0$ of $Y_n$ (`branch_point`), on
        the real coordinates of $X$, with the same continuation as on so(3);
        $Y_{n+1} = A Y_n A^H$."""
        alg = system.algebra
        real = real_dtype(y.dtype)
        lam = 1.0 if self.scale is None else self.scale
        z = y / lam
        dt_s, dW_s = lam * dt, scale_noise(dW, lam)
        # (the chart's base point: constant for derivatives, which the implicit function
        # theorem gives through the residual; eigh's derivative is singular here anyway)
        a0, gap = jax.tree_util.tree_map(jax.lax.stop_gradient, branch_point(alg.to_matrix(z)))
        second = 1.0 if self.second_order else 0.0

        # (unknowns and equations on the group's Lie algebra: u(N) for su(N), where A is
        # unitary and the in-map has a trace)
        def rotation(x):
            return a0 @ alg.cayley(alg.from_group_coordinates(x))

        def residual(x, lam_):
            a = rotation(x)
            return alg.group_coordinates(
                group_in_map(system, a, lam_ * dt_s, scale_noise(dW_s, lam_), second)
                - alg.to_matrix(z)
            )

        zero = jnp.zeros((alg.group_dim,), real)

        def chart():  # d skew(A_0 cay(X)) / dX at X = 0: the in-map of a step of size 0
            return jax.jacfwd(
                lambda x: alg.group_coordinates(0.5 * (rotation(x) - adjoint(rotation(x))))
            )(zero)

        mode = "newton" if self.iteration == "newton" else chart
        x, result, iterations, res = solve_array(
            residual,
            zero,
            zero,
            tol=tol,
            max_iter=self.max_iter,
            jacobian=mode,
            active=gap > 0.0,
            continuation=CONTINUATION,
        )
        a = rotation(x)
        # The branch: a positive definite symmetric part. Tested once, at the root (a
        # Cholesky factorisation in every update would cost a third of the step at so(4));
        # a root off it is a failure the driver reports (and `retry_substeps` splits).
        on_branch = jnp.all(jnp.isfinite(jnp.linalg.cholesky(0.5 * (a + adjoint(a)))))
        result = jnp.where(
            (result == RESULTS.successful) & ~on_branch, RESULTS.off_branch, result
        ).astype(jnp.int32)
        # (projected: a symmetric part left by rounding would add up over the steps and
        # move the Casimirs)
        y_next = alg.act(a, y).astype(y.dtype)
        return y_next, StepInfo(finite_result(y_next, result), iterations, res.astype(real))
