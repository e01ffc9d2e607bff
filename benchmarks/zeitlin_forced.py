#!/usr/bin/env python
"""Forced-dissipative Euler–Zeitlin: its cost against the inviscid step, and quflow beside us.

- Cost (one state, complex128, h = 0.64/N s, 16 steps from the smooth state of
  `benchmarks/zeitlin.py`): ms per step of `EulerZeitlin(N)` and of the forced-dissipative
  `EulerZeitlin(N, nu, p=2, alpha, forcing=F)` (a Strang splitting around the same
  isospectral step, the linear substep exact in the quantised harmonics, consecutive steps
  joining their half substeps), timed alternately in three rounds of >= 3 calls of
  `simulate` after one that compiles (medians), their ratio and the fixed point's updates
  per step; with quflow installed,
  its `isomp` at its defaults with its Strang splitting of `solve_viscdamp` (theta = 1/2,
  in the same seconds as ours, its viscosity nu Delta with p = 1: the same work per step
  whatever p) on the same state, and our ratio to it.
- Rough states: a su(64) state with energy at every degree, at h = 0.01 s (where every step
  is redone as substeps) and at `system.step_guide`'s step: seconds per unit of simulated
  time, updates per step, the share of steps redone, and whether `simulate` warned.
- Against quflow (where it is installed by hand from its sources; never a dependency):
  - the quasi-geostrophic stream against `solve_globalqg` (N = 64, 128; gamma 0.5, 10),
    the largest difference relative to the largest entry;
  - 100 steps of the same forced-dissipative model (N = 64, 128) at h, h/2, h/4: the
    largest difference of the final states (quflow solved to 1e-13). Its linear substep is
    Crank–Nicolson, ours exact: the difference is theirs, O(h^2), and shrinks by about 4
    per halving.

- `--transport`: transport noise end to end (N = 128): ms per step through `simulate` of the
  deterministic step (warm-started and cold) and of 8 transport noises with and without
  their Lévy areas, and through `integrate` with the noises given, with the fixed point's
  updates per step (`zeitlin_transport.json`, `zeitlin_transport.md`).

Writes `zeitlin_forced.json` and `zeitlin_forced.md` into --out (default benchmarks/results).

    python benchmarks/zeitlin_forced.py [--fast] [--transport] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os
import sys
import time

import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common
from zeitlin import _one_path, initial

import slps_jax as sj
from slps_jax import zeitlin as z

try:  # quflow is measured beside us where it is installed; never a dependency
    import quflow as qf
except ImportError:
    qf = None

NU, P, ALPHA = 1e-7, 2, 0.05  # per second: hyperviscosity and damping


def _forcing(N):
    """A forcing on degrees 8..10, coefficients N(0, 1) (seed 1)."""
    rng = np.random.default_rng(1)
    om = np.zeros(11 * 11)
    for el in range(8, 11):
        for m in range(-el, el + 1):
            om[z.elm2ind(el, m)] = rng.normal()
    return z.shr2mat(om, N)


def _model(N, **kwargs):
    return sj.EulerZeitlin(N, nu=NU, p=P, alpha=ALPHA, forcing=_forcing(N), **kwargs)


def _quflow_splitting(N, nu_q, alpha_q, force_q):
    """quflow's Strang splitting of its viscosity nu_q Delta, damping and forcing (theta =
    1/2; its `isomp` and `solve_viscdamp` take seconds, as ours). Its viscosity damps
    l = 1 too (the rate nu_q l(l+1)): ours with p = 1 and alpha + 2 nu is the same model."""

    def split(dt, w):
        return qf.laplacian.solve_viscdamp(dt, w, nu_q, alpha_q, force_q, theta=0.5).copy()

    return split


def _runner(system, w0, h, n_steps):
    """`simulate`'s one path of `n_steps` steps of `h` (a function of nothing), its first
    call's seconds, and its fixed point's updates per step."""

    def run(stats=False):
        sol = sj.simulate(
            system,
            w0,
            t1=n_steps * h,
            dt=h,
            n_samples=1,
            key=jax.random.key(0),
            newton_stats=stats,
            failures=sj.Failures(throw=False),
        )
        return sol if stats else sol.ys

    start = time.perf_counter()
    jax.block_until_ready(run())
    first = time.perf_counter() - start
    updates = float(run(stats=True).stats["newton_iterations_mean"])
    return run, first, updates


def cost(ns, n_steps=16, rounds=3):
    """The inviscid and the forced step, timed alternately in `rounds` rounds (a machine
    whose speed drifts moves both alike); medians over all calls."""
    rows = []
    for N in ns:
        h = 0.64 / N
        w0 = initial(N)
        runs = [_runner(system, w0, h, n_steps) for system in (sj.EulerZeitlin(N), _model(N))]
        times = ([], [])
        for _ in range(rounds):
            for (run, _, _), out in zip(runs, times):
                out.append(_common.time_call(run, repeats=3, warmup=False)[0])
        plain, forced = (1e3 * float(np.median(t)) / n_steps for t in times)
        c_plain, c_forced = (
            first - t / 1e3 * n_steps for (_, first, _), t in zip(runs, (plain, forced))
        )
        flow = jax.jit(lambda system, w: system.linear_flow(w, 0.5 * h))
        substep = 1e3 * _common.time_call(flow, _model(N), w0)[0]
        row = dict(
            N=N,
            inviscid_ms=plain,
            forced_ms=forced,
            forced_vs_inviscid=forced / plain,
            updates_inviscid=runs[0][2],
            updates_forced=runs[1][2],
            linear_substep_ms=substep,
            compile_s_inviscid=c_plain,
            compile_s_forced=c_forced,
        )
        if qf is not None:
            split = _quflow_splitting(N, NU, ALPHA, np.asarray(_forcing(N)))
            qf.isomp(np.array(w0), h, steps=1, strang_splitting=split)
            times = []
            for _ in range(3):
                w = np.array(w0)
                start = time.perf_counter()
                qf.isomp(w, h, steps=n_steps, strang_splitting=split)
                times.append(time.perf_counter() - start)
            row["quflow_forced_ms"] = 1e3 * float(np.median(times)) / n_steps
            row["forced_vs_quflow"] = forced / row["quflow_forced_ms"]
        print(row, flush=True)
        rows.append(row)
    return rows


def qg(ns=(64, 128), gammas=(0.5, 10.0)):
    rows = []
    for N in ns:
        rng = np.random.default_rng(0)
        om = rng.normal(size=N * N)
        om[0] = 0.0
        w = np.asarray(z.shr2mat(om, N))
        for gamma in gammas:
            theirs = np.array(qf.laplacian.solve_globalqg(w.copy(), gamma))
            ours = np.asarray(z.solve_poisson(w, gamma=gamma))
            rel = float(np.max(np.abs(ours - theirs)) / np.max(np.abs(theirs)))
            rows.append(dict(N=N, gamma=gamma, qg_rel_difference=rel))
            print(rows[-1], flush=True)
    return rows


def agreement(ns=(64, 128), n_steps=100):
    """Ours (p = 1, damping alpha + 2 nu: quflow's nu Delta + alpha) against quflow's
    splitting at h, h/2, h/4 over the same time."""
    rows = []
    nu = 1e-3
    for N in ns:
        w0 = initial(N)
        F = np.asarray(_forcing(N))
        system = sj.EulerZeitlin(N, nu=nu, p=1, alpha=ALPHA + 2 * nu, forcing=F)
        split = _quflow_splitting(N, nu, ALPHA, F)
        h0 = 0.64 / N
        for k in range(3):
            h, n = h0 / 2**k, n_steps * 2**k
            ours = np.asarray(sj.integrate(system, w0, jnp.zeros((n, 1)), h, save_every=n))[-1]
            w = np.array(w0)
            w = qf.isomp(w, h, steps=n, strang_splitting=split, tol=1e-13, maxit=100)
            diff = float(np.max(np.abs(ours - w)) / np.max(np.abs(w)))
            rows.append(dict(N=N, h=h, steps=n, rel_difference=diff))
            print(rows[-1], flush=True)
    return rows


def rough(N=64, scales=(4.0, 6.0), h=0.01, t1=0.16):
    """A rough su(N) state (coefficients N(0, 1)/l, x0.3 above l = 15, seed 0, times each
    of `scales`), deterministic: seconds per unit of simulated time and solver updates per
    step at h (most steps redone as substeps) and at `system.step_guide`'s step."""
    import warnings

    rng = np.random.default_rng(0)
    el = np.repeat(np.arange(N), 2 * np.arange(N) + 1).astype(float)
    om = rng.normal(size=N * N) / np.maximum(el, 1)
    om[el > 15] *= 0.3
    om[0] = 0.0
    system = sj.EulerZeitlin(N)
    rows = []
    for scale in scales:
        w = z.shr2mat(scale * om, N)
        guide = system.step_guide(w)
        for name, step in (("h", h), ("step_guide", guide)):
            n = max(1, int(round(t1 / step)))
            run = lambda: _one_path(system, w, sj.IsospectralMidpoint(), n, h=step)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                sol = run()
            med = _common.time_call(lambda: run().ys, repeats=3)[0]
            rows.append(
                dict(
                    N=N,
                    scale=scale,
                    step=name,
                    h=step,
                    s_per_unit_time=med / (n * step),
                    updates=float(sol.stats["newton_iterations_mean"]),
                    retried_share=float(sol.stats["n_retried_steps"]) / n,
                    warned=any("redone" in str(c.message) for c in caught),
                )
            )
            print(rows[-1], flush=True)
    return rows


def transport(N=128, n_steps=32):
    """Transport noise end to end: one state, h = 0.64/N s, ms per step through `simulate`
    (the driver's drawing included) of the deterministic system (warm-started, and cold),
    of 8 transport noises (degrees 1-2, amplitude 0.05) with and without their Lévy areas,
    and through `integrate` with the same noises given (no drawing), with the fixed
    point's updates per step."""
    h = 0.64 / N
    w0 = initial(N)
    det = sj.EulerZeitlin(N)
    noisy = sj.EulerZeitlin(N, noise=sj.salt_noise(0.05 * z.shr2mat(np.eye(9)[1:], N)))

    def through_simulate(system, method=None, **kwargs):
        method = sj.IsospectralMidpoint() if method is None else method
        run = lambda: _one_path(system, w0, method, n_steps, h=h, **kwargs)
        sol = run()
        med = _common.time_call(lambda: run().ys, repeats=5)[0]
        return 1e3 * med / n_steps, float(sol.stats["newton_iterations_mean"])

    rows = [
        ("deterministic (warm start)", *through_simulate(det)),
        (
            "deterministic, cold start",
            *through_simulate(det, method=sj.IsospectralMidpoint(warm_start=0)),
        ),
        ("8 noises with areas (drawn)", *through_simulate(noisy)),
        (
            "8 noises without areas",
            *through_simulate(noisy, driver=sj.BrownianMotion(levy_area=False)),
        ),
    ]
    dW, A = sj.BrownianMotion().increments(
        jax.random.key(1), n_steps, h, n_noises=8, levy_area=True
    )
    given = jax.jit(
        lambda m, w, d, a: sj.integrate(m, w, d, h, areas=a, failures=sj.Failures(throw=False))
    )
    med = _common.time_call(given, noisy, w0, dW, A, repeats=5)[0]
    rows.append(("8 noises with areas given (integrate)", 1e3 * med / n_steps, None))
    base = rows[0][1]
    out = [
        dict(N=N, case=c, ms_per_step=ms, vs_deterministic=ms / base, updates=u)
        for c, ms, u in rows
    ]
    for row in out:
        print(row, flush=True)
    return out


def main(argv=None):
    p = _common.parser(__doc__, "N = 16 and 32 only, no quflow")
    p.add_argument(
        "--transport", action="store_true", help="only transport noise end to end (N = 128)"
    )
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    if args.transport:
        rows = transport(N=16 if args.fast else 128)
        results.json("zeitlin_transport", dict(rows=rows))
        formats = {"ms_per_step": ".3g", "vs_deterministic": ".3g", "updates": ".3g"}
        results.markdown(
            "zeitlin_transport",
            _common.markdown_table(rows, list(rows[0]), formats),
            "; one state, complex128, h = 0.64/N s, 32 steps.",
        )
        return
    ns = (16, 32) if args.fast else (128, 256)
    out = dict(cost=cost(ns), rough=rough(N=16 if args.fast else 64))
    if qf is not None and not args.fast:
        out["qg"] = qg()
        out["agreement"] = agreement()
    results.json("zeitlin_forced", out)
    tables = []
    for key in ("cost", "rough", "qg", "agreement"):
        if key in out:
            cols = list(out[key][0])
            formats = {c: ".3g" for c in cols if c not in ("N", "steps", "step", "warned")}
            tables.append(_common.markdown_table(out[key], cols, formats))
    results.markdown(
        "zeitlin_forced",
        "\n\n".join(tables) + "\n",
        f"; one state, complex128, h = 0.64/N s; nu = {NU:g}, p = {P}, alpha = {ALPHA:g}, a "
        "forcing on degrees 8-10.",
    )


if __name__ == "__main__":
    main()
