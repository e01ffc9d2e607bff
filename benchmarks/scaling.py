#!/usr/bin/env python
"""Scaling of `slps_jax.simulate` (final state only) with samples and steps, and its memory.

1. Run time against `n_samples` (10^2 ... 10^5) at a fixed 128 steps (h = 2^-7, T = 1).
2. Run time against `n_steps` (2^6 ... 2^12) at a fixed 1000 samples (h = 2^-7, T = n h).
   Each point: the first call (compile + run) and the median / min of >= 3 further calls of
   `simulate(...)` with `jax.block_until_ready` on `ys`; compile ~ first - median.
3. Peak memory of final-state-only runs as `n_steps` grows, two ways:
   (a) XLA's compiled memory analysis of `jax.jit(lambda key: simulate(..., key=key).ys)`
       (`.lower(key).compile().memory_analysis()`: temp + argument + output bytes);
   (b) a fresh Python process per configuration that imports, compiles and runs one
       `simulate`: its peak resident set size, both `ru_maxrss` (`resource.getrusage`,
       whole process, import included) and the rise of the peak during compile + run
       alone (Linux: `/proc/self/status` VmHWM after resetting it with `clear_refs`). The
       children are started by a small launcher process, because Linux carries a process'
       ru_maxrss over fork and exec: started from this process they would report its peak.
   Both are also measured for a control that materialises the increments (`vmap(integrate)`
   over `BrownianMotion().increments(key, n_steps, h, n_samples=...)`, Strang), which must grow: so a
   flat line means something. The script prints whether the runs stayed flat.

A configuration whose predicted run time (from the method's measured cost per sample-step)
exceeds `--max-call-s` (default 40 s) is skipped and listed as skipped, so the script ends in
minutes on 2 cores whatever the per-step cost is.

Writes `scaling.csv` (time sweeps), `scaling_memory.csv`, `scaling.json` and `scaling.png`.

    python benchmarks/scaling.py [--fast] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402

METHODS = {"LiePoisson": sj.LiePoisson(), "Strang": sj.Strang()}
DT = 2.0**-7
CONTROL = "Strang, materialised increments (control)"
RSS_NOISE_MB = 8.0


def run_simulate(method, n_steps, n_samples, seed=0):
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    sol = sj.simulate(
        system,
        y0,
        t1=n_steps * DT,
        dt=DT,
        n_samples=n_samples,
        key=jax.random.key(seed),
        method=METHODS[method],
        failures=sj.Failures(throw=False),
    )
    return jax.block_until_ready(sol.ys)


def time_point(method, n_steps, n_samples, repeats):
    start = time.perf_counter()
    ys = run_simulate(method, n_steps, n_samples)
    first = time.perf_counter() - start
    t_med, t_min, n_rep, ys = _common.time_call(
        lambda: run_simulate(method, n_steps, n_samples),
        repeats=repeats,
        min_total=0.3,
        warmup=False,
    )  # the first call warmed up
    assert ys.shape == (n_samples, 1, 3)
    finite = bool(jnp.all(jnp.isfinite(ys)))
    return {
        "method": method,
        "n_samples": n_samples,
        "n_steps": n_steps,
        "h": DT,
        "first_call_s": first,
        "time_median_s": t_med,
        "time_min_s": t_min,
        "n_repeats": n_rep,
        "compile_est_s": max(first - t_med, 0.0),
        "ns_per_sample_step": t_med / (n_samples * n_steps) * 1e9,
        "finite": finite,
    }


def compiled_memory(method, n_steps, n_samples):
    """XLA's memory analysis of one compiled final-state-only ensemble run (bytes)."""
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    if method == CONTROL:

        def fn(key):
            dW = sj.BrownianMotion().increments(key, n_steps, DT, n_samples=n_samples)
            return jax.vmap(
                lambda d: sj.integrate(
                    system, y0, d, DT, method=sj.Strang(), failures=sj.Failures(throw=False)
                )
            )(dW)
    else:

        def fn(key):
            return sj.simulate(
                system,
                y0,
                t1=n_steps * DT,
                dt=DT,
                n_samples=n_samples,
                key=key,
                method=METHODS[method],
                failures=sj.Failures(throw=False),
            ).ys

    m = jax.jit(fn).lower(jax.random.key(0)).compile().memory_analysis()
    if m is None:
        return None
    out = {
        k: int(getattr(m, k + "_size_in_bytes", 0) or 0)
        for k in ("temp", "argument", "output", "alias")
    }
    out["total"] = out["temp"] + out["argument"] + out["output"] - out["alias"]
    return out


