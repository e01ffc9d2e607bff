"""The Brownian driver: what one step's noise is, how it is drawn, and how it composes.

A step's noise is one value, a `BrownianStep`: the increments `dW` of the `s` noises and,
when asked for, their Lévy areas `area` (`(s, s)`, antisymmetric). Every rule for it lives
here: drawing it from a sample's key (`draw`), joining consecutive steps into one (`join`:
increments add, areas by Chen's relation), and scaling it (`scale_noise`: a step split into `m`
equal substeps has `(dW/m, A/m)` each, consistent with Chen's relation because the
fine steps' increments are parallel).

Sample `i` of an ensemble uses the key `fold_in(key, i)`, and its step `n` the increment drawn
from `fold_in(fold_in(key, i), n)`. So a sample's path depends on nothing but the user's key,
its index and the step: not on the batch size, the chunking, or the number of steps. The
areas of step `n` come from `fold_in(fold_in(fold_in(key, i), n), AREA_STREAM)`, a key that
no increment uses.
"""

from __future__ import annotations

import abc
import functools
import math
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


class BrownianStep(NamedTuple):
    r"""The noise of one step, as a method's `step(system, y, dt, dW)` receives it: the
    increments and, when drawn, the Lévy areas. A pytree (a `NamedTuple`).

    **Arguments:**

    - `dW`: the increments, shape `(s,)`, one per noise.
    - `area`: the Lévy areas, shape `(s, s)`, antisymmetric:
      `area[q, r]` $= \tfrac12(J_{qr} - J_{rq})$ with the iterated Stratonovich integral
      $J_{qr} = \int_{t_n}^{t_{n+1}} (W_q(t) - W_q(t_n)) \circ dW_r(t)$; or `None`
      (default) when the step has none (one noise, or a method that does not use them).
    """

    dW: jax.Array
    area: jax.Array | None = None


def as_step(noise):
    """`noise` as a `BrownianStep`: a `BrownianStep` as it is, an array of increments (or a
    scalar, for one noise) as the step without areas."""
    if isinstance(noise, BrownianStep):
        return noise
    return BrownianStep(jnp.reshape(jnp.asarray(noise), (-1,)))


def scale_noise(noise, factor):
    """The step's noise times `factor` (increments and areas alike): a substep of a step
    split into `m` equal parts is `scale_noise(noise, 1/m)`, and `m` of them joined by Chen's
    relation give the step back (their increments are parallel, so no cross terms)."""
    noise = as_step(noise)
    return jax.tree_util.tree_map(lambda x: factor * x, noise)


def where(cond, noise, other=0.0):
    """`noise` where `cond`, else `other` (increments and areas alike)."""
    return jax.tree_util.tree_map(lambda x: jnp.where(cond, x, other).astype(x.dtype), noise)


def join(first, second):
    r"""One step made of two consecutive ones: the increments add, the areas by Chen's
    relation $A = A_1 + A_2 + \tfrac12(\delta_1\delta_2^T - \delta_2\delta_1^T)$."""
    dW = first.dW + second.dW
    if first.area is None:
        return BrownianStep(dW)
    cross = jnp.outer(first.dW, second.dW)
    return BrownianStep(dW, first.area + second.area + 0.5 * (cross - cross.T))


