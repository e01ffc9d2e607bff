"""The noise of a system, $dy = y \\times \\nabla H_0(y)\\,dt + \\sum_r y \\times
\\nabla H_r(y) \\circ dW_r$: every system has a noise family, the one home of what a step's
noise does.

A noise family is a pytree whose leaves are its parameters (so `jax.grad` reaches them) and
which gives the integrators the one combination they need: for weights $w$ (a step's
increments) $\\sum_r w_r H_r = \\tau(w) H_0 + \\sum_r w_r \\tilde H_r$, a change
$\\tau(w)$ of the drift's time (`drift_time`; only `ProportionalNoise`, the family of `c=`,
has one) and the family's own Hamiltonians $\\tilde H_r$, through
$u(y) = \\sum_r w_r \\nabla\\tilde H_r(y)$ and its Jacobian $\\partial u/\\partial y$. A
family of its own Hamiltonians writes `values` and `gradient`; the Jacobian comes from JAX
unless it has a closed form (`salt_noise`, `random_inertia_noise`).
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._support.checks import concrete, float_dtype, numeric_array, real_array


class AbstractNoise(eqx.Module):
    """A noise family: the extension point for noise Hamiltonians with closed forms or
    parameters of their own (`LiePoissonSystem(..., noise=family)`, `RigidBody(..., noise=)`,
    `EulerZeitlin(N, noise=)`).

    A subclass is an `equinox.Module` (its parameters, declared as fields, are the pytree's
    leaves; static data is `eqx.field(static=True)`) and writes `n_noises`, `values` and
    `gradient`; everything else has a default.

    - `n_noises`: the number $s$ of noises (static).
    - `values(y, params)`: $(H_1(y), \\dots, H_s(y))$ for one state `y`.
    - `gradient(y, w, params, algebra)`: $u = \\sum_r w_r \\nabla H_r(y)$, a state.
    - `gradient_jacobian(y, w, params, algebra)`: $(u, \\partial u/\\partial y)$, the
      Jacobian of shape `shape + shape` (by JAX unless overridden with a closed form).
    - `check_algebra(algebra)`: raise `ValueError` if the family does not fit its states.

    - `drift_time(w)`: $\\tau(w)$ where part of the noise is the drift's own, so that
      $\\sum_r w_r H_r = \\tau(w) H_0 + \\sum_r w_r\\tilde H_r$ (`None`, the default, where none
      is: every family but `ProportionalNoise`). A family without Hamiltonians of its own
      returns `None` from `values`, `gradient` and `gradient_jacobian`.

    `params` are the system's parameters (families with their own leaves ignore them).
    """

    linear = False  # all H_r linear: u does not depend on y (SALT; enables closed forms)
    takes_areas = True  # the step's Lévy areas enter it (not with one noise)

    def drift_amplitude(self):
        """The amplitude $c$ of a noise proportional to the drift (`ProportionalNoise`), else
        `None`."""
        return None

    def drift_time(self, w):
        r"""$\tau(w)$: how far the weights `w` move the drift's time (`None`: not at all)."""
        return None

    @property
    @abc.abstractmethod
    def n_noises(self) -> int:
        """The number $s$ of noises."""

    @abc.abstractmethod
    def values(self, y, params):
        r"""$(H_1(y), \dots, H_s(y))$, shape `(s,)`, at one state `y`."""

    def gradient(self, y, w, params, algebra):
        raise NotImplementedError

    def gradient_jacobian(self, y, w, params, algebra):
        r"""$(u, \partial u/\partial y)$ at one state `y`, in one forward-mode pass."""

        def u(x):
            return self.gradient(x, w, params, algebra)

        jac, g = jax.jacfwd(lambda x: (u(x), u(x)), has_aux=True)(y)
        return g, jac

    def check_algebra(self, algebra):
        pass

    def area_hamiltonian(self, y, area, params, algebra):
        r"""$G_A(y) = \tfrac12\sum_{q,r} A_{qr}\langle y, [\nabla H_q(y), \nabla H_r(y)]\rangle$
        for the areas `area` (`(s, s)`, antisymmetric): the gradients by JAX."""
        g = algebra.gradient(jax.jacrev(lambda u: self.values(u, params))(y))  # (s, *shape)
        return 0.5 * algebra.pairing(y, algebra.bracket_sum(g, jnp.tensordot(area, g, axes=1)))

    def area_gradient(self, y, area, params, algebra):
        r"""$\nabla G_A(y)$ (`area_hamiltonian`), by JAX."""
        return algebra.gradient(jax.grad(self.area_hamiltonian)(y, area, params, algebra))


