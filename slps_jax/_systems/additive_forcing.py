r"""Additive stochastic forcing of Euler–Zeitlin over a band of degrees (`AdditiveForcing`).

$dW = \dots + \sum_{\ell=\ell_1}^{\ell_2}\sigma_\ell\sum_{m=-\ell}^{\ell}T_{\ell m}\,dB_{\ell m}$:
independent Brownian motions on every harmonic of the band (isotropic within a degree),
the forcing of studies of forced 2D turbulence, and the only noise that moves the Casimirs.
Additive, so Itô and Stratonovich agree. Its increments are the system's last noises (after
the transport noises), so any driver drives it: Brownian (white in time) or
Ornstein–Uhlenbeck (`driver=sj.OrnsteinUhlenbeck(T)`: a forcing correlated in time, each
step's increment the exact integral of the trace over the step).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._support.checks import concrete, is_int


class AdditiveForcing(eqx.Module):
    r"""An additive stochastic forcing of `EulerZeitlin` on a band of degrees,
    $\sum_{\ell=\ell_1}^{\ell_2}\sigma_\ell\sum_m T_{\ell m}\,dB_{\ell m}$: independent
    Brownian motions on every harmonic of the band, $\sigma_\ell$ per $\sqrt{\text{second}}$.
    It injects enstrophy at the mean rate $\tfrac12\sum_\ell(2\ell+1)\sigma_\ell^2$
    (`enstrophy_injection`) and energy at $\tfrac12\sum_\ell(2\ell+1)\sigma_\ell^2/(\ell(\ell+1))$
    (`energy_injection`), in quflow's normalisation.

    `EulerZeitlin(N, additive=AdditiveForcing((8, 10), 0.1))`. Its Brownian motions are the
    system's last `n_noises` noises, after the transport noises: white in time with the
    default driver, correlated with `driver=OrnsteinUhlenbeck(T)`.

    **Arguments:**

    - `band`: the forced degrees `(l1, l2)`, integers with $1 \le \ell_1 \le \ell_2$ (and
      $\ell_2 \le N - 1$, checked by the system).
    - `amplitude`: $\sigma_\ell \ge 0$, a number for every degree of the band or one per
      degree (`l2 - l1 + 1` of them).
    """

    amplitude: jax.Array  # (sigma_l for l = l1 ... l2)
    band: tuple = eqx.field(static=True)

    def __init__(self, band, amplitude):
        ok = (
            isinstance(band, (tuple, list))
            and len(band) == 2
            and all(is_int(b) for b in band)
            and 1 <= band[0] <= band[1]
        )
        if not ok:
            raise ValueError(
                f"AdditiveForcing: band must be two integer degrees (l1, l2) with "
                f"1 <= l1 <= l2, got {band!r}."
            )
        n_degrees = band[1] - band[0] + 1
        if amplitude is None or isinstance(amplitude, (bool, np.bool_, str)):
            raise ValueError(
                f"AdditiveForcing: amplitude must be a number >= 0 or {n_degrees} of "
                f"them (one per degree of the band), got {amplitude!r}."
            )
        a = jnp.asarray(amplitude, float)
        if a.ndim > 1 or (a.ndim == 1 and a.shape[0] != n_degrees):
            raise ValueError(
                f"AdditiveForcing: amplitude must be a number or {n_degrees} of them "
                f"(one per degree {band[0]} ... {band[1]}), got shape {a.shape}."
            )
        value = concrete(a)
        if value is not None and not np.all(np.isfinite(value) & (value >= 0)):
            raise ValueError(
                f"AdditiveForcing: amplitude must be finite and >= 0, got {amplitude!r}."
            )
        self.amplitude = jnp.broadcast_to(a, (n_degrees,))
        self.band = (int(band[0]), int(band[1]))

    def check(self, N):
        """Refuse a band beyond the degrees su(N) resolves (`ValueError`)."""
        if self.band[1] > N - 1:
            raise ValueError(
                f"EulerZeitlin: the additive forcing's band {self.band} reaches degree "
                f"{self.band[1]}; su({N}) resolves degrees up to N - 1 = {N - 1}."
            )

    @property
    def n_noises(self):
        r"""The number of Brownian motions: $\sum_{\ell=\ell_1}^{\ell_2}(2\ell + 1)$."""
        l1, l2 = self.band
        return (l2 + 1) ** 2 - l1 * l1

    def _per_harmonic(self):
        """$\\sigma_\\ell$ for each harmonic of the band, in the coefficient order."""
        l1, l2 = self.band
        degree = np.repeat(np.arange(l1, l2 + 1), 2 * np.arange(l1, l2 + 1) + 1)
        return self.amplitude[degree - l1]

    def kick(self, dB, N, dtype):
        r"""The su(N) matrix $\sum\sigma_\ell\,\Delta B_{\ell m}T_{\ell m}$ of the increments
        `dB` (`(n_noises,)`), in the complex `dtype`."""
        l1, _ = self.band
        real = jnp.finfo(dtype).dtype
        coefficients = self._per_harmonic().astype(real) * jnp.asarray(dB).astype(real)
        omega = jnp.concatenate([jnp.zeros((l1 * l1,), real), coefficients])
        return zeitlin.shr2mat(omega, N).astype(dtype)

    def enstrophy_injection(self):
        r"""$\tfrac12\sum_\ell(2\ell+1)\sigma_\ell^2$: the mean rate at which the forcing adds
        enstrophy (`zeitlin.enstrophy`), per second."""
        return 0.5 * jnp.sum(self._per_harmonic() ** 2)

    def energy_injection(self):
        r"""$\tfrac12\sum_\ell(2\ell+1)\sigma_\ell^2/(\ell(\ell+1))$: the mean rate at which the
        forcing adds energy (`zeitlin.energy`), per second."""
        l1, l2 = self.band
        degree = np.repeat(np.arange(l1, l2 + 1), 2 * np.arange(l1, l2 + 1) + 1)
        return 0.5 * jnp.sum(self._per_harmonic() ** 2 / (degree * (degree + 1.0)))

    def __repr__(self):
        a = concrete(self.amplitude)
        if a is None:
            amplitude = "traced"
        elif np.all(a == a[0]):
            amplitude = f"{float(a[0]):g}"
        else:
            amplitude = "[" + ", ".join(f"{x:g}" for x in a) + "]"
        return f"AdditiveForcing(band={self.band}, amplitude={amplitude})"
