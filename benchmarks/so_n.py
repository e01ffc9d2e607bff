#!/usr/bin/env python
"""so(n)*: the generalised rigid body dY = [Y, Omega] (dt + c o dW), Y = J Omega + Omega J.

J = linspace(0.6, 2.3, n) (J = (0.6, 1.1, 1.7, 2.3) at n = 4), c = 0.4, Y0 a random skew
matrix of spectral norm 0.8 (seed 1), T = 1.

- Cost against n = 3, 4, 6, 8, 12, 16: run time per sample-step (median of >= 3 blocking
  calls after a warm-up; compile time on its own) of `jit(vmap(integrate))`, 32 samples x 32
  steps (h = 2^-5) on shared increments, for `LiePoisson` (both ways of solving, the chord
  iteration `"chord"`, its default, and `"newton"`),
  `IsospectralMidpoint` (`"newton"` and `"fixed_point"`), `Midpoint`, `Heun` and diffrax
  `Heun` (on the same increments; only with the `bench` extra). Also Newton updates per step.
- Work-precision at n = 4: RMS error at T (the norm of the pairing, |Y|^2 = sum_{i<j} Y_ij^2)
  against the time change Y(T) = phi_{T + c W(T)}(Y0) of `drift_flow`, 200 samples,
  h = 2^-3 ... 2^-7, against run time; fitted strong orders.
- Casimirs over 10^4 steps: so(6) with two linear (SALT) noises, h = 0.01, 8 paths: the
  largest relative drift of tr(Y^2), tr(Y^4), tr(Y^6) along the paths.
- Stress: so(4) and so(8), one noise c = 0.4 or three SALT noises of strength 0.4,
  ||Y0||_2 = 0.5, 0.9, 0.99, h = 2^-2 and 2^-4, T = 1, 200 samples: failed samples (flagged,
  frozen at their last good state) without and with `retry_substeps=4`, and non-finite
  entries (there must be none).

Writes `so_n.csv`, `so_n.json`, `so_n.md` into --out (default benchmarks/results) and the
figure `so_n.png` there.

    python benchmarks/so_n.py [--fast] [--out DIR]
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
import work_precision as wp  # noqa: E402  (its diffrax import is guarded)

import slps_jax as sj  # noqa: E402

C = 0.4
DIFFRAX_HEUN = "diffrax Heun"


def setup(n):
    j = jnp.asarray([0.6, 1.1, 1.7, 2.3]) if n == 4 else jnp.linspace(0.6, 2.3, n)
    a = np.random.default_rng(1).normal(size=(n, n))
    y0 = a - a.T
    return sj.GeneralisedRigidBody(j, c=C), jnp.asarray(0.8 * y0 / np.linalg.norm(y0, 2))


def methods(n):
    out = {
        "LiePoisson newton": sj.LiePoisson(iteration="newton"),
        "LiePoisson chord": sj.LiePoisson(iteration="chord"),
        "Isospectral newton": sj.IsospectralMidpoint(iteration="newton"),
        "Isospectral fixed point": sj.IsospectralMidpoint(iteration="fixed_point"),
        "Midpoint": sj.Midpoint(),
        "Heun": sj.Heun(),
    }
    if n >= 16:  # 11 ms per sample-step: the n(n-1)/2 tangents at every update
        del out["LiePoisson newton"]
    return out


def ours(system, y0, method, h):
    return lambda d: jax.vmap(
        lambda di: sj.integrate(system, y0, di, h, method=method, failures=sj.Failures(throw=False))
    )(d)


def diffrax_heun(system, y0, h, n_steps, h_fine):
    dfx = wp.dfx
    f = system.vector_field

    def fn(w):
        terms = dfx.MultiTerm(
            dfx.ODETerm(lambda t, y, a: f(y)),
            dfx.ControlTerm(lambda t, y, a: C * f(y), wp.IncrementPath(w, h_fine)),
        )
        sol = dfx.diffeqsolve(
            terms, dfx.Heun(), 0.0, n_steps * h, h, y0, max_steps=n_steps, throw=False
        )
        return sol.ys[-1]

    return lambda ws: jax.vmap(fn)(ws)


def newton_stats(system, y0, method, h, n_steps, n_samples):
    if method.__class__ in (sj.Heun,):
        return 0.0
    sol = sj.simulate(
        system,
        y0,
        t1=n_steps * h,
        dt=h,
        n_samples=n_samples,
        key=jax.random.key(0),
        method=method,
        newton_stats=True,
    )
    if int(sol.stats["n_failed"]):
        raise RuntimeError(f"{method}: samples failed; their frozen states are not data.")
    return float(sol.stats["newton_iterations_mean"])


def cost(ns, n_samples, n_steps, skipped=()):
    h = 1.0 / n_steps
    rows = []
    for n in ns:
        system, y0 = setup(n)
        dW = sj.BrownianMotion().increments(jax.random.key(n), n_steps, h, n_samples=n_samples)
        cumulative = jnp.concatenate([jnp.zeros((n_samples, 1)), jnp.cumsum(dW, axis=1)], 1)
        runs = {
            name: (ours(system, y0, m, h), dW[..., None])
            for name, m in methods(n).items()
            if name not in skipped
        }
        if wp.dfx is not None:
            runs[DIFFRAX_HEUN] = diffrax_heun(system, y0, h, n_steps, h), cumulative
        for name, (fn, arg) in runs.items():
            compiled, compile_s = _common.compile_timed(fn, arg)
            med, best, reps, y = _common.time_call(compiled, arg, repeats=3, min_total=0.3)
            its = (
                newton_stats(system, y0, methods(n)[name], h, n_steps, n_samples)
                if name in methods(n)
                else 0.0
            )
            rows.append(
                dict(
                    n=n,
                    unknowns=n * (n - 1) // 2,
                    method=name,
                    ns_per_sample_step=1e9 * med / (n_samples * n_steps),
                    time_min_s=best,
                    compile_s=compile_s,
                    newton_updates=its,
                )
            )
            print(
                f"n={n:2d} {name:22s} {rows[-1]['ns_per_sample_step']:12.0f} ns/sample-step"
                f"  compile {compile_s:5.2f} s  updates {its:.2f}",
                flush=True,
            )
    for row in rows:
        base = next(
            (
                r["ns_per_sample_step"]
                for r in rows
                if r["n"] == row["n"] and r["method"] == DIFFRAX_HEUN
            ),
            None,
        )
        row["vs_diffrax_heun"] = row["ns_per_sample_step"] / base if base else None
    return rows


def work_precision(ks, n_samples):
    system, y0 = setup(4)
    n_fine = 2 ** max(ks)
    dW = sj.BrownianMotion().increments(
        jax.random.key(4), n_fine, 1.0 / n_fine, n_samples=n_samples
    )
    w_t = np.asarray(jnp.sum(dW, axis=1))
    reference = sj.drift_flow(system, y0, 1.0 + C * w_t)
    cumulative = jnp.concatenate([jnp.zeros((n_samples, 1)), jnp.cumsum(dW, axis=1)], 1)
    named = {
        "LiePoisson": sj.LiePoisson(),
        "IsospectralMidpoint": sj.IsospectralMidpoint(),
        "Midpoint": sj.Midpoint(),
        "Heun": sj.Heun(),
    }
    rows = []
    for name in list(named) + ([DIFFRAX_HEUN] if wp.dfx is not None else []):
        for k in ks:
            n, h = 2**k, 2.0**-k
            if name in named:
                fn, arg = (
                    ours(system, y0, named[name], h),
                    dW.reshape(n_samples, n, -1).sum(2)[..., None],
                )
            else:
                fn, arg = diffrax_heun(system, y0, h, n, 1.0 / n_fine), cumulative
            compiled, compile_s = _common.compile_timed(fn, arg)
            med, _, _, y = _common.time_call(compiled, arg, repeats=3, min_total=0.3)
            err = float(jnp.sqrt(jnp.mean(sj.so(4).norm_sq(y - reference))))
            rows.append(
                dict(method=name, h=h, rms_error=err, time_median_s=med, compile_s=compile_s)
            )
            print(f"n=4 {name:20s} h=2^-{k}  rms {err:.3e}  run {med:.4f} s", flush=True)
    orders = {}
    for name in {r["method"] for r in rows}:
        pts = [r for r in rows if r["method"] == name]
        orders[name] = float(
            np.polyfit(np.log([r["h"] for r in pts]), np.log([r["rms_error"] for r in pts]), 1)[0]
        )
    return rows, orders


def casimirs(n_steps, n_paths):
    n = 6
    j = jnp.linspace(0.6, 2.3, n)
    chi = np.random.default_rng(2).normal(size=(2, n, n))
    chi = 0.3 * (chi - np.swapaxes(chi, 1, 2)) / np.sqrt(2 * n)
    system = sj.GeneralisedRigidBody(j, noise=sj.salt_noise(chi))
    a = np.random.default_rng(1).normal(size=(n, n))
    y0 = jnp.asarray(0.7 * (a - a.T) / np.linalg.norm(a - a.T, 2))
    h = 0.01
    dW = sj.BrownianMotion().increments(
        jax.random.key(6), n_steps, h, n_samples=n_paths, n_noises=2
    )
    c0 = np.asarray(sj.so(n).casimirs(y0))
    rows = []
    for name, m in {
        "LiePoisson": sj.LiePoisson(),
        "IsospectralMidpoint": sj.IsospectralMidpoint(),
        "Midpoint": sj.Midpoint(),
        "Heun": sj.Heun(),
    }.items():
        ys = jax.jit(
            jax.vmap(
                lambda d: sj.integrate(
                    system,
                    y0,
                    d,
                    h,
                    method=m,
                    save_every=n_steps // 10,
                    failures=sj.Failures(throw=False),
                )
            )
        )(dW)
        drift = np.max(np.abs(np.asarray(sj.so(n).casimirs(ys)) / c0 - 1), axis=(0, 1))
        rows.append(
            dict(method=name, steps=n_steps, tr_y2=drift[0], tr_y4=drift[1], tr_y6=drift[2])
        )
        print(f"casimirs {name:20s} " + "  ".join(f"{d:.1e}" for d in drift), flush=True)
    return rows


def stress(fast):
    import warnings

    rows = []
    ns, norms, dts = (
        ((4,), (0.99,), (0.25,)) if fast else ((4, 8), (0.5, 0.9, 0.99), (0.25, 0.0625))
    )
    for n in ns:
        j = jnp.asarray([0.6, 1.1, 1.7, 2.3]) if n == 4 else jnp.linspace(0.6, 2.3, n)
        chi = np.random.default_rng(2).normal(size=(3, n, n))
        chi = 0.4 * (chi - np.swapaxes(chi, 1, 2)) / np.sqrt(2 * n)
        models = {
            "c=0.4": sj.GeneralisedRigidBody(j, c=C),
            "3 SALT": sj.GeneralisedRigidBody(j, noise=sj.salt_noise(chi)),
        }
        a = np.random.default_rng(1).normal(size=(n, n))
        for label, system in models.items():
            if fast and label != "c=0.4":
                continue
            for norm in norms:
                y0 = jnp.asarray(norm * (a - a.T) / np.linalg.norm(a - a.T, 2))
                for dt in dts:
                    for name, m in {
                        "LiePoisson": sj.LiePoisson(),
                        "IsospectralMidpoint": sj.IsospectralMidpoint(),
                        "Midpoint": sj.Midpoint(),
                    }.items():
                        row = dict(n=n, noise=label, norm=norm, h=dt, method=name)
                        for retry in (None, 4):
                            with warnings.catch_warnings():
                                warnings.simplefilter("ignore", RuntimeWarning)
                                sol = sj.simulate(
                                    system,
                                    y0,
                                    t1=1.0,
                                    dt=dt,
                                    n_samples=8 if fast else 200,
                                    key=jax.random.key(0),
                                    method=m,
                                    failures=sj.Failures(retry_substeps=retry, throw=False),
                                )
                            key = "failed" if retry is None else "failed_retry4"
                            row[key] = int(sol.stats["n_failed"])
                            row["nonfinite"] = row.get("nonfinite", 0) + int(
                                jnp.sum(~jnp.isfinite(sol.ys))
                            )
                        rows.append(row)
                        print(
                            f"stress n={n} {label:6s} |Y0|={norm} h={dt} {name:20s} failed "
                            f"{row['failed']}, with retry {row['failed_retry4']}, non-finite "
                            f"{row['nonfinite']}",
                            flush=True,
                        )
    return rows


def figure(path, cost_rows, wp_rows):
    plt = _common.pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    names = list(dict.fromkeys(r["method"] for r in cost_rows))
    colors = plt.get_cmap("tab10")
    for i, name in enumerate(names):
        pts = [r for r in cost_rows if r["method"] == name]
        ax1.loglog(
            [r["n"] for r in pts],
            [r["ns_per_sample_step"] for r in pts],
            "o-",
            color=colors(i),
            label=name,
            base=2,
        )
    ax1.set_xlabel("n (so(n))")
    ax1.set_ylabel("ns per sample-step")
    ax1.set_title("Cost against n, generalised rigid body")
    ax1.legend(fontsize=7)
    for i, name in enumerate(dict.fromkeys(r["method"] for r in wp_rows)):
        pts = [r for r in wp_rows if r["method"] == name]
        ax2.loglog(
            [r["time_median_s"] for r in pts],
            [r["rms_error"] for r in pts],
            "o-",
            color=colors(i),
            label=name,
        )
    ax2.set_xlabel("run time (s), 200 samples")
    ax2.set_ylabel("RMS error at T = 1")
    ax2.set_title("Work-precision, so(4), one noise c H")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    p = _common.parser(
        __doc__,
        "a smoke run: n = 3 without the Newton-Jacobian variants; 8 samples; "
        "h = 2^-3, 2^-4; 200 steps",
    )
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    info = results.info
    print(
        f"# so(n): {results.measured_on()}, diffrax {info['diffrax']}",
        flush=True,
    )
    fast = args.fast
    # (--fast, a smoke run: without the two Newton-Jacobian variants, which add nothing the
    # full run does not measure)
    cost_rows = cost(
        (3,) if fast else (3, 4, 6, 8, 12, 16),
        8 if fast else 32,
        32,
        skipped=("LiePoisson newton", "Isospectral newton") if fast else (),
    )
    wp_rows, orders = work_precision(range(3, 5) if fast else range(3, 8), 8 if fast else 200)
    cas_rows = casimirs(200 if fast else 10_000, 2 if fast else 8)
    stress_rows = stress(fast)
    results.csv("so_n", cost_rows)
    results.json(
        "so_n",
        dict(
            machine=info,
            cost=cost_rows,
            work_precision=wp_rows,
            strong_orders=orders,
            casimirs=cas_rows,
            stress=stress_rows,
        ),
    )
    cost_table = _common.markdown_table(
        cost_rows,
        ["n", "method", "ns_per_sample_step", "vs_diffrax_heun", "compile_s", "newton_updates"],
        {
            "ns_per_sample_step": ".0f",
            "vs_diffrax_heun": ".2f",
            "compile_s": ".2f",
            "newton_updates": ".2f",
        },
    )
    orders_line = ", ".join(f"{k} {v:.2f}" for k, v in sorted(orders.items()))
    casimir_table = _common.markdown_table(
        cas_rows,
        ["method", "steps", "tr_y2", "tr_y4", "tr_y6"],
        {"tr_y2": ".1e", "tr_y4": ".1e", "tr_y6": ".1e"},
    )
    stress_table = _common.markdown_table(
        stress_rows, ["n", "noise", "norm", "h", "method", "failed", "failed_retry4", "nonfinite"]
    )
    results.markdown(
        "so_n",
        f"{cost_table}\nStrong orders at n = 4 (h = 2^-3..2^-7): {orders_line}\n\n"
        f"{casimir_table}\nStress (200 samples, T = 1): failed samples without / with "
        f"retry_substeps=4\n\n{stress_table}",
        f", diffrax {info['diffrax']}.",
    )
    figure(os.path.join(args.out, "so_n.png"), cost_rows, wp_rows)


if __name__ == "__main__":
    main()
