"""The stochastic rigid body, the paper's system (10)."""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._algebra import SO3, AbstractAlgebra, so
from .._support.checks import concrete, float_dtype, real_array
from .noise import AbstractNoise, noise_or_c
from .system import AbstractLiePoissonSystem


def _rigid_body_hamiltonian(y, inertia):
    return 0.5 * jnp.sum(y**2 / inertia, axis=-1)


class RigidBody(AbstractLiePoissonSystem):
    r"""The stochastic rigid body $dy = y \times I^{-1} y\,(dt + c \circ dW)$.

    In the paper's notation a stochastic Lie–Poisson system on so(3)* with structure matrix
    $B(y) = \hat y$, Hamiltonian $H(y) = \tfrac12 y^T I^{-1} y$ and Casimir
    $C(y) = \tfrac12 |y|^2$ (Liu & Wang, system (10)).

    The analytic special case of `LiePoissonSystem` (Hamiltonian
    $H(y) = \tfrac12 y^T I^{-1} y$, `params` the inertia): its gradient and Hessian are
    written out, and it has the rigid body's closed forms (`inverse_inertia`) that some
    methods need (`LiePoisson`, `Strang`, `Exact`). A pytree whose leaves are `inertia` and
    `c`, so `jax.grad` reaches both.

    **Arguments:**

    - `inertia`: the principal moments $(I_1, I_2, I_3)$, shape `(3,)`, finite and positive.
    - `c`: the noise amplitude, a finite scalar (default 0, the deterministic free rigid body).
    - `noise`: instead of `c`, noise Hamiltonians of their own, as for `LiePoissonSystem`
      (for example `salt_noise(chi)`); their `params` are the inertia.

    The system's floating dtype (`system.dtype`: the promoted dtype of `inertia`, `c` and the
    noise's parameters, at least the default float) is the dtype of every computation with it:
    `simulate` and `integrate` cast `y0` and the increments to it. For float32 work pass float32 `inertia`.

    Raises `ValueError` naming the argument if a concrete value is invalid. Traced values
    (inside `jit` or `grad`) are not checked.
    """

    hamiltonian_fn: Any = eqx.field(static=True)
    algebra: AbstractAlgebra = eqx.field(static=True)
    params: Any
    noise: AbstractNoise

    def __init__(self, inertia, c=None, noise=None):
        inertia = real_array("inertia", inertia)
        inertia = inertia.astype(float_dtype(inertia))
        if inertia.shape != (3,):
            raise ValueError(f"inertia must have shape (3,), got shape {inertia.shape}.")
        i_np = concrete(inertia)
        if i_np is not None and not (np.all(np.isfinite(i_np)) and np.all(i_np > 0)):
            raise ValueError(f"inertia must be finite and positive, got {i_np}.")
        self.noise = noise_or_c(c, noise, inertia, [inertia], SO3)
        self.params = inertia.astype(float_dtype(inertia, *jax.tree_util.tree_leaves(self.noise)))
        self.hamiltonian_fn = _rigid_body_hamiltonian
        self.algebra = SO3

    @classmethod
    def paper(cls):
        """The paper's setup (Section 4.4): $I = (\\sqrt2 + \\sqrt2/1.51,
        \\sqrt2 - 0.51\\sqrt2/1.51, 1)$, $c = 0.2$. Its initial value is `PAPER_Y0`."""
        r2 = math.sqrt(2.0)
        return cls([r2 + r2 / 1.51, r2 - 0.51 * r2 / 1.51, 1.0], 0.2)

    def __repr__(self):
        return f"RigidBody(inertia={self.inertia!r}, {self._noise_repr()})"

    quadratic_hamiltonian = True

    @property
    def inertia(self):
        """The principal moments $(I_1, I_2, I_3)$: the Hamiltonian's parameters (`params`)."""
        return self.params

    def hamiltonian(self, y):
        """$H(y) = \\tfrac12 \\sum_i y_i^2 / I_i$, over the last axis of `y`."""
        return _rigid_body_hamiltonian(jnp.asarray(y), self.inertia)

    def gradient(self, y):
        """$\\nabla H(y) = I^{-1} y$, over the last axis of `y`."""
        return jnp.asarray(y) / self.inertia

    def inverse_inertia(self):
        """$I^{-1}$, the inverse principal moments, shape `(3,)`."""
        return 1.0 / self.inertia

    @property
    def quadratic_drift(self):
        r"""$I^{-1}$: $H(y) = \tfrac12 y\cdot I^{-1}y$ is diagonal and quadratic."""
        return self.inverse_inertia()


