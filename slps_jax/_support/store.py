r"""Long runs on disk: a store that a time loop appends snapshots to, record by record, with
memory flat, that survives the writer being killed at any moment, and that a user opens with
Zarr or xarray.

A store is a Zarr (v3) directory:

- one array per snapshot field, `(time, *shape)`, with dimension names (`time`, `sample`
  where the field's first axis has `n_samples` entries, then `<field>_<axis>`), plus `time`
  ($= \text{step}\cdot dt$) and `step`;
- `_carry/<name>`, `(2, *shape)`: the loop's carry (what it needs to continue bit for bit:
  state, step counter, random or driver state, a solver's warm start), opaque to the store,
  in two slots used in turn, so that the committed carry is never overwritten;
- `_commit`, a group whose attributes say which snapshots and which carry slot are
  complete. They are written last (zarr writes a temporary file and renames it), after the
  data (`durable=True`: after an `fsync` of every file written), so that a record written
  half-way is never read as complete. Zarr itself writes every chunk and metadata file by a
  rename, so a kill cannot leave a committed chunk half-written either; every chunk carries
  a CRC-32C, so a chunk damaged later (a disk, a copy) is an error when read, never other
  numbers.

`RunStore` writes (`mode="create"`, `"resume"` or `"overwrite"`), `open_run` reads. Why Zarr
rather than HDF5: `benchmarks/store_format.py` (the numbers are in `benchmarks/README.md`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shutil
import warnings
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from . import saving
from .checks import check_option, user_stacklevel

_FORMAT = "slps-jax run store"
_VERSION = 1
_RESERVED = frozenset({"time", "step", "_carry", "_commit"})
_CHUNK_BYTES = 1 << 20  # (about 1 MiB a chunk; a snapshot larger than that is split by sample)
_MAX_TIME_CHUNK = 1024  # (a small field's partial last chunk is rewritten on every append)
_MODES = ("create", "resume", "overwrite")


RECORD_SNAPSHOTS = 16  # snapshots per record of `simulate_to_store`, at most (default)


@dataclass(frozen=True)
class Store:
    r"""Where and how a run goes to disk as it runs: the `store=` of `simulate_to_store` and
    `particle_filter_to_store`.

    **Arguments:**

    - `folder`: the store's directory (a Zarr store, `RunStore`); it must not exist unless
      `resume=True`.
    - `resume`: `False` (default): a new store (an existing one is an error); `True`: go on
      from the store's last complete record (a record half-written when the run was killed
      is dropped with a warning), or start one if there is none. A store of another run
      (system, step, key, method, initial state, ...) is refused, naming what differs.
    - `progress`: a progress bar with the time left, where someone watches (default `True`).
    - `diagnostics`: computed on each snapshot, per sample: `"auto"` (default: for a matrix
      state the Casimirs $\operatorname{tr}W^k$, $k = 2 \dots 6$ (their real part for even
      $k$, imaginary for odd); for `EulerZeitlin` also `energy`, `enstrophy`, up to
      N = 128 `energy_spectrum`, `enstrophy_spectrum`, `energy_flux` and `enstrophy_flux`
      by degree ($N^3$-number tables above; the last axis named `degree`), and with linear
      terms or an additive forcing the budgets' rates `energy_injection`,
      `energy_dissipation`, `energy_damping` and the same for the enstrophy
      (`EulerZeitlin.budget`); for so(3)* the Casimir $|y|^2$), `None`, or a dict
      `name -> fn(state)` of JAX functions of one state. `simulate_to_store` only.
    - `save_states`: also store the states themselves (default `True`; `False` keeps the
      diagnostics only). `simulate_to_store` only.
    - `record_snapshots`: snapshots per record at most (default 16): the largest divisor of
      the number of snapshots not above it; each record is one compiled call, appended and
      committed together. `simulate_to_store` only.
    """

    folder: str | os.PathLike
    resume: bool = False
    progress: bool = True
    diagnostics: Any = "auto"
    save_states: bool = True
    record_snapshots: int = RECORD_SNAPSHOTS

    def __post_init__(self):
        if not isinstance(self.folder, (str, os.PathLike)):
            raise TypeError(f"Store: folder must be a path, got {self.folder!r}.")
        for name in ("resume", "progress", "save_states"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise TypeError(
                    f"Store: {name} must be True or False, got {getattr(self, name)!r}."
                )
        n = self.record_snapshots
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"Store: record_snapshots must be a positive integer, got {n!r}.")

    def only_folder_options(self, caller):
        """Refuse the options of `simulate_to_store` that `caller` has no use for."""
        other = [
            f.name
            for f in dataclasses.fields(self)
            if f.name not in ("folder", "resume", "progress") and getattr(self, f.name) != f.default
        ]
        if other:
            raise ValueError(
                f"{caller}: the Store's {', '.join(other)} are simulate_to_store's; "
                f"{caller} writes its own records (leave them at their defaults)."
            )


def check_store(caller, store) -> Store:
    return check_option(caller, "store", store, Store)


def _zarr() -> Any:  # (zarr's JSON types do not help here: its objects are Any)
    try:
        import zarr
    except ImportError as e:
        raise ImportError('The run store needs zarr (>= 3): pip install "slps-jax[store]"') from e
    if int(zarr.__version__.split(".")[0]) < 3:
        raise ImportError(
            f'The run store needs zarr >= 3, found {zarr.__version__}: pip install "slps-jax[store]"'
        )
    return zarr


def digest_bytes(*arrays):
    """SHA-256 of the arrays' bytes in C order, in turn: stable across processes and
    machines of one byte order. The fingerprints of stored runs (`RunStore`) are made of
    these."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a)).tobytes())
    return h.digest()


