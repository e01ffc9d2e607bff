r"""How `EulerZeitlin` finds the stream of a vorticity: its Hamiltonian (`Stream`).

The stream $P$ of the vorticity $W$ solves $\Delta_NP + \tfrac\gamma2(Z^2P + PZ^2) = W$
($\gamma = 0$: Euler; $\gamma > 0$: the global quasi-geostrophic model, quflow's
`solve_globalqg`), plus a degree-diagonal correction $\sum_\ell g_\ell W_\ell$ ($W_\ell$ the
degree-$\ell$ part of $W$). The Hamiltonian is $H_0 = -N\langle W, P\rangle_{L^2}/(4\hbar)$,
a quadratic form, so any such stream keeps every Casimir $\operatorname{tr}W^k$ and the
energy $-\tfrac12\langle W, P\rangle$; the correction commutes with rotations. A fitted
closure's modified Hamiltonian is one (`fit_closure`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._support.checks import concrete
from .system import Tables


class Stream(eqx.Module):
    r"""The stream of `EulerZeitlin` (its `stream=`): $P = S_\gamma^{-1}W + \sum_\ell
    g_\ell W_\ell$, $S_\gamma P = \Delta_NP + \tfrac\gamma2(Z^2P + PZ^2)$.

    `EulerZeitlin(16, stream=Stream(gamma=0.5))` is the global quasi-geostrophic model;
    `EulerZeitlin(8, stream=Stream(gain=g))` Euler with the stream of degree $\ell$ changed
    by $g_\ell\omega_{\ell m}$ (a modified Hamiltonian: $\psi_{\ell m} = (-1/(\ell(\ell+1))
    + g_\ell)\omega_{\ell m}$ for Euler).

    **Arguments:**

    - `gamma`: the quasi-geostrophic $\gamma \ge 0$, a Python number (default 0: Euler;
      it sets the solver's tables, so it is not traced). $\gamma > 0$ takes the Poisson
      routes `"sweep"` and `"scan"`.
    - `gain`: `None` (default) or $g_\ell$ for the degrees $\ell = 0 \dots N - 1$, `(N,)`
      real and finite (the trace's, $\ell = 0$, unused): it fixes the system's $N$. It is
      applied in the eigenbasis of $\Delta_N$ (two batched products over $N^3/2$ numbers,
      carried here), and differentiable.
    """

    gain: jax.Array | None
    basis: Tables | None
    gamma: float = eqx.field(static=True)

    def __init__(self, gamma=0.0, gain=None):
        self.gamma = zeitlin._check_gamma(gamma)
        if gain is None:
            self.gain, self.basis = None, None
            return
        g = jnp.asarray(gain)
        value = concrete(g)
        if g.ndim != 1 or g.shape[0] < 2 or (value is not None and not np.isrealobj(value)):
            raise ValueError(
                f"Stream: gain must be one real number per degree 0 ... N - 1, shape (N,), "
                f"got shape {g.shape} and dtype {g.dtype}."
            )
        if value is not None and not np.all(np.isfinite(value)):
            raise ValueError("Stream: gain must be finite.")
        self.gain = g.astype(float)
        self.basis = Tables(zeitlin._folded_tables(g.shape[0], jnp.finfo(self.gain.dtype).dtype))

    @property
    def euler(self):
        r"""Whether this is Euler's stream $\Delta_N^{-1}W$ (no $\gamma$, no gain)."""
        return not self.gamma and self.gain is None

    def check(self, N, poisson):
        """Refuse a gain of another size than `N`, and `gamma` with the eigenbasis route."""
        if self.gain is not None and self.gain.shape[0] != N:
            raise ValueError(
                f"EulerZeitlin: the stream's gain has {self.gain.shape[0]} degrees; su({N}) "
                f"has N = {N} (degrees 0 ... {N - 1})."
            )
        if self.gamma and poisson == "eigenbasis":
            raise ValueError("EulerZeitlin: gamma > 0 takes poisson='auto', 'sweep' or 'scan'.")

    def correction(self, w):
        r"""$\sum_\ell g_\ell W_\ell$ of skew-Hermitian `w` (over leading axes)."""
        assert self.gain is not None and self.basis is not None
        real = jnp.finfo(w.dtype).dtype
        return zeitlin._by_degree_map(w, self.gain.astype(real), self.basis.arrays)

    def __repr__(self):
        parts = [f"gamma={self.gamma:g}"] if self.gamma else []
        if self.gain is not None:
            parts.append(f"gain=<{self.gain.shape[0]} degrees>")
        return ", ".join(parts)
