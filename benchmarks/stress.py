#!/usr/bin/env python
"""Stress matrix: where each method fails, and whether a failure is ever silent.

One factor at a time around a base case, plus a few hard corners (not the full product):

- base: the paper's body and c = 0.2, y0 along the paper's (0.7, 0.7, 0) with |y0| = 0.99,
  h = 2^-5, T = 1, float64;
- step h in {1e-3, 1e-2, 2^-5, 0.1, 0.25, 0.5}; c in {0, 0.2, 1, 3};
- |y0| in {0.1, 0.9, 0.99, 0.999} and 2 (LiePoisson(scale=3) there: |y0| >= 1 needs it);
- y0 next to each principal axis (major, minor, the unstable intermediate) and on the
  separatrix through the intermediate axis;
- inertia (1, 2, 3), (1, 10, 100), (1, 30, 1000), and the axisymmetric (1, 1, 2), (2, 2, 1),
  with y0 along a generic direction (0.6, 0.5, 0.62)/|.| (the paper's is a fixed point of
  the axisymmetric ones);
- horizon T in {10, 100, 1e4} (few samples);
- float32 (the system's dtype decides; increments are drawn in float32) at the base case,
  at h = 0.25 and at |y0| = 0.999;
- hard corners combining the above.

Every method (LiePoisson, Midpoint, Strang, EulerMaruyama, Exact, and LiePoisson with the
driver's `retry_substeps=4`) runs every cell through the public `simulate(..., throw=False,
newton_stats=True)`. Recorded per cell and method: failed samples; NaN/Inf entries of the
states of samples *not* flagged as failed (must be 0) and of flagged ones (must be 0 too:
a failed sample keeps its last good state); Newton iterations (mean per step, max);
relative Casimir drift `max |C(y_T)/C(y0) - 1|` and Hamiltonian error
`max |H(y_T)/H(y0) - 1|` over the successful samples (the exact solution conserves both);
the RMS error at T against the exact solution `phi_{T + cW_T}(y0)` (from the very same
increments, `BrownianMotion().increments` in the run's dtype, evaluated in float64); wall time with
compilation.

A second matrix does the same for **several noises**: the rigid body I = (1, 2, 3) with three
SALT noises chi = a [[1, 0, 0], [0, 1, 0], [0, 0.5, 1]] (base a = 0.4), y0 along
(0.6, 0.5, 0.3) with |y0| = 0.9, h = 2^-5, T = 1; one factor at a time: a in {0.1, 1, 3},
h in {1e-2, 0.1, 0.25, 0.5}, |y0| in {0.5, 0.99, 0.999}, T in {10, 100, 1e4}, float32, and
hard corners. Methods LiePoisson (with and without retry), Midpoint, SaltSplitting, Heun,
EulerMaruyama. No exact solution: recorded are the failed samples with their reasons (the
`RESULTS` codes), NaN/Inf entries (flagged or not) and the Casimir drift.

Writes `stress.csv`, `stress.json` and `stress.md` (the Markdown tables) into `--out`
(`stress_noises.csv` for the second matrix).

    python benchmarks/stress.py [--fast] [--out DIR]
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

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
# The checkout this script lives in, ahead of any installed slps_jax (an editable install of
# another worktree would otherwise win).
sys.path.insert(1, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402

PAPER_I = tuple(float(x) for x in sj.RigidBody.paper().inertia)
BASE = dict(
    h=2.0**-5,
    c=0.2,
    r=0.99,
    direction="paper",
    inertia=PAPER_I,
    T=1.0,
    dtype="float64",
    n_samples=100,
)
METHODS = ("LiePoisson", "LiePoisson+retry4", "Midpoint", "Strang", "EulerMaruyama", "Exact")


def direction(name, inertia):
    """A unit vector: the paper's direction, next to a principal axis, or on the separatrix."""
    inertia = np.asarray(inertia, float)
    order = np.argsort(inertia)  # minor (smallest I), intermediate, major (largest I)
    if name == "paper":
        v = np.array([0.7, 0.7, 0.0])
    elif name == "generic":
        # Off every symmetry plane: the paper's direction is a relative equilibrium of the
        # axisymmetric bodies (1, 1, 2) and (2, 2, 1), whose flow would then be trivial.
        v = np.array([0.6, 0.5, 0.62])
    elif name.startswith("near_"):
        axis = {"near_minor": order[0], "near_intermediate": order[1], "near_major": order[2]}[name]
        v = np.full(3, 1e-3)
        v[axis] = 1.0
    elif name == "separatrix":
        # |y|^2 = 2 H I_mid: y_a^2 (1/I_mid - 1/I_a) = y_b^2 (1/I_b - 1/I_mid) for the
        # minor axis a... b and major, with any component along the intermediate axis.
        a, m, b = order[0], order[1], order[2]
        v = np.zeros(3)
        v[b] = 1.0
        v[a] = math.sqrt((1 / inertia[m] - 1 / inertia[b]) / (1 / inertia[a] - 1 / inertia[m]))
        v[m] = 0.3
    else:
        raise ValueError(name)
    return v / np.linalg.norm(v)