def digest(*arrays):
    """`digest_bytes` as a hexadecimal string (a field of a store's fingerprint)."""
    return digest_bytes(*arrays).hex()


def fingerprint(*, system, method, dt, save_every, dtype, key_data, **more):
    """What makes a stored run this run (`RunStore` compares it on `resume`, naming what
    differs): the system (its description and its numbers), the method, the step, the steps
    between records' snapshots, the dtype, the key's data, and the caller's `more`."""
    return {
        "dt": float(dt),
        "save_every": int(save_every),
        "system": repr(system),
        "system_numbers": digest(*jax.tree_util.tree_leaves(system)),
        "dtype": str(dtype),
        "method": repr(method),
        "key": digest(key_data),
        **more,
    }


_SAVED = "_saved/system"  # (the run's system, `keep_system`: a subgroup, unseen by xarray)


def keep_system(path, system, caller):
    """Save the run's `system` in the store at `path` (the bytes of `saving.dumps` as an
    array of the subgroup `_saved`, with their SHA-256), once; where it cannot be pickled,
    warn that `open_run(path).system` will not give it back."""
    group = _zarr().open_group(os.fspath(path), mode="r+", zarr_format=3)
    if _saved_system_bytes(group) is not None:
        return
    try:
        data = np.frombuffer(saving.dumps(system), np.uint8)
    except TypeError as e:
        warnings.warn(
            f"{caller}: the system is not kept in the store, so open_run(path).system will "
            f"not give it back: {e}",
            RuntimeWarning,
            stacklevel=user_stacklevel(),
        )
        return
    array = group.require_group("_saved").create_array(
        "system",
        shape=data.shape,
        dtype=np.uint8,
        chunks=(max(1, min(data.size, 1 << 24)),),
        overwrite=True,
    )
    array[:] = data
    array.attrs["sha256"] = digest(data)


def _saved_system_bytes(group):
    """The bytes of the system kept in the store's `group`, or `None` (none, or incomplete:
    their SHA-256 differs)."""
    try:
        array = group[_SAVED]
        data = np.asarray(array[:], np.uint8)
        expected = array.attrs.get("sha256")
    except (KeyError, FileNotFoundError):
        return None
    return data.tobytes() if expected == digest(data) else None


def _hook(point):
    """Called at the named points of an append ("data", "carry", "commit", "committed");
    a no-op. The crash tests replace it to kill the writer there."""


@dataclass(frozen=True)
class Checkpoint:
    """The last complete record of a store: `carry` (name → NumPy array, as appended),
    `step` (the loop's step count given with it) and `n_snapshots` (snapshots stored)."""

    carry: dict[str, np.ndarray]
    step: int
    n_snapshots: int


# --- specifications and checks


