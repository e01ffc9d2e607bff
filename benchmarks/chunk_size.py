"""Run time per sample-step of `ensemble_statistics` against its `chunk_size`, on this device.

The paper's setup (`t1 = 1`, `dt = 2^-5`, key 0), `LiePoisson` with the default retry,
float64. Each chunk size runs twice (the first run compiles); the second run's wall time
per sample-step is reported. On a CPU a batch's Newton loops run until its slowest sample
has converged, and large batches fall out of cache, so smaller chunks can be faster.

    python benchmarks/chunk_size.py              # 10^5 samples, chunks of 10^3, 10^4, 10^5
    python benchmarks/chunk_size.py --fast       # 2000 samples, chunks of 500, 2000
"""

from __future__ import annotations

import os
import sys
import warnings

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402


def main(argv=None):
    parser = _common.parser(__doc__, "2000 samples, chunks of 500, 2000")
    parser.add_argument("--samples", type=int, default=10**5)
    parser.add_argument("--chunks", default="1000,10000,100000")
    args = parser.parse_args(argv)
    if args.fast:
        args.samples, args.chunks = 2000, "500,2000"
    import jax

    jax.config.update("jax_enable_x64", True)
    import slps_jax as sj

    system, y0 = sj.RigidBody.paper(), jax.numpy.asarray(sj.PAPER_Y0)
    dt, rows = 2.0**-5, []
    print(
        f"{args.samples} samples x 32 steps\n\n| chunk_size | s (second run) | "
        f"us per sample-step |\n|---|---|---|"
    )
    for chunk in (int(c) for c in args.chunks.split(",")):
        for _ in range(2):
            with _common.Stopwatch() as sw, warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                sj.ensemble_statistics(
                    system,
                    y0,
                    t1=1.0,
                    dt=dt,
                    n_samples=args.samples,
                    key=jax.random.key(0),
                    method=sj.LiePoisson(),
                    chunks=sj.Chunks(chunk, progress=False),
                )
            seconds = sw.seconds
        us = 1e6 * seconds / (args.samples * 32)
        rows.append({"chunk_size": chunk, "seconds": seconds, "us_per_sample_step": us})
        print(f"| {chunk} | {seconds:.2f} | {us:.2f} |", flush=True)
    _common.Output(args.out).json("chunk_size", {"samples": args.samples, "rows": rows})
    return rows


if __name__ == "__main__":
    main()