PAPER_Y0 = (0.7, 0.7, 0.0)
r"""The paper's initial value $y_0 = (0.7, 0.7, 0)$ (Section 4.4), a tuple, for
`RigidBody.paper()`: $|y_0| \approx 0.99$, close to the unit sphere where `LiePoisson`'s
solve may fail."""


def _generalised_rigid_body_hamiltonian(y, j):
    return 0.25 * jnp.sum(y**2 / (j[..., :, None] + j[..., None, :]), axis=(-2, -1))


class GeneralisedRigidBody(AbstractLiePoissonSystem):
    r"""The n-dimensional (Manakov) rigid body on so(n)*, with noise:
    $dY = [Y, \Omega]\,(dt + c\circ dW)$, or with noises of its own
    ($dY = [Y, \Omega]\,dt + \sum_r [Y, \nabla H_r] \circ dW_r$).

    $Y = J\Omega + \Omega J$ with $J = \mathrm{diag}(J_1, \dots, J_n) > 0$, so
    $\Omega_{ij} = Y_{ij}/(J_i + J_j)$ and $H(Y) = \tfrac12\langle Y, \Omega\rangle
    = \tfrac14\sum_{ij} Y_{ij}^2/(J_i + J_j)$, $\nabla H = \Omega$ (written out). For
    $n = 3$ it is the rigid body with $I_1 = J_2 + J_3$ and cyclic. States are skew `(n, n)`
    matrices (`algebra = so(n)`); the Casimirs $\operatorname{tr}(Y^{2k})$ are kept by the
    Lie–Poisson methods.

    **Arguments:** `j`: $(J_1, \dots, J_n)$, shape `(n,)` with `n >= 3`, finite and positive (a
    pytree leaf, like `c` and a noise family's parameters); `c` or `noise` as for
    `LiePoissonSystem` (its `params` are `j`).
    """

    hamiltonian_fn: Any = eqx.field(static=True)
    algebra: AbstractAlgebra = eqx.field(static=True)
    params: Any
    noise: AbstractNoise

    def __init__(self, j, c=None, noise=None):
        j = real_array("j", j)
        j = j.astype(float_dtype(j))
        if j.ndim != 1 or j.shape[0] < 3:
            raise ValueError(f"j must have shape (n,) with n >= 3, got shape {j.shape}.")
        j_np = concrete(j)
        if j_np is not None and not (np.all(np.isfinite(j_np)) and np.all(j_np > 0)):
            raise ValueError(f"j must be finite and positive, got {j_np}.")
        self.algebra = so(j.shape[0])
        self.noise = noise_or_c(c, noise, j, [j], self.algebra)
        self.params = j.astype(float_dtype(j, *jax.tree_util.tree_leaves(self.noise)))
        self.hamiltonian_fn = _generalised_rigid_body_hamiltonian

    def __repr__(self):
        return f"GeneralisedRigidBody(j={self.j!r}, {self._noise_repr()})"

    quadratic_hamiltonian = True

    @property
    def j(self):
        """$(J_1, \\dots, J_n)$: the Hamiltonian's parameters (`params`)."""
        return self.params

    def hamiltonian(self, y):
        return _generalised_rigid_body_hamiltonian(jnp.asarray(y), self.j)

    def gradient(self, y):
        r"""$\Omega$, $\Omega_{ij} = Y_{ij}/(J_i + J_j)$, over the last two axes of `y`."""
        return jnp.asarray(y) / (self.j[:, None] + self.j[None, :])
