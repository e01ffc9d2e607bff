"""Failures on the paper's own setup, with and without the default retry of failing steps.

The streaming example's setup (`docs/scaling.md`, there with 10^5 samples):
`RigidBody.paper()`, `y0 = PAPER_Y0`, `t1 = 1`, key 0, 10^6 samples through
`ensemble_statistics` (chunks of 1000), `LiePoisson`, float64. For each
step size, the samples that fail without the retry (`retry_substeps=None`) and with the
default (`retry_substeps=4`: a failing step is redone as 4, 16, 64 substeps), and the wall
time of each run (compilation included, one per step size and setting).

    python benchmarks/robust_default.py            # 10^6 samples, h = 2^-4, 2^-5, 2^-6
    python benchmarks/robust_default.py --fast     # 4000 samples, h = 2^-4
"""

from __future__ import annotations

import os
import sys
import warnings

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402


def run(n_samples, chunk_size, dt, retry):
    import jax

    import slps_jax as sj

    system, y0 = sj.RigidBody.paper(), jax.numpy.asarray(sj.PAPER_Y0)
    with _common.Stopwatch() as sw, warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the failures are the measurement
        st = sj.ensemble_statistics(
            system,
            y0,
            t1=1.0,
            dt=dt,
            n_samples=n_samples,
            key=jax.random.key(0),
            method=sj.LiePoisson(),
            failures=sj.Failures(retry_substeps=retry),
            chunks=sj.Chunks(chunk_size, progress=False),
        )
    return st.n_failed, sw.seconds


def main(argv=None):
    parser = _common.parser(__doc__, "4000 samples, h = 2^-4")
    parser.add_argument("--samples", type=int, default=10**6)
    parser.add_argument("--chunk", type=int, default=1000)
    parser.add_argument("--levels", default="4,5,6", help="k of the step sizes 2^-k")
    args = parser.parse_args(argv)
    if args.fast:
        args.samples, args.chunk, args.levels = 4000, 1000, "4"
    import jax

    jax.config.update("jax_enable_x64", True)
    rows = []
    print(f"{args.samples} samples, chunks of {args.chunk}\n")
    print("| h | failed, no retry | failed, default | s, no retry | s, default | default / none |")
    print("|---|---|---|---|---|---|")
    for k in (int(x) for x in args.levels.split(",")):
        dt = 2.0**-k
        fail_none, s_none = run(args.samples, args.chunk, dt, None)
        fail_def, s_def = run(args.samples, args.chunk, dt, 4)
        rows.append(
            {
                "dt": dt,
                "failed_no_retry": fail_none,
                "failed_default": fail_def,
                "seconds_no_retry": s_none,
                "seconds_default": s_def,
            }
        )
        print(
            f"| 2^-{k} | {fail_none} | {fail_def} | {s_none:.1f} | {s_def:.1f} | "
            f"{s_def / s_none:.2f} |",
            flush=True,
        )
    results = _common.Output(args.out)
    results.json("robust_default", {"samples": args.samples, "rows": rows})
    results.csv("robust_default", rows)
    return rows


if __name__ == "__main__":
    main()
