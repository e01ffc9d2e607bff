#!/usr/bin/env python
"""Work-precision diagram: RMS error at T = 1 against the exact solution vs wall time.

The paper's setup (`RigidBody.paper()`, `PAPER_Y0`, c = 0.2), 500 samples, h = 2^-3 ... 2^-10.

- slps_jax methods (LiePoisson, LiePoissonSym2/4, Midpoint, Strang, Strang4, EulerMaruyama,
  Exact):
  `jax.jit(jax.vmap(lambda dW: integrate(system, y0, dW, h, method=m, throw=False)))`.
- diffrax `Heun`, `Midpoint`, `ReversibleHeun` on the Stratonovich SDE
  `MultiTerm(ODETerm(f), ControlTerm(g, path))`, f(t, y) = y x (y / I), g = c f, scalar
  Brownian motion (control shape `()`, so `g` returns shape (3,)), constant step h:
  (a) "VBT": `path` is a `VirtualBrownianTree` (tol = finest h) with its own Brownian paths;
      the reference uses that tree's W(1) = tree.evaluate(0, 1);
  (b) "shared dW": `path` is `IncrementPath` below, the piecewise-linear interpolant of the
      cumulative sum of the very same fine increments the slps_jax methods get.
- diffrax `SPaRK` needs space-time Levy area: only a `VirtualBrownianTree` with
  `levy_area=diffrax.SpaceTimeLevyArea` (its own paths, its own reference).
- "lax.scan Heun": Stratonovich Heun written as a plain `lax.scan`, vmapped over samples:
  tau = h + c dW, predictor y + f(y) tau, corrector y + (f(y) + f(y~)) tau / 2.

Same increments for everyone but the VBT runs: the fine increments are drawn once with
`slps_jax.BrownianMotion().increments(key, n_fine, h_fine, n_samples=...)`, a coarse increment is the sum
of the fine ones it spans, and the reference is `exact_solution(system, y0, 1, sum(dW))`.

Timing: every (method, h) is compiled ahead of time (compile time reported on its own), run
once to warm up, then timed (median and min of >= 3 blocking calls). For the implicit
methods (LiePoisson, Midpoint) an extra untimed run with `save_every=1` counts the samples
whose Newton solve failed (`throw=False` freezes them; their error is then not a
discretisation error). Skipped under --fast.

Writes `work_precision.csv` (one row per method and h), `per_step_cost.csv` (LiePoisson vs
diffrax Heun per sample-step on the same increments), `work_precision.json` (both, plus which
method reaches RMS error 1e-6 fastest and the machine) and `work_precision.png`.

    python benchmarks/work_precision.py [--fast] [--out DIR]
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

try:
    import diffrax as dfx
    import equinox as eqx
except ImportError:  # the `bench` extra is not installed: our methods only
    dfx = eqx = None

TARGET = 1e-6

OURS = {
    "LiePoisson": sj.LiePoisson(),
    "LiePoissonSym2": sj.LiePoissonSym2(),
    "LiePoissonSym4": sj.LiePoissonSym4(),
    "Midpoint": sj.Midpoint(),
    "Strang": sj.Strang(),
    "Strang4": sj.Strang4(),
    "EulerMaruyama": sj.EulerMaruyama(),
    "Exact": sj.Exact(),
}
# name -> (diffrax solver class name, Brownian path kind)
DIFFRAX = {
    "diffrax Heun (shared dW)": ("Heun", "shared"),
    "diffrax Midpoint (shared dW)": ("Midpoint", "shared"),
    "diffrax ReversibleHeun (shared dW)": ("ReversibleHeun", "shared"),
    "diffrax Heun (VBT)": ("Heun", "vbt"),
    "diffrax Midpoint (VBT)": ("Midpoint", "vbt"),
    "diffrax ReversibleHeun (VBT)": ("ReversibleHeun", "vbt"),
    "diffrax SPaRK (VBT, space-time Levy area)": ("SPaRK", "vbt-levy"),
}
SCAN_HEUN = "lax.scan Heun (shared dW)"
FAST_METHODS = [
    "LiePoisson",
    "Strang",
    SCAN_HEUN,
    "diffrax Heun (shared dW)",
    "diffrax SPaRK (VBT, space-time Levy area)",
]


def all_method_names(with_diffrax):
    names = list(OURS) + [SCAN_HEUN]
    if with_diffrax:
        names += list(DIFFRAX)
    return names


# --------------------------------------------------------------------------------------
# The vector fields and the integrators.


def drift(system):
    inertia = system.inertia

    def f(t, y, args):
        return jnp.cross(y, y / inertia)

    return f


def diffusion(system):
    f, c = drift(system), system.c

    def g(t, y, args):  # scalar Brownian motion: control shape (), g(t, y) shape (3,)
        return c * f(t, y, args)

    return g


def scan_heun(system, y0, dW, h):
    """Stratonovich Heun for dy = f(y)(dt + c o dW), one path, as a plain lax.scan."""
    f = drift(system)

    def step(y, dw):
        tau = h + system.c * dw
        fy = f(None, y, None)
        y_pred = y + fy * tau
        return y + 0.5 * (fy + f(None, y_pred, None)) * tau, None

    y, _ = jax.lax.scan(step, y0, dW)
    return y


if dfx is not None:

    class IncrementPath(dfx.AbstractPath):
        """W on [0, n h_fine]: the piecewise-linear interpolant of `w` (the cumulative sum of
        the fine increments, `w[0] = 0`). On grid points `evaluate(s, t)` is `w[j] - w[i]`:
        the sum of the increments in between (to round-off)."""

        w: jax.Array
        h_fine: float = eqx.field(static=True)

        @property
        def t0(self):
            return 0.0

        @property
        def t1(self):
            return self.h_fine * (self.w.shape[0] - 1)

        def _value(self, t):
            x = t / self.h_fine
            i = jnp.clip(jnp.floor(x).astype(jnp.int32), 0, self.w.shape[0] - 2)
            return self.w[i] + (x - i) * (self.w[i + 1] - self.w[i])

        def evaluate(self, t0, t1=None, left=True):
            del left
            if t1 is None:
                return self._value(t0)
            return self._value(t1) - self._value(t0)


def vbt(key, tol, levy):
    levy_area = dfx.SpaceTimeLevyArea if levy else dfx.BrownianIncrement
    return dfx.VirtualBrownianTree(0.0, 1.0, tol=tol, shape=(), key=key, levy_area=levy_area)


def diffrax_final(system, y0, path, solver, h, n_steps):
    terms = dfx.MultiTerm(dfx.ODETerm(drift(system)), dfx.ControlTerm(diffusion(system), path))
    sol = dfx.diffeqsolve(terms, solver, 0.0, n_steps * h, h, y0, max_steps=n_steps, throw=False)
    return sol.ys[-1]


def build(name, system, y0, h, n_steps, h_fine, data):
    """`(fn, args, reference_key)`: `fn(*args)` gives the final states `(n_samples, 3)`;
    `reference_key` names which reference solution they are compared with."""
    if name in OURS:
        method = OURS[name]

        def fn(dW):
            return jax.vmap(
                lambda d: sj.integrate(
                    system, y0, d, h, method=method, failures=sj.Failures(throw=False)
                )
            )(dW)

        return fn, (data["coarse"](n_steps),), "shared"
    if name == SCAN_HEUN:
        return (
            lambda dW: jax.vmap(lambda d: scan_heun(system, y0, d, h))(dW),
            (data["coarse"](n_steps),),
            "shared",
        )
    solver_name, kind = DIFFRAX[name]
    solver = getattr(dfx, solver_name)()
    if kind == "shared":

        def fn(w):
            return jax.vmap(
                lambda wi: diffrax_final(system, y0, IncrementPath(wi, h_fine), solver, h, n_steps)
            )(w)

        return fn, (data["cumulative"],), "shared"
    levy = kind == "vbt-levy"

    def fn(keys):
        return jax.vmap(
            lambda k: diffrax_final(system, y0, vbt(k, h_fine, levy), solver, h, n_steps)
        )(keys)

    return fn, (data["vbt_keys"],), kind


IMPLICIT = ("LiePoisson", "Midpoint")  # Newton solves that can fail at large steps


def count_failed(system, y0, dW, h, method):
    """Samples whose Newton solve failed: `integrate(throw=False)` freezes such a sample at
    its last good state, so its last two saved states are identical (an untimed extra run)."""
    traj = jax.jit(
        jax.vmap(
            lambda d: sj.integrate(
                system, y0, d, h, method=method, save_every=1, failures=sj.Failures(throw=False)
            )
        )
    )(dW)
    return int(jnp.sum(jnp.all(traj[:, -1] == traj[:, -2], axis=-1)))


def references(system, y0, data, h_fine, with_diffrax):
    """Exact final states per sample for each family of Brownian paths."""
    exact = jax.jit(jax.vmap(lambda w: sj.exact_solution(system, y0, 1.0, w)))
    refs = {"shared": exact(data["fine"].sum(axis=1))}
    if with_diffrax:
        for kind, levy in (("vbt", False), ("vbt-levy", True)):
            w1 = jax.jit(jax.vmap(lambda k: vbt(k, h_fine, levy).evaluate(0.0, 1.0)))(
                data["vbt_keys"]
            )
            refs[kind] = exact(w1)
    return refs


# --------------------------------------------------------------------------------------
# Analysis.


def time_to_target(points, target=TARGET):
    """Wall time at which a method's RMS error reaches `target`, interpolated in log-log
    between the two step sizes that bracket it. `points`: (h, error, time), any order.

    **Returns:** `(seconds or None, how)` with `how` one of "interpolated", "coarsest h"
    (already below target at the largest h: an upper bound), "extrapolated" (from the last
    two points, only when the smallest h missed the target by less than a factor 2; not used
    to pick the winner), "not reached".
    """
    pts = sorted(points, key=lambda p: -p[0])  # cheapest (largest h) first
    e = np.array([p[1] for p in pts])
    t = np.array([p[2] for p in pts])
    if e[0] <= target:
        return float(t[0]), "coarsest h"
    for i in range(len(pts) - 1):
        if e[i] > target >= e[i + 1]:
            s = (math.log(t[i + 1]) - math.log(t[i])) / (math.log(e[i + 1]) - math.log(e[i]))
            return float(
                math.exp(math.log(t[i]) + s * (math.log(target) - math.log(e[i])))
            ), "interpolated"
    # Extrapolate only a short way (the target within a factor 2 of the last error) and only
    # where the error still falls like a convergent method's (local order >= 1/2).
    if len(pts) >= 2 and e[-1] <= 2 * target and t[-1] > t[-2]:
        h = np.array([p[0] for p in pts])
        order = math.log(e[-2] / e[-1]) / math.log(h[-2] / h[-1])
        if order >= 0.5:
            s = (math.log(t[-1]) - math.log(t[-2])) / (math.log(e[-1]) - math.log(e[-2]))
            return float(
                math.exp(math.log(t[-1]) + s * (math.log(target) - math.log(e[-1])))
            ), "extrapolated"
    return None, "not reached"


def fastest(rows, target=TARGET):
    by_method = {}
    for r in rows:
        by_method.setdefault(r["method"], []).append((r["h"], r["rms_error"], r["time_median_s"]))
    table = []
    for name, pts in by_method.items():
        sec, how = time_to_target(pts, target)
        table.append({"method": name, "seconds": sec, "how": how})
    usable = [r for r in table if r["how"] in ("interpolated", "coarsest h")]
    best = min(usable, key=lambda r: r["seconds"], default=None)
    # Exact has round-off error at every h: it "reaches" any target at the coarsest step.
    best_integrator = min(
        (r for r in usable if r["method"] != "Exact"), key=lambda r: r["seconds"], default=None
    )
    return table, best, best_integrator


def _group(name):
    """Colour group: a solver's shared-dW and VBT runs share a colour, the line style differs."""
    return name.split(" (")[0]