class ProportionalNoise(AbstractNoise):
    r"""One noise proportional to the drift, $H_1 = cH_0$:
    $dy = y \times \nabla H_0(y)\,(dt + c \circ dW)$, the paper's noise. A step with the
    increment $\Delta W$ is the drift's step over the random time $\tau = h + c\Delta W$
    (`drift_time`), so the family has no Hamiltonians of its own, and no Lévy area (one
    noise). Build with `proportional_noise(c)`, or pass `c=` to a system; `c` is a pytree
    leaf."""

    takes_areas = False
    c: jax.Array

    @property
    def n_noises(self):
        return 1

    def __repr__(self):
        return f"proportional_noise({self.c!r})"

    def drift_amplitude(self):
        return self.c

    def drift_time(self, w):
        return self.c * jnp.reshape(w, ())

    def values(self, y, params):
        return None

    def gradient(self, y, w, params, algebra):
        return None

    def gradient_jacobian(self, y, w, params, algebra):
        return None, None

    def area_hamiltonian(self, y, area, params, algebra):
        raise ValueError(
            "this system has one noise proportional to the drift (c=): it has no Lévy area."
        )

    area_gradient = area_hamiltonian


def proportional_noise(c, dtype=None):
    r"""One noise proportional to the drift, $H_1 = cH_0$: the noise of `c=`
    ($dy = y \times \nabla H_0(y)\,(dt + c \circ dW)$).

    **Arguments:** `c`, a finite real scalar (0: no noise; a pytree leaf, so `jax.grad`
    reaches it); `dtype` (default: `c`'s floating dtype, at least the default float).

    **Returns:** the noise family (a `ProportionalNoise`, one noise) for `noise=` of any
    system; `RigidBody(I, c=0.2)` is `RigidBody(I, noise=proportional_noise(0.2))`.
    """
    c = real_array("c", c)
    c = c.astype(float_dtype(c) if dtype is None else dtype)
    if c.shape != ():
        raise ValueError(f"c must be a scalar, got shape {c.shape}.")
    c_np = concrete(c)
    if c_np is not None and not np.isfinite(c_np):
        raise ValueError(f"c must be finite, got {c_np}.")
    return ProportionalNoise(c)


def noise_or_c(c, noise, params, leaves, algebra):
    """A system's noise family from its arguments: `noise` (a family or a function, `as_noise`)
    or `c` (`proportional_noise`, 0 when neither is given), in the floating dtype of `leaves`
    (the system's parameters) and `c`. Refuses both together and bad values by name."""
    if noise is not None:
        if c is not None:
            raise ValueError(
                "Pass either c (one noise proportional to the drift, H_1 = c H_0) "
                "or noise (the noise Hamiltonians), not both."
            )
        return as_noise(noise, params, float_dtype(*leaves), algebra)
    c = real_array("c", 0.0 if c is None else c)
    return proportional_noise(c, float_dtype(c, *leaves))


def _parameter_matrix(name, x, what, matrices=False):
    """A family's parameter: shape `(s, 3)`, or with `matrices` also `(s, n, n)` (one
    element of the algebra per noise, real or complex: checked against the system's algebra
    by `check_algebra`)."""
    x = numeric_array(name, x, allow_complex=matrices)
    x = x.astype(float_dtype(x))
    square = matrices and x.ndim == 3 and x.shape[1] == x.shape[2] >= 2
    if not (x.ndim == 2 and x.shape[1] == 3 or square) or x.shape[0] < 1:
        raise ValueError(
            f"{name} must have shape (s, 3), one row per noise ({what})"
            + (", or (s, n, n), one element of so(n) or su(n) per noise" if matrices else "")
            + f", got shape {x.shape}."
        )
    x_np = concrete(x)
    if x_np is not None and not np.all(np.isfinite(x_np)):
        raise ValueError(f"{name} must be finite, got {x_np}.")
    if square and x_np is not None:  # (the algebra's own conditions: `check_algebra`)
        asym = np.max(np.abs(x_np + np.conj(np.swapaxes(x_np, 1, 2))))
        if asym > 1e-12 * max(1.0, float(np.max(np.abs(x_np)))):
            raise ValueError(
                f"{name}[r] must be skew-symmetric (so(n)) or skew-Hermitian "
                f"(su(n)) matrices; max |{name} + {name}^H| = {asym:.3g}."
            )
    return x


