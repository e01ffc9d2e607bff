"""Sharding the sample axis of an ensemble over devices, with JAX's own SPMD partitioner.

The per-sample keys are laid out on the devices by a jitted constructor with
`out_shardings`, and `jit` partitions the `vmap`ped time loop along the sample axis: every
device integrates its own samples and nothing is communicated until the statistics at the
end. Sample `i` still uses `fold_in(key, i)`, so a sharded run gives the very same paths as
an unsharded one.

The same code runs on JAX's multi-process runtime (`jax.distributed.initialize()`, a mesh
over `jax.devices()` of all processes): each process builds the keys of its own devices'
samples only, integrates them, and the arrays that come back are global `jax.Array`s of
which each process holds its own shards. What the driver itself needs whole (the failure
report) it gathers across processes.
"""

from __future__ import annotations

import functools

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._noise import sample_keys


def auto_sharding():
    """All local devices along one mesh axis `'samples'`, or `None` with a single device."""
    devices = jax.local_devices()
    if len(devices) < 2:
        return None
    return NamedSharding(Mesh(devices, ("samples",)), PartitionSpec("samples"))


def check_sharding(sharding, n_samples, name="n_samples"):
    """`None`, `"auto"` or a `jax.sharding.Sharding` of a 1-D sample axis of length
    `n_samples`: the sharding to use (`None`: none), or a clear `TypeError`/`ValueError`."""
    if sharding is None:
        return None
    if isinstance(sharding, str):
        if sharding != "auto":
            raise ValueError(f"sharding must be None, 'auto' or a jax.sharding.Sharding, "
                             f"got the string {sharding!r}.")
        sharding = auto_sharding()
        if sharding is None:
            return None
    if not isinstance(sharding, jax.sharding.Sharding):
        raise TypeError(
            f"sharding must be None, 'auto' or a jax.sharding.Sharding such as "
            f"NamedSharding(Mesh(jax.devices(), ('samples',)), PartitionSpec('samples')), "
            f"got {type(sharding).__name__}.")
    try:
        shard = sharding.shard_shape((n_samples,))
    except Exception as err:  # noqa: BLE001 - JAX raises ValueError or others by version
        n_dev = len(sharding.device_set)
        lower, upper = (n_samples // n_dev) * n_dev, -(-n_samples // n_dev) * n_dev
        raise ValueError(
            f"{name}={n_samples} cannot be split evenly by this sharding over {n_dev} "
            f"devices: use a multiple of the number of shards, for example "
            f"{lower or upper} or {upper} ({err}).") from None
    if len(shard) != 1:
        raise ValueError(f"sharding must describe a 1-D sample axis, got one for "
                         f"{sharding.ndim if hasattr(sharding, 'ndim') else '?'} dimensions.")
    return sharding


def sharded_keys(key, n_samples, sharding):
    """The keys of samples `0, ..., n_samples - 1` laid out by `sharding`. Each process
    computes only the keys of its own devices (no data moves between processes)."""
    return _keys_constructor(n_samples, sharding)(key)


@functools.cache
def _keys_constructor(n_samples, sharding):
    return jax.jit(functools.partial(sample_keys, n_samples=n_samples), out_shardings=sharding)


def gather(x):
    """`x` as a NumPy array on every process: itself when this process holds all of it, its
    shards from all processes otherwise (a collective: every process must call it)."""
    if getattr(x, "is_fully_addressable", True):
        return np.asarray(x)
    return np.asarray(multihost_utils.process_allgather(x, tiled=True))
