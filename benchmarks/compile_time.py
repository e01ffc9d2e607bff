"""Compile time of every method: trace+lower, XLA compile, StableHLO size.

For `jax.jit(jax.vmap(integrate))` on shared increments and for `simulate` (increments drawn
inside), paper setup, float64; diffrax Heun on the same increments is the reference, measured
in the same run. Each case runs in a fresh process (`--isolate`, default) so that no tracing
cache of an earlier case helps a later one: what a notebook user pays for a new method.

    python benchmarks/compile_time.py                 # all methods, 500 samples x 512 steps
    python benchmarks/compile_time.py --methods LiePoisson --fast
    python benchmarks/compile_time.py --ab-retry none --methods LiePoisson --how simulate
                                                      # the default retry against none
    python benchmarks/compile_time.py --system salt --ab OLD_PYTHON --python NEW_PYTHON
                                                      # two installations, SALT with areas

`--system`: `rigid` (the paper's body, `c = 0.2`; the default), `salt` (the rigid body with
three SALT noises and, for the methods that use them, their Lévy areas), `so4` (the
generalised rigid body on so(4), `c = 0.2`) or `su16` (Euler–Zeitlin on su(16), `c = 0.2`,
an initial vorticity of spectral norm 0.5). A method a system cannot serve is skipped. The
Heun baselines run on `rigid` only.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

METHODS = [
    "LiePoisson",
    "LiePoissonSym2",
    "LiePoissonSym4",
    "Midpoint",
    "IsospectralMidpoint",
    "Strang",
    "Strang4",
    "SaltSplitting",
    "Exact",
    "Heun",
    "Milstein",
    "EulerMaruyama",
]
REFERENCE = "diffrax Heun"
SCAN_HEUN = "lax.scan Heun"


def _lines(lowered):
    return lowered.as_text().count("\n")


SYSTEMS = ("rigid", "salt", "so4", "su16")


def _system(sj, name):
    """The system and initial value of `--system`."""
    import numpy as np

    if name == "salt":
        chi = 0.4 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
        return sj.RigidBody([1.0, 2.0, 3.0], noise=sj.salt_noise(chi)), np.array([0.6, 0.5, 0.3])
    if name == "so4":
        y0 = sj.so(4).from_coordinates(np.array([0.3, -0.2, 0.1, 0.25, 0.15, -0.1]))
        return sj.GeneralisedRigidBody([1.0, 2.0, 3.0, 4.0], c=0.2), np.asarray(y0)
    if name == "su16":  # Euler–Zeitlin, a traceless skew-Hermitian state of spectral norm 0.5
        rng = np.random.default_rng(0)
        z = rng.normal(size=(16, 16)) + 1j * rng.normal(size=(16, 16))
        w = z - z.conj().T
        w -= np.trace(w) / 16 * np.eye(16)
        return sj.EulerZeitlin(16, c=0.2), 0.5 * w / np.linalg.norm(w, 2)
    return sj.RigidBody.paper(), np.asarray(sj.PAPER_Y0)


def measure(name, how, n_samples, n_steps, retry=None, system_name="rigid"):
    """Seconds to trace+lower and to compile, and StableHLO lines, of one case.
    `retry`: `None` for the library's default `retry_substeps`, else `"none"` or `"k"`."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import slps_jax as sj

    system, y0 = _system(sj, system_name)
    y0 = jnp.asarray(y0)
    dt = 2.0**-9
    dW = jax.random.normal(jax.random.key(0), (n_samples, n_steps)) * dt**0.5
    if name in (REFERENCE, SCAN_HEUN):
        if how == "simulate" or system_name != "rigid":
            return None
        import work_precision as wp

        if name == SCAN_HEUN:
            fn = jax.vmap(lambda dw: wp.scan_heun(system, y0, dw, dt))
            args = (dW,)
        else:
            w = jnp.concatenate([jnp.zeros((n_samples, 1)), jnp.cumsum(dW, axis=1)], axis=1)
            fn = jax.vmap(
                lambda wi: wp.diffrax_final(
                    system, y0, wp.IncrementPath(wi, dt), wp.dfx.Heun(), dt, n_steps
                )
            )
            args = (w,)
    else:
        # a class name, or a constructor call such as "LiePoisson(unroll=3)"
        method = eval(name if "(" in name else name + "()", {"__builtins__": {}}, vars(sj))
        # (the failures' keywords: `failures=` now, `throw=`, `retry_substeps=` before it)
        substeps = (
            {} if retry is None else {"retry_substeps": None if retry == "none" else int(retry)}
        )
        if hasattr(sj, "Failures"):
            opts = {"failures": sj.Failures(throw=False, **substeps)}
        else:
            opts = {"throw": False, **substeps}
        if how == "integrate":
            # (several noises: drawn with the library, with the areas for a method that uses them)
            areas = system.n_noises > 1 and method.uses_levy_area()
            if system.n_noises > 1:
                # (the driver's method now, the function `brownian_increments` before it)
                draw = getattr(sj, "brownian_increments", None) or sj.BrownianMotion().increments
                dW = draw(
                    jax.random.key(0),
                    n_steps,
                    dt,
                    n_samples=n_samples,
                    n_noises=system.n_noises,
                    levy_area=areas,
                )
            args = dW if areas else (dW,)
            # (the areas' keyword: `areas` now, `levy_area` in installations before it)
            named = (
                "areas" if "areas" in inspect.signature(sj.integrate).parameters else "levy_area"
            )
            fn = jax.vmap(
                lambda dw, a=None: sj.integrate(
                    system,
                    y0,
                    dw,
                    dt,
                    method=method,
                    **{named: a},
                    **opts,
                )
            )
        else:

            def fn(key):
                return sj.simulate(
                    system,
                    y0,
                    t1=n_steps * dt,
                    dt=dt,
                    n_samples=n_samples,
                    key=key,
                    method=method,
                    **opts,
                ).ys

            args = (jax.random.key(1),)
    start = time.perf_counter()
    try:
        lowered = jax.jit(fn).lower(*args)
    except TypeError as err:  # a method this system cannot serve: no case
        if "needs a system" in str(err):
            return None
        raise
    t_lower = time.perf_counter() - start
    start = time.perf_counter()
    compiled = lowered.compile()
    t_compile = time.perf_counter() - start
    from _common import time_call

    median, best, _, _ = time_call(compiled, *args, repeats=5)
    return {
        "method": name,
        "how": how,
        "lower_s": t_lower,
        "compile_s": t_compile,
        "total_s": t_lower + t_compile,
        "stablehlo_lines": _lines(lowered),
        "run_ns_per_sample_step": 1e9 * median / (n_samples * n_steps),
        "run_ns_per_sample_step_min": 1e9 * best / (n_samples * n_steps),
    }


