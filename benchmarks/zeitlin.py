#!/usr/bin/env python
"""Euler–Zeitlin on su(N)*: cost against N, conservation, and quflow measured beside us.

The deterministic Euler–Zeitlin system (`sj.EulerZeitlin(N)`, physical time), a smooth
initial vorticity of degrees l = 1..4 (coefficients N(0, 1), seed 0), step h = 0.01 s.

- Cost against N = 16, 32, 64, 128, 256: run time per sample-step (median of >= 3 blocking
  calls after a warm-up) and compile time (ahead of time, on its own) of
  `IsospectralMidpoint` (the fixed-point iteration: Newton's dense Jacobian would have
  (N^2 - 1)^2 entries), `Midpoint` and `Heun`, for an ensemble of 16 states
  (`jit(vmap(integrate))`) and for one state (`jit(integrate)`), over 64 / 32 / 16 / 8 / 4
  steps; solver updates per step and steps redone as substeps (`retry_substeps`; ours
  solve to 64 eps, about 1.4e-14). With quflow importable (installed by hand from its
  sources; never a dependency), its `isomp` (Numba, fixed point, the same h, its default
  tolerance `eps (h/hbar) |W|_inf` and at most 10 updates, which it leaves silently
  unconverged: the share of such steps is reported) on one state in the same run, and the
  largest difference between its final state (solved to 1e-13) and ours (the same scheme).
- Conservation over 10^4 steps at N = 32: the largest relative drift of tr W^2, |tr W^3|,
  tr W^4 and of the energy along one path, for each method.
- `--final-update`: the final update's crossover (`final_update`).
- `--check-quflow`: quflow's `shr2mat`, `mat2shr`, `solve_poisson`, `energy_euler`,
  `enstrophy` against ours (N = 5, 8, 16), and the order of its `isomp` against our exact
  flow `drift_flow` (the same time units).

Writes `zeitlin.csv`, `zeitlin.json`, `zeitlin.md` into --out (default benchmarks/results)
and the figure `zeitlin.png` there.

    python benchmarks/zeitlin.py [--fast] [--check-quflow] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin as z  # noqa: E402
from slps_jax._algebra import matmul  # noqa: E402

try:  # quflow is measured beside us where it is installed; never a dependency
    import quflow as qf
except ImportError:
    qf = None

H = 0.01
STEPS = {8: 64, 16: 64, 32: 32, 64: 16, 128: 8, 256: 4}
ENSEMBLE = 16
TOL = 64 * float(np.finfo(np.float64).eps)  # the implicit methods' default tolerance
FINAL_SAMPLES = {8: 32, 16: 32, 32: 32, 64: 8}  # (--final-update's ensembles)
EIGENBASIS_MAX_N = 512  # its table: N^3 numbers, 1.1 GB at N = 512 in float64


def initial(N, degrees=range(1, 5), seed=0, decay=0):
    """A random vorticity of `degrees`, coefficients N(0, 1) / l^decay (seed `seed`)."""
    rng = np.random.default_rng(seed)
    om = np.zeros((max(degrees) + 1) ** 2)  # (only these degrees: conversion tables of N L^2)
    for el in degrees:
        for m in range(-el, el + 1):
            om[z.elm2ind(el, m)] = rng.normal() / el**decay
    return z.shr2mat(om, N)


METHODS = {
    "IsospectralMidpoint": sj.IsospectralMidpoint(),
    "Midpoint": sj.Midpoint(),
    "Heun": sj.Heun(),
}


def _integrate(system, y0, method):
    return lambda d: sj.integrate(
        system, y0, d, H, method=method, failures=sj.Failures(throw=False)
    )


def _one_path(system, w0, method, n_steps, h=H, **kwargs):
    """`simulate`'s one path of `n_steps` steps of `h` from `w0`, key 0, with the solver's
    statistics (`kwargs`: more of `simulate`'s options)."""
    return sj.simulate(
        system,
        w0,
        t1=n_steps * h,
        dt=h,
        n_samples=1,
        key=jax.random.key(0),
        method=method,
        newton_stats=True,
        **kwargs,
    )


def iterations(system, w0, method, n_steps):
    """Solver updates per step (all attempts) and the steps redone as substeps, one path."""
    if isinstance(method, sj.Heun):
        return 0.0, 0
    sol = _one_path(system, w0, method, n_steps)
    return float(sol.stats["newton_iterations_mean"]), int(sol.stats["n_retried_steps"])


def cost(ns):
    rows = []
    for N in ns:
        system, w0 = sj.EulerZeitlin(N), initial(N)
        n_steps = STEPS[N]
        for name, method in METHODS.items():
            for size in (ENSEMBLE, 1):
                one = _integrate(system, w0, method)
                fn = jax.vmap(one) if size > 1 else one
                dW = jnp.zeros((size, n_steps, 1) if size > 1 else (n_steps, 1))
                compiled, compile_s = _common.compile_timed(fn, dW)
                med, best, reps, y = _common.time_call(compiled, dW, repeats=3, min_total=0.5)
                y = y[0] if size > 1 else y
                if size == ENSEMBLE:  # (the same path for both sizes)
                    its, retried = iterations(system, w0, method, n_steps)
                rows.append(
                    dict(
                        N=N,
                        method=name,
                        samples=size,
                        steps=n_steps,
                        ms_per_sample_step=1e3 * med / (size * n_steps),
                        ms_per_step=1e3 * med / n_steps,
                        compile_s=compile_s,
                        repeats=reps,
                        iterations=its,
                        retried_steps=retried,
                        # (IsospectralMidpoint: rtol 2^-26 of the increment, not absolute)
                        tol=None if isinstance(method, (sj.Heun, sj.IsospectralMidpoint)) else TOL,
                        vs_quflow=None,
                        diff_vs_quflow=None,
                        final=np.asarray(y),
                    )
                )
                print(
                    f"N={N:3d} {name:20s} x{size:2d}: {rows[-1]['ms_per_sample_step']:9.3f} "
                    f"ms/sample-step, compile {compile_s:5.2f} s",
                    flush=True,
                )
        if qf is not None:
            w = np.array(w0)
            qf.isomp(w.copy(), H, steps=1)  # compile Numba's kernels
            times = []
            while len(times) < 3 or (sum(times) < 0.5 and len(times) < 30):
                w = np.array(w0)
                start = time.perf_counter()
                qf.isomp(w, H, steps=n_steps)
                times.append(time.perf_counter() - start)
            med = float(np.median(times))
            stats = {"iterations": 0}  # (quflow fills a non-empty dict)
            qf.isomp(np.array(w0), H, steps=n_steps, stats=stats)
            # (its default tolerance, eps h |W|_inf / hbar, is about 1e-8 here: for the
            # comparison of final states, the same run solved to round-off)
            w = np.array(w0)
            qf.isomp(w, H, steps=n_steps, tol=1e-13, maxit=100)
            rows.append(
                dict(
                    N=N,
                    method="quflow isomp",
                    samples=1,
                    steps=n_steps,
                    ms_per_sample_step=1e3 * med / n_steps,
                    ms_per_step=1e3 * med / n_steps,
                    compile_s=None,
                    repeats=len(times),
                    iterations=stats["iterations"],
                    retried_steps=None,
                    maxit_reached=stats.get("number_of_maxit"),
                    tol=stats.get("tol_auto"),
                    vs_quflow=1.0,
                    diff_vs_quflow=0.0,
                    final=w,
                )
            )
            print(
                f"N={N:3d} quflow isomp           x 1: "
                f"{rows[-1]['ms_per_sample_step']:9.3f} ms/step",
                flush=True,
            )
            for r in rows:
                if r["N"] == N and r["method"] != "quflow isomp":
                    r["vs_quflow"] = r["ms_per_sample_step"] / rows[-1]["ms_per_sample_step"]
                    if r["method"] == "IsospectralMidpoint":
                        r["diff_vs_quflow"] = float(np.max(np.abs(r["final"] - w)))
    for r in rows:
        del r["final"]
        r.setdefault("maxit_reached", None)
    return rows


def _products(a, b):
    """Two dependent N x N products, `(a b) b`, as the isospectral step makes them
    (`matmul`: three real products for a complex one): the floor's unit (an update of the
    fixed point needs two, `A X` and `(A X) A`)."""
    return matmul(matmul(a, b), b)


def _complex_products(a, b):
    """The same with XLA's complex product."""
    return (a @ b) @ b


def _quflow_step_ms(w0, h, n_steps=8):
    """quflow's `isomp` on one state, solved to 1e-13 (at most 100 updates), ms per step:
    the median of 3 runs of `n_steps` steps after one that compiles Numba's kernels."""
    qf.isomp(np.array(w0), h, steps=1, tol=1e-13, maxit=100)
    times = []
    for _ in range(3):
        w = np.array(w0)
        start = time.perf_counter()
        qf.isomp(w, h, steps=n_steps, tol=1e-13, maxit=100)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times)) / n_steps


