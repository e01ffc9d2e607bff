#!/usr/bin/env python
"""The paper's whole convergence study, end to end, compile included, in a fresh process.

    strong_convergence(RigidBody.paper(), PAPER_Y0, t1=1.0, dts=[2^-5 ... 2^-9],
                       n_samples=500, key=jax.random.key(0),
                       methods={"LiePoisson": LiePoisson()})

and a second case with all methods (LiePoisson, Midpoint, Strang, EulerMaruyama, Exact).
Each case runs in a fresh Python process (no JAX compilation cache); its clock starts on the
first line of this file, before `import jax`, and stops when the results are in NumPy. The
target for the LiePoisson case is 10 s on a 2-core CPU. The parent also reports the
subprocess' wall time (interpreter start-up included).

Writes `paper_study.json`, `paper_study.csv` (errors per method and h) and `paper_study.png`.

    python benchmarks/paper_study.py [--fast] [--out DIR]
"""

import time

_T0 = time.perf_counter()  # the study's clock starts before any heavy import

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import os  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402

TARGET_S = 10.0
CASES = {
    "LiePoisson": ["LiePoisson"],
    "all": ["LiePoisson", "Midpoint", "Strang", "EulerMaruyama", "Exact"],
}


def child(case, n_samples, kmin, kmax):
    """Runs in the fresh process: the study, then one JSON line on stdout."""
    import numpy as np

    import slps_jax as sj

    t_import = time.perf_counter() - _T0
    methods = {name: getattr(sj, name)() for name in CASES[case]}
    start = time.perf_counter()
    res = sj.strong_convergence(
        sj.RigidBody.paper(),
        sj.PAPER_Y0,
        t1=1.0,
        dts=[2.0**-k for k in range(kmin, kmax + 1)],
        n_samples=n_samples,
        key=jax.random.key(0),
        methods=methods,
    )
    errors = {k: np.asarray(v).tolist() for k, v in res.errors.items()}  # results are in
    end = time.perf_counter()
    print(
        json.dumps(
            {
                "case": case,
                "wall_s": end - _T0,
                "import_s": t_import,
                "study_s": end - start,
                "dts": np.asarray(res.dts).tolist(),
                "errors": errors,
                "stderr": {k: np.asarray(v).tolist() for k, v in res.stderr.items()},
                "order": res.order,
                "order_stderr": res.order_stderr,
                "seconds": res.seconds,
            }
        )
    )


def run_case(case, n_samples, kmin, kmax):
    env = dict(os.environ, JAX_ENABLE_COMPILATION_CACHE="false")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    cmd = [
        sys.executable,
        os.path.abspath(__file__),
        "--child",
        case,
        "--samples",
        str(n_samples),
        "--kmin",
        str(kmin),
        "--kmax",
        str(kmax),
    ]
    start = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    outer = time.perf_counter() - start
    if out.returncode:
        raise RuntimeError(f"{case} failed:\n{out.stderr[-3000:]}")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["process_wall_s"] = outer
    return res


