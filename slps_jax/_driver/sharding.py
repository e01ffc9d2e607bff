"""Sharding the sample axis of an ensemble over devices, with JAX's own SPMD partitioner.

The per-sample keys are laid out on the devices by a jitted constructor with
`out_shardings`, and `jit` partitions the `vmap`ped time loop along the sample axis: every
device integrates its own samples and nothing is communicated until the statistics at the
end. Sample `i` still uses `fold_in(key, i)`, so a sharded run gives the very same paths as
an unsharded one.

Meshes of explicit axes (`jax.make_mesh`'s default) and of automatic ones are both taken:
the loops run over an auto-axis copy of the caller's mesh, with the caller's context mesh
set aside, and the results come back on the caller's mesh.

The same code runs on JAX's multi-process runtime (`jax.distributed.initialize()`, a mesh
over `jax.devices()` of all processes): each process builds the keys of its own devices'
samples only, integrates them, and the arrays that come back are global `jax.Array`s of
which each process holds its own shards. What the driver itself needs whole (the failure
report) it gathers across processes.
"""

from __future__ import annotations

import contextlib
import functools

import jax
import jax.core
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

try:
    from jax.sharding import AxisType
except ImportError:  # JAX before mesh axis types: every axis is automatic
    AxisType = None

from .._brownian import sample_keys


def auto_sharding():
    """The samples split over every axis of the caller's context mesh (`jax.set_mesh`)
    when one is set, else over all local devices along one mesh axis `'samples'`; `None`
    with a single device."""
    context = getattr(jax.sharding, "get_mesh", lambda: None)()
    if isinstance(context, Mesh) and not context.empty and context.size > 1:
        return NamedSharding(context, PartitionSpec(tuple(context.axis_names)))
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
            raise ValueError(
                f"sharding must be None, 'auto' or a jax.sharding.Sharding, "
                f"got the string {sharding!r}."
            )
        sharding = auto_sharding()
        if sharding is None:
            return None
    if not isinstance(sharding, jax.sharding.Sharding):
        raise TypeError(
            f"sharding must be None, 'auto' or a jax.sharding.Sharding such as "
            f"NamedSharding(jax.make_mesh((jax.device_count(),), ('samples',)), "
            f"PartitionSpec('samples')), "
            f"got {type(sharding).__name__}."
        )
    try:
        shard = sharding.shard_shape((n_samples,))
    except Exception as err:  # noqa: BLE001 - JAX raises ValueError or others by version
        n_dev = len(sharding.device_set)
        lower, upper = (n_samples // n_dev) * n_dev, -(-n_samples // n_dev) * n_dev
        raise ValueError(
            f"{name}={n_samples} cannot be split evenly by this sharding over {n_dev} "
            f"devices: use a multiple of the number of shards, for example "
            f"{lower or upper} or {upper} ({err})."
        ) from None
    if len(shard) != 1:
        raise ValueError(
            f"sharding must describe a 1-D sample axis, got one for "
            f"{getattr(sharding, 'ndim', '?')} dimensions."
        )
    return sharding


@contextlib.contextmanager
def automatic(sharding, inputs):
    """The ensemble's sharding for JAX's automatic partitioner (`auto_axes`) and `inputs`
    (a pytree: the system, `y0`, the key) laid out over its mesh where they were on the
    caller's; the mesh is JAX's context mesh while the block runs, since a caller's own
    context mesh (`jax.set_mesh` of a mesh with explicit axes) would otherwise clash with
    the samples' sharding. `None` stays `None` and changes nothing."""
    auto = auto_axes(sharding)
    mesh = getattr(auto, "mesh", None)
    if not isinstance(mesh, Mesh) or not hasattr(jax, "set_mesh"):
        yield auto, inputs
        return
    with jax.set_mesh(mesh):
        yield auto, _relabel(inputs, mesh)


def as_given(tree, sharding):
    """`tree`'s arrays over `sharding`'s own mesh again where `automatic` ran them over an
    auto-axis copy of it, so that they combine with the caller's arrays (`_relabel` leaves
    arrays already on it alone)."""
    mesh = getattr(sharding, "mesh", None)
    return _relabel(tree, mesh) if isinstance(mesh, Mesh) else tree


def _relabel(tree, mesh):
    """`tree`'s arrays sharded over a mesh of the same devices and axis names as `mesh` but
    other axis types, as the same shards over `mesh`: relabelled, not copied (on every
    process its own shards). Other leaves are returned as they are."""

    def relabel(x):
        if not isinstance(x, jax.Array) or isinstance(x, jax.core.Tracer):
            return x
        s = x.sharding
        if (
            not isinstance(s, NamedSharding)
            or s.mesh == mesh
            or s.mesh.axis_names != mesh.axis_names
            or not np.array_equal(np.asarray(s.mesh.device_ids), np.asarray(mesh.device_ids))
        ):
            return x
        return jax.make_array_from_single_device_arrays(
            x.shape, NamedSharding(mesh, s.spec), [a.data for a in x.addressable_shards]
        )

    return jax.tree_util.tree_map(relabel, tree)


def auto_axes(sharding):
    """`sharding` over a mesh whose axes are all `AxisType.Auto`: the same devices, axis
    names and layout. `jax.make_mesh` gives explicit axes by default, with which a sharding
    is part of each array's type; the ensemble's loops are written for JAX's automatic
    partitioner, and a sharding over auto axes lays the samples out the same way."""
    mesh = getattr(sharding, "mesh", None)
    axis_types = getattr(mesh, "axis_types", None)
    if (
        AxisType is None
        or not isinstance(sharding, NamedSharding)
        or not isinstance(mesh, Mesh)
        or axis_types is None
        or all(t == AxisType.Auto for t in axis_types)
    ):
        return sharding
    auto = Mesh(mesh.devices, mesh.axis_names, axis_types=(AxisType.Auto,) * len(axis_types))
    return NamedSharding(auto, sharding.spec)


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