def scale(ns, dtypes, budget_s, members, member_ns, write):
    """Per N and dtype, one state: `solve_poisson` by each route, two N x N products (the
    floor's unit, by `matmul` and by XLA's complex product), and one `IsospectralMidpoint`
    step at h = 0.64/N s (a step its fixed point solves: h = 0.01 s at N = 64,
    0.0025 s at N = 256), cold-started, with its updates and matrix products (2 per update,
    and 10 for the Cayley rotation, the default final update: four squarings at this step,
    2 products each, and 2 to apply it; none for the explicit one). The floor is the
    products alone, the faster kind. The same step with 8 transport noises and their Lévy
    areas (`areas_vs_step`: the area term's cost, one step, both cold).
    quflow's `isomp` at the same h, solved to 1e-13, where it is installed (complex128). A
    part whose last point took longer than `budget_s` is not run at larger N. Matrix
    products at `precision="highest"` (on a GPU the default is TF32 for complex64)."""
    rows, over = [], set()
    for N in ns:
        for dtype in dtypes:
            w0 = initial(N).astype(dtype)
            real = jnp.finfo(dtype).dtype
            row = dict(N=N, dtype=jnp.dtype(dtype).name, h=0.64 / N)
            parts = {
                f"poisson_{r}_ms": (lambda w, r=r: z.solve_poisson(w, route=r), (w0,))
                for r in ("sweep", "scan")
            }
            if N <= EIGENBASIS_MAX_N:  # (its table, an argument: a closure would be compiled in)
                parts["poisson_eigenbasis_ms"] = (
                    lambda w, t: z.solve_poisson(w, route="eigenbasis", eigenbasis=t),
                    (w0, z.poisson_eigenbasis(N, real)),
                )
            rng = np.random.default_rng(N)
            a, b = (
                jnp.asarray(rng.normal(size=(N, N)) + 1j * rng.normal(size=(N, N)), dtype)
                for _ in range(2)
            )
            parts["two_products_ms"] = (_products, (a, b))
            parts["two_complex_products_ms"] = (_complex_products, (a, b))
            system = sj.EulerZeitlin(N, dtype=dtype)
            step = lambda w, d: sj.integrate(
                system,
                w,
                d,
                0.64 / N,
                method=sj.IsospectralMidpoint(),
                failures=sj.Failures(throw=False),
            )
            parts["step_ms"] = (step, (w0, jnp.zeros((1, 1), real)))
            ensemble = jax.vmap(  # (the model an argument: its tables are not compiled in)
                lambda m, w, d: sj.integrate(
                    m,
                    w,
                    d,
                    0.64 / N,
                    method=sj.IsospectralMidpoint(),
                    failures=sj.Failures(throw=False),
                ),
                in_axes=(None, 0, 0),
            )
            scales = jnp.asarray(1.0 + 0.01 * np.arange(members), real)[:, None, None]
            # 8 transport noises with their Lévy areas, one step (the area term's cost)
            noisy = sj.EulerZeitlin(
                N, noise=sj.salt_noise(0.05 * z.shr2mat(np.eye(9)[1:], N)), dtype=dtype
            )
            dW8, A8 = sj.BrownianMotion().increments(
                jax.random.key(N), 1, 0.64 / N, n_noises=8, levy_area=True
            )
            areas = lambda m, w, d, a: sj.integrate(
                m,
                w,
                d,
                0.64 / N,
                areas=a,
                method=sj.IsospectralMidpoint(),
                failures=sj.Failures(throw=False),
            )
            parts["step_8_areas_ms"] = (areas, (noisy, w0, dW8.astype(real), A8.astype(real)))
            if N in member_ns:
                dW0 = jnp.zeros((members, 4, 1), real)
                parts["ensemble_ms"] = (ensemble, (system, scales * w0, dW0))
                if N <= EIGENBASIS_MAX_N:
                    eig = sj.EulerZeitlin(N, dtype=dtype, poisson="eigenbasis")
                    parts["ensemble_eigenbasis_ms"] = (ensemble, (eig, scales * w0, dW0))
            for name, (fn, args) in parts.items():
                if (name, dtype) in over:
                    row[name] = None
                    continue
                compiled, compile_s = _common.compile_timed(fn, *args)
                med, _, _, _ = _common.time_call(compiled, *args, repeats=3, min_total=0.3)
                row[name] = 1e3 * med
                if compile_s + 4 * med > budget_s:
                    over.add((name, dtype))
            for route in ("", "_eigenbasis"):  # (4 steps of each member)
                ensemble_ms = row.pop(f"ensemble{route}_ms", None)
                row[f"ms_per_member_step{route}"] = (
                    None if ensemble_ms is None else ensemble_ms / (4 * members)
                )
            if row["step_ms"] is not None:
                sol = _one_path(system, w0, sj.IsospectralMidpoint(), 1, 0.64 / N)
                row["updates"] = float(sol.stats["newton_iterations_mean"])
                final = 8 if sj.IsospectralMidpoint()._cayley(system, dtype) else 0
                row["products"] = 2 * row["updates"] + final
                unit = min(row["two_products_ms"], row["two_complex_products_ms"])
                row["floor_ms"] = row["products"] / 2 * unit
                row["step_vs_floor"] = row["step_ms"] / row["floor_ms"]
            if row["step_8_areas_ms"] is not None and row["step_ms"] is not None:
                row["areas_vs_step"] = row["step_8_areas_ms"] / row["step_ms"]
            if qf is not None and dtype == jnp.complex128 and jax.default_backend() == "cpu":
                row["quflow_ms"] = _quflow_step_ms(w0, 0.64 / N)
                row["step_vs_quflow"] = row["step_ms"] / row["quflow_ms"]
            rows.append(row)
            write(rows)
            print(
                "  ".join(
                    f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()
                ),
                flush=True,
            )
    return rows


