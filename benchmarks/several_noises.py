#!/usr/bin/env python
"""Several noises: the rigid body with three SALT noises about non-parallel axes, with and
without the Lévy areas of the noises.

    dy = y x I^{-1} y dt + sum_r y x chi_r o dW_r,  I = (1, 2, 3),
    chi = 0.4 [[1, 0, 0], [0, 1, 0], [0, 0.5, 1]],  y0 = (0.6, 0.5, 0.3),  T = 1.

No exact solution: the reference is `Midpoint` with Lévy areas on the very same Brownian
paths at h_fine = 2^-14 (64x finer than the finest step studied); its own error is
estimated by the same method at 2 h_fine and printed next to the errors. The paths' fine
increments and areas are drawn once (as `simulate` draws them); a coarse step's are the fine
ones joined by Chen's relation (`_brownian.coarsen`). Every method is timed the same way: on
these precomputed increments (and areas).

- Work-precision: RMS error at T against the reference vs run time (median of >= 3 blocking
  calls after a warm-up; compile time on its own), 500 samples, h = 2^-4 ... 2^-8, for every
  slps_jax method that serves the system, with areas where it uses them and without, the
  order-1 baseline `Milstein` with areas, a `lax.scan` Heun and diffrax `Heun` (shared
  increments through the same piecewise-linear path as `work_precision.py`; only with the
  `bench` extra). The run time at RMS error 1e-3 is read off each method's line
  (interpolated, or extrapolated from its smallest step along its fitted order, marked).
- Per sample-step cost at h = 2^-8 (run time / (samples x steps)), as a ratio to diffrax Heun.
- Strong orders (least-squares slope over h) and weak orders (`weak_convergence`, the same
  reference, observables H(y) and y_3^2, for seven of the methods; printed only where every
  bias is resolved).
- The cost of drawing the areas against the increments alone, s = 2, 3, 5 and
  h = 2^-6, 2^-8, 2^-10 (jitted draws of 500 samples x 256 steps).
- so(4), the generalised rigid body with three SALT noises: IsospectralMidpoint and
  LiePoisson with and without areas, and Milstein, 200 samples, h = 2^-3 ... 2^-6.
- Long time: T = 100 at h = 2^-6, 100 samples: the number of samples that failed (blew up),
  and over the others the largest relative Casimir drift max | |y_t| - |y_0| | / |y_0| along
  the path and E[H(y_T)] with its 95% interval.

A failed sample in the work-precision runs (counted by an untimed run) stops the script:
frozen states are not data.

Writes `several_noises.csv`, `several_noises.json`, `several_noises.md` and
`several_noises.png` into --out (default benchmarks/results).

    python benchmarks/several_noises.py [--fast] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import math  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402
import work_precision as wp  # noqa: E402  (its diffrax import is guarded)

import slps_jax as sj  # noqa: E402
from slps_jax import _brownian  # noqa: E402

INERTIA = jnp.asarray([1.0, 2.0, 3.0])
CHI = 0.4 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
Y0 = jnp.asarray([0.6, 0.5, 0.3])
MODEL = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))

# name: (method, with Lévy areas)
OURS = {
    "LiePoisson + areas": (sj.LiePoisson(), True),
    "Midpoint + areas": (sj.Midpoint(), True),
    "SaltSplitting + areas": (sj.SaltSplitting(), True),
    "Milstein + areas": (sj.Milstein(), True),
    "LiePoisson": (sj.LiePoisson(), False),
    "LiePoissonSym2": (sj.LiePoissonSym2(), False),
    "LiePoissonSym4": (sj.LiePoissonSym4(), False),
    "Midpoint": (sj.Midpoint(), False),
    "SaltSplitting": (sj.SaltSplitting(), False),
    "Heun": (sj.Heun(), False),
    "EulerMaruyama": (sj.EulerMaruyama(), False),
}
POISSON = (
    "LiePoisson + areas",
    "Midpoint + areas",
    "SaltSplitting + areas",
    "LiePoisson",
    "LiePoissonSym2",
    "LiePoissonSym4",
    "Midpoint",
    "SaltSplitting",
)
POISSON_AREAS = ("LiePoisson + areas", "Midpoint + areas", "SaltSplitting + areas")
BASELINE = "Milstein + areas"  # order 1, no structure
SCAN_HEUN = "lax.scan Heun"
DIFFRAX_HEUN = "diffrax Heun"
TARGET = 1e-3  # the RMS error at which the methods' costs are compared


def fields(y):
    """The drift and the three noise fields: y x I^{-1} y, and the columns y x chi_r."""
    g = jnp.stack([jnp.cross(y, c) for c in jnp.asarray(CHI)], axis=1)  # (3, s)
    return jnp.cross(y, y / INERTIA), g


def scan_heun(y0, dW, h):
    """Stratonovich Heun for the SALT rigid body, one path, as a plain lax.scan."""

    def step(y, dw):
        f, g = fields(y)
        k1 = f * h + g @ dw
        f2, g2 = fields(y + k1)
        return y + 0.5 * (k1 + f2 * h + g2 @ dw), None

    return jax.lax.scan(step, y0, dW)[0]


def diffrax_heun(w, h, n_steps, h_fine):
    dfx = wp.dfx
    terms = dfx.MultiTerm(
        dfx.ODETerm(lambda t, y, a: fields(y)[0]),
        dfx.ControlTerm(lambda t, y, a: fields(y)[1], wp.IncrementPath(w, h_fine)),
    )
    sol = dfx.diffeqsolve(
        terms, dfx.Heun(), 0.0, n_steps * h, h, Y0, max_steps=n_steps, throw=False
    )
    return sol.ys[-1]


def parse(argv):
    p = _common.parser(
        __doc__,
        "a smoke run: 32 samples, h = 2^-4 and 2^-5, reference at 2^-8, weak "
        "errors of two methods, a short long-time run, small so(4) and "
        "area-cost runs",
    )
    p.add_argument(
        "--area-costs-only",
        action="store_true",
        help="only the cost of drawing the areas (written to "
        "several_noises_area_costs.md and .json)",
    )
    return p.parse_args(argv)


def draw_paths(key, n_samples, n_steps, h, n_noises=3, batch=20):
    """The increments and Lévy areas `simulate` draws for samples `0 .. n_samples-1`
    (untruncated increments here: `truncate_k=None`), `batch` samples at a time (the areas'
    normals of one batch are the memory high-water mark)."""
    dtype = jnp.float64
    terms = _brownian.levy_area_terms(h, n_noises)
    steps = jnp.arange(n_steps, dtype=jnp.uint32)

    def one(k):
        noise = jax.vmap(
            lambda n: _brownian.draw(k, n, jnp.asarray(h, dtype), jnp.inf, dtype, n_noises, terms)
        )(steps)
        return noise.dW, noise.area

    return jax.jit(lambda keys: jax.lax.map(one, keys, batch_size=batch))(
        _brownian.sample_keys(key, n_samples)
    )


def solver(system, y0, method, h, areas):
    """All samples' final states of `method` on given increments (and areas): one jit."""
    if areas:
        return lambda d, a: jax.vmap(
            lambda di, ai: sj.integrate(
                system, y0, di, h, areas=ai, method=method, failures=sj.Failures(throw=False)
            )
        )(d, a)
    return lambda d, a: jax.vmap(
        lambda di: sj.integrate(system, y0, di, h, method=method, failures=sj.Failures(throw=False))
    )(d)


