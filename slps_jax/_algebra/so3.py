"""so(3)* as 3-vectors, with every closed form of so(3) and SO(3) in one place.

Formulas are written once on *components*: a vector is a tuple of three arrays, a matrix a
tuple of three rows (`vec`, `mat` and their inverses convert from and to arrays). Under
`vmap` each component becomes one array over the batch, so the integrators' hot loops are
element-wise arithmetic on long vectors (structure of arrays) rather than many tiny batched
3x3 products, which XLA executes poorly on CPU; arrays of shape `(B, 3)` inside a loop
(where batching puts the batch axis first) would be strided. The public toolkit
`slps_jax.so3` is these formulas on arrays; `SO3Algebra` is so(3)* with the components as
the form a method's loop carries (`local`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .base import AbstractAlgebra


def vec(x):
    """Array `(..., 3)` -> tuple of three arrays."""
    return (x[..., 0], x[..., 1], x[..., 2])


def unvec(v):
    """Tuple of three arrays -> array `(..., 3)`."""
    return jnp.stack(jnp.broadcast_arrays(*v), axis=-1)


def mat(m):
    """Array `(..., 3, 3)` -> tuple of three rows."""
    return tuple(tuple(m[..., i, j] for j in range(3)) for i in range(3))


def unmat(m):
    """Tuple of three rows -> array `(..., 3, 3)`."""
    return jnp.stack([unvec(row) for row in m], axis=-2)


def add(a, b):
    return tuple(x + y for x, y in zip(a, b))


def sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def scale(s, a):
    return tuple(s * x for x in a)


def mul(a, b):
    """Component-wise product (a diagonal matrix times a vector)."""
    return tuple(x * y for x, y in zip(a, b))


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def mv(m, x):
    """Matrix times vector."""
    return tuple(dot(row, x) for row in m)


def mtv(m, x):
    """Transposed matrix times vector."""
    return tuple(m[0][j] * x[0] + m[1][j] * x[1] + m[2][j] * x[2] for j in range(3))


def transpose(m):
    return tuple(tuple(m[i][j] for i in range(3)) for j in range(3))


def mm(a, b):
    """Matrix product."""
    return tuple(
        tuple(a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3))
        for i in range(3)
    )


def madd(*ms):
    return tuple(tuple(sum(m[i][j] for m in ms) for j in range(3)) for i in range(3))


def mscale(s, m):
    return tuple(tuple(s * m[i][j] for j in range(3)) for i in range(3))


def diag_right(m, d):
    """`m @ diag(d)`."""
    return tuple(tuple(m[i][j] * d[j] for j in range(3)) for i in range(3))


def outer(a, b):
    return tuple(tuple(a[i] * b[j] for j in range(3)) for i in range(3))


def trace(m):
    return m[0][0] + m[1][1] + m[2][2]


def shift(m, s):
    """`m + s Id`."""
    return tuple(tuple(m[i][j] + s if i == j else m[i][j] for j in range(3)) for i in range(3))


def hat(v):
    z = jnp.zeros_like(v[0])
    return ((z, -v[2], v[1]), (v[2], z, -v[0]), (-v[1], v[0], z))


def vee_skew(m):
    """`vee(skew(m))`, the axial vector of the skew part."""
    return (
        0.5 * (m[2][1] - m[1][2]),
        0.5 * (m[0][2] - m[2][0]),
        0.5 * (m[1][0] - m[0][1]),
    )


def solve3(m, b):
    """Solve `m x = b` by cofactors (Cramer's rule): far cheaper than a batched LU for 3x3."""
    c00 = m[1][1] * m[2][2] - m[1][2] * m[2][1]
    c01 = m[1][2] * m[2][0] - m[1][0] * m[2][2]
    c02 = m[1][0] * m[2][1] - m[1][1] * m[2][0]
    c10 = m[0][2] * m[2][1] - m[0][1] * m[2][2]
    c11 = m[0][0] * m[2][2] - m[0][2] * m[2][0]
    c12 = m[0][1] * m[2][0] - m[0][0] * m[2][1]
    c20 = m[0][1] * m[1][2] - m[0][2] * m[1][1]
    c21 = m[0][2] * m[1][0] - m[0][0] * m[1][2]
    c22 = m[0][0] * m[1][1] - m[0][1] * m[1][0]
    inv_det = 1.0 / (m[0][0] * c00 + m[0][1] * c01 + m[0][2] * c02)
    # The inverse is the transposed cofactor matrix over the determinant.
    return (
        inv_det * (c00 * b[0] + c10 * b[1] + c20 * b[2]),
        inv_det * (c01 * b[0] + c11 * b[1] + c21 * b[2]),
        inv_det * (c02 * b[0] + c12 * b[1] + c22 * b[2]),
    )


# Matrices that may be diagonal: a tuple of three arrays (the diagonal) or of three rows. A
# closed form that is diagonal (a diagonal quadratic Hamiltonian's Hessian) stays so through
# these, at trace time, so that no product with a zero is computed.


def is_diagonal(m):
    return not isinstance(m[0], tuple)


def full(m):
    """The rows of `m`."""
    if not is_diagonal(m):
        return m
    z = jnp.zeros_like(m[0])
    return ((m[0], z, z), (z, m[1], z), (z, z, m[2]))


def scale_any(s, m):
    return scale(s, m) if is_diagonal(m) else mscale(s, m)


def add_any(a, b):
    """`a + b`, diagonal if both are; `None` is zero."""
    if a is None or b is None:
        return b if a is None else a
    if is_diagonal(a) and is_diagonal(b):
        return add(a, b)
    if is_diagonal(a):
        a, b = b, a
    if is_diagonal(b):
        return tuple(
            tuple(a[i][j] + b[i] if i == j else a[i][j] for j in range(3)) for i in range(3)
        )
    return madd(a, b)


def mm_any(a, m):
    """`a @ m` for rows `a`."""
    return diag_right(a, m) if is_diagonal(m) else mm(a, m)


def mtv_any(m, x):
    """`m^T x`."""
    return mul(m, x) if is_diagonal(m) else mtv(m, x)


def small_angle_threshold(dtype):
    # Below this theta^2 the two-term Taylor series is exact to round-off: its first
    # neglected term is O(theta^4) = O(eps).
    return math.sqrt(float(jnp.finfo(dtype).eps))


def exp_coefficients(theta2):
    """`sin(t)/t`, `(1 - cos t)/t^2` and `(t - sin t)/t^3` at `t^2 = theta2`.

    The "double where" keeps gradients finite at t = 0: the exact branch never sees t = 0,
    the series branch is used there. `1 - cos t` is computed as `2 sin^2(t/2)`, which does not
    cancel.
    """
    small = theta2 < small_angle_threshold(theta2.dtype)
    t2 = jnp.where(small, 1.0, theta2)
    t = jnp.sqrt(t2)
    s = jnp.sin(t)
    half = jnp.sin(0.5 * t) / (0.5 * t)
    a = jnp.where(small, 1.0 - theta2 / 6.0, s / t)
    b = jnp.where(small, 0.5 - theta2 / 24.0, 0.5 * half * half)
    c = jnp.where(small, 1.0 / 6.0 - theta2 / 120.0, (t - s) / (t2 * t))
    return a, b, c


def exp(xi):
    """Rodrigues' formula on components: `exp(hat xi) = Id + a X + b X^2`."""
    a, b, _ = exp_coefficients(dot(xi, xi))
    x = hat(xi)
    return shift(madd(mscale(a, x), mscale(b, mm(x, x))), 1.0)


def cayley(xi):
    """Cayley map on components: `(Id - X/2)^{-1} (Id + X/2) = Id + 4/(4+|xi|^2) (X + X^2/2)`."""
    x = hat(xi)
    s = 4.0 / (4.0 + dot(xi, xi))
    return shift(madd(mscale(s, x), mscale(0.5 * s, mm(x, x))), 1.0)


class SO3Algebra(AbstractAlgebra):
    r"""so(3)* identified with $\mathbb R^3$ by `hat`: states are 3-vectors $y$, the matrix
    of a state is $\hat y$, the pairing $x\cdot y$ (that of so(3) as skew matrices,
    $\tfrac12\operatorname{tr}\hat x^T\hat y$), the bracket $[y, x] = y \times x$, the
    Casimir $C(y) = \tfrac12|y|^2$. Its `local` form is the components (a system's step
    on them: `_systems/fields.py`). One instance, `SO3`, is shared by every so(3) system.
    """

    condition = "a 3-vector"

    @property
    def name(self):
        return "so(3)"

    @property
    def dim(self):
        return 3

    @property
    def shape(self):
        return (3,)

    @property
    def matrix_size(self):
        return 3

    def distance(self, y):
        return 0.0  # (every 3-vector is a state)

    def spectral_norm(self, y):
        return float(np.sqrt(np.sum(np.asarray(y) ** 2)))  # (the eigenvalues of hat y: 0, ±i|y|)

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

    def bracket_sum(self, x, y):
        return jnp.sum(self.bracket(x, y), axis=0)

    def casimirs(self, y):
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2, axis=-1, keepdims=True)

    def structure_matrix(self, y):
        return self.to_matrix(y)

    def to_matrix(self, y):
        return unmat(hat(vec(jnp.asarray(y))))

    def from_matrix(self, m):
        return unvec(vee_skew(mat(jnp.asarray(m))))

    def project(self, m):
        return self.from_matrix(m)  # the axial vector of the skew part

    # -- the form a method's loop carries: the components

    def local(self, y):
        return vec(y)

    def from_local(self, x):
        return unvec(x)

    def local_coordinates(self, x):
        return x  # (the components are the coordinates)

    def from_local_coordinates(self, u):
        return u

    def __repr__(self):
        return "SO3"


SO3 = SO3Algebra()
"""so(3)* as 3-vectors (`SO3Algebra`): the algebra of `RigidBody` and of every so(3) system,
one shared instance (the default `algebra=` of `LiePoissonSystem`)."""