def _status_kb(field):
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak():
    """Reset VmHWM to the current RSS (Linux >= 4.0); False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def child_rss(method, n_steps, n_samples):
    """In a fresh process: peak RSS of compile + one run, and of the whole process (kB)."""
    inherited = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    key = jax.random.key(0)
    jax.block_until_ready(jnp.zeros(3) + 1.0)  # backend up before the baseline
    baseline = _status_kb("VmRSS")
    reset = _reset_peak()
    start = time.perf_counter()
    if method == CONTROL:
        dW = sj.BrownianMotion().increments(key, n_steps, DT, n_samples=n_samples)
        ys = jax.jit(
            jax.vmap(
                lambda d: sj.integrate(
                    system, y0, d, DT, method=sj.Strang(), failures=sj.Failures(throw=False)
                )
            )
        )(dW)
        ys = jax.block_until_ready(ys)
    else:
        ys = run_simulate(method, n_steps, n_samples)
    seconds = time.perf_counter() - start
    hwm = _status_kb("VmHWM")
    print(
        json.dumps(
            {
                "ru_maxrss_start_kb": inherited,
                "ru_maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
                "run_peak_rise_kb": (hwm - baseline) if (reset and hwm and baseline) else None,
                "seconds": seconds,
                "finite": bool(jnp.all(jnp.isfinite(ys))),
            }
        )
    )


# Linux keeps a process' peak RSS (ru_maxrss) across fork and exec, so a child started from
# this process, after its large runs, would report *our* peak. The children are therefore
# started by a small launcher process, itself started at the beginning of main().
_LAUNCHER = """
import json, subprocess, sys
for line in sys.stdin:
    p = subprocess.run(json.loads(line), capture_output=True, text=True)
    print(json.dumps({"rc": p.returncode, "out": p.stdout, "err": p.stderr[-3000:]}), flush=True)
