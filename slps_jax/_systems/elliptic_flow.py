r"""The exact flow of the free rigid body in closed form: the rigid body's `drift_flow`, and
through it the exact solution of the stochastic rigid body $dy = y \times I^{-1} y\,(dt + c
\circ dW)$ and the `Exact` method.

The flow is the Jacobi-elliptic closed form of Celledoni, Fassò, Säfström & Zanna (2008),
written with the addition theorem of the elliptic functions: the initial phase $u_0$ enters
only through $\mathrm{sn}, \mathrm{cn}, \mathrm{dn}(u_0)$, which are read off `y0`
algebraically, so neither the incomplete integral $F(\varphi|m)$ nor $K(m)$ is needed (nor
their logarithmic singularity at the separatrix, nor a reduction modulo the period).

The Jacobi functions come from the descending Landen transformation (the AGM) with a fixed
number of steps, so everything is plain `jax.numpy` and works under `jit`, `vmap` and
`grad`. Degenerate cases are chosen with `jnp.where`, each branch fed safe inputs when it is
not taken ("double where"), so no branch produces NaN values or gradients.
"""

from __future__ import annotations

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._support.checks import real_array

# Descending Landen steps. Each step squares the nome, so the moduli k_n = c_n / a_n fall
# doubly exponentially; the slowest case is the largest m the AGM branch sees, 1 − eps²
# (below it the separatrix branch takes over). Measured in float64 against 50-digit mpmath:
# 8 steps reach round-off for 1 − m ≥ 1e-24, 9 for 1 − m = eps²; 10 keep one in reserve.
# float32 needs 6; it runs the same 10.
_AGM_STEPS = 10


def _ellipj(u, m, m1):
    """(sn, cn, dn)(u|m), given both m and m1 = 1 − m (accurate each), 0 ≤ m ≤ 1."""
    dtype = jnp.result_type(u, m, m1)
    eps = jnp.finfo(dtype).eps
    near_sep = m1 < eps * eps

    # Landen/AGM branch (A&S 16.4), on safe inputs when the separatrix branch is taken.
    # c_n is computed as c_{n-1}^2 / (4 a_n) and c_1 as m / (4 a_1): no cancellation, and
    # no sqrt(m), whose derivative at m = 0 (a uniform rotation) would be infinite.
    ma = jnp.where(near_sep, 0.0, m)
    m1a = jnp.where(near_sep, 1.0, m1)
    # (lax.scan rather than unrolled loops: the same numbers, but XLA compiles the
    # transcendental functions and their derivatives once instead of ten times.)
    kp = jnp.sqrt(m1a)
    a1 = (1 + kp) / 2

    def agm_step(abc, _):
        a, b, c = abc
        a_next = (a + b) / 2
        return (a_next, jnp.sqrt(a * b), c * c / (4 * a_next)), c / a

    (a, _, _), ratios = lax.scan(agm_step, (a1, jnp.sqrt(kp), ma / (4 * a1)), length=_AGM_STEPS)

    # The amplitude am(u|m) itself is recursed, so no reduction modulo 4K is needed; the
    # backward step never amplifies errors in phi (its derivative lies in [0, 1]).
    def landen_step(phi, r):
        return (phi + jnp.arcsin(r * jnp.sin(phi))) / 2, None

    phi = 2.0**_AGM_STEPS * a * u  # a = a_{N+1} = a_N to round-off
    phi, _ = lax.scan(landen_step, phi, ratios, reverse=True)
    sn, cn = jnp.sin(phi), jnp.cos(phi)
    dn = jnp.sqrt(cn * cn + m1a * sn * sn)  # = sqrt(1 − m sn²) without cancellation

    # Separatrix branch, m1 < eps²: the m = 1 functions (tanh, sech) plus their first
    # order in m1 (A&S 16.15), which is below round-off in value but gives the right
    # derivative in m on the separatrix. sinh is capped where the m1-term is < eps/8.
    tanh = jnp.tanh(u)
    e = jnp.exp(-jnp.abs(u))
    sech = 2 * e / (1 + e * e)  # no overflow, unlike 1 / cosh(u)
    m1s = jnp.where(near_sep, m1, 0.0)
    cap = -jnp.log(eps)
    sinh = jnp.sinh(jnp.clip(u, -cap, cap))
    sn_s = tanh + m1s / 4 * (tanh - u * sech * sech)
    cn_s = sech - m1s / 4 * (sinh - u * sech) * tanh
    dn_s = sech + m1s / 4 * (sinh + u * sech) * tanh

    return (
        jnp.where(near_sep, sn_s, sn),
        jnp.where(near_sep, cn_s, cn),
        jnp.where(near_sep, dn_s, dn),
    )


def ellipj(u, m):
    """Jacobi elliptic functions `(sn, cn, dn)` of argument `u` and parameter
    `0 <= m <= 1` (scipy's `ellipj` convention), by a 10-step descending Landen
    transformation; for `1 - m < eps**2` the separatrix limit `(tanh, sech, sech)`."""
    u, m = jnp.asarray(u), jnp.asarray(m)
    dtype = jnp.result_type(float, u, m)
    u, m = u.astype(dtype), m.astype(dtype)
    return _ellipj(u, m, 1 - m)


