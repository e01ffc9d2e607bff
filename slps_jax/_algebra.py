"""The Lie algebra a system lives on: for now so(3)*, identified with R^3."""

from __future__ import annotations

import jax.numpy as jnp

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

    def bracket(self, y, x):
        return jnp.cross(y, x)

    def structure_matrix(self, y):
        return _so3.hat(y)

    def casimirs(self, y):
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2, axis=-1, keepdims=True)

    exp = staticmethod(_so3.exp)
    cayley = staticmethod(_so3.cayley)

    def __repr__(self):
        return "SO3"


SO3 = SO3Algebra()
