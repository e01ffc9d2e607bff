"""Noise Hamiltonians $H_1, \\dots, H_s$ of a system with several noises:
$dy = y \\times \\nabla H_0(y)\\,dt + \\sum_r y \\times \\nabla H_r(y) \\circ dW_r$.

A noise family is a pytree whose leaves are its parameters (so `jax.grad` reaches them) and
which gives the integrators, on components (tuples of arrays, see `_so3`), the one combination
they need: $u(v) = \\sum_r w_r \\nabla H_r(v)$ for weights $w$ (a step's increments) and its
Jacobian $\\partial u/\\partial v$. Closed forms where they exist (`salt_noise`,
`random_inertia_noise`), derivatives by JAX otherwise (`FunctionNoise`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _so3
from ._checks import concrete, float_dtype, real_array


class AbstractNoise:
    """What a noise family provides.

    - `n_noises`: the number $s$ of noises (static).
    - `values(y, params)`: $(H_1(y), \\dots, H_s(y))$ for `y` of shape `(3,)`.
    - `gradient_c(v, w, params)`: $u = \\sum_r w_r \\nabla H_r(v)$ on components.
    - `gradient_jacobian_c(v, w, params)`: $(u, \\partial u/\\partial v)$ on components.

    `params` are the system's parameters (families with their own leaves ignore them).
    """

    n_noises: int
    linear = False  # all H_r linear: u does not depend on v

    def values(self, y, params):
        raise NotImplementedError

    def gradient_c(self, v, w, params):
        raise NotImplementedError

    def gradient_jacobian_c(self, v, w, params):
        raise NotImplementedError


def _weighted(w, rows):
    """$\\sum_r w_r\\,\\mathrm{rows}_r$ for `rows` of shape `(s, 3)`, on components."""
    total = jnp.tensordot(w, rows, axes=1)
    return _so3.vec(total)


def _parameter_matrix(name, x, what):
    x = real_array(name, x)
    x = x.astype(float_dtype(x))
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 1:
        raise ValueError(f"{name} must have shape (s, 3), one row per noise ({what}), got "
                         f"shape {x.shape}.")
    x_np = concrete(x)
    if x_np is not None and not np.all(np.isfinite(x_np)):
        raise ValueError(f"{name} must be finite, got {x_np}.")
    return x


class _MatrixNoise(AbstractNoise):
    """A family whose one parameter is an `(s, 3)` array, one row per noise, stored under
    `parameter_name` (a pytree leaf; `calibrate` fits it by that name)."""

    parameter_name: str
    builder: str  # the public function that builds it, for the repr

    def __init__(self, value):
        setattr(self, self.parameter_name, value)

    @property
    def matrix(self):
        return getattr(self, self.parameter_name)

    @property
    def n_noises(self):
        return self.matrix.shape[0]

    def tree_flatten(self):
        return (self.matrix,), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children)

    def __repr__(self):
        return f"{self.builder}({self.matrix!r})"


@jax.tree_util.register_pytree_node_class
class SaltNoise(_MatrixNoise):
    r"""Stochastic advection by Lie transport: $H_r(y) = \chi_r \cdot y$, so the noise field
    $y \times \chi_r$ rotates $y$ about the fixed axis $\chi_r$. Build with `salt_noise`."""

    linear = True
    parameter_name, builder = "chi", "salt_noise"

    def values(self, y, params):
        return self.chi @ y

    def gradient_c(self, v, w, params):
        return _weighted(w, self.chi)

    def gradient_jacobian_c(self, v, w, params):
        zero = jnp.zeros_like(v[0])
        return self.gradient_c(v, w, params), ((zero,) * 3,) * 3


def salt_noise(chi):
    r"""Stochastic advection by Lie transport (Holm 2015): $s$ linear noise Hamiltonians
    $H_r(y) = \chi_r \cdot y$.

    **Arguments:** `chi`, shape `(s, 3)`: row $r$ is the axis (times the strength) of noise
    $r$. A pytree leaf: `jax.grad` reaches it.
    """
    return SaltNoise(_parameter_matrix("chi", chi, "the axis of each noise"))


@jax.tree_util.register_pytree_node_class
class RandomInertiaNoise(_MatrixNoise):
    r"""Random inertia: $H_r(y) = \tfrac12 \sum_j \sigma_{rj} y_j^2$. Build with
    `random_inertia_noise`."""

    parameter_name, builder = "sigma", "random_inertia_noise"

    def values(self, y, params):
        return 0.5 * self.sigma @ (y * y)

    def gradient_c(self, v, w, params):
        return _so3.mul(_weighted(w, self.sigma), v)

    def gradient_jacobian_c(self, v, w, params):
        d = _weighted(w, self.sigma)
        zero = 0.0 * (v[0] + d[0])
        return _so3.mul(d, v), ((d[0] + zero, zero, zero), (zero, d[1] + zero, zero),
                                (zero, zero, d[2] + zero))


def random_inertia_noise(sigma):
    r"""Random inertia: $s$ quadratic noise Hamiltonians
    $H_r(y) = \tfrac12 \sum_j \sigma_{rj} y_j^2$ (for the rigid body, noise on the inverse
    moments of inertia $1/I_j$).

    **Arguments:** `sigma`, shape `(s, 3)`: row $r$ the strengths of noise $r$. A pytree leaf.
    """
    return RandomInertiaNoise(_parameter_matrix("sigma", sigma, "the strengths of each noise"))


@jax.tree_util.register_pytree_node_class
class FunctionNoise(AbstractNoise):
    """Noise Hamiltonians from a function `fn(y, params) -> (s,)`, derivatives by JAX.
    `LiePoissonSystem(..., noise=fn)` builds it (and checks the shape); the function is static
    data, its parameters are the system's `params`."""

    def __init__(self, fn, n_noises):
        self.fn = fn
        self._n = n_noises

    @property
    def n_noises(self):
        return self._n

    def tree_flatten(self):
        return (), (self.fn, self._n)

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*aux)

    def __repr__(self):
        return getattr(self.fn, "__name__", repr(self.fn))

    def values(self, y, params):
        return self.fn(y, params)

    def _weighted_h(self, w, params):
        return lambda y: jnp.dot(w, self.fn(y, params))

    def gradient_c(self, v, w, params):
        return _so3.vec(jax.grad(self._weighted_h(w, params))(_so3.unvec(v)))

    def gradient_jacobian_c(self, v, w, params):
        grad = jax.grad(self._weighted_h(w, params))
        jac, u = jax.jacfwd(lambda x: (grad(x), grad(x)), has_aux=True)(_so3.unvec(v))
        return _so3.vec(u), _so3.mat(jac)


def as_noise(noise, params, dtype):
    """`noise` as a noise family: a family is returned as it is; a function
    `noise(y, params) -> (s,)` is wrapped in `FunctionNoise` after its output shape is checked
    (by `jax.eval_shape`, nothing is computed)."""
    if isinstance(noise, AbstractNoise):
        return noise
    if not callable(noise):
        raise TypeError(f"noise must be a function noise(y, params) -> shape (s,) or a noise "
                        f"family such as salt_noise(chi), got {type(noise).__name__}.")
    try:
        out = jax.eval_shape(noise, jax.ShapeDtypeStruct((3,), dtype), params)
    except Exception as err:  # noqa: BLE001 - reported with the function's name
        raise ValueError(f"noise(y, params) failed on y of shape (3,): {err}") from err
    shape = getattr(out, "shape", None)
    if shape is None or len(shape) != 1 or shape[0] < 1:
        raise ValueError(f"noise(y, params) must return the s noise Hamiltonians, shape (s,) "
                         f"with s >= 1, got {shape if shape is not None else type(out)}.")
    return FunctionNoise(noise, int(shape[0]))
