"""so(3)* as 3-vectors: the fast component path of the rigid body."""

from __future__ import annotations

import jax.numpy as jnp

from .. import so3
from .base import SO3_VECTORS, AbstractAlgebra


class SO3Algebra(AbstractAlgebra):
    r"""so(3)* identified with $\mathbb R^3$ by `hat`: states are 3-vectors $y$, the matrix
    of a state is $\hat y$, the pairing $x\cdot y$ (that of so(3) as skew matrices,
    $\tfrac12\operatorname{tr}\hat x^T\hat y$), the bracket $[y, x] = y \times x$, the
    Casimir $C(y) = \tfrac12|y|^2$. Methods with a closed form on components declare
    `SO3_VECTORS`. One instance, `SO3`, is shared by every so(3) system.
    """

    name = "so(3)"
    dim = 3
    shape = (3,)
    matrix_size = 3
    condition = "a 3-vector"
    structure = frozenset({SO3_VECTORS})

    def distance(self, y):
        return 0.0  # (every 3-vector is a state)

    def pairing(self, x, y):
        return jnp.sum(x * y, axis=-1)

    def coordinates(self, y):
        return y

    def from_coordinates(self, x):
        return x

    def gradient(self, g):
        return g

    def bracket(self, y, x):
        return jnp.cross(y, x)

    def casimirs(self, y):
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2, axis=-1, keepdims=True)

    def structure_matrix(self, y):
        return so3.hat(y)

    def to_matrix(self, y):
        return so3.hat(y)

    def from_matrix(self, m):
        return so3.vee(m)

    def project(self, m):
        return so3.vee(m)  # the axial vector of the skew part

    def __repr__(self):
        return "SO3"


SO3 = SO3Algebra()
