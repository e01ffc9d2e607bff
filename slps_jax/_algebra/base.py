"""The Lie algebra interface: what systems and methods may use of an algebra.

An algebra is static data of a system: an `equinox.Module` whose fields are static (so(n)'s
and su(N)'s size), hashed and compared by value, and a pytree with no leaves. A state `y` is
an array of shape `shape` and dtype `state_dtype(dtype)` (real, or complex for su(N)). Every
algebra here is a matrix algebra; its states may be stored in another form (so(3) as
3-vectors), converted by `to_matrix` / `from_matrix`.

What a method may use, and nothing else:

- the vector space: `shape`, `dim` (real dimension), `state_dtype`, `coordinates` /
  `from_coordinates` (real coordinates, orthonormal for the pairing), `pairing`, `norm_sq`;
- the Lie–Poisson structure: `gradient` (the gradient for the pairing from JAX's gradient of
  a real function of the state), `bracket(y, x)` (the field $[y, x]$ of a gradient `x`:
  $dy = [y, \\nabla H]$), `bracket_sum` (of stacks, for the Lévy-area term), `casimirs`;
- the form a method's loop carries (`local`, `from_local`: the state, components on so(3))
  and its real coordinates (`local_coordinates`, `from_local_coordinates`); a system's step
  in that form is the system's (`local_field`, `coordinate_field`, ...), not the algebra's;
- the group: `to_matrix`, `from_matrix`, `project` (the state nearest to a matrix),
  `adjoint` ($M^H$), `cayley` ($(I - X)^{-1}(I + X)$), `act(a, y)` ($a\\,y\\,a^{-1}$ for a
  unitary `a`), and real coordinates of the group's Lie algebra (`group_dim`,
  `group_coordinates`, `from_group_coordinates`: u(N) for su(N)) and `project_group`;
- `validate` (a concrete state, with a clear message) and `random_state` (for tests).

The defaults below are written once for every matrix algebra; an algebra overrides what it
has in closed form.
"""

from __future__ import annotations

import abc
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def adjoint(m):
    """$M^H$ over the last two axes (the transpose for real matrices)."""
    return jnp.conj(jnp.swapaxes(m, -1, -2))


def matmul(a, b):
    """`a @ b`; for complex matrices by Gauss's three real products
    ($(A_r + iA_i)(B_r + iB_i)$ from $A_rB_r$, $A_iB_i$, $(A_r + A_i)(B_r + B_i)$), normwise
    as accurate: on a CPU XLA's complex product took 4.0 ms at N = 256, the three real ones
    1.3 ms (NumPy's 1.5 ms)."""
    if not (jnp.iscomplexobj(a) or jnp.iscomplexobj(b)):
        return a @ b
    ar, ai, br, bi = jnp.real(a), jnp.imag(a), jnp.real(b), jnp.imag(b)
    t1, t2, t3 = ar @ br, ai @ bi, (ar + ai) @ (br + bi)
    return jax.lax.complex(t1 - t2, t3 - t1 - t2)


def skew_bracket_sum(x, y):
    r"""$\sum_q [X_q, Y_q]$ for stacks `(q, n, n)` of skew-adjoint matrices: $M - M^H$,
    $M = \sum_q X_qY_q$ one product of inner size $qn$ (`matmul`), since
    $Y_qX_q = (X_qY_q)^H$: the work of $q$ products, not of $2q$."""
    q, n = x.shape[0], x.shape[-1]
    m = matmul(jnp.swapaxes(x, 0, 1).reshape(n, q * n), y.reshape(q * n, n))
    return m - adjoint(m)


def skew_from_upper(u, n):
    """The `(n, n)` matrix with the entries `u` (`(..., n(n-1)/2)`, in `np.triu_indices(n, 1)`
    order) above the diagonal, their negated conjugates below it and zeros on it. A gather
    with fixed indices: a scatter into a zero matrix runs element by element on a GPU (0.65 s
    at n = 256 on an H200, where the gather takes microseconds)."""
    i, j = np.indices((n, n))
    g = u[..., _upper_position(n)]
    return jnp.where(i < j, g, jnp.where(i > j, -jnp.conj(g), jnp.zeros((), g.dtype)))


@functools.cache
def upper_indices(n):
    """`np.triu_indices(n, 1)`: the rows and columns of the entries above the diagonal."""
    return np.triu_indices(n, 1)


@functools.cache
def _upper_position(n):
    """`p[i, j]`: the position of `(min(i, j), max(i, j))` in `np.triu_indices(n, 1)` (0 on
    the diagonal)."""
    rows, cols = upper_indices(n)
    p = np.zeros((n, n), dtype=np.int64)
    p[rows, cols] = np.arange(rows.size)
    return p + p.T


