"""so(n)* for n >= 3: real skew-symmetric matrices."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from .base import AbstractSquareMatrixAlgebra, adjoint, skew_from_upper, upper_indices


class SOnAlgebra(AbstractSquareMatrixAlgebra):
    r"""so(n)* for $n \ge 3$: states are skew-symmetric `(n, n)` matrices $Y$.

    - Pairing $\langle X, Y\rangle = \tfrac12\operatorname{tr}(X^TY) = \sum_{i<j}X_{ij}Y_{ij}$
      (for $n = 3$ and $Y = \hat y$ it is $x\cdot y$, so the so(3) conventions carry over).
    - Gradients $\nabla H(Y)$ are skew matrices for this pairing ($G - G^T$ from JAX's
      entrywise gradient $G$); the field of a gradient $X$ is $[Y, X] = YX - XY$.
    - `casimirs(Y)`: $\operatorname{tr}(Y^{2k})$, $k = 1, \dots, \lfloor n/2\rfloor$.
    - `coordinates(Y)`: the `n(n-1)/2` entries $Y_{ij}$, $i < j$.

    `so(n)` returns it (static data of a system: its one field, `n`, is static).
    """

    condition = "skew-symmetric"

    @property
    def dim(self):
        return self.n * (self.n - 1) // 2

    @property
    def name(self):
        return f"so({self.n})"

    def pairing(self, x, y):
        return 0.5 * jnp.sum(x * y, axis=(-2, -1))

    def gradient(self, g):
        return g - jnp.swapaxes(g, -1, -2)

    def casimirs(self, y):
        y = jnp.asarray(y)
        y2 = y @ y
        out, p = [], y2
        for k in range(self.n // 2):
            if k:
                p = p @ y2
            out.append(jnp.trace(p, axis1=-2, axis2=-1))
        return jnp.stack(out, axis=-1)

    def project(self, m):
        return 0.5 * (m - adjoint(m))

    def coordinates(self, y):
        rows, cols = upper_indices(self.n)
        return y[..., rows, cols]

    def from_coordinates(self, x):
        return skew_from_upper(x, self.n)


@functools.cache
def _so(n):
    return SOnAlgebra(n)


def so(n):
    """The Lie algebra so(n)* of skew `(n, n)` matrices (see `SOnAlgebra`): pass it as
    `LiePoissonSystem(..., algebra=so(n))`.

    **Arguments:**

    - `n`: the matrix size, an integer `n >= 3` (else `ValueError`).

    **Returns:** the algebra, an `AbstractAlgebra`: the one instance for each `n`.
    """
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 3:
        raise ValueError(f"so(n) needs an integer n >= 3, got {n!r}.")
    return _so(int(n))