def _normalise_metadata(metadata):
    if not isinstance(metadata, dict) or not all(isinstance(k, str) for k in metadata):
        raise TypeError(f"metadata must be a dict with string keys, got {type(metadata).__name__}.")
    for key in ("dt", "save_every"):
        if key not in metadata:
            raise ValueError(f"metadata needs {key!r} (the snapshots' times are step * dt).")
    dt = metadata["dt"]
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0:
        raise ValueError(f"metadata['dt'] must be a positive number, got {dt!r}.")
    save_every = metadata["save_every"]
    if isinstance(save_every, bool) or not isinstance(save_every, int) or save_every < 1:
        raise ValueError(f"metadata['save_every'] must be an integer >= 1, got {save_every!r}.")
    try:  # (as it reads back: tuples become lists)
        return json.loads(json.dumps(metadata, allow_nan=False))
    except (TypeError, ValueError) as e:
        raise TypeError(f"metadata must be JSON-able (numbers, strings, lists, dicts): {e}") from e


def _normalise_spec(spec, what, reserved=frozenset()):
    """`{name: {"shape": [...], "dtype": str}}` of `{name: (shape, dtype)}`."""
    if not isinstance(spec, dict):
        raise TypeError(f"{what} must be a dict name -> (shape, dtype), got {type(spec).__name__}.")
    out = {}
    for name, entry in spec.items():
        if not isinstance(name, str) or not name.isidentifier() or name in reserved:
            raise ValueError(
                f"{what}: {name!r} is not a usable name (an identifier, not one of "
                f"{sorted(reserved)})."
            )
        try:
            shape, dtype = entry
            shape = tuple(int(n) for n in shape)
            dtype = np.dtype(dtype)
        except (TypeError, ValueError) as e:
            raise TypeError(f"{what}[{name!r}] must be (shape, dtype), got {entry!r}.") from e
        if any(n < 0 for n in shape) or dtype.kind not in "biufc":
            raise ValueError(
                f"{what}[{name!r}]: a shape of non-negative sizes and a numeric dtype, got "
                f"{shape} {dtype} (a JAX random key: store jax.random.key_data(key))."
            )
        out[name] = {"shape": list(shape), "dtype": dtype.str}
    return out


def _as_array(x, name, spec, leading):
    """`x` as a NumPy array of the spec's dtype and shape (`leading`: axes in front, `None`
    for any length), refusing a cast across kinds (complex to real, float to int)."""
    try:
        a = np.asarray(x)
    except TypeError as e:  # (a typed JAX key: its data are the numbers to keep)
        raise TypeError(
            f"{name}: not an array of numbers ({e}); for a JAX random key "
            "store jax.random.key_data(key)."
        ) from e
    dtype, shape = np.dtype(spec["dtype"]), tuple(spec["shape"])
    if (
        a.shape[len(leading) :] != shape
        or len(a.shape) != len(leading) + len(shape)
        or any(n is not None and a.shape[i] != n for i, n in enumerate(leading))
    ):
        want = ", ".join(["k" if n is None else str(n) for n in leading] + [str(n) for n in shape])
        raise ValueError(f"{name}: shape ({want}) expected, got {a.shape}.")
    if not np.can_cast(a.dtype, dtype, casting="same_kind"):
        raise TypeError(
            f"{name}: dtype {dtype} expected, got {a.dtype} (not cast: it would lose data)."
        )
    return np.ascontiguousarray(a, dtype=dtype)


