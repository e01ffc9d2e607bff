#!/usr/bin/env python
"""Several noises: the rigid body with three SALT noises about non-parallel axes.

    dy = y x I^{-1} y dt + sum_r y x chi_r o dW_r,  I = (1, 2, 3),
    chi = 0.4 [[1, 0, 0], [0, 1, 0], [0, 0.5, 1]],  y0 = (0.6, 0.5, 0.3),  T = 1.

No exact solution: the reference is `Midpoint` on the very same Brownian paths at
h_fine = 2^-14 (64x finer than the finest step studied); its own error is estimated by the
same method at 2 h_fine and printed next to the errors.

- Work-precision: RMS error at T against the reference vs run time (median of >= 3 blocking
  calls after a warm-up; compile time on its own), 500 samples, h = 2^-4 ... 2^-8, for every
  slps_jax method that serves the system, a `lax.scan` Heun and diffrax `Heun` (shared
  increments through the same piecewise-linear path as `work_precision.py`; only with the
  `bench` extra).
- Per sample-step cost at h = 2^-8 (run time / (samples x steps)), as a ratio to diffrax Heun.
- Strong orders (least-squares slope over h) and weak orders (`weak_convergence`, the same
  reference, observables H(y) and y_3^2; failing steps retried in 4 substeps). A failed
  sample in the work-precision runs (counted by an untimed run) stops the script: frozen
  states are not data.
- Long time: T = 100 at h = 2^-6, 100 samples: the number of samples that failed (blew up),
  and over the others the largest relative Casimir drift max | |y_t| - |y_0| | / |y_0| along
  the path and E[H(y_T)] with its 95% interval.

Writes `several_noises.csv`, `several_noises.json`, `several_noises.md` and
`several_noises.png` into --out (default benchmarks/results).

    python benchmarks/several_noises.py [--fast] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import argparse  # noqa: E402
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

INERTIA = jnp.asarray([1.0, 2.0, 3.0])
CHI = 0.4 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
Y0 = jnp.asarray([0.6, 0.5, 0.3])
MODEL = sj.RigidBody(INERTIA, noise=sj.salt_noise(CHI))

OURS = {
    "LiePoisson": sj.LiePoisson(),
    "LiePoissonSym2": sj.LiePoissonSym2(),
    "LiePoissonSym4": sj.LiePoissonSym4(),
    "Midpoint": sj.Midpoint(),
    "SaltSplitting": sj.SaltSplitting(),
    "Heun": sj.Heun(),
    "EulerMaruyama": sj.EulerMaruyama(),
}
POISSON = ("LiePoisson", "LiePoissonSym2", "LiePoissonSym4", "Midpoint", "SaltSplitting")
IMPLICIT = ("LiePoisson", "LiePoissonSym2", "LiePoissonSym4", "Midpoint")  # Newton solves that can fail
SCAN_HEUN = "lax.scan Heun"
DIFFRAX_HEUN = "diffrax Heun"


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
    terms = dfx.MultiTerm(dfx.ODETerm(lambda t, y, a: fields(y)[0]),
                          dfx.ControlTerm(lambda t, y, a: fields(y)[1],
                                          wp.IncrementPath(w, h_fine)))
    sol = dfx.diffeqsolve(terms, dfx.Heun(), 0.0, n_steps * h, h, Y0, max_steps=n_steps,
                          throw=False)
    return sol.ys[-1]


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fast", action="store_true",
                   help="a smoke run: 32 samples, h = 2^-4 and 2^-5, reference at 2^-8, weak "
                        "errors of two methods, a short long-time run")
    p.add_argument("--out", default=_common.DEFAULT_OUT, help="output folder (default: %(default)s)")
    return p.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    os.makedirs(args.out, exist_ok=True)
    info = _common.machine_info()
    fast = args.fast
    n_samples = 32 if fast else 500
    ks = range(4, 6) if fast else range(4, 9)
    factor = 8 if fast else 64
    n_fine = 2 ** (max(ks)) * factor
    h_fine = 1.0 / n_fine
    print(f"# several noises: SALT rigid body, {n_samples} samples, h = 2^-{min(ks)}..2^-"
          f"{max(ks)}, reference Midpoint at 2^-{int(math.log2(n_fine))}\n"
          f"# {info['cpu_model']}, {info['cpu_count']} cores, jax {info['jax']}, "
          f"diffrax {info['diffrax']}, {info['date']}", flush=True)

    dW = sj.brownian_increments(jax.random.key(0), n_fine, h_fine, n_samples=n_samples,
                                n_noises=3)
    cumulative = jnp.concatenate([jnp.zeros((n_samples, 1, 3)), jnp.cumsum(dW, axis=1)], 1)

    def coarse(n):
        return dW.reshape(n_samples, n, -1, 3).sum(2)

    def ours(method, h):
        return lambda d: jax.vmap(lambda di: sj.integrate(MODEL, Y0, di, h, method=method,
                                                          throw=False))(d)

    reference = jax.jit(ours(sj.Midpoint(), h_fine))(dW)
    ref2 = jax.jit(ours(sj.Midpoint(), 2 * h_fine))(coarse(n_fine // 2))
    ref_error = float(jnp.sqrt(jnp.mean(jnp.sum((ref2 - reference) ** 2, -1))))
    print(f"reference's own error (RMS, Midpoint at 2 h_fine vs h_fine): {ref_error:.2e}",
          flush=True)

    names = list(OURS) + [SCAN_HEUN] + ([DIFFRAX_HEUN] if wp.dfx is not None else [])
    rows = []
    for name in names:
        for k in ks:
            n, h = 2 ** k, 2.0 ** -k
            if name in OURS:
                fn, arg = ours(OURS[name], h), coarse(n)
            elif name == SCAN_HEUN:
                fn, arg = (lambda d, h=h: jax.vmap(lambda di: scan_heun(Y0, di, h))(d)), coarse(n)
            else:
                fn = (lambda w, h=h, n=n: jax.vmap(
                    lambda wi: diffrax_heun(wi, h, n, h_fine))(w))
                arg = cumulative
            compiled, compile_s = _common.compile_timed(fn, arg)
            med, best, reps, y = _common.time_call(compiled, arg)
            e2 = jnp.sum((y - reference) ** 2, -1)
            casimir = float(jnp.max(jnp.abs(jnp.linalg.norm(y, axis=-1) / jnp.linalg.norm(Y0)
                                            - 1.0)))
            rows.append(dict(method=name, h=h, rms_error=float(jnp.sqrt(jnp.mean(e2))),
                             time_median_s=med, time_min_s=best, compile_s=compile_s,
                             ns_per_sample_step=1e9 * med / (n_samples * n),
                             max_rel_casimir_error=casimir,
                             failed=(wp.count_failed(MODEL, Y0, arg, h, OURS[name])
                                     if name in IMPLICIT else 0)))
            print(f"{name:16s} h=2^-{k}  rms {rows[-1]['rms_error']:.3e}  run {med:.4f} s  "
                  f"compile {compile_s:.2f} s  casimir {casimir:.1e}  failed "
                  f"{rows[-1]['failed']}", flush=True)
            if rows[-1]["failed"]:
                raise RuntimeError(f"{name} at h = 2^-{k}: {rows[-1]['failed']} samples failed; "
                                   "their frozen states are not data. Use smaller steps.")
    _common.write_csv(os.path.join(args.out, "several_noises.csv"), rows)

    # Strong orders; per sample-step cost at the finest h.
    summary = []
    h_last = 2.0 ** -max(ks)
    base = next((r["ns_per_sample_step"] for r in rows
                 if r["method"] == DIFFRAX_HEUN and r["h"] == h_last), None)
    for name in names:
        pts = [r for r in rows if r["method"] == name]
        order = float(np.polyfit(np.log([r["h"] for r in pts]),
                                 np.log([r["rms_error"] for r in pts]), 1)[0])
        last = pts[-1]
        summary.append(dict(method=name, strong_order=order, rms_error=last["rms_error"],
                            ns_per_sample_step=last["ns_per_sample_step"],
                            vs_diffrax_heun=(last["ns_per_sample_step"] / base if base else None),
                            compile_s=last["compile_s"],
                            max_rel_casimir_error=max(r["max_rel_casimir_error"] for r in pts)))

    # Weak orders against the same reference (coupled differences).
    def observable(y):
        return jnp.stack([MODEL.hamiltonian(y), y[2] ** 2])

    weak = sj.weak_convergence(
        MODEL, Y0, t1=1.0, dts=[2.0 ** -k for k in ks], n_samples=n_samples,
        key=jax.random.key(0), observable=observable, reference=sj.Midpoint(),
        reference_factor=factor, retry_substeps=4,
        methods={n: OURS[n] for n in (("Midpoint", "SaltSplitting") if fast else OURS)})
    for row in summary:
        row.update(weak_order_H=math.nan, weak_order_y3sq=math.nan, weak_resolved="—")
        if row["method"] in weak.order:
            name = row["method"]
            row["weak_order_H"], row["weak_order_y3sq"] = (float(o) for o in weak.order[name])
            resolved = np.abs(weak.bias[name]) > weak.ci[name]
            row["weak_resolved"] = f"{int(resolved.sum())}/{resolved.size}"

    # Long time: Casimir drift along the path and E[H(y_T)].
    t_long, h_long, n_long = (4.0, 2.0 ** -4, 8) if fast else (100.0, 2.0 ** -6, 100)
    key = jax.random.key(1)
    long_rows = []
    for name in POISSON + ("Heun", "EulerMaruyama"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # failures are counted below
            sol = sj.simulate(MODEL, Y0, t1=t_long, dt=h_long, n_samples=n_long, key=key,
                              method=OURS[name], save_every=int(round(1 / h_long)),
                              throw=False)
        ys = np.asarray(sol.ys)
        ok = np.asarray(sol.result) == 0  # failed samples (EulerMaruyama blows up) left out
        if ok.sum() >= 2:
            drift = np.abs(np.linalg.norm(ys[ok], axis=-1) / float(jnp.linalg.norm(Y0))
                           - 1).max()
            energy = np.asarray(MODEL.hamiltonian(ys[ok, -1]))
            mean, ci = energy.mean(), 1.96 * energy.std(ddof=1) / math.sqrt(ok.sum())
        else:
            drift = mean = ci = math.nan
        long_rows.append(dict(method=name, failed=int((~ok).sum()),
                              max_rel_casimir_drift=float(drift), mean_H_T=float(mean),
                              ci95_H_T=float(ci)))
        print(f"long time {name:14s} casimir drift {drift:.1e}  E[H(T)] "
              f"{long_rows[-1]['mean_H_T']:.4f} ± {long_rows[-1]['ci95_H_T']:.4f}", flush=True)

    md = (f"SALT rigid body, I = (1, 2, 3), three noises, {n_samples} samples, T = 1; reference "
          f"Midpoint at 2^-{int(math.log2(n_fine))} on the same paths (its own error "
          f"{ref_error:.1e}). Per sample-step cost at h = 2^-{max(ks)}. {info['cpu_model']}, "
          f"jax {info['jax']}, diffrax {info['diffrax']}, {info['date'][:10]}.\n\n")
    md += _common.markdown_table(
        summary, ["method", "strong_order", "weak_order_H", "weak_order_y3sq", "weak_resolved",
                  "rms_error", "ns_per_sample_step", "vs_diffrax_heun", "compile_s",
                  "max_rel_casimir_error"],
        {"strong_order": ".2f", "weak_order_H": ".2f", "weak_order_y3sq": ".2f",
         "rms_error": ".2e", "ns_per_sample_step": ".0f", "vs_diffrax_heun": ".2f",
         "compile_s": ".2f", "max_rel_casimir_error": ".1e"}).replace("| nan ", "| — ")
    md += (f"\nLong time: T = {t_long:g}, h = 2^{int(math.log2(h_long))}, {n_long} samples.\n\n"
           + _common.markdown_table(long_rows, ["method", "failed", "max_rel_casimir_drift",
                                                "mean_H_T", "ci95_H_T"],
                                    {"max_rel_casimir_drift": ".1e", "mean_H_T": ".4f",
                                     "ci95_H_T": ".4f"}).replace("| nan ", "| — "))
    print("\n" + md)
    with open(os.path.join(args.out, "several_noises.md"), "w") as fh:
        fh.write(md)
    _common.write_json(os.path.join(args.out, "several_noises.json"),
                       dict(machine=info, reference_error=ref_error, rows=rows,
                            summary=summary, long_time=long_rows))

    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    markers = "osD^vx*P"
    for i, name in enumerate(names):
        pts = [r for r in rows if r["method"] == name]
        ax.loglog([r["time_median_s"] for r in pts], [r["rms_error"] for r in pts],
                  marker=markers[i % len(markers)], color=f"C{i}", label=name)
    ax.axhline(ref_error, color="gray", ls=":", label="reference's own error")
    ax.set_xlabel("run time, s (median)")
    ax.set_ylabel("RMS error at T = 1")
    ax.set_title(f"SALT rigid body, three noises, {n_samples} samples")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "several_noises.png"), dpi=120)


if __name__ == "__main__":
    main()
