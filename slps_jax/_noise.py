"""Brownian increments: one key per sample, one draw per step, optional truncation.

Sample `i` of an ensemble uses the key `fold_in(key, i)`, and its step `n` the increment drawn
from `fold_in(fold_in(key, i), n)`. So a sample's path depends on nothing but the user's key,
its index and the step: not on the batch size, the chunking, or the number of steps.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np


def check_key(key, name="key"):
    """A typed PRNG key (`jax.random.key`), or a legacy raw `uint32[2]` key
    (`jax.random.PRNGKey`), as a typed key. Both give the same samples for the same seed.
    Anything else (a plain integer, a batch of keys, a float array) is a `TypeError` or
    `ValueError` that says what to pass."""
    if isinstance(key, (bool, np.bool_)):
        raise TypeError(f"{name} must be a JAX PRNG key, got {key!r}: pass jax.random.key(seed).")
    if isinstance(key, (int, np.integer)):
        raise TypeError(
            f"{name} must be a JAX PRNG key, got the integer {key!r}: "
            f"pass jax.random.key({key!r})."
        )
    if not hasattr(key, "dtype") or not hasattr(key, "shape"):
        raise TypeError(f"{name} must be a JAX PRNG key (jax.random.key(seed)), got {type(key)}.")
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.shape != ():
            raise ValueError(f"{name} must be a single key, got a key array of shape {key.shape}: "
                             f"pass one key, for example {name}[0].")
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
            isinstance(truncate_k, (int, float, np.integer, np.floating)) and truncate_k > 0
            and math.isfinite(truncate_k)):
        raise ValueError(f"truncate_k must be a positive number or None, got {truncate_k!r}.")
    if dt >= 1.0:
        raise ValueError(
            f"truncate_k={truncate_k} needs dt < 1: the bound sqrt(2k|ln dt|) collapses at "
            f"dt = 1 (got dt={dt}); pass truncate_k=None."
        )


def sample_keys(key, n_samples, offset=0):
    """Keys of samples `offset, ..., offset + n_samples - 1` (`offset` may be traced: one
    compilation serves every chunk of a streamed ensemble)."""
    idx = jnp.asarray(offset, jnp.uint32) + jnp.arange(n_samples, dtype=jnp.uint32)
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(idx)


def increment(sample_key, n, dt, bound, dtype, n_noises=1):
    """The truncated increments of step `n`, shape `(n_noises,)`:
    $\\Delta\\hat W_{n,r} = \\sqrt h\\, \\mathrm{clip}(\\xi_{n,r}, \\pm A_h)$, componentwise, from
    `fold_in(sample_key, n)` (the first component does not depend on `n_noises`)."""
    xi = jax.random.normal(jax.random.fold_in(sample_key, n), (n_noises,), dtype)
    return jnp.sqrt(dt).astype(dtype) * jnp.clip(xi, -bound, bound)


def brownian_increments(key, n_steps, dt, *, n_samples=None, truncate_k=4, dtype=None,
                        n_noises=None):
    """The increments `simulate` uses, materialised: for `integrate`, plots and checks.

    **Arguments:**

    - `key`: a `jax.random.key`.
    - `n_steps`, `dt`: number and size of the steps.
    - `n_samples`: `None` for one path (the path of sample 0), else that many paths.
    - `truncate_k`: the truncation parameter $k$ of $A_h = \\sqrt{2k|\\ln h|}$, `None` for none.
    - `dtype`: a floating dtype, by default the default float (float64 with
      `jax_enable_x64`); use the model's dtype (`model.dtype`).
    - `n_noises`: `None` for one noise, or the number `s` of independent noises (the
      system's `n_noises`): then each step has `s` increments, a last axis of length `s`.

    **Returns:** `(n_steps,)`, or `(n_samples, n_steps)`, with a last axis `(n_noises,)` when
    `n_noises` is given; row `i` equals what `simulate` draws for sample `i` with the same
    key.
    """
    key = check_key(key)
    if isinstance(dt, (bool, np.bool_, str)) or np.ndim(dt) != 0:
        raise TypeError(f"dt must be a positive number, got {dt!r}.")
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise TypeError(f"dt must be a positive number, got {dt!r}.") from None
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be positive and finite, got {dt}.")
    for name, n in (("n_steps", n_steps), ("n_samples", n_samples)):
        if name == "n_samples" and n is None:
            continue
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"{name} must be a positive integer, got {n!r}.")
    if n_noises is not None and (isinstance(n_noises, (bool, np.bool_))
                                 or not isinstance(n_noises, (int, np.integer)) or n_noises < 1):
        raise ValueError(f"n_noises must be None or a positive integer, got {n_noises!r}.")
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
        if jnp.dtype(dtype).itemsize == 8 and not jax.config.jax_enable_x64:
            raise ValueError("dtype=float64 needs jax.config.update('jax_enable_x64', True).")
    bound = jnp.asarray(truncation_bound(dt, truncate_k), dtype)
    dt = jnp.asarray(dt, dtype)
    steps = jnp.arange(int(n_steps), dtype=jnp.uint32)

    s = 1 if n_noises is None else n_noises

    def one(k):
        out = jax.vmap(lambda n: increment(k, n, dt, bound, dtype, s))(steps)
        return out[:, 0] if n_noises is None else out

    keys = sample_keys(key, 1 if n_samples is None else int(n_samples))
    out = jax.vmap(one)(keys)
    return out[0] if n_samples is None else out
