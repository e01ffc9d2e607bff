"""The Euler–Zeitlin system: 2D incompressible flow on the sphere, quantised on su(N)*."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import zeitlin
from .._algebra import AbstractAlgebra, su
from .._support.checks import concrete
from . import budgets
from .additive_forcing import AdditiveForcing
from .linear_terms import LinearTerms, check_power
from .noise import AbstractNoise, noise_or_c
from .stream_operator import Stream
from .system import AbstractLiePoissonSystem, Tables


def _euler_hamiltonian(w, params):
    r"""$H_0 = N E(W) / (2\hbar)$, $E$ quflow's energy (its gradient is in closed form:
    `EulerZeitlin.gradient`; `EulerZeitlin._h` evaluates it with the system's own stream)."""
    n = w.shape[-1]
    return n * zeitlin.energy(w) / (2.0 * zeitlin.hbar(n))


def _cast(tree, dtype):
    """The inexact leaves of `tree` in the complex `dtype` (complex ones) or its real one."""
    real = jnp.finfo(dtype).dtype
    return jax.tree_util.tree_map(
        lambda x: (
            x.astype(dtype if jnp.iscomplexobj(x) else real)
            if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.inexact)
            else x
        ),
        tree,
    )


class EulerZeitlin(AbstractLiePoissonSystem):
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

    - `nu`, `p`, `alpha`, `forcing`: the linear terms
      $-\nu(-\Delta_N - 2)^pW - \alpha W + F$, per second (default: none). `nu >= 0` the
      viscosity, `p` a positive integer (1: Navier–Stokes on the sphere, which spares the
      rigid rotations $\ell = 1$; above: hyperviscosity), `alpha >= 0` the linear (Ekman)
      damping, `forcing` a constant element $F$ of su(N) (`(N, N)`, traceless and
      skew-Hermitian). `alpha` may also be one rate per degree $\ell = 0 \dots N - 1$
      (`(N,)`): a degree-dependent damping. quflow's viscosity `solve_viscdamp(h, W, nu, alpha)` is
      $\nu\Delta W$, which damps $\ell = 1$ too: ours with `p=1` and `alpha + 2 nu` is
      the same model.
    - `omega`: the sphere's rotation rate $\Omega$ (radians per second, default `None`: not
      rotating). The planetary vorticity $f = 2\Omega\cos\theta$, quantised
      (`zeitlin.planetary_vorticity`), enters the bracket: $\dot W = [P, W + f]/\hbar$.
      The state stays the relative vorticity $W$; the Casimirs kept are those of the
      absolute vorticity $W + f$.
    - `additive`: an additive stochastic forcing on a band of degrees,
      `AdditiveForcing(band, amplitude)` (default `None`). Its Brownian motions are the
      system's last `additive.n_noises` noises, after the transport noises (`n_noises`
      counts both). No Lévy areas with it.
    - `stream`: how the stream of a vorticity is found, a `Stream` (default `None`:
      Euler's, $\Delta_N^{-1}W$). `Stream(gamma=...)`: the global quasi-geostrophic model,
      $\Delta_NP + \tfrac\gamma2(Z^2P + PZ^2) = W$, as quflow's `solve_globalqg`
      (`zeitlin.solve_poisson`; routes `"sweep"` and `"scan"`); `Stream(gain=g)`: a
      degree-diagonal change $\sum_\ell g_\ell W_\ell$ of the stream (a modified
      Hamiltonian, as `fit_closure` fits). Every Casimir is kept either way.

    With linear terms, every method's step is the Strang splitting
    $L_{h/2}\circ\Phi_h\circ L_{h/2}$: $L$ the exact flow of the linear terms
    (`LinearTerms`), $\Phi_h$ the method's step of the bracket part (with its noise). The
    Casimirs change only in $L$. With no new term the step is the inviscid one, bit for bit.

    `system.stream(W)` ($P = \Delta_N^{-1}W$), `system.energy(W)`, `system.enstrophy(W)`
    (quflow's normalisation), `system.algebra.casimirs(W)` ($\operatorname{tr}W^k$). All
    computations are $O(N^2)$ except the methods' matrix products.

    **References:** V. Zeitlin (1991, 2004), the quantisation; K. Modin & M. Viviani,
    J. Fluid Mech. 884 (2020) A22, the conventions (quflow's); Ephrati, Jansson, Lang &
    Luesink, arXiv:2408.16701, the stochastic version with transport noise.
    """

    hamiltonian_fn: Any = eqx.field(static=True)
    algebra: AbstractAlgebra = eqx.field(static=True)
    params: Any
    noise: AbstractNoise
    poisson: str = eqx.field(static=True)
    tables: Tables | None
    linear: LinearTerms | None
    omega: jax.Array | None
    additive: AdditiveForcing | None
    stream_operator: Stream
    shift: jax.Array | None  # (the bracket's view: `bracket_view`)

    def __init__(
        self,
        N,
        *,
        c=None,
        noise=None,
        dtype=None,
        poisson="auto",
        nu=0.0,
        p=1,
        alpha: float | Any = 0.0,
        forcing=None,
        omega=None,
        stream=None,
        additive=None,
    ):
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
            noise = _cast(noise, dtype)
        self.hamiltonian_fn = _euler_hamiltonian
        self.algebra = algebra
        self.params = None
        self.noise = noise
        zeitlin._route(poisson)  # (refuses an unknown route)
        self.poisson = poisson
        if stream is None:
            stream = Stream()
        elif not isinstance(stream, Stream):
            raise TypeError(
                f"EulerZeitlin: stream must be a Stream(gamma, gain), got {type(stream).__name__}."
            )
        stream.check(int(N), poisson)
        self.stream_operator = stream
        complex_ = jnp.result_type(1j if dtype is None else dtype)
        if LinearTerms.present(nu, alpha, forcing):
            self.linear = LinearTerms(int(N), jnp.finfo(complex_).dtype, nu, p, alpha, forcing)
        else:
            check_power(p)
            self.linear = None
        if omega is not None:
            if isinstance(omega, (bool, np.bool_, str)):
                raise ValueError(f"EulerZeitlin: omega must be a real number, got {omega!r}.")
            value = concrete(jnp.asarray(omega))
            if value is not None and (np.shape(value) != () or not np.isfinite(value)):
                raise ValueError(f"EulerZeitlin: omega must be a finite scalar, got {omega!r}.")
            omega = jnp.asarray(omega, jnp.finfo(complex_).dtype)
        self.omega = omega
        if additive is not None:
            if not isinstance(additive, AdditiveForcing):
                raise TypeError(
                    f"EulerZeitlin: additive must be an AdditiveForcing(band, amplitude), "
                    f"got {type(additive).__name__}."
                )
            additive.check(int(N))
        self.additive = additive
        if dtype is not None:  # (the new terms' leaves too)
            self.linear, self.omega, self.additive, self.stream_operator = _cast(
                (self.linear, self.omega, self.additive, self.stream_operator), dtype
            )
        self.shift = None
        self.tables = (
            Tables(zeitlin.poisson_eigenbasis(int(N), jnp.finfo(complex_).dtype))
            if poisson == "eigenbasis"
            else None
        )

    @property
    def gamma(self):
        r"""The quasi-geostrophic $\gamma$ of the stream (0: Euler; `Stream`)."""
        return self.stream_operator.gamma

    @property
    def euler_stream(self):
        r"""Whether the stream is Euler's, $\Delta_N^{-1}W$ (no `Stream` gamma or gain)."""
        return self.stream_operator.euler

    def _solve_poisson(self, w):
        if self.gamma:
            p = zeitlin.solve_poisson(w, route=self.poisson, gamma=self.gamma)
        else:
            tables = None if self.tables is None else self.tables.arrays
            p = zeitlin.solve_poisson(w, route=self.poisson, eigenbasis=tables)
        if self.stream_operator.gain is not None:
            p = p + self.stream_operator.correction(w)
        return p

    def _relative(self, w):
        """The relative vorticity of a state of this view (`bracket_view`)."""
        return w if self.shift is None else w - self.shift.astype(w.dtype)

    def _h(self, y):
        if self.euler_stream and self.shift is None:
            return super()._h(y)
        return self.N * self.energy(y) / (2.0 * self.hbar)

    @property
    def planetary_vorticity(self):
        r"""$f = 2\Omega\cos\theta$ quantised (`zeitlin.planetary_vorticity`), or `None`."""
        if self.omega is None:
            return None
        return zeitlin.planetary_vorticity(self.N, self.omega, jnp.result_type(self.omega, 1j))

    def bracket_view(self):
        """The system whose state is the absolute vorticity $q = W + f$, with the Hamiltonian
        $H_0(q - f)$: the Lie–Poisson system that a method steps on the rotating sphere
        (`slps_jax._driver.splitting`), and `(view, f)`; `(self, None)` without rotation."""
        f = self.planetary_vorticity
        if f is None:
            return self, None
        return eqx.tree_at(lambda s: s.shift, self, f, is_leaf=lambda x: x is None), f

    def tendency(self, w):
        r"""The deterministic tendency $[P, W + f]/\hbar - \nu(-\Delta_N - 2)^pW - \alpha W
        + F$ of the state `w` (the drift without any noise: bracket, rotation and linear
        terms), over leading axes."""
        view, f = self.bracket_view()
        q = w if f is None else w + f.astype(w.dtype)
        out = self.algebra.bracket(q, view.gradient(q))
        return out if self.linear is None else out + self.linear.tendency(w)

    def linear_flow(self, w, tau):
        """The exact flow of the linear terms for the time `tau` (`LinearTerms.flow`)."""
        assert self.linear is not None
        return self.linear.flow(w, tau)

    @property
    def N(self):
        return self.algebra.matrix_size

    @property
    def hbar(self):
        r"""$\hbar = 2/\sqrt{N^2-1}$: seconds per unit of quflow's qtime."""
        return zeitlin.hbar(self.N)

    def __repr__(self):
        if self.c is None:  # (the noise's matrices are N x N: their count only)
            parts = [f"noise={type(self.noise).__name__} of {self.n_noises}"]
        else:
            c = concrete(self.c)
            parts = [f"c={self.c!r}" if c is None else f"c={float(c):g}"]
        if self.linear is not None:
            parts.append(repr(self.linear))
        omega = None if self.omega is None else concrete(self.omega)
        if self.omega is not None:
            parts.append(f"omega={self.omega!r}" if omega is None else f"omega={float(omega):g}")
        if not self.euler_stream:
            parts.append(repr(self.stream_operator))
        if self.additive is not None:
            parts.append(f"additive={self.additive!r}")
        return f"EulerZeitlin({self.N}, {', '.join(parts)})"

    @property
    def n_noises(self):
        """The number of independent noises: the transport noises (`noise=`, or one with
        `c=`), then the additive forcing's (`additive`), in that order in `dW`."""
        return self.noise.n_noises + (0 if self.additive is None else self.additive.n_noises)

    @property
    def takes_areas(self):
        """Whether a method may be given Lévy areas: not with an additive forcing (its many
        noises would make the areas' count grow as their square; the transport noises then
        run with their increments only)."""
        return self.additive is None

    @property
    def quadratic_hamiltonian(self):
        """$H_0$ is a quadratic form, except on the rotating sphere's view (`bracket_view`)."""
        return self.shift is None

    def stream(self, w):
        r"""The stream matrix $P = \Delta_N^{-1}W$ (traceless; with `gamma`, the
        quasi-geostrophic one), over leading axes."""
        return self._solve_poisson(self._relative(w))

    def energy(self, w):
        r"""quflow's energy $-\tfrac12\langle W, P\rangle_{L^2}$, over leading axes (with
        `gamma`, $P$ the quasi-geostrophic stream)."""
        if self.euler_stream and self.shift is None:
            return zeitlin.energy(w)
        return -0.5 * zeitlin.inner(self._relative(w), self.stream(w))

    def budget(self, w):
        r"""The energy and enstrophy budgets' rates of the state `w`, over leading axes: a
        dict of `energy_injection`, `energy_dissipation`, `energy_damping` and the same for
        the enstrophy, per second (`slps_jax._systems.budgets` has the formulas; $O(N^2)$)."""
        forcing = None if self.linear is None else self.linear.forcing
        return budgets.budget(self, w, forcing)

    def flux(self, w):
        r"""The flux of enstrophy and of energy across each degree $\ell = 0 \dots N - 1$ by
        the bracket, $\Pi(\ell) = -\sum_{\ell' \le \ell}T(\ell')$, `(..., 2, N)` (row 0 the
        enstrophy's, row 1 the energy's): positive where it moves them from the degrees up
        to $\ell$ to those above. Uses `mat2shr`'s tables ($N^3$ numbers)."""
        return budgets.flux(self, w)

    def enstrophy(self, w):
        r"""quflow's enstrophy $\tfrac12\langle W, W\rangle_{L^2}$, over leading axes."""
        return zeitlin.enstrophy(w)

    def gradient(self, y):
        return -self.stream(y) / self.hbar