def count_failed(system, y0, method, h, areas, d, a):
    """Samples whose step failed: `integrate(throw=False)` freezes such a sample, so its last
    two saved states are identical (an untimed extra run)."""
    run = lambda di, ai: sj.integrate(
        system,
        y0,
        di,
        h,
        method=method,
        save_every=1,
        areas=ai if areas else None,
        failures=sj.Failures(throw=False),
    )
    traj = jax.jit(jax.vmap(run))(d, a)
    return int(jnp.sum(jnp.all(traj[:, -1] == traj[:, -2], axis=tuple(range(1, traj.ndim - 1)))))


def time_at(pts, target, order):
    """Run time at RMS error `target` on a method's work-precision line: log-log
    interpolation between the two points that bracket it; else extrapolated from the
    smallest step along the fitted strong order (run time ~ 1/h ~ error^(-1/order)), which
    is steadier than the last segment of noisy timings. **Returns** `(seconds,
    extrapolated)`."""
    e = np.log([r["rms_error"] for r in pts])
    t = np.log([r["time_median_s"] for r in pts])
    lt = math.log(target)
    for i in range(len(pts) - 1):
        if (e[i] - lt) * (e[i + 1] - lt) <= 0 and e[i] != e[i + 1]:
            w = (lt - e[i]) / (e[i + 1] - e[i])
            return float(math.exp(t[i] + w * (t[i + 1] - t[i]))), False
    if order < 0.2:  # no convergence (EulerMaruyama)
        return math.nan, True
    return float(math.exp(t[-1] + (e[-1] - lt) / order)), True