def plot(rows, path, n_samples, fastest_row):
    plt = _common.pyplot()
    methods = list(dict.fromkeys(r["method"] for r in rows))
    groups = list(dict.fromkeys(_group(m) for m in methods))
    hs = sorted({r["h"] for r in rows}, reverse=True)
    markers = "os^vD<>ph*X"
    fig, ax = plt.subplots(figsize=(10, 6.5))
    # tab20's ten dark hues first, then its ten light ones: a distinct colour for up to 20
    # solvers (tab10 repeated LiePoisson's colour for the eleventh).
    cmap = plt.get_cmap("tab20")
    handles = []
    floor = (
        min(
            (r["rms_error"] for r in rows if r["method"] != "Exact" and r["rms_error"] > 0),
            default=1e-8,
        )
        / 5
    )
    off_scale = []
    for name in methods:
        pts = sorted((r for r in rows if r["method"] == name), key=lambda r: -r["h"])
        if all(p["rms_error"] < floor for p in pts):
            off_scale.append(
                (name, min(p["rms_error"] for p in pts), max(p["rms_error"] for p in pts))
            )
            continue
        i = groups.index(_group(name)) % 20
        color = cmap((2 * i) % 20 + (2 * i) // 20)
        style = "--" if "VBT" in name else (":" if "scan" in name else "-")
        (line,) = ax.plot(
            [p["time_median_s"] for p in pts],
            [p["rms_error"] for p in pts],
            style,
            color=color,
            label=name,
        )
        handles.append(line)
        for p in pts:
            ax.plot(
                p["time_median_s"],
                p["rms_error"],
                markers[hs.index(p["h"]) % len(markers)],
                color=color,
                ms=6,
            )
    ax.axhline(TARGET, color="grey", lw=0.8, ls="-.")
    ax.text(
        min(r["time_median_s"] for r in rows),
        TARGET * 1.15,
        f"RMS {TARGET:g}",
        fontsize=7,
        color="grey",
    )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(bottom=floor)
    ax.set_xlabel(f"run time for {n_samples} samples to T = 1 [s] (median, compile excluded)")
    ax.set_ylabel("RMS error at T = 1 vs exact solution")
    title = (
        "Stochastic rigid body, paper's setup (c = 0.2), float64, "
        f"{n_samples} samples: work-precision"
    )
    if fastest_row is not None:
        title += (
            f"\nfastest to RMS {TARGET:g} in this range of h (Exact excluded): "
            f"{fastest_row['method']}, {fastest_row['seconds'] * 1e3:.0f} ms"
        )
    if off_scale:
        title += "\n" + "; ".join(
            f"{n}: RMS {lo:.0e} to {hi:.0e} (round-off), off scale" for n, lo, hi in off_scale
        )
    ax.set_title(title, fontsize=9)
    leg1 = ax.legend(
        handles=handles,
        fontsize=7,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        title="method (dashed: diffrax's own VBT paths)",
        title_fontsize=7,
    )
    ax.add_artist(leg1)
    h_handles = [ax.plot([], [], markers[j % len(markers)], color="k")[0] for j in range(len(hs))]
    leg2 = ax.legend(
        h_handles,
        [f"h = 2^{round(math.log2(h))}" for h in hs],
        fontsize=7,
        loc="lower left",
        bbox_to_anchor=(1.01, 0.0),
        title="step size",
        title_fontsize=7,
    )
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=120, bbox_inches="tight", bbox_extra_artists=[leg1, leg2])
    plt.close(fig)


