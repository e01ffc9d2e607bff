"""The Euler–Zeitlin system: 2D incompressible flow on the sphere, quantised on su(N)*."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._algebra import su
from .noise import noise_or_c
from .system import LiePoissonSystem, Tables


def _euler_hamiltonian(w, params):
    r"""$H_0 = N E(W) / (2\hbar)$, $E$ quflow's energy (its gradient is in closed form:
    `EulerZeitlin.gradient`)."""
    n = w.shape[-1]
    return n * zeitlin.energy(w) / (2.0 * zeitlin.hbar(n))


class EulerZeitlin(LiePoissonSystem):
    r"""Zeitlin's model of the incompressible Euler equations on the unit sphere, stochastic:

    $dW = [P, W]/\hbar\,dt + \sum_r [W, X_r]\circ dB_r$ (`noise=salt_noise(X)`, transport
    noise), or $dW = [P, W]/\hbar\,(dt + c\circ dB)$ (`c=`), with $\Delta_N P = W$, in
    **physical time** (seconds; quflow's "qtime" is $t/\hbar$, $\hbar = 2/\sqrt{N^2-1}$).

    The state `W` is the quantised vorticity, an element of su(N) (traceless skew-Hermitian
    `(N, N)`, complex; build one with `zeitlin.shr2mat`). In the library's form
    $dW = [W, \nabla H_0]dt + \dots$ with the pairing
    $\langle X, Y\rangle = \tfrac12\operatorname{Re}\operatorname{tr}X^HY$, the Hamiltonian is
    $H_0(W) = -\langle W, \Delta_N^{-1}W\rangle / (2\hbar) = N E(W)/(2\hbar)$, $E$ quflow's
    energy, so that $\nabla H_0 = -P/\hbar$ (`docs/zeitlin.md` derives the scales).
    Transport noise $H_r(W) = \langle X_r, W\rangle$ adds $[W, X_r]\circ dB_r$; write
    `salt_noise(X)` with $X_r = -\xi_r$ for the noise $[\xi_r, W]$ of the literature.

    **Arguments:**

    - `N`: the matrix size, an integer $\ge 2$ (the field is resolved up to degree $N - 1$).
    - `c`, `noise`: as for `LiePoissonSystem` (default: deterministic).
    - `dtype`: the states' dtype, `complex128` or `complex64` (default: that of `c` or of the
      noise's matrices, complex128 with float64 enabled). `complex64` runs the system in
      single precision while float64 stays enabled for everything else: `c` and the noise
      are cast to it, and so are the states and increments given to it.
    - `poisson`: the route of the Poisson solve in every step (`zeitlin.solve_poisson`):
      `"auto"` (default), `"sweep"`, `"scan"` or `"eigenbasis"`. With `"eigenbasis"` the
      system carries its table of $N^3$ numbers (1.1 GB at N = 512 in complex128), built
      here; jitted functions must take the system as an argument, not close over it, and
      derivatives with respect to the system's parameters do not see the table.

    `system.stream(W)` ($P = \Delta_N^{-1}W$), `system.energy(W)`, `system.enstrophy(W)`
    (quflow's normalisation), `system.algebra.casimirs(W)` ($\operatorname{tr}W^k$). All
    computations are $O(N^2)$ except the methods' matrix products.

    **References:** V. Zeitlin (1991, 2004), the quantisation; K. Modin & M. Viviani,
    J. Fluid Mech. 884 (2020) A22, the conventions (quflow's); Ephrati, Jansson, Lang &
    Luesink, arXiv:2408.16701, the stochastic version with transport noise.
    """

    poisson: str = eqx.field(static=True)
    tables: Tables | None

    def __init__(self, N, *, c=None, noise=None, dtype=None, poisson="auto"):
        if isinstance(N, (bool, np.bool_)) or not isinstance(N, (int, np.integer)) or N < 2:
            raise ValueError(f"EulerZeitlin needs an integer N >= 2, got {N!r}.")
        if dtype is not None:
            if jnp.dtype(dtype) not in (jnp.dtype(jnp.complex64), jnp.dtype(jnp.complex128)):
                raise ValueError(
                    f"EulerZeitlin: dtype must be complex64 or complex128, got {dtype!r}."
                )
        algebra = su(int(N))
        noise = noise_or_c(c, noise, None, [], algebra)
        if dtype is not None:  # (the family's leaves: c, or its matrices)
            real = jnp.finfo(dtype).dtype
            noise = jax.tree_util.tree_map(
                lambda x: (
                    x.astype(dtype if jnp.iscomplexobj(x) else real)
                    if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.inexact)
                    else x
                ),
                noise,
            )
        super().__init__(_euler_hamiltonian, None, noise=noise, algebra=algebra)
        zeitlin._route(poisson)  # (refuses an unknown route)
        self.poisson = poisson
        complex_ = jnp.result_type(1j if dtype is None else dtype)
        self.tables = (
            Tables(zeitlin.poisson_eigenbasis(int(N), jnp.finfo(complex_).dtype))
            if poisson == "eigenbasis"
            else None
        )

    def _solve_poisson(self, w):
        tables = None if self.tables is None else self.tables.arrays
        return zeitlin.solve_poisson(w, route=self.poisson, eigenbasis=tables)

    @property
    def N(self):
        return self.algebra.matrix_size

    @property
    def hbar(self):
        r"""$\hbar = 2/\sqrt{N^2-1}$: seconds per unit of quflow's qtime."""
        return zeitlin.hbar(self.N)

    def __repr__(self):
        if self.c is None:  # (the noise's matrices are N x N: their count only)
            return f"EulerZeitlin({self.N}, noise={type(self.noise).__name__} of {self.n_noises})"
        return f"EulerZeitlin({self.N}, c={self.c!r})"

    quadratic_hamiltonian = True

    def stream(self, w):
        r"""The stream matrix $P = \Delta_N^{-1}W$ (traceless), over leading axes."""
        return self._solve_poisson(w)

    def energy(self, w):
        r"""quflow's energy $-\tfrac12\langle W, P\rangle_{L^2}$, over leading axes."""
        return zeitlin.energy(w)

    def enstrophy(self, w):
        r"""quflow's enstrophy $\tfrac12\langle W, W\rangle_{L^2}$, over leading axes."""
        return zeitlin.enstrophy(w)

    def gradient(self, y):
        return -self._solve_poisson(y) / self.hbar
