"""The stochastic rigid body, the paper's system (10)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from . import _so3
from ._checks import concrete, float_dtype, real_array
from ._system import RIGID_BODY, LiePoissonSystem, _noise_or_c


def _rigid_body_hamiltonian(y, inertia):
    return 0.5 * jnp.sum(y ** 2 / inertia, axis=-1)


@jax.tree_util.register_pytree_node_class
class RigidBody(LiePoissonSystem):
    r"""The stochastic rigid body $dy = y \times I^{-1} y\,(dt + c \circ dW)$.

    In the paper's notation a stochastic Lie–Poisson system on so(3)* with structure matrix
    $B(y) = \hat y$, Hamiltonian $H(y) = \tfrac12 y^T I^{-1} y$ and Casimir
    $C(y) = \tfrac12 |y|^2$ (Liu & Wang, system (10)).

    The analytic special case of `LiePoissonSystem` (Hamiltonian
    $H(y) = \tfrac12 y^T I^{-1} y$, `params` the inertia): its gradient and Hessian are
    written out, and it offers the rigid body's structure (`inverse_inertia`) that some
    methods need (`LiePoisson`, `Strang`, `Exact`). A pytree whose leaves are `inertia` and
    `c`, so `jax.grad` reaches both.

    **Arguments:**

    - `inertia`: the principal moments $(I_1, I_2, I_3)$, shape `(3,)`, finite and positive.
    - `c`: the noise amplitude, a finite scalar (default 0, the deterministic free rigid body).
    - `noise`: instead of `c`, noise Hamiltonians of their own, as for `LiePoissonSystem`
      (for example `salt_noise(chi)`); their `params` are the inertia.

    The model's floating dtype (`model.dtype`: the promoted dtype of `inertia`, `c` and the
    noise's parameters, at least the default float) is the dtype of every computation with it: `simulate` and `integrate` cast `y0`
    and the increments to it. For float32 work pass float32 `inertia`.

    Raises `ValueError` naming the argument if a concrete value is invalid. Traced values
    (inside `jit` or `grad`) are not checked.
    """

    hamiltonian_fn = staticmethod(_rigid_body_hamiltonian)

    def __init__(self, inertia, c=None, noise=None):
        inertia = real_array("inertia", inertia)
        inertia = inertia.astype(float_dtype(inertia))
        if inertia.shape != (3,):
            raise ValueError(f"inertia must have shape (3,), got shape {inertia.shape}.")
        i_np = concrete(inertia)
        if i_np is not None and not (np.all(np.isfinite(i_np)) and np.all(i_np > 0)):
            raise ValueError(f"inertia must be finite and positive, got {i_np}.")
        self.c, self.noise = _noise_or_c(c, noise, inertia, [inertia])
        self.inertia = inertia.astype(
            float_dtype(inertia, *jax.tree_util.tree_leaves((self.c, self.noise))))

    @classmethod
    def paper(cls):
        """The paper's setup (Section 4.4): $I = (\\sqrt2 + \\sqrt2/1.51,
        \\sqrt2 - 0.51\\sqrt2/1.51, 1)$, $c = 0.2$. Its initial value is `PAPER_Y0`."""
        r2 = math.sqrt(2.0)
        return cls([r2 + r2 / 1.51, r2 - 0.51 * r2 / 1.51, 1.0], 0.2)

    def tree_flatten(self):
        return (self.inertia, self.c, self.noise), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        # Bypass __init__: unflattening happens with tracers and placeholder leaves.
        obj = object.__new__(cls)
        obj.inertia, obj.c, obj.noise = children
        return obj

    def __repr__(self):
        return (f"RigidBody(inertia={self.inertia!r}, "
                + (f"c={self.c!r})" if self.noise is None else f"noise={self.noise!r})"))

    @property
    def structure(self):
        return super().structure | {RIGID_BODY}

    @property
    def params(self):
        """The inertia: the parameters of the Hamiltonian, as for a `LiePoissonSystem`."""
        return self.inertia

    def hamiltonian(self, y):
        """$H(y) = \\tfrac12 \\sum_i y_i^2 / I_i$, over the last axis of `y`."""
        return _rigid_body_hamiltonian(jnp.asarray(y), self.inertia)

    def gradient(self, y):
        """$\\nabla H(y) = I^{-1} y$, over the last axis of `y`."""
        return jnp.asarray(y) / self.inertia

    def inverse_inertia(self):
        """$I^{-1}$ as component tuple (private helper for the integrators)."""
        return _so3.vec(1.0 / self.inertia)

    def gradient_c(self, v):
        return _so3.mul(self.inverse_inertia(), v)

    def gradient_hessian_c(self, v):
        d = self.inverse_inertia()
        z = jnp.zeros_like(d[0])
        return _so3.mul(d, v), ((d[0], z, z), (z, d[1], z), (z, z, d[2]))


PAPER_Y0 = (0.7, 0.7, 0.0)