# --------------------------------------------------------------------------------------


def parse(argv):
    p = _common.parser(
        __doc__,
        "tiny size for the test suite: 40 samples, h = 2^-3, 2^-4, a subset of the methods",
    )
    p.add_argument("--samples", type=int, default=None, help="number of samples (500)")
    p.add_argument("--kmin", type=int, default=None, help="largest step 2^-kmin (3)")
    p.add_argument("--kmax", type=int, default=None, help="smallest step 2^-kmax (10)")
    p.add_argument(
        "--methods", default=None, help="comma-separated method names (default: all available)"
    )
    p.add_argument("--no-diffrax", action="store_true", help="skip the diffrax methods")
    p.add_argument("--repeats", type=int, default=3, help="timed calls per point, at least")
    p.add_argument(
        "--cost-repeats",
        type=int,
        default=None,
        help="interleaved repeats of the per-sample-step cost table (7)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--replot", action="store_true", help="only redraw the PNG from OUT/work_precision.csv"
    )
    return p.parse_args(argv)


def replot(out):
    import csv

    with open(os.path.join(out, "work_precision.csv"), newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for key in ("h", "rms_error", "time_median_s"):
            r[key] = float(r[key])
    _, _, best_integrator = fastest(rows)
    plot(rows, os.path.join(out, "work_precision.png"), int(rows[0]["n_samples"]), best_integrator)
    return 0


def main(argv=None):
    args = parse(argv)
    if args.replot:
        return replot(args.out)
    fast = args.fast
    n_samples = args.samples or (40 if fast else 500)
    kmin = args.kmin if args.kmin is not None else 3
    kmax = args.kmax if args.kmax is not None else (4 if fast else 10)
    with_diffrax = dfx is not None and not args.no_diffrax
    if args.methods:
        names = [m.strip() for m in args.methods.split(",") if m.strip()]
        unknown = set(names) - set(all_method_names(True))
        if unknown:
            raise SystemExit(f"unknown methods {sorted(unknown)}; known: {all_method_names(True)}")
    else:
        names = FAST_METHODS if fast else all_method_names(True)
    if not with_diffrax:
        skipped = [n for n in names if n in DIFFRAX]
        if skipped:
            print(f"diffrax not available or disabled: skipping {skipped}")
        names = [n for n in names if n not in DIFFRAX]
    results = _common.Output(args.out)

    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    ks = list(range(kmin, kmax + 1))
    h_fine, n_fine = 2.0**-kmax, 2**kmax
    fine = sj.BrownianMotion().increments(
        jax.random.key(args.seed), n_fine, h_fine, n_samples=n_samples
    )
    data = {
        "fine": fine,
        "coarse": lambda n: fine.reshape(n_samples, n, n_fine // n).sum(axis=2),
        "cumulative": jnp.concatenate(
            [jnp.zeros((n_samples, 1), fine.dtype), jnp.cumsum(fine, axis=1)], axis=1
        ),
        "vbt_keys": jax.random.split(jax.random.key(args.seed + 1), n_samples),
    }
    refs = references(system, y0, data, h_fine, with_diffrax)
    info = results.info
    print(
        f"work-precision: {n_samples} samples, h = 2^-{kmin} ... 2^-{kmax}, "
        f"{results.measured_on()}, diffrax {info['diffrax']}"
    )

    rows, finals, compiled = [], {}, {}
    for name in names:
        for k in ks:
            h, n_steps = 2.0**-k, 2**k
            fn, fn_args, ref_key = build(name, system, y0, h, n_steps, h_fine, data)
            exe, t_compile = _common.compile_timed(fn, *fn_args)
            t_med, t_min, n_rep, ys = _common.time_call(exe, *fn_args, repeats=args.repeats)
            compiled[(name, k)] = (exe, fn_args)
            finals[(name, k)] = ys
            n_failed = None
            if name in IMPLICIT and not fast:
                n_failed = count_failed(system, y0, fn_args[0], h, OURS[name])
            e2 = np.asarray(jnp.sum((ys - refs[ref_key]) ** 2, axis=-1))
            rms = float(np.sqrt(e2.mean()))
            se = float(e2.std(ddof=1) / math.sqrt(n_samples) / (2 * rms)) if rms > 0 else 0.0
            norm0 = float(jnp.linalg.norm(y0))
            casimir = float(jnp.max(jnp.abs(jnp.linalg.norm(ys, axis=-1) - norm0))) / norm0
            row = {
                "method": name,
                "brownian": {
                    "shared": "shared increments",
                    "vbt": "VBT",
                    "vbt-levy": "VBT + space-time Levy area",
                }[ref_key],
                "h": h,
                "log2_h": -k,
                "n_steps": n_steps,
                "n_samples": n_samples,
                "rms_error": rms,
                "rms_stderr": se,
                "time_median_s": t_med,
                "time_min_s": t_min,
                "n_repeats": n_rep,
                "compile_s": t_compile,
                "max_rel_casimir_error": casimir,
                "finite": bool(np.all(np.isfinite(ys))),
                "n_failed": n_failed,
            }
            rows.append(row)
            print(
                f"  {name:44s} h=2^-{k:<2d} rms {rms:.3e} ± {se:.1e}  run {t_med * 1e3:9.2f} ms"
                f" (min {t_min * 1e3:8.2f}, n={n_rep:2d})  compile {t_compile:5.2f} s"
                + (f"  FAILED SAMPLES: {n_failed}" if n_failed else "")
            )

    # ---- per sample-step cost: LiePoisson vs diffrax Heun on the same increments ---------
    k_cost = min(9, kmax)
    h_cost, n_cost = 2.0**-k_cost, 2**k_cost
    cost_names = (
        ["LiePoisson"] + (["diffrax Heun (shared dW)"] if with_diffrax else []) + [SCAN_HEUN]
    )
    cost_repeats = args.cost_repeats or (3 if fast else 7)
    cost_exes = {}
    for name in cost_names:
        if (name, k_cost) in compiled:
            cost_exes[name] = compiled[(name, k_cost)]
        else:
            fn, fn_args, _ = build(name, system, y0, h_cost, n_cost, h_fine, data)
            exe, _ = _common.compile_timed(fn, *fn_args)
            jax.block_until_ready(exe(*fn_args))
            cost_exes[name] = (exe, fn_args)
    samples = {name: [] for name in cost_names}
    for _ in range(cost_repeats):  # interleaved, so the machine's load hits all alike
        for name in cost_names:
            exe, fn_args = cost_exes[name]
            t_med, _, _, _ = _common.time_call(exe, *fn_args, repeats=1, min_total=0.0)
            samples[name].append(t_med)
    ref_name = "diffrax Heun (shared dW)" if with_diffrax else SCAN_HEUN
    per_step = {name: float(np.median(samples[name])) / (n_samples * n_cost) for name in cost_names}
    cost_rows = [
        {
            "method": name,
            "n_samples": n_samples,
            "n_steps": n_cost,
            "h": h_cost,
            "median_s": float(np.median(samples[name])),
            "min_s": float(np.min(samples[name])),
            "n_repeats": cost_repeats,
            "ns_per_sample_step": per_step[name] * 1e9,
            f"ratio_to_{ref_name.split(' (')[0].replace(' ', '_')}": per_step[name]
            / per_step[ref_name],
        }
        for name in cost_names
    ]
    heun_check = None
    if with_diffrax:
        ya = cost_exes["diffrax Heun (shared dW)"][0](*cost_exes["diffrax Heun (shared dW)"][1])
        yb = cost_exes[SCAN_HEUN][0](*cost_exes[SCAN_HEUN][1])
        heun_check = float(jnp.max(jnp.abs(ya - yb)))

    table, best, best_integrator = fastest(rows)
    results.csv("work_precision", rows)
    results.csv("per_step_cost", cost_rows)
    results.json(
        "work_precision",
        {
            "machine": info,
            "n_samples": n_samples,
            "h": [2.0**-k for k in ks],
            "target_rms": TARGET,
            "points": rows,
            "per_step_cost": cost_rows,
            "per_step_ratio_LiePoisson_to_reference": per_step["LiePoisson"] / per_step[ref_name],
            "per_step_reference": ref_name,
            "max_abs_diff_diffrax_heun_vs_scan_heun": heun_check,
            "time_to_target": table,
            "fastest": best,
            "fastest_integrator": best_integrator,
            "note": "noisy numbers from a shared 2-core machine; medians of repeated calls",
        },
    )
    plot(rows, os.path.join(args.out, "work_precision.png"), n_samples, best_integrator)

    print(
        f"\nper sample-step cost, {n_samples} samples x {n_cost} steps (h = 2^-{k_cost}), "
        f"same increments, {cost_repeats} interleaved repeats:"
    )
    for r in cost_rows:
        print(
            f"  {r['method']:28s} {r['ns_per_sample_step']:8.1f} ns/sample-step "
            f"(median {r['median_s'] * 1e3:.2f} ms)  x{per_step[r['method']] / per_step[ref_name]:.2f}"
            f" of {ref_name}"
        )
    if heun_check is not None:
        print(
            f"  diffrax Heun vs lax.scan Heun on the same increments: max |diff| = {heun_check:.1e}"
        )
    print(f"\ntime to reach RMS error {TARGET:g} (log-log interpolation):")
    for r in sorted(
        table,
        key=lambda r: (
            r["how"] not in ("interpolated", "coarsest h"),
            r["seconds"] if r["seconds"] is not None else math.inf,
        ),
    ):
        sec = "-" if r["seconds"] is None else f"{r['seconds'] * 1e3:.2f} ms"
        print(f"  {r['method']:44s} {sec:>12s}  ({r['how']})")
    if best is not None:
        print(
            f"fastest to {TARGET:g}: {best['method']} ({best['seconds'] * 1e3:.2f} ms, "
            f"{best['how']})"
        )
    if best_integrator is not None:
        print(
            f"fastest time-discretising integrator (Exact excluded): "
            f"{best_integrator['method']} ({best_integrator['seconds'] * 1e3:.2f} ms)"
        )
    else:
        print(f"no time-discretising integrator reached {TARGET:g} in this range of h")
    print(f"wrote {args.out}/work_precision.{{csv,json,png}} and per_step_cost.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
