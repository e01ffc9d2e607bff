#!/usr/bin/env python
"""Data-driven transport noise for Euler–Zeitlin, end to end (Cotter et al. 2019; Ephrati,
Cifani, Luesink & Geurts 2023).

1. A fine deterministic run, su(M), from a random vorticity of degrees 1..10 (amplitude
   ~ 1/l), step h.
2. `fit_transport_noise` at su(N) on its first `train` steps, over windows of `window` steps.
3. From `starts` later snapshots (coarse-grained: the truth), `lead` steps ahead: the
   deterministic coarse forecast, an ensemble of `members` with the calibrated noise, and one
   with an isotropic noise (the degrees 1..3 equally) of the same total variance.
4. Scores of the degree 1..3 coefficients, pooled over the starts (`forecast_scores`):
   spread / RMSE, CRPS against the deterministic forecast's mean absolute error, ranks; and
   every member's Casimirs.

The window sets the time scale at which the white noise matches the data's transport. The
traces of the missed transport are smooth in time (lag-one autocorrelation near 1 at
h = 0.01 s): matched over one step, the noise is far too weak at a lead of seconds; matched
over half the lead, its spread follows the error.

    python examples/data_driven_noise.py [--small] [--windows W ...] [--out DIR]

(the figure is of the first window's run).

The full size (M = 64, N = 16) takes about a minute on a 2-core CPU.
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import argparse  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin  # noqa: E402

FULL = dict(M=64, N=16, h=0.01, train=4000, window=200, lead=400, every=40, starts=4, members=32)
SMALL = dict(M=24, N=8, h=0.02, train=400, window=40, lead=80, every=20, starts=2, members=8)


def initial(M, degrees=10, seed=0):
    """A random vorticity of degrees 1..`degrees`, coefficients N(0, 1/l^2)."""
    rng = np.random.default_rng(seed)
    om = np.zeros((degrees + 1) ** 2)
    for el in range(1, degrees + 1):
        for m in range(-el, el + 1):
            om[zeitlin.elm2ind(el, m)] = rng.normal() / el
    return zeitlin.shr2mat(om, M)


def observe(w):
    """The degree 1..3 coefficients (15) of states `(..., N, N)`."""
    return np.asarray(zeitlin.mat2shr(w, L=4))[..., 1:]


def isotropic_noise(fit, N):
    """`salt_noise` of the 15 harmonics of degrees 1..3, equal amplitudes, scaled to the
    calibrated noise's total variance (the sum of its streams' squared L2 norms)."""
    total = float(np.sum(np.asarray(zeitlin.enstrophy(-np.asarray(fit.noise.chi)))))
    basis = zeitlin.shr2mat(np.eye(16)[1:], N)
    basis = basis * np.sqrt(total / float(np.sum(np.asarray(zeitlin.enstrophy(basis)))))
    return sj.salt_noise(-basis)


def fine_run(M, h, train, lead, starts, seed=0):
    """Step 1: the fine deterministic run, `(train + starts * lead + 1, M, M)`."""
    steps = train + starts * lead
    return sj.integrate(
        sj.EulerZeitlin(M),
        initial(M, seed=seed),
        np.zeros((steps, 1)),
        h,
        save_every=1,
        method=sj.IsospectralMidpoint(),
    )


def experiment(
    M, N, h, train, window, lead, every, starts, members, seed=0, fine=None, n_modes=None
):
    """The four steps above (`fine`: step 1's run, if already made; `n_modes`: as many EOFs,
    instead of those that explain 90 % of the variance). **Returns** a dict:
    `fine`, `fit`, `truth` `(starts, T + 1, N, N)` at the start and every `every` steps
    (`T = lead / every`), `deterministic` (same shape), `ensembles` {name:
    `(starts, members, T + 1, N, N)`}; at the `T` lead times `lead_times` after the start,
    `scores` {name: `ForecastScores` pooled over the starts} and `deterministic_mae`;
    `casimir_drift` {name: the largest relative drift of tr W^2 ... tr W^N over every
    member and time}; `seconds` per part."""
    seconds = {}
    start = time.perf_counter()
    if fine is None:
        fine = fine_run(M, h, train, lead, starts, seed)
        seconds["fine run"] = time.perf_counter() - start
    start = time.perf_counter()
    fit = sj.fit_transport_noise(fine[: train + 1], dt=h, N=N, window=window, n_modes=n_modes)
    seconds["fit"] = time.perf_counter() - start
    idx = train + lead * np.arange(starts)[:, None] + every * np.arange(lead // every + 1)
    truth = zeitlin.truncate(fine[idx.ravel()], N).reshape(starts, -1, N, N)
    x0 = truth[:, 0]
    start = time.perf_counter()
    deterministic = jax.vmap(
        lambda w: sj.integrate(sj.EulerZeitlin(N), w, jnp.zeros((lead, 1)), h, save_every=every)
    )(x0)
    seconds["deterministic"] = time.perf_counter() - start
    ensembles, drift = {}, {}
    for name, noise in (("calibrated", fit.noise), ("isotropic", isotropic_noise(fit, N))):
        start = time.perf_counter()
        system = sj.EulerZeitlin(N, noise=noise)
        runs = []
        for s in range(starts):
            sol = sj.simulate(
                system,
                x0[s],
                t1=lead * h,
                dt=h,
                n_samples=members,
                key=jax.random.key(100 + s),
                method=sj.IsospectralMidpoint(),
                save_every=every,
            )
            if int(sol.stats["n_failed"]):
                raise RuntimeError(f"{name}: {int(sol.stats['n_failed'])} members failed.")
            runs.append(np.asarray(sol.ys))
        ensembles[name] = np.stack(runs)
        c = np.asarray(system.algebra.casimirs(ensembles[name]))
        drift[name] = float(np.max(np.abs(c / c[..., :1, :] - 1)))
        seconds[name] = time.perf_counter() - start
    # the lead times after the start, the starts pooled as observables:
    # (starts, ..., T, 15) -> (..., T - 1, starts * 15)
    pooled = lambda a: np.moveaxis(a[..., 1:, :], 0, -2).reshape(*a.shape[1:-2], -1, 15 * starts)
    y = pooled(observe(truth))
    scores = {name: sj.forecast_scores(pooled(observe(e)), y) for name, e in ensembles.items()}
    mae = np.mean(np.abs(pooled(observe(deterministic)) - y), axis=-1)
    return dict(
        fine=fine,
        fit=fit,
        lead_times=h * every * np.arange(1, lead // every + 1),
        truth=np.asarray(truth),
        deterministic=np.asarray(deterministic),
        ensembles=ensembles,
        scores=scores,
        deterministic_mae=mae,
        casimir_drift=drift,
        seconds=seconds,
    )


def summary(result):
    """One line per ensemble: spread / RMSE at each lead time, the time-mean CRPS against
    the deterministic forecast's MAE, the Casimirs' drift."""
    mae = float(np.mean(result["deterministic_mae"]))
    lines = [f"deterministic forecast: time-mean MAE {mae:.3g}"]
    for name, s in result["scores"].items():
        lines.append(
            f"{name}: spread/RMSE {np.array2string(s.ratio, precision=2)} (mean "
            f"{np.mean(s.ratio):.2f}), time-mean CRPS {np.mean(s.crps):.3g}, "
            f"Casimir drift {result['casimir_drift'][name]:.1e}"
        )
    return "\n".join(lines)


def figure(result):
    """EOFs on the sphere, explained variance, spread and RMSE, CRPS, rank histograms and
    the traces' autocorrelation; **returns** the matplotlib figure."""
    import matplotlib.pyplot as plt

    fit, t = result["fit"], result["lead_times"]
    fig = plt.figure(figsize=(13, 7.5))
    grid = fig.add_gridspec(6, 4)
    top, bottom = (lambda c: fig.add_subplot(grid[:3, c])), (lambda c: fig.add_subplot(grid[3:, c]))
    theta, phi = zeitlin.grid(48)
    for j in range(min(3, fit.modes.shape[0])):
        ax = fig.add_subplot(grid[2 * j : 2 * j + 2, 0])
        f = zeitlin.field(zeitlin.mat2shr(fit.modes[j]), theta, phi)
        ax.imshow(np.asarray(f), extent=(0, 360, 180, 0), cmap="RdBu_r", aspect="auto")
        ax.set_title(f"EOF {j + 1}: {100 * fit.explained[j]:.0f} %", fontsize=9)
        ax.set_yticks([0, 90, 180])
        ax.set_xticks([0, 180, 360])
    ax = top(1)
    cumulative, acf = fit.diagnostics(max_lag=5)
    ax.plot(np.arange(1, len(cumulative) + 1), cumulative, ".-")
    ax.axvline(fit.modes.shape[0], color="k", lw=0.8, ls=":")
    ax.set(xlabel="EOFs kept", ylabel="variance explained", title="explained variance")
    ax = top(2)
    for name, s in result["scores"].items():
        (line,) = ax.plot(t, s.rmse, label=f"{name} RMSE")
        ax.plot(t, s.spread, ls="--", color=line.get_color(), label=f"{name} spread")
    ax.plot(t, result["deterministic_mae"], "k:", label="deterministic MAE")
    ax.set(xlabel="lead time (s)", title="spread and error")
    ax.legend(fontsize=7)
    ax = top(3)
    for name, s in result["scores"].items():
        ax.plot(t, s.crps.mean(axis=-1), label=name)
    ax.plot(t, result["deterministic_mae"], "k:", label="deterministic (MAE)")
    ax.set(xlabel="lead time (s)", title="CRPS, degrees 1..3")
    ax.legend(fontsize=7)
    for k, (name, s) in enumerate(result["scores"].items()):
        ax = bottom(1 + k)
        ax.bar(np.arange(len(s.rank_histogram)), s.rank_histogram, width=1.0)
        ax.set(xlabel="rank of the truth", title=f"rank histogram, {name}")
    ax = bottom(3)
    ax.plot(acf[:, : min(5, acf.shape[1])], ".-")
    ax.set(xlabel="lag (windows)", title="traces' autocorrelation")
    fig.tight_layout()
    return fig


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--small", action="store_true", help="M = 24, N = 8: a few seconds")
    p.add_argument(
        "--windows", type=int, nargs="+", help="steps per window of the fit: one run each"
    )
    p.add_argument("--n-modes", type=int, help="keep this many EOFs (default: 90 %% variance)")
    p.add_argument("--out", default=".", help="folder for data_driven_noise.png")
    args = p.parse_args(argv)
    size = dict(SMALL if args.small else FULL)
    print("size:", size, flush=True)
    result = fine = None
    for window in args.windows or [size["window"]]:
        out = experiment(**dict(size, window=window), fine=fine, n_modes=args.n_modes)
        fine, result = out["fine"], result or out
        seconds = {k: round(v, 1) for k, v in out["seconds"].items()}
        print(f"window {window}: {out['fit'].modes.shape[0]} EOFs; seconds {seconds}")
        print(summary(out), flush=True)
    os.makedirs(args.out, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    figure(result).savefig(os.path.join(args.out, "data_driven_noise.png"), dpi=110)
    return result


if __name__ == "__main__":
    main()
