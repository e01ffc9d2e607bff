"""The isospectral midpoint rule of Modin & Viviani, with noise."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .._algebra import adjoint, matmul
from .._support.checks import check_options, real_dtype
from .._support.solution import RESULTS
from .base import AbstractMethod, StepInfo, StrongOrders, default_tol, finite_result
from .newton import implicit_root, jacobian_mode, newton, solve_array


@dataclasses.dataclass(frozen=True)
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

    Solved for $X$ from $X = Y_n$ (`jacobian` below).

    **Arguments:**

    - `tol`: max-norm residual tolerance (default `64 eps` of the dtype).
    - `max_iter`: updates allowed (default `None`: 12 for Newton, 48 for the other modes).
    - `jacobian`: `"auto"` (default: `"newton"` up to so(5), `"identity"` above),
      `"newton"` (the Jacobian by autodiff at every update: quadratic convergence, 2–3
      updates; on the real coordinates of $X$), `"identity"` (the fixed-point iteration
      $X = Y_n + \tfrac12[\hat W, X] + \tfrac14\hat W X\hat W$ on the matrix, two
      products per update, complex ones as three real products: linear convergence at a
      rate $O(h^{1/2})$ and no linear algebra, 4–7 updates at $h = 2^{-6}$, the fastest from
      so(8) on and on su(N) (Euler–Zeitlin: 8–25 updates at N = 8 … 128, h = 0.01 s; the
      linearly implicit iteration of quflow, $X = A^{-1}Y_nA^{-H}$, $A = I - \tfrac12\hat W$,
      took 8–20 updates there and more time per step, `docs/zeitlin.md`); it can fail to
      converge at large steps and strong noise, where Newton does not; a failed step is
      reported, and split into substeps by the driver's `retry_substeps`).
    - `final_update`: how $Y_{n+1}$ is formed at the root: `"explicit"`
      ($Y_n + [\hat W, X]$, one matrix product, quflow's form; isospectral to the solver's
      tolerance), `"cayley"` ($QY_nQ^H$: an LU and two products; isospectral to round-off
      whatever the tolerance), `"auto"` (default: `"explicit"` in double precision,
      `"cayley"` in single). Over $10^4$ steps of Euler–Zeitlin at N = 32 the Casimirs
      drifted by up to 3e-13 (explicit) and 7e-14 (Cayley) in complex128, 5e-4 and 2e-6
      in complex64; at N = 256 on a CPU a Cayley step cost 1.6x an explicit one in
      complex128 (95 against 60 ms), 1.7x in complex64.

    **References:** K. Modin & M. Viviani, *A Casimir preserving scheme for long-time
    simulation of spherical ideal hydrodynamics*, J. Fluid Mech. 884 (2020) A22;
    S. Ephrati, E. Jansson, A. Lang & E. Luesink, *An exponential map free implicit midpoint
    method for stochastic Lie–Poisson systems*, arXiv:2408.16701.
    """

    strong_orders = StrongOrders(one=1.0, increments=0.5, areas=1.0)
    poisson = True

    tol: float | None = None
    max_iter: int | None = None
    jacobian: str = "auto"
    final_update: str = "auto"

    def _cayley(self, dtype):
        """Whether the step is the Cayley rotation (`final_update`)."""
        if self.final_update == "auto":
            return jnp.finfo(dtype).bits < 64
        return self.final_update == "cayley"

    def __post_init__(self):
        check_options(self)
        if self.final_update not in ("auto", "explicit", "cayley"):
            raise ValueError(
                f"IsospectralMidpoint: final_update must be 'auto', 'explicit' "
                f"or 'cayley', got {self.final_update!r}."
            )
        if self.jacobian not in ("auto", "newton", "identity"):
            raise ValueError(
                f"IsospectralMidpoint: jacobian must be 'auto', 'newton' or "
                f"'identity', got "
                f"{self.jacobian!r}."
            )

    def step(self, system, y, dt, dW):
        dtype = y.dtype
        tol = default_tol(dtype) if self.tol is None else self.tol
        alg = system.algebra
        yn = alg.to_matrix(y)
        eye = jnp.eye(yn.shape[-1], dtype=yn.dtype)

        def half_w(x):  # (1/2) W^ = -(1/2) grad K(X) for a matrix X of the group's algebra
            return -0.5 * alg.to_matrix(system.step_gradient(alg.project_group(x), dt, dW))

        # The midpoint X lies in the group's Lie algebra, not always in the system's: on
        # su(N), tr Y_n = 0 gives tr X = tr((W/2)^2 X), and X is solved for in u(N).
        def residual(xc, lam):  # (I - W/2) X (I + W/2) - Y_n, on real coordinates
            x = alg.from_group_coordinates(xc)
            b = eye - half_w(x)
            return alg.group_coordinates(b @ x @ adjoint(b)) - x0

        x0 = alg.group_coordinates(yn)
        mode = jacobian_mode(self.jacobian, alg.group_dim, large="identity")
        if mode == "identity":
            xc, result, it, res = _fixed_point(
                alg, half_w, yn, residual, x0, tol, 48 if self.max_iter is None else self.max_iter
            )
        else:
            xc, result, it, res = solve_array(
                residual, x0, x0, tol=tol, max_iter=self.max_iter, jacobian=mode
            )
        x = alg.from_group_coordinates(xc)
        a = half_w(x)
        if self._cayley(dtype):  # Q Y_n Q^H, Q = (I - A)^{-1}(I + A), A = W/2
            y_next = alg.act(alg.cayley(a), y).astype(dtype)
        else:  # (I + A) X (I - A) = Y_n + 2(AX - XA) at the root: one product
            ax = matmul(a, x)
            y_next = alg.project(yn + 2.0 * (ax - adjoint(ax))).astype(dtype)
        return y_next, StepInfo(finite_result(y_next, result), it, res.astype(real_dtype(dtype)))


def _fixed_point(alg, half_w, yn, residual, x0, tol, max_iter):
    r"""The fixed point $X = Y_n + AX - XA + AXA$, $A = \tfrac12\hat W(X)$, iterated on the
    matrix: two products per update ($AX$, and $(AX)A$; $XA = (AX)^H$ for skew-Hermitian
    $A$, $X$), no coordinates, for complex matrices on their real and imaginary parts.
    Derivatives by the implicit function theorem on `residual` (real coordinates, `x0`).

    **Returns:** `(x, result, iterations, residual)` as `solve_array`."""
    complex_ = jnp.iscomplexobj(yn)
    split = (lambda m: (jnp.real(m), jnp.imag(m))) if complex_ else (lambda m: (m,))
    join = (lambda p: jax.lax.complex(*p)) if complex_ else (lambda p: p[0])

    def update(parts):  # (X - F(X), and the identity as the linear solve)
        x = join(parts)
        a = half_w(x)
        ax = matmul(a, x)
        return split(x - (yn + ax - adjoint(ax) + matmul(ax, a))), lambda r: r

    def solve():
        s = newton(update, split(yn), tol=tol, max_iter=max_iter)
        return (
            alg.group_coordinates(join(s.x)),
            s.result == RESULTS.successful,
            (s.result, s.iterations, s.residual),
        )

    x, _, (result, iterations, res) = implicit_root(lambda xc: residual(xc, 1.0), solve, x0)
    return x, result.astype(jnp.int32), iterations.astype(jnp.int32), res
