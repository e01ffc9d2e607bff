r"""`particle_filter`: the filter of `assimilation.py` with the library's integrators as the
forecast, in memory or written to a run store on disk as it goes (`particle_filter_to_store`,
resumable, and extendable with later observations)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._brownian import AbstractDriver, BrownianMotion, check_driver
from .._driver.failures import Failures, check_failures
from .._driver.integrate import path_of_noise
from .._driver.plan import check_method, check_y0
from .._driver.sharding import as_given, automatic, check_sharding
from .._support.checks import check_count, steps_on_grid
from .._support.progress import progress_bar
from .._support.solution import RESULTS
from .._support.store import (
    RunStore,
    Store,
    check_store,
    digest,
    digest_bytes,
    fingerprint,
    keep_system,
    open_run,
)
from .assimilation import (
    Forecast,
    Observations,
    Tempering,
    _assimilate,
    _prepare,
    _start,
    _State,
    check_observations,
    check_tempering,
    checked_key,
)


@functools.partial(jax.jit, static_argnames=("method", "m", "retry", "chunk_size", "auto"))
def _forecast(method, system, particles, innovations, step, path, *, m, retry, chunk_size, auto):
    """`particle_filter`'s forecast: every particle `m` steps of `method` with the noise its
    `innovations` make (`AbstractPath.steps_from`), and whether it succeeded; compiled once
    per method, system structure, shapes and layout. A particle is its state and its
    driver's state (`()` for Brownian increments, Ornstein–Uhlenbeck traces)."""

    def one(particle, innovations):
        y, state = particle
        state, dWs = path.steps_from(state, innovations)
        ys, _, result, _, _ = path_of_noise(method, system, y, dWs, step, m, False, retry)
        return Forecast((ys[-1], state), result == RESULTS.successful)

    if chunk_size is not None:
        return jax.lax.map(lambda a: one(*a), (particles, innovations), batch_size=chunk_size)
    if auto is not None:
        particles, innovations = jax.lax.with_sharding_constraint((particles, innovations), auto)
    return jax.vmap(one)(particles, innovations)


@dataclasses.dataclass(frozen=True)
class _OnState:
    """`observe` of a particle, which carries its driver's state beside its state: of the
    state alone (equal, and hashed alike, for the same `observe`: compiled once)."""

    observe: Any

    def __call__(self, particle):
        return self.observe(particle[0])


def particle_filter(
    system,
    particles,
    observations: Observations,
    *,
    dt,
    key,
    t0=0.0,
    tempering: Tempering = Tempering(),
    method: Any = "auto",
    failures: Failures = Failures(),
    chunk_size: int | None = None,
    sharding=None,
    driver: AbstractDriver | None = None,
):
    r"""Assimilate observations into an ensemble of a stochastic Lie–Poisson system: the
    filter of `assimilate` (adaptive tempering, systematic resampling, pCN jittering of each
    particle's Brownian increments; Cotter, Crisan, Holm, Pan & Shevchenko 2020) with the
    library's integrators as the forecast. Every state a particle takes is a step of
    `method` from its parent's state: with a Poisson method (`IsospectralMidpoint` on so(n)*
    and su(N)*, the default there) every particle stays on its initial coadjoint orbit.

    The increments are Gaussian, not truncated, and drawn without Lévy areas (the methods'
    strong order ½ with several noises), or the integrals of Ornstein–Uhlenbeck traces
    (`driver`).

    **Arguments:**

    - `system`: the model, any system of the library.
    - `particles`: the initial ensemble, `(n, *state)`, `n >= 2`, each a state of the system.
    - `observations`: an `Observations` with its `times`: increasing, equally spaced, after
      `t0`, each on the grid of `dt` from `t0`.
    - `dt`: the integrator's step; `key`: a JAX key; `t0`: the particles' time (0).
    - `tempering`: a `Tempering`, as for `assimilate`.
    - `method`: as for `integrate`.
    - `failures`: a `Failures`: its `retry_substeps` as for `simulate`; a particle whose
      forecast still fails gets likelihood 0 (it is never resampled, and a pCN move to it
      is rejected), so `throw=True` is refused.
    - `chunk_size`: `None` (default): every forecast runs all particles at once (`vmap`);
      `k`: `k` particles at a time (`jax.lax.map` in batches), so that the memory of a
      forecast is that of `k` particles. Each particle's forecast is its own, so the
      result is the same (`tests/test_assimilation.py`).
    - `sharding`: `None` (default), `"auto"` or a `jax.sharding.Sharding` of the particle
      axis, as for `simulate`: each forecast runs every device's particles on that device
      (JAX's SPMD partitioner), and the tempering and resampling, which need all the
      weights, gather them. The result is that of the unsharded filter, to round-off
      (`tests/test_scale.py`). One process only; not with `chunk_size`.
    - `driver`: `None` (default): Gaussian Brownian increments, as
      `sj.BrownianMotion(truncate_k=None, levy_area=False)` (a driver that truncates its
      increments or draws Lévy areas is refused: pCN keeps a Gaussian law);
      `sj.OrnsteinUhlenbeck(T)`: smooth Ornstein–Uhlenbeck traces, one per noise (the
      driver of a noise fitted with `time_model="ou"`). Each particle then carries its
      traces beside its state, drawn from their stationary law at the start and copied with
      it when resampled, and pCN moves the standard normal numbers of the traces' exact
      steps (`AbstractPath.innovations`).

    **Returns:** a `FilterResult` (its `particles` and `mean` the system's states alone).
    """
    tempering = check_tempering("particle_filter", tempering)
    setup = _setup(
        "particle_filter",
        system,
        particles,
        observations,
        dt=dt,
        t0=t0,
        method=method,
        failures=failures,
        chunk_size=chunk_size,
        sharding=sharding,
        driver=driver,
        key=key,
    )
    key, x = setup.initial(checked_key("particle_filter", key))
    with automatic(setup.sharding, (system, x)) as (auto, (system, x)):
        result = _assimilate(
            "particle_filter",
            setup.forecast(system, auto),
            x,
            setup.observing(observations),
            increments_shape=setup.innovations[0],
            dt=setup.innovations[1],
            key=key,
            tempering=tempering,
        )
    # (the analyses' states, without the driver's)
    result = result._replace(particles=result.particles[0], mean=result.mean[0])
    return as_given(result, setup.sharding)