class _AbstractParameterNoise(AbstractNoise):
    """A family whose one parameter is an `(s, 3)` array, one row per noise, stored under
    `parameter_name` (a pytree leaf; `calibrate` fits it by that name)."""

    parameter_name: eqx.AbstractClassVar[str]
    builder: eqx.AbstractClassVar[str]  # the public function that builds it, for the repr

    def __init__(self, value):
        setattr(self, self.parameter_name, value)

    @property
    def parameter(self):
        return getattr(self, self.parameter_name)

    @property
    def n_noises(self):
        return self.parameter.shape[0]

    def __repr__(self):
        return f"{self.builder}({self.parameter!r})"

    def check_algebra(self, algebra):
        if self.parameter.shape[1:] != algebra.shape:
            raise ValueError(
                f"{self.builder}: {self.parameter_name} of shape {self.parameter.shape} does not fit "
                f"the states of {algebra.name}, shape {algebra.shape}: pass shape "
                f"(s, {', '.join(map(str, algebra.shape))})."
            )
        x_np = concrete(self.parameter)
        if self.linear and x_np is not None:  # (its rows are elements of the algebra)
            for r, x in enumerate(x_np):
                algebra.validate(f"{self.parameter_name}[{r}]", x)
        elif x_np is not None and np.iscomplexobj(x_np):
            raise TypeError(f"{self.builder}: {self.parameter_name} must be real.")


class SaltNoise(_AbstractParameterNoise):
    r"""Stochastic advection by Lie transport: $H_r(y) = \chi_r \cdot y$, so the noise field
    $y \times \chi_r$ rotates $y$ about the fixed axis $\chi_r$. Build with `salt_noise`."""

    linear = True
    parameter_name: ClassVar[str] = "chi"
    builder: ClassVar[str] = "salt_noise"
    chi: jax.Array

    def values(self, y, params):
        if self.chi.ndim == 2:
            return self.chi @ y
        # <X_r, Y> = (1/2) Re tr(X_r^H Y) on so(n) and su(N)
        return 0.5 * jnp.sum(jnp.real(jnp.conj(self.chi) * y), axis=(-2, -1))

    def gradient(self, y, w, params, algebra):
        return jnp.tensordot(w, self.chi, axes=1).astype(y.dtype)

    def gradient_jacobian(self, y, w, params, algebra):
        u = self.gradient(y, w, params, algebra)
        return u, jnp.zeros(u.shape + y.shape, u.dtype)  # (constant: linear Hamiltonians)

    def area_gradient(self, y, area, params, algebra):
        r"""$\nabla G_A = \tfrac12\sum_{q,r} A_{qr}[\chi_q, \chi_r]
        = \tfrac12\sum_q[\chi_q, \sum_r A_{qr}\chi_r]$ (on so(3)
        $\chi_q \times \chi_r$): constant, in closed form; $O(s)$ products on matrices
        (`bracket_sum`)."""
        chi = self.chi.astype(y.dtype)
        return 0.5 * algebra.bracket_sum(chi, jnp.tensordot(area, chi, axes=1))

    def area_hamiltonian(self, y, area, params, algebra):
        return algebra.pairing(y, self.area_gradient(y, area, params, algebra))


