"""Symmetric splitting into the three axis rotations (McLachlan 1993)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._algebra import so3 as comp
from .._brownian import as_step
from .._systems.capabilities import LINEAR_NOISE, NOISE_PROPORTIONAL_TO_DRIFT, RIGID_BODY
from .base import AbstractMethod, StrongOrders, explicit_info
from .composition import TRIPLE_JUMP

# The two components that axis i rotates, in cyclic order (i, j, k).
_PLANES = ((1, 2), (2, 0), (0, 1))


def axis_flow(y, inverse_inertia, axis, tau):
    r"""The exact flow of $H_i(y) = y_i^2/(2I_i)$ for time `tau`, on components.

    $\dot y = y \times \nabla H_i(y) = (y_i/I_i)\, y \times e_i$: $y_i$ is constant and, with
    $(i, j, k)$ cyclic and $\omega = y_i/I_i$, $\dot y_j = \omega y_k$, $\dot y_k = -\omega y_j$,
    a plane rotation by the angle $-\omega\tau$ about $e_i$:
    $y_j \leftarrow \cos(\omega\tau) y_j + \sin(\omega\tau) y_k$,
    $y_k \leftarrow -\sin(\omega\tau) y_j + \cos(\omega\tau) y_k$.

    **Arguments:** `y` and `inverse_inertia` component tuples, `axis` in {0, 1, 2} (a Python
    int), `tau` the (possibly random, possibly negative) time.

    **Returns:** the component tuple of the new state.
    """
    j, k = _PLANES[axis]
    angle = inverse_inertia[axis] * y[axis] * tau
    cos, sin = jnp.cos(angle), jnp.sin(angle)
    out = list(y)
    out[j] = cos * y[j] + sin * y[k]
    out[k] = cos * y[k] - sin * y[j]
    return tuple(out)


class Strang(AbstractMethod):
    r"""Symmetric (Strang) splitting of the Hamiltonian into its three axis parts.

    $$y_{n+1} = \Phi^{1}_{\tau_n/2} \circ \Phi^{2}_{\tau_n/2} \circ \Phi^{3}_{\tau_n}
    \circ \Phi^{2}_{\tau_n/2} \circ \Phi^{1}_{\tau_n/2}(y_n), \qquad
    \tau_n = h + c\,\Delta W_n,$$

    where $\Phi^i_t$ is the exact flow of $H_i(y) = y_i^2/(2I_i)$ for
    $\dot y = y \times \nabla H_i(y)$, $H = H_1 + H_2 + H_3$: the rotation about the axis
    $e_i$ by the angle $-t\,y_i/I_i$ (with $y_i$ constant), so each sub-flow is explicit and
    closed-form. Any palindromic order of the axes gives a method of the same kind; this one
    uses 1, 2, 3, 2, 1.

    Every sub-flow is a Poisson map of so(3)* and a rotation, so the step is explicit, a
    Poisson map, and preserves the Casimir $|y|$ exactly up to round-off (it does not
    conserve $H$ exactly). It is symmetric and of deterministic order 2.

    The noise multiplies the drift's own vector field, so the SDE is the free rigid body flow
    run to the random time $t + cW(t)$, and a deterministic method of order $p$ applied with
    the random step $\tau_n$ has strong order $\lfloor p/2 \rfloor$: here 1. (The
    non-symmetric Lie–Trotter splitting, $p = 1$, does not converge, so it is not offered.)

    **Reference:**

    R. I. McLachlan, "Explicit Lie–Poisson integration and the Euler equations",
    Phys. Rev. Lett. 71 (1993), 3043–3046.
    """

    requires = frozenset({RIGID_BODY, NOISE_PROPORTIONAL_TO_DRIFT})
    can_fail = False  # exact rotations: no solve
    strong_orders = StrongOrders(one=1.0, increments=None)
    poisson = True

    def step(self, system, y, dt, dW):
        return _composed_step(system, y, dt + system.noise_time(dW), (1.0,))


def _strang_flow(yc, inv_i, tau):
    half = 0.5 * tau
    for axis, t in ((0, half), (1, half), (2, tau), (1, half), (0, half)):
        yc = axis_flow(yc, inv_i, axis, t)
    return yc


def _composed_step(system, y, tau, weights):
    inv_i = comp.vec(system.inverse_inertia())
    yc = comp.vec(y)
    # A loop, not an unrolled chain, even for one Strang step: each flow reads every
    # component twice, and XLA's CPU backend fuses an unrolled chain of flows (with whatever
    # computed tau, the random-number generator in `simulate`) into one elementwise kernel
    # that re-evaluates the earlier flows exponentially often (~1000x slower for 15 flows,
    # ~150x for Strang's 5 inside `simulate`; `optimization_barrier` does not stop it). The
    # loop body is one Strang step.
    gammas = jnp.asarray(weights, jnp.asarray(tau).dtype)
    yc = jax.lax.fori_loop(
        0, len(weights), lambda i, u: _strang_flow(u, inv_i, gammas[i] * tau), yc
    )
    y_next = comp.unvec(yc).astype(y.dtype)
    return y_next, explicit_info(y_next)


class Strang4(AbstractMethod):
    r"""Yoshida's triple jump of `Strang`: explicit, deterministic order 4, strong order 2.

    $$y_{n+1} = S_{\gamma_1\tau_n} \circ S_{\gamma_0\tau_n} \circ S_{\gamma_1\tau_n}(y_n),
    \qquad \gamma_1 = \frac{1}{2 - 2^{1/3}},\ \gamma_0 = 1 - 2\gamma_1,$$

    with $S_t$ the `Strang` step and $\tau_n = h + c\,\Delta W_n$. Fifteen exact axis
    rotations per step, so it is explicit, a Poisson map, and keeps the Casimir $|y|$ to
    round-off, for any $|y_0|$. Rigid body only.

    A deterministic order-4 method applied with the random step $\tau_n$ has strong order
    $\lfloor 4/2 \rfloor = 2$ for this SDE (its noise multiplies the drift's own vector
    field).

    **Reference:** H. Yoshida, "Construction of higher order symplectic integrators",
    Phys. Lett. A 150 (1990), 262–268; R. I. McLachlan (1993), see `Strang`;
    D. Cohen, K. Debrabant, A. Rößler, arXiv:2004.12887.
    """

    requires = frozenset({RIGID_BODY, NOISE_PROPORTIONAL_TO_DRIFT})
    can_fail = False  # exact rotations: no solve
    strong_orders = StrongOrders(one=2.0, increments=None)
    poisson = True

    def step(self, system, y, dt, dW):
        return _composed_step(system, y, dt + system.noise_time(dW), TRIPLE_JUMP)


class SaltSplitting(AbstractMethod):
    r"""Explicit symmetric splitting for a rigid body with linear (SALT) noise,
    $dy = y \times I^{-1}y\,dt + \sum_r y \times \chi_r \circ dW_r$:

    $$y_{n+1} = N_n \circ D_h \circ N_n(y_n), \qquad
    N_n = \exp(-\tfrac12\hat u_n),\ u_n = \sum_r \Delta W_{r,n}\,\chi_r,$$

    where $D_h$ is one `Strang` step of the drift (five exact axis rotations) and $N_n$ is the
    exact flow of the step's noise Hamiltonian $\sum_r \Delta W_{r,n}\,\chi_r\cdot y$ for half
    the step: one rotation about $u_n$ by $|u_n|/2$. (Solving each noise separately,
    palindromically, as Bréhier, Cohen & Jahnke do, agrees with $N_n$ to second order in the
    increments, the commutators cancelling; both miss the same Lévy-area terms.) Every piece
    is a rotation, so the step is an explicit Poisson map that keeps $|y|$ to round-off; it
    is symmetric, of strong order 1/2 and weak order 1 (measured in
    `benchmarks/several_noises.py`). No solve, so it never fails. The cost is the ten sines
    and cosines of the drift's axis rotations.

    **Reference:** C.-E. Bréhier, D. Cohen, T. Jahnke, "Splitting integrators for stochastic
    Lie–Poisson systems", Math. Comp. 92 (2023), 2167–2216; R. I. McLachlan (1993), see
    `Strang`.
    """

    requires = frozenset({RIGID_BODY, LINEAR_NOISE})
    can_fail = False  # exact rotations: no solve
    # (the areas in the noise rotation's axis)
    strong_orders = StrongOrders(one=None, increments=0.5, areas=1.0)
    poisson = True

    def step(self, system, y, dt, dW):
        inv_i = comp.vec(system.inverse_inertia())
        noise = as_step(dW)
        u = system.noise_gradient(y, noise)  # (constant: linear Hamiltonians)
        if noise.area is not None:  # the area term's rotation axis (`area_gradient`)
            u = u + system.area_gradient(y, noise.area)
        u = comp.vec(u)
        noise = comp.exp(comp.scale(-0.5, u))

        # N, D, N as two rounds of (N, then D in the first round only): a loop, not a chain
        # of flows that XLA would fuse into one kernel re-evaluating them (`_composed_step`);
        # the round index is not batched, so `cond` runs one branch.
        def body(i, v):
            v = comp.mv(noise, v)
            return jax.lax.cond(i == 0, lambda w: _strang_flow(w, inv_i, dt), lambda w: w, v)

        yc = jax.lax.fori_loop(0, 2, body, comp.vec(y))
        y_next = comp.unvec(yc).astype(y.dtype)
        return y_next, explicit_info(y_next)