"""


class Launcher:
    def __init__(self):
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _LAUNCHER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )

    def run(self, cmd):
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def fresh_rss(launcher, method, n_steps, n_samples):
    cmd = [
        sys.executable,
        os.path.abspath(__file__),
        "--child-rss",
        method,
        str(n_steps),
        str(n_samples),
    ]
    out = launcher.run(cmd)
    if out["rc"]:
        raise RuntimeError(f"RSS child failed:\n{out['err']}")
    return json.loads(out["out"].strip().splitlines()[-1])


def flat(values, tolerance):
    return max(values) - min(values) <= tolerance


def plot(time_rows, mem_rows, path, fixed_steps, fixed_samples):
    plt = _common.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    methods = list(dict.fromkeys(r["method"] for r in time_rows))
    for name in methods:
        pts = sorted(
            {
                r["n_samples"]: r
                for r in time_rows
                if r["method"] == name and r["n_steps"] == fixed_steps
            }.values(),
            key=lambda r: r["n_samples"],
        )
        axes[0].plot(
            [p["n_samples"] for p in pts], [p["time_median_s"] for p in pts], "o-", label=name
        )
        pts = sorted(
            {
                r["n_steps"]: r
                for r in time_rows
                if r["method"] == name and r["n_samples"] == fixed_samples
            }.values(),
            key=lambda r: r["n_steps"],
        )
        axes[1].plot(
            [p["n_steps"] for p in pts], [p["time_median_s"] for p in pts], "o-", label=name
        )
    axes[0].set_xlabel("n_samples")
    axes[0].set_xscale("log")
    axes[0].set_title(f"simulate, {fixed_steps} steps (h = 2^-7)", fontsize=10)
    axes[1].set_xlabel("n_steps (h = 2^-7, T = n h)")
    axes[1].set_xscale("log", base=2)
    axes[1].set_title(f"simulate, {fixed_samples} samples", fontsize=10)
    for ax in axes[:2]:
        ax.set_ylabel("run time [s] (median, compile excluded)")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    ax = axes[2]
    for i, name in enumerate(dict.fromkeys(r["method"] for r in mem_rows)):
        color = plt.get_cmap("tab10")(i)
        pts = sorted((r for r in mem_rows if r["method"] == name), key=lambda r: r["n_steps"])
        xla = [
            (p["n_steps"], p["xla_total_bytes"] / 2**20)
            for p in pts
            if p["xla_total_bytes"] is not None
        ]
        if xla:
            ax.plot(*zip(*xla), "o-", color=color, label=f"{name}: XLA temp+arg+out")
        rss = [
            (p["n_steps"], p["rss_run_rise_mb"]) for p in pts if p["rss_run_rise_mb"] is not None
        ]
        if rss:
            ax.plot(
                *zip(*rss),
                "s--",
                color=color,
                label=f"{name}: peak RSS rise in compile+run (fresh process)",
            )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("n_steps (final state only)")
    ax.set_ylabel("memory [MiB]")
    ax.set_title(f"peak memory, {fixed_samples} samples", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse(argv):
    p = _common.parser(
        __doc__,
        "tiny size for the test suite (Strang only, 50-100 samples, 32-64 steps)",
    )
    p.add_argument("--methods", default=None, help="comma-separated (LiePoisson,Strang)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument(
        "--max-call-s",
        type=float,
        default=40.0,
        help="skip configurations predicted to take longer per call",
    )
    p.add_argument("--no-rss", action="store_true", help="skip the fresh-process RSS runs")
    p.add_argument(
        "--child-rss", nargs=3, metavar=("METHOD", "N_STEPS", "N_SAMPLES"), help=argparse.SUPPRESS
    )
    return p.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    if args.child_rss:
        method, n_steps, n_samples = args.child_rss
        child_rss(method, int(n_steps), int(n_samples))
        return 0
    launcher = None if args.no_rss else Launcher()  # while this process is still small
    fast = args.fast
    methods = args.methods.split(",") if args.methods else (["Strang"] if fast else list(METHODS))
    if fast:
        samples_sweep, fixed_steps = [50, 100], 32
        steps_sweep, fixed_samples = [32, 64], 50
        mem_steps, rss_steps = [64, 256, 1024], [64, 256]
    else:
        samples_sweep, fixed_steps = [10**2, 10**3, 10**4, 10**5], 128
        steps_sweep, fixed_samples = [2**k for k in range(6, 13)], 1000
        mem_steps, rss_steps = [2**k for k in range(6, 13)], [2**6, 2**8, 2**10, 2**12]
    results = _common.Output(args.out)
    info = results.info
    print(
        f"scaling of simulate (final state only), h = 2^-7: {results.measured_on()}; "
        "skipping calls predicted "
        f"> {args.max_call_s:g} s"
    )

    time_rows, skipped, done, cost = [], [], set(), {}
    configs = sorted(
        {(s, fixed_steps) for s in samples_sweep} | {(fixed_samples, n) for n in steps_sweep},
        key=lambda c: c[0] * c[1],
    )
    for method in methods:
        for n_samples, n_steps in configs:
            if (method, n_samples, n_steps) in done:
                continue
            done.add((method, n_samples, n_steps))
            predicted = cost.get(method, 0.0) * n_samples * n_steps
            if predicted > args.max_call_s:
                skipped.append(
                    {
                        "method": method,
                        "n_samples": n_samples,
                        "n_steps": n_steps,
                        "predicted_s": predicted,
                    }
                )
                print(
                    f"  {method:10s} samples {n_samples:7d} steps {n_steps:5d}: skipped "
                    f"(predicted {predicted:.0f} s per call)"
                )
                continue
            row = time_point(method, n_steps, n_samples, args.repeats)
            cost[method] = row["time_median_s"] / (n_samples * n_steps)
            time_rows.append(row)
            print(
                f"  {method:10s} samples {n_samples:7d} steps {n_steps:5d}: "
                f"{row['time_median_s']:9.4f} s (min {row['time_min_s']:.4f}, "
                f"n={row['n_repeats']}), first call {row['first_call_s']:.2f} s, "
                f"{row['ns_per_sample_step']:8.1f} ns/sample-step"
            )

    mem_rows = []
    for method in methods + [CONTROL]:
        for n_steps in mem_steps:
            xla = compiled_memory(method, n_steps, fixed_samples)
            rss, note = None, ""
            if not args.no_rss and n_steps in rss_steps:
                predicted = cost.get(method, 0.0) * fixed_samples * n_steps
                if predicted > args.max_call_s:
                    note = f"RSS skipped (predicted {predicted:.0f} s)"
                else:
                    rss = fresh_rss(launcher, method, n_steps, fixed_samples)
            rise = (
                None
                if rss is None or rss["run_peak_rise_kb"] is None
                else rss["run_peak_rise_kb"] / 1024
            )
            row = {
                "method": method,
                "n_samples": fixed_samples,
                "n_steps": n_steps,
                "xla_temp_bytes": None if xla is None else xla["temp"],
                "xla_total_bytes": None if xla is None else xla["total"],
                "ru_maxrss_mb": None if rss is None else rss["ru_maxrss_kb"] / 1024,
                "ru_maxrss_at_start_mb": None if rss is None else rss["ru_maxrss_start_kb"] / 1024,
                "rss_run_rise_mb": rise,
                "materialised_increments_mb": fixed_samples * n_steps * 8 / 2**20,
                "note": note,
            }
            mem_rows.append(row)
            print(
                f"  memory {method:42s} steps {n_steps:5d}: XLA "
                + ("n/a" if xla is None else f"{xla['total'] / 2**20:8.3f} MiB")
                + (
                    ""
                    if rss is None
                    else f", ru_maxrss {row['ru_maxrss_mb']:7.1f} MiB "
                    f"(at start {row['ru_maxrss_at_start_mb']:.0f})"
                )
                + ("" if rise is None else f", peak rise in compile+run {rise:7.1f} MiB")
                + (f", {note}" if note else "")
            )

    # Flatness: from the smallest to the largest n_steps, a final-state-only run may grow by
    # no more than a small part of what merely storing the increments would take.
    def growth(method, key):
        """Signed: at the largest n_steps minus at the smallest (compilation of a short loop
        can take more memory than of a long one, so max - min would overstate growth)."""
        pts = sorted(
            (r["n_steps"], r[key]) for r in mem_rows if r["method"] == method and r[key] is not None
        )
        return (pts[-1][1] - pts[0][1]) if len(pts) > 1 else None

    verdict = {}
    for method in methods + [CONTROL]:
        steps_x = [
            r["n_steps"]
            for r in mem_rows
            if r["method"] == method and r["xla_total_bytes"] is not None
        ]
        steps_r = [
            r["n_steps"]
            for r in mem_rows
            if r["method"] == method and r["rss_run_rise_mb"] is not None
        ]
        xg = growth(method, "xla_total_bytes")
        rg = growth(method, "rss_run_rise_mb")
        # materialised increments over the measured range, in MiB
        x_ref = fixed_samples * (max(steps_x) - min(steps_x)) * 8 / 2**20 if xg is not None else 0
        r_ref = fixed_samples * (max(steps_r) - min(steps_r)) * 8 / 2**20 if rg is not None else 0
        verdict[method] = {
            "xla_growth_mb": None if xg is None else xg / 2**20,
            "xla_flat": None if xg is None else xg / 2**20 <= max(0.05 * x_ref, 1e-3),
            "rss_growth_mb": rg,
            "rss_range_steps": [min(steps_r), max(steps_r)] if steps_r else None,
            # fresh processes differ by a few MiB in what compilation takes: 8 MiB floor
            "rss_flat": None if rg is None else rg <= max(0.25 * r_ref, RSS_NOISE_MB),
            "materialised_growth_mb": r_ref if rg is not None else x_ref,
        }
    control = verdict.pop(CONTROL)

    results.csv("scaling", time_rows)
    results.csv("scaling_memory", mem_rows)
    results.json(
        "scaling",
        {
            "machine": info,
            "h": DT,
            "fixed_steps": fixed_steps,
            "fixed_samples": fixed_samples,
            "max_call_s": args.max_call_s,
            "time": time_rows,
            "skipped": skipped,
            "memory": mem_rows,
            "memory_flat": verdict,
            "control": control,
            "control_growth_mb": control["xla_growth_mb"],
            "memory_method": "XLA compiled memory_analysis (temp+argument+output-alias) of "
            "jit(simulate(...).ys); fresh process per configuration (started by "
            "a small launcher, since ru_maxrss survives fork/exec): ru_maxrss "
            "(whole process, import included) and the rise of VmHWM during "
            "compile+run after resetting it via /proc/self/clear_refs; growth = "
            "value at the largest n_steps minus value at the smallest",
            "note": "noisy numbers from a shared 2-core machine; medians of repeated calls",
        },
    )
    plot(time_rows, mem_rows, os.path.join(args.out, "scaling.png"), fixed_steps, fixed_samples)

    print(
        f"\nmemory of final-state-only runs as n_steps grows {min(mem_steps)} -> "
        f"{max(mem_steps)} ({fixed_samples} samples):"
    )
    for method, v in list(verdict.items()) + [(CONTROL, control)]:
        line = f"  {method}: XLA growth {v['xla_growth_mb']:.3f} MiB"
        if v["rss_growth_mb"] is not None:
            line += (
                f"; RSS peak-rise growth {v['rss_growth_mb']:.1f} MiB over n_steps "
                f"{v['rss_range_steps'][0]}..{v['rss_range_steps'][1]}"
            )
        line += f" (storing the increments: {v['materialised_growth_mb']:.1f} MiB)"
        if method != CONTROL:
            line += " -> " + (
                "flat" if v["xla_flat"] and v["rss_flat"] is not False else "NOT flat"
            )
        print(line)
    print(
        f"  (growth: value at the largest n_steps minus at the smallest; flat: XLA growth <= "
        f"5% of the increments' size, RSS growth <= max(25% of it, {RSS_NOISE_MB:g} MiB of "
        f"process-to-process noise))"
    )
    all_flat = all(
        v["xla_flat"] is not False and v["rss_flat"] is not False for v in verdict.values()
    )
    print("memory stayed flat as n_steps grew: " + ("YES" if all_flat else "NO"))
    if skipped:
        print(f"skipped {len(skipped)} configurations predicted > {args.max_call_s:g} s per call")
    if launcher is not None:
        launcher.close()
    print(f"wrote {args.out}/scaling.{{csv,json,png}} and scaling_memory.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
