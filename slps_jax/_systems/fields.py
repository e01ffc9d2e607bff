r"""A system's step in the form a method's loop carries it: the field
$F(x) = [x, \nabla K(x)]$ of one step's Hamiltonian $K = hH_0 + \sum_r \Delta W_r H_r$
(plus the area term $G_A$), its Jacobian, and what scheme (42)'s in-map needs on so(3).

The system offers these to the methods (`LiePoissonSystem.local_field`, `coordinate_field`,
`coordinate_field_jacobian`, `step_fields`); an algebra gives only its forms (`local`,
`local_coordinates`) and its bracket, and knows nothing of systems. On so(3)* as 3-vectors
(`SO3`) everything is written on components from what the system states in closed form (a
diagonal quadratic $H_0$, `quadratic_drift`; the noise family's `gradient` and
`gradient_jacobian`): element-wise arithmetic on long vectors under `vmap`. Elsewhere it is
written once for every algebra, with Jacobians by forward-mode autodiff.
"""

from __future__ import annotations

import jax

from .._algebra import SO3
from .._algebra.so3 import (
    add,
    add_any,
    cross,
    hat,
    madd,
    mat,
    mm_any,
    mscale,
    mul,
    scale,
    scale_any,
    unvec,
    vec,
)
from .._brownian import as_step


def local_field(system, x, dt, dW):
    r"""$F(x) = [x, \nabla K(x)]$ of one step (`dW` its `BrownianStep`), in the local form."""
    if system.algebra is SO3:
        return cross(x, _step_gradient(system, x, dt, dW))
    return system.algebra.bracket(x, system.step_gradient(x, dt, dW))


def coordinate_field(system, u, dt, dW):
    """`local_field` on the local form's real coordinates (the unknowns of an implicit solve)."""
    alg = system.algebra
    x = alg.from_local_coordinates(u)
    return alg.local_coordinates(local_field(system, x, dt, dW))


def coordinate_field_jacobian(system, u, dt, dW):
    """`(coordinate_field(u), its Jacobian)`: on so(3) in closed form, elsewhere by
    forward-mode autodiff."""
    if system.algebra is SO3:
        k, hk, _, _ = step_fields(system, u, dt, dW, second=False)
        # d(u x k(u))/du = hat(u) grad^2 K - hat(k)
        return cross(u, k), madd(mm_any(hat(u), hk), mscale(-1.0, hat(k)))
    f = lambda u: coordinate_field(system, u, dt, dW)
    return f(u), jax.jacfwd(f)(u)


def step_fields(system, v, dt, dW, second=True):
    r"""What scheme (42)'s in-map needs of a step (`sine_chart_in_map`), on so(3)'s
    components: $(\nabla K, \nabla^2 K, u, \partial u/\partial v)$ at `v`, with
    $u = \sum_r \Delta W_r \nabla H_r$ the increments' part of the noise (the areas'
    $\nabla G_A$ is in $K$ only). Without the second-order term (`second=False`) `u` and
    its Jacobian are `None`; a Jacobian is `None` where it is zero (linear noise), and
    diagonal (`is_diagonal`) where the closed form is."""
    if system.algebra is not SO3:
        raise ValueError(
            "step_fields: the components of so(3)* (a system on sj.SO3); this system is on "
            f"{system.algebra}."
        )
    dW = as_step(dW)
    g, hess = _drift_hessian(system, v)
    tau = system.noise.drift_time(dW.dW)  # (the noise's part proportional to the drift)
    time = dt if tau is None else dt + tau
    k, hk = scale(time, g), scale_any(time, hess)
    u, ju = _noise_jacobian(system, v, dW.dW)  # (the family's own Hamiltonians)
    if u is not None:
        k, hk = add(k, u), add_any(hk, ju)
    if system.has_area(dW):
        ga, ha = _area_jacobian(system, v, dW.area)
        k, hk = add(k, ga), add_any(hk, ha)
    if not second:
        return k, hk, None, None
    if tau is not None:  # u = sum_r dW_r grad H_r includes the drift's part
        du, dju = scale(tau, g), scale_any(tau, hess)
        u, ju = (du, dju) if u is None else (add(u, du), add_any(ju, dju))
    return k, hk, u, ju


def _step_gradient(system, v, dt, dW):
    r"""$\nabla K(v)$ on so(3)'s components; with `c=`, $K = \tau H_0$, $\tau = h + c\Delta W$."""
    dW = as_step(dW)
    g = scale(system._drift_time(dt, dW), _drift(system, v))
    own = _noise(system, v, dW.dW)
    g = g if own is None else add(g, own)
    return add(g, _area(system, v, dW.area)) if system.has_area(dW) else g


def _drift(system, v):
    r"""$\nabla H_0(v)$: written out for a diagonal quadratic $H_0$
    (`system.quadratic_drift`), else by JAX."""
    d = system.quadratic_drift
    if d is not None:
        return mul(vec(d), v)
    return vec(jax.grad(system.hamiltonian)(unvec(v)))


def _drift_hessian(system, v):
    r"""$(\nabla H_0(v), \nabla^2 H_0(v))$, the Hessian diagonal (`is_diagonal`) for a
    diagonal quadratic $H_0$, else by JAX in one forward-mode pass."""
    d = system.quadratic_drift
    if d is not None:
        d = vec(d)
        return mul(d, v), d
    grad = jax.grad(system.hamiltonian)
    hess, g = jax.jacfwd(lambda u: (grad(u), grad(u)), has_aux=True)(unvec(v))
    return vec(g), mat(hess)


def _noise(system, v, w):
    r"""$u(v) = \sum_r w_r \nabla \tilde H_r(v)$ of the family's own Hamiltonians
    (`AbstractNoise.gradient`; `None` without any)."""
    u = system.noise.gradient(unvec(v), w, system.params, system.algebra)
    return None if u is None else vec(u)


def _noise_jacobian(system, v, w):
    r"""$(u, \partial u/\partial v)$ (`AbstractNoise.gradient_jacobian`) of the family's own Hamiltonians,
    `(None, None)` without any; the Jacobian is `None` for linear noise (zero: no arithmetic
    with zeros)."""
    if system.noise.linear:
        return _noise(system, v, w), None
    u, ju = system.noise.gradient_jacobian(unvec(v), w, system.params, system.algebra)
    return (None, None) if u is None else (vec(u), mat(ju))


def _area(system, v, area):
    r"""$\nabla G_A(v)$."""
    return vec(system.area_gradient(unvec(v), area))


def _area_jacobian(system, v, area):
    r"""$(\nabla G_A(v), \nabla^2 G_A(v))$; `None` (zero) for linear noise, whose $G_A$ is
    linear."""
    if system.noise.linear:
        return _area(system, v, area), None
    grad = lambda u: system.area_gradient(u, area)
    jac, g = jax.jacfwd(lambda u: (grad(u), grad(u)), has_aux=True)(unvec(v))
    return vec(g), mat(jac)