# The fixed point's options measured by `economy`: the default and what it trades.
ECONOMY = {
    "default": dict(),
    "default, cold start": dict(warm_start=0),
    "explicit, rtol 2^-26": dict(final_update="explicit"),
    "explicit, round-off": dict(rtol=0.0, final_update="explicit"),
    "explicit, tol 1e-13": dict(tol=1e-13, final_update="explicit"),
}


def _casimir_drift(w0, w1):
    """The largest relative change of tr W^2 ... tr W^6 (complex128 arithmetic)."""
    w0, w1 = np.asarray(w0, np.complex128), np.asarray(w1, np.complex128)
    powers0, powers1, out = w0, w1, 0.0
    for _ in range(2, 7):
        powers0, powers1 = powers0 @ w0, powers1 @ w1
        c0, c1 = np.trace(powers0), np.trace(powers1)
        out = max(out, abs(c1 - c0) / abs(c0))
    return out


def _quflow_run(w0, h, n_steps, **options):
    """quflow's `isomp` on one state over `n_steps` steps: ms per step (median of 3 runs
    after one that compiles Numba's kernels), its updates per step, the share of steps it
    left at its `maxit`, and the final state."""
    qf.isomp(np.array(w0), h, steps=1, **options)
    times = []
    for _ in range(3):
        w = np.array(w0)
        start = time.perf_counter()
        qf.isomp(w, h, steps=n_steps, **options)
        times.append(time.perf_counter() - start)
    stats = {"iterations": 0}  # (quflow fills a non-empty dict only)
    w = np.array(w0)
    qf.isomp(w, h, steps=n_steps, stats=stats, **options)
    return (
        1e3 * float(np.median(times)) / n_steps,
        stats["iterations"],
        stats.get("number_of_maxit"),
        w,
    )