def area_costs(fast):
    """Drawing the areas against drawing the increments alone, per sample-step, for
    s = 2, 3, 5 and h = 2^-6, 2^-8, 2^-10: both jitted, 500 samples x 256 steps."""
    rows = []
    n_samples, n_steps = (50, 64) if fast else (500, 256)
    key = jax.random.key(5)
    keys = _brownian.sample_keys(key, n_samples)
    steps = jnp.arange(n_steps, dtype=jnp.uint32)
    for s in (3,) if fast else (2, 3, 5):
        for k in (8,) if fast else (6, 8, 10):
            h = jnp.asarray(2.0**-k)
            terms = _brownian.levy_area_terms(2.0**-k, s)

            def draws(keys, terms=terms, s=s, h=h):
                return jax.vmap(
                    lambda kk: jax.vmap(
                        lambda n: _brownian.draw(kk, n, h, jnp.inf, jnp.float64, s, terms)
                    )(steps)
                )(keys)

            def incs(keys, s=s, h=h):
                return jax.vmap(
                    lambda kk: jax.vmap(
                        lambda n: _brownian.increment(kk, n, h, jnp.inf, jnp.float64, s)
                    )(steps)
                )(keys)

            t_inc = _common.time_call(jax.jit(incs), keys)[0]
            t_area = _common.time_call(jax.jit(draws), keys)[0]
            per = 1e9 / (n_samples * n_steps)
            rows.append(
                dict(
                    s=s,
                    h=2.0**-k,
                    terms=terms,
                    normals_per_step=2 * s * terms + s + s * (s - 1) // 2 + s,
                    ns_increments=t_inc * per,
                    ns_with_areas=t_area * per,
                    ratio=t_area / t_inc,
                )
            )
            print(
                f"areas s={s} h=2^-{k}: p={terms}, {rows[-1]['normals_per_step']} normals, "
                f"{rows[-1]['ns_increments']:.0f} ns -> {rows[-1]['ns_with_areas']:.0f} ns "
                f"per sample-step ({rows[-1]['ratio']:.2f}x)",
                flush=True,
            )
    return rows


J4 = jnp.asarray([0.6, 0.9, 1.3, 1.7])
_E = np.eye(4)
X4 = 0.5 * np.stack(
    [
        np.outer(_E[0], _E[1]) - np.outer(_E[1], _E[0]),
        np.outer(_E[1], _E[2])
        - np.outer(_E[2], _E[1])
        + 0.3 * (np.outer(_E[0], _E[3]) - np.outer(_E[3], _E[0])),
        np.outer(_E[2], _E[3]) - np.outer(_E[3], _E[2]),
    ]
)
Y4 = 0.3 * jnp.asarray(
    np.array([[0, 1, -0.5, 0.2], [-1, 0, 0.8, -0.4], [0.5, -0.8, 0, 0.6], [-0.2, 0.4, -0.6, 0]])
)