def child(python, name, how, args, retry=None):
    """One case measured in a fresh process of `python`."""
    out = (
        subprocess.run(
            [
                python,
                os.path.abspath(__file__),
                "--one",
                "--methods",
                name,
                "--how",
                how,
                "--samples",
                str(args.samples),
                "--steps",
                str(args.steps),
            ]
            + ([] if retry is None else ["--retry", retry])
            + ["--system", args.system],
            capture_output=True,
            text=True,
            check=True,
        )
        .stdout.strip()
        .splitlines()[-1]
    )
    return json.loads(out)


def ab(args):
    """Medians over alternating fresh processes of two installations: B (`--ab`) against A
    (`--python`), so that both see the same machine load; or, with `--ab-retry`, of the
    library's default `retry_substeps` (A) against the given one (B)."""
    import statistics

    if args.ab_retry:
        cases = (("A", args.python, None), ("B", args.python, args.ab_retry))
        print(f"A: retry_substeps default\nB: retry_substeps={args.ab_retry}")
    else:
        cases = (("A", args.python, args.retry), ("B", args.ab, args.retry))
        print(f"A: {args.python}\nB: {args.ab}")
    print(
        f"{args.samples} samples x {args.steps} steps, {args.repeats} processes each, alternating\n"
    )
    print(
        "| method | how | compile+trace A s | B s | A/B | run ns per sample-step A (min) | B | "
        "A/B |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for how in args.how.split(","):
        for name in args.methods.split(","):
            runs = {"A": [], "B": []}
            for _ in range(args.repeats):
                for tag, python, retry in cases:
                    try:
                        row = child(python, name, how, args, retry)
                    except subprocess.CalledProcessError:  # (B may lack the method)
                        row = None
                    if row is not None:
                        runs[tag].append(row)
            if not runs["A"] or not runs["B"]:
                continue
            # compile: median over processes; run: the fastest of all timed calls, the
            # least disturbed by other load on a shared machine
            med = {
                t: (
                    statistics.median(r["total_s"] for r in rs),
                    min(r["run_ns_per_sample_step_min"] for r in rs),
                )
                for t, rs in runs.items()
            }
            (ca, ra), (cb, rb) = med["A"], med["B"]
            print(
                f"| {name} | {how} | {ca:.2f} | {cb:.2f} | {ca / cb:.2f} | {ra:.0f} | "
                f"{rb:.0f} | {ra / rb:.2f} |",
                flush=True,
            )


def main(argv=None):
    parser = _common.parser(__doc__, "50 samples x 64 steps", out=None)
    parser.add_argument("--methods", default=",".join(METHODS + [REFERENCE, SCAN_HEUN]))
    parser.add_argument("--how", default="integrate,simulate")
    parser.add_argument("--samples", type=int, default=500)
    parser.add_argument("--steps", type=int, default=512)
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--ab",
        default=None,
        metavar="PYTHON",
        help="A/B: alternate this interpreter (another installation of "
        "slps_jax, for example of an earlier commit) with --python, "
        "--repeats fresh processes each, and print medians and ratios",
    )
    parser.add_argument(
        "--ab-retry",
        default=None,
        metavar="K",
        help="A/B in this installation: the default retry_substeps against "
        "retry_substeps=K ('none' for no retry)",
    )
    parser.add_argument(
        "--retry",
        default=None,
        metavar="K",
        help="retry_substeps of the measured cases: an integer or 'none' "
        "(default: the library's default)",
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--system", choices=SYSTEMS, default="rigid")
    parser.add_argument(
        "--python",
        default=sys.executable,
        help="the interpreter of the measured processes, for an A/B against "
        "another installation of slps_jax (default: this one)",
    )
    args = parser.parse_args(argv)
    if args.fast:
        args.samples, args.steps = 50, 64
    if args.one:  # a child process: one case, JSON on stdout
        row = measure(args.methods, args.how, args.samples, args.steps, args.retry, args.system)
        print(json.dumps(row))
        return
    import jax

    jax.config.update("jax_enable_x64", True)  # as in the measured processes
    from _common import DEFAULT_OUT

    if args.ab or args.ab_retry:
        return ab(args)
    rows = []
    for how in args.how.split(","):
        for name in args.methods.split(","):
            row = child(args.python, name, how, args, args.retry)
            if row is None:
                continue
            rows.append(row)
            print(
                f"{how:9s} {name:16s} lower {row['lower_s']:6.2f} s  compile "
                f"{row['compile_s']:6.2f} s  total {row['total_s']:6.2f} s  "
                f"{row['stablehlo_lines']:6d} lines  run {row['run_ns_per_sample_step']:7.1f} ns",
                flush=True,
            )
    ref = {r["how"]: r["total_s"] for r in rows if r["method"] == REFERENCE}
    ref_total = ref.get("integrate")
    print(
        "\n| method | how | trace+lower s | compile s | total s | x diffrax Heun | "
        "StableHLO lines | run ns per sample-step |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        ratio = f"{r['total_s'] / ref_total:.2f}" if ref_total else "-"
        print(
            f"| {r['method']} | {r['how']} | {r['lower_s']:.2f} | {r['compile_s']:.2f} | "
            f"{r['total_s']:.2f} | {ratio} | {r['stablehlo_lines']} | "
            f"{r['run_ns_per_sample_step']:.0f} |"
        )
    results = _common.Output(args.out or DEFAULT_OUT)
    results.json("compile_time", {"samples": args.samples, "steps": args.steps, "rows": rows})


if __name__ == "__main__":
    main()