def cells(fast):
    """(sweep, label, settings) for each cell of the matrix."""
    if fast:
        return [
            (
                "corner",
                "h=0.25 c=3 |y0|=0.999 separatrix",
                dict(h=0.25, c=3.0, r=0.999, direction="separatrix"),
            ),
        ]
    out = [("base", "base", {})]
    for h in (1e-3, 1e-2, 0.1, 0.25, 0.5):
        out.append(("h", f"h={h:g}", dict(h=h)))
    for c in (0.0, 1.0, 3.0):
        out.append(("c", f"c={c:g}", dict(c=c)))
    for r in (0.1, 0.9, 0.999, 2.0):
        out.append(("|y0|", f"|y0|={r:g}", dict(r=r)))
    for d in ("near_major", "near_minor", "near_intermediate", "separatrix"):
        out.append(("y0 direction", d, dict(direction=d)))
    for inertia in (
        (1.0, 2.0, 3.0),
        (1.0, 10.0, 100.0),
        (1.0, 30.0, 1000.0),
        (1.0, 1.0, 2.0),
        (2.0, 2.0, 1.0),
    ):
        out.append(
            (
                "inertia",
                "I=" + ",".join(f"{x:g}" for x in inertia),
                dict(inertia=inertia, direction="generic"),
            )
        )
    out.append(("T", "T=10", dict(T=10.0, n_samples=20)))
    out.append(("T", "T=100", dict(T=100.0, h=2.0**-4, n_samples=8)))
    out.append(("T", "T=1e4", dict(T=1e4, h=2.0**-3, n_samples=4)))
    out.append(("dtype", "float32", dict(dtype="float32")))
    out.append(("dtype", "float32 h=0.25", dict(dtype="float32", h=0.25)))
    out.append(("dtype", "float32 |y0|=0.999", dict(dtype="float32", r=0.999)))
    out.append(("corner", "h=0.5 c=3 |y0|=0.999", dict(h=0.5, c=3.0, r=0.999)))
    out.append(
        (
            "corner",
            "h=0.25 c=1 near_intermediate I=1,30,1000",
            dict(h=0.25, c=1.0, direction="near_intermediate", inertia=(1.0, 30.0, 1000.0)),
        )
    )
    out.append(
        (
            "corner",
            "h=0.25 c=3 |y0|=0.999 separatrix",
            dict(h=0.25, c=3.0, r=0.999, direction="separatrix"),
        )
    )
    out.append(("corner", "h=0.1 c=1 T=100", dict(h=0.1, c=1.0, T=100.0, n_samples=8)))
    out.append(
        ("corner", "float32 h=0.5 c=3 |y0|=0.999", dict(dtype="float32", h=0.5, c=3.0, r=0.999))
    )
    return out


def make_method(name, r):
    scale = 1.5 * r if r >= 1 else None
    return {
        "LiePoisson": lambda: (sj.LiePoisson(scale=scale), None),
        "LiePoisson+retry4": lambda: (sj.LiePoisson(scale=scale), 4),
        "Midpoint": lambda: (sj.Midpoint(), None),
        "Strang": lambda: (sj.Strang(), None),
        "EulerMaruyama": lambda: (sj.EulerMaruyama(), None),
        "Exact": lambda: (sj.Exact(), None),
    }[name]()


def exact_reference(settings, y0, key, n_steps):
    """y(T) = phi_{T + c W_T}(y0) in float64, with W_T the sum of the run's own increments."""
    dtype = jnp.float32 if settings["dtype"] == "float32" else jnp.float64
    dW = sj.BrownianMotion().increments(
        key, n_steps, settings["h"], n_samples=settings["n_samples"], dtype=dtype
    )
    w_t = jnp.sum(dW.astype(jnp.float64), axis=1)
    system = sj.RigidBody(jnp.asarray(settings["inertia"], jnp.float64), settings["c"])
    y0 = jnp.asarray(y0, jnp.float64)
    return np.asarray(
        jax.jit(jax.vmap(lambda w: sj.exact_solution(system, y0, settings["T"], w)))(w_t)
    )


