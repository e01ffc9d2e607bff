r"""What a turbulence study reads off an Euler–Zeitlin state: the energy and enstrophy
budgets of the forced-dissipative terms, and the transfer and flux of both across degrees.

In quflow's normalisation, with $\omega_{\ell m}$ the coefficients of $W$ (`zeitlin.mat2shr`)
and $\psi_{\ell m}$ those of the stream $P$: the enstrophy is $Z = \tfrac12\sum\omega^2$ and
the energy $E = -\tfrac12\sum\psi\omega$ ($\psi = -\omega/(\ell(\ell+1))$ for Euler). Under
$\dot W = -\Lambda W - \alpha W + F$ (viscosity $\lambda_\ell = \nu(\ell(\ell+1)-2)^p$) they
change at the rates (every term a rate per second, dissipation and damping counted positive
as losses):

- enstrophy: injection $\sum\omega f + \varepsilon_Z$, dissipation $\sum\lambda_\ell\omega^2$,
  damping $\alpha\sum\omega^2 = 2\alpha Z$;
- energy: injection $-\sum\psi f + \varepsilon_E$, dissipation $-\sum\lambda_\ell\psi\omega$,
  damping $-\alpha\sum\psi\omega = 2\alpha E$;

$\varepsilon_Z$, $\varepsilon_E$ the mean rates of an additive forcing (its Itô terms). The
bracket moves neither (Casimir and Hamiltonian); it moves them between degrees: the transfer
$T_Z(\ell) = \sum_m\omega_{\ell m}\dot\omega_{\ell m}$ and $T_E(\ell) = -\sum_m\psi_{\ell m}
\dot\omega_{\ell m}$, $\dot W = [P, W + f]/\hbar$, and the flux across degree $\ell$ from the
degrees up to $\ell$ to those above, $\Pi(\ell) = -\sum_{\ell' \le \ell}T(\ell')$ (zero at
$\ell = N - 1$).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin


def _degrees(N):
    r"""The degree of each coefficient $\ell^2 + \ell + m$, `(N^2,)`."""
    return np.repeat(np.arange(N), 2 * np.arange(N) + 1)


def _by_degree(x, N):
    """Sum the per-coefficient `x` (`(..., N^2)`) over each degree: `(..., N)`."""
    terms = jnp.moveaxis(x, -1, 0)
    return jnp.moveaxis(jax.ops.segment_sum(terms, _degrees(N), num_segments=N), 0, -1)


def _coefficients(w):
    """The real coefficients of `w` (`mat2shr`), in its real dtype."""
    return zeitlin.mat2shr(w).astype(jnp.finfo(w.dtype).dtype)


def budget(system, w, forcing=None):
    r"""The rates of the energy and enstrophy budgets of `w` (the module's formulas, over
    leading axes): a dict of real arrays `energy_injection`, `energy_dissipation`,
    `energy_damping`, `enstrophy_injection`, `enstrophy_dissipation`, `enstrophy_damping`
    (per second; zero for the terms the system lacks). `forcing`: the system's constant
    forcing $F$ (`system.linear.forcing`), or `None`. $O(N^2)$: the viscous sums are inner
    products with $(-\Delta_N - 2)^pW$, $p$ applications of `zeitlin.laplacian`."""
    p = system.stream(w)
    real = jnp.finfo(w.dtype).dtype
    zero = jnp.zeros(w.shape[:-2], real)
    out = dict(
        energy_injection=zero,
        energy_dissipation=zero,
        energy_damping=zero,
        enstrophy_injection=zero,
        enstrophy_dissipation=zero,
        enstrophy_damping=zero,
    )
    linear = system.linear
    if linear is not None:
        viscous = w
        for _ in range(linear.p):  # (-Delta_N - 2)^p W
            viscous = -zeitlin.laplacian(viscous) - 2.0 * viscous
        nu, alpha = linear.nu.astype(real), linear.alpha.astype(real)
        out["enstrophy_dissipation"] = nu * zeitlin.inner(w, viscous)
        out["energy_dissipation"] = -nu * zeitlin.inner(p, viscous)
        if alpha.ndim:  # (one rate per degree: the damped part of w)
            damped = zeitlin._by_degree_map(w, alpha, linear.basis.arrays)
            out["enstrophy_damping"] = zeitlin.inner(w, damped)
            out["energy_damping"] = -zeitlin.inner(p, damped)
        else:
            out["enstrophy_damping"] = alpha * zeitlin.inner(w, w)
            out["energy_damping"] = -alpha * zeitlin.inner(p, w)
        if forcing is not None:
            f = jnp.asarray(forcing).astype(w.dtype)
            out["enstrophy_injection"] = zeitlin.inner(w, f)
            out["energy_injection"] = -zeitlin.inner(p, f)
    if system.additive is not None:
        out["enstrophy_injection"] = out["enstrophy_injection"] + (
            system.additive.enstrophy_injection().astype(real)
        )
        out["energy_injection"] = out["energy_injection"] + additive_energy_rate(system, real)
    return out


def additive_energy_rate(system, dtype):
    r"""$\varepsilon_E = -\tfrac12\sum_k\sigma_k^2\langle T_k, P(T_k)\rangle$, the mean rate at
    which the additive forcing adds energy ($\tfrac12\sum\sigma_\ell^2(2\ell+1)/(\ell(\ell+1))$
    for Euler's stream; with another `Stream`, through the stream of each forced harmonic)."""
    additive = system.additive
    if system.euler_stream:
        return additive.energy_injection().astype(dtype)
    l1, l2 = additive.band
    N = system.N
    eye = np.eye((l2 + 1) ** 2)[l1 * l1 :]
    T = zeitlin.shr2mat(eye, N)  # (K, N, N): the forced harmonics
    pairs = zeitlin.inner(T, system.stream(T))
    return (-0.5 * jnp.sum(additive._per_harmonic() ** 2 * pairs)).astype(dtype)


def transfer(system, w):
    r"""The bracket's transfer of enstrophy and energy into each degree, $T_Z(\ell)$ and
    $T_E(\ell)$, `(..., 2, N)` (per second; each sums to zero over $\ell$ without rotation;
    on the rotating sphere the relative enstrophy's does not: $\langle W, [P, f]\rangle$).
    `mat2shr`'s tables ($N^3$ numbers)."""
    N = w.shape[-1]
    view, shift = system.bracket_view()
    q = w if shift is None else w + shift.astype(w.dtype)
    p = view.stream(q)
    nonlinear = (p @ q - q @ p) / system.hbar
    rate = _coefficients(nonlinear)
    omega = _coefficients(w)
    psi = _coefficients(p)
    return jnp.stack([_by_degree(omega * rate, N), _by_degree(-psi * rate, N)], axis=-2)


def flux(system, w):
    r"""The flux of enstrophy and energy across each degree, $\Pi(\ell) =
    -\sum_{\ell'\le\ell}T(\ell')$ (`transfer`), `(..., 2, N)`: positive where the bracket
    moves them from the degrees up to $\ell$ to those above."""
    return -jnp.cumsum(transfer(system, w), axis=-1)
