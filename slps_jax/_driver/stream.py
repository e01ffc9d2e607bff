"""Streaming ensembles: ensembles larger than memory, run in chunks, kept as running moments.

Chunk `c` integrates samples `offset, ..., offset + chunk_size - 1` with the keys
`fold_in(key, i)`, exactly the samples of one big `simulate`, and folds their moments into
the running ones with Chan, Golub & LeVeque's pairwise update (and Pébay's for the third and
fourth moments). One compiled function serves every chunk: the offset is traced, and the last
chunk is padded to the same shape and its padding masked out.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _brownian
from .._methods.base import AbstractMethod
from .._support.checks import check_count, check_option
from .._support.progress import advance, progress_bar
from .failures import Failures, message, warn_or_raise
from .integrate import ensemble
from .plan import plan_ensemble
from .sharding import automatic

STATISTICS = ("mean", "var", "cov", "skewness", "kurtosis")


@dataclasses.dataclass(frozen=True)
class Chunks:
    """An ensemble run as a sequence of chunks of samples (`ensemble_statistics`): only one
    chunk's paths are in memory at a time.

    **Arguments:**

    - `size`: samples per chunk (at most `n_samples` are run). One compilation serves every
      chunk (the last one is padded and masked).
    - `sharding`: as for `simulate`, applied to each chunk (`size` must be a multiple of the
      number of shards).
    - `progress`: show a progress bar across chunks (default `True`; tqdm: on a terminal or
      in a notebook, nothing in a log file or a pipe).
    """

    size: int
    sharding: Any = None
    progress: bool = True

    def __post_init__(self):
        object.__setattr__(self, "size", check_count("Chunks: size", self.size))
        if not isinstance(self.progress, (bool, np.bool_)):
            raise TypeError(f"Chunks: progress must be True or False, got {self.progress!r}.")


@dataclasses.dataclass(frozen=True)
class Statistics:
    """Which moments `ensemble_statistics` keeps, and of what.

    **Arguments:**

    - `names`: among `"mean"` (always computed), `"var"`, `"cov"`, `"skewness"`,
      `"kurtosis"` (default `("mean", "var")`; one name alone is a tuple of one).
    - `observable`: `None` (default) for the state itself, or a function of one sample's
      saved states `(n_saved, *state_shape)` giving an array `(n_saved, ...)` (for example
      `lambda ys: system.hamiltonian(ys)` under `vmap`) whose moments are taken instead. It
      must be hashable (a module-level function or a lambda kept alive by the caller) to be
      compiled once.
    """

    names: tuple = ("mean", "var")
    observable: Callable[..., Any] | None = None

    def __post_init__(self):
        names = (self.names,) if isinstance(self.names, str) else tuple(self.names)
        unknown = [n for n in names if n not in STATISTICS]
        if unknown:
            raise ValueError(f"Statistics: names must be among {STATISTICS}, got {unknown}.")
        object.__setattr__(self, "names", names)
        if self.observable is not None and not callable(self.observable):
            raise TypeError(
                f"Statistics: observable must be None or a function, got {self.observable!r}."
            )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EnsembleStatistics:
    """What `ensemble_statistics` returns: moments over the successful samples.

    - `ts`: the saved times, shape `(n_saved,)`.
    - `n`: the number of samples the moments are over (successful ones); `n_failed`: the
      number of samples that failed (frozen paths, left out of the moments).
    - `mean`: shape `(n_saved, *obs)`, where `obs` is the observable's shape (`(3,)` for the
      state itself).
    - `var`: the sample variance (divisor `n - 1`), same shape; `None` if not asked for.
    - `cov`: the sample covariance over the observable's last axis, `(n_saved, *obs, d)`.
    - `skewness`: $m_3 / m_2^{3/2}$; `kurtosis`: $m_4 / m_2^2$ (3 for a Gaussian), with the
      central moments $m_k$ of divisor `n`.
    - `n_chunks`: the number of chunks run.
    """

    ts: np.ndarray
    n: int
    n_failed: int
    mean: np.ndarray
    var: np.ndarray | None
    cov: np.ndarray | None
    skewness: np.ndarray | None
    kurtosis: np.ndarray | None
    n_chunks: int


def _chunk_moments(x, w, want_cov):
    """Count, mean and central sums `M2, M3, M4` (and the co-moment) of the rows of `x`
    with weight `w` (0 or 1)."""
    wb = w.reshape((-1,) + (1,) * (x.ndim - 1)).astype(x.dtype)
    n = jnp.sum(w).astype(x.dtype)
    # Shifted by the first row: less cancellation, and identical rows (t = 0) give exact
    # zeros, so a degenerate skewness is NaN rather than round-off over round-off.
    shifted = x - x[0]
    mean_shifted = jnp.sum(wb * shifted, axis=0) / jnp.maximum(n, 1)
    mean = x[0] + mean_shifted
    d = jnp.where(wb > 0, shifted - mean_shifted, 0.0)
    d2 = d * d
    m = (n, mean, jnp.sum(d2, axis=0), jnp.sum(d2 * d, axis=0), jnp.sum(d2 * d2, axis=0))
    cov = jnp.einsum("s...i,s...j->...ij", d, d) if want_cov else ()
    return m + (cov,)


def _merge(a, b):
    """Chan et al. (1979) and Pébay (2008): moments of the union of two disjoint sets."""
    na, ma, m2a, m3a, m4a, ca = a
    nb, mb, m2b, m3b, m4b, cb = b
    n = na + nb
    safe = jnp.maximum(n, 1)
    delta = mb - ma
    mean = ma + delta * nb / safe
    m2 = m2a + m2b + delta**2 * na * nb / safe
    m3 = (
        m3a
        + m3b
        + delta**3 * na * nb * (na - nb) / safe**2
        + 3.0 * delta * (na * m2b - nb * m2a) / safe
    )
    m4 = (
        m4a
        + m4b
        + delta**4 * na * nb * (na * na - na * nb + nb * nb) / safe**3
        + 6.0 * delta**2 * (na * na * m2b + nb * nb * m2a) / safe**2
        + 4.0 * delta * (na * m3b - nb * m3a) / safe
    )
    cov = (
        ca + cb + delta[..., :, None] * delta[..., None, :] * na * nb / safe
        if not isinstance(ca, tuple)
        else ()
    )
    return n, mean, m2, m3, m4, cov


@functools.partial(
    jax.jit,
    static_argnames=(
        "method",
        "n_blocks",
        "block_len",
        "chunk_size",
        "observable",
        "want_cov",
        "retry",
        "sharding",
    ),
)
def _chunk(
    state,
    offset,
    n_samples,
    method,
    system,
    y0,
    key,
    path,
    n_blocks,
    block_len,
    chunk_size,
    observable,
    want_cov,
    retry,
    sharding,
):
    idx = offset + jnp.arange(chunk_size, dtype=jnp.uint32)
    keys = _brownian.sample_keys(key, chunk_size, offset)
    if sharding is not None:
        keys = jax.lax.with_sharding_constraint(keys, sharding)
    ys, fail_step, _, _, _ = ensemble(
        method, system, y0, keys, path, n_blocks, block_len, False, retry=retry
    )
    ys = jnp.concatenate([jnp.broadcast_to(y0, (chunk_size, 1, *y0.shape)), ys], axis=1)
    obs = _observe(observable, ys)
    valid = idx < n_samples
    ok = valid & (fail_step < 0)
    n_failed = state[0] + jnp.sum(valid & ~ok, dtype=state[0].dtype)
    return n_failed, _merge(state[1], _chunk_moments(obs, ok, want_cov))


def ensemble_statistics(
    system,
    y0,
    *,
    t1,
    dt,
    n_samples,
    key,
    chunks: Chunks,
    method: AbstractMethod | str = "auto",
    save_every=None,
    statistics: Statistics = Statistics(),
    failures: Failures = Failures(),
    driver: _brownian.BrownianMotion | _brownian.OrnsteinUhlenbeck | None = None,
):
    r"""Moments of an ensemble of $dy = f(y)(dt + c \circ dW)$, run in chunks of samples.

    The same samples as `simulate(..., n_samples=n_samples, key=key)` (sample `i` draws from
    `fold_in(key, i)`), but only `chunks.size` paths are held at a time, and only running
    moments are kept: memory does not grow with `n_samples`. The moments are merged with the
    pairwise update of Chan, Golub & LeVeque (1979) (third and fourth moments: Pébay 2008),
    so the results do not depend on the chunk size beyond round-off.

    **Arguments:**

    - `system`, `y0`, `t1`, `dt`, `key`, `method`, `driver`: as for `simulate`.
    - `n_samples`: the total number of samples.
    - `chunks`: a `Chunks`: samples per chunk, their sharding, a progress bar.
    - `save_every`: `None` (statistics of the final state, and of `y0` at `t = 0`) or `k`
      (statistics at steps `0, k, 2k, ..., n`).
    - `statistics`: a `Statistics`: which moments (default mean and variance), of the state
      or of an observable.
    - `failures`: a `Failures`, as for `simulate`: samples that fail (even split into
      substeps) are left out of the moments and counted in `n_failed`, with a
      `RuntimeWarning` (`throw=True`: `RuntimeError` instead).

    **Returns:** an `EnsembleStatistics` (NumPy arrays). Failed samples are never used as
    data.
    """
    check_option("ensemble_statistics", "chunks", chunks, Chunks)
    check_option("ensemble_statistics", "statistics", statistics, Statistics)
    p = plan_ensemble(
        "ensemble_statistics",
        system,
        y0,
        t1=t1,
        dt=dt,
        n_samples=n_samples,
        key=key,
        method=method,
        save_every=save_every,
        failures=failures,
        sharding=chunks.sharding,
        driver=driver,
        chunk_size=chunks.size,
    )
    method, y0, dt, n_steps, k = p.method, p.y0, p.dt, p.n_steps, p.save_every
    n_samples = p.n_samples
    chunk_size = p.chunk_size
    observable = statistics.observable
    want_cov = "cov" in statistics.names
    progress = chunks.progress

    n_blocks = n_steps // k
    ts = np.arange(0, n_steps + 1, k, dtype=np.float64) * dt
    if save_every is None:
        ts = np.array([0.0, n_steps * dt])
    # The zero state: its shapes from an abstract evaluation of one chunk's moments.
    observed = jax.eval_shape(
        lambda: _observe(observable, jnp.zeros((chunk_size, n_blocks + 1, *y0.shape), y0.dtype))
    )
    if any(
        jnp.issubdtype(x.dtype, jnp.complexfloating) for x in jax.tree_util.tree_leaves(observed)
    ):
        raise TypeError(
            "ensemble_statistics takes moments of real numbers; "
            + (
                "the states of " + system.algebra.name + " are complex: pass an observable "
                "giving real numbers, such as the coefficients "
                "statistics=Statistics(observable=lambda ys: slps_jax.zeitlin.mat2shr(ys)), an "
                "energy or the Casimirs."
                if observable is None
                else "the observable returns complex numbers."
            )
        )
    shapes = jax.eval_shape(
        lambda: _chunk_moments(
            jnp.zeros(observed.shape, observed.dtype), jnp.ones(chunk_size, bool), want_cov
        )
    )
    n_chunks = -(-n_samples // chunk_size)
    bar = progress_bar(n_chunks, "ensemble_statistics", unit="chunk") if progress else None
    with automatic(p.sharding, (system, y0, p.key)) as (sharding, (system, y0, key)):
        zero = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        state = (jnp.zeros((), jnp.int32), zero)
        args = (
            method,
            system,
            y0,
            key,
            p.path,
            n_blocks,
            k,
            chunk_size,
            observable,
            want_cov,
            p.retry,
            sharding,
        )
        for c in range(n_chunks):
            state = _chunk(
                state,
                jnp.asarray(c * chunk_size, jnp.uint32),
                jnp.asarray(n_samples, jnp.uint32),
                *args,
            )
            # One chunk in flight at a time: asynchronous dispatch would otherwise let the
            # next chunk's buffers be allocated before this one's are freed.
            jax.block_until_ready(state)
            if bar is not None:
                advance(bar, f"{min((c + 1) * chunk_size, n_samples)}/{n_samples} samples")
    if bar is not None:
        bar.close()
    n_failed = int(state[0])
    n, mean, m2, m3, m4, cov = jax.tree_util.tree_map(np.asarray, state[1])
    n = int(n)
    if n_failed:
        warn_or_raise(
            p.failures,
            message(
                "ensemble_statistics",
                n_failed,
                n_samples,
                "They are left out of the moments (n_failed).",
                retried=p.failures.retried,
            ),
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        var = m2 / (n - 1) if n > 1 else np.full_like(m2, np.nan)
        mom2 = m2 / n
        return EnsembleStatistics(
            ts=ts,
            n=n,
            n_failed=n_failed,
            mean=mean,
            var=var if "var" in statistics.names else None,
            cov=(cov / (n - 1) if n > 1 else np.full_like(cov, np.nan)) if want_cov else None,
            skewness=(m3 / n) / mom2**1.5 if "skewness" in statistics.names else None,
            kurtosis=(m4 / n) / mom2**2 if "kurtosis" in statistics.names else None,
            n_chunks=n_chunks,
        )


def _observe(observable, ys):
    return ys if observable is None else jax.vmap(observable)(ys)
