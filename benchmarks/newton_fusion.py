#!/usr/bin/env python
"""The Newton loops on a CPU: `LiePoisson` against `Midpoint`, with and without `one_kernel`.

XLA:CPU has no multi-output loop fusion: where a residual and its Jacobian are read by
several elementwise consumers (the test, each component of the update), it fuses a copy of
their graph into each consumer. `slps_jax._methods.newton.one_kernel` computes the loop
body's next state as the outputs of one variadic reduce, into which the graph is fused once.
This script watches that it still does, on the paper's body (`RigidBody.paper()`, float64,
`simulate` of 500 samples x 512 steps of h = 2^-9, final state only):

- per sample-step time of `Midpoint`, `LiePoisson` and `LiePoisson(unroll=3)`, and of
  `Midpoint` and `LiePoisson` traced again with `one_kernel` replaced by the identity (the
  loop as it was), all compiled ahead of time in this one process and timed alternately;
  ratios to `Midpoint` with the kernel;
- compile time, and the instructions of all fused computations of the compiled program
  (a graph copied into several fusions shows as a larger count);
- the Newton iterates (mean and largest updates per step, largest residual) and the
  largest difference of the final states with and without the kernel.

Writes `newton_fusion.json` and `newton_fusion.md`.

    python benchmarks/newton_fusion.py [--fast] [--out DIR] [--rounds R]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import re  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402
from slps_jax._methods import newton  # noqa: E402

METHODS = {
    "Midpoint": lambda: sj.Midpoint(),
    "LiePoisson": lambda: sj.LiePoisson(),
    "LiePoisson(unroll=3)": lambda: sj.LiePoisson(unroll=3),
}
WITHOUT = ("Midpoint", "LiePoisson")  # traced again without the kernel
BASE = "Midpoint"


def fused_instructions(compiled):
    """Instructions in all fused computations of a compiled program's HLO."""
    text = compiled.as_text()
    return sum(
        block.count("\n")
        for block in re.split(r"\n(?=\S)", text)
        if block.startswith("%fused_computation")
    )


def build(name, system, y0, kw, key):
    """(compiled run, compile seconds, fused instructions, Newton statistics, final states)."""
    method = METHODS[name]()

    def run(key):
        return sj.simulate(system, y0, key=key, method=method, **kw).ys

    compiled, seconds = _common.compile_timed(run, key)
    stats = sj.simulate(system, y0, key=key, method=method, newton_stats=True, **kw).stats
    stats = {k: float(stats[k]) for k in ("newton_iterations_mean", "newton_iterations_max")}
    return compiled, seconds, fused_instructions(compiled), stats, np.asarray(compiled(key))


def main(argv=None):
    parser = _common.parser(__doc__, "50 samples x 64 steps, 2 rounds")
    parser.add_argument("--rounds", type=int, default=9, help="alternated timing rounds")
    args = parser.parse_args(argv)
    n_samples, t1, rounds = (50, 64 * 2.0**-9, 2) if args.fast else (500, 1.0, args.rounds)
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    kw = dict(t1=t1, dt=2.0**-9, n_samples=n_samples)
    key = jax.random.key(0)
    cases = {name: build(name, system, y0, kw, key) for name in METHODS}
    kernel = newton.one_kernel
    newton.one_kernel = lambda *xs: xs  # the loop as it was, traced afresh
    jax.clear_caches()
    try:
        for name in WITHOUT:
            cases[f"{name}, no one_kernel"] = build(name, system, y0, kw, key)
    finally:
        newton.one_kernel = kernel
        jax.clear_caches()
    times = {name: [] for name in cases}
    for r in range(rounds):  # alternated, so that the machine's drift hits every case alike
        k = jax.random.key(r + 1)
        for name, case in cases.items():
            start = time.perf_counter()
            jax.block_until_ready(case[0](k))
            times[name].append(time.perf_counter() - start)
    steps = n_samples * round(t1 / kw["dt"])
    base = statistics.median(times[BASE])
    rows = []
    for name, (_, compile_s, fused, stats, ys) in cases.items():
        plain = name.split(",")[0]
        med = statistics.median(times[name])
        rows.append(
            {
                "method": name,
                "compile_s": compile_s,
                "median_ms": 1e3 * med,
                "min_ms": 1e3 * min(times[name]),
                "ns_per_sample_step": 1e9 * med / steps,
                "x_midpoint": med / base,
                "fused_instructions": fused,
                **stats,
                "max_diff_to_kernel": float(np.max(np.abs(ys - cases[plain][4]))),
            }
        )
    results = _common.Output(args.out)
    head = (
        f"`simulate` of the paper's body, {n_samples} samples x {round(t1 / kw['dt'])} steps of "
        f"h = 2^-9, float64, {rounds} alternated rounds."
    )
    table = _common.markdown_table(
        rows,
        list(rows[0]),
        {
            "compile_s": ".2f",
            "median_ms": ".1f",
            "min_ms": ".1f",
            "ns_per_sample_step": ".0f",
            "x_midpoint": ".2f",
            "newton_iterations_mean": ".3f",
            "max_diff_to_kernel": ".1e",
        },
    )
    print(f"{results.measured_on()}: {head}\n\n{table}")
    results.json("newton_fusion", {"rows": rows})
    results.markdown("newton_fusion", table, f": {head}")


if __name__ == "__main__":
    main()