def salt_noise(chi):
    r"""Stochastic advection by Lie transport (Holm 2015): $s$ linear noise Hamiltonians
    $H_r(y) = \chi_r \cdot y$ on so(3), $H_r(Y) = \langle X_r, Y\rangle$ on so(n).

    **Arguments:** `chi`, shape `(s, 3)`: row $r$ is the axis (times the strength) of noise
    $r$; on so(n) shape `(s, n, n)`, one skew matrix $X_r$ per noise (on su(N) a
    skew-Hermitian one, complex). A pytree leaf: `jax.grad` reaches it.

    **Returns:** the noise family (an `AbstractNoise` of `s` noises) for `noise=` of
    `RigidBody`, `LiePoissonSystem` or `EulerZeitlin`.
    """
    return SaltNoise(_parameter_matrix("chi", chi, "the axis of each noise", matrices=True))


class RandomInertiaNoise(_AbstractParameterNoise):
    r"""Random inertia: $H_r(y) = \tfrac12 \sum_j \sigma_{rj} y_j^2$. Build with
    `random_inertia_noise`."""

    parameter_name: ClassVar[str] = "sigma"
    builder: ClassVar[str] = "random_inertia_noise"
    sigma: jax.Array

    def values(self, y, params):
        return 0.5 * self.sigma @ (y * y)

    def gradient(self, y, w, params, algebra):
        return (w @ self.sigma) * y

    def gradient_jacobian(self, y, w, params, algebra):
        d = w @ self.sigma
        return d * y, jnp.diag(d)


def random_inertia_noise(sigma):
    r"""Random inertia: $s$ quadratic noise Hamiltonians
    $H_r(y) = \tfrac12 \sum_j \sigma_{rj} y_j^2$ (for the rigid body, noise on the inverse
    moments of inertia $1/I_j$).

    **Arguments:** `sigma`, shape `(s, 3)`: row $r$ the strengths of noise $r$. A pytree leaf.

    **Returns:** the noise family (an `AbstractNoise` of `s` noises) for `noise=` of
    `RigidBody` or `LiePoissonSystem` on so(3)*.
    """
    return RandomInertiaNoise(_parameter_matrix("sigma", sigma, "the strengths of each noise"))


class FunctionNoise(AbstractNoise):
    """Noise Hamiltonians from a function `fn(y, params) -> (s,)`, derivatives by JAX.
    `LiePoissonSystem(..., noise=fn)` builds it (and checks the shape); the function is static
    data, its parameters are the system's `params`."""

    fn: Callable = eqx.field(static=True)
    count: int = eqx.field(static=True)

    @property
    def n_noises(self):
        return self.count

    def __repr__(self):
        return getattr(self.fn, "__name__", repr(self.fn))

    def values(self, y, params):
        return self.fn(y, params)

    def _weighted_h(self, w, params):
        return lambda y: jnp.dot(w, self.fn(y, params))

    def gradient(self, y, w, params, algebra):
        return algebra.gradient(jax.grad(self._weighted_h(w, params))(y))


def as_noise(noise, params, dtype, algebra):
    """`noise` as a noise family for states of `algebra`: a family is returned as it is
    (after checking that it fits the states); a function `noise(y, params) -> (s,)` is
    wrapped in `FunctionNoise` after its output shape is checked (by `jax.eval_shape`,
    nothing is computed)."""
    if isinstance(noise, AbstractNoise):
        noise.check_algebra(algebra)
        return noise
    if not callable(noise):
        raise TypeError(
            f"noise must be a function noise(y, params) -> shape (s,) or a noise "
            f"family such as salt_noise(chi), got {type(noise).__name__}."
        )
    try:
        out = jax.eval_shape(
            noise, jax.ShapeDtypeStruct(algebra.shape, algebra.state_dtype(dtype)), params
        )
    except Exception as err:  # noqa: BLE001 - reported with the function's name
        raise ValueError(f"noise(y, params) failed on y of shape {algebra.shape}: {err}") from err
    shape = getattr(out, "shape", None)
    if shape is None or len(shape) != 1 or shape[0] < 1:
        raise ValueError(
            f"noise(y, params) must return the s noise Hamiltonians, shape (s,) "
            f"with s >= 1, got {shape if shape is not None else type(out)}."
        )
    return FunctionNoise(noise, int(shape[0]))
