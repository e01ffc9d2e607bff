"""The so(3) / SO(3) toolkit: `hat`, `vee`, `skew`, `sym`, `exp`, `log`, `cayley`,
`cayley_inv`. The functions take arrays whose last axis has length 3 (vectors) or whose last
two axes are 3x3 (matrices), and broadcast over leading axes; underneath, every formula is
written once on components (the so(3) algebra's module)."""

from __future__ import annotations

import jax.numpy as jnp

from ._algebra import so3 as _comp

__all__ = ["cayley", "cayley_inv", "exp", "hat", "log", "skew", "sym", "vee"]


def hat(v):
    """The skew matrix of a vector: `hat(v) @ u = v x u`.

    **Arguments:** `v`, shape `(..., 3)`. **Returns:** shape `(..., 3, 3)`.
    """
    return _comp.unmat(_comp.hat(_comp.vec(jnp.asarray(v))))


def vee(m):
    """Inverse of `hat` on skew matrices: the axial vector. For a general matrix it returns
    the axial vector of its skew part.

    **Arguments:** `m`, shape `(..., 3, 3)`. **Returns:** shape `(..., 3)`.
    """
    return _comp.unvec(_comp.vee_skew(_comp.mat(jnp.asarray(m))))


def skew(m):
    """The skew-symmetric part of a matrix, $\\mathrm{skew}(M) = (M - M^T)/2$.

    **Arguments:** `m`, shape `(..., 3, 3)` (the formula is the same for any square
    `(..., n, n)`). **Returns:** the skew-symmetric part, the shape of `m`.
    """
    m = jnp.asarray(m)
    return 0.5 * (m - jnp.swapaxes(m, -1, -2))


def sym(m):
    """The symmetric part of a matrix, $\\mathrm{sym}(M) = (M + M^T)/2$.

    **Arguments:** `m`, shape `(..., 3, 3)` (the formula is the same for any square
    `(..., n, n)`). **Returns:** the symmetric part, the shape of `m`.
    """
    m = jnp.asarray(m)
    return 0.5 * (m + jnp.swapaxes(m, -1, -2))


def exp(xi):
    """The exponential map so(3) -> SO(3) (Rodrigues' formula).

    $\\exp(\\hat\\xi) = I + \\frac{\\sin\\theta}{\\theta}\\hat\\xi
    + \\frac{1-\\cos\\theta}{\\theta^2}\\hat\\xi^2$, $\\theta = |\\xi|$, with a Taylor series
    below a dtype-dependent threshold so that values and gradients are exact at $\\theta = 0$.

    **Arguments:** `xi`, shape `(..., 3)`. **Returns:** rotation matrices `(..., 3, 3)`.
    """
    return _comp.unmat(_comp.exp(_comp.vec(jnp.asarray(xi))))


def log(r):
    """Inverse of `exp` for rotations by an angle $\\theta < \\pi$.

    Uses $\\theta = \\operatorname{atan2}(|w|, (\\operatorname{tr} R - 1)/2)$ with
    $w = \\mathrm{vee}(\\mathrm{skew}\\,R) = \\sin\\theta\\, u$; accurate away from
    $\\theta = \\pi$, where the axis is not determined by the skew part.

    **Arguments:** `r`, rotation matrices `(..., 3, 3)`. **Returns:** `(..., 3)`.
    """
    m = _comp.mat(jnp.asarray(r))
    w = _comp.vee_skew(m)
    s2 = _comp.dot(w, w)
    small = s2 < _comp.small_angle_threshold(s2.dtype) ** 2
    s = jnp.sqrt(jnp.where(small, 1.0, s2))
    theta = jnp.arctan2(s, 0.5 * (_comp.trace(m) - 1.0))
    # theta / sin(theta) -> 1 + theta^2/6 as theta -> 0.
    factor = jnp.where(small, 1.0 + s2 / 6.0, theta / s)
    return _comp.unvec(_comp.scale(factor, w))


def cayley(xi):
    """The Cayley map so(3) -> SO(3): $(I - \\hat\\xi/2)^{-1}(I + \\hat\\xi/2)$.

    It is the rotation by $\\theta = 2\\arctan(|\\xi|/2)$ about $\\xi/|\\xi|$, smooth everywhere.

    **Arguments:** `xi`, shape `(..., 3)`. **Returns:** `(..., 3, 3)`.
    """
    return _comp.unmat(_comp.cayley(_comp.vec(jnp.asarray(xi))))


def cayley_inv(r):
    """Inverse of `cayley` for rotations by $\\theta < \\pi$: $\\xi = 4 w / (1 + \\operatorname{tr} R)$.

    **Arguments:** `r`, rotation matrices `(..., 3, 3)`. **Returns:** `(..., 3)`.
    """
    m = _comp.mat(jnp.asarray(r))
    return _comp.unvec(_comp.scale(4.0 / (1.0 + _comp.trace(m)), _comp.vee_skew(m)))
