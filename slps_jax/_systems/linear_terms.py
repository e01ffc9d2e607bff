r"""The linear terms of forced-dissipative Euler–Zeitlin, and their exact flow.

$\dot W = -\nu(-\Delta_N - 2)^pW - \alpha W + F$: viscosity ($p = 1$, Navier–Stokes on the
sphere, which spares the rigid rotations $\ell = 1$) or hyperviscosity ($p > 1$), linear
(Ekman) damping and a constant forcing $F \in \mathfrak{su}(N)$. Every term is diagonal in
the quantised harmonics, so the flow for a time $\tau$ is exact: a degree-$\ell$ component
is multiplied by $e^{-\tau\lambda_\ell}$, $\lambda_\ell = \nu(\ell(\ell+1) - 2)^p + \alpha_\ell$
($\alpha$ one number, or one per degree: a degree-dependent damping, as a fitted closure's),
and the forcing enters by variation of constants, $\tau\varphi(\tau\lambda_\ell)F_\ell$ with
$\varphi(z) = (1 - e^{-z})/z$. Computed in the eigenbasis of $\Delta_N$ on each diagonal
(`zeitlin.poisson_eigenbasis`): two batched products.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._support.checks import concrete, is_int
from .system import Tables


def _nonnegative(name, x):
    """`x` as a real scalar array, refused when concretely negative or not finite."""
    if isinstance(x, (bool, np.bool_, str)) or x is None:
        raise ValueError(f"EulerZeitlin: {name} must be a finite number >= 0, got {x!r}.")
    value = concrete(jnp.asarray(x)) if not isinstance(x, (int, float)) else np.asarray(x)
    if value is not None:
        if np.shape(value) != () or not np.isrealobj(value):
            raise ValueError(f"EulerZeitlin: {name} must be a real scalar, got {x!r}.")
        if not (math.isfinite(float(value)) and float(value) >= 0):
            raise ValueError(f"EulerZeitlin: {name} must be a finite number >= 0, got {x!r}.")
    return jnp.asarray(x, float)


def _damping(alpha, N):
    r"""The linear damping: a number $\ge 0$, or one per degree $\ell = 0 \dots N - 1$
    (`(N,)`, each $\ge 0$; the trace's, $\ell = 0$, unused), as a real array."""
    if isinstance(alpha, (bool, np.bool_, str)) or alpha is None or np.ndim(alpha) == 0:
        return _nonnegative("alpha", alpha)
    a = jnp.asarray(alpha)
    value = concrete(a)
    if a.shape != (N,) or (value is not None and not np.isrealobj(value)):
        raise ValueError(
            f"EulerZeitlin: alpha must be a number or one real number per degree "
            f"0 ... {N - 1} (shape ({N},)), got shape {a.shape}."
        )
    if value is not None and not np.all(np.isfinite(value) & (value >= 0)):
        raise ValueError("EulerZeitlin: alpha's values must be finite and >= 0.")
    return a.astype(float)


def check_power(p):
    """The viscosity's power `p`: a positive integer (`ValueError` otherwise)."""
    if not is_int(p) or p < 1:
        raise ValueError(f"EulerZeitlin: p must be a positive integer, got {p!r}.")


def check_forcing(forcing, N):
    """A constant forcing: an `(N, N)` traceless skew-Hermitian matrix (an element of su(N)),
    refused otherwise by name."""
    f = np.asarray(forcing) if concrete(jnp.asarray(forcing)) is not None else None
    if f is None:
        return jnp.asarray(forcing)
    if f.shape != (N, N):
        raise ValueError(
            f"EulerZeitlin: forcing must be an element of su({N}), an ({N}, {N}) matrix, "
            f"got shape {f.shape}."
        )
    if not np.all(np.isfinite(f)):
        raise ValueError("EulerZeitlin: forcing must be finite.")
    scale = max(float(np.max(np.abs(f))), np.finfo(np.float64).tiny)
    tol = 1e-10 if f.dtype != np.complex64 else 1e-5
    if float(np.max(np.abs(f + np.conj(f.T)))) / 2 > tol * scale:
        raise ValueError(
            "EulerZeitlin: forcing must be skew-Hermitian (an element of su(N): build one "
            "with zeitlin.shr2mat of real coefficients)."
        )
    if abs(complex(np.trace(f))) / N > tol * scale:
        raise ValueError(
            "EulerZeitlin: forcing must be traceless (an element of su(N): its degree-0 "
            "coefficient is zero)."
        )
    return jnp.asarray(f)


class LinearTerms(eqx.Module):
    r"""$-\nu(-\Delta_N - 2)^pW - \alpha W + F$ (`EulerZeitlin`'s `nu`, `p`, `alpha`,
    `forcing`), per second, with its exact flow (`flow`). It carries the eigenvectors of
    $\Delta_N$ on half of the cyclic diagonals (`basis`: $(N/2 + 1)N^2$ numbers, 67 MB at
    N = 256 in float64), and the forcing in that basis."""

    nu: jax.Array
    alpha: jax.Array
    forcing_coefficients: jax.Array | None  # (F in the half eigenbasis: `forcing`)
    basis: Tables
    p: int = eqx.field(static=True)
    N: int = eqx.field(static=True)

    def __init__(self, N, real_dtype, nu=0.0, p=1, alpha=0.0, forcing=None):
        check_power(p)
        self.nu = _nonnegative("nu", nu)
        self.alpha = _damping(alpha, N)
        self.p = int(p)
        self.N = int(N)
        tables = zeitlin._folded_tables(N, real_dtype)
        self.basis = Tables(tables)
        self.forcing_coefficients = (
            None
            if forcing is None
            else zeitlin._to_skew_eigenbasis(
                check_forcing(forcing, N).astype(jnp.result_type(real_dtype, 1j)), tables
            )
        )

    @property
    def forcing(self):
        """The forcing $F$, an `(N, N)` element of su(N), or `None`."""
        if self.forcing_coefficients is None:
            return None
        return zeitlin._from_skew_eigenbasis(self.forcing_coefficients, self.basis.arrays, self.N)

    @staticmethod
    def present(nu, alpha, forcing):
        """Whether any term is on (a traced `nu` or `alpha` counts as on)."""
        values = [concrete(jnp.asarray(x)) for x in (nu, alpha)]
        return forcing is not None or any(v is None or np.any(v != 0.0) for v in values)

    def rates(self, N, dtype):
        r"""$\lambda_\ell = \nu(\ell(\ell+1) - 2)^p + \alpha$ at each coefficient of the
        folded eigenbasis (`zeitlin._folded_eigenbasis`), `(2, N // 2 + 1, N // 2 + 1)`; the
        trace ($\ell = 0$, zero in su(N)) and the padding get $\alpha$."""
        ell = zeitlin._folded_degrees(N)
        viscous = np.where(ell > 0, (ell * (ell + 1.0) - 2.0) ** self.p, 0.0)
        return self.nu.astype(dtype) * jnp.asarray(viscous, dtype) + self.damping(dtype)[ell]

    def damping(self, dtype):
        r"""The linear damping rate of each degree $\ell = 0 \dots N - 1$, `(N,)`."""
        return jnp.broadcast_to(self.alpha.astype(dtype), (self.N,))

    def flow(self, w, tau):
        r"""The exact flow of $\dot W = -\Lambda W + F$ for the time `tau` (a scalar, possibly
        traced; 0 leaves `w` as it is), over leading axes of `w` (skew-Hermitian)."""
        tables = self.basis.arrays
        N = w.shape[-1]
        real = jnp.finfo(w.dtype).dtype
        tau = jnp.asarray(tau).astype(real)
        z = tau * self.rates(N, real)
        y = zeitlin._to_skew_eigenbasis(w, tables) * jnp.exp(-z)
        if self.forcing_coefficients is not None:  # tau phi(tau lambda) F, phi = (1 - e^-z)/z
            safe = jnp.where(z == 0, 1.0, z)
            phi = jnp.where(z == 0, 1.0, -jnp.expm1(-safe) / safe)
            y = y + tau * phi * self.forcing_coefficients.astype(y.dtype)
        return zeitlin._from_skew_eigenbasis(y, tables, N).astype(w.dtype)

    def tendency(self, w):
        r"""$-\Lambda W + F$: the linear terms' rate of change at `w` (over leading axes)."""
        tables = self.basis.arrays
        real = jnp.finfo(w.dtype).dtype
        y = -zeitlin._to_skew_eigenbasis(w, tables) * self.rates(w.shape[-1], real)
        if self.forcing_coefficients is not None:
            y = y + self.forcing_coefficients.astype(y.dtype)
        return zeitlin._from_skew_eigenbasis(y, tables, w.shape[-1]).astype(w.dtype)

    def __repr__(self):
        parts = []
        for name in ("nu", "alpha"):
            leaf = getattr(self, name)
            value = concrete(leaf)
            if value is None:
                parts.append(f"{name}={leaf!r}")
            elif np.ndim(value):
                parts.append(f"{name}=<one per degree>")
            elif float(value) != 0.0:
                parts.append(f"{name}={float(value):g}")
        if self.p != 1:
            parts.append(f"p={self.p}")
        if self.forcing_coefficients is not None:
            parts.append("forcing=F")
        return ", ".join(parts)
