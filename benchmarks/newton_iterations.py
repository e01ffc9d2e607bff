#!/usr/bin/env python
"""Distribution of LiePoisson's Newton updates per sample-step on the paper's setup.

For each h = 2^-5 ... 2^-9 (500 samples, T = 1, the paper's truncated increments), the
ensemble is simulated with `save_every=1`, and every step is solved again from its saved
state and increment to read its `StepInfo`: updates used (usually 3, then the fourth
residual passes the test), the final residual, and which steps needed more. Under `vmap` the
Newton loop runs for the whole batch as long as its slowest sample needs, so the fraction of
*time steps* in which some sample needed more than 3 updates is reported too: that is what
the slow samples cost.

Writes `newton_iterations.csv` (one row per h and iteration count), `newton_iterations.json`
and `newton_iterations.png`.

    python benchmarks/newton_iterations.py [--fast] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import sys  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402

USUAL = 3  # Newton updates that solve almost every step of the paper's setup


def step_infos(system, method, ys, dW, dt):
    """`StepInfo` of every step `ys[:, n] -> ys[:, n + 1]` with increment `dW[:, n]`."""
    y_n = ys[:, :-1].reshape(-1, 3)
    step = jax.jit(jax.vmap(lambda y, w: method.step(system, y, jnp.asarray(dt, y.dtype), w)))
    y_next, info = step(y_n, dW.reshape(-1))
    return np.asarray(y_next).reshape(ys[:, 1:].shape), info


def main(argv=None):
    parser = _common.parser(__doc__, "100 samples, h = 2^-5 ... 2^-7")
    args = parser.parse_args(argv)
    results = _common.Output(args.out)

    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    method = sj.LiePoisson()
    n_samples = 100 if args.fast else 500
    levels = [5, 6, 7] if args.fast else [5, 6, 7, 8, 9]
    key = jax.random.key(0)
    tol = 64 * float(jnp.finfo(y0.dtype).eps)
    rows, summary = (
        [],
        {
            "n_samples": n_samples,
            "usual_updates": USUAL,
            "tol": tol,
            "per_h": [],
        },
    )
    print(
        f"LiePoisson Newton updates per sample-step, paper's setup, {n_samples} samples, "
        f"T = 1 (usually {USUAL} updates, the fourth residual passing the test)\n"
    )
    print(
        "| h | mean | max | at most 3 updates | time steps where some sample needed more | max residual |\n"
        "|---|---|---|---|---|---|"
    )
    for k in levels:
        dt = 2.0**-k
        n_steps = 2**k
        sol = sj.simulate(
            system, y0, t1=1.0, dt=dt, n_samples=n_samples, key=key, method=method, save_every=1
        )
        dW = sj.BrownianMotion().increments(key, n_steps, dt, n_samples=n_samples)
        y_next, info = step_infos(system, method, sol.ys, dW, dt)
        # the re-solved steps reproduce the trajectory: the statistics are of the same steps
        assert np.max(np.abs(y_next - np.asarray(sol.ys[:, 1:]))) < 1e-13
        it = np.asarray(info.iterations).reshape(n_samples, n_steps)
        res = np.asarray(info.residual)
        assert np.all(np.asarray(info.ok))
        more_steps = float(np.mean(np.any(it > USUAL, axis=0)))
        counts = np.bincount(it.ravel())
        for n_it, count in enumerate(counts):
            if count:
                rows.append(
                    {
                        "h": dt,
                        "log2_h": -k,
                        "iterations": n_it,
                        "count": int(count),
                        "fraction": count / it.size,
                    }
                )
        entry = {
            "h": dt,
            "log2_h": -k,
            "mean": float(it.mean()),
            "max": int(it.max()),
            "fraction_at_most_usual": float(np.mean(it <= USUAL)),
            "fraction_time_steps_with_more": more_steps,
            "max_residual": float(res.max()),
        }
        summary["per_h"].append(entry)
        print(
            f"| 2^-{k} | {entry['mean']:.4f} | {entry['max']} | "
            f"{100 * entry['fraction_at_most_usual']:.3f} % | {100 * more_steps:.1f} % | "
            f"{entry['max_residual']:.1e} |"
        )

    results.csv("newton_iterations", rows)
    results.json("newton_iterations", summary)
    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4))
    width = 0.8 / len(levels)
    for i, k in enumerate(levels):
        pts = [r for r in rows if r["log2_h"] == -k]
        ax.bar(
            [r["iterations"] + (i - len(levels) / 2) * width for r in pts],
            [r["fraction"] for r in pts],
            width=width,
            label=f"h = 2^-{k}",
        )
    ax.set_yscale("log")
    ax.set_xlabel("Newton updates in one step")
    ax.set_ylabel("fraction of sample-steps")
    ax.set_title("LiePoisson: Newton updates per step, paper's setup")
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "newton_iterations.png"), dpi=120)
    print(f"\nwrote {args.out}/newton_iterations.{{csv,json,png}}")


if __name__ == "__main__":
    main()
