"""The stochastic rigid body, the paper's system (10)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from . import _so3


def concrete(x):
    """`x` as a NumPy array, or `None` if it is traced (inside `jit`, `vmap`, `grad`)."""
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


def float_dtype(*xs):
    """The floating dtype the computation runs in: the inputs' promoted dtype, at least the
    default float (float32, or float64 with `jax_enable_x64`)."""
    return jnp.result_type(float, *xs)


def _real_array(name, x):
    """`x` as an array of real numbers, or a `TypeError` naming the argument."""
    if isinstance(x, str):
        raise TypeError(f"{name} must be real numbers, got the string {x!r}.")
    try:
        arr = jnp.asarray(x)  # (also a list of tracers, inside jit)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be real numbers, got {x!r} ({err}).") from None
    # (a key array has an extended dtype, which NumPy cannot describe)
    if jax.dtypes.issubdtype(arr.dtype, jax.dtypes.extended) or \
            np.dtype(arr.dtype).kind not in "fiu":
        raise TypeError(f"{name} must be real numbers, got dtype {arr.dtype}.")
    return arr


@jax.tree_util.register_pytree_node_class
class RigidBody:
    r"""The stochastic rigid body $dy = y \times I^{-1} y\,(dt + c \circ dW)$.

    In the paper's notation a stochastic Lie–Poisson system on so(3)* with structure matrix
    $B(y) = \hat y$, Hamiltonian $H(y) = \tfrac12 y^T I^{-1} y$ and Casimir
    $C(y) = \tfrac12 |y|^2$ (Liu & Wang, system (10)).

    A pytree whose leaves are `inertia` and `c`, so `jax.grad` reaches both.

    **Arguments:**

    - `inertia`: the principal moments $(I_1, I_2, I_3)$, shape `(3,)`, finite and positive.
    - `c`: the noise amplitude, a finite scalar (default 0, the deterministic free rigid body).

    The model's floating dtype (the promoted dtype of `inertia` and `c`, at least the default
    float) is the dtype of every computation with it: `simulate` and `integrate` cast `y0`
    and the increments to it. For float32 work pass float32 `inertia`.

    Raises `ValueError` naming the argument if a concrete value is invalid. Traced values
    (inside `jit` or `grad`) are not checked.
    """

    def __init__(self, inertia, c=0.0):
        inertia = _real_array("inertia", inertia)
        c = _real_array("c", c)
        dtype = float_dtype(inertia, c)
        inertia, c = inertia.astype(dtype), c.astype(dtype)
        if inertia.shape != (3,):
            raise ValueError(f"inertia must have shape (3,), got shape {inertia.shape}.")
        if c.shape != ():
            raise ValueError(f"c must be a scalar, got shape {c.shape}.")
        i_np, c_np = concrete(inertia), concrete(c)
        if i_np is not None and not (np.all(np.isfinite(i_np)) and np.all(i_np > 0)):
            raise ValueError(f"inertia must be finite and positive, got {i_np}.")
        if c_np is not None and not np.isfinite(c_np):
            raise ValueError(f"c must be finite, got {c_np}.")
        self.inertia = inertia
        self.c = c

    @classmethod
    def paper(cls):
        """The paper's setup (Section 4.4): $I = (\\sqrt2 + \\sqrt2/1.51,
        \\sqrt2 - 0.51\\sqrt2/1.51, 1)$, $c = 0.2$. Its initial value is `PAPER_Y0`."""
        r2 = math.sqrt(2.0)
        return cls([r2 + r2 / 1.51, r2 - 0.51 * r2 / 1.51, 1.0], 0.2)

    def tree_flatten(self):
        return (self.inertia, self.c), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        # Bypass __init__: unflattening happens with tracers and placeholder leaves.
        obj = object.__new__(cls)
        obj.inertia, obj.c = children
        return obj

    def __repr__(self):
        return f"RigidBody(inertia={self.inertia!r}, c={self.c!r})"

    def hamiltonian(self, y):
        """$H(y) = \\tfrac12 \\sum_i y_i^2 / I_i$, over the last axis of `y`."""
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2 / self.inertia, axis=-1)

    def casimir(self, y):
        """$C(y) = \\tfrac12 |y|^2$, over the last axis of `y`."""
        return 0.5 * jnp.sum(jnp.asarray(y) ** 2, axis=-1)

    def vector_field(self, y):
        """$f(y) = y \\times I^{-1} y$, so that $dy = f(y)(dt + c \\circ dW)$."""
        y = jnp.asarray(y)
        return jnp.cross(y, y / self.inertia)

    def inverse_inertia(self):
        """$I^{-1}$ as component tuple (private helper for the integrators)."""
        return _so3.vec(1.0 / self.inertia)


PAPER_Y0 = (0.7, 0.7, 0.0)
