"""`slps-jax paper`: the paper's Figures 4.1-4.4 and a results table, with its parameters.

Liu & Wang, Section 4.4: I = (√2 + √2/1.51, √2 − 0.51·√2/1.51, 1), c = 0.2,
y0 = (0.7, 0.7, 0). The exact solution y(t) = φ_{t + cW(t)}(y0) replaces the paper's
"midpoint rule with h = 1e-5" reference: it is exact for every Brownian path.
"""

from __future__ import annotations

import concurrent.futures
import json
import math
import os
import sys
import time
from typing import Any

from .._studies.convergence import order_text


def _settings(fast) -> dict[str, Any]:
    if fast:
        return dict(
            n_samples=100,
            levels=[5, 6, 7],
            path_t1=5.0,
            path_dt=1e-2,
            drift_t1=20.0,
            drift_dt=1e-2,
            sphere_t1=20.0,
        )
    return dict(
        n_samples=500,
        levels=[5, 6, 7, 8, 9],
        path_t1=10.0,
        path_dt=1e-2,
        drift_t1=200.0,
        drift_dt=1e-2,
        sphere_t1=50.0,
    )


def _path(system, y0, method, dW, dt, every):
    import slps_jax as sj

    return sj.integrate(
        system, y0, dW, dt, method=method, save_every=every, failures=sj.Failures(throw=False)
    )


