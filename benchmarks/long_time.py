#!/usr/bin/env python
"""Long-time behaviour of the invariants: Casimir and Hamiltonian relative error up to T = 1000.

The paper's setup (`RigidBody.paper()`, `PAPER_Y0`, c = 0.2), h = 0.01, 20 Brownian paths
(shared by every method), states saved 200 times. For each method and saved time: the median
and the maximum over the paths of

    |C(y_t) / C(y_0) - 1|  (C = |y|^2 / 2, the Casimir)   and   |H(y_t) / H(y_0) - 1|.

Both are invariants of the exact solution (a random time change of the free rigid body), so
any change is numerical. Methods: EulerMaruyama, Midpoint, Strang, LiePoisson, LiePoissonSym4
(slps_jax, `simulate` with `throw=False`) and diffrax `Heun` on the same increments
(`IncrementPath` of work_precision.py; skipped cleanly when diffrax, the `bench` extra, is not
installed). A path whose step fails (Euler-Maruyama blowing up) counts from then on as lost:
its errors are left out and the time of the first failure is reported.

Each method's growth is summarised by the slope of log(median error) against log t over the
last two decades (1 for a linear drift, 1/2 for a random walk, 0 for bounded), and a verdict:
"round-off" (median error at T below 1e-12), else "bounded" (slope < 0.25), "random walk"
(slope < 0.75) or "drifts"; "blows up" if a path failed.

Writes `long_time.csv` (one row per method and saved time), `long_time.json` (summary per
method, settings, machine) and `long_time.png`.

    python benchmarks/long_time.py [--fast] [--out DIR]

`--fast`: T = 100, 8 paths (about 20 s, mostly compilation).
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import math  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, _HERE)
# This checkout's slps_jax, not whichever one the environment has installed (an editable
# install of another checkout would otherwise win).
sys.path.insert(1, os.path.dirname(_HERE))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402

try:
    import diffrax as dfx
    from work_precision import IncrementPath, diffusion, drift
except ImportError:  # the `bench` extra is not installed: our methods only
    dfx = None

OURS = {
    "EulerMaruyama": sj.EulerMaruyama(),
    "Midpoint": sj.Midpoint(),
    "Strang": sj.Strang(),
    "LiePoisson": sj.LiePoisson(),
    "LiePoissonSym4": sj.LiePoissonSym4(),
}
DIFFRAX_HEUN = "diffrax Heun"
FLOOR = 1e-17  # errors of exactly 0 are drawn here on the log axes


def run_ours(method, system, y0, t1, h, n_samples, key, save_every):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # failures are reported below
        sol = sj.simulate(
            system,
            y0,
            t1=t1,
            dt=h,
            n_samples=n_samples,
            key=key,
            method=method,
            save_every=save_every,
            failures=sj.Failures(throw=False),
        )
    ys = np.asarray(sol.ys)
    fail = np.asarray(sol.fail_step)
    return ys, fail


def run_diffrax_heun(system, y0, dW, h, save_every):
    n_steps = dW.shape[1]
    ts = jnp.arange(0, n_steps + 1, save_every) * h
    terms_of = lambda path: dfx.MultiTerm(
        dfx.ODETerm(drift(system)),
        dfx.ControlTerm(diffusion(system), path),
    )

    @jax.jit
    def solve(dW):
        def one(d):
            w = jnp.concatenate([jnp.zeros(1, d.dtype), jnp.cumsum(d)])
            sol = dfx.diffeqsolve(
                terms_of(IncrementPath(w, h)),
                dfx.Heun(),
                0.0,
                n_steps * h,
                h,
                y0,
                saveat=dfx.SaveAt(ts=ts),
                max_steps=n_steps + 16,
                throw=False,
            )
            return sol.ys, sol.result == dfx.RESULTS.successful

        return jax.vmap(one)(dW)

    ys, ok = solve(dW)
    ys = np.asarray(ys)
    if not np.all(np.asarray(ok)):
        print(f"  diffrax Heun: {int(np.sum(~np.asarray(ok)))} paths did not finish")
    # a path that turns non-finite is lost from the last finite saved state on
    bad = ~np.all(np.isfinite(ys), axis=-1)
    fail = np.where(bad.any(1), (np.argmax(bad, 1) - 1) * save_every, -1)
    return ys, fail


def relative_errors(system, y0, ys, fail, save_every):
    """(casimir, energy) relative errors, shape (n_samples, n_saved); NaN after a failure."""
    c0, h0 = float(system.casimir(y0)), float(system.hamiltonian(y0))
    with np.errstate(all="ignore"):
        cas = np.abs(np.asarray(system.casimir(ys)) / c0 - 1.0)
        ene = np.abs(np.asarray(system.hamiltonian(ys)) / h0 - 1.0)
    idx = np.arange(ys.shape[1]) * save_every  # saved state k is after step idx[k]
    lost = (fail[:, None] >= 0) & (idx[None, :] > fail[:, None])
    cas[lost | ~np.isfinite(cas)] = np.nan
    ene[lost | ~np.isfinite(ene)] = np.nan
    return cas, ene


def growth_slope(ts, err, t1):
    """Slope of log(error) against log(t) over t in [t1/100, t1] (finite, positive only)."""
    sel = (ts >= t1 / 100) & np.isfinite(err) & (err > 0)
    if sel.sum() < 3:
        return float("nan")
    return float(np.polyfit(np.log(ts[sel]), np.log(err[sel]), 1)[0])


def verdict(slope, final, failed):
    if failed or not math.isfinite(final):
        return "blows up"
    if final < 1e-12:
        return "round-off"
    if slope < 0.25:
        return "bounded"
    if slope < 0.75:
        return "random walk"
    return "drifts"


def plot(rows, summary, path, t1):
    plt = _common.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), sharex=True)
    names = list(summary)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, key, title in (
        (axes[0], "casimir", "Casimir $|y|^2/2$"),
        (axes[1], "energy", "Hamiltonian $H$"),
    ):
        for i, name in enumerate(names):
            pts = [r for r in rows if r["method"] == name and r["t"] > 0]
            ts = np.array([r["t"] for r in pts])
            med = np.array([r[f"{key}_median"] for r in pts], float)
            mx = np.array([r[f"{key}_max"] for r in pts], float)
            col = colors[i % len(colors)]
            s = summary[name][key]
            ax.loglog(
                ts,
                np.maximum(med, FLOOR),
                color=col,
                label=f"{name} ({s['verdict']}, slope {s['slope']:.2f})",
            )
            ax.fill_between(
                ts,
                np.maximum(med, FLOOR),
                np.maximum(mx, FLOOR),
                color=col,
                alpha=0.12,
                linewidth=0,
            )
        ax.set_title(f"{title}: relative error, median (band: max) over paths")
        ax.set_xlabel("t")
        ax.set_xlim(t1 / 200, t1)
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    axes[0].set_ylabel("$|I(y_t)/I(y_0) - 1|$")
    fig.suptitle(summary[names[0]]["setting"], fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse(argv):
    p = _common.parser(__doc__, "T = 100, 8 paths (about 20 s)")
    p.add_argument("--t1", type=float, default=None, help="final time (1000)")
    p.add_argument("--samples", type=int, default=None, help="number of paths (20)")
    p.add_argument("--dt", type=float, default=0.01, help="step size (0.01)")
    p.add_argument("--saves", type=int, default=200, help="saved times (200)")
    p.add_argument("--no-diffrax", action="store_true", help="skip diffrax Heun")
    p.add_argument("--seed", type=int, default=0)
    return p.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    t1 = args.t1 or (100.0 if args.fast else 1000.0)
    n_samples = args.samples or (8 if args.fast else 20)
    h = args.dt
    n_steps = int(round(t1 / h))
    saves = min(args.saves, n_steps)
    while n_steps % saves:
        saves -= 1
    save_every = n_steps // saves
    results = _common.Output(args.out)
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    key = jax.random.key(args.seed)
    setting = (
        f"paper's rigid body, y0 = {sj.PAPER_Y0}, c = 0.2, h = {h:g}, T = {t1:g}, "
        f"{n_samples} paths shared by all methods"
    )
    print(f"long-time invariants: {setting}")
    use_diffrax = dfx is not None and not args.no_diffrax
    if not use_diffrax:
        print("diffrax not available or disabled: skipping diffrax Heun")

    ts = np.arange(0, n_steps + 1, save_every) * h
    runs = {}
    for name, method in OURS.items():
        start = time.perf_counter()
        ys, fail = run_ours(method, system, y0, t1, h, n_samples, key, save_every)
        runs[name] = (ys, fail, time.perf_counter() - start)
    if use_diffrax:
        dW = sj.BrownianMotion().increments(
            key, n_steps, h, n_samples=n_samples
        )  # simulate's paths
        start = time.perf_counter()
        ys, fail = run_diffrax_heun(system, y0, dW, h, save_every)
        runs[DIFFRAX_HEUN] = (ys, fail, time.perf_counter() - start)

    rows, summary = [], {}
    for name, (ys, fail, seconds) in runs.items():
        cas, ene = relative_errors(system, y0, ys, fail, save_every)
        alive = np.sum(np.isfinite(cas), axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns after blow-up
            stats = {
                k: (np.nanmedian(e, 0), np.nanmax(e, 0))
                for k, e in (("casimir", cas), ("energy", ene))
            }
        for i, t in enumerate(ts):
            rows.append(
                {
                    "method": name,
                    "t": float(t),
                    "n_alive": int(alive[i]),
                    "casimir_median": float(stats["casimir"][0][i]),
                    "casimir_max": float(stats["casimir"][1][i]),
                    "energy_median": float(stats["energy"][0][i]),
                    "energy_max": float(stats["energy"][1][i]),
                }
            )
        failed = fail >= 0
        entry = {
            "seconds": seconds,
            "n_failed": int(failed.sum()),
            "setting": setting,
            "first_failure_t": float(fail[failed].min() * h) if failed.any() else None,
        }
        for k in ("casimir", "energy"):
            med, mx = stats[k]
            slope = growth_slope(ts, med, t1)
            last = np.flatnonzero(np.isfinite(med))
            final = float(med[last[-1]]) if last.size else float("nan")
            entry[k] = {
                "slope": slope,
                "final_median": final,
                "max_over_time_and_paths": float(np.nanmax(mx)) if last.size else None,
                "at_t": {
                    f"{t:g}": float(med[np.argmin(np.abs(ts - t))]) for t in (t1 / 100, t1 / 10, t1)
                },
                "verdict": verdict(slope, final, bool(failed.any())),
            }
        summary[name] = entry

    results.csv("long_time", rows)
    results.json(
        "long_time",
        {
            "settings": {
                "t1": t1,
                "dt": h,
                "n_samples": n_samples,
                "save_every": save_every,
                "seed": args.seed,
                "y0": list(sj.PAPER_Y0),
                "c": 0.2,
            },
            "methods": summary,
        },
    )
    plot(rows, summary, os.path.join(args.out, "long_time.png"), t1)

    print(
        f"\n{'method':16s} {'Casimir at T':>12s} {'slope':>6s} {'':11s} "
        f"{'energy at T':>12s} {'slope':>6s} {'':11s} {'seconds':>8s}"
    )
    for name, s in summary.items():
        c, e = s["casimir"], s["energy"]
        print(
            f"{name:16s} {c['final_median']:12.2e} {c['slope']:6.2f} {c['verdict']:11s} "
            f"{e['final_median']:12.2e} {e['slope']:6.2f} {e['verdict']:11s} "
            f"{s['seconds']:8.1f}"
            + (
                f"  ({s['n_failed']} paths failed, first at t = {s['first_failure_t']:g})"
                if s["n_failed"]
                else ""
            )
        )
    print(f"wrote {args.out}/long_time.{{csv,json,png}}")


if __name__ == "__main__":
    main()