class AbstractAlgebra(eqx.Module):
    r"""The interface of the Lie algebra $\mathfrak g^*$ a system lives on: the state space,
    the pairing $\langle x, y\rangle$, the Lie–Poisson field $[y, \nabla H]$ and the
    Casimirs, and the forms of a step that methods are written on (the list in this
    module's docstring; `docs/algebras.md`).

    The algebras are `SO3` (3-vectors), `so(n)` (skew matrices) and `su(N)` (traceless
    skew-Hermitian matrices, complex states): `equinox.Module`s whose fields are static
    (the size), compared by value, static data of a system (`LiePoissonSystem(...,
    algebra=)`). A new algebra provides `name`, `shape` (a state's), `dim` (its real
    dimension) and `matrix_size` (abstract properties),
    `is_complex` and `condition`, and implements the abstract `pairing`, `coordinates`,
    `from_coordinates`, `gradient`, `casimirs` and `project`; the other methods have
    defaults for matrix algebras, which an algebra overrides where it has closed forms.
    """

    is_complex = False  # states are complex arrays

    @property
    @abc.abstractmethod
    def name(self) -> str:
        """The algebra's name, such as `"su(4)"`."""

    @property
    @abc.abstractmethod
    def shape(self) -> tuple:
        """The shape of a state."""

    @property
    @abc.abstractmethod
    def dim(self) -> int:
        """The real dimension."""

    @property
    @abc.abstractmethod
    def matrix_size(self) -> int:
        """The size `n` of the matrices (`to_matrix`)."""

    # -- the vector space

    def state_dtype(self, dtype):
        """The dtype of a state for a computation in the real floating `dtype`."""
        dtype = jnp.dtype(dtype)
        return jnp.result_type(dtype, jnp.complex64) if self.is_complex else dtype

    @abc.abstractmethod
    def pairing(self, x, y):
        r"""$\langle x, y\rangle$ over the state axes (real)."""
        raise NotImplementedError

    def norm_sq(self, y):
        r"""$\langle y, y\rangle$ over the state axes."""
        return self.pairing(y, y)

    @abc.abstractmethod
    def coordinates(self, y):
        """Real coordinates of a state, orthonormal for the pairing, shape `(..., dim)`."""
        raise NotImplementedError

    @abc.abstractmethod
    def from_coordinates(self, x):
        raise NotImplementedError

    # -- the Lie–Poisson structure

    @abc.abstractmethod
    def gradient(self, g):
        """The gradient for the pairing of a real function, from JAX's gradient `g` of it."""
        raise NotImplementedError

    def bracket(self, y, x):
        """$[y, x]$: the Lie–Poisson field of a gradient `x` at `y`."""
        return self.from_matrix(_commutator(self.to_matrix(y), self.to_matrix(x)))

    def bracket_sum(self, x, y):
        r"""$\sum_q [x_q, y_q]$ over the leading axis of two stacks of elements: one product
        of the stacked matrices (`skew_bracket_sum`)."""
        return self.from_matrix(skew_bracket_sum(self.to_matrix(x), self.to_matrix(y)))

    @abc.abstractmethod
    def casimirs(self, y):
        """The Casimir functions (real), shape `(..., k)`."""
        raise NotImplementedError

    # -- the form the methods' loops carry (here the state itself; the components on so(3)),
    # and its real coordinates, the unknowns of implicit solves (a system's step on them:
    # `_systems/fields.py`)

    def local(self, y):
        """A state in the form a method's loop carries it."""
        return y

    def from_local(self, x):
        return x

    def local_coordinates(self, x):
        """Real coordinates of a local form: the unknowns of an implicit solve."""
        return self.coordinates(x)

    def from_local_coordinates(self, u):
        return self.from_coordinates(u)

    # -- the group

    def to_matrix(self, y):
        return y

    def from_matrix(self, m):
        return m

    @abc.abstractmethod
    def project(self, m):
        """The state whose matrix is nearest to the matrix `m` (its part in the algebra)."""
        raise NotImplementedError

    adjoint = staticmethod(adjoint)

    # The Lie algebra of the group the methods act with (`cayley`, `act`): the algebra itself
    # for so(3) and so(n); for su(N) it is u(N), one dimension more (the centre i R I), since
    # the Cayley map takes su(N) into U(N) and an implicit midpoint of su(N) states has a
    # trace. Real coordinates of its matrices, for the unknowns of implicit solves.

    @property
    def group_dim(self):
        return self.dim

    def group_coordinates(self, m):
        """Real coordinates (`group_dim`) of a matrix of the group's Lie algebra."""
        return self.coordinates(self.from_matrix(m))

    def from_group_coordinates(self, x):
        """The matrix of the group's Lie algebra with coordinates `x`."""
        return self.to_matrix(self.from_coordinates(x))

    def project_group(self, m):
        """The state nearest to a matrix `m` of the group's Lie algebra (skew-adjoint up to
        rounding): `project`, which an algebra may do more cheaply for such matrices."""
        return self.project(m)

    def cayley(self, x):
        r"""The Cayley map $(I - X)^{-1}(I + X) = I + 2X + O(X^2)$ of one matrix `x` of the
        algebra (a unitary matrix). Up to 8 x 8, Gauss–Jordan elimination without pivoting,
        written out: stable because $I - X$ has Hermitian part $I$, and on a CPU some times
        faster under `vmap` than a batched LAPACK solve of small matrices; above, LU."""
        n = x.shape[-1]
        eye = jnp.eye(n, dtype=x.dtype)
        if n > 8:  # (unrolled, the elimination's program would grow as n^2 operations)
            return jnp.linalg.solve(eye - x, eye + x)
        m = jnp.concatenate([eye - x, eye + x], axis=1)
        for k in range(n):
            row = m[k] / m[k, k]
            m = (m - jnp.outer(m[:, k], row)).at[k].set(row)
        return m[:, n:]

    def act(self, a, y):
        r"""$a\,y\,a^{-1} = a\,y\,a^H$ for a unitary (orthogonal) matrix `a`: the coadjoint
        action, which keeps every Casimir (projected back onto the algebra, so that rounding
        does not add up over steps)."""
        return self.project(matmul(matmul(a, self.to_matrix(y)), adjoint(a)))

    # -- validation and test states

    def validate(self, name, y):
        """Raise `ValueError` unless the concrete array `y` (NumPy) is a state of the algebra
        (shape, finite, and the algebra's own conditions)."""
        if y.shape != self.shape:
            raise ValueError(
                f"{name} must have shape {self.shape} (a state of {self.name}), "
                f"got shape {y.shape}."
            )
        if not np.all(np.isfinite(y)):
            raise ValueError(f"{name} must be finite, got {y}.")
        if np.iscomplexobj(y) and not self.is_complex:
            raise TypeError(f"{name} must be real (a state of {self.name}), got a complex array.")
        off = self.distance(y)
        # (relative to the state's size and its own precision: float32 states are 1e-7 off)
        tol = max(1e-12, 64.0 * float(np.finfo(y.dtype).eps)) * max(1.0, float(np.max(np.abs(y))))
        if off > tol:
            raise ValueError(
                f"{name} must be {self.condition} (a state of {self.name}); it is {off:.3g} away."
            )

    condition = "a state"  # the algebra's condition on a matrix, in words

    def spectral_norm(self, y):
        """$\\|Y\\|_2$ of a concrete state `y` (NumPy, before anything compiles; the states
        here are their matrices)."""
        return float(np.linalg.norm(np.asarray(y), 2))

    def distance(self, y):
        """How far the NumPy array `y` of the state's shape is from the algebra, in the
        max-norm: here its (skew-)Hermitian part. NumPy, not JAX: checks run before anything
        compiles, and eager JAX operations would each compile a program on first use."""
        return float(np.max(np.abs(y + np.conj(np.swapaxes(y, -1, -2))))) / 2.0

    def random_state(self, key, dtype=None):
        """A random state with standard normal coordinates (for tests)."""
        dtype = jnp.result_type(float) if dtype is None else dtype
        return _random_state(self, key, jnp.dtype(dtype))

    def __repr__(self):
        return self.name


class AbstractSquareMatrixAlgebra(AbstractAlgebra):
    """An algebra of `(n, n)` matrices given by their size: its one field, `n`, is static
    (so(n), su(N))."""

    n: int = eqx.field(static=True)

    @property
    def matrix_size(self):
        return self.n

    @property
    def shape(self):
        return (self.n, self.n)


def _commutator(a, b):
    return a @ b - b @ a


@functools.partial(jax.jit, static_argnums=(0, 2))
def _random_state(algebra, key, dtype):
    """`AbstractAlgebra.random_state`: one program per algebra and dtype."""
    return algebra.from_coordinates(jax.random.normal(key, (algebra.dim,), dtype)).astype(
        algebra.state_dtype(dtype)
    )
