"""Long runs on disk: `simulate`'s ensemble written to a run store as it goes, resumable."""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _brownian
from .._support.progress import progress_bar
from .._support.store import (
    RunStore,
    Store,
    check_store,
    digest,
    fingerprint,
    keep_system,
    open_run,
)
from .failures import Failures, report
from .integrate import _highest_precision, initial_carry, run_blocks
from .plan import plan_ensemble

# Casimirs tr W^k, k = 2 ... CASIMIR_ORDER, in the default diagnostics of a matrix state
CASIMIR_ORDER = 6
# su(N) energy and enstrophy spectra by default up to this N (`mat2shr`'s tables: N^3 numbers)
SPECTRA_MAX_N = 128


def simulate_to_store(
    system,
    y0,
    store: Store,
    *,
    t1,
    dt,
    n_samples,
    key,
    save_every,
    method="auto",
    failures: Failures = Failures(),
    driver: _brownian.BrownianMotion | _brownian.OrnsteinUhlenbeck | None = None,
):
    r"""`simulate`'s ensemble, written to a run store on disk as it goes: memory stays flat in
    the number of steps, and a run killed at any point goes on from its last complete
    record with `Store(..., resume=True)`, giving the same states, bit for bit, as a run
    never stopped.

    The run is cut into records of `store.record_snapshots` snapshots (`save_every` steps
    apart); each record is one compiled call (compiled once for the whole run) whose
    snapshots and diagnostics, and the loop's carry after it (the states, the step, each
    sample's failure code and retry count, the method's history, the driver's state), are
    appended to the store and committed together (`RunStore`: Zarr, a commit that a kill
    cannot leave half-written). Sample `i` draws its increments from `fold_in(key, i)` by
    absolute step, as `simulate` does, so the records compose into one run.

    **Arguments:** as `simulate`'s, and

    - `store`: a `Store`: the folder, whether to resume (the store's `t1` may then be
      extended), the diagnostics, whether to keep the states, the record size, the progress
      bar.
    - `save_every`: steps between snapshots (required: a run to disk saves snapshots).
    - `failures`: a `Failures`, as for `simulate`; at the end of the run a `RuntimeWarning`
      (or with `throw=True` a `RuntimeError`) says how many samples failed, why and
      where; the store's `"ok"` says which.

    **Returns:** the store opened for reading (`open_run(folder)`: `.read(name)`, `.times`,
    `.to_xarray()`); `"state"` is `(time, n_samples, *state)` and `"ok"` says which samples
    had not failed at each snapshot.
    """
    store = check_store("simulate_to_store", store)
    path, resume, save_states = store.folder, store.resume, store.save_states
    if save_every is None:
        raise ValueError("simulate_to_store needs save_every: the steps between snapshots.")
    p = plan_ensemble(
        "simulate_to_store",
        system,
        y0,
        t1=t1,
        dt=dt,
        n_samples=n_samples,
        key=key,
        method=method,
        save_every=save_every,
        failures=failures,
        sharding=None,
        driver=driver,
    )
    if p.method.flow_in_time is not None:
        raise ValueError(
            f"simulate_to_store: {type(p.method).__name__} evaluates its flow only where a state "
            "is saved; use simulate, or another method."
        )
    fns = _diagnostics(p.system, store.diagnostics)
    per_record = _record_size(p.n_steps // p.save_every, store.record_snapshots)
    keys = _brownian.sample_keys(p.key, p.n_samples)
    carry0 = _initial_carries(p.method, p.system, p.y0, p.path, keys)
    leaves0, treedef = jax.tree_util.tree_flatten(carry0)
    state_spec = {"state": ((p.n_samples, *p.y0.shape), p.y0.dtype)} if save_states else {}
    shapes = {k: v for name, fn in fns.items() for k, v in _fields(name, jax.eval_shape(fn, p.y0))}
    snapshots = {
        **state_spec,
        "ok": ((p.n_samples,), np.bool_),
        **{k: ((p.n_samples, *s.shape), s.dtype) for k, s in shapes.items()},
    }
    carry_spec = {f"carry_{i}": (leaf.shape, leaf.dtype) for i, leaf in enumerate(leaves0)}
    writer = RunStore(
        path,
        _fingerprint(p, keys, shapes, save_states),
        snapshots,
        carry_spec,
        mode="resume" if resume else "create",
        caller="simulate_to_store",
    )
    with writer:
        keep_system(path, p.system, "simulate_to_store")
        leaves, start = leaves0, 0
        if writer.checkpoint is not None:
            leaves = [
                jnp.asarray(writer.checkpoint.carry[f"carry_{i}"]) for i in range(len(leaves0))
            ]
            start = writer.checkpoint.step
            if start % (per_record * p.save_every) or start > p.n_steps:
                raise ValueError(
                    f"simulate_to_store: the store ends at step {start}, which is not a record "
                    f"boundary of this run (records of {per_record * p.save_every} steps, "
                    f"{p.n_steps} steps in all): resume with the run's Store(record_snapshots=...) and t1."
                )
        else:  # the initial state as the first snapshot
            writer.append(
                _snapshot(fns, save_states, carry0[0][0][None], (carry0[0][1] == 0)[None]),
                _carry_dict(leaves0),
                0,
                snapshot_steps=[0],
            )
        carry = jax.tree_util.tree_unflatten(treedef, leaves)
        steps = per_record * p.save_every
        bar = progress_bar(
            (p.n_steps - start) // steps, "simulate_to_store", unit="record", enabled=store.progress
        )
        for first in range(start, p.n_steps, steps):
            carry, ys = _record(
                p.method, p.system, p.dt, p.path, keys, carry, per_record, p.save_every, p.retry
            )
            ok = jnp.broadcast_to(carry[0][1] == 0, (per_record, p.n_samples))
            # (the failure codes are those at the record's end: a sample that failed within it
            # is frozen at its last good state, so its later snapshots repeat that state)
            writer.append(
                _snapshot(fns, save_states, jnp.swapaxes(ys, 0, 1), ok),
                _carry_dict(jax.tree_util.tree_leaves(carry)),
                first + steps,
                snapshot_steps=list(range(first + p.save_every, first + steps + 1, p.save_every)),
            )
            bar.update(1)
        bar.close()
    report("simulate_to_store", p.failures.throw, p.failures.retried, carry[0][2], carry[0][1])
    return open_run(path)


def _record_size(n_snapshots, at_most):
    """The largest divisor of `n_snapshots` not above `at_most` (one compiled record)."""
    return max(d for d in range(1, min(at_most, n_snapshots) + 1) if n_snapshots % d == 0)


def _initial_carries(method, system, y0, path, keys):
    return jax.vmap(
        lambda k: initial_carry(
            method, system, y0, path.draws(k), False, like=jax.random.key_data(k)
        )
    )(keys)


@functools.partial(jax.jit, static_argnames=("method", "n_blocks", "block_len", "retry"))
@_highest_precision
def _record(method, system, dt, path, keys, carry, n_blocks, block_len, retry):
    """One record of every sample: `n_blocks` snapshots `block_len` steps apart from `carry`."""

    def one(key, c):
        return run_blocks(method, system, dt, path.draws(key), c, n_blocks, block_len, False, retry)

    return jax.vmap(one)(keys, carry)


def _diagnostics(system, diagnostics) -> dict[str, Any]:
    """`name -> fn(state)` of the run's diagnostics (`simulate_to_store`)."""
    if diagnostics is None:
        return {}
    if isinstance(diagnostics, dict):
        for name, fn in diagnostics.items():
            if not isinstance(name, str) or not callable(fn):
                raise TypeError(
                    f"diagnostics must map names to functions of one state, got {name!r}: {fn!r}."
                )
            if name in ("state", "ok"):
                raise ValueError(f"diagnostics: {name!r} is taken by the store's own field.")
        return dict(diagnostics)
    if diagnostics != "auto":
        raise ValueError(f"diagnostics must be 'auto', None or a dict, got {diagnostics!r}.")
    from .. import zeitlin
    from .._systems import budgets
    from .._systems.euler_zeitlin import EulerZeitlin

    alg = system.algebra
    if len(alg.shape) == 1:
        return {"casimir": lambda y: jnp.sum(y**2)}
    out: dict[str, Any] = {
        "casimirs": functools.partial(_casimirs, order=min(CASIMIR_ORDER, alg.shape[-1]))
    }
    if isinstance(system, EulerZeitlin):
        out["energy"] = zeitlin.energy if system.euler_stream else system.energy
        out["enstrophy"] = zeitlin.enstrophy
        if system.N <= SPECTRA_MAX_N:
            out["energy_spectrum"] = zeitlin.energy_spectrum
            out["enstrophy_spectrum"] = zeitlin.enstrophy_spectrum
            out["(fluxes)"] = lambda w: dict(
                zip(("enstrophy_flux", "energy_flux"), budgets.flux(system, w))
            )
        if system.linear is not None or system.additive is not None:
            # (the forcing as a constant of N^2 numbers, not through the system's tables)
            forcing = None if system.linear is None else system.linear.forcing
            forcing = None if forcing is None else np.asarray(forcing)
            out["(budgets)"] = lambda w: budgets.budget(system, w, forcing)
    return out


def _fields(name, value):
    """A diagnostic's fields: `(name, value)`, or the items of a diagnostic that gives several
    fields at once as a dict (the budgets, the fluxes: computed once per state)."""
    return value.items() if isinstance(value, dict) else [(name, value)]


def _casimirs(w, order):
    """$\\operatorname{tr}W^k$, $k = 2 \\dots$ `order`: the real part for even $k$, the
    imaginary part for odd $k$ (real for real matrices)."""
    out, power = [], w
    for k in range(2, order + 1):
        power = power @ w
        t = jnp.trace(power)
        out.append(jnp.real(t) if k % 2 == 0 or not jnp.iscomplexobj(t) else jnp.imag(t))
    return jnp.stack(out)


def _snapshot(fns, save_states, ys, ok):
    """A record's fields, `(snapshots, n_samples, ...)`, as NumPy arrays."""
    out = {"state": ys} if save_states else {}
    out["ok"] = ok
    out.update(_evaluate(tuple(fns.items()), ys))
    return {k: np.asarray(v) for k, v in out.items()}


@functools.partial(jax.jit, static_argnames="fns")
@_highest_precision
def _evaluate(fns, ys):
    return {k: v for name, fn in fns for k, v in _fields(name, jax.vmap(jax.vmap(fn))(ys))}


def _carry_dict(leaves):
    return {f"carry_{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)}


def _fingerprint(p, keys, fns, save_states):
    """What makes a run this run (`fingerprint`): with the initial state, the samples, the
    noise, the retry, the diagnostics."""
    return fingerprint(
        system=p.system,
        method=p.method,
        dt=p.dt,
        save_every=p.save_every,
        dtype=p.y0.dtype,
        key_data=jax.random.key_data(keys),
        y0=digest(p.y0),
        n_samples=int(p.n_samples),
        noise=_describe(p.path),
        retry_substeps=p.retry,
        diagnostics=sorted(fns),
        save_states=bool(save_states),
    )


def _describe(path):
    """The noise's description: its kind and its numbers (a hash), stable across processes."""
    leaves, treedef = jax.tree_util.tree_flatten(path)
    return f"{type(path).__name__} {treedef} {digest(*leaves)}"