def _reduced_flow(b, z, t):
    """The flow of dz/dt = z × diag(b) z for b1 ≤ b2 ≤ b3 on the side of the separatrix
    where z1 keeps its sign: (b2 − b1) z1² ≥ (b3 − b2) z3²."""
    g12, g23, g13 = b[1] - b[0], b[2] - b[1], b[2] - b[0]
    z1, z2, z3 = z[0], z[1], z[2]
    # Two equal moments and z in the plane they span (if b1 = b2, this side of the
    # separatrix forces z3 = 0): fixed points, where the elliptic formula is 0/0. They are
    # written as the uniform rotation about the distinct axis, the exact flow of the
    # axisymmetric body, so the derivative in z is right; the one in b misses the symmetry
    # breaking. Off that plane an axisymmetric body takes the elliptic formula with m = 0.
    in_plane = (g12 == 0) | ((g23 == 0) & (z1 == 0))
    saddle = ~in_plane & (z1 == 0)  # z1 = 0 then forces z3 = 0: the middle axis
    elliptic = ~in_plane & ~saddle

    sym3 = g12 == 0
    theta = jnp.where(sym3, g13 * z3, -g13 * z1) * t
    co, si = jnp.cos(theta), jnp.sin(theta)
    rot = jnp.where(
        sym3,
        jnp.stack([z1 * co + z2 * si, -z1 * si + z2 * co, z3]),
        jnp.stack([z1, z2 * co + z3 * si, -z2 * si + z3 * co]),
    )

    # The middle axis is a fixed point; writing it as its linearisation exp(Jt) applied to
    # (z1, z3) = 0 gives the right value and the right first derivatives.
    mu2 = g12 * g23 * z2 * z2
    pos = mu2 > 0
    mu = jnp.sqrt(jnp.where(pos, mu2, 1.0))
    # Capped so that cosh stays far from overflow (no inf * 0 = NaN in values or gradients);
    # beyond e^big ~ 1e154 (float32: 1e19) the derivatives are capped with it.
    big = jnp.log(jnp.finfo(mu.dtype).max) / 2
    mut = jnp.clip(mu * t, -big, big)
    ch = jnp.where(pos, jnp.cosh(mut), 1.0)
    shc = jnp.where(pos, jnp.sinh(mut) / mu, t)  # sinh(mu t) / mu
    lin = jnp.stack([ch * z1 + shc * g23 * z2 * z3, z2, ch * z3 + shc * g12 * z1 * z2])

    # Generic case. With y1 = p dn, y2 = beta sn, y3 = gamma cn (Celledoni et al. 2008, in
    # these variables) the phase is u0 + lambda t, and sn, cn, dn of u0 are y0's components
    # over (beta, gamma, p); the addition theorem then gives y(t) from sn, cn, dn(lambda t).
    one = jnp.ones_like(g12)
    g12, g23, g13 = (jnp.where(elliptic, g, k * one) for g, k in ((g12, 1), (g23, 1), (g13, 2)))
    z1 = jnp.where(elliptic, z1, 1.0)
    z2, z3 = jnp.where(elliptic, z2, 0.0), jnp.where(elliptic, z3, 0.0)
    den = g12 * (g13 * z1 * z1 + g23 * z2 * z2)  # = (b2 − b1)(b3 C − 2H) > 0
    m = g23 * (g12 * z2 * z2 + g13 * z3 * z3) / den
    m1 = g13 * (g12 * z1 * z1 - g23 * z3 * z3) / den  # ∝ b2 C − 2H, 0 on the separatrix
    p = jnp.sign(z1) * jnp.sqrt(z1 * z1 + g23 / g13 * z2 * z2)
    q, rho = jnp.sqrt(g12 * g13), jnp.sqrt(g13 / g12)  # rho = beta / gamma
    s, c, d = _ellipj(-q * p * t, m, m1)
    w = z1 / p  # = dn(u0) in (0, 1]
    delta = c * c + (s * w) ** 2  # = 1 − m sn² sn²(u0), with no cancellation
    ell = (
        jnp.stack(
            [
                z1 * d - s * c * z2 * z3 * g23 / (q * p),
                z2 * c * d + s * z3 * rho * w,
                z3 * c - s * d * z2 * w / rho,
            ]
        )
        / delta
    )

    return jnp.where(in_plane, rot, jnp.where(saddle, lin, ell))


def _check_real(name, x, shape, hint=""):
    """`x` as an array of real numbers with `shape`, finite where concrete."""
    x = real_array(name, x)
    if x.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got shape {x.shape}{hint}.")
    if not isinstance(x, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(x))):
        raise ValueError(f"{name} must be finite, got {np.asarray(x)}.")
    return x


