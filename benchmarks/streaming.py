#!/usr/bin/env python
"""Streamed ensembles (`slps_jax.ensemble_statistics`): time and peak memory against samples.

Final-state mean, variance and covariance of `LiePoisson` on the paper's body (h = 2^-5,
T = 1, 32 steps, float64) for `n_samples` = 10^5, 2·10^5 and 10^6 at one `chunk_size` = 10^5
(1, 2 and 10 chunks). Each configuration runs in a fresh Python process (started by a small launcher,
as in `scaling.py`, because Linux carries ru_maxrss over fork and exec) that reports its
whole-process peak RSS (`ru_maxrss`), the rise of the peak during compile + run alone
(`VmHWM` after `clear_refs`), and the wall time. Memory that stays flat while the number of
chunks grows tenfold is what streaming promises; the script prints whether it did.

Writes `streaming.csv` and `streaming.json`.

    python benchmarks/streaming.py [--fast] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402
import scaling  # noqa: E402  (the fresh-process launcher and /proc helpers)

import slps_jax as sj  # noqa: E402

DT = 2.0**-5
T1 = 1.0
RSS_FLAT_MB = 20.0


def child(n_samples, chunk_size):
    system, y0 = sj.RigidBody.paper(), jnp.asarray(sj.PAPER_Y0)
    jax.block_until_ready(jnp.zeros(3) + 1.0)
    baseline = scaling._status_kb("VmRSS")
    reset = scaling._reset_peak()
    start = time.perf_counter()
    st = sj.ensemble_statistics(
        system,
        y0,
        t1=T1,
        dt=DT,
        n_samples=n_samples,
        key=jax.random.key(0),
        method=sj.LiePoisson(),
        chunks=sj.Chunks(chunk_size, progress=False),
        statistics=sj.Statistics(("mean", "var", "cov")),
    )
    seconds = time.perf_counter() - start
    hwm = scaling._status_kb("VmHWM")
    print(
        json.dumps(
            {
                "n": st.n,
                "n_failed": st.n_failed,
                "n_chunks": st.n_chunks,
                "seconds": seconds,
                "mean_final": st.mean[-1].tolist(),
                "var_final": st.var[-1].tolist(),
                "ru_maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
                "run_peak_rise_kb": (hwm - baseline) if (reset and hwm and baseline) else None,
            }
        )
    )


def parse(argv):
    p = _common.parser(__doc__, "10^3 and 10^4 samples, chunks of 10^3")
    p.add_argument("--child", nargs=2, type=int, help=argparse.SUPPRESS)
    return p.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    if args.child:
        child(*args.child)
        return 0
    launcher = scaling.Launcher()  # while this process is still small
    chunk = 10**3 if args.fast else 10**5
    sizes = [chunk, 2 * chunk, 10 * chunk]
    results = _common.Output(args.out)
    info = results.info
    print(
        f"streamed ensemble_statistics, LiePoisson, h = 2^-5, T = 1, chunk_size {chunk}: "
        f"{results.measured_on()}, {info['backend']}"
    )
    rows = []
    for n in sizes:
        out = launcher.run(
            [sys.executable, os.path.abspath(__file__), "--child", str(n), str(chunk)]
        )
        if out["rc"]:
            raise RuntimeError(f"child failed:\n{out['err']}")
        res = json.loads(out["out"].strip().splitlines()[-1])
        row = {
            "n_samples": n,
            "chunk_size": chunk,
            "n_chunks": res["n_chunks"],
            "n_failed": res["n_failed"],
            "seconds": res["seconds"],
            "ru_maxrss_mb": res["ru_maxrss_kb"] / 1024,
            "run_peak_rise_mb": (
                res["run_peak_rise_kb"] / 1024 if res["run_peak_rise_kb"] is not None else None
            ),
            "mean_final": res["mean_final"],
            "var_final": res["var_final"],
        }
        rows.append(row)
        rise = row["run_peak_rise_mb"]
        print(
            f"  n_samples {n:>8d} ({row['n_chunks']:3d} chunks): {row['seconds']:7.2f} s, "
            f"peak RSS {row['ru_maxrss_mb']:7.1f} MB (rise during the run "
            f"{'n/a' if rise is None else f'{rise:.1f}'} MB), {row['n_failed']} failed"
        )
    launcher.close()
    # From 2 chunks on, the allocator has seen a chunk's buffers freed and reused.
    growth = rows[-1]["ru_maxrss_mb"] - rows[1]["ru_maxrss_mb"]
    flat = growth < RSS_FLAT_MB
    print(
        f"peak RSS {'stayed flat' if flat else 'GREW'} from {rows[1]['n_chunks']} to "
        f"{rows[-1]['n_chunks']} chunks: {growth:+.1f} MB (from 1 chunk: "
        f"{rows[-1]['ru_maxrss_mb'] - rows[0]['ru_maxrss_mb']:+.1f} MB)"
    )
    results.csv(
        "streaming",
        [{k: v for k, v in r.items() if not k.endswith("_final")} for r in rows],
    )
    results.json(
        "streaming",
        {
            "machine": info,
            "dt": DT,
            "t1": T1,
            "method": "LiePoisson",
            "rows": rows,
            "rss_growth_mb": growth,
            "flat": flat,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
