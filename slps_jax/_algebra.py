"""The Lie algebra a system lives on: so(3)* as 3-vectors (`SO3`), or so(n)* as skew
matrices (`so(n)`)."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from . import _so3


class SO3Algebra:
    """so(3)* identified with $\\mathbb R^3$ by `hat`: what the systems and methods need of it.

    - `dim`: the dimension of a state (3).
    - `bracket(y, x)`: the Lie–Poisson vector field $B(y)\\,x = y \\times x$ of a gradient
      `x`, over the last axis.
    - `structure_matrix(y)`: $B(y) = \\hat y$.
    - `casimirs(y)`: the Casimir functions, here $C(y) = \\tfrac12|y|^2$, shape `(..., 1)`.
    - `exp`, `cayley`: the group maps, from `slps_jax.so3`.

    One instance, `SO3`, is shared by every so(3) system; it is static data of a system
    (hashable, compared by identity).
    """

    name = "so(3)"
    dim = 3
    shape = (3,)
    matrix = False  # states are 3-vectors (the component fast paths of the methods)

    def bracket(self, y, x):
        return jnp.cross(y, x)

    def structure_matrix(self, y):
        return _so3.hat(y)

    def casimirs(self, y):
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2, axis=-1, keepdims=True)

    exp = staticmethod(_so3.exp)
    cayley = staticmethod(_so3.cayley)

    def to_matrix(self, y):
        r"""The state as a skew matrix, $\hat y$ (methods written for matrices use it)."""
        return _so3.hat(y)

    def from_matrix(self, m):
        return _so3.vee(m)

    def gradient(self, g):
        """The gradient for the pairing from JAX's gradient of a function of the state."""
        return g

    def norm_sq(self, y):
        r"""$\langle y, y\rangle = |y|^2$ over the state axes."""
        return jnp.sum(jnp.asarray(y) ** 2, axis=-1)

    def pairing(self, x, y):
        r"""$\langle x, y\rangle = x \cdot y$ over the state axes."""
        return jnp.sum(x * y, axis=-1)

    def __repr__(self):
        return "SO3"


SO3 = SO3Algebra()


class SOnAlgebra:
    r"""so(n)* for $n \ge 3$: states are skew-symmetric `(n, n)` matrices $Y$.

    - Pairing $\langle X, Y\rangle = \tfrac12\operatorname{tr}(X^TY) = \sum_{i<j}X_{ij}Y_{ij}$
      (for $n = 3$ and $Y = \hat y$ it is $x\cdot y$, so the so(3) conventions carry over);
      `norm_sq(Y)` is $\langle Y, Y\rangle$.
    - Gradients $\nabla H(Y)$ are skew matrices for this pairing (`gradient` makes one from
      JAX's entrywise gradient $G$: $G - G^T$).
    - `bracket(Y, X)`: the Lie–Poisson field $[Y, X] = YX - XY$ of a gradient $X$: the system is
      $dY = [Y, \nabla H_0]\,dt + \sum_r [Y, \nabla H_r]\circ dW_r$.
    - `casimirs(Y)`: $\operatorname{tr}(Y^{2k})$, $k = 1, \dots, \lfloor n/2\rfloor$.
    - `coordinates(Y)`: the `n(n-1)/2` entries $Y_{ij}$, $i < j$ (orthonormal for the
      pairing), and `from_coordinates`.

    `so(n)` returns the one instance for each `n` (static data of a system).
    """

    matrix = True

    def __init__(self, n):
        self.n = n
        self.dim = n * (n - 1) // 2
        self.shape = (n, n)
        self.name = f"so({n})"
        self._rows, self._cols = np.triu_indices(n, 1)

    def __repr__(self):
        return f"so({self.n})"

    def bracket(self, y, x):
        return y @ x - x @ y

    def casimirs(self, y):
        y = jnp.asarray(y)
        y2 = y @ y
        out, p = [], y2
        for k in range(self.n // 2):
            if k:
                p = p @ y2
            out.append(jnp.trace(p, axis1=-2, axis2=-1))
        return jnp.stack(out, axis=-1)

    def to_matrix(self, y):
        return y

    def from_matrix(self, m):
        return m

    def gradient(self, g):
        return g - jnp.swapaxes(g, -1, -2)

    def norm_sq(self, y):
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2, axis=(-2, -1))

    def pairing(self, x, y):
        return 0.5 * jnp.sum(x * y, axis=(-2, -1))

    def cayley(self, x):
        r"""The Cayley map so(n) -> SO(n), $(I - X)^{-1}(I + X) = I + 2X + O(X^2)$, for one
        skew `x`. Gauss–Jordan elimination without pivoting, written out: stable here because
        $I - X$ has the symmetric part $I$, and on a CPU some times faster under `vmap`
        than a batched LAPACK solve of small matrices."""
        eye = jnp.eye(self.n, dtype=x.dtype)
        m = jnp.concatenate([eye - x, eye + x], axis=1)
        for k in range(self.n):
            row = m[k] / m[k, k]
            m = (m - jnp.outer(m[:, k], row)).at[k].set(row)
        return m[:, self.n:]

    def coordinates(self, y):
        return y[..., self._rows, self._cols]

    def from_coordinates(self, x):
        m = jnp.zeros(x.shape[:-1] + self.shape, x.dtype)
        m = m.at[..., self._rows, self._cols].set(x)
        return m - jnp.swapaxes(m, -1, -2)


@functools.cache
def _so(n):
    return SOnAlgebra(n)


def so(n):
    """The Lie algebra so(n)* of skew `(n, n)` matrices, `n >= 3` (see `SOnAlgebra`): pass it
    as `LiePoissonSystem(..., algebra=so(n))`."""
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 3:
        raise ValueError(f"so(n) needs an integer n >= 3, got {n!r}.")
    return _so(int(n))