def plot(res, path, walls):
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import _common

    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    dts = res["dts"]
    for name, err in res["errors"].items():
        ax.errorbar(
            dts,
            err,
            yerr=res["stderr"][name],
            marker="o",
            capsize=2,
            label=f"{name}: order {res['order'][name]:.3f} ± {res['order_stderr'][name]:.3f}",
        )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("step size h")
    ax.set_ylabel("RMS error at T = 1 vs exact solution")
    ax.set_title(
        "strong_convergence, paper's setup, fresh process: "
        + ", ".join(f"{k} {v:.1f} s" for k, v in walls.items()),
        fontsize=9,
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse(argv):
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import _common

    p = _common.parser(
        __doc__,
        "tiny size for the test suite: 100 samples, h = 2^-5 ... 2^-7, "
        "the LiePoisson case only, one process",
    )
    p.add_argument("--samples", type=int, default=None, help="number of samples (500)")
    p.add_argument("--kmin", type=int, default=None)
    p.add_argument("--kmax", type=int, default=None)
    p.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="fresh processes per case (3; the median is reported)",
    )
    p.add_argument("--cases", default=None, help="comma-separated: LiePoisson,all")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    return p.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    n_samples = args.samples or (100 if args.fast else 500)
    kmin = args.kmin if args.kmin is not None else 5
    kmax = args.kmax if args.kmax is not None else (7 if args.fast else 9)
    if args.child:
        child(args.child, n_samples, kmin, kmax)
        return 0
    import _common

    cases = args.cases.split(",") if args.cases else (["LiePoisson"] if args.fast else list(CASES))
    repeats = args.repeats or (1 if args.fast else 3)
    results = _common.Output(args.out)
    info = results.info
    print(
        f"paper study: strong_convergence, {n_samples} samples, h = 2^-{kmin} ... 2^-{kmax}, "
        f"fresh process per run; {results.measured_on()}"
    )
    summary, last, rows = {}, {}, []
    for case in cases:
        runs = [run_case(case, n_samples, kmin, kmax) for _ in range(repeats)]
        walls = [r["wall_s"] for r in runs]
        last[case] = runs[-1]
        summary[case] = {
            "methods": CASES[case],
            "wall_s_median": statistics.median(walls),
            "wall_s_min": min(walls),
            "wall_s_all": walls,
            "process_wall_s_median": statistics.median(r["process_wall_s"] for r in runs),
            "import_s_median": statistics.median(r["import_s"] for r in runs),
            "study_s_median": statistics.median(r["study_s"] for r in runs),
            "order": runs[-1]["order"],
            "order_stderr": runs[-1]["order_stderr"],
            "method_seconds": runs[-1]["seconds"],
            "within_target": statistics.median(walls) <= TARGET_S,
        }
        s = summary[case]
        print(
            f"  {case:10s}: wall {s['wall_s_median']:6.2f} s (median of {repeats}, min "
            f"{s['wall_s_min']:.2f}; import {s['import_s_median']:.2f} s, study "
            f"{s['study_s_median']:.2f} s; process incl. interpreter "
            f"{s['process_wall_s_median']:.2f} s)"
        )
        for name in CASES[case]:
            err = runs[-1]["errors"][name]
            print(
                f"      {name:14s} order {s['order'][name]:.3f} ± {s['order_stderr'][name]:.3f}"
                f"  RMS at h=2^-{kmax}: {err[-1]:.3e}  ({s['method_seconds'][name]:.2f} s)"
            )
        for name in CASES[case]:
            for h, e, se in zip(
                runs[-1]["dts"], runs[-1]["errors"][name], runs[-1]["stderr"][name]
            ):
                rows.append(
                    {
                        "case": case,
                        "method": name,
                        "h": h,
                        "log2_h": round(math.log2(h)),
                        "rms_error": e,
                        "rms_stderr": se,
                        "order": s["order"][name],
                        "order_stderr": s["order_stderr"][name],
                    }
                )
    results.csv("paper_study", rows)
    results.json(
        "paper_study",
        {
            "machine": info,
            "n_samples": n_samples,
            "dts": [2.0**-k for k in range(kmin, kmax + 1)],
            "target_s": TARGET_S,
            "cases": summary,
            "timing": "from the child's first line (before import jax) to the results as NumPy "
            "arrays; process_wall_s adds interpreter start-up",
            "note": "noisy numbers from a shared 2-core machine",
        },
    )
    biggest = "all" if "all" in last else cases[-1]
    plot(
        last[biggest],
        os.path.join(args.out, "paper_study.png"),
        {k: v["wall_s_median"] for k, v in summary.items()},
    )
    if "LiePoisson" in summary:
        s = summary["LiePoisson"]
        print(
            f"LiePoisson study within {TARGET_S:.0f} s: "
            f"{'YES' if s['within_target'] else 'NO'} ({s['wall_s_median']:.2f} s)"
        )
    print(f"wrote {args.out}/paper_study.{{csv,json,png}}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
