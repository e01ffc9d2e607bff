"""su(N)* for N >= 2: traceless skew-Hermitian complex matrices."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from .base import AbstractSquareMatrixAlgebra, adjoint, skew_from_upper, upper_indices


class SUnAlgebra(AbstractSquareMatrixAlgebra):
    r"""su(N)* for $N \ge 2$: states are traceless skew-Hermitian `(N, N)` complex matrices
    $W$ (complex64 or complex128, following the system's real dtype).

    - Pairing $\langle X, Y\rangle = \tfrac12\operatorname{Re}\operatorname{tr}(X^HY)$: on real
      skew matrices it is so(n)'s $\tfrac12\operatorname{tr}(X^TY)$, so so(n) ⊂ su(n) keeps
      its pairing.
    - Gradients are the traceless skew-Hermitian part of $2\bar G$, $G$ JAX's gradient of a
      real function of $W$ (JAX returns $\partial_{\operatorname{Re}} -
      i\,\partial_{\operatorname{Im}}$); the field of a gradient $X$ is $[W, X]$.
    - `casimirs(W)`: $\operatorname{tr}W^k$, $k = 2, \dots, N$, in real form (the real part
      for even $k$, the imaginary part for odd $k$: the other part is zero).
    - `coordinates(W)`: the real and imaginary parts of $W_{ij}$, $i < j$, and $N - 1$
      coordinates of the diagonal in an orthonormal basis of the traceless diagonal matrices
      ($\sqrt{2/(k(k+1))}\operatorname{diag}(i, \dots, i, -ki, 0, \dots)$), `N² - 1` in all.

    `su(N)` returns the one instance for each `N`.
    """

    is_complex = True
    condition = "traceless and skew-Hermitian"

    @property
    def dim(self):
        return self.n * self.n - 1

    @property
    def name(self):
        return f"su({self.n})"

    def pairing(self, x, y):
        return 0.5 * jnp.sum(jnp.real(jnp.conj(x) * y), axis=(-2, -1))

    def gradient(self, g):
        return self.project(2.0 * jnp.conj(g))

    def casimirs(self, y):
        r"""$\operatorname{tr}W^k$, $k = 2, \dots, N$, real, over leading axes: the real part
        for even $k$, the imaginary part for odd $k$ (the other part is zero). With the
        eigenvalues $i\lambda_j$ of $W$, $\operatorname{tr}W^k = i^k\sum_j\lambda_j^k$: the
        odd ones are odd moments of the vorticity, often near zero, so a drift is best
        measured relative to $\sum_j|\lambda_j|^k$, not to the value itself."""
        y = jnp.asarray(y)
        out, p = [], y
        for k in range(2, self.n + 1):
            p = p @ y
            t = jnp.trace(p, axis1=-2, axis2=-1)
            out.append(jnp.real(t) if k % 2 == 0 else jnp.imag(t))
        return jnp.stack(out, axis=-1)

    def project(self, m):
        s = 0.5 * (m - adjoint(m))
        tr = jnp.trace(s, axis1=-2, axis2=-1)[..., None, None] / self.n
        return s - tr * jnp.eye(self.n, dtype=s.dtype)

    def distance(self, y):
        return max(super().distance(y), abs(complex(np.trace(y))) / self.n)

    @property
    def group_dim(self):
        return self.n * self.n  # u(N): su(N) and the centre

    def group_coordinates(self, m):
        return jnp.concatenate(
            [
                self.coordinates(self.project(m)),
                jnp.imag(jnp.trace(m, axis1=-2, axis2=-1))[..., None] / np.sqrt(2.0 * self.n),
            ],
            axis=-1,
        )

    def from_group_coordinates(self, x):
        centre = (1j * np.sqrt(2.0 / self.n)) * x[..., -1:, None]
        return self.from_coordinates(x[..., :-1]) + centre * jnp.eye(self.n, dtype=centre.dtype)

    def project_group(self, m):
        """The traceless part of a matrix of u(N): skew-Hermitian already, up to rounding
        (no transpose: `project`'s cost a third of a fixed-point update in an ensemble at
        N = 48)."""
        tr = jnp.trace(m, axis1=-2, axis2=-1)[..., None, None] / self.n
        return m - tr * jnp.eye(self.n, dtype=m.dtype)

    def coordinates(self, y):
        rows, cols = upper_indices(self.n)
        upper = y[..., rows, cols]
        d = jnp.imag(jnp.diagonal(y, axis1=-2, axis2=-1))
        diag = 0.5 * d @ jnp.asarray(_diagonal_basis(self.n).T, d.dtype)
        return jnp.concatenate([jnp.real(upper), jnp.imag(upper), diag], axis=-1)

    def from_coordinates(self, x):
        k = self.n * (self.n - 1) // 2
        dtype = jnp.result_type(x.dtype, jnp.complex64)
        upper = (x[..., :k] + 1j * x[..., k : 2 * k]).astype(dtype)
        m = skew_from_upper(upper, self.n)
        d = x[..., 2 * k :] @ jnp.asarray(_diagonal_basis(self.n), x.dtype)
        return m + 1j * d[..., None, :] * jnp.eye(self.n, dtype=x.dtype)


@functools.cache
def _diagonal_basis(n):
    """The `(n - 1, n)` orthonormal basis (for $\tfrac12\\sum_j d_j^2$) of the traceless
    diagonals: row `k - 1` is $\\sqrt{2/(k(k+1))}\\,(1, \\dots, 1, -k, 0, \\dots)$."""
    basis = np.zeros((n - 1, n))
    for k in range(1, n):
        basis[k - 1, :k] = 1.0
        basis[k - 1, k] = -k
        basis[k - 1] *= np.sqrt(2.0 / (k * (k + 1)))
    return basis


@functools.cache
def _su(n):
    return SUnAlgebra(n)


def su(n):
    """The Lie algebra su(N)* of traceless skew-Hermitian `(N, N)` matrices (see
    `SUnAlgebra`): pass it as `LiePoissonSystem(..., algebra=su(N))`.

    **Arguments:**

    - `n`: the matrix size $N$, an integer `N >= 2` (else `ValueError`).

    **Returns:** the algebra, an `AbstractAlgebra`: the one instance for each `N`.
    """
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"su(N) needs an integer N >= 2, got {n!r}.")
    return _su(int(n))
