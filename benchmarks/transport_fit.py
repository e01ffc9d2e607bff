#!/usr/bin/env python
"""Data-driven transport noise: the cost of the fit and of the coarse ensembles against M, N.

For (M, N) = (32, 8), (64, 16), h = 0.64/M s (the fit's dense transport solve costs O(N^6)
per sample: larger N need a matrix-free solve, not built):

- the fine deterministic run of su(M), `IsospectralMidpoint`, ms per step;
- `fit_transport_noise` at su(N) on 8 windows of 50 snapshots, 401 samples of the missed
  tendency (wall time of the whole call, the L-curve and NumPy's SVD included, after a first
  call that compiles);
- an ensemble of 32 members with the fitted noise and its Lévy areas, 50 steps at h, ms per
  member-step (`simulate`, final states only; compile time apart).

Writes `transport_fit.json` and `transport_fit.md` into --out (default benchmarks/results).

    python benchmarks/transport_fit.py [--fast] [--out DIR] [--sizes 64:16] [--windows 80]

(`--windows 80`: 4001 snapshots, the size of `docs/data-driven-noise.md`'s su(64) fit.)
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402
from zeitlin import initial  # noqa: E402  (benchmarks/zeitlin.py: a random vorticity)

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin  # noqa: E402

WINDOWS, WINDOW, MEMBERS = 8, 50, 32


def case(M, N, windows=WINDOWS, window=WINDOW, members=MEMBERS):
    h = 0.64 / M
    steps = windows * window  # (steps + 1 snapshots: windows windows and one left over)
    run = lambda w: sj.integrate(
        sj.EulerZeitlin(M),
        w,
        np.zeros((steps, 1)),
        h,
        save_every=1,
        failures=sj.Failures(throw=False),
    )
    w0 = initial(M, degrees=range(1, min(10, M - 1) + 1), decay=1)
    jax.block_until_ready(run(w0))  # (compiles)
    start = time.perf_counter()
    fine = jax.block_until_ready(run(w0))
    fine_ms = 1e3 * (time.perf_counter() - start) / steps
    sj.fit_transport_noise(
        fine, dt=h, N=N, window=window, n_modes=min(4, windows - 1)
    )  # (compiles)
    start = time.perf_counter()
    fit = sj.fit_transport_noise(fine, dt=h, N=N, window=window, n_modes=min(4, windows - 1))
    fit_s = time.perf_counter() - start
    system = sj.EulerZeitlin(N, noise=fit.noise)
    x0 = zeitlin.truncate(fine[-1], N)
    ensemble = lambda key: (
        sj.simulate(
            system,
            x0,
            t1=window * h,
            dt=h,
            n_samples=members,
            key=key,
            failures=sj.Failures(throw=False),
        ).ys
    )
    start = time.perf_counter()
    jax.block_until_ready(ensemble(jax.random.key(0)))
    first_s = time.perf_counter() - start
    med, _, _, _ = _common.time_call(ensemble, jax.random.key(1), repeats=3, min_total=0.5)
    member_step_ms = 1e3 * med / (members * window)
    return dict(
        M=M,
        N=N,
        h=h,
        fine_ms_per_step=fine_ms,
        fit_s=fit_s,
        fit_windows=windows,
        window=window,
        ensemble_ms_per_member_step=member_step_ms,
        ensemble_first_call_s=first_s,
    )


def main(argv=None):
    p = _common.parser(__doc__, "a smoke run: M = 12, N = 6, small sizes")
    p.add_argument("--sizes", default="32:8,64:16", help="M:N pairs, comma-separated")
    p.add_argument("--windows", type=int, default=WINDOWS, help="windows of 50 snapshots")
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    sizes = [tuple(int(k) for k in pair.split(":")) for pair in args.sizes.split(",")]
    rows = []
    for M, N in [(12, 6)] if args.fast else sizes:
        extra = dict(windows=4, window=10, members=4) if args.fast else dict(windows=args.windows)
        rows.append(case(M, N, **extra))
        print(rows[-1], flush=True)
    results.json("transport_fit", dict(rows=rows))
    cols = [
        "M",
        "N",
        "h",
        "fine_ms_per_step",
        "fit_s",
        "ensemble_ms_per_member_step",
        "ensemble_first_call_s",
    ]
    results.markdown(
        "transport_fit", _common.markdown_table(rows, cols, {k: ".3g" for k in cols[2:]})
    )


if __name__ == "__main__":
    main()