def so4_study(fast):
    """so(4), the generalised rigid body with three SALT noises: IsospectralMidpoint and
    LiePoisson with and without areas, and the Milstein baseline, against
    IsospectralMidpoint with areas at a 64x finer step on the same paths."""
    system = sj.GeneralisedRigidBody(J4, noise=sj.salt_noise(X4))
    n_samples = 16 if fast else 200
    ks = range(3, 5) if fast else range(3, 7)
    n_fine = 2 ** max(ks) * (8 if fast else 64)
    dW, A = draw_paths(jax.random.key(4), n_samples, n_fine, 1.0 / n_fine)
    reference = jax.jit(solver(system, Y4, sj.IsospectralMidpoint(), 1.0 / n_fine, True))(dW, A)
    methods = {
        "IsospectralMidpoint + areas": (sj.IsospectralMidpoint(), True),
        "LiePoisson + areas": (sj.LiePoisson(), True),
        "Milstein + areas": (sj.Milstein(), True),
        "IsospectralMidpoint": (sj.IsospectralMidpoint(), False),
        "LiePoisson": (sj.LiePoisson(), False),
    }
    if fast:  # a smoke run: the two Poisson methods with areas
        methods = {n: methods[n] for n in ("IsospectralMidpoint + areas", "LiePoisson + areas")}
    c0 = np.asarray(system.algebra.casimirs(Y4))
    rows = []
    for name, (method, areas) in methods.items():
        for k in ks:
            n, h = 2**k, 2.0**-k
            d, a = _brownian.coarsen(dW, A, n_fine // n)
            compiled, compile_s = _common.compile_timed(solver(system, Y4, method, h, areas), d, a)
            med, _, _, y = _common.time_call(compiled, d, a)
            err = float(jnp.sqrt(jnp.mean(system.algebra.norm_sq(y - reference))))
            drift = float(np.max(np.abs(np.asarray(system.algebra.casimirs(y)) - c0) / np.abs(c0)))
            rows.append(
                dict(
                    method=name,
                    h=h,
                    rms_error=err,
                    time_median_s=med,
                    compile_s=compile_s,
                    max_rel_casimir_error=drift,
                )
            )
            print(
                f"so(4) {name:28s} h=2^-{k} rms {err:.3e} run {med:.4f} s casimirs {drift:.1e}",
                flush=True,
            )
    summary = []
    for name in methods:
        pts = [r for r in rows if r["method"] == name]
        order = float(
            np.polyfit(np.log([r["h"] for r in pts]), np.log([r["rms_error"] for r in pts]), 1)[0]
        )
        summary.append(
            dict(
                method=name,
                strong_order=order,
                rms_error=pts[-1]["rms_error"],
                time_median_s=pts[-1]["time_median_s"],
                max_rel_casimir_error=max(r["max_rel_casimir_error"] for r in pts),
            )
        )
    return rows, summary, n_samples, max(ks)


def main(argv=None):
    args = parse(argv)
    results = _common.Output(args.out)
    info = results.info
    fast = args.fast
    if args.area_costs_only:
        costs = area_costs(fast)
        md = (
            "Drawing the Lévy areas (`_brownian.draw`, jitted, per sample-step) against the "
            "increments alone.\n\n"
            + _common.markdown_table(
                costs,
                ["s", "h", "terms", "normals_per_step", "ns_increments", "ns_with_areas", "ratio"],
                {"h": ".5f", "ns_increments": ".0f", "ns_with_areas": ".0f", "ratio": ".2f"},
            )
        )
        print("\n" + md)
        results.markdown("several_noises_area_costs", md)
        results.json("several_noises_area_costs", dict(area_costs=costs))
        return
    n_samples = 32 if fast else 500
    ks = range(4, 6) if fast else range(4, 9)
    factor = 8 if fast else 64
    n_fine = 2 ** (max(ks)) * factor
    h_fine = 1.0 / n_fine
    print(
        f"# several noises: SALT rigid body, {n_samples} samples, h = 2^-{min(ks)}..2^-"
        f"{max(ks)}, reference Midpoint with areas at 2^-{int(math.log2(n_fine))}\n"
        f"# {results.measured_on()}, diffrax {info['diffrax']}",
        flush=True,
    )

    # The paths: fine increments and areas, drawn once; a coarse step's are joined by Chen's
    # relation (`_brownian.coarsen`). Every method is timed on precomputed noise.
    dW, A = draw_paths(jax.random.key(0), n_samples, n_fine, h_fine)
    cumulative = jnp.concatenate([jnp.zeros((n_samples, 1, 3)), jnp.cumsum(dW, axis=1)], 1)

    def coarse(n):
        return _brownian.coarsen(dW, A, n_fine // n)

    reference = jax.jit(solver(MODEL, Y0, sj.Midpoint(), h_fine, True))(dW, A)
    ref2 = jax.jit(solver(MODEL, Y0, sj.Midpoint(), 2 * h_fine, True))(*coarse(n_fine // 2))
    ref_error = float(jnp.sqrt(jnp.mean(jnp.sum((ref2 - reference) ** 2, -1))))
    print(
        f"reference's own error (RMS, Midpoint with areas at 2 h_fine vs h_fine): {ref_error:.2e}",
        flush=True,
    )

    # (--fast, a smoke run: without the compositions and Euler-Maruyama, which add nothing
    # the full run does not measure)
    skipped = ("LiePoissonSym2", "LiePoissonSym4", "EulerMaruyama") if fast else ()
    names = (
        [n for n in OURS if n not in skipped]
        + [SCAN_HEUN]
        + ([DIFFRAX_HEUN] if wp.dfx is not None else [])
    )
    rows = []
    for name in names:
        for k in ks:
            n, h = 2**k, 2.0**-k
            if name in OURS:
                method, areas = OURS[name]
                fn, arg = solver(MODEL, Y0, method, h, areas), coarse(n)
            elif name == SCAN_HEUN:
                fn = lambda d, a, h=h: jax.vmap(lambda di: scan_heun(Y0, di, h))(d)
                arg = coarse(n)
            else:
                fn = lambda w, h=h, n=n: jax.vmap(lambda wi: diffrax_heun(wi, h, n, h_fine))(w)
                arg = (cumulative,)
            compiled, compile_s = _common.compile_timed(fn, *arg)
            med, best, reps, y = _common.time_call(compiled, *arg)
            e2 = jnp.sum((y - reference) ** 2, -1)
            casimir = float(
                jnp.max(jnp.abs(jnp.linalg.norm(y, axis=-1) / jnp.linalg.norm(Y0) - 1.0))
            )
            failed = (
                count_failed(MODEL, Y0, OURS[name][0], h, OURS[name][1], *arg)
                if name in OURS and OURS[name][0].can_fail
                else 0
            )
            rows.append(
                dict(
                    method=name,
                    h=h,
                    rms_error=float(jnp.sqrt(jnp.mean(e2))),
                    time_median_s=med,
                    time_min_s=best,
                    compile_s=compile_s,
                    ns_per_sample_step=1e9 * med / (n_samples * n),
                    max_rel_casimir_error=casimir,
                    failed=failed,
                )
            )
            print(
                f"{name:22s} h=2^-{k}  rms {rows[-1]['rms_error']:.3e}  run {med:.4f} s  "
                f"compile {compile_s:.2f} s  casimir {casimir:.1e}  failed {failed}",
                flush=True,
            )
            if failed:
                raise RuntimeError(
                    f"{name} at h = 2^-{k}: {failed} samples failed; their "
                    "frozen states are not data. Use smaller steps."
                )
    results.csv("several_noises", rows)

    # Strong orders; per sample-step cost at the finest h; run time at the target error.
    summary = []
    h_last = 2.0 ** -max(ks)
    base = next(
        (r["ns_per_sample_step"] for r in rows if r["method"] == DIFFRAX_HEUN and r["h"] == h_last),
        None,
    )
    for name in names:
        pts = [r for r in rows if r["method"] == name]
        order = float(
            np.polyfit(np.log([r["h"] for r in pts]), np.log([r["rms_error"] for r in pts]), 1)[0]
        )
        t_target, extrapolated = time_at(pts, TARGET, order)
        last = pts[-1]
        summary.append(
            dict(
                method=name,
                strong_order=order,
                rms_error=last["rms_error"],
                ns_per_sample_step=last["ns_per_sample_step"],
                vs_diffrax_heun=(last["ns_per_sample_step"] / base if base else None),
                compile_s=last["compile_s"],
                time_at_target_s=t_target,
                extrapolated=extrapolated,
                max_rel_casimir_error=max(r["max_rel_casimir_error"] for r in pts),
            )
        )
    at = {r["method"]: r["time_at_target_s"] for r in summary}
    fastest = min(POISSON_AREAS, key=lambda n: at[n])
    targets = dict(
        target_rms=TARGET,
        fastest_poisson_with_areas=fastest,
        seconds=at[fastest],
        baseline_seconds=at[BASELINE],
        vs_baseline=at[fastest] / at[BASELINE],
        diffrax_heun_seconds=at.get(DIFFRAX_HEUN),
        speedup_vs_diffrax_heun=(at[DIFFRAX_HEUN] / at[fastest] if DIFFRAX_HEUN in at else None),
        speedup_vs_scan_heun=at[SCAN_HEUN] / at[fastest],
    )

    # Weak orders against the same reference (coupled differences): with areas for the
    # methods that use them, without for the rest.
    def observable(y):
        return jnp.stack([MODEL.hamiltonian(y), y[2] ** 2])

    weak_names = (
        ("Midpoint + areas", "SaltSplitting")
        if fast
        else (
            "LiePoisson + areas",
            "Midpoint + areas",
            "SaltSplitting + areas",
            "Milstein + areas",
            "Midpoint",
            "SaltSplitting",
            "Heun",
        )
    )
    weak = {}
    for areas in (True, False):
        chosen = {n: OURS[n][0] for n in weak_names if OURS[n][1] == areas}
        if chosen:
            res = sj.weak_convergence(
                MODEL,
                Y0,
                t1=1.0,
                dts=[2.0**-k for k in ks],
                n_samples=n_samples,
                key=jax.random.key(0),
                observable=observable,
                methods=chosen,
                driver=sj.BrownianMotion(levy_area=areas),
                failures=sj.Failures(retry_substeps=4),
                reference=sj.Reference(sj.Midpoint(), factor=factor),
            )
            weak.update({n: (res.order[n], res.bias[n], res.ci[n]) for n in chosen})
    for row in summary:
        row.update(weak_order_H=math.nan, weak_order_y3sq=math.nan, weak_resolved="—")
        if row["method"] in weak:
            order, bias, ci = weak[row["method"]]
            resolved = np.abs(bias) > ci
            row["weak_resolved"] = f"{int(resolved.sum())}/{resolved.size}"
            # an order is a slope of resolved biases: printed only where every one is
            if resolved[:, 0].all():
                row["weak_order_H"] = float(order[0])
            if resolved[:, 1].all():
                row["weak_order_y3sq"] = float(order[1])

    # Long time: Casimir drift along the path and E[H(y_T)].
    t_long, h_long, n_long = (4.0, 2.0**-4, 8) if fast else (100.0, 2.0**-6, 100)
    key = jax.random.key(1)
    long_rows = []
    long_names = (
        ("SaltSplitting + areas", "Midpoint", "Heun")
        if fast
        else POISSON + ("Milstein + areas", "Heun", "EulerMaruyama")
    )
    for name in long_names:
        method, areas = OURS[name]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # failures are counted below
            sol = sj.simulate(
                MODEL,
                Y0,
                t1=t_long,
                dt=h_long,
                n_samples=n_long,
                key=key,
                method=method,
                save_every=int(round(1 / h_long)),
                driver=sj.BrownianMotion(levy_area=areas),
                failures=sj.Failures(throw=False),
            )
        ys = np.asarray(sol.ys)
        ok = np.asarray(sol.result) == 0  # failed samples (EulerMaruyama blows up) left out
        if ok.sum() >= 2:
            drift = np.abs(np.linalg.norm(ys[ok], axis=-1) / float(jnp.linalg.norm(Y0)) - 1).max()
            energy = np.asarray(MODEL.hamiltonian(ys[ok, -1]))
            mean, ci = energy.mean(), 1.96 * energy.std(ddof=1) / math.sqrt(ok.sum())
        else:
            drift = mean = ci = math.nan
        long_rows.append(
            dict(
                method=name,
                failed=int((~ok).sum()),
                max_rel_casimir_drift=float(drift),
                mean_H_T=float(mean),
                ci95_H_T=float(ci),
            )
        )
        print(
            f"long time {name:22s} casimir drift {drift:.1e}  E[H(T)] "
            f"{long_rows[-1]['mean_H_T']:.4f} ± {long_rows[-1]['ci95_H_T']:.4f}",
            flush=True,
        )

    costs = area_costs(fast)
    so4_rows, so4_summary, so4_n, so4_k = so4_study(fast)

    md = (
        f"SALT rigid body, I = (1, 2, 3), three noises, {n_samples} samples, T = 1; reference "
        f"Midpoint with Lévy areas at 2^-{int(math.log2(n_fine))} on the same paths (its own "
        f"error {ref_error:.1e}). Every method runs on precomputed increments (and areas) "
        f"of the same paths. Per sample-step cost at h = 2^-{max(ks)}; run time at RMS "
        f"error {TARGET:g} interpolated on each method's work-precision line (* "
        f"extrapolated from the smallest step along the fitted order).\n\n"
    )
    for row in summary:
        row["time_at_target"] = f"{row['time_at_target_s']:.3g}" + (
            "*" if row["extrapolated"] else ""
        )
    md += _common.markdown_table(
        summary,
        [
            "method",
            "strong_order",
            "weak_order_H",
            "weak_order_y3sq",
            "weak_resolved",
            "rms_error",
            "ns_per_sample_step",
            "vs_diffrax_heun",
            "compile_s",
            "time_at_target",
            "max_rel_casimir_error",
        ],
        {
            "strong_order": ".2f",
            "weak_order_H": ".2f",
            "weak_order_y3sq": ".2f",
            "rms_error": ".2e",
            "ns_per_sample_step": ".0f",
            "vs_diffrax_heun": ".2f",
            "compile_s": ".2f",
            "max_rel_casimir_error": ".1e",
        },
    ).replace("| nan ", "| — ")
    md += (
        f"\nAt RMS error {TARGET:g}: the fastest Poisson method with areas, {fastest}, "
        f"takes {targets['seconds']:.3g} s; the order-1 baseline {BASELINE} "
        f"{targets['baseline_seconds']:.3g} s ({targets['vs_baseline']:.2f}x)"
        + (
            f"; diffrax Heun {targets['diffrax_heun_seconds']:.3g} s "
            f"({targets['speedup_vs_diffrax_heun']:.0f}x slower)"
            if targets["speedup_vs_diffrax_heun"]
            else ""
        )
        + f"; lax.scan Heun {targets['speedup_vs_scan_heun']:.0f}x slower.\n"
    )
    md += (
        "\nDrawing the Lévy areas (`_brownian.draw`, jitted, per sample-step) against the "
        "increments alone:\n\n"
        + _common.markdown_table(
            costs,
            ["s", "h", "terms", "normals_per_step", "ns_increments", "ns_with_areas", "ratio"],
            {"h": ".5f", "ns_increments": ".0f", "ns_with_areas": ".0f", "ratio": ".2f"},
        )
    )
    md += (
        f"\nso(4), generalised rigid body with three SALT noises, {so4_n} samples, "
        f"T = 1, values at h = 2^-{so4_k}; reference IsospectralMidpoint with areas at a "
        f"64x finer step:\n\n"
        + _common.markdown_table(
            so4_summary,
            ["method", "strong_order", "rms_error", "time_median_s", "max_rel_casimir_error"],
            {
                "strong_order": ".2f",
                "rms_error": ".2e",
                "time_median_s": ".4f",
                "max_rel_casimir_error": ".1e",
            },
        )
    )
    md += (
        f"\nLong time: T = {t_long:g}, h = 2^{int(math.log2(h_long))}, {n_long} samples.\n\n"
        + _common.markdown_table(
            long_rows,
            ["method", "failed", "max_rel_casimir_drift", "mean_H_T", "ci95_H_T"],
            {"max_rel_casimir_drift": ".1e", "mean_H_T": ".4f", "ci95_H_T": ".4f"},
        ).replace("| nan ", "| — ")
    )
    print("\n" + md)
    results.markdown("several_noises", md, f", diffrax {info['diffrax']}.")
    results.json(
        "several_noises",
        dict(
            reference_error=ref_error,
            rows=rows,
            summary=summary,
            targets=targets,
            area_costs=costs,
            so4_rows=so4_rows,
            so4_summary=so4_summary,
            long_time=long_rows,
        ),
    )

    plt = _common.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    markers = "osD^vx*P<>h"
    for i, name in enumerate(names):
        pts = [r for r in rows if r["method"] == name]
        style = "-" if name in POISSON_AREAS or name == BASELINE else "--"
        for ax, key in ((axes[0], "h"), (axes[1], "time_median_s")):
            ax.loglog(
                [r[key] for r in pts],
                [r["rms_error"] for r in pts],
                style,
                marker=markers[i % len(markers)],
                color=f"C{i % 10}",
                label=name,
            )
    for ax in axes:
        ax.axhline(ref_error, color="gray", ls=":", label="reference's own error")
        ax.axhline(TARGET, color="k", lw=0.5)
        ax.set_ylabel("RMS error at T = 1")
    axes[0].set_xlabel("step h")
    axes[0].set_title("strong error: with Lévy areas (solid) order 1, without ½")
    axes[1].set_xlabel("run time, s (median)")
    axes[1].set_title(f"work-precision, {n_samples} samples")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "several_noises.png"), dpi=120)


if __name__ == "__main__":
    main()