def _chunks(shape, itemsize):
    """Chunks of `(time, *shape)`: whole snapshots up to about 1 MiB (at most 1024 in time);
    a larger snapshot split along its leading axes."""
    chunks = []
    for i in range(len(shape) + 1):
        rest = itemsize * math.prod(shape[i:])
        if rest >= _CHUNK_BYTES:
            chunks.append(1)
        else:
            n = max(1, _CHUNK_BYTES // max(rest, 1))
            chunks.append(min(n, _MAX_TIME_CHUNK) if i == 0 else min(n, shape[i - 1]))
            chunks.extend(shape[i:])
            break
    return tuple(chunks[: len(shape) + 1])


def _dimension_names(name, shape, n_samples):
    """`time`, then `sample` (where the field has one per sample), then: the last axis of a
    field by degree (a name ending in `_spectrum` or `_flux`) `degree`; a state's axes (the
    fields `state` and `mean`) `row` and `column` for a matrix, `component` for a vector;
    other axes `{name}_{i}`."""
    dims = ["time"]
    by_degree = name.endswith(("_spectrum", "_flux"))
    per_sample = bool(shape) and n_samples is not None and shape[0] == n_samples
    rest = len(shape) - per_sample
    state_axes = {2: ["row", "column"], 1: ["component"]}.get(rest) if name in _STATES else None
    for i in range(len(shape)):
        if i == 0 and per_sample:
            dims.append("sample")
        elif by_degree and i == len(shape) - 1:
            dims.append("degree")
        elif state_axes is not None:
            dims.append(state_axes[i - per_sample])
        else:
            dims.append(f"{name}_{i}")
    return dims


_STATES = ("state", "mean")  # (the fields that hold states, whose axes are named by kind)


def _differences(expected, found, what):
    keys = sorted(set(expected) | set(found))
    return [
        f"{what}[{k!r}]: {found.get(k, '(absent)')!r} in the store, {expected.get(k, '(absent)')!r} given"
        for k in keys
        if expected.get(k, ...) != found.get(k, ...)
    ]


def _fsync(path):
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(path):
    """`fsync` every file and folder under `path` (a chunk's folder: its files and their names)."""
    if not os.path.exists(path):
        return
    for root, _, files in os.walk(path):
        for f in files:
            _fsync(os.path.join(root, f))
        _fsync(root)


def _write_commit(group, path, commit, durable):
    """`commit` as the attributes of the group `_commit`: zarr writes its `zarr.json` into
    a temporary file and renames it, so a reader sees the old commit or the new one whole."""
    _hook("commit")
    group["_commit"].attrs.put(commit)
    if durable:
        _fsync(os.path.join(path, "_commit", "zarr.json"))
        _fsync(os.path.join(path, "_commit"))


def _read_commit(group, path, restart="open it with mode='overwrite' to start again"):
    try:
        commit = group["_commit"].attrs.asdict()
        for key in ("records", "snapshots", "step", "slot"):
            int(commit[key])
        return commit
    except KeyError:
        raise ValueError(
            f"{path}: no commit record: its creation was interrupted ({restart})."
        ) from None
    except (ValueError, TypeError) as e:
        raise ValueError(
            f"{path}: its commit record is unreadable ({e}); the store cannot be trusted."
        ) from e


def _open_group(path, mode):
    zarr = _zarr()
    try:
        group = zarr.open_group(path, mode=mode, zarr_format=3)
        attrs = dict(group.attrs)
    except Exception as e:  # (zarr's errors for a missing or damaged group vary by version)
        raise ValueError(f"{path}: not a readable Zarr v3 store ({type(e).__name__}: {e}).") from e
    if attrs.get("format") != _FORMAT:
        raise ValueError(f"{path}: a Zarr group, but not an slps-jax run store.")
    if attrs.get("version") != _VERSION:
        raise ValueError(
            f"{path}: run store version {attrs.get('version')}, this library reads {_VERSION}."
        )
    return group, attrs


def _check_chunks(path, name, array, time_chunks):
    """Every chunk file of `time_chunks` is there (zarr reads a missing chunk as its fill
    value, zeros: a lost file would pass for data)."""
    per = math.prod(math.ceil(n / c) for n, c in zip(array.shape[1:], array.chunks[1:]))
    for t in time_chunks:
        chunk = os.path.join(path, name, "c", str(t))
        found = int(os.path.isfile(chunk))  # (one axis: the chunk is a file, else a folder)
        for _, _, files in os.walk(chunk):
            found += sum(not f.endswith(".partial") for f in files)
        if found < per:
            raise FileNotFoundError(
                f"{name}: {per - found} of the chunk files of rows {t} are missing"
            )


def _read_record(group, path, commit, names):
    """The carry of `commit`, after reading the rows of its last record (so checked against
    their CRCs, and their chunk files counted): an exception when one is damaged or missing."""
    first = int(commit.get("record_start", 0))
    n = int(commit["snapshots"])
    for name in [*names, "time", "step"]:
        a = group[name]
        a[first:n]
        if n > first:
            _check_chunks(path, name, a, range(first // a.chunks[0], (n - 1) // a.chunks[0] + 1))
    slot = int(commit["slot"])
    carry = {}
    for name in group.attrs["carry"]:
        a = group["_carry"][name]
        carry[name] = np.asarray(a[slot])
        _check_chunks(path, os.path.join("_carry", name), a, [slot])
    return carry


# --- the writer


class RunStore:
    """A run's store on disk, written record by record (`append`), resumable after a kill.

    **Arguments:**

    - `path`: the store's folder (Zarr v3).
    - `metadata`: a JSON-able dict describing the run: it must hold `dt` and `save_every`
      (times are step $\\cdot$ `dt`); add what makes a run this run (the system, method, key,
      `n_samples`, dtype, a `fingerprint` computed by the caller). On resume every key must
      be equal, or a `ValueError` names the keys that differ.
    - `snapshots`: `{name: (shape, dtype)}`, each snapshot's fields, e.g.
      `{"state": ((n_samples, N, N), complex), "energy": ((n_samples,), float)}`; stored as
      arrays `(time, *shape)`.
    - `carry`: `{name: (shape, dtype)}`, what the loop needs to continue bit for bit; opaque
      to the store (a JAX random key: its `jax.random.key_data`).
    - `mode`: `"create"` (default: a new store; an existing `path` is an error),
      `"resume"` (continue the store at `path`, which must have been made with equal
      `metadata`, `snapshots` and `carry`; created when absent), `"overwrite"` (delete
      what is at `path`, if a run store, and create).
    - `durable`: `fsync` each record before its commit (default), so that a record survives
      a power cut as it survives a kill; `False` survives a kill of the process only.
    - `caller`: the entry point that opens the store for the user (`"simulate_to_store"`),
      whose `Store(..., resume=True)` its messages then name instead of the `mode`s
      (default `None`).

    After opening, `checkpoint` is the last complete record (`Checkpoint`: `carry`, `step`,
    `n_snapshots`), `None` when the store holds none. A record left incomplete by a kill is
    dropped on resume, with a warning; so is a last record found damaged (a chunk that fails
    its CRC or is missing), the one before it taking its place (its carry is kept in the
    other slot). The store is locked while open (one writer).
    """

    def __init__(
        self, path, metadata, snapshots, carry, *, mode="create", durable=True, caller=None
    ):
        if mode not in _MODES:
            raise ValueError(f"mode must be one of {_MODES}, got {mode!r}.")
        zarr = _zarr()
        self.path = os.fspath(path)
        self.durable = bool(durable)
        self.metadata = _normalise_metadata(metadata)
        self._snapshots = _normalise_spec(snapshots, "snapshots", _RESERVED)
        self._carry = _normalise_spec(carry, "carry")
        if not self._snapshots:
            raise ValueError("snapshots: at least one field.")
        # what a user can do, in the words of the function they called
        self._restart = (
            "mode='overwrite' starts again"
            if caller is None
            else f"delete {self.path} to start again"
        )
        exists = os.path.exists(self.path)
        if exists and mode == "create":
            again = (
                "mode='resume' to continue it, mode='overwrite' to replace it"
                if caller is None
                else f"{caller}(..., Store(..., resume=True)) continues the same run; delete "
                "it to start again"
            )
            raise FileExistsError(f"{self.path} exists: {again}.")
        if exists and mode == "overwrite":
            if os.path.isdir(self.path) and not os.listdir(self.path):
                pass
            else:
                _open_group(self.path, "r")  # (only a run store is deleted, never other data)
                shutil.rmtree(self.path)
            exists = False
        self._lock = None
        if exists and mode == "resume" and os.path.isdir(self.path) and not os.listdir(self.path):
            exists = False  # (an empty folder: the store is created in it)
        if exists:
            _open_group(self.path, "r")  # (a clear error for a folder that is not a store)
            self._lock_store()
            self._group, self._commit, self.checkpoint = self._resume()
        else:
            self._group = self._create(zarr)
            self._lock_store()
            self._commit = {"records": 0, "snapshots": 0, "step": -1, "slot": 1}
            _write_commit(self._group, self.path, self._commit, self.durable)
            self.checkpoint = None

    # -- opening

    def _lock_store(self):
        try:
            import fcntl
        except ImportError:  # (no advisory locks on this platform: one writer is up to the user)
            return
        self._lock = open(os.path.join(self.path, "zarr.json"), "rb")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.close()
            self._lock = None
            raise RuntimeError(f"{self.path} is open for writing by another process.") from None

    def _create(self, zarr):
        from zarr.codecs import Crc32cCodec

        n_samples = self.metadata.get("n_samples")
        group = zarr.open_group(self.path, mode="w-", zarr_format=3)
        group.attrs.update(
            {
                "format": _FORMAT,
                "version": _VERSION,
                "metadata": self.metadata,
                "snapshots": self._snapshots,
                "carry": self._carry,
            }
        )
        crc = [Crc32cCodec()]
        fields = {**self._snapshots, "time": {"shape": [], "dtype": "<f8"}}
        fields["step"] = {"shape": [], "dtype": "<i8"}
        for name, spec in fields.items():
            shape, dtype = tuple(spec["shape"]), np.dtype(spec["dtype"])
            group.create_array(
                name,
                shape=(0, *shape),
                dtype=dtype,
                chunks=_chunks(shape, dtype.itemsize),
                compressors=crc,
                fill_value=0,
                dimension_names=_dimension_names(name, shape, n_samples),
            )
        group.create_group("_commit")
        carry = group.create_group("_carry")
        for name, spec in self._carry.items():
            shape, dtype = tuple(spec["shape"]), np.dtype(spec["dtype"])
            carry.create_array(
                name,
                shape=(2, *shape),
                dtype=dtype,
                chunks=(1, *shape),
                compressors=crc,
                fill_value=0,
            )
        return group

    def _resume(self):
        group, attrs = _open_group(self.path, "r+")
        problems = (
            _differences(self.metadata, attrs.get("metadata", {}), "metadata")
            + _differences(self._snapshots, attrs.get("snapshots", {}), "snapshots")
            + _differences(self._carry, attrs.get("carry", {}), "carry")
        )
        if problems:
            raise ValueError(
                f"{self.path} was made by another run; not resumed:\n  " + "\n  ".join(problems)
            )
        commit = _read_commit(group, self.path, self._restart)
        # leftovers of a kill: zarr's temporary files and ours
        for root, _, files in os.walk(self.path):
            for f in files:
                if f.endswith(".partial"):
                    os.remove(os.path.join(root, f))
        carry = None
        if commit["records"]:
            try:
                carry = _read_record(group, self.path, commit, self._snapshots)
            except Exception as e:
                previous = commit.get("previous")
                if previous is None:
                    raise ValueError(
                        f"{self.path}: its only record is damaged ({type(e).__name__}: {e}); "
                        f"nothing to resume from ({self._restart})."
                    ) from e
                try:
                    carry = _read_record(group, self.path, previous, self._snapshots)
                except Exception as e2:
                    raise ValueError(
                        f"{self.path}: its last two records are damaged ({e}; {e2}); not resumed."
                    ) from e2
                warnings.warn(
                    f"{self.path}: the last record (snapshots {previous['snapshots']} ... "
                    f"{commit['snapshots'] - 1}, step {commit['step']}) is damaged "
                    f"({type(e).__name__}: {e}); dropped, resuming from step {previous['step']}.",
                    stacklevel=3,
                )
                commit = {**previous, "previous": None}
        n = int(commit["snapshots"])
        lengths = {name: group[name].shape[0] for name in [*self._snapshots, "time", "step"]}
        if any(k < n for k in lengths.values()):
            raise ValueError(f"{self.path}: {n} snapshots committed but the arrays hold {lengths}.")
        if any(k > n for k in lengths.values()):
            warnings.warn(
                f"{self.path}: dropped {max(lengths.values()) - n} snapshots of a record that "
                f"was not complete (the writer stopped mid-record); resuming from step "
                f"{commit['step']}.",
                stacklevel=3,
            )
            for name in lengths:
                a = group[name]
                a.resize((n, *a.shape[1:]))
        _write_commit(group, self.path, commit, self.durable)
        checkpoint = None
        if commit["records"]:
            checkpoint = Checkpoint(carry=carry or {}, step=int(commit["step"]), n_snapshots=n)
        return group, commit, checkpoint

    # -- writing

    def append(self, snapshots, carry, step, *, snapshot_steps=None):
        """Write one record: `snapshots` (`{name: array}`, each with a leading axis of the
        record's `k` snapshots), the loop's `carry` after it (`{name: array}`) and `step`,
        the loop's step count there. Complete on return; a kill before then leaves the store
        at the previous record.

        `snapshot_steps`: the steps of the `k` snapshots (increasing, after the store's
        last); default: `step` for the last and `save_every` apart."""
        if self._group is None:
            raise ValueError(f"{self.path}: the store is closed.")
        if set(snapshots) != set(self._snapshots):
            raise ValueError(
                f"snapshots: fields {sorted(self._snapshots)} expected, got {sorted(snapshots)}."
            )
        if set(carry) != set(self._carry):
            raise ValueError(f"carry: fields {sorted(self._carry)} expected, got {sorted(carry)}.")
        first = next(iter(self._snapshots))
        k = np.shape(snapshots[first])[0] if np.ndim(snapshots[first]) else 0
        if k < 1:
            raise ValueError(f"snapshots[{first!r}]: a leading axis of at least one snapshot.")
        data = {
            name: _as_array(snapshots[name], f"snapshots[{name!r}]", spec, (k,))
            for name, spec in self._snapshots.items()
        }
        state = {
            name: _as_array(carry[name], f"carry[{name!r}]", spec, ())
            for name, spec in self._carry.items()
        }
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)):
            raise TypeError(f"step must be an integer, got {step!r}.")
        step = int(step)
        if step <= self._commit["step"]:
            raise ValueError(
                f"step {step}: the store's last record is at step {self._commit['step']}."
            )
        if snapshot_steps is None:
            steps = step - self.metadata["save_every"] * np.arange(k - 1, -1, -1, dtype=np.int64)
        else:
            steps = np.asarray(snapshot_steps, dtype=np.int64)
            if steps.shape != (k,):
                raise ValueError(f"snapshot_steps: {k} steps expected, got shape {steps.shape}.")
        last = self._group["step"][-1] if self._commit["snapshots"] else -1
        if np.any(np.diff(steps) <= 0) or steps[0] <= last:
            raise ValueError(
                f"snapshot_steps must increase, after the store's last ({last}): {steps}."
            )
        data["step"] = steps
        data["time"] = steps * float(self.metadata["dt"])

        # (zarr leaves out a chunk equal to the fill value, zero, unless told: a record of zeros
        # would then read as missing chunks)
        with _zarr().config.set({"array.write_empty_chunks": True}):
            self._write(data, state, step, k)

    def _write(self, data, state, step, k):
        assert self._group is not None
        n = int(self._commit["snapshots"])
        slot = 1 - int(self._commit["slot"])
        written = []
        for i, (name, x) in enumerate(data.items()):
            a = self._group[name]
            a.resize((n + k, *a.shape[1:]))
            a[n : n + k] = x
            ct = a.chunks[0]
            written += [
                os.path.join(self.path, name, "c", str(c))
                for c in range(n // ct, (n + k - 1) // ct + 1)
            ]
            written.append(os.path.join(self.path, name))
            if i == 0:
                _hook("data")
        _hook("carry")
        for name, x in state.items():
            self._group["_carry"][name][slot] = x
            written.append(os.path.join(self.path, "_carry", name, "c", str(slot)))
        if self.durable:
            for p in written:
                _fsync_tree(p)
        previous = {key: self._commit[key] for key in ("snapshots", "step", "slot")}
        previous["record_start"] = self._commit.get("record_start", 0)
        previous["records"] = self._commit["records"]
        commit = {
            "records": self._commit["records"] + 1,
            "snapshots": n + k,
            "step": step,
            "slot": slot,
            "record_start": n,
            "previous": previous if self._commit["records"] else None,
        }
        _write_commit(self._group, self.path, commit, self.durable)
        _hook("committed")
        self._commit = commit
        self.checkpoint = Checkpoint(carry=state, step=step, n_snapshots=n + k)

    def close(self):
        """Release the store (and its lock); every appended record is already on disk."""
        self._group = None
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        c = getattr(self, "_commit", None) or {"records": 0, "snapshots": 0, "step": -1}
        counts = f"records={c['records']}, snapshots={c['snapshots']}, step={c['step']}"
        return f"RunStore({self.path!r}, {counts})"


# --- the reader


class StoredRun:
    """A run store opened for reading (`open_run`): its committed snapshots only (a record
    being written, or left incomplete by a kill, is not seen).

    - `metadata`: the dict given at creation; `fields`: the snapshot fields' names;
    - `steps`, `times` (NumPy, one per snapshot), `len(run)` the number of snapshots;
    - `read(name, index=slice(None))`: snapshots `index` of field `name` (NumPy; read from
      disk, only those asked for);
    - `checkpoint`: the last complete record's carry and step (`Checkpoint`), or `None`;
    - `to_xarray()`: an `xarray.Dataset`, lazily read, dimensions `(time, sample, ...)`,
      coordinate `time`, variable `step`, attributes the metadata.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        if not os.path.isdir(self.path):
            raise FileNotFoundError(f"{self.path}: no run store there.")
        self._group, attrs = _open_group(self.path, "r")
        self._commit = _read_commit(self._group, self.path)
        self.metadata = attrs["metadata"]
        self.fields = tuple(attrs["snapshots"])
        self._n = int(self._commit["snapshots"])
        self.steps = np.asarray(self._group["step"][: self._n])
        self.times = np.asarray(self._group["time"][: self._n])

    def __len__(self):
        return self._n

    @property
    def system(self):
        """The system that made the run, as it was, bit for bit (as `sj.load` gives it;
        `simulate_to_store` and `particle_filter_to_store` keep it in the store); a
        `ValueError` where the store holds none."""
        data = _saved_system_bytes(self._group)
        if data is None:
            raise ValueError(
                f"{self.path} holds no saved system (a store written by RunStore itself, or "
                "by a run whose system could not be pickled)."
            )
        return saving.loads(data, what=f"{self.path}'s system")

    def read(self, name, index=slice(None)):
        """Snapshots `index` (an int, a slice, or an array of indices into the committed
        snapshots) of the field `name`, as a NumPy array."""
        if name not in self.fields:
            raise KeyError(f"{name!r}: the store's fields are {list(self.fields)}.")
        rows = np.arange(self._n)[index]
        a = self._group[name]
        if np.ndim(rows) == 0:
            return np.asarray(a[int(rows)])
        if rows.size and np.all(np.diff(rows) == 1):
            return np.asarray(a[int(rows[0]) : int(rows[-1]) + 1])
        return np.asarray(a.oindex[rows]) if rows.size else np.empty((0, *a.shape[1:]), a.dtype)

    @property
    def checkpoint(self):
        if not self._commit["records"]:
            return None
        carry = {
            name: np.asarray(self._group["_carry"][name][int(self._commit["slot"])])
            for name in self._group.attrs["carry"]
        }
        return Checkpoint(carry=carry, step=int(self._commit["step"]), n_snapshots=self._n)

    def to_xarray(self):
        """The committed snapshots as an `xarray.Dataset` (read lazily: only what is
        indexed and loaded comes off the disk): dimensions `time` (a coordinate, in
        seconds), `sample`, `degree` (a coordinate, 0, 1, ..., on spectra and fluxes), a
        state's `row` and `column` (or `component`); the run's metadata as attributes.
        Needs xarray (`pip install "slps-jax[store]"`)."""
        try:
            import xarray as xr  # pyright: ignore[reportMissingImports]
        except ImportError as e:
            raise ImportError(
                'StoredRun.to_xarray needs xarray: pip install "slps-jax[store]" (or xarray)'
            ) from e
        ds = xr.open_zarr(self.path, consolidated=False, zarr_format=3, chunks=None)
        ds = ds.isel(time=slice(0, self._n))
        if "degree" in ds.dims:
            ds = ds.assign_coords(degree=np.arange(ds.sizes["degree"]))
            ds["degree"].attrs["long_name"] = "degree l of the spherical harmonics"
        ds["time"].attrs["units"] = "s"
        ds.attrs = dict(self.metadata)
        return ds

    def __repr__(self):
        return f"StoredRun({self.path!r}, snapshots={self._n}, fields={list(self.fields)})"


def open_run(path):
    """Open the run store at `path` for reading. xarray also opens the folder itself,
    `xarray.open_zarr(path, consolidated=False)`, but then sees, until the next resume,
    the rows of a record that a kill left incomplete: `StoredRun.to_xarray` cuts them.

    **Arguments:**

    - `path`: the store's folder, as given to `RunStore` (or `simulate_to_store`); no folder
      there is a `FileNotFoundError`.

    **Returns:** a `StoredRun` (snapshots, times, the last checkpoint, `to_xarray()`).
    """
    return StoredRun(path)
