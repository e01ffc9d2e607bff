"""A system (or a noise family, or any equinox Module of the library) saved to a file and
loaded back bit for bit: its arrays as NumPy arrays (their bytes, dtypes and shapes exactly),
its static fields as they are, in a pickle with a header that says what it is.

Loading a pickle runs the code it names: load only files you trust (your own runs). A
system whose static fields cannot be pickled (a `LiePoissonSystem` built on a lambda or a
closure) is refused when saved, naming the field; define its functions at a module's top
level instead.
"""

from __future__ import annotations

import io
import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np

_FORMAT = "slps-jax saved object"
_VERSION = 1


def dumps(obj):
    """The bytes of `obj` saved (`save`)."""
    leaves, treedef = jax.tree_util.tree_flatten(obj)
    arrays = [np.asarray(x) if isinstance(x, jax.Array | np.ndarray) else x for x in leaves]
    payload = {
        "format": _FORMAT,
        "version": _VERSION,
        "type": f"{type(obj).__module__}.{type(obj).__qualname__}",
        "object": jax.tree_util.tree_unflatten(treedef, arrays),
    }
    try:
        return pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, AttributeError, TypeError) as e:
        raise TypeError(
            f"cannot save this {type(obj).__name__}: a part of it cannot be pickled ({e}). "
            "Functions in it (a Hamiltonian, a noise) must be defined at a module's top "
            "level, not as lambdas or closures."
        ) from e


def loads(data, what="the data"):
    """The object of `dumps`'s bytes, its arrays as JAX arrays of the saved dtypes."""
    try:
        payload = pickle.load(io.BytesIO(data))
    except Exception as e:
        raise ValueError(f"{what}: not a saved slps-jax object ({type(e).__name__}: {e}).") from e
    if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
        raise ValueError(f"{what}: not a saved slps-jax object.")
    if payload.get("version") != _VERSION:
        raise ValueError(
            f"{what}: saved by format version {payload.get('version')}; this library reads "
            f"{_VERSION}."
        )
    obj = payload["object"]
    leaves, treedef = jax.tree_util.tree_flatten(obj)
    wide = [x for x in leaves if isinstance(x, np.ndarray) and x.dtype.itemsize == 8]
    if wide and not jax.config.read("jax_enable_x64"):
        raise ValueError(
            f"{what}: a {payload['type']} in double precision ({wide[0].dtype}); enable it "
            'before loading, jax.config.update("jax_enable_x64", True), or it would not come '
            "back bit for bit."
        )
    arrays = [jnp.asarray(x) if isinstance(x, np.ndarray) else x for x in leaves]
    return jax.tree_util.tree_unflatten(treedef, arrays)


def save(path, obj):
    """Save a system or a noise family to a file, written whole or not at all (a temporary
    file renamed), to be loaded back bit for bit by `load`.

    **Arguments:**

    - `path`: the file to write (replaced if it exists).
    - `obj`: a system (`EulerZeitlin`, `RigidBody`, ...), a noise family (a fitted one
      too), or any equinox Module of the library; functions in it must be defined at a
      module's top level (a lambda is refused with a `TypeError`).

    **Returns:** `path`.
    """
    data = dumps(obj)
    path = os.fspath(path)
    tmp = f"{path}.partial"
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def load(path):
    """Load what `save` saved, bit for bit. Load only files you trust: a pickle runs the code
    it names.

    **Arguments:**

    - `path`: a file written by `save` (another file is a `ValueError`).

    **Returns:** the saved object, its arrays JAX arrays of the saved dtypes (double
    precision needs `jax_enable_x64` enabled first, or a `ValueError` says so).
    """
    path = os.fspath(path)
    with open(path, "rb") as fh:
        return loads(fh.read(), what=path)