def run_cell(settings, method_name, seed=0):
    s = settings
    dtype = np.float32 if s["dtype"] == "float32" else np.float64
    y0 = (s["r"] * direction(s["direction"], s["inertia"])).astype(dtype)
    system = sj.RigidBody(np.asarray(s["inertia"], dtype), dtype(s["c"]))
    method, retry = make_method(method_name, s["r"])
    n_steps = int(round(s["T"] / s["h"]))
    key = jax.random.key(seed)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # failures are counted below
        sol = sj.simulate(
            system,
            y0,
            t1=s["T"],
            dt=s["h"],
            n_samples=s["n_samples"],
            key=key,
            method=method,
            newton_stats=True,
            failures=sj.Failures(retry_substeps=retry, throw=False),
        )
        ys = np.asarray(jax.block_until_ready(sol.ys), np.float64)
    wall = time.perf_counter() - start
    failed = np.asarray(sol.result) != sj.RESULTS.successful
    finite = np.isfinite(ys).all(axis=(1, 2))
    y_t = ys[:, -1]
    ok = ~failed & finite
    y0_64 = y0.astype(np.float64)
    y_t = np.where(ok[:, None], y_t, 0.0)  # (an unflagged EM state may still be huge)
    inertia = np.asarray(s["inertia"], float)
    c0, h0 = 0.5 * y0_64 @ y0_64, 0.5 * np.sum(y0_64**2 / inertia)
    with np.errstate(over="ignore", invalid="ignore"):
        cas = np.abs(0.5 * np.sum(y_t**2, -1) / c0 - 1)[ok]
        ham = np.abs(0.5 * np.sum(y_t**2 / inertia, -1) / h0 - 1)[ok]
    y_ref = exact_reference(s, y0, key, n_steps)
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.sqrt(np.mean(np.sum((y_t[ok] - y_ref[ok]) ** 2, -1))) if ok.any() else math.nan
    st = sol.stats
    return {
        "n_samples": s["n_samples"],
        "n_steps": n_steps,
        "failed": int(failed.sum()),
        "first_fail_step": int(np.min(np.asarray(sol.fail_step)[failed])) if failed.any() else -1,
        "retried_steps": int(st["n_retried_steps"]) if "n_retried_steps" in st else 0,
        "nonfinite_unflagged": int((~np.isfinite(ys[~failed])).sum()),
        "nonfinite_flagged": int((~np.isfinite(ys[failed])).sum()),
        "newton_it_mean": float(st["newton_iterations_mean"]),
        "newton_it_max": int(st["newton_iterations_max"]),
        "residual_max": float(st["residual_max"]),
        "casimir_drift": float(cas.max()) if cas.size else math.nan,
        "hamiltonian_error": float(ham.max()) if ham.size else math.nan,
        "rms_error_vs_exact": float(err),
        "wall_s": wall,
    }


NOISE_BASE = dict(h=2.0**-5, a=0.4, r=0.9, T=1.0, dtype="float64", n_samples=100)
NOISE_METHODS = (
    "LiePoisson",
    "LiePoisson+retry4",
    "Midpoint",
    "SaltSplitting",
    "Heun",
    "EulerMaruyama",
)
SALT_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])


def noise_cells(fast):
    """(sweep, label, settings) of the several-noises matrix."""
    corner = ("corner", "h=0.25 a=1 |y0|=0.999", dict(h=0.25, a=1.0, r=0.999))
    if fast:
        return [corner]
    out = [("base", "base", {})]
    out += [("noise", f"a={a:g}", dict(a=a)) for a in (0.1, 1.0, 3.0)]
    out += [("h", f"h={h:g}", dict(h=h)) for h in (1e-2, 0.1, 0.25, 0.5)]
    out += [("|y0|", f"|y0|={r:g}", dict(r=r)) for r in (0.5, 0.99, 0.999)]
    out += [
        ("T", "T=10", dict(T=10.0, n_samples=20)),
        ("T", "T=100", dict(T=100.0, n_samples=8)),
        ("T", "T=1e4", dict(T=1e4, h=2.0**-3, n_samples=4)),
        ("dtype", "float32", dict(dtype="float32")),
        ("dtype", "float32 h=0.25 a=1", dict(dtype="float32", h=0.25, a=1.0)),
        corner,
        ("corner", "h=0.5 a=3 |y0|=0.99", dict(h=0.5, a=3.0, r=0.99)),
        ("corner", "h=0.1 a=1 T=100", dict(h=0.1, a=1.0, T=100.0, n_samples=8)),
    ]
    return out