def particle_filter_to_store(
    system,
    particles,
    observations: Observations,
    store: Store,
    *,
    dt,
    key,
    t0=0.0,
    tempering: Tempering = Tempering(),
    method: Any = "auto",
    failures: Failures = Failures(),
    chunk_size: int | None = None,
    driver: AbstractDriver | None = None,
):
    r"""`particle_filter`, written to a run store on disk as it goes: each observation's
    analysis is appended to the store with the filter's state (every particle's pCN window,
    the random key, the log evidence) and committed together, so that memory stays flat in the
    number of observations, and a run killed at any point goes on from its last complete
    observation with `Store(..., resume=True)`, giving the same analyses, bit for bit, as a
    run never stopped. Resuming with more observations than the store holds extends the run:
    a filter kept up to date as observations arrive.

    **Arguments:** as `particle_filter`'s (without `sharding`), and

    - `store`: a `Store` (its folder, `resume` and `progress`; the other options are
      `simulate_to_store`'s). On `resume`, a store of another filter (system, particles,
      step, key, method, options, `observe` on the particles) is refused, naming what
      differs, and so are observations that differ from those already assimilated. The
      observations and their times may run further than the store's.

    **Returns:** the store opened for reading (`open_run(folder)`), one record per
    observation: `"state"` the analysis ensemble `(n_obs, n, *state)`, `"mean"` its mean,
    `"observation"` what was assimilated, `"ess"` the least stage ESS, `"stages"` the
    tempering stages, `"acceptance"` pCN's mean acceptance, `"log_evidence"` the log
    evidence so far; its `.times` are the observation times less `t0`.
    """
    store = check_store("particle_filter_to_store", store)
    store.only_folder_options("particle_filter_to_store")
    tempering = check_tempering("particle_filter_to_store", tempering)
    setup = _setup(
        "particle_filter_to_store",
        system,
        particles,
        observations,
        dt=dt,
        t0=t0,
        method=method,
        failures=failures,
        chunk_size=chunk_size,
        sharding=None,
        driver=driver,
        key=key,
    )
    x, m, lag = setup.x, setup.m, tempering.jitter_lag
    key = checked_key("particle_filter_to_store", key)
    key_data = np.asarray(jax.random.key_data(key))
    key, x0 = setup.initial(key)
    run = _prepare(
        setup.forecast(system, None),
        x0,
        setup.observing(observations),
        tempering,
        "particle_filter_to_store",
    )
    n, ys, real = x.shape[0], run.ys, run.real
    increments = setup.innovations[0]
    leaves = jax.tree_util.tree_leaves(x0)
    snapshots = {
        "state": (x.shape, x.dtype),
        "mean": (x.shape[1:], x.dtype),
        "observation": (ys.shape[1:], real),
        "ess": ((), real),
        "stages": ((), np.int64),
        "acceptance": ((), real),
        "log_evidence": ((), np.float64),
    }
    carry = {
        **{f"anchor_{i}": (a.shape, a.dtype) for i, a in enumerate(leaves)},
        **{f"xs_{i}": ((n, lag, *a.shape[1:]), a.dtype) for i, a in enumerate(leaves)},
        "dws": ((n, lag, *increments), real),
        "ells": ((n, lag), real),
        "width": ((), np.int64),
        "key": (key_data.shape, key_data.dtype),
        "log_z": ((), np.float64),
        "observations": ((32,), np.uint8),  # (a digest of those assimilated)
    }
    what = fingerprint(
        system=system,
        method=setup.method,
        dt=setup.h,
        save_every=m,
        dtype=x.dtype,
        key_data=key_data,
        t0=float(t0),
        particles=digest(x),
        observe=digest(jax.vmap(observations.observe)(x)),
        obs_std=digest(run.std),
        key_impl=str(jax.random.key_impl(key)),
        options=[*dataclasses.astuple(tempering), setup.retry],
        driver=repr(driver),
    )
    writer = RunStore(
        store.folder,
        what,
        snapshots,
        carry,
        mode="resume" if store.resume else "create",
        caller="particle_filter_to_store",
    )
    with writer:
        keep_system(store.folder, system, "particle_filter_to_store")
        state = _start(run, key)
        if writer.checkpoint is not None:
            state = _restore(writer.checkpoint, key, ys, m, x0)
        filtering = run.cycles(state, increments_shape=increments, dt=setup.innovations[1])
        bar = progress_bar(
            ys.shape[0] - state.k,
            "particle_filter_to_store",
            unit="observation",
            enabled=store.progress,
        )
        for cycle in filtering:
            k = cycle.state.k
            analysis = cycle.analysis[0]
            record = {
                "state": analysis[None],
                "mean": jnp.mean(analysis, axis=0)[None],
                "observation": ys[k - 1][None],
                "ess": np.asarray([cycle.ess]),
                "stages": np.asarray([len(cycle.temperatures)]),
                "acceptance": np.asarray([np.mean(cycle.acceptance)]),
                "log_evidence": np.asarray([cycle.state.log_z]),
            }
            writer.append(
                {name: np.asarray(v) for name, v in record.items()},
                _carry(cycle.state, lag, np.frombuffer(digest_bytes(ys[:k]), np.uint8)),
                k * m,
            )
            bar.update(1)
        bar.close()
    return open_run(store.folder)