def economy(ns, dtypes, n_steps, write, options=None, members=0, member_ns=()):
    """The fixed point's economy: one state, `n_steps` steps of h = 0.64/N s from the smooth
    state, for each of `options` (default `ECONOMY`) of `IsospectralMidpoint`: ms per step
    (`simulate` with `newton_stats`, median of >= 3 calls after the first; compile time: the
    first call's excess), updates per step and the share of steps at `max_iter`, and the
    Casimirs' largest relative drift over the run. Beside them (complex128, CPU, where quflow is installed)
    quflow's `isomp` over the same steps at its defaults (tolerance
    `sqrt(eps) (h/hbar) |W|_inf`, at most 10 updates, warm start) and at tol 1e-13 (at most
    100 updates), and each row's time as a ratio to both. With `members`, at each N of
    `member_ns` also the default for an ensemble of that many states (the smooth state
    scaled by 1 + 0.01 i), in ms per member-step, with the drift of its first member."""
    options = ECONOMY if options is None else options
    rows = []
    for N in ns:
        h = 0.64 / N
        for dtype in dtypes:
            w0 = initial(N).astype(dtype)
            real = jnp.finfo(dtype).dtype
            system = sj.EulerZeitlin(N, dtype=dtype)
            quflow = {}
            if qf is not None and dtype == jnp.complex128 and jax.default_backend() == "cpu":
                for name, kw in (("default", {}), ("1e-13", dict(tol=1e-13, maxit=100))):
                    quflow[name] = _quflow_run(w0, h, n_steps, **kw)
                    ms, its, maxit, w = quflow[name]
                    rows.append(
                        dict(
                            N=N,
                            dtype=jnp.dtype(dtype).name,
                            option=f"quflow isomp, {name}",
                            ms_per_step=ms,
                            compile_s=None,
                            updates=its,
                            max_iter_share=maxit,
                            casimir_drift=_casimir_drift(w0, w),
                        )
                    )
            for name, kw in options.items():
                method = sj.IsospectralMidpoint(**kw)
                run = lambda m=method: _one_path(system, w0, m, n_steps, h)
                start = time.perf_counter()
                jax.block_until_ready(run())
                first = time.perf_counter() - start
                med, _, _, sol = _common.time_call(run, repeats=3, warmup=False)
                row = dict(
                    N=N,
                    dtype=jnp.dtype(dtype).name,
                    option=name,
                    ms_per_step=1e3 * med / n_steps,
                    compile_s=first - med,
                    updates=float(sol.stats["newton_iterations_mean"]),
                    max_iter_share=float(sol.stats["max_iter_share"]),
                    casimir_drift=_casimir_drift(w0, sol.ys[0, -1]),
                )
                for q, (ms, _, _, _) in quflow.items():
                    row[f"vs_quflow_{q}"] = row["ms_per_step"] / ms
                rows.append(row)
                write(rows)
                _print(row)
            if N in member_ns and members:
                ws = jnp.asarray(1.0 + 0.01 * np.arange(members), real)[:, None, None] * w0
                dWs = jnp.zeros((members, n_steps, 1), real)
                fn = jax.vmap(
                    lambda s, w, d: sj.integrate(
                        s,
                        w,
                        d,
                        h,
                        method=sj.IsospectralMidpoint(),
                        failures=sj.Failures(throw=False),
                    ),
                    in_axes=(None, 0, 0),
                )
                compiled, compile_s = _common.compile_timed(fn, system, ws, dWs)
                med, _, _, w = _common.time_call(compiled, system, ws, dWs, repeats=3)
                rows.append(
                    dict(
                        N=N,
                        dtype=jnp.dtype(dtype).name,
                        option=f"default, ensemble of {members} (per member-step)",
                        ms_per_step=1e3 * med / (n_steps * members),
                        compile_s=compile_s,
                        casimir_drift=_casimir_drift(ws[0], w[0]),  # (final states)
                    )
                )
                write(rows)
                _print(rows[-1])
    return rows