def run_noise_cell(settings, method_name, seed=0):
    s = settings
    dtype = np.float32 if s["dtype"] == "float32" else np.float64
    y0 = (s["r"] * np.array([0.6, 0.5, 0.3]) / np.linalg.norm([0.6, 0.5, 0.3])).astype(dtype)
    system = sj.RigidBody(
        np.array([1.0, 2.0, 3.0], dtype), noise=sj.salt_noise((s["a"] * SALT_AXES).astype(dtype))
    )
    method, retry = {
        "LiePoisson": (sj.LiePoisson(), None),
        "LiePoisson+retry4": (sj.LiePoisson(), 4),
        "Midpoint": (sj.Midpoint(), None),
        "SaltSplitting": (sj.SaltSplitting(), None),
        "Heun": (sj.Heun(), None),
        "EulerMaruyama": (sj.EulerMaruyama(), None),
    }[method_name]
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # failures are counted below
        sol = sj.simulate(
            system,
            y0,
            t1=s["T"],
            dt=s["h"],
            n_samples=s["n_samples"],
            key=jax.random.key(seed),
            method=method,
            failures=sj.Failures(retry_substeps=retry, throw=False),
        )
        ys = np.asarray(jax.block_until_ready(sol.ys), np.float64)
    wall = time.perf_counter() - start
    result = np.asarray(sol.result)
    failed = result != sj.RESULTS.successful
    reasons = ", ".join(
        f"{int((result == code).sum())} {sj.RESULTS.name(code)}"
        for code in np.unique(result[failed])
    )
    ok = ~failed & np.isfinite(ys).all(axis=(1, 2))
    with np.errstate(over="ignore", invalid="ignore"):
        cas = np.abs(np.linalg.norm(ys[ok], axis=-1) / np.linalg.norm(y0.astype(float)) - 1)
    return {
        "n_samples": s["n_samples"],
        "n_steps": int(round(s["T"] / s["h"])),
        "failed": int(failed.sum()),
        "reasons": reasons or "-",
        "nonfinite_unflagged": int((~np.isfinite(ys[~failed])).sum()),
        "nonfinite_flagged": int((~np.isfinite(ys[failed])).sum()),
        "casimir_drift": float(cas.max()) if cas.size else math.nan,
        "wall_s": wall,
    }


def parse(argv):
    p = _common.parser(
        __doc__,
        "a smoke run for the test suite: one hard corner, every method, 8 samples",
    )
    p.add_argument("--methods", default=None, help="comma-separated subset of " + ",".join(METHODS))
    return p.parse_args(argv)


def md(text):
    """A table cell: `|` (as in |y0|) would end the cell."""
    return str(text).replace("|", "\\|")


def compact_tables(rows, methods):
    """Two Markdown tables with one row per cell: failures (and Newton work), invariants."""
    cells_ = list(dict.fromkeys(r["cell"] for r in rows))
    by = {(r["cell"], r["method"]): r for r in rows}
    short = {
        "LiePoisson": "LP",
        "LiePoisson+retry4": "LP+retry4",
        "Midpoint": "Midpoint",
        "Strang": "Strang",
        "EulerMaruyama": "EM",
        "Exact": "Exact",
    }
    ms = [m for m in METHODS if m in methods]

    def get(cell, m):
        return by.get((cell, m))

    head = (
        "| cell | n | "
        + " | ".join(f"{short[m]} failed" for m in ms)
        + " | LP Newton it mean/max | LP+retry4 retried steps, it max | NaN/Inf |\n|"
        + "---|" * (len(ms) + 5)
        + "\n"
    )
    body = ""
    for cell in cells_:
        any_row = next(r for r in rows if r["cell"] == cell)
        lp, lpr = get(cell, "LiePoisson"), get(cell, "LiePoisson+retry4")
        nonfinite = sum(
            r["nonfinite_unflagged"] + r["nonfinite_flagged"] for r in rows if r["cell"] == cell
        )
        fails = [str(get(cell, m)["failed"]) if get(cell, m) else "" for m in ms]
        lp_it = f"{lp['newton_it_mean']:.1f} / {lp['newton_it_max']}" if lp else ""
        lpr_it = f"{lpr['retried_steps']}, {lpr['newton_it_max']}" if lpr else ""
        body += f"| {md(cell)} | {any_row['n_samples']} | " + " | ".join(fails + [lp_it, lpr_it])
        body += f" | {nonfinite} |\n"
    failures = head + body

    head = (
        "| cell | "
        + " | ".join(f"{short[m]} Casimir / H" for m in ms)
        + " |\n|"
        + "---|" * (len(ms) + 1)
        + "\n"
    )
    body = ""
    for cell in cells_:
        cols = []
        for m in ms:
            r = get(cell, m)
            cols.append(
                ""
                if r is None
                else f"{r['casimir_drift']:.0e} / {r['hamiltonian_error']:.0e}"
                if r["casimir_drift"] == r["casimir_drift"]
                else "all failed"
            )
        body += f"| {md(cell)} | " + " | ".join(cols) + " |\n"
    return failures, head + body


