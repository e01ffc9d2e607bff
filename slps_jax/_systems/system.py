"""Stochastic Lie–Poisson systems with a general Hamiltonian, on so(3)*, so(n)* or su(N)*."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._algebra import SO3, AbstractAlgebra
from .._brownian import as_step
from .._support.checks import float_dtype, real_dtype
from . import fields
from .noise import AbstractNoise, noise_or_c


class Tables(eqx.Module):
    """Precomputed arrays a system carries (`EulerZeitlin`'s Poisson eigenbasis): leaves of
    its pytree, so that `jit` takes them as arguments rather than compiling them in as
    constants, but not parameters: the derivatives with respect to the system that the
    driver forms (a retried step's Jacobians) skip them."""

    arrays: tuple = eqx.field(converter=tuple)


def differentiable_leaves(system):
    """The system's leaves (a `Tables` as one), its tree structure, and the indices of the
    inexact leaves other than tables: the parameters a derivative acts on."""
    leaves, treedef = jax.tree_util.tree_flatten(system, is_leaf=lambda x: isinstance(x, Tables))
    idx = [
        i
        for i, leaf in enumerate(leaves)
        if not isinstance(leaf, Tables) and jnp.issubdtype(jnp.result_type(leaf), jnp.inexact)
    ]
    return leaves, treedef, idx


class AbstractLiePoissonSystem(eqx.Module):
    r"""What every system of the library is: a stochastic Lie–Poisson system on the dual of
    a Lie algebra, $dy = [y, \nabla H_0]\,dt + \sum_r [y, \nabla H_r]\circ dW_r$, with its
    drift Hamiltonian `hamiltonian_fn(y, params)`, its `algebra`, the Hamiltonian's `params`
    and its `noise` family; and everything the methods and the driver ask of it, written here
    once. `LiePoissonSystem` (a Hamiltonian you supply), `RigidBody`,
    `GeneralisedRigidBody` and `EulerZeitlin` are its final cases; a subclass may replace a
    derivative by its closed form (`gradient`) and declare what it states in closed form
    (`quadratic_drift`, `quadratic_hamiltonian`)."""

    hamiltonian_fn: eqx.AbstractVar[Any]
    algebra: eqx.AbstractVar[AbstractAlgebra]
    params: eqx.AbstractVar[Any]
    noise: eqx.AbstractVar[AbstractNoise]  # the noise family (`c=`: `ProportionalNoise`)

    # What the system is.

    @property
    def n_noises(self):
        """The number $s$ of independent noises (1 with `c=`)."""
        return self.noise.n_noises

    # Whether a method may be given the Lévy areas of the system's noises (`EulerZeitlin`
    # with an additive forcing may not).
    takes_areas = True

    @property
    def c(self):
        """The amplitude $c$ of one noise proportional to the drift (`c=`), else `None`."""
        return self.noise.drift_amplitude()

    # What the system states in closed form, for the algebra's fast paths (`SO3Algebra`).
    quadratic_drift = None
    r"""`D` (the state's shape) when $H_0(y) = \tfrac12\langle y, D \odot y\rangle$, so
    that $\nabla H_0(y) = D \odot y$; `None` otherwise (derivatives by JAX)."""

    def _noise_repr(self):
        """`c=...` or `noise=...`, for the systems' `__repr__`."""
        return f"noise={self.noise!r}" if self.c is None else f"c={self.c!r}"

    # Whether H_0 is a quadratic form (declared by the systems that know it: the rigid
    # bodies, Euler–Zeitlin); with c= then y -> y/s is a time change (`LiePoisson(scale=)`).
    quadratic_hamiltonian = False

    @property
    def dtype(self):
        """The floating dtype of every computation with this system."""
        leaves = [
            x
            for x in jax.tree_util.tree_leaves(self)
            if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.inexact)
        ]
        return real_dtype(float_dtype(*leaves))

    def _h(self, y):
        return self.hamiltonian_fn(y, self.params)

    def _signature(self, out):
        state = "(" + ",".join(f"d{i}" for i in range(len(self.algebra.shape))) + ")"
        return f"{state}->{state if out == 'state' else out}"

    def hamiltonian(self, y):
        """$H_0(y)$ over the state axes of `y` (the last one on so(3), the last two on so(n))."""
        return jnp.vectorize(self._h, signature=self._signature("()"))(jnp.asarray(y))

    def noise_hamiltonians(self, y):
        r"""$(H_1(y), \dots, H_s(y))$ over the state axes of `y`, shape `(..., s)`."""
        if self.c is not None:  # (H_1 = c H_0: no Hamiltonian of the family's own)
            return (self.c * self.hamiltonian(y))[..., None]
        return jnp.vectorize(
            lambda u: self.noise.values(u, self.params), signature=self._signature("(s)")
        )(jnp.asarray(y))

    def step_guide(self, y, safety=0.1):
        r"""A step for the state `y` that the implicit methods' solves take in a few updates:
        $h = \text{safety}\cdot\pi/\rho(\nabla H_0(y))$, $\rho$ the spectral norm of the
        gradient's matrix (on so(3)*, $|\nabla H_0(y)|$). The fixed point's update contracts
        by about $h\rho$: the default, quflow's `estimate_stepsize` (0.1π in its units,
        $\hbar$ seconds for `EulerZeitlin`), keeps that near 0.3. It looks at the drift only:
        strong noise, or a state that roughens along the run, may need less.

        **Arguments:** `y`, one concrete state; `safety`, a positive factor (default 0.1).

        **Returns:** $h$, a Python float (`inf` where the gradient vanishes).
        """
        if not (isinstance(safety, (int, float)) and safety > 0):
            raise ValueError(f"step_guide: safety must be a positive number, got {safety!r}.")
        g = np.asarray(self.algebra.to_matrix(self.gradient(jnp.asarray(y))))
        rho = float(np.linalg.norm(g.astype(np.complex128), 2))
        return float("inf") if rho == 0 else safety * np.pi / rho

    def casimir(self, y):
        r"""The first Casimir: $C(y) = \tfrac12 |y|^2$ on so(3), $\operatorname{tr}(Y^2)$ on
        so(n) (all of them: `algebra.casimirs`)."""
        return self.algebra.casimirs(y)[..., 0]

    def gradient(self, y):
        r"""$\nabla H_0(y)$ over the state axes of `y` (a skew matrix on so(n), for the
        pairing $\langle X, Y\rangle = \tfrac12\operatorname{tr}X^TY$)."""
        return jnp.vectorize(
            lambda u: self.algebra.gradient(jax.grad(self._h)(u)),
            signature=self._signature("state"),
        )(jnp.asarray(y))

    def vector_field(self, y):
        r"""The drift $f_0(y) = B(y)\nabla H_0(y)$: $y \times \nabla H_0(y)$ on so(3),
        $[Y, \nabla H_0(Y)]$ on so(n)."""
        y = jnp.asarray(y)
        return self.algebra.bracket(y, self.gradient(y))

    # One sample's step. `dW` is the step's noise, a `BrownianStep` (increments `dW`,
    # and Lévy areas `area` or `None`; an array of increments is accepted for a step without
    # areas; the system's `noise` is its family of Hamiltonians). The step's Hamiltonian is
    #   K = h H_0 + sum_r dW_r H_r + G_A,  G_A(y) = 1/2 sum_{q,r} A_qr <y, [grad H_q, grad H_r]>,
    # G_A the Hamiltonian of the area term sum_{q<r} A_qr [f_q, f_r] of the strong-order-1
    # expansion (`docs/levy-area.md`).

    def noise_gradient(self, y, dW):
        r"""$u(y) = \sum_r \Delta W_r \nabla H_r(y)$ for one state `y` (no area term)."""
        dW = as_step(dW).dW
        tau = self.noise.drift_time(dW)
        own = self.noise.gradient(y, dW, self.params, self.algebra)
        if tau is None:
            return own
        drift = tau * self.gradient(y)
        return drift if own is None else own + drift

    def area_hamiltonian(self, y, area):
        r"""$G_A(y) = \tfrac12\sum_{q,r} A_{qr}\langle y, [\nabla H_q(y), \nabla H_r(y)]\rangle$
        for one state `y` and a step's areas `area` (`(s, s)`): the Hamiltonian whose field is
        $\sum_{q<r} A_{qr}[f_q, f_r]$, the Lévy-area term of the step. On so(3)
        $[a, b] = a \times b$; for SALT noise $G_A$ is linear (closed form)."""
        return self.noise.area_hamiltonian(y, area, self.params, self.algebra)

    def area_gradient(self, y, area):
        r"""$\nabla G_A(y)$ (`area_hamiltonian`) for one state `y`."""
        return self.noise.area_gradient(y, area, self.params, self.algebra)

    def has_area(self, dW):
        """Whether the step `dW` brings Lévy areas that enter the step (noises of the
        system's own: with one noise `c=` there is no area)."""
        return dW.area is not None and self.noise.takes_areas

    def step_hamiltonian(self, y, dt, dW):
        r"""$K(y) = hH_0(y) + \sum_r \Delta W_r H_r(y)$ (plus $G_A(y)$ with areas) for one
        state `y`."""
        dW = as_step(dW)
        k = self._drift_time(dt, dW) * self.hamiltonian(y)
        own = self.noise.values(y, self.params)
        k = k if own is None else k + jnp.dot(dW.dW, own)
        return k + self.area_hamiltonian(y, dW.area) if self.has_area(dW) else k

    def step_gradient(self, y, dt, dW):
        r"""$\nabla K(y)$ for one state `y`."""
        dW = as_step(dW)
        g = self._drift_time(dt, dW) * self.gradient(y)
        own = self.noise.gradient(y, dW.dW, self.params, self.algebra)
        g = g if own is None else g + own
        return g + self.area_gradient(y, dW.area) if self.has_area(dW) else g

    def _drift_time(self, dt, dW):
        r"""The time $h + \tau(\Delta W)$ over which the step moves with the drift's field
        ($h$ where the noise has no part proportional to the drift)."""
        tau = self.noise.drift_time(dW.dW)
        return dt if tau is None else dt + tau

    def step_gradient_of(self, y, dt, dW):
        r"""$x \mapsto \nabla K(x)$ for one step (`step_gradient`), for the iterations of an
        implicit step near the state `y`: the noise's part computed once where it does not
        depend on the state (a linear family: $\sum_r \Delta W_r \nabla H_r$ and the area
        term, $O(s)$ matrix products on so(n), su(N)), not at every evaluation."""
        dW = as_step(dW)
        if not self.noise.linear:
            return lambda x: self.step_gradient(x, dt, dW)
        u = self.noise_gradient(y, dW)
        u = u + self.area_gradient(y, dW.area) if self.has_area(dW) else u
        return lambda x: dt * self.gradient(x) + u

    # The step in the form a method's loop carries (`fields`): what the methods call, so
    # that the algebra never sees a system.
    local_field = fields.local_field
    coordinate_field = fields.coordinate_field
    coordinate_field_jacobian = fields.coordinate_field_jacobian
    step_fields = fields.step_fields

    def noise_time(self, dW):
        r"""$c\,\Delta W$: how far one step's noise moves the random time
        $\tau = h + c\,\Delta W$ of a system whose one noise is proportional to the drift.
        `dW` is the step's increments, shape `(n_noises,) = (1,)` (a scalar, or the step's
        `BrownianStep`, is accepted)."""
        tau = self.noise.drift_time(as_step(dW).dW)
        if tau is None:
            raise ValueError("noise_time: this system has noises of its own (noise=), not c.")
        return tau


def check_system(system):
    if not isinstance(system, AbstractLiePoissonSystem):
        raise TypeError(
            f"system must be a RigidBody or a LiePoissonSystem, got {type(system).__name__}: "
            f"build one with slps_jax.RigidBody(inertia, c)."
        )


class LiePoissonSystem(AbstractLiePoissonSystem):
    r"""A stochastic Lie–Poisson system on so(3)* (or, with `algebra=`, so(n)* and su(N)*,
    where $y \times \cdot$ reads $[Y, \cdot]$): a drift Hamiltonian $H_0$ you supply and
    its noise, either one noise proportional to the drift,

    $dy = y \times \nabla H_0(y)\,(dt + c \circ dW)$ (`c=`), or $s$ noises with their own
    Hamiltonians, $dy = y \times \nabla H_0(y)\,dt + \sum_{r=1}^s y \times \nabla H_r(y)
    \circ dW_r$ (`noise=`; Stratonovich, independent Brownian motions).

    Structure matrix $B(y) = \hat y$, Casimir $C(y) = \tfrac12|y|^2$ (kept by every
    Lie–Poisson method whatever the Hamiltonians are). The rigid body is
    $H_0(y) = \tfrac12 y^T I^{-1} y$; `RigidBody` is its fast analytic special case. The
    derivatives of a Hamiltonian given as a function come from JAX.

    A pytree: `params` (any pytree of arrays), `c` and the parameters of a noise family are
    leaves, so `jax.grad` reaches them; the functions are static data. Pass the same function
    object each time (not a fresh `lambda`), or every call compiles anew.

    **Arguments:**

    - `hamiltonian`: `hamiltonian(y, params) -> scalar`, for `y` of shape `(3,)`; smooth
      (twice differentiable by JAX).
    - `params`: a pytree of parameters passed to `hamiltonian` and to `noise` (default `None`).
    - `c`: the amplitude of one noise proportional to the drift, $H_1 = cH_0$, a finite
      scalar (default 0: no noise).
    - `noise`: instead of `c`, the noise Hamiltonians: a function
      `noise(y, params) -> shape (s,)` (derivatives by JAX), or a family with closed-form
      derivatives, `salt_noise(chi)` ($H_r = \chi_r\cdot y$) or
      `random_inertia_noise(sigma)` ($H_r = \tfrac12\sum_j\sigma_{rj}y_j^2$).

    `system.n_noises` is $s$ (1 with `c`). The computation runs in the promoted floating dtype
    of the parameters (`system.dtype`). Raises `ValueError` (`TypeError` for a non-callable
    `hamiltonian` or `noise`) for invalid concrete values, before anything is compiled;
    traced values are not checked.

    **Reference:** Liu & Wang, *Lie–Poisson numerical method for a class of stochastic
    Lie–Poisson systems*, system (1) with $B(y) = \hat y$.
    """

    hamiltonian_fn: Any = eqx.field(static=True)
    algebra: AbstractAlgebra = eqx.field(static=True)
    params: Any
    noise: AbstractNoise  # the noise family (`c=`: `ProportionalNoise`)

    def __init__(
        self, hamiltonian, params=None, c=None, noise=None, algebra: AbstractAlgebra = SO3
    ):
        if not callable(hamiltonian):
            raise TypeError(
                f"hamiltonian must be callable as hamiltonian(y, params), got "
                f"{type(hamiltonian).__name__}."
            )
        if not isinstance(algebra, AbstractAlgebra):
            raise TypeError(
                f"algebra must be a Lie algebra of slps_jax (SO3, so(n), su(N)), got {algebra!r}."
            )
        params = jax.tree_util.tree_map(jnp.asarray, params)
        leaves = [
            x for x in jax.tree_util.tree_leaves(params) if jnp.issubdtype(x.dtype, jnp.inexact)
        ]
        self.hamiltonian_fn = hamiltonian
        self.params = params
        self.algebra = algebra
        self.noise = noise_or_c(c, noise, params, leaves, algebra)

    def __repr__(self):
        name = getattr(self.hamiltonian_fn, "__name__", repr(self.hamiltonian_fn))
        return (
            f"LiePoissonSystem(hamiltonian={name}, params={self.params!r}, "
            + self._noise_repr()
            + ("" if self.algebra is SO3 else f", algebra={self.algebra!r}")
            + ")"
        )