def coarsen(dW, area, m):
    r"""Given noises of consecutive steps, `dW` of shape `(..., n_steps, s)` and `area` of
    shape `(..., n_steps, s, s)` (or `None`), those of the steps made of `m` consecutive
    ones (`n_steps` a multiple of `m`): `join` applied over each block, vectorised,
    $A = \sum_j A_j + \tfrac12\sum_j (S_j\delta_j^T - \delta_jS_j^T)$ with $S_j$ the
    increment of the block before step $j$. **Returns** `(dW, area)`."""
    *batch, n, s = dW.shape
    if n % m:
        raise ValueError(f"the number of steps {n} must be a multiple of m = {m}.")
    d = dW.reshape(*batch, n // m, m, s)
    if area is None:
        return d.sum(-2), None
    before = jnp.cumsum(d, axis=-2) - d
    cross = jnp.einsum("...jq,...jr->...qr", before, d)
    a = area.reshape(*batch, n // m, m, s, s).sum(-3)
    return d.sum(-2), a + 0.5 * (cross - jnp.swapaxes(cross, -1, -2))


def zero_step(n_noises, dtype, areas):
    """The noise of a step of length 0 (the start of `join`)."""
    return BrownianStep(
        jnp.zeros((n_noises,), dtype), jnp.zeros((n_noises, n_noises), dtype) if areas else None
    )


def check_key(key, name="key"):
    """A typed PRNG key (`jax.random.key`), or a legacy raw `uint32[2]` key
    (`jax.random.PRNGKey`), as a typed key. Both give the same samples for the same seed.
    Anything else (a plain integer, a batch of keys, a float array) is a `TypeError` or
    `ValueError` that says what to pass."""
    if isinstance(key, (bool, np.bool_)):
        raise TypeError(f"{name} must be a JAX PRNG key, got {key!r}: pass jax.random.key(seed).")
    if isinstance(key, (int, np.integer)):
        raise TypeError(
            f"{name} must be a JAX PRNG key, got the integer {key!r}: pass jax.random.key({key!r})."
        )
    if not hasattr(key, "dtype") or not hasattr(key, "shape"):
        raise TypeError(f"{name} must be a JAX PRNG key (jax.random.key(seed)), got {type(key)}.")
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.shape != ():
            raise ValueError(
                f"{name} must be a single key, got a key array of shape {key.shape}: "
                f"pass one key, for example {name}[0]."
            )
        return key
    if key.dtype == jnp.uint32 and key.shape == (2,):
        return jax.random.wrap_key_data(jnp.asarray(key))
    if key.dtype == jnp.uint32 and key.ndim == 2 and key.shape[-1] == 2:
        raise ValueError(f"{name} must be a single key, got {key.shape[0]} legacy keys: pass one.")
    raise TypeError(
        f"{name} must be a JAX PRNG key: jax.random.key(seed) (or a legacy "
        f"jax.random.PRNGKey(seed)); got an array of dtype {key.dtype} and shape {key.shape}."
    )


def truncation_bound(dt, truncate_k):
    """$A_h = \\sqrt{2k|\\ln h|}$ (Milstein, Repin & Tretyakov 2002), or `inf` for `None`."""
    if truncate_k is None:
        return math.inf
    return math.sqrt(2.0 * truncate_k * abs(math.log(dt)))


def check_truncation(dt, truncate_k):
    if truncate_k is None:
        return
    if isinstance(truncate_k, (bool, np.bool_)) or not (
        isinstance(truncate_k, (int, float, np.integer, np.floating))
        and truncate_k > 0
        and math.isfinite(truncate_k)
    ):
        raise ValueError(f"truncate_k must be a positive number or None, got {truncate_k!r}.")
    if dt >= 1.0:
        raise ValueError(
            f"truncate_k={truncate_k} needs dt < 1: the bound sqrt(2k|ln dt|) collapses at "
            f"dt = 1 (got dt={dt}); pass truncate_k=None."
        )


@functools.partial(jax.jit, static_argnames="n_samples")
def sample_keys(key, n_samples, offset=0):
    """Keys of samples `offset, ..., offset + n_samples - 1` (`offset` may be traced: one
    compilation serves every chunk of a streamed ensemble). Jitted: called eagerly it is one
    program per `n_samples`, not a program for each of its operations."""
    idx = jnp.asarray(offset, jnp.uint32) + jnp.arange(n_samples, dtype=jnp.uint32)
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(idx)


def increment(sample_key, n, dt, bound, dtype, n_noises=1):
    """The truncated increments of step `n`, shape `(n_noises,)`:
    $\\Delta\\hat W_{n,r} = \\sqrt h\\, \\mathrm{clip}(\\xi_{n,r}, \\pm A_h)$, componentwise, from
    `fold_in(sample_key, n)` (the first component does not depend on `n_noises`)."""
    return _increment(jax.random.fold_in(sample_key, n), dt, bound, dtype, n_noises)


def _increment(step_key, dt, bound, dtype, n_noises):
    """`increment` from the step's key `fold_in(sample_key, n)`."""
    xi = jax.random.normal(step_key, (n_noises,), dtype)
    return jnp.sqrt(dt).astype(dtype) * jnp.clip(xi, -bound, bound)


# The data folded into a step's key for the key of its areas: the increments use the first
# few numbers of the step key's stream, never this one, in either of JAX's threefry modes.
AREA_STREAM = 0xFFFFFFFF


def levy_area_terms(dt, n_noises):
    r"""The number $p$ of series terms of the area sampler (`draw_levy_area`) for steps of size
    `dt` and `n_noises` noises: the smallest $p \ge 1$ with
    $\sqrt s\,h/(\sqrt{12}\,\pi\,p) \le h^{3/2}$, the bound of Mrongowius & Rößler
    (2022) on the root-mean-square error of every area. A mean-square error $O(h^3)$ per step
    is what strong order 1 needs. For $s = 3$: $p = 2, 3, 4, 6$ at
    $h = 2^{-7}, 2^{-8}, 2^{-9}, 2^{-10}$, that is $2sp + s + s(s-1)/2 = 18, 24, 30, 42$
    normal numbers per step (the increments take $s = 3$)."""
    return max(1, math.ceil(math.sqrt(n_noises) / (math.sqrt(12.0) * math.pi * math.sqrt(dt))))


def _tail(p):
    r"""$\sum_{k > p} 1/k^2 = \pi^2/6 - \sum_{k \le p} 1/k^2$."""
    return math.pi**2 / 6.0 - sum(1.0 / k**2 for k in range(1, p + 1))


def draw_levy_area(key, dW, dt, bound, terms):
    r"""The Lévy areas of one step given its increments `dW` (shape `(s,)`), sampled by the
    algorithm of Mrongowius & Rößler (2022): the Fourier series of the Brownian bridge
    (Kloeden, Platen & Wright 1992) truncated after `terms` terms,

    $A_{qr} = \frac{h}{2\pi}\sum_{k=1}^p \frac1k\big(X_{qk}(Y_{kr} - \sqrt2\xi_r)
    - X_{rk}(Y_{kq} - \sqrt2\xi_q)\big) + \text{tail}$, $\xi = \Delta W/\sqrt h$,

    with the tail replaced by a Gaussian of the same conditional covariance,
    $\frac{h}{2\pi}\sqrt{2a_p}\,\big(\xi_q\Psi_r - \xi_r\Psi_q + G_{qr}\big)$,
    $a_p = \sum_{k>p} k^{-2}$: $2sp + s + s(s-1)/2$ standard normals from `key`, clipped at
    the truncation bound of the increments (`bound`). Conditionally on the increments the
    areas have mean 0 and variance $h^2/12 + h(\Delta W_q^2 + \Delta W_r^2)/12$ exactly,
    whatever `terms`; their mean-square error is $O(h^2/p^2)$ (`levy_area_terms`).

    **Returns:** the `(s, s)` antisymmetric matrix of areas.
    """
    s, dtype = dW.shape[0], dW.dtype
    p = int(terms)
    z = jnp.clip(jax.random.normal(key, (2 * s * p + s + s * (s - 1) // 2,), dtype), -bound, bound)
    xi = dW / jnp.sqrt(dt).astype(dtype)
    k = jnp.arange(1, p + 1, dtype=dtype)
    x = z[: s * p].reshape(s, p)
    y = (z[s * p : 2 * s * p].reshape(p, s) - math.sqrt(2.0) * xi) / k[:, None]
    psi = z[2 * s * p : 2 * s * p + s]
    a = math.sqrt(2.0 * _tail(p))
    # (elementwise products and sums, not a matmul or a scatter, which under `vmap` over
    # samples and steps become batches of tiny matrices)
    m = jnp.sum(x[:, :, None] * y[None, :, :], axis=1) + a * xi[:, None] * psi[None, :]
    m = m + a * jnp.sum(z[2 * s * p + s :, None, None] * _upper(s, dtype), axis=0)
    return (dt / (2.0 * math.pi)).astype(dtype) * (m - m.T)


def _upper(s, dtype):
    """The `s(s-1)/2` unit matrices `E_qr`, `q < r`, shape `(s(s-1)/2, s, s)`."""
    rows, cols = np.triu_indices(s, 1)
    e = np.zeros((len(rows), s, s))
    e[np.arange(len(rows)), rows, cols] = 1.0
    return jnp.asarray(e, dtype)


def draw(sample_key, n, dt, bound, dtype, n_noises, terms=None):
    """The noise of step `n` of a sample (a `BrownianStep`): its truncated increments
    (`increment`) and, with `terms` (the series length, `levy_area_terms`), its Lévy areas
    drawn from the step key's own area stream. The increments do not depend on whether the
    areas are drawn."""
    step_key = jax.random.fold_in(sample_key, n)  # (derived once, for both)
    dW = _increment(step_key, dt, bound, dtype, n_noises)
    if terms is None:
        return BrownianStep(dW)
    area_key = jax.random.fold_in(step_key, AREA_STREAM)
    return BrownianStep(dW, draw_levy_area(area_key, dW, jnp.asarray(dt, dtype), bound, terms))


def draw_joined(sample_key, n, fine_steps, fine_dt, bound, dtype, n_noises, terms=None):
    """The noise of coarse step `n` made of the fine steps `n m, ..., n m + m - 1`
    (`m = fine_steps`, possibly traced) of size `fine_dt`, joined by `join`: the very same
    Brownian path as a run with step `fine_dt`."""
    if isinstance(fine_steps, int) and fine_steps == 1:
        return draw(sample_key, n, fine_dt, bound, dtype, n_noises, terms)
    return jax.lax.fori_loop(
        0,
        fine_steps,
        lambda k, w: join(
            w, draw(sample_key, n * fine_steps + k, fine_dt, bound, dtype, n_noises, terms)
        ),
        zero_step(n_noises, dtype, terms is not None),
    )


class AbstractDraws(abc.ABC):
    """The steps' noise of one sample, as the driver's loop draws it: `init`, the state
    before the first step (`()` for none), and `block(state, n0, length, n_live)`, the noises
    of steps `n0 ... n0 + length - 1` (a `BrownianStep` with a leading axis) and the state
    after the first `n_live` of them (the rest are the loop's padding)."""

    init: Any = ()

    @abc.abstractmethod
    def block(self, state, n0, length, n_live):
        """`(state, noises)` of the steps `n0 ... n0 + length - 1`."""


class IndexedDraws(AbstractDraws):
    """Noise drawn by step index, with no state: a Brownian path's, or given increments.
    `draw(n)` is step `n`'s `BrownianStep` (`n` may be traced)."""

    def __init__(self, draw):
        self.draw = draw

    def block(self, state, n0, length, n_live):
        return state, jax.vmap(lambda j: self.draw(n0 + j))(jnp.arange(length, dtype=n0.dtype))


class AbstractPath(eqx.Module):
    """A driver's steps of one size, as the driver's loop asks for them (`AbstractDriver.path`):
    `draws(key)` is the noise of the sample whose key is `key` (an `AbstractDraws`). A pytree:
    its step `dt` and constants are leaves.

    - `coarsens`: whether `coarsened(m, dt)` gives the same noise in steps of `m` of its
      own (what the convergence studies need).
    """

    dt: eqx.AbstractVar[Any]
    coarsens: eqx.AbstractClassVar[bool]

    @property
    @abc.abstractmethod
    def has_areas(self) -> bool:
        """Whether the steps' noises carry their Lévy areas."""

    @abc.abstractmethod
    def without_areas(self) -> AbstractPath:
        """The same noise without the Lévy areas."""

    @abc.abstractmethod
    def draws(self, key) -> AbstractDraws:
        """The noise of the steps of the sample whose key is `key`."""

    @abc.abstractmethod
    def innovations(self, n_steps) -> tuple[tuple[int, ...], float]:
        """`(shape, variance)` of the independent Gaussian numbers from which `steps_from`
        makes `n_steps` steps of one sample's noise: what a move in the space of the noise
        (the filter's pCN) proposes. A path whose noise is not Gaussian in them (truncated,
        or with Lévy areas) raises `ValueError`, naming the option."""

    @abc.abstractmethod
    def initial_state(self, key, batch=()):
        """The state of `batch` samples before their first step, drawn from `key` (`()`: a
        path without a state)."""

    @abc.abstractmethod
    def steps_from(self, state, innovations, n_live=None):
        """`(state, noises)`: the noises of the steps that `innovations` (`innovations`'
        shape) make from `state` (a `BrownianStep` with a leading axis), and the state after
        the first `n_live` of them (all by default; the rest are padding)."""

    def coarsened(self, m, dt) -> AbstractPath:
        """The same noise in steps `dt` of `m` of this path's steps (where `coarsens`)."""
        raise TypeError(f"{type(self).__name__} does not coarsen its steps.")


class BrownianPath(AbstractPath):
    r"""The Brownian motions of an ensemble, as the driver asks for them: the noise of step
    `n` of the sample whose key is `key` is `sampler(key)(n)`, a `BrownianStep`. Everything
    that decides it lives here: the step, the truncation of the increments, the Lévy areas
    and the coarsening of fine steps into the driver's.

    - `dt`: the driver's step, an array (or NumPy scalar) of the computation's floating dtype.
    - `bound`: the truncation bound of the fine increments (`truncation_bound`), same dtype.
    - `n_noises`: the number $s$ of Brownian motions (static).
    - `fine_steps`: $m$: each step joins the fine steps $nm, \dots, nm + m - 1$ of size
      $dt/m$ (`draw_joined`), so that a coarse run sees the very same Brownian motion as a
      run with step $dt/m$. A Python int is static; an integer array is traced (one
      program serves every step size of a convergence study).
    - `terms`: the series length of the Lévy-area sampler of a fine step
      (`levy_area_terms`), or `None`: no areas (static).

    An `equinox.Module`: `dt`, `bound` and a traced `fine_steps` are its leaves.
    """

    coarsens: ClassVar[bool] = True
    dt: Any
    bound: Any
    n_noises: int = eqx.field(static=True)
    terms: int | None = eqx.field(static=True)
    fixed_fine_steps: int | None = eqx.field(static=True)  # (fine_steps, a Python int)
    traced_fine_steps: Any  # (or fine_steps, an integer array)

    def __init__(self, dt, bound, n_noises, *, fine_steps=1, terms=None):
        self.dt = dt
        self.bound = bound
        self.n_noises = n_noises
        self.terms = terms
        fixed = isinstance(fine_steps, int)
        self.fixed_fine_steps = fine_steps if fixed else None
        self.traced_fine_steps = None if fixed else fine_steps

    @property
    def fine_steps(self) -> Any:
        """$m$, the fine steps per step: a Python int, or a traced integer array."""
        return self.fixed_fine_steps if self.traced_fine_steps is None else self.traced_fine_steps

    @classmethod
    def of(cls, dt, n_noises, dtype, *, truncate_k, levy_area=False):
        """The path of steps `dt` (a Python float) for `n_noises` noises in `dtype`: the
        increments truncated at `truncation_bound(dt, truncate_k)`, and with `levy_area`
        (and `n_noises > 1`) the Lévy areas."""
        # (NumPy scalars: `jit` takes them as arguments in whatever mesh context it runs)
        return cls(
            np.asarray(dt, dtype),
            np.asarray(truncation_bound(dt, truncate_k), dtype),
            n_noises,
            terms=levy_area_terms(dt, n_noises) if levy_area and n_noises > 1 else None,
        )

    @property
    def has_areas(self):
        """Whether the steps' noises carry their Lévy areas."""
        return self.terms is not None

    def coarsened(self, m, dt):
        """The same Brownian motions in steps `dt` of `m` of this path's steps (`m` and `dt`
        may be traced)."""
        return BrownianPath(dt, self.bound, self.n_noises, fine_steps=m, terms=self.terms)

    def without_areas(self):
        """The same increments, without the Lévy areas (they are drawn from a stream of
        their own, so the increments do not change)."""
        return BrownianPath(self.dt, self.bound, self.n_noises, fine_steps=self.fine_steps)

    def sampler(self, key):
        """The noise of the steps of the sample whose key is `key`: a function of the step
        index `n` (possibly traced) returning its `BrownianStep`. The fine step is computed
        here, once, not at every step."""
        fine_dt = self.dt / self.fine_steps
        return lambda n: self._draw(key, n, self.fine_steps, fine_dt)

    def draws(self, key):
        return IndexedDraws(self.sampler(key))

    def joined(self, key, n_steps):
        r"""The noise of the first `n_steps` steps (a Python int) of the sample whose key is
        `key`, joined into one step: for the increments, $W(n\,dt)$."""
        return self._draw(key, 0, n_steps * self.fine_steps, self.dt / self.fine_steps)

    def _draw(self, key, n, m, fine_dt):
        """Coarse step `n` made of `m` fine steps of size `fine_dt` (`draw_joined`)."""
        return draw_joined(key, n, m, fine_dt, self.bound, self.dt.dtype, self.n_noises, self.terms)

    def innovations(self, n_steps):
        """The increments themselves, `(n_steps, n_noises)` of variance `dt`: given as
        Gaussian numbers, so neither truncated nor with Lévy areas."""
        if np.isfinite(np.asarray(self.bound)) or self.has_areas:
            raise ValueError(
                "steps from given Gaussian increments are neither truncated nor with Lévy "
                "areas: use BrownianMotion(truncate_k=None, levy_area=False)."
            )
        return (n_steps, self.n_noises), float(self.dt)

    def initial_state(self, key, batch=()):
        return ()

    def steps_from(self, state, innovations, n_live=None):
        return state, BrownianStep(innovations, None)


def _check_dt(dt):
    """`dt` as a Python float: a positive finite number."""
    if isinstance(dt, (bool, np.bool_, str)) or np.ndim(dt) != 0:
        raise TypeError(f"dt must be a positive number, got {dt!r}.")
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise TypeError(f"dt must be a positive number, got {dt!r}.") from None
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be positive and finite, got {dt}.")
    return dt


def _check_counts(n_steps, n_samples):
    """`n_steps` a positive integer, `n_samples` `None` or one (the materialised paths')."""
    for name, n in (("n_steps", n_steps), ("n_samples", n_samples)):
        if name == "n_samples" and n is None:
            continue
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"{name} must be a positive integer, got {n!r}.")


def brownian_increments(
    key,
    n_steps,
    dt,
    *,
    n_samples=None,
    truncate_k: float | None = 4,
    dtype=None,
    n_noises=None,
    levy_area=False,
):
    """`BrownianMotion(truncate_k).increments`: the increments `simulate` uses, materialised
    (for `integrate`, plots and checks).

    **Arguments:**

    - `key`: a `jax.random.key`.
    - `n_steps`, `dt`: number and size of the steps.
    - `n_samples`: `None` for one path (the path of sample 0), else that many paths.
    - `truncate_k`: the truncation parameter $k$ of $A_h = \\sqrt{2k|\\ln h|}$, `None` for none.
    - `dtype`: a floating dtype, by default the default float (float64 with
      `jax_enable_x64`); use the system's dtype (`system.dtype`).
    - `n_noises`: `None` for one noise, or the number `s` of independent noises (the
      system's `n_noises`): then each step has `s` increments, a last axis of length `s`.

    - `levy_area`: also return the Lévy areas of every step (`draw_levy_area`, with
      `levy_area_terms(dt, n_noises)` series terms), shape `(..., n_steps, s, s)`,
      antisymmetric; needs `n_noises`. For `s = 1` they are zero.

    **Returns:** `(n_steps,)`, or `(n_samples, n_steps)`, with a last axis `(n_noises,)` when
    `n_noises` is given; with `levy_area=True` the pair `(dW, A)`. Row `i` equals what
    `simulate` draws for sample `i` with the same key (with `levy_area=True`: what it draws
    when it draws areas).
    """
    key = check_key(key)
    dt = _check_dt(dt)
    _check_counts(n_steps, n_samples)
    if n_noises is not None and (
        isinstance(n_noises, (bool, np.bool_))
        or not isinstance(n_noises, (int, np.integer))
        or n_noises < 1
    ):
        raise ValueError(f"n_noises must be None or a positive integer, got {n_noises!r}.")
    if not isinstance(levy_area, (bool, np.bool_)):
        raise TypeError(f"levy_area must be True or False, got {levy_area!r}.")
    if levy_area and n_noises is None:
        raise ValueError(
            "levy_area=True needs n_noises (the system's n_noises): the areas "
            "are those of pairs of noises."
        )
    check_truncation(dt, truncate_k)
    if dtype is None:
        dtype = jnp.result_type(float)
    else:
        try:
            ok = jnp.issubdtype(dtype, jnp.floating)
        except TypeError:
            ok = False
        if not ok:
            raise TypeError(f"dtype must be a floating dtype such as jnp.float64, got {dtype!r}.")
        if jnp.dtype(dtype).itemsize == 8 and not jax.config.read("jax_enable_x64"):
            raise ValueError("dtype=float64 needs jax.config.update('jax_enable_x64', True).")
    s = 1 if n_noises is None else int(n_noises)
    return _brownian_paths(
        key,
        BrownianPath.of(dt, s, dtype, truncate_k=truncate_k, levy_area=bool(levy_area)),
        n_samples=None if n_samples is None else int(n_samples),
        n_steps=int(n_steps),
        one_noise=n_noises is None,
        levy_area=bool(levy_area),
    )


@functools.partial(jax.jit, static_argnames=("n_samples", "n_steps", "one_noise", "levy_area"))
def _brownian_paths(key, path, *, n_samples, n_steps, one_noise, levy_area):
    """`brownian_increments` after its checks: one program per shape, not one for each of
    its operations (a new `dt` of the same shape compiles nothing)."""
    steps = jnp.arange(n_steps, dtype=jnp.uint32)
    s, dtype = path.n_noises, path.dt.dtype

    def one(k):
        out = jax.vmap(path.sampler(k))(steps)
        if levy_area:
            area = out.area if path.has_areas else jnp.zeros((n_steps, s, s), dtype)
            return out.dW, area
        return out.dW[:, 0] if one_noise else out.dW

    keys = sample_keys(key, 1 if n_samples is None else n_samples)
    out = jax.vmap(one)(keys)
    return jax.tree_util.tree_map(lambda x: x[0], out) if n_samples is None else out


class AbstractDriver(abc.ABC):
    """What draws an ensemble's noise (`simulate(..., driver=)`): its options, and
    `path(dt, n_noises, dtype, *, levy_area)`, its steps of size `dt` as the driver's loop
    asks for them (an `AbstractPath`); `increments(...)`, the same noise materialised for
    `integrate`. Code outside this module asks a driver, never which driver it is.

    - `levy_area`: the Lévy-area option (`"auto"`, `True`, `False`, or a dict per method in
      the studies); `False` for a driver without areas.
    - `carries_state`: whether a sample's next step depends on its earlier ones (a state the
      loop carries: Ornstein–Uhlenbeck traces).
    - `coarsens`: whether its paths at a step are the same noise as at a finer step joined
      (`AbstractPath.coarsens`; what the convergence studies need).
    """

    levy_area: Any = False
    carries_state: ClassVar[bool] = False
    coarsens: ClassVar[bool] = False

    @abc.abstractmethod
    def path(self, dt, n_noises, dtype, *, levy_area=False) -> AbstractPath:
        """The driver's steps of size `dt` (a Python float) for `n_noises` noises, with the
        Lévy areas when `levy_area` (the option resolved for the method, a bool)."""

    @abc.abstractmethod
    def increments(
        self, key, n_steps, dt, *, n_samples=None, n_noises=None, dtype=None, levy_area=False
    ):
        """The noise `simulate` draws with this driver, materialised: for `integrate`, plots
        and checks. Row `i` is what `simulate` draws for sample `i` with the same key.

        **Arguments:**

        - `key`: a `jax.random.key`; `n_steps`, `dt`: number and size of the steps.
        - `n_samples`: `None` for one path (sample 0's), else that many paths.
        - `n_noises`: the number `s` of noises (the system's `n_noises`): each step then has
          `s` increments, a last axis of length `s`; `None`: one noise, no such axis (an
          `OrnsteinUhlenbeck` of `s` correlation times: `s`).
        - `dtype`: a floating dtype, by default the default float (float64 with
          `jax_enable_x64`); use the system's dtype (`system.dtype`).
        - `levy_area`: also return the Lévy areas of every step, shape `(..., n_steps, s,
          s)`, antisymmetric (needs `n_noises`; a driver without areas refuses it).

        **Returns:** `(n_steps,)` or `(n_samples, n_steps)`, with a last axis `(s,)` for
        several noises; with `levy_area=True` the pair `(dW, A)`.
        """


def check_driver(driver):
    """`driver` checked: `None` stands for `BrownianMotion()`."""
    if driver is None:
        return BrownianMotion()
    if not isinstance(driver, AbstractDriver):
        raise TypeError(
            f"driver must be None, sj.BrownianMotion(...) or sj.OrnsteinUhlenbeck(...), got "
            f"{driver!r}."
        )
    return driver


class BrownianMotion(AbstractDriver):
    r"""The default driver of an ensemble: independent standard Brownian motions, one per
    noise, each step's increments drawn truncated, and with them, when asked for, the steps'
    Lévy areas. `simulate(system, y0, ..., driver=BrownianMotion(levy_area=True))`;
    `BrownianMotion().increments(key, n_steps, dt, ...)` materialises the same increments for
    `integrate`.

    **Arguments:**

    - `truncate_k`: the $k$ of the truncation
      $\Delta\hat W = \sqrt h\,\mathrm{clip}(\xi, \pm\sqrt{2k|\ln h|})$ (Milstein, Repin &
      Tretyakov 2002; default 4, the paper's), or `None` for none.
    - `levy_area`: whether the steps' Lévy areas are drawn: `"auto"` (default: for a method
      that `uses_levy_area` when the system has several noises), `True` (refused for a
      method that cannot use them) or `False`. Each step's areas are sampled given its
      increments, so the increments are the same with or without them; one noise has no
      areas. The convergence studies also take a dict `{method name: "auto"/True/False}`,
      to choose per method (the others and the reference on `"auto"`).
    """

    def __init__(
        self,
        *,
        truncate_k: float | None = 4,
        levy_area: str | bool | dict[str, str | bool] = "auto",
    ):
        check_truncation(0.5, truncate_k)
        if not (
            isinstance(levy_area, (bool, np.bool_, dict))
            or (isinstance(levy_area, str) and levy_area == "auto")
        ):
            raise TypeError(
                f"BrownianMotion: levy_area must be 'auto', True or False, got {levy_area!r}."
            )
        self.truncate_k = truncate_k
        self.levy_area = levy_area

    def __repr__(self):
        return f"BrownianMotion(truncate_k={self.truncate_k!r}, levy_area={self.levy_area!r})"

    def __eq__(self, other):
        return isinstance(other, BrownianMotion) and (self.truncate_k, self.levy_area) == (
            other.truncate_k,
            other.levy_area,
        )

    def __hash__(self):  # (a TypeError for a dict option)
        return hash((BrownianMotion, self.truncate_k, self.levy_area))

    coarsens: ClassVar[bool] = True

    def path(self, dt, n_noises, dtype, *, levy_area=False):
        check_truncation(dt, self.truncate_k)
        return BrownianPath.of(dt, n_noises, dtype, truncate_k=self.truncate_k, levy_area=levy_area)

    def increments(
        self, key, n_steps, dt, *, n_samples=None, n_noises=None, dtype=None, levy_area=False
    ):
        """The truncated increments `simulate` draws (and with `levy_area` their Lévy areas,
        by `levy_area_terms(dt, n_noises)` series terms; zero for one noise), materialised:
        see `AbstractDriver.increments`."""
        return brownian_increments(
            key,
            n_steps,
            dt,
            n_samples=n_samples,
            n_noises=n_noises,
            levy_area=levy_area,
            dtype=dtype,
            truncate_k=self.truncate_k,
        )


class OrnsteinUhlenbeck(AbstractDriver):
    r"""A smooth driver for `simulate`: unit-variance Ornstein–Uhlenbeck traces
    $d\eta_r = -\eta_r/T_r\,dt + \sqrt{2/T_r}\,dB_r$, started from their stationary law, each
    step's increment the integral $\int\eta_r\,dt$ over the step (a random ODE: no Lévy
    areas, no truncation).

    `simulate(system, y0, ..., driver=OrnsteinUhlenbeck(T))`; `increments` materialises the
    same increments for `integrate`.

    **Arguments:**

    - `correlation_time`: `(s,)` positive times $T_r$, one per noise of the system
      (`TransportNoiseFit.correlation_time`), or a scalar for every noise (else
      `ValueError`).
    """

    def __init__(self, correlation_time):
        kind = np.asarray(correlation_time).dtype.kind
        if kind not in "iuf" or isinstance(correlation_time, (bool, np.bool_)):
            raise TypeError(
                f"OrnsteinUhlenbeck: correlation_time must be numbers (seconds), a scalar or "
                f"(s,), got {correlation_time!r}."
            )
        T = np.asarray(correlation_time, dtype=float)
        if T.ndim > 1 or T.size == 0 or not np.all(np.isfinite(T) & (T > 0)):
            raise ValueError(
                f"OrnsteinUhlenbeck: correlation_time must be positive times, a scalar or "
                f"(s,), got {correlation_time!r}."
            )
        self.correlation_time = T

    def __repr__(self):
        return f"OrnsteinUhlenbeck(correlation_time={self.correlation_time.tolist()})"

    carries_state: ClassVar[bool] = True

    def increments(
        self, key, n_steps, dt, *, n_samples=None, n_noises=None, dtype=None, levy_area=False
    ):
        r"""The increments `simulate(..., driver=self)` draws, materialised: over each step
        the integral $\int\eta_r\,dt$ of the traces, started from their stationary law,
        each step's pair $(\eta_{n+1}, \int\eta)$ drawn exactly from its Gaussian law given
        $\eta_n$ (see `AbstractDriver.increments`; no Lévy areas)."""
        key = check_key(key)
        dt = _check_dt(dt)
        _check_counts(n_steps, n_samples)
        several = n_noises is not None or self.correlation_time.ndim == 1
        s = self.correlation_time.size if n_noises is None else n_noises
        dtype = jnp.result_type(float) if dtype is None else dtype
        # (the path's own checks: no areas, one correlation time per noise)
        path = self.path(dt, s, dtype, levy_area=levy_area)
        out = _ou_paths(key, path, n_steps=int(n_steps), n_samples=n_samples)
        return out if several else out[..., 0]

    def path(self, dt, n_noises, dtype, *, levy_area=False):
        if levy_area:
            raise ValueError("OrnsteinUhlenbeck: a smooth driver has no Lévy areas.")
        T = np.broadcast_to(self.correlation_time, np.shape(self.correlation_time) or (n_noises,))
        if T.shape != (n_noises,):
            raise ValueError(
                f"OrnsteinUhlenbeck: {T.shape[0]} correlation times for a system with "
                f"{n_noises} noises."
            )
        a = np.exp(-dt / T)
        # given eta_n: eta_{n+1} = a eta_n + e1, I = T (1 - a) eta_n + e2, (e1, e2) Gaussian
        v11 = 1.0 - a * a
        v22 = 2.0 * T * (dt - 2.0 * T * (1.0 - a) + 0.5 * T * (1.0 - a * a))
        v12 = T * (1.0 - a) ** 2
        l11 = np.sqrt(v11)
        l21 = v12 / l11
        l22 = np.sqrt(np.maximum(v22 - l21 * l21, 0.0))
        consts = tuple(np.asarray(x, dtype) for x in (a, T * (1.0 - a), l11, l21, l22))
        return OrnsteinUhlenbeckPath(np.asarray(dt, dtype), consts)


class OrnsteinUhlenbeckPath(AbstractPath):
    """The Ornstein–Uhlenbeck driver as the driver asks for it (`BrownianPath`'s sibling):
    `draws(key)` is a `StatefulDraws`, since a trace's next increment depends on its
    present value. Sample `key`'s path does not depend on how the steps are blocked: step
    `n` draws from `fold_in(key', n)`. A pytree: `dt` and the step's constants are leaves."""

    coarsens: ClassVar[bool] = False
    dt: Any
    consts: tuple

    @property
    def has_areas(self):
        return False

    @property
    def n_noises(self):
        return self.consts[0].shape[0]

    def without_areas(self):
        return self

    def draws(self, key):
        return StatefulDraws(self, key)

    def innovations(self, n_steps):
        """Two standard normal numbers per noise and step, `(n_steps, 2, n_noises)`: those
        of the traces' exact step (`ou_step`)."""
        return (n_steps, 2, self.n_noises), 1.0

    def initial_state(self, key, batch=()):
        """The traces drawn from their stationary law, standard normal: `(*batch, n_noises)`."""
        return jax.random.normal(key, (*batch, self.n_noises), self.dt.dtype)

    def steps_from(self, eta, innovations, n_live=None):
        """The traces' exact steps (`ou_step`), one per row of `innovations`; the traces
        stop after the first `n_live` steps."""
        if n_live is None:
            eta, dW = jax.lax.scan(lambda e, z: ou_step(self.consts, e, z), eta, innovations)
            return eta, BrownianStep(dW, None)

        def step(eta, zj):
            z, live = zj
            nxt, increment = ou_step(self.consts, eta, z)
            return jnp.where(live, nxt, eta), increment

        live = jnp.arange(innovations.shape[0]) < n_live
        eta, dW = jax.lax.scan(step, eta, (innovations, live))
        return eta, BrownianStep(dW, None)


class StatefulDraws(AbstractDraws):
    """The steps' noise of one sample of a driver with a state: `init`, the state before the
    first step, and `block(state, n0, length, n_live)`, the noises of steps `n0 ...
    n0 + length - 1` (a `BrownianStep` with a leading axis) and the state after the first
    `n_live` of them (the rest are the driver loop's padding)."""

    def __init__(self, path, key):
        k0, self.key = jax.random.split(key)
        self.path = path
        self.init = path.initial_state(k0)

    def block(self, eta, n0, length, n_live):
        shape, _ = self.path.innovations(length)
        z = jax.vmap(
            lambda j: jax.random.normal(jax.random.fold_in(self.key, n0 + j), shape[1:], eta.dtype)
        )(jnp.arange(length, dtype=jnp.asarray(n0).dtype))
        return self.path.steps_from(eta, z, n_live)


def ou_step(consts, eta, z):
    r"""One exact step of unit Ornstein–Uhlenbeck traces (`OrnsteinUhlenbeck.path`'s
    `consts`): from $\eta_n$ and standard normal numbers `z`, shape `(2, s)`, the traces
    $\eta_{n+1}$ and the step's increment $\int \eta\,dt$, jointly Gaussian given
    $\eta_n$."""
    a, b, l11, l21, l22 = consts
    return a * eta + l11 * z[0], b * eta + l21 * z[0] + l22 * z[1]


@functools.partial(jax.jit, static_argnames=("n_steps", "n_samples"))
def _ou_paths(key, path, *, n_steps, n_samples):
    def one(k):
        draws = path.draws(k)
        return draws.block(draws.init, jnp.uint32(0), n_steps, n_steps)[1].dW

    keys = sample_keys(key, 1 if n_samples is None else n_samples)
    out = jax.vmap(one)(keys)
    return out[0] if n_samples is None else out
