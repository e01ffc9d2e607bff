"""Exact-signature reference for the Lévy-area tests (docs/levy-area.md), independent of the library.

A fine piecewise-linear Brownian path drives the SDE
`dy = f0(y) dt + sum_r f_r(y) o dW_r`; its solution is the ODE driven by that path
(Wong-Zakai), solved piece by piece with RK4, so the reference has no scheme error. A coarse
step gets the path's exact increments and Lévy areas over the step (`coarsen`).

Plain JAX in whatever precision the caller set (the tests enable float64; this module does
not flip the flag).
"""

import jax
import jax.numpy as jnp
from jax import lax


def fine_path(key, n_paths, n_fine, T, s, dtype=None):
    """Standard Brownian increments of step `T / n_fine`, shape `(n_paths, n_fine, s)`."""
    dt = T / n_fine
    dtype = jnp.result_type(float) if dtype is None else dtype
    return jax.random.normal(key, (n_paths, n_fine, s), dtype) * jnp.sqrt(jnp.asarray(dt, dtype))


def coarsen(dW_fine, m):
    """Increments and Lévy areas of coarse steps of `m` consecutive fine pieces.

    `dW_fine`: shape `(n_paths, n_fine, s)` (or `(n_fine, s)`), the pieces of a piecewise-linear
    path; `n_fine` must be a multiple of `m`.

    **Returns** `(dW, A)`: `dW` shape `(n_paths, n_fine // m, s)`, the sums; `A` shape
    `(n_paths, n_fine // m, s, s)`, `A[..., q, r] = (J_qr - J_rq) / 2` with
    `J_qr = sum_j S_j^q d_j^r + d_j^q d_j^r / 2`, `S_j` the path before piece `j` measured from
    the coarse step's start, `d_j` the fine increments (a linear piece has zero area).
    """
    dW_fine = jnp.asarray(dW_fine)
    *batch, n_fine, s = dW_fine.shape
    if n_fine % m:
        raise ValueError(f"n_fine = {n_fine} is not a multiple of m = {m}")
    d = dW_fine.reshape(*batch, n_fine // m, m, s)
    S = jnp.cumsum(d, axis=-2) - d  # the path before piece j (exclusive)
    J = jnp.einsum("...jq,...jr->...qr", S, d) + 0.5 * jnp.einsum("...jq,...jr->...qr", d, d)
    A = 0.5 * (J - jnp.swapaxes(J, -1, -2))
    return d.sum(axis=-2), A


def chen_combine(dW1, A1, dW2, A2):
    """Chen's relation for two consecutive steps: increments add, and
    `A = A1 + A2 + (d1^q d2^r - d1^r d2^q) / 2`."""
    cross = jnp.einsum("...q,...r->...qr", dW1, dW2)
    return dW1 + dW2, A1 + A2 + 0.5 * (cross - jnp.swapaxes(cross, -1, -2))


def wong_zakai_solution(vector_fields, y0, dW_fine, T, rk4_steps=4):
    """The SDE's solution driven by the piecewise-linear path of `dW_fine`: on piece `j`,
    `dy/dt = f0(y) + sum_r f_r(y) d_j^r / dt_fine`, `rk4_steps` RK4 steps per piece.

    - `vector_fields(y) -> (f0(y), F(y))`, `F(y)` of shape `(s, *y.shape)`.
    - `y0`: the initial state, shared by all paths.
    - `dW_fine`: shape `(n_paths, n_fine, s)`.

    **Returns** the final states, shape `(n_paths, *y0.shape)`.
    """
    dW_fine = jnp.asarray(dW_fine)
    y0 = jnp.asarray(y0, jnp.result_type(jnp.asarray(y0).dtype, dW_fine.dtype))
    n_fine = dW_fine.shape[1]
    dt = T / n_fine
    h = dt / rk4_steps

    def field(y, rate):
        f0, F = vector_fields(y)
        return f0 + jnp.tensordot(rate, F, axes=1)

    def rk4(_, y, rate):
        k1 = field(y, rate)
        k2 = field(y + 0.5 * h * k1, rate)
        k3 = field(y + 0.5 * h * k2, rate)
        k4 = field(y + h * k3, rate)
        return y + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)

    def piece(y, d):
        rate = d / dt
        return lax.fori_loop(0, rk4_steps, lambda i, y: rk4(i, y, rate), y), None

    def one(dW):
        return lax.scan(piece, y0, dW)[0]

    return jax.jit(jax.vmap(one))(dW_fine)


def salt_rigid_body_fields(inertia, chi):
    """`dy = y x I^{-1} y dt + sum_r y x chi_r o dW_r` on R^3: `f0(y) = y x (y / I)`,
    `f_r(y) = y x chi_r` (`chi` shape `(s, 3)`, rows the axes)."""
    inertia = jnp.asarray(inertia)
    chi = jnp.asarray(chi)

    def vector_fields(y):
        return jnp.cross(y, y / inertia), jnp.cross(y[None, :], chi)

    return vector_fields


def salt_so_n_fields(grad_h0, X):
    """SALT noise on so(n) (and su(n)): `f0(Y) = [Y, grad_h0(Y)]`,
    `f_r(Y) = [Y, X_r] = Y X_r - X_r Y` (`[A, B] = AB - BA`; `X` shape `(s, n, n)`, skew
    (skew-Hermitian); `grad_h0(Y)` an element of the algebra)."""
    X = jnp.asarray(X)

    def vector_fields(Y):
        G = grad_h0(Y)
        return Y @ G - G @ Y, Y[None] @ X - X @ Y[None]

    return vector_fields