class _Setup(NamedTuple):
    """A filter's checked inputs: the method, the particles, the steps between observations
    `m` of `h`, the retry, the layout, and the driver's path at steps `h` (a particle is its
    state and the path's state)."""

    method: Any
    x: Any
    m: int
    h: float
    retry: Any
    chunk_size: Any
    sharding: Any
    driver: AbstractDriver
    path: Any
    innovations: tuple  # (shape, variance) of a particle's Gaussian numbers per interval

    def forecast(self, system, auto):
        """The forecast of a batch of particles to the next observation (jitted, shared)."""
        options = dict(m=self.m, retry=self.retry, chunk_size=self.chunk_size, auto=auto)
        step = jnp.asarray(self.h, self.x.real.dtype)
        return functools.partial(
            _forecast, self.method, system, step=step, path=self.path, **options
        )

    def initial(self, key):
        """`(key, particles)`: each particle its state and its driver's state, drawn (for a
        driver that carries one: Ornstein–Uhlenbeck traces from their stationary law)."""
        if not self.driver.carries_state:
            return key, (self.x, self.path.initial_state(key))
        key, draw = jax.random.split(key)
        return key, (self.x, self.path.initial_state(draw, (self.x.shape[0],)))

    def observing(self, observations):
        """What the filter observes of a particle (its state, without its driver's)."""
        return dataclasses.replace(observations, observe=_OnState(observations.observe))


