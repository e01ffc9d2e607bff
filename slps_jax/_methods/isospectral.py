"""The isospectral midpoint rule of Modin & Viviani, with noise."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from .._algebra import adjoint, matmul
from .._support.batching import batched_like
from .._support.checks import check_options, real_dtype
from .._support.solution import RESULTS
from .base import AbstractMethod, StepInfo, StrongOrders, default_tol, finite_result
from .newton import _RUNNING, implicit_root, jacobian_mode, solve_array


class IsospectralMidpoint(AbstractMethod):
    r"""The isospectral midpoint rule (Modin & Viviani 2020), stochastic as in Ephrati,
    Jansson, Lang & Luesink (2024):

    $Y_n = (I - \tfrac12\hat W)\,X\,(I + \tfrac12\hat W)$,
    $Y_{n+1} = (I + \tfrac12\hat W)\,X\,(I - \tfrac12\hat W)$,
    $\hat W = -\nabla K_n(X)$, $K_n = hH_0 + \sum_r \Delta W_{r,n} H_r$,

    solved for the midpoint $X$. The sign makes $Y_{n+1} - Y_n = [X, \nabla K_n(X)] + O(h^{3/2})$,
    the system $dY = [Y, \nabla H_0]dt + \sum_r[Y, \nabla H_r]\circ dW_r$. Since
    $Y_{n+1} = QY_nQ^T$ with the Cayley rotation $Q = (I + \tfrac12\hat W)(I - \tfrac12\hat W)^{-1}$,
    every Casimir $\operatorname{tr}(Y^{2k})$ is kept (to the solver's tolerance). A
    Lie–Poisson integrator for any Hamiltonians, symmetric, with no domain restriction
    (unlike `LiePoisson`'s $\|Y\|_2 < 1$); strong order 1 with one noise proportional to
    the drift, 1/2 with several non-commuting noises; order 1 with several noises and their
    Lévy areas. Works on every algebra (so(3) through $\hat y$, so(n), su(N) with
    $Q Y_n Q^H$).

    Solved for $X$ by Newton's method on small algebras and by a fixed-point iteration on
    the matrix above (`iteration`). The fixed point starts from the increments of earlier
    steps (`warm_start`), stops at a tolerance relative to the step's increment (`rtol`), and
    the step then keeps the Casimirs to round-off through the Cayley rotation whatever the
    tolerance (`final_update`): on Euler–Zeitlin at h = 0.64/N s, about 2.4 updates per step
    where a cold start to round-off takes 12–13 (`benchmarks/zeitlin.py --economy`).

    **Arguments:**

    - `tol`: an absolute max-norm tolerance of the solve; for the fixed point it replaces
      `rtol` (default `None`: 64 eps of the dtype for Newton, `rtol` for the fixed point).
    - `rtol`: the fixed point's tolerance relative to the step's increment: it stops when
      its correction $\max|X_{k+1} - X_k|$ is at most `rtol` $\max|X_{k+1} - Y_n|$, and
      never below 16 ulps of $\max|X|$, where rounding leaves it (0: to round-off). Default:
      $\sqrt{\epsilon}$ in double precision (1.5e-8, quflow's choice of $\sqrt\epsilon$,
      taken relative to the increment so that it does not depend on the state's scale or
      the algebra; far below the step's local error, $O(h^2)$ relative to the increment),
      0 in single precision (round-off there is 6e-8, and reached in a few updates).
    - `max_iter`: updates allowed (default `None`: 12 for Newton, 48 for the fixed point).
      The fixed point also stops when its correction stops decreasing above the tolerance
      (`RESULTS.stalled`: a contraction's corrections decrease, so the step is too large
      for it); a failed step is reported, and split into substeps by the driver's
      `retry_substeps`. `newton_stats=True` reports the updates per step and the share of
      steps that used `max_iter`.
    - `iteration`: `"auto"` (default: `"newton"` up to so(5), `"fixed_point"` above),
      `"newton"` (the Jacobian by autodiff at every update: quadratic convergence, 2–3
      updates; on the real coordinates of $X$), `"fixed_point"` (the fixed-point iteration
      $X = Y_n + \tfrac12[\hat W, X] + \tfrac14\hat W X\hat W$ on the matrix, two
      products per update, complex ones as three real products: linear convergence at a
      rate $O(h^{1/2})$ and no linear algebra, the fastest from so(8) on and on su(N); it can
      fail to converge at large steps and strong noise, where Newton does not).
    - `warm_start`: how the fixed point starts (0 … 3): from $Y_n$ (0), or from
      $Y_n + \tau_n\,d$, $d$ extrapolated from the increments per unit time
      $(X_m - Y_m)/\tau_m$ of the last `warm_start` steps (1: the last one, quflow's start;
      2: linear; 3, the default: quadratic), $\tau_n = h + c\,\Delta W_n$ the step's time.
      Kept for a system whose noise is proportional to the drift (`c=`, and deterministic
      ones), whose increment scales with $\tau_n$; a system with noises of their own starts
      from $Y_n$, since most of its increment is this step's noise. The driver carries the
      increments per sample (`initial_history`), over live steps only, and a step redone as
      substeps starts its substeps, and the step after, anew: paths do not depend on the
      loop's layout, chunks or sharding. The root, and so the derivatives (by the implicit
      function theorem), do not depend on the start.
    - `final_update`: how $Y_{n+1}$ is formed at the root: `"explicit"`
      ($Y_n + [\hat W, X]$ from the fixed point's last product: no product of its own,
      quflow's form; isospectral to the solver's tolerance), `"cayley"` ($QY_nQ^H$: an LU
      and two products; isospectral to round-off whatever the tolerance), `"auto"`
      (default: `"explicit"` where the solve goes to round-off in double precision (Newton,
      or `rtol=0`), `"cayley"` otherwise). Over $10^4$ steps of Euler–Zeitlin at N = 64 the
      default kept $\operatorname{tr}W^2 \dots \operatorname{tr}W^6$ to 5e-14 in complex128
      (h = 0.005 s; `tests/test_zeitlin_economy.py`) and 2e-6 in complex64; at N = 32 and
      h = 0.01 s the explicit update after the same solve let them drift by 1e-7 and 1e-3
      (`benchmarks/zeitlin.py`).

    **References:** K. Modin & M. Viviani, *A Casimir preserving scheme for long-time
    simulation of spherical ideal hydrodynamics*, J. Fluid Mech. 884 (2020) A22;
    S. Ephrati, E. Jansson, A. Lang & E. Luesink, *An exponential map free implicit midpoint
    method for stochastic Lie–Poisson systems*, arXiv:2408.16701.
    """

    strong_orders = StrongOrders(one=1.0, increments=0.5, areas=1.0)
    poisson = True

    tol: float | None = eqx.field(default=None, static=True)
    rtol: float | None = eqx.field(default=None, static=True)
    max_iter: int | None = eqx.field(default=None, static=True)
    iteration: str = eqx.field(default="auto", static=True)
    final_update: str = eqx.field(default="auto", static=True)
    warm_start: int = eqx.field(default=3, static=True)

    def _cayley(self, system, dtype):
        """Whether the step is the Cayley rotation (`final_update`): by default wherever the
        solve stops short of round-off."""
        if self.final_update == "auto":
            single = jnp.finfo(dtype).bits < 64
            loose = self.tol is not None or self._rtol(dtype) > 0
            return single or (self._mode(system) == "identity" and loose)
        return self.final_update == "cayley"

    def _rtol(self, dtype):
        """The tolerance relative to the step's increment (`rtol`)."""
        if self.rtol is not None:
            return self.rtol
        return math.sqrt(float(jnp.finfo(dtype).eps)) if jnp.finfo(dtype).bits >= 64 else 0.0

    def __post_init__(self):
        check_options(self)
        if self.final_update not in ("auto", "explicit", "cayley"):
            raise ValueError(
                f"IsospectralMidpoint: final_update must be 'auto', 'explicit' "
                f"or 'cayley', got {self.final_update!r}."
            )
        if self.iteration not in ("auto", "newton", "fixed_point"):
            raise ValueError(
                f"IsospectralMidpoint: iteration must be 'auto', 'newton' or 'fixed_point', "
                f"got {self.iteration!r}."
            )
        if self.rtol is not None and (
            not isinstance(self.rtol, (int, float)) or not 0.0 <= self.rtol < 1.0
        ):
            raise ValueError(
                f"IsospectralMidpoint: rtol must be a number in [0, 1) or None, got {self.rtol!r}."
            )
        w = self.warm_start
        if isinstance(w, bool) or not isinstance(w, int) or not 0 <= w < len(_EXTRAPOLATION):
            raise ValueError(
                f"IsospectralMidpoint: warm_start must be an integer 0 ... "
                f"{len(_EXTRAPOLATION) - 1}, got {w!r}."
            )

    def _mode(self, system):
        mode = "identity" if self.iteration == "fixed_point" else self.iteration
        return jacobian_mode(mode, system.algebra.group_dim, large="identity")

    def initial_history(self, system, y0):
        r"""The increments of the last `warm_start` steps, per unit of the step's time, and how
        many of them are known: kept for the fixed point on matrices (`iteration="fixed_point"`)
        of a system whose noise is proportional to the drift (`c=`, deterministic included),
        where the increment scales with the time $h + c\,\Delta W$ of the step. Empty
        otherwise: the increment of a step with noises of their own is mostly this step's
        noise, which no earlier step knows."""
        if not self.warm_start or self._mode(system) != "identity" or system.c is None:
            return ()
        ym = system.algebra.to_matrix(y0)
        return (jnp.zeros((), jnp.int32),) + (jnp.zeros_like(ym),) * self.warm_start

    def step(self, system, y, dt, dW, history=None):
        dtype = y.dtype
        alg = system.algebra
        yn = alg.to_matrix(y)
        eye = jnp.eye(yn.shape[-1], dtype=yn.dtype)
        half_w = functools.partial(_half_w, system, system.step_gradient_of(y, dt, dW))

        # The midpoint X lies in the group's Lie algebra, not always in the system's: on
        # su(N), tr Y_n = 0 gives tr X = tr((W/2)^2 X), and X is solved for in u(N).
        def residual(xc, lam):  # (I - W/2) X (I + W/2) - Y_n, on real coordinates
            x = alg.from_group_coordinates(xc)
            b = eye - half_w(x)
            return alg.group_coordinates(b @ x @ adjoint(b)) - x0

        x0 = alg.group_coordinates(yn)
        history = () if history is None else history
        if self._mode(system) == "identity":
            tau = start = None
            if history:  # (the step's time: the increment is about proportional to it)
                tau = jnp.asarray(dt + system.noise_time(dW)).astype(real_dtype(dtype))
                start = yn + tau * _extrapolate(history)
            max_iter = 48 if self.max_iter is None else self.max_iter
            xc, result, it, res, ax = _fixed_point(
                alg,
                half_w,
                yn,
                yn if start is None else start,
                residual,
                x0,
                self.tol,
                self._rtol(dtype),
                max_iter,
            )
        else:
            xc, result, it, res = solve_array(
                residual,
                x0,
                x0,
                tol=default_tol(dtype) if self.tol is None else self.tol,
                max_iter=self.max_iter,
                jacobian=self._mode(system),
            )
            tau = ax = None
        x = alg.from_group_coordinates(xc)
        if self._cayley(system, dtype):  # Q Y_n Q^H, Q = (I - A)^{-1}(I + A), A = W/2
            if ax is None:  # (Newton, on small algebras: Gauss-Jordan or LU)
                q = alg.cayley(half_w(x))
                y_next = alg.act(q, y).astype(dtype)
            else:  # (the fixed point, on large ones: products only)
                # Q Y_n Q^H = Y_n + B Y_n + Y_n B^H + B Y_n B^H with B = Q - I small: the
                # step's change from small factors, so that its rounding error is eps |B| |Y|
                # rather than eps |Y| (over 10^4 steps at N = 64, h = 0.005 s: a drift of 5e-14
                # instead of 1e-12)
                b, converged = _rotation(half_w(x))
                result = jnp.where(converged, result, RESULTS.stalled)
                by = matmul(b, yn)
                y_next = alg.project(yn + (by - adjoint(by) + matmul(by, adjoint(b))))
                y_next = y_next.astype(dtype)
        else:  # (I + A) X (I - A) = Y_n + 2(AX - XA) at the root: one product, or none
            # with the product of the fixed point's last update (`_reuse`)
            ax = matmul(half_w(x), x) if ax is None else _reuse(_product, ax, system, dt, dW, x)
            y_next = alg.project(yn + 2.0 * (ax - adjoint(ax))).astype(dtype)
        if history:
            history = _remember(history, jax.lax.stop_gradient(x - yn), tau, result)
        info = StepInfo(finite_result(y_next, result), it, res.astype(real_dtype(dtype)), history)
        return y_next, info


# The increment of the next step from those of the last k = 0 ... 3 steps: the polynomial of
# degree k - 1 through them, one step on (coefficients of the newest first).
_EXTRAPOLATION = ((), (1.0,), (2.0, -1.0), (3.0, -3.0, 1.0))


def _extrapolate(history):
    """The next increment per unit time from `history = (known, d_1, ..., d_p)`, newest first:
    extrapolated from the `min(known, p)` known ones (zero when none is)."""
    known, ds = history[0], history[1:]
    p = len(ds)
    table = jnp.asarray(
        [list(_EXTRAPOLATION[k]) + [0.0] * (p - k) for k in range(p + 1)], ds[0].real.dtype
    )
    coef = table[jnp.minimum(known, p)]
    return sum(coef[j] * d for j, d in enumerate(ds))


def _remember(history, increment, tau, result):
    """`history` with this step's increment per unit time first, where the step succeeded
    with a time of its own (an idle sample's step has `tau = 0` and teaches nothing)."""
    known, ds = history[0], history[1:]
    learn = (result == RESULTS.successful) & (tau != 0)
    d = increment / jnp.where(tau != 0, tau, 1.0).astype(increment.real.dtype)
    new = (jnp.minimum(known + 1, len(ds)), d, *ds[:-1])
    return tuple(jnp.where(learn, a, b).astype(b.dtype) for a, b in zip(new, history))


def _half_w(system, gradient, x):
    r"""$\tfrac12\hat W = -\tfrac12\nabla K_n(X)$ for a matrix $X$ of the group's algebra
    (`gradient`: $\nabla K_n$, `System.step_gradient_of`)."""
    alg = system.algebra
    return -0.5 * alg.to_matrix(gradient(alg.project_group(x)))


def _product(system, dt, dW, x):
    r"""$AX$, $A = \tfrac12\hat W(X)$: the explicit final update's product (for its
    derivatives: `_reuse`, whose function takes every differentiable input as an argument)."""
    return matmul(_half_w(system, system.step_gradient_of(x, dt, dW), x), x)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _reuse(fn, value, *args):
    """`value`, a number already computed equal to `fn(*args)` up to the solver's tolerance,
    with the derivative of `fn(*args)`: the primal computation is saved, the derivatives
    are those of the formula."""
    return value


@_reuse.defjvp
def _reuse_jvp(fn, primals, tangents):
    value, *args = primals
    _, *t_args = tangents
    _, t_out = jax.jvp(fn, tuple(args), tuple(t_args))
    return value, t_out


class _Iteration(NamedTuple):
    """The state of `_fixed_point`."""

    x: jax.Array  # the newest iterate X_{k+1}
    ax: jax.Array  # A_k X_k: the last update's product, at the iterate before
    correction: jax.Array  # max|X_{k+1} - X_k| (inf before the first update)
    updates: jax.Array
    result: jax.Array


def _fixed_point(alg, half_w, yn, start, residual, x0, tol, rtol, max_iter):
    r"""The fixed point $X = Y_n + AX - XA + AXA$, $A = \tfrac12\hat W(X)$, iterated on the
    matrix from `start`: two products per update ($AX$, and $(AX)A$; $XA = (AX)^H$ for
    skew-Hermitian $A$, $X$). It stops

    - when the correction $\max|X_{k+1} - X_k|$ is at most `tol`, or `rtol` times the
      increment $\max|X_{k+1} - Y_n|$ (never less than 16 ulps of $\max|X_{k+1}|$, where
      rounding leaves the iteration: 1-2 ulps at N = 64 ... 512): `successful`;
    - when the correction stops decreasing above that (`stalled`: a contraction's
      corrections decrease, so the step is too large for the iteration), or after
      `max_iter` updates (`max_iterations_reached`).

    Derivatives by the implicit function theorem on `residual` (real coordinates, `x0`).

    **Returns:** `(x, result, iterations, correction, ax)`, `x` in real coordinates and `ax`
    the last update's product (the explicit final update reuses it).
    """
    real = real_dtype(yn.dtype)
    eps = float(jnp.finfo(real).eps)

    def update(s):
        a = half_w(s.x)
        ax = matmul(a, s.x)
        x = yn + ax - adjoint(ax) + matmul(ax, a)
        c = jnp.max(jnp.abs(x - s.x))
        wanted = tol if tol is not None else rtol * jnp.max(jnp.abs(x - yn))
        target = jnp.maximum(16.0 * eps * jnp.max(jnp.abs(x)), wanted)
        updates = s.updates + 1
        result = jnp.select(
            [c <= target, ~jnp.isfinite(c), c >= s.correction, updates >= max_iter],
            [
                RESULTS.successful,
                RESULTS.nonfinite,
                RESULTS.stalled,
                RESULTS.max_iterations_reached,
            ],
            _RUNNING,
        ).astype(jnp.int32)
        return _Iteration(x, ax, c.astype(real), updates, result)

    def solve():
        s = _Iteration(
            start,
            jnp.zeros_like(yn),
            jnp.asarray(jnp.inf, real),
            jnp.zeros((), jnp.int32),
            jnp.asarray(_RUNNING, jnp.int32),
        )
        s = jax.lax.while_loop(lambda s: s.result == _RUNNING, update, batched_like(s, (yn, start)))
        ok = s.result == RESULTS.successful
        return alg.group_coordinates(s.x), ok, (s.result, s.updates, s.correction, s.ax)

    x, _, (result, iterations, res, ax) = implicit_root(lambda xc: residual(xc, 1.0), solve, x0)
    return x, result.astype(jnp.int32), iterations.astype(jnp.int32), res, ax


@jax.custom_jvp
def _rotation(a):
    r"""$B = Q - I$ for the Cayley rotation $Q = (I + A)(I - A)^{-1} = 2V - I$ of a
    skew-adjoint $A$ with $\|A\|_2 < 1$, by matrix products alone:
    $V = (I - A)^{-1} = (I + A)(I + A^2)(I + A^4)\cdots$, each factor one squaring and one
    product, until the factor left out, $(I - A^{2^{k+1}})^{-1}$, is the identity to an
    eighth of an ulp ($\|A^{2^k}\|_F^2 \le \epsilon/8$): $Q$ unitary to round-off, as an LU
    solve makes it, and on a GPU cheaper (an LU of N = 2048 costs about 12 products there),
    and on a CPU free of the LAPACK threads that contend with XLA's. $U = V - I$ is carried
    instead of $V$ ($U \leftarrow U + P + UP$, $P = A^{2^k}$) so that the small $B = 2U$ is
    never the difference of numbers near 1. Four squarings at h = 0.64/N s on Euler–Zeitlin
    ($\|A\|_2 \approx 0.18$: $A^{16}$ is 8e-13, so three leave $Q$ unitary only to that).
    Derivatives by the closed form $dB = 2V\,dA\,V$.

    **Returns:** `(B, converged)`; not converged after 10 squarings ($\|A\|_2$ near 1: a step
    too large for the fixed point too) the step fails, and is redone as substeps."""
    eps = float(jnp.finfo(a.dtype).eps)

    def small(p):
        return jnp.sum(jnp.abs(p) ** 2) <= eps / 8

    def body(s):
        u, p, k = s
        p = matmul(p, p)
        return u + p + matmul(u, p), p, k + 1

    u, p, _ = jax.lax.while_loop(
        lambda s: ~small(s[1]) & (s[2] < 10), body, (a, a, jnp.zeros((), jnp.int32))
    )
    return 2.0 * u, small(p)


@_rotation.defjvp
def _rotation_jvp(primals, tangents):
    (a,), (t_a,) = primals, tangents
    b, converged = _rotation(a)
    v = 0.5 * b + jnp.eye(a.shape[-1], dtype=a.dtype)  # (I - A)^{-1}
    return (b, converged), (
        2.0 * matmul(matmul(v, t_a), v),
        jnp.zeros(converged.shape, jax.dtypes.float0),
    )