def _check_flow_args(system, y0, t, need_c=False):
    if not hasattr(system, "inertia") or (need_c and not hasattr(system, "c")):
        raise TypeError(
            f"system must have `inertia`{' and `c`' if need_c else ''} (for example "
            f"a RigidBody), got {type(system).__name__}."
        )
    inertia = _check_real("system.inertia", system.inertia, (3,))
    if not isinstance(inertia, jax.core.Tracer) and not np.all(np.asarray(inertia) > 0):
        raise ValueError(f"system.inertia must be positive, got {np.asarray(inertia)}.")
    y0 = _check_real("y0", y0, (3,), "; use jax.vmap for a batch of initial values")
    t = _check_real("t", t, (), "; use jax.vmap for several times")
    return inertia, y0, t


def rigid_body_flow(system, y0, t):
    r"""The exact flow $\varphi_t(y_0)$ of the free rigid body

    $$\frac{dy}{dt} = y \times I^{-1} y, \qquad I = \operatorname{diag}(I_1, I_2, I_3),$$

    in closed form with Jacobi elliptic functions. The Casimir $C = |y|^2$ and the energy
    $2H = \sum_i y_i^2 / I_i$ fix the orbit; the sign of $|y|^2 - 2H I_\text{mid}$ picks
    which pair of components oscillates. The separatrix, axisymmetric bodies, the
    principal axes (fixed points), `y0 = 0`, negative `t` and moments in any order are all
    handled, and the result is differentiable in `y0`, `t` and `system.inertia`: gradients
    are finite everywhere, and exact except in the inertia where two moments are equal
    *and* `y0` lies in the plane they span (the symmetry breaking is missed there).

    Accuracy: round-off times the conditioning of the flow, which grows like $t/(1-m)$
    towards the separatrix. Measured (float64, $|t| \le 50$): ~1e-15 relative off the
    separatrix, ~3e-11 at relative distance 1e-6 from it; float32 ~1e-5.

    **Arguments:**

    - `system`: anything with `inertia`, the principal moments, shape `(3,)`, positive,
        in any order (e.g. a `RigidBody`).
    - `y0`: the initial angular momentum, shape `(3,)`.
    - `t`: the time, a scalar, may be negative.

    **Returns:**

    $\varphi_t(y_0)$, shape `(3,)`, in the promoted floating dtype of the inputs. Use
    `jax.vmap` for batches.

    **Reference:**

    E. Celledoni, F. Fassò, N. Säfström, A. Zanna, "The exact computation of the free rigid
    body motion and its use in splitting methods", SIAM J. Sci. Comput. 30 (2008),
    2084–2112. Jacobi functions by the descending Landen transformation / AGM (Abramowitz
    & Stegun 16.4, and 16.15 at the separatrix); Fukushima (2012) gives faster schemes.
    """
    inertia, y0, t = _check_flow_args(system, y0, t)
    dtype = jnp.result_type(float, inertia, y0, t)
    return _flow(inertia.astype(dtype), y0.astype(dtype), t.astype(dtype))


@jax.jit
def _flow(inertia, y0, t):
    """`rigid_body_flow` after its argument checks. Compiled as one program: run op by op (for
    example under an eager `vmap`) its hundreds of small operations took seconds."""
    dtype = y0.dtype
    # Scale y0 and a = 1/I to order one by powers of two (exact, and constants for autodiff):
    # the flow of (y / s, a / r) at time s r t is the flow of (y, a) at t, over s, and the
    # squares below then neither overflow nor underflow.
    a = 1 / inertia
    ey = jnp.clip(jnp.frexp(jnp.max(jnp.abs(y0)))[1], -1000, 1000)
    ea = jnp.clip(jnp.frexp(jnp.max(a))[1], -1000, 1000)
    one = jnp.ones((), dtype)
    s, r = jnp.ldexp(one, ey), jnp.ldexp(one, ea)  # (not ldexp(y0, .): its derivative is off)
    y0, a, t = y0 / s, a / r, t * (s * r)

    # Sort a increasingly. Permuting the axes by P turns y × Ay into
    # det(P) Py × (P A Pᵀ) Py, so an odd sort reverses time.
    order = jnp.argsort(a)
    o0, o1, o2 = order[0], order[1], order[2]
    parity = jnp.sign((o1 - o0) * (o2 - o0) * (o2 - o1)).astype(dtype)
    y_s, a_s = y0[order], a[order]
    # On the far side of the separatrix the third component keeps its sign; reversing the
    # axes (odd) and negating a (reverses time, keeps the flow) brings it back to the
    # first, with a again increasing and the time sign unchanged.
    near_side = (a_s[1] - a_s[0]) * y_s[0] ** 2 >= (a_s[2] - a_s[1]) * y_s[2] ** 2
    perm = jnp.where(near_side, order, order[::-1])
    b = jnp.where(near_side, 1.0, -1.0).astype(dtype) * a[perm]
    z = _reduced_flow(b, y0[perm], parity * t)
    return jnp.zeros_like(y0).at[perm].set(z) * s
