"""Stochastic Lie–Poisson systems on so(3)* with a general Hamiltonian."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _so3
from ._algebra import SO3
from ._checks import concrete, float_dtype


# What a system offers, which methods may declare they need (`AbstractMethod.requires`).
NOISE_PROPORTIONAL_TO_DRIFT = "noise proportional to the drift"  # one noise, H_1 = c H_0
RIGID_BODY = "rigid body"  # H_0 = y^T I^{-1} y / 2 on so(3)*, `inverse_inertia()` available


@jax.tree_util.register_pytree_node_class
class LiePoissonSystem:
    r"""The stochastic Lie–Poisson system $dy = y \times \nabla H(y)\,(dt + c \circ dW)$ on
    so(3)*, for a differentiable Hamiltonian $H$ you supply.

    Structure matrix $B(y) = \hat y$, Casimir $C(y) = \tfrac12|y|^2$ (kept by every
    Lie–Poisson method whatever $H$ is). The rigid body is $H(y) = \tfrac12 y^T I^{-1} y$;
    `RigidBody` is its fast analytic special case. The derivatives of $H$ come from JAX:
    $\nabla H$ by `jax.grad`, the Hessian (for Newton's Jacobian) by `jax.jacfwd` of it.

    A pytree: `params` (any pytree of arrays) and `c` are leaves, so `jax.grad` reaches them;
    the function `hamiltonian` is static data. Pass the same function object each time (not a
    fresh `lambda`), or every call compiles anew.

    **Arguments:**

    - `hamiltonian`: `hamiltonian(y, params) -> scalar`, for `y` of shape `(3,)`; smooth
      (twice differentiable by JAX).
    - `params`: a pytree of parameters passed to `hamiltonian` (default `None`).
    - `c`: the noise amplitude, a finite scalar (default 0).

    The computation runs in the promoted floating dtype of `c` and the leaves of `params`.
    Raises `ValueError` (`TypeError` for a non-callable `hamiltonian`) for invalid concrete
    values; traced values are not checked.

    **Reference:** Liu & Wang, *Lie–Poisson numerical method for a class of stochastic
    Lie–Poisson systems*, system (1) with $B(y) = \hat y$, $H_0 = H$ and $H_1 = cH$.
    """

    algebra = SO3
    n_noises = 1
    structure = frozenset({NOISE_PROPORTIONAL_TO_DRIFT})

    def __init__(self, hamiltonian, params=None, c=0.0):
        if not callable(hamiltonian):
            raise TypeError(f"hamiltonian must be callable as hamiltonian(y, params), got "
                            f"{type(hamiltonian).__name__}.")
        params = jax.tree_util.tree_map(jnp.asarray, params)
        c = jnp.asarray(c)
        leaves = [x for x in jax.tree_util.tree_leaves(params)
                  if jnp.issubdtype(x.dtype, jnp.inexact)]
        dtype = float_dtype(c, *leaves)
        c = c.astype(dtype)
        if c.shape != ():
            raise ValueError(f"c must be a scalar, got shape {c.shape}.")
        c_np = concrete(c)
        if c_np is not None and not np.isfinite(c_np):
            raise ValueError(f"c must be finite, got {c_np}.")
        self.hamiltonian_fn = hamiltonian
        self.params = params
        self.c = c

    def tree_flatten(self):
        return (self.params, self.c), self.hamiltonian_fn

    @classmethod
    def tree_unflatten(cls, aux, children):
        obj = object.__new__(cls)
        obj.hamiltonian_fn = aux
        obj.params, obj.c = children
        return obj

    def __repr__(self):
        name = getattr(self.hamiltonian_fn, "__name__", repr(self.hamiltonian_fn))
        return f"LiePoissonSystem(hamiltonian={name}, params={self.params!r}, c={self.c!r})"

    def _h(self, y):
        return self.hamiltonian_fn(y, self.params)

    def hamiltonian(self, y):
        """$H(y)$ over the last axis of `y`."""
        return jnp.vectorize(self._h, signature="(3)->()")(jnp.asarray(y))

    def casimir(self, y):
        """$C(y) = \\tfrac12 |y|^2$, over the last axis of `y`."""
        return self.algebra.casimirs(y)[..., 0]

    def gradient(self, y):
        """$\\nabla H(y)$ over the last axis of `y`."""
        return jnp.vectorize(jax.grad(self._h), signature="(3)->(3)")(jnp.asarray(y))

    def vector_field(self, y):
        """$f(y) = B(y)\\nabla H(y) = y \\times \\nabla H(y)$, so that
        $dy = f(y)(dt + c \\circ dW)$."""
        y = jnp.asarray(y)
        return self.algebra.bracket(y, self.gradient(y))

    def noise_time(self, dW):
        """$c\\,\\Delta W$: how far one step's noise moves the random time
        $\\tau = h + c\\,\\Delta W$ of a system whose one noise is proportional to the drift.
        `dW` is the step's increments, shape `(n_noises,) = (1,)` (a scalar is accepted)."""
        return self.c * jnp.reshape(dW, ())

    # Component forms for the integrators (tuples of arrays: see `_so3`). Subclasses with a
    # closed form override them.

    def gradient_c(self, v):
        """$\\nabla H(v)$ on components."""
        return _so3.vec(jax.grad(self._h)(_so3.unvec(v)))

    def gradient_hessian_c(self, v):
        """$(\\nabla H(v), \\nabla^2 H(v))$ on components, in one forward-mode pass."""
        grad = jax.grad(self._h)
        hess, g = jax.jacfwd(lambda u: (grad(u), grad(u)), has_aux=True)(_so3.unvec(v))
        return _so3.vec(g), _so3.mat(hess)