COLUMNS = [
    "sweep",
    "cell",
    "method",
    "failed",
    "nonfinite_unflagged",
    "newton_it_mean",
    "newton_it_max",
    "casimir_drift",
    "hamiltonian_error",
    "rms_error_vs_exact",
]
FORMATS = {
    "newton_it_mean": ".1f",
    "casimir_drift": ".1e",
    "hamiltonian_error": ".1e",
    "rms_error_vs_exact": ".1e",
}


def main(argv=None):
    args = parse(argv)
    methods = args.methods.split(",") if args.methods else list(METHODS)
    results = _common.Output(args.out)
    rows = []
    start = time.perf_counter()
    for sweep, label, change in cells(args.fast):
        settings = dict(BASE, **change)
        if args.fast:
            settings["n_samples"] = min(settings["n_samples"], 8)
        for name in methods:
            row = {
                "sweep": sweep,
                "cell": label,
                "method": name,
                "h": settings["h"],
                "c": settings["c"],
                "r": settings["r"],
                "direction": settings["direction"],
                "inertia": ",".join(f"{x:g}" for x in settings["inertia"]),
                "T": settings["T"],
                "dtype": settings["dtype"],
            }
            row.update(run_cell(settings, name))
            rows.append(row)
            print(
                f"{label:45s} {name:18s} failed {row['failed']:3d}/{row['n_samples']:<3d} "
                f"nonfinite {row['nonfinite_unflagged']} "
                f"it {row['newton_it_mean']:5.1f}/{row['newton_it_max']:3d} "
                f"C {row['casimir_drift']:.1e} H {row['hamiltonian_error']:.1e} "
                f"err {row['rms_error_vs_exact']:.1e} ({row['wall_s']:.1f} s)",
                flush=True,
            )
    total = time.perf_counter() - start
    summary = {
        "fast": args.fast,
        "wall_s": total,
        "base": {k: v for k, v in BASE.items()},
        "nonfinite_total": sum(r["nonfinite_unflagged"] + r["nonfinite_flagged"] for r in rows),
        "rows": rows,
    }
    results.csv("stress", rows)
    results.json("stress", summary)
    noise_rows = []
    for sweep, label, change in noise_cells(args.fast):
        settings = dict(NOISE_BASE, **change)
        if args.fast:
            settings["n_samples"] = min(settings["n_samples"], 8)
        for name in NOISE_METHODS:
            row = {"sweep": sweep, "cell": label, "method": name, **settings}
            row.update(run_noise_cell(settings, name))
            noise_rows.append(row)
            print(
                f"[noises] {label:28s} {name:18s} failed {row['failed']:3d}/"
                f"{row['n_samples']:<3d} ({row['reasons']}) nonfinite "
                f"{row['nonfinite_unflagged']}/{row['nonfinite_flagged']} "
                f"C {row['casimir_drift']:.1e} ({row['wall_s']:.1f} s)",
                flush=True,
            )
    total = time.perf_counter() - start
    summary["wall_s"] = total
    summary["nonfinite_total"] += sum(
        r["nonfinite_unflagged"] + r["nonfinite_flagged"] for r in noise_rows
    )
    summary["noise_rows"] = noise_rows
    results.csv("stress_noises", noise_rows)
    results.json("stress", summary)
    table = _common.markdown_table([dict(r, cell=md(r["cell"])) for r in rows], COLUMNS, FORMATS)
    failures, invariants = compact_tables(rows, methods)
    noise_table = _common.markdown_table(
        [dict(r, cell=md(r["cell"])) for r in noise_rows],
        [
            "cell",
            "method",
            "n_samples",
            "failed",
            "reasons",
            "nonfinite_unflagged",
            "casimir_drift",
        ],
        {"casimir_drift": ".1e"},
    )
    results.markdown(
        "stress",
        "### Failed samples, Newton work, non-finite values\n\n"
        + failures
        + "\n### Largest relative Casimir drift / Hamiltonian error at T "
        "(successful samples)\n\n"
        + invariants
        + "\n### Every run\n\n"
        + table
        + "\n### Several noises: failures with their reasons, Casimir drift\n\n"
        + noise_table,
    )
    print(f"\nNaN/Inf entries in any returned state: {summary['nonfinite_total']}")
    print(f"stress matrix: {len(rows) + len(noise_rows)} runs in {total:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