def _exact_paths(system, y0, *parts):
    """The exact paths on the increments of each `(dW, dt)` of `parts`, at every step: one
    evaluation of the closed-form flow for all of them (one compilation)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import slps_jax as sj

    ws = [jnp.concatenate([jnp.zeros(1, dW.dtype), jnp.cumsum(dW)]) for dW, _ in parts]
    ts = [jnp.arange(w.shape[0], dtype=w.dtype) * dt for w, (_, dt) in zip(ws, parts)]
    ys = jax.vmap(lambda ti, wi: sj.exact_solution(system, y0, ti, wi))(
        jnp.concatenate(ts), jnp.concatenate(ws)
    )
    return jnp.split(ys, np.cumsum([w.shape[0] for w in ws])[:-1])


def paper_methods():
    """The methods `slps-jax paper` and `summary` compare, in their order: the paper's scheme
    (42), the implicit midpoint rule, the Strang splitting and Euler–Maruyama."""
    import slps_jax as sj

    return {
        "LiePoisson": sj.LiePoisson(),
        "Midpoint": sj.Midpoint(),
        "Strang": sj.Strang(),
        "EulerMaruyama": sj.EulerMaruyama(),
    }


def run(out_dir="paper-output", fast=False, seed=0, stream=None):
    """Reproduce Figures 4.1-4.4 into `out_dir`; write `results.json` and `results.md`
    (and print the table to `stream`, default `sys.stdout` at call time)."""
    stream = sys.stdout if stream is None else stream
    import jax
    import jax.numpy as jnp
    import numpy as np

    import slps_jax as sj

    from .._support.progress import advance, progress_bar

    os.makedirs(out_dir, exist_ok=True)
    cfg = _settings(fast)
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    key = jax.random.key(seed)
    methods = paper_methods()
    colors = {
        "LiePoisson": "C0",
        "Midpoint": "C2",
        "Strang": "C1",
        "EulerMaruyama": "C3",
        "exact": "k",
    }
    progress = progress_bar(3 + len(methods) + 1, "slps-jax paper", unit="part")
    results = {
        "settings": {
            **cfg,
            "seed": seed,
            "inertia": np.asarray(system.inertia).tolist(),
            "c": float(np.asarray(system.c)),
            "y0": list(sj.PAPER_Y0),
            "truncate_k": 4,
            "dtype": str(y0.dtype),
        },
        "wall_seconds": {},
    }
    t_start = time.perf_counter()

    # Fourteen independent programs: the paths of Figures 4.1-4.3 and the convergence studies
    # of Figure 4.4, compiled and run by two threads (XLA compiles without the GIL, so the
    # two cores compile at once); the figures of the paths are drawn while the studies run.
    t0 = time.perf_counter()
    runs = {}
    dt41, n41 = cfg["path_dt"], int(round(cfg["path_t1"] / cfg["path_dt"]))
    dW41 = sj.BrownianMotion().increments(jax.random.fold_in(key, 1), n41, dt41)
    runs["4.1", "LiePoisson"] = (_path, (system, y0, methods["LiePoisson"], dW41, dt41, 1))
    dt42, n42 = cfg["drift_dt"], int(round(cfg["drift_t1"] / cfg["drift_dt"]))
    every42 = max(1, n42 // 400)
    dW42 = sj.BrownianMotion().increments(jax.random.fold_in(key, 2), n42, dt42)
    for name, method in methods.items():
        runs["4.2", name] = (_path, (system, y0, method, dW42, dt42, every42))
    dt43, n43 = 1e-2, int(round(cfg["sphere_t1"] / 1e-2))
    dW43 = sj.BrownianMotion().increments(jax.random.fold_in(key, 3), n43, dt43)
    for name in ("LiePoisson", "EulerMaruyama"):
        runs["4.3", name] = (_path, (system, y0, methods[name], dW43, dt43, 1))
    runs["4.1 and 4.3", "exact"] = (_exact_paths, (system, y0, (dW41, dt41), (dW43, dt43)))
    # Figure 4.4: RMS error at T = 1 against h, n_samples samples, exact reference.
    dts = [2.0**-k for k in cfg["levels"]]
    studies = {name: {name: method} for name, method in methods.items()}
    studies["Exact"] = {"Exact": sj.Exact()}
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=2)
    try:
        futures = {k: pool.submit(fn, *args) for k, (fn, args) in runs.items()}
        study_futures = {
            name: pool.submit(
                sj.strong_convergence,
                system,
                y0,
                t1=1.0,
                dts=dts,
                n_samples=cfg["n_samples"],
                key=key,
                methods=m,
            )
            for name, m in studies.items()
        }
        import matplotlib  # while the pool compiles

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        paths = {k: f.result() for k, f in futures.items()}
        paths["4.1", "exact"], paths["4.3", "exact"] = paths.pop(("4.1 and 4.3", "exact"))
        paths = {k: np.asarray(p) for k, p in paths.items()}
        results["wall_seconds"]["paths_fig4_1_to_4_3"] = time.perf_counter() - t0

        # Figure 4.1: one sample path, scheme (42) at h = 1e-2 against the exact path.
        t0 = time.perf_counter()
        dt, n = dt41, n41
        ys, ye = paths["4.1", "LiePoisson"], paths["4.1", "exact"]
        ts = np.arange(n + 1) * dt
        # the two paths overlap at this scale: a fourth panel shows their distance, per time
        # the largest component's (its maximum is the deviation in the title)
        fig, axes = plt.subplots(
            4,
            1,
            figsize=(7, 8),
            sharex=True,
            layout="constrained",
            gridspec_kw={"height_ratios": [1, 1, 1, 1.3]},
        )
        for i, ax in enumerate(axes[:3]):
            ax.plot(
                ts, ye[:, i], color="k", lw=2.2, alpha=0.35, label=r"exact $\varphi_{t+cW(t)}(y_0)$"
            )
            ax.plot(
                ts,
                ys[:, i],
                color=colors["LiePoisson"],
                lw=1.0,
                ls="--",
                label=f"LiePoisson, $h = {dt:g}$",
            )
            ax.set_ylabel(f"$y_{i + 1}$")
        dev = np.abs(ys - ye).max(axis=1)
        ax = axes[3]
        ax.semilogy(ts[1:], dev[1:], color=colors["LiePoisson"], lw=0.9)  # 0 at t = 0
        ax.axhline(dev.max(), color="0.5", ls=":", lw=1)
        ax.text(
            ts[-1],
            dev.max(),
            f"max {dev.max():.1e} ",
            ha="right",
            va="bottom",
            fontsize=8,
            color="0.3",
        )
        ax.set_ylim(top=4 * dev.max())
        ax.set_ylabel(r"error $\|y_h(t) - y(t)\|_\infty$")
        ax.grid(True, which="major", alpha=0.3)
        ax.set_xlabel("time $t$")
        axes[0].legend(
            loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=2, fontsize=9, frameon=False
        )
        fig.suptitle(f"Fig. 4.1: one sample path (max deviation {dev.max():.1e})")
        fig.savefig(os.path.join(out_dir, "fig4_1_sample_path.png"), dpi=110)
        plt.close(fig)
        results["fig4_1"] = {"h": dt, "t1": cfg["path_t1"], "max_abs_deviation": float(dev.max())}
        results["wall_seconds"]["fig4_1"] = time.perf_counter() - t0
        advance(progress, "Fig 4.1 sample path")

        # Figure 4.2: Casimir and Hamiltonian errors along time.
        t0 = time.perf_counter()
        dt, n, every = dt42, n42, every42
        ts = np.arange(0, n + 1, every) * dt
        c0, h0 = float(system.casimir(y0)), float(system.hamiltonian(y0))
        fig, (ax_c, ax_h) = plt.subplots(1, 2, figsize=(11, 4.5), layout="constrained")
        drift = {}
        for name in methods:
            ys = paths["4.2", name]
            dc = np.abs(np.asarray(system.casimir(ys)) / c0 - 1)
            dh = np.abs(np.asarray(system.hamiltonian(ys)) / h0 - 1)
            drift[name] = {"casimir_max": float(dc.max()), "energy_max": float(dh.max())}
            floor = 1e-17
            ax_c.semilogy(ts, np.maximum(dc, floor), color=colors[name], label=name)
            ax_h.semilogy(ts, np.maximum(dh, floor), color=colors[name], label=name)
        for ax, what in (
            (ax_c, "Casimir $|C(y_n)/C(y_0) - 1|$"),
            (ax_h, "Hamiltonian $|H(y_n)/H(y_0) - 1|$"),
        ):
            ax.set_xlabel("time t")
            ax.set_ylabel("relative error")
            ax.set_title(what, fontsize=10)
            ax.set_ylim(2e-18, 1e2)  # the floor 1e-17 inside the frame, not on its edge
            ax.grid(True, which="major", alpha=0.3)
        # one legend for both panels, below them: inside, it covered the curves
        fig.legend(
            *ax_c.get_legend_handles_labels(),
            loc="outside lower center",
            ncol=len(methods),
            fontsize=9,
            frameon=False,
        )
        fig.suptitle(
            f"Fig. 4.2: invariants along one path, h = {dt:g} (values below 1e-17 drawn at 1e-17)"
        )
        fig.savefig(os.path.join(out_dir, "fig4_2_invariants.png"), dpi=110)
        plt.close(fig)
        results["fig4_2"] = {"h": dt, "t1": cfg["drift_t1"], "drift": drift}
        results["wall_seconds"]["fig4_2"] = time.perf_counter() - t0
        advance(progress, "Fig 4.2 invariants")

        # Figure 4.3: phase trajectories on the sphere |y| = |y0|.
        t0 = time.perf_counter()
        dt = dt43
        paths = {name: paths["4.3", name] for name in ("LiePoisson", "EulerMaruyama", "exact")}
        fig = plt.figure(figsize=(13, 5.2), layout="constrained")
        r0 = float(np.linalg.norm(y0))
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 37), np.linspace(0, np.pi, 19))
        sphere = r0 * np.cos(u) * np.sin(v), r0 * np.sin(u) * np.sin(v), r0 * np.cos(v)
        lim = 1.05 * max(r0, *(np.abs(p).max() for p in paths.values()))  # one scale for all
        tick = float(f"{lim / 1.05:.1g}")
        for k, (name, p) in enumerate(paths.items()):
            ax = fig.add_subplot(1, 3, k + 1, projection="3d")
            ax.plot_surface(*sphere, color="C0", alpha=0.08, lw=0, shade=False)
            ax.plot_wireframe(*sphere, color="0.45", lw=0.3, alpha=0.35)
            ax.plot(p[:, 0], p[:, 1], p[:, 2], color=colors[name], lw=0.8)
            ax.scatter(*p[-1], color=colors[name], s=18, depthshade=False)  # the final state
            r_end = float(np.linalg.norm(p[-1]))
            ax.set_title(
                f"{name}"
                + ("" if name == "exact" else f", $h = {dt:g}$")
                + f"\nfinal $|y|$ = {r_end:.6f}, $|y|/|y_0| - 1$ = {r_end / r0 - 1:.1e}",
                fontsize=10,
            )
            ax.set_xlabel("$y_1$", labelpad=-4)
            ax.set_ylabel("$y_2$", labelpad=-4)
            ax.set_zlabel("$y_3$", labelpad=-4)
            for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
                axis.set_ticks([-tick, 0, tick])
                axis.set_tick_params(labelsize=8, pad=-2)
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_zlim(-lim, lim)
            ax.set_box_aspect((1, 1, 1))  # a sphere looks like one
        fig.suptitle(
            f"Fig. 4.3: phase trajectories, $t \\in [0, {cfg['sphere_t1']:g}]$, on the "
            f"sphere $|y| = |y_0| = {r0:.6f}$ (dot: the final state)"
        )
        fig.savefig(os.path.join(out_dir, "fig4_3_phase_sphere.png"), dpi=110)
        plt.close(fig)
        results["fig4_3"] = {
            name: {"final_norm": float(np.linalg.norm(p[-1]))} for name, p in paths.items()
        }
        results["wall_seconds"]["fig4_3"] = time.perf_counter() - t0
        advance(progress, "Fig 4.3 phase trajectories")

        # Figure 4.4: the studies, started with the paths, as they finish.
        t0 = time.perf_counter()
        conv = {}
        for name in methods:
            conv[name] = study_futures[name].result()
            advance(progress, f"Fig 4.4 {name}")
        exact_err = study_futures["Exact"].result()
        advance(progress, "Fig 4.4 Exact")
        fig, ax = plt.subplots(figsize=(9.5, 5), layout="constrained")
        hs = np.asarray(dts)
        for name, res in conv.items():
            e, se = res.errors[name], res.stderr[name]
            ax.errorbar(
                hs,
                e,
                yerr=2 * se,
                marker="o",
                ms=4,
                capsize=2,
                color=colors[name],
                label=f"{name}: slope {order_text(res.order[name], res.order_stderr[name])}",
            )
        # the largest bar relative to its error, for the title: at 500 samples most bars are
        # shorter than the markers' radius and cannot be seen (15% at --fast's 100 samples)
        bar = max(float(np.max(2 * res.stderr[n] / res.errors[n])) for n, res in conv.items())
        anchor = conv["LiePoisson"].errors["LiePoisson"][0]
        for slope, ls in ((0.5, ":"), (1.0, "--")):
            ax.loglog(
                hs,
                anchor * 2 * (hs / hs[0]) ** slope,
                color="0.5",
                ls=ls,
                lw=1,
                label=f"reference slope {slope:g}",
            )
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("step size h")
        ax.set_ylabel("RMS error $(E|y_N - y(1)|^2)^{1/2}$ at T = 1")
        ax.set_title(
            f"Fig. 4.4: strong convergence, {cfg['n_samples']} samples, reference: exact solution\n"
            f"error bars: ±2 standard errors, at most ±{100 * bar:.2g}% of the error\n"
            "(a bar not seen is shorter than the marker's radius)",
            fontsize=10,
        )
        ax.grid(True, which="both", alpha=0.3)
        fig.legend(
            loc="outside right upper", fontsize=8
        )  # beside the axes: inside, it covered points
        fig.savefig(os.path.join(out_dir, "fig4_4_strong_order.png"), dpi=110)
        plt.close(fig)
        results["fig4_4"] = {
            "dts": dts,
            "methods": {
                name: {
                    "rms_error": res.errors[name].tolist(),
                    "stderr": res.stderr[name].tolist(),
                    "order": res.order[name],
                    "order_stderr": res.order_stderr[name],
                    "seconds": res.seconds[name],
                }
                for name, res in conv.items()
            },
            "exact_method_max_rms_error": float(exact_err.errors["Exact"].max()),
        }
        results["wall_seconds"]["fig4_4"] = time.perf_counter() - t0
    finally:
        # at once on an error; after the last result, nothing is left to cancel
        pool.shutdown(cancel_futures=True)
        progress.close()
    results["wall_seconds"]["total"] = time.perf_counter() - t_start

    md = _table(results, list(methods))
    with open(os.path.join(out_dir, "results.json"), "w") as f:
        json.dump(results, f, indent=2)
    with open(os.path.join(out_dir, "results.md"), "w") as f:
        f.write(md)
    stream.write("\n" + md)
    stream.write(f"\nFigures, results.json and results.md written to {out_dir}/\n")
    return results


def _table(results, names):
    f44, f42 = results["fig4_4"], results["fig4_2"]
    lines = [
        f"# slps-jax paper: results (seed {results['settings']['seed']}, "
        f"{results['settings']['n_samples']} samples, {results['settings']['dtype']})",
        "",
        f"Strong order at T = 1 fitted on h = {', '.join(f'2^{math.log2(h):.0f}' for h in f44['dts'])} "
        f"against the exact solution; invariant drift = max over t ≤ {f42['t1']:g} along one "
        f"path with h = {f42['h']:g}; seconds = the method's convergence runs, compilation included "
        f"(two of the run's programs compile or run at a time).",
        "",
        "| method | strong order | RMS error at h = "
        + f"2^{math.log2(f44['dts'][-1]):.0f}"
        + " | max rel. Casimir drift | max rel. energy drift | seconds |",
        "|---|---|---|---|---|---|",
    ]
    for n in names:
        m = f44["methods"][n]
        d = f42["drift"][n]
        lines.append(
            f"| {n} | {order_text(m['order'], m['order_stderr'])} | "
            f"{m['rms_error'][-1]:.3e} | {d['casimir_max']:.1e} | {d['energy_max']:.1e} | "
            f"{m['seconds']:.1f} |"
        )
    lines += [
        "",
        f"Exact sampler (`Exact`): largest RMS error {f44['exact_method_max_rms_error']:.1e} "
        "(round-off).",
        f"Total wall time {results['wall_seconds']['total']:.1f} s.",
        "",
    ]
    return "\n".join(lines)