FINAL_UPDATES = {  # the default's Cayley rotation against the explicit update of quflow's form
    "cayley (default)": dict(),
    "explicit, round-off": dict(rtol=0.0, final_update="explicit"),
    "explicit, rtol 2^-26": dict(final_update="explicit"),
}


def final_update(ns, n_steps, write):
    """Where the explicit final update solved to round-off would beat the Cayley rotation:
    an ensemble (`FINAL_SAMPLES`) of `EulerZeitlin(N, c=0.1)` through `simulate`, `n_steps`
    steps of h = 2^-9, 2^-7 and 0.64/N s from the smooth state; us per sample-step (median),
    updates per step and the Casimirs' drift over the run, for each of `FINAL_UPDATES`."""
    rows = []
    for N in ns:
        w0, system = initial(N), sj.EulerZeitlin(N, c=0.1)
        samples = FINAL_SAMPLES.get(N, 1)
        for h in (2.0**-9, 2.0**-7, 0.64 / N):
            for name, options in FINAL_UPDATES.items():
                method = sj.IsospectralMidpoint(**options)

                def run(method=method, h=h):
                    return sj.simulate(
                        system,
                        w0,
                        t1=n_steps * h,
                        dt=h,
                        n_samples=samples,
                        key=jax.random.key(0),
                        method=method,
                        newton_stats=True,
                    )

                seconds, _, _, sol = _common.time_call(run)
                row = dict(
                    N=N,
                    h=h,
                    samples=samples,
                    update=name,
                    us_per_sample_step=1e6 * seconds / (samples * n_steps),
                    updates=float(sol.stats["newton_iterations_mean"]),
                    casimir_drift=_casimir_drift(w0, np.asarray(sol.ys).reshape(-1, N, N)[0]),
                )
                rows.append(row)
                _print(row)
                write(rows)
    return rows


def store_cost(N, n_steps, save_every, n_samples, directory):
    """A run to disk against the same run in memory: `EulerZeitlin(N)`, deterministic,
    `n_samples` states, `n_steps` steps of h = 0.64/N and a snapshot every `save_every`;
    seconds per step of `simulate` (the snapshots kept in memory) and of `simulate_to_store`
    (written record by record, fsync'd, with the default diagnostics), each after a first
    run that compiles, and the bytes written."""
    import shutil

    h = 0.64 / N
    system, w0 = sj.EulerZeitlin(N), initial(N)
    args = dict(t1=n_steps * h, dt=h, n_samples=n_samples, key=jax.random.key(0))
    run = lambda: sj.simulate(system, w0, save_every=save_every, **args).ys
    path = os.path.join(directory, "store_cost.zarr")

    def to_store():
        shutil.rmtree(path, ignore_errors=True)
        return sj.simulate_to_store(
            system, w0, sj.Store(path, progress=False), save_every=save_every, **args
        ).read("energy")

    out = dict(N=N, steps=n_steps, save_every=save_every, samples=n_samples)
    for name, fn in (("memory", run), ("store", to_store)):
        jax.block_until_ready(fn())
        med = _common.time_call(fn, repeats=3, warmup=False)[0]
        out[f"s_per_step_{name}"] = med / n_steps
    out["store_vs_memory"] = out["s_per_step_store"] / out["s_per_step_memory"]
    out["bytes_written"] = sum(
        os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files
    )
    shutil.rmtree(path, ignore_errors=True)
    _print(out)
    return out


def _print(row):
    print(
        "  ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
        flush=True,
    )


