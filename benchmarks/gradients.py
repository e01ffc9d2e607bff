#!/usr/bin/env python
"""Cost of pathwise gradients: reverse and forward mode against a forward run, and memory.

The paper's setup (500 samples, T = 1, h = 2^-7): the statistic is mean H(y_T) and the
gradient is taken with respect to (I_1, I_2, I_3, c). For each method: the median wall time
of the jitted forward run, of `jax.grad` (reverse mode) and of `jax.jacfwd` (forward mode,
four tangents), each compiled ahead and timed separately, and their ratios. Then XLA's
temporary-buffer size of the compiled reverse pass against the number of steps (the time
loop is checkpointed in sqrt(n) chunks, so it should grow like sqrt(n), not n).

Writes `gradients.csv`, `gradients_memory.csv`, `gradients.json`.

    python benchmarks/gradients.py [--fast] [--out DIR]
    python benchmarks/gradients.py --retry none   # without the default retry of failing steps
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import math  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402

Y0 = jnp.asarray(sj.PAPER_Y0)
METHODS = {"LiePoisson": sj.LiePoisson(), "Midpoint": sj.Midpoint(), "Strang": sj.Strang()}


def statistic(params, method, n_samples, n_steps, dt, retry_kw=None):
    system = sj.RigidBody(params[:3], params[3])
    sol = sj.simulate(
        system,
        Y0,
        t1=n_steps * dt,
        dt=dt,
        n_samples=n_samples,
        key=jax.random.key(0),
        method=method,
        **(retry_kw or {}),
    )
    return jnp.mean(system.hamiltonian(sol.ys[:, -1]))


def main(argv=None):
    parser = _common.parser(
        __doc__,
        "50 samples, 32 steps, LiePoisson only (the reverse pass's memory: Midpoint)",
    )
    parser.add_argument(
        "--retry",
        default=None,
        metavar="K",
        help="retry_substeps: an integer or 'none' (default: the library's)",
    )
    args = parser.parse_args(argv)
    retry_kw = (
        {}
        if args.retry is None
        else {
            "failures": sj.Failures(
                retry_substeps=None if args.retry == "none" else int(args.retry)
            )
        }
    )
    results = _common.Output(args.out)
    n_samples, n_steps, dt = (50, 32, 2.0**-5) if args.fast else (500, 128, 2.0**-7)
    params = jnp.asarray(np.r_[np.asarray(sj.RigidBody.paper().inertia), 0.2])

    rows = []
    print(
        f"Gradient of mean H(y_T) w.r.t. (I, c): {n_samples} samples x {n_steps} steps, "
        f"median wall time\n"
    )
    print(
        "| method | forward s | grad (reverse) s | ratio | jacfwd (4 tangents) s | ratio | "
        "compile forward s | compile grad s |\n|---|---|---|---|---|---|---|---|"
    )
    # --fast (the test suite): LiePoisson only, the compile-heavy case
    methods = {"LiePoisson": METHODS["LiePoisson"]} if args.fast else METHODS
    for name, method in methods.items():

        def f(p, method=method):
            return statistic(p, method, n_samples, n_steps, dt, retry_kw)

        out = {}
        for kind, fn in (("forward", f), ("reverse", jax.grad(f)), ("jacfwd", jax.jacfwd(f))):
            compiled, compile_s = _common.compile_timed(fn, params)
            median, minimum, n_rep, _ = _common.time_call(compiled, params)
            out[kind] = (median, compile_s)
        row = {
            "method": name,
            "n_samples": n_samples,
            "n_steps": n_steps,
            "forward_s": out["forward"][0],
            "reverse_s": out["reverse"][0],
            "jacfwd_s": out["jacfwd"][0],
            "reverse_ratio": out["reverse"][0] / out["forward"][0],
            "jacfwd_ratio": out["jacfwd"][0] / out["forward"][0],
            "compile_forward_s": out["forward"][1],
            "compile_reverse_s": out["reverse"][1],
        }
        rows.append(row)
        print(
            f"| {name} | {row['forward_s']:.4f} | {row['reverse_s']:.4f} | "
            f"{row['reverse_ratio']:.1f} | {row['jacfwd_s']:.4f} | {row['jacfwd_ratio']:.1f} | "
            f"{row['compile_forward_s']:.2f} | {row['compile_reverse_s']:.2f} |"
        )

    mem = []
    steps_list = [64, 1024] if args.fast else [64, 256, 1024, 4096, 16384]
    # (--fast: Midpoint, which compiles in half the time; the checkpointing is the same)
    mem_method = "Midpoint" if args.fast else "LiePoisson"
    print(
        f"\nXLA temporary memory of the compiled reverse pass ({mem_method}, "
        f"{n_samples} samples):\n\n| n_steps | temp MiB | ratio to sqrt(n) growth |\n|---|---|---|"
    )
    for n in steps_list:

        def g(p, n=n):
            return statistic(p, METHODS[mem_method], n_samples, n, dt)

        compiled = jax.jit(jax.grad(g)).lower(params).compile()
        temp = compiled.memory_analysis().temp_size_in_bytes
        mem.append({"n_steps": n, "temp_bytes": int(temp)})
        ref = mem[0]["temp_bytes"] * math.sqrt(n / mem[0]["n_steps"])
        print(f"| {n} | {temp / 2**20:.2f} | {temp / ref:.2f} |")

    results.csv("gradients", rows)
    results.csv("gradients_memory", mem)
    results.json(
        "gradients",
        {"timing": rows, "memory": mem},
    )
    print(f"\nwrote {args.out}/gradients.{{csv,json}}, gradients_memory.csv")


if __name__ == "__main__":
    main()
