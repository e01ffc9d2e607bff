#!/usr/bin/env python
"""Throughput of ensemble integration: sample-steps per second on `jax.default_backend()`.

For `n_samples` in a sweep (CPU: 10^3 ... 10^5; GPU: 10^3 ... 10^7) at a fixed 64 steps
(h = 2^-6, T = 1, the paper's body and y0, float64), each method integrates the ensemble
and keeps the final state only:

- `Midpoint` (the default on so(3)*), `LiePoisson`, `Strang`, `Strang4` (or any of
  `SIMULATED` named by `--methods`): the public `slps_jax.simulate(..., throw=False)`,
  increments drawn inside the time loop from `fold_in(key, i)`;
- `lax.scan Heun`: Stratonovich Heun as a bare `lax.scan` (a floor for any explicit
  method), increments drawn from the same keys inside the jitted function;
- `diffrax Heun (shared dW)` (only with diffrax, the `bench` extra): `diffeqsolve` with
  `Heun` over the piecewise-linear path of the same increments (as in
  `work_precision.py`), drawn inside the jitted function: the cumulative path of every
  sample is materialised, `(n_samples, 65)` floats.

Each point: the first call (compile + run), then the median / min of >= 3 calls with
`block_until_ready`; compile ~ first - median. A point predicted (from the method's cost at
the previous size) to take longer than `--max-call-s` is skipped, and one that fails (out of
memory) is recorded with its error. Throughput = n_samples * n_steps / median time.

Writes `throughput.csv`, `throughput.json` (with the device) and `throughput.md`.

    python benchmarks/throughput.py [--fast] [--out DIR] [--max-samples N]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402
import work_precision as wp  # noqa: E402  (its diffrax import is guarded)

import slps_jax as sj  # noqa: E402

H = 2.0**-6
N_STEPS = 64
DIFFRAX_HEUN = "diffrax Heun (shared dW)"
SCAN_HEUN = "lax.scan Heun"


def _increments(key, h):
    bound = jnp.asarray(sj._brownian.truncation_bound(h, 4), jnp.float64)
    steps = jnp.arange(N_STEPS, dtype=jnp.uint32)
    return jax.vmap(lambda n: sj._brownian.increment(key, n, jnp.asarray(h), bound, jnp.float64))(
        steps
    )


# the library's methods for the paper's rigid body, run through `simulate`
SIMULATED = (
    "Midpoint",
    "LiePoisson",
    "LiePoissonSym2",
    "LiePoissonSym4",
    "Strang",
    "Strang4",
    "Heun",
    "Milstein",
    "EulerMaruyama",
)


def runner(name, system, y0):
    """`run(key, n_samples)`: the final states `(n_samples, 3)`, blocked."""
    if name in SIMULATED:
        method = getattr(sj, name)()

        def run(key, n_samples):
            sol = sj.simulate(
                system,
                y0,
                t1=N_STEPS * H,
                dt=H,
                n_samples=n_samples,
                key=key,
                method=method,
                failures=sj.Failures(throw=False),
            )
            return jax.block_until_ready(sol.ys[:, -1])

        return run
    if name == SCAN_HEUN:

        def one(k):
            return wp.scan_heun(system, y0, _increments(k, H), H)
    else:
        solver = wp.dfx.Heun()

        def one(k):
            dW = _increments(k, H)
            w = jnp.concatenate([jnp.zeros(1, dW.dtype), jnp.cumsum(dW)])
            return wp.diffrax_final(system, y0, wp.IncrementPath(w, H), solver, H, N_STEPS)

    fn = jax.jit(lambda key, idx: jax.vmap(lambda i: one(jax.random.fold_in(key, i)))(idx))

    def run(key, n_samples):
        return jax.block_until_ready(fn(key, jnp.arange(n_samples, dtype=jnp.uint32)))

    return run


def device_name(cpu_model):
    dev = jax.devices()[0]
    kind = cpu_model if dev.platform == "cpu" else getattr(dev, "device_kind", str(dev))
    return f"{dev.platform}: {kind} x{len(jax.devices())}"


def parse(argv):
    p = _common.parser(__doc__, "tiny sizes for the test suite")
    p.add_argument(
        "--max-samples", type=int, default=None, help="largest n_samples (CPU 10^5, GPU 10^7)"
    )
    p.add_argument(
        "--max-call-s",
        type=float,
        default=20.0,
        help="skip points predicted to take longer per call",
    )
    p.add_argument("--methods", default=None, help="comma-separated subset")
    return p.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    backend = jax.default_backend()
    top = args.max_samples or (10**7 if backend == "gpu" else 10**5)
    sizes = [100, 1000] if args.fast else [n for n in (10**k for k in range(3, 8)) if n <= top]
    methods = ["Midpoint", "LiePoisson", "Strang", "Strang4", SCAN_HEUN] + (
        [DIFFRAX_HEUN] if wp.dfx else []
    )
    if args.methods:
        methods = args.methods.split(",")
    unknown = [m for m in methods if m not in SIMULATED + (SCAN_HEUN, DIFFRAX_HEUN)]
    if unknown:
        raise SystemExit(
            f"unknown methods {unknown}: choose among "
            f"{', '.join(SIMULATED + (SCAN_HEUN, DIFFRAX_HEUN))}"
        )
    results = _common.Output(args.out)
    info = results.info
    info["device"] = device_name(info["cpu_model"])
    print(
        f"throughput, {N_STEPS} steps of h = 2^-6, float64, on {info['device']} "
        f"(jax {info['jax']}, diffrax {info['diffrax']})"
    )
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    key = jax.random.key(0)
    rows = []
    for name in methods:
        run, cost = runner(name, system, y0), None
        for n in sizes:
            row = {
                "method": name,
                "n_samples": n,
                "n_steps": N_STEPS,
                "device": info["device"],
                "first_call_s": None,
                "time_median_s": None,
                "time_min_s": None,
                "compile_est_s": None,
                "sample_steps_per_s": None,
                "status": "ok",
            }
            if cost is not None and cost * n > args.max_call_s:
                row["status"] = f"skipped (predicted {cost * n:.0f} s)"
                rows.append(row)
                print(f"  {name:26s} n={n:>9d}: {row['status']}")
                continue
            try:
                start = time.perf_counter()
                out = run(key, n)
                first = time.perf_counter() - start
                t_med, t_min, _, out = _common.time_call(
                    lambda: run(key, n), repeats=3, min_total=0.3, warmup=False
                )
            except Exception as err:  # noqa: BLE001 - out of memory and the like: record it
                row["status"] = f"failed: {type(err).__name__}: {str(err).splitlines()[0][:120]}"
                rows.append(row)
                print(f"  {name:26s} n={n:>9d}: {row['status']}")
                break
            assert out.shape == (n, 3)
            cost = t_med / n
            row.update(
                first_call_s=first,
                time_median_s=t_med,
                time_min_s=t_min,
                compile_est_s=max(first - t_med, 0.0),
                sample_steps_per_s=n * N_STEPS / t_med,
                finite=bool(jnp.all(jnp.isfinite(out))),
            )
            rows.append(row)
            print(
                f"  {name:26s} n={n:>9d}: {t_med:9.4f} s (min {t_min:.4f}), first call "
                f"{first:6.2f} s, {row['sample_steps_per_s']:10.3e} sample-steps/s"
            )
    for row in rows:
        row.setdefault("finite", None)
    results.csv("throughput", rows)
    results.json(
        "throughput",
        {"machine": info, "h": H, "n_steps": N_STEPS, "rows": rows},
    )
    table = _common.markdown_table(
        rows,
        ["method", "n_samples", "time_median_s", "compile_est_s", "sample_steps_per_s", "status"],
        {"time_median_s": ".4f", "compile_est_s": ".1f", "sample_steps_per_s": ".3e"},
    )
    results.markdown(
        "throughput",
        table,
        f" ({info['device']}); {N_STEPS} steps of h = 2^-6, float64, final state only.",
    )
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