def breakdown(N, members, big_N, write):
    """Where an ensemble step's time goes: per member of an ensemble of `members` at N,
    two batched N x N products, `solve_poisson` by the scan and eigenbasis routes, and an
    `IsospectralMidpoint` step (2 steps timed) by final update and route, complex128 and
    complex64; then one complex64 state at `big_N`: the Cayley rotation's LU solve, two
    products, and a step by final update. ms, median of >= 3 calls."""
    rows = []

    def timed(case, dtype, fn, *args, per=1):
        compiled, compile_s = _common.compile_timed(fn, *args)
        med = _common.time_call(compiled, *args, repeats=3, min_total=0.3)[0]
        rows.append(dict(case=case, dtype=jnp.dtype(dtype).name, ms=1e3 * med / per))
        rows[-1]["compile_s"] = compile_s
        print(f"{case} {rows[-1]['dtype']}: {rows[-1]['ms']:.4g} ms", flush=True)
        write(rows)

    for dtype in (jnp.complex128, jnp.complex64):
        real = jnp.finfo(dtype).dtype
        w = (jnp.asarray(1.0 + 0.01 * np.arange(members))[:, None, None] * initial(N)).astype(dtype)
        label = f"N = {N}, per member of {members}:"
        two = jax.vmap(lambda a, b: matmul(matmul(a, b), b))
        timed(f"{label} two products", dtype, two, w, w, per=members)
        scan = jax.vmap(lambda x: z.solve_poisson(x, route="scan"))
        timed(f"{label} solve_poisson scan", dtype, scan, w, per=members)
        eig = lambda x, t: z.solve_poisson(x, route="eigenbasis", eigenbasis=t)
        timed(
            f"{label} solve_poisson eigenbasis",
            dtype,
            eig,
            w,
            z.poisson_eigenbasis(N, real),
            per=members,
        )
        dW = jnp.zeros((members, 2, 1), real)
        for final in ("explicit", "cayley"):
            ensemble = jax.vmap(
                lambda m, x, d, f=final: sj.integrate(
                    m,
                    x,
                    d,
                    0.64 / N,
                    method=sj.IsospectralMidpoint(final_update=f),
                    failures=sj.Failures(throw=False),
                ),
                in_axes=(None, 0, 0),
            )
            for route in ("scan", "eigenbasis"):
                system = sj.EulerZeitlin(N, dtype=dtype, poisson=route)
                timed(
                    f"{label} step, {final}, {route}",
                    dtype,
                    ensemble,
                    system,
                    w,
                    dW,
                    per=2 * members,
                )
    w = initial(big_N).astype(jnp.complex64)
    eye = jnp.eye(big_N, dtype=jnp.complex64)
    label = f"N = {big_N}, one state:"
    timed(f"{label} LU solve", jnp.complex64, lambda a: jnp.linalg.solve(eye - a, eye + a), w)
    timed(f"{label} two products", jnp.complex64, lambda a, b: matmul(matmul(a, b), b), w, w)
    system = sj.EulerZeitlin(big_N, dtype=jnp.complex64)
    for final in ("explicit", "cayley"):
        step = lambda m, x, d, f=final: sj.integrate(
            m,
            x,
            d,
            0.64 / big_N,
            method=sj.IsospectralMidpoint(final_update=f),
            failures=sj.Failures(throw=False),
        )
        dW = jnp.zeros((2, 1), jnp.float32)
        timed(f"{label} step, {final}", jnp.complex64, step, system, w, dW, per=2)
    return rows


def conservation(N, n_steps):
    """The largest relative drift of tr W^2, |tr W^3|, tr W^4 and of the energy along one
    deterministic path, each method in complex128 and `IsospectralMidpoint` in complex64
    (`EulerZeitlin(N, dtype=complex64)`, the same initial state cast); and
    `IsospectralMidpoint` with the explicit final update in both (the default solve, without
    the Cayley rotation: what the rotation buys)."""
    rows = []
    runs = [(name, method, jnp.complex128) for name, method in METHODS.items()]
    runs.append(("IsospectralMidpoint", METHODS["IsospectralMidpoint"], jnp.complex64))
    explicit = sj.IsospectralMidpoint(final_update="explicit")
    runs += [
        ("IsospectralMidpoint (explicit)", explicit, d) for d in (jnp.complex128, jnp.complex64)
    ]
    w0 = initial(N)
    c0 = np.asarray(sj.su(N).casimirs(w0))
    e0 = float(z.energy(w0))
    for name, method, dtype in runs:
        system = sj.EulerZeitlin(N, dtype=dtype)
        sol = sj.simulate(
            system,
            w0,
            t1=n_steps * H,
            dt=H,
            n_samples=1,
            key=jax.random.key(0),
            method=method,
            save_every=n_steps // 10,
        )
        if int(sol.stats["n_failed"]):
            raise RuntimeError(f"{name}: the path failed; its frozen state is not data.")
        ws = sol.ys[0].astype(jnp.complex128)
        c = np.asarray(system.algebra.casimirs(ws))
        rel = np.max(np.abs(c - c0), axis=0) / np.abs(c0)
        rows.append(
            dict(
                method=name,
                dtype=jnp.dtype(dtype).name,
                N=N,
                steps=n_steps,
                tr_w2=rel[0],
                tr_w3=rel[1],
                tr_w4=rel[2],
                energy=float(np.max(np.abs(np.asarray(z.energy(ws)) - e0))) / e0,
            )
        )
        print(
            f"conservation {name:30s} {jnp.dtype(dtype).name:10s}: tr W^2 {rel[0]:.1e}, "
            f"tr W^3 {rel[1]:.1e}, tr W^4 {rel[2]:.1e}, energy {rows[-1]['energy']:.1e}",
            flush=True,
        )
    return rows