def _setup(
    name,
    system,
    particles,
    observations,
    *,
    dt,
    t0,
    method,
    failures,
    chunk_size,
    sharding,
    driver,
    key,
):
    """The inputs of a filter `name` (`particle_filter`, `ensemble_kalman_filter`) but its
    analysis's options checked, by name, before any work (`key` too, used later)."""
    checked_key(name, key)
    observations = check_observations(name, observations, timed=True)
    failures = check_failures(name, failures)
    if failures.throw:
        raise ValueError(
            f"{name}: a particle whose forecast fails gets likelihood 0 (it is left out by "
            "the resampling): Failures(throw=True) is not an option of the filter."
        )
    method = check_method(method, system)
    x = jnp.asarray(particles)
    shape = tuple(system.algebra.shape)
    if x.shape[1:] != shape or x.shape[0] < 2:
        one = " (one state: give n >= 2 of them)" if x.shape == shape else ""
        raise ValueError(
            f"{name}: particles must be n >= 2 states of {system.algebra.name}, shape "
            f"(n, {', '.join(map(str, shape))}); got shape {x.shape}{one}."
        )
    x = jnp.stack([check_y0(p, method, system) for p in np.asarray(x)])
    times = np.asarray(observations.times, dtype=float)
    h = float(dt)
    if not h > 0:
        raise ValueError(f"{name}: dt must be positive, got {dt!r}.")
    gaps = np.diff(np.concatenate([[float(t0)], times]))
    if times.ndim != 1 or times.size == 0 or np.any(gaps <= 0):
        raise ValueError(
            f"{name}: the observation times must be increasing and after t0 = {t0}, got "
            f"{observations.times!r}."
        )
    values = observations.values
    n_obs = np.shape(values)[0] if np.ndim(values) else None
    if n_obs is not None and times.size != n_obs:
        raise ValueError(
            f"{name}: the observations have {times.size} times for {n_obs} values; give one "
            "time per observation."
        )
    steps, on_grid = steps_on_grid(gaps, h)
    m = int(steps[0])
    if not np.all(on_grid) or np.any(steps != m):
        raise ValueError(
            f"{name}: the observation times must be equally spaced on the grid of dt from t0 "
            f"(dt = {h}); their gaps are {gaps.tolist()} s."
        )
    retry = failures.retry_substeps
    if chunk_size is not None:
        chunk_size = min(check_count("chunk_size", chunk_size), x.shape[0])
    sharding = check_sharding(sharding, x.shape[0], name="the number of particles")
    if sharding is not None and chunk_size is not None:
        raise ValueError(
            f"{name}: give chunk_size or sharding, not both (the chunks would run one after "
            "another across the devices)."
        )
    # (the filter's pCN needs Gaussian increments: untruncated, without areas)
    driver = check_driver(
        BrownianMotion(truncate_k=None, levy_area=False) if driver is None else driver
    )
    try:
        path = driver.path(h, system.n_noises, x.real.dtype, levy_area=driver.levy_area is True)
        innovations = path.innovations(m)
    except ValueError as err:
        raise ValueError(f"{name}: {err}") from None
    return _Setup(method, x, m, h, retry, chunk_size, sharding, driver, path, innovations)


def _carry(state, lag, observations):
    """A filter's `_State` as the store's carry: the windows padded to `lag` intervals, a
    particle's parts (its state, a driver's traces) one field each."""
    width = state.dws.shape[1]

    def pad(a):
        a = np.asarray(a)
        return np.concatenate([a, np.zeros((a.shape[0], lag - width, *a.shape[2:]), a.dtype)], 1)

    anchors, xs = jax.tree_util.tree_leaves(state.anchor), jax.tree_util.tree_leaves(state.xs)
    return {
        **{f"anchor_{i}": np.asarray(a) for i, a in enumerate(anchors)},
        **{f"xs_{i}": pad(a) for i, a in enumerate(xs)},
        "dws": pad(state.dws),
        "ells": pad(state.ells),
        "width": np.asarray(width),
        "key": np.asarray(jax.random.key_data(state.key)),
        "log_z": np.asarray(state.log_z, np.float64),
        "observations": observations,
    }


def _restore(checkpoint, key, ys, m, like):
    """The `_State` a store's last record left (`_carry`; a particle's parts as in `like`),
    once the observations it assimilated are found equal to the first ones of `ys`."""
    c = checkpoint.carry
    k = checkpoint.step // m
    if k > ys.shape[0]:
        raise ValueError(
            f"particle_filter_to_store: the store holds {k} observations, more than the "
            f"{ys.shape[0]} given: resume with all of them."
        )
    if digest_bytes(ys[:k]) != np.asarray(c["observations"]).tobytes():
        raise ValueError(
            f"particle_filter_to_store: the observations differ from the {k} the store has "
            "assimilated."
        )
    width = int(c["width"])
    treedef = jax.tree_util.tree_structure(like)
    parts = range(treedef.num_leaves)

    def tree(name, window):
        leaves = [
            jnp.asarray(c[f"{name}_{i}"][:, :width] if window else c[f"{name}_{i}"]) for i in parts
        ]
        return jax.tree_util.tree_unflatten(treedef, leaves)

    return _State(
        k,
        tree("anchor", False),
        jnp.asarray(c["dws"][:, :width]),
        tree("xs", True),
        jnp.asarray(c["ells"][:, :width]),
        jax.random.wrap_key_data(jnp.asarray(c["key"]), impl=jax.random.key_impl(key)),
        float(c["log_z"]),
    )
