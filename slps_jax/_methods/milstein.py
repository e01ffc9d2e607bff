"""A derivative-free Stratonovich Milstein method with Lévy areas: the order-1 baseline that
keeps no structure."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._brownian import as_step
from .base import AbstractMethod, StrongOrders, explicit_info


class Milstein(AbstractMethod):
    r"""The Stratonovich Milstein method with the iterated integrals
    $J_{qr} = \tfrac12\Delta W_q\Delta W_r + A_{qr}$ (increments and Lévy areas) and its
    derivatives replaced by central differences of the noise fields:

    $y_{n+1} = y_n + hf_0(y_n) + \sum_r \Delta W_r f_r(y_n)
    + \sum_q \frac{g_q(y_n + \sqrt h f_q) - g_q(y_n - \sqrt h f_q)}{2\sqrt h}$,
    $g_q = \sum_r J_{qr} f_r$,

    the last sum being $\sum_{q,r} J_{qr}(Df_r)f_q$ up to $O(h^2)$ (the central difference
    has no second-derivative error, which the one-sided difference of Kloeden & Platen's
    derivative-free scheme would leave in the mean of the step at $O(h^{3/2})$ for
    nonlinear noise). Explicit, strong order 1 for any noise when given the areas (without
    them, for non-commuting noise, 1/2), weak order 1; $2s + 2$ evaluations of the noise
    fields and one of the drift per step. Not a Poisson map: $|y|$ and the Casimirs drift.
    The baseline with which the Poisson methods with areas are compared (the same accuracy
    order as Julia's `RKMilGeneral` with LevyArea.jl). Works for any system.

    **Reference:** P. E. Kloeden & E. Platen, *Numerical Solution of Stochastic Differential
    Equations* (1992), 10.3 and 11.1; A. Rößler, SIAM J. Numer. Anal. 48 (2010).
    """

    strong_orders = StrongOrders(one=1.0, increments=0.5, areas=1.0)

    def step(self, system, y, dt, dW):
        noise = as_step(dW)
        alg = system.algebra
        dtype = y.dtype
        w = noise.dW.astype(dtype)
        s = w.shape[0]
        jmat = 0.5 * jnp.outer(w, w)
        if noise.area is not None:
            jmat = jmat + noise.area.astype(dtype)

        def field(z, weights):  # sum_r weights_r f_r(z)
            return alg.bracket(z, system.noise_gradient(z, weights))

        eye = jnp.eye(s, dtype=dtype)
        f = jax.vmap(lambda e: field(y, e))(eye)  # (s, *shape): f_q(y)
        # (a failed sample idles with dt = 0: keep the difference step finite)
        eps = jnp.sqrt(jnp.where(dt > 0, dt, 1.0)).astype(dtype)
        diff = jax.vmap(
            lambda fq, jq: (field(y + eps * fq, jq) - field(y - eps * fq, jq)) / (2.0 * eps)
        )(f, jmat)
        drift = alg.bracket(y, dt * system.gradient(y))
        y_next = (y + drift + jnp.tensordot(w, f, axes=1) + jnp.sum(diff, axis=0)).astype(dtype)
        return y_next, explicit_info(y_next)