def check_quflow():
    """quflow's conventions against ours, and its isomp's order against our exact flow."""
    out = {"quflow": getattr(qf, "__version__", "?")}
    for N in (5, 8, 16):
        om = np.random.default_rng(N).normal(size=N * N)
        om[0] = 0.0
        wq = qf.shr2mat(om, N)
        out[f"N={N}"] = dict(
            shr2mat=float(np.max(np.abs(wq - np.asarray(z.shr2mat(om, N))))),
            mat2shr=float(np.max(np.abs(qf.mat2shr(wq) - np.asarray(z.mat2shr(wq))))),
            solve_poisson=float(
                np.max(np.abs(qf.solve_poisson(wq) - np.asarray(z.solve_poisson(wq))))
            ),
            energy=abs(qf.energy_euler(wq) - float(z.energy(wq))) / qf.energy_euler(wq),
            enstrophy=abs(qf.enstrophy(wq) - float(z.enstrophy(wq))) / qf.enstrophy(wq),
        )
    N, t = 16, 2.0
    w0 = np.asarray(initial(N))
    ref = np.asarray(sj.drift_flow(sj.EulerZeitlin(N), w0, np.array([t]), max_step=2.0**-10)[0])
    errs = []
    for h in (0.01, 0.005, 0.0025):
        w = w0.copy()
        qf.isomp(w, h, steps=round(t / h))
        errs.append(float(np.max(np.abs(w - ref))))
    out["isomp_vs_flow"] = dict(
        h=[0.01, 0.005, 0.0025],
        max_error=errs,
        order=float(np.polyfit(np.log([0.01, 0.005, 0.0025]), np.log(errs), 1)[0]),
    )
    print("quflow check:", out, flush=True)
    return out


def figure(path, rows):
    plt = _common.pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = plt.get_cmap("tab10")
    for i, name in enumerate(dict.fromkeys(r["method"] for r in rows)):
        for size, style in ((ENSEMBLE, "o-"), (1, "s--")):
            pts = [r for r in rows if r["method"] == name and r["samples"] == size]
            if not pts:
                continue
            label = f"{name}" + (f", ensemble of {size}" if size > 1 else ", one state")
            ax1.loglog(
                [r["N"] for r in pts],
                [r["ms_per_sample_step"] for r in pts],
                style,
                color=colors(i),
                label=label,
                base=2,
            )
            if pts[0]["compile_s"] is not None:
                ax2.semilogx(
                    [r["N"] for r in pts],
                    [r["compile_s"] for r in pts],
                    style,
                    color=colors(i),
                    label=label,
                    base=2,
                )
    ax1.set_xlabel("N (su(N))")
    ax1.set_ylabel("ms per sample-step")
    ax1.set_title(f"Euler–Zeitlin, h = {H} s: cost per sample-step")
    ax1.legend(fontsize=7)
    ax2.set_xlabel("N (su(N))")
    ax2.set_ylabel("compile time (s)")
    ax2.set_title("Compile time")
    ax2.set_ylim(0, 1.4 * max(r["compile_s"] for r in rows if r["compile_s"] is not None))
    ax2.legend(fontsize=7, ncol=2, loc="upper center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _writer(results, name, caption, cols, formats, csv=False):
    """`write(rows)` for one part of the run, called after every row so that a run cut short
    keeps what it measured: `name.json` (with the machine), `name.md` (where and when,
    `caption`, the table of `cols` with `formats`) and, with `csv`, `name.csv`."""

    def write(rows):
        if csv:
            results.csv(name, rows)
        results.json(name, dict(rows=rows))
        table = [{k: r.get(k) for k in cols} for r in rows]
        results.markdown(name, _common.markdown_table(table, cols, formats), caption)

    return write


def main(argv=None):
    p = _common.parser(__doc__, "a smoke run: N = 8; 200 steps")
    p.add_argument(
        "--check-quflow",
        action="store_true",
        help="compare conventions and dynamics with quflow (needs quflow)",
    )
    p.add_argument(
        "--scale",
        action="store_true",
        help="only the Poisson solve's routes, the step and its matrix-product "
        "floor against N (64 ... 256; with --gpu 64 ... 2048), complex128 "
        "and complex64, into zeitlin_scale.*",
    )
    p.add_argument(
        "--gpu",
        action="store_true",
        help="with --scale: N = 64 ... 2048 on one GPU and an ensemble of 64 at "
        "N = 512, about 8 minutes",
    )
    p.add_argument(
        "--sizes",
        type=int,
        nargs="+",
        help="with --scale: these N, in this order (default: 64 ... 256; with --gpu 64 ... 2048)",
    )
    p.add_argument(
        "--breakdown",
        action="store_true",
        help="only where an ensemble step's time goes (N = 512, 64 members; one state at "
        "N = 2048; with --fast 8, 4 and 16) into zeitlin_breakdown.*",
    )
    p.add_argument(
        "--economy",
        action="store_true",
        help="only the fixed point's economy: one state, 32 steps, each option of "
        "IsospectralMidpoint beside quflow (N = 64, 128, 256; with --gpu 256 ... 2048 in "
        "complex128 and complex64; --sizes to choose), into zeitlin_economy.*",
    )
    p.add_argument(
        "--final-update",
        action="store_true",
        help="only the final update's crossover: Cayley against the explicit update "
        "solved to round-off (N = 8 ... 128; with --fast 8), into zeitlin_final_update.*",
    )
    p.add_argument(
        "--options",
        help="with --economy: a ';'-separated subset of its options (default: all)",
    )
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    info = results.info
    info["quflow"] = None if qf is None else getattr(qf, "__version__", "?")
    print(
        f"# Euler-Zeitlin: {results.measured_on()}, quflow {info['quflow']}",
        flush=True,
    )
    if args.final_update:
        cols = ["N", "h", "samples", "update", "us_per_sample_step", "updates", "casimir_drift"]
        write = _writer(
            results,
            "zeitlin_final_update",
            "; EulerZeitlin(N, c=0.1) through simulate, an ensemble, from the smooth state.",
            cols,
            {"h": ".4g", "us_per_sample_step": ".3g", "updates": ".3g", "casimir_drift": ".1e"},
        )
        final_update((8,) if args.fast else (8, 16, 32, 64, 128), 16 if args.fast else 128, write)
        return
    if args.breakdown:
        write_breakdown = _writer(
            results,
            "zeitlin_breakdown",
            ".",
            ["case", "dtype", "ms", "compile_s"],
            {"ms": ".4g", "compile_s": ".1f"},
        )

        with jax.default_matmul_precision("highest"):
            breakdown(*((8, 4, 16) if args.fast else (512, 64, 2048)), write=write_breakdown)
        return
    if args.economy:
        ns = (8,) if args.fast else (256, 512, 1024, 2048) if args.gpu else (64, 128, 256)
        ns = tuple(args.sizes) if args.sizes else ns
        cols = [
            "N",
            "dtype",
            "option",
            "ms_per_step",
            "vs_quflow_default",
            "vs_quflow_1e-13",
            "updates",
            "max_iter_share",
            "casimir_drift",
            "compile_s",
        ]
        write_economy = _writer(
            results,
            "zeitlin_economy",
            f", quflow {info['quflow']}; one state, 32 steps of h = 0.64/N s.",
            cols,
            {k: ".3g" for k in cols[3:]},
        )

        with jax.default_matmul_precision("highest"):
            if not args.gpu:  # (a run to disk against the same in memory)
                store_row = store_cost(
                    *((8, 64, 8, 2) if args.fast else (128, 256, 8, 2)), args.out
                )
                results.json("zeitlin_store", dict(row=store_row))
            economy(
                ns,
                (jnp.complex128, jnp.complex64) if args.gpu else (jnp.complex128,),
                8 if args.fast else 32,
                write_economy,
                # (on a GPU without the comparison at 1e-13, which is quflow's, on a CPU)
                options={
                    k: v
                    for k, v in ECONOMY.items()
                    if (k in args.options.split(";") if args.options else True)
                    and not (args.gpu and "1e-13" in k)
                },
                members=4 if args.fast else 64 if args.gpu else 0,
                member_ns=ns[:1] if args.fast else (512,),
            )
        return
    if args.scale:
        ns = (8,) if args.fast else (64, 128, 256, 512, 1024, 2048) if args.gpu else (64, 128, 256)
        ns = tuple(args.sizes) if args.sizes else ns
        cols = [
            "N",
            "dtype",
            "h",
            "poisson_sweep_ms",
            "poisson_scan_ms",
            "poisson_eigenbasis_ms",
            "two_products_ms",
            "two_complex_products_ms",
            "step_ms",
            "updates",
            "floor_ms",
            "step_vs_floor",
            "quflow_ms",
            "step_vs_quflow",
            "ms_per_member_step",
            "ms_per_member_step_eigenbasis",
            "areas_vs_step",
        ]
        write = _writer(
            results,
            "zeitlin_scale",
            "; one state, ms; an ensemble, ms per member-step.",
            cols,
            {k: ".3g" for k in cols[2:]},
            csv=True,
        )

        with jax.default_matmul_precision("highest"):
            scale(
                ns,
                (jnp.complex128, jnp.complex64),
                budget_s=60.0,
                members=64 if args.gpu else 4,
                member_ns=(512,) if args.gpu else ns,
                write=write,
            )
        return
    if args.check_quflow and qf is None:
        raise SystemExit("--check-quflow needs quflow (install it from its sources).")
    checked = check_quflow() if args.check_quflow else None
    rows = cost((8,) if args.fast else (16, 32, 64, 128, 256))
    cons = conservation(8 if args.fast else 32, 200 if args.fast else 10_000)
    results.csv("zeitlin", rows)
    results.json(
        "zeitlin",
        dict(h=H, cost=rows, conservation=cons, quflow_check=checked),
    )
    cost_table = _common.markdown_table(
        rows,
        [
            "N",
            "method",
            "samples",
            "ms_per_sample_step",
            "vs_quflow",
            "compile_s",
            "iterations",
            "retried_steps",
            "tol",
            "maxit_reached",
            "diff_vs_quflow",
        ],
        {
            "ms_per_sample_step": ".3f",
            "vs_quflow": ".2f",
            "compile_s": ".2f",
            "iterations": ".1f",
            "tol": ".1e",
            "maxit_reached": ".2f",
            "diff_vs_quflow": ".1e",
        },
    )
    drift_table = _common.markdown_table(
        cons,
        ["method", "dtype", "N", "steps", "tr_w2", "tr_w3", "tr_w4", "energy"],
        {k: ".1e" for k in ("tr_w2", "tr_w3", "tr_w4", "energy")},
    )
    results.markdown(
        "zeitlin",
        f"{cost_table}\nRelative drift over the path\n\n{drift_table}",
        f", quflow {info['quflow']}; h = {H} s.",
    )
    figure(os.path.join(args.out, "zeitlin.png"), rows)


if __name__ == "__main__":
    main()
