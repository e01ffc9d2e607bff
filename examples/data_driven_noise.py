#!/usr/bin/env python
"""Data-driven transport noise for Euler–Zeitlin, fitted and verified fairly (after Cotter,
Crisan, Holm, Pan & Shevchenko 2019).

1. A fine deterministic run, su(M), from a random vorticity of degrees 1..10 (amplitude
   ~ 1/l), step h.
2. `fit_transport_noise` at su(N) on its first `train` steps: the EOFs of the transport that
   explains the tendency the coarse model misses, white in time.
3. One amplitude factor for the calibrated noise and one for an isotropic noise (every
   harmonic of degrees 2..N-1 alike, first scaled to the calibrated noise's total stream
   L^2), each tuned (`tune_amplitude`, fair CRPS) on `tune`
   forecasts started inside the training period.
4. `starts` held-out forecasts after the training period, `lead` steps each, `members`
   members: the deterministic coarse forecast and the two tuned ensembles.
5. Scores chosen before scoring: the coefficients of degrees 2..N-1 (where the noise acts;
   degree 1, the angular momentum, is kept by truth and model alike, reported apart). Per
   start, the fair CRPS over the lead times; the paired comparison of the two ensembles and
   of each ensemble against the deterministic forecast's mean absolute error (bootstrap
   over starts, 90 %); spread / RMSE at each lead time; every member's Casimirs.

    python examples/data_driven_noise.py [--small] [--seed S] [--out DIR]

The full size (M = 32, N = 8, 16 starts of 4 s, 32 members) takes a few minutes on a 2-core
CPU.
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

FULL = dict(M=32, N=8, h=0.01, train=4000, tune=8, starts=16, lead=400, every=40, members=32)
SMALL = dict(M=12, N=6, h=0.02, train=200, tune=3, starts=4, lead=40, every=20, members=6)


def initial(M, degrees=10, seed=0):
    """A random vorticity of degrees 1..`degrees` (at most M - 1), coefficients N(0, 1/l^2)."""
    rng = np.random.default_rng(seed)
    degrees = min(degrees, M - 1)
    om = np.zeros((degrees + 1) ** 2)
    for el in range(1, degrees + 1):
        om[el * el : (el + 1) ** 2] = rng.normal(size=2 * el + 1) / el
    return zeitlin.shr2mat(om, M)


def observables(N):
    """`{name: states (..., N, N) -> coefficients (..., k)}`: degrees 2..N-1 (the score),
    and degree 1 (reported apart)."""
    return {
        "degrees 2..N-1": lambda w: zeitlin.mat2shr(w)[..., 4:],
        "degree 1": lambda w: zeitlin.mat2shr(w, L=2)[..., 1:],
    }


def isotropic_noise(fit, N):
    """`salt_noise` of every harmonic of degrees 2..N-1 alike, with the calibrated noise's
    total stream L^2 (a starting point: its amplitude is tuned)."""
    basis = zeitlin.shr2mat(np.eye(N * N)[4:], N)
    total = np.sum(np.asarray(zeitlin.enstrophy(np.asarray(fit.noise.chi))))
    return sj.salt_noise(-basis * np.sqrt(total / np.sum(np.asarray(zeitlin.enstrophy(basis)))))


def experiment(M, N, h, train, tune, starts, lead, every, members, seed=0):
    """The steps above. **Returns** a dict: `fine` (step 1's run), `fit`, `tuning` {name:
    `AmplitudeTuning`}, `lead_times`, `scores` {observable: {name: `ForecastScores` pooled
    over the held-out starts}}, `crps_by_start` {observable: {name: `(starts,)`}} (the
    deterministic forecast's is its mean absolute error), `deterministic_mae` {observable:
    `(T,)`} by lead time, `comparisons` {observable: {pair: `PairedComparison`}},
    `casimir_drift` {name: the largest drift of tr W^2 ... tr W^N over every member and time,
    relative to sum |lambda|^k}, `seconds` per step."""
    seconds, clock = {}, time.perf_counter()
    fine = np.asarray(
        sj.integrate(
            sj.EulerZeitlin(M),
            initial(M, seed=seed),
            np.zeros((train + starts * lead, 1)),
            h,
            save_every=1,
        )
    )
    seconds["fine run"], clock = time.perf_counter() - clock, time.perf_counter()
    fit = sj.fit_transport_noise(fine[: train + 1], dt=h, N=N)
    red = sj.fit_transport_noise(fine[: train + 1], dt=h, N=N, time_model="ou")
    seconds["fit"], clock = time.perf_counter() - clock, time.perf_counter()
    coarse = lambda idx: np.asarray(zeitlin.truncate(fine[idx.ravel()], N)).reshape(
        *idx.shape, N, N
    )
    times = every * np.arange(1, lead // every + 1)
    tune_at = np.linspace(0, train - lead, tune).astype(int)  # starts inside the training
    test_at = train + lead * np.arange(starts)  # held out, after it
    main = observables(N)["degrees 2..N-1"]
    noises = {  # name: (noise, driver)
        "calibrated": (fit.noise, None),
        "calibrated, OU": (red.noise, sj.OrnsteinUhlenbeck(red.correlation_time)),
        "isotropic": (isotropic_noise(fit, N), None),
    }
    forecast = dict(lead=lead, dt=h, every=every)
    tuning = {
        name: sj.tune_amplitude(
            sj.EulerZeitlin(N, noise=noise),
            coarse(tune_at),
            coarse(tune_at[:, None] + times),
            observe=main,
            members=members // 2,
            key=jax.random.key(seed + 1),
            driver=driver,
            **forecast,
        )
        for name, (noise, driver) in noises.items()
    }
    seconds["tuning"], clock = time.perf_counter() - clock, time.perf_counter()
    x0, truth = coarse(test_at), coarse(test_at[:, None] + times)
    det = jax.vmap(
        lambda w: sj.integrate(sj.EulerZeitlin(N), w, jnp.zeros((lead, 1)), h, save_every=every)
    )(jnp.asarray(x0))
    ensembles = {
        name: sj.forecast_ensembles(
            sj.EulerZeitlin(N, noise=sj.scaled_noise(noise, tuning[name].factor)),
            x0,
            members=members,
            key=jax.random.key(seed + 2),
            driver=driver,
            **forecast,
        )
        for name, (noise, driver) in noises.items()
    }
    seconds["held-out forecasts"] = time.perf_counter() - clock
    scale = np.sum(np.abs(np.linalg.eigvals(x0))[..., None] ** np.arange(2, N + 1), axis=-2)
    drift = {}
    for name, ens in ensembles.items():
        c = np.asarray(sj.EulerZeitlin(N).algebra.casimirs(ens))  # (starts, m, T, k)
        c0 = np.asarray(sj.EulerZeitlin(N).algebra.casimirs(x0))[:, None, None]
        drift[name] = float(np.max(np.abs(c - c0) / scale[:, None, None]))
    scores, by_start, comparisons, mae_by_lead = {}, {}, {}, {}
    for label, observe in observables(N).items():
        y = np.asarray(observe(truth))  # (starts, T, k)
        # the starts pooled as observables: (starts, [m,] T, k) -> ([m,] T, starts * k)
        pooled = lambda a: np.moveaxis(a, 0, -2).reshape(*a.shape[1:-1], -1)
        scores[label] = {
            name: sj.forecast_scores(pooled(np.asarray(observe(e))), pooled(y))
            for name, e in ensembles.items()
        }
        error = np.abs(np.asarray(observe(det))[:, 1:] - y)  # (starts, T, k)
        mae_by_lead[label] = np.mean(error, axis=(0, 2))
        crps = {"deterministic": np.mean(error, axis=(1, 2))}
        crps |= {name: sj.start_crps(e, truth, observe) for name, e in ensembles.items()}
        by_start[label] = crps
        comparisons[label] = {
            "calibrated vs isotropic": sj.paired_comparison(crps["calibrated"], crps["isotropic"]),
            "calibrated OU vs isotropic": sj.paired_comparison(
                crps["calibrated, OU"], crps["isotropic"]
            ),
            "OU vs white": sj.paired_comparison(crps["calibrated, OU"], crps["calibrated"]),
        }
        if label == "degree 1":  # (kept by the deterministic forecast: no ratio to it)
            continue
        comparisons[label] |= {
            "calibrated vs deterministic": sj.paired_comparison(
                crps["calibrated"], crps["deterministic"]
            ),
            "calibrated OU vs deterministic": sj.paired_comparison(
                crps["calibrated, OU"], crps["deterministic"]
            ),
            "isotropic vs deterministic": sj.paired_comparison(
                crps["isotropic"], crps["deterministic"]
            ),
        }
    return dict(
        fine=fine,
        fit=fit,
        tuning=tuning,
        lead_times=h * times,
        scores=scores,
        crps_by_start=by_start,
        deterministic_mae=mae_by_lead,
        comparisons=comparisons,
        casimir_drift=drift,
        seconds=seconds,
        size=dict(M=M, N=N, starts=starts, members=members, seed=seed),
    )


def summary(result):
    """The tuned factors, the paired comparisons, spread / RMSE by lead, the Casimirs."""
    lines = [f"{name}: tuned factor {t.factor:.3g}" for name, t in result["tuning"].items()]
    for label, pairs in result["comparisons"].items():
        means = ", ".join(
            f"{k} {np.mean(v):.3g}" for k, v in result["crps_by_start"][label].items()
        )
        lines.append(f"{label}: mean CRPS (deterministic: MAE) {means}")
        lines += [f"  {k}: {v}" for k, v in pairs.items()]
    for name, s in result["scores"]["degrees 2..N-1"].items():
        lines.append(
            f"{name}: spread/RMSE at {np.round(result['lead_times'], 2)} s: "
            f"{np.array2string(s.ratio, precision=2)}; Casimir drift "
            f"{result['casimir_drift'][name]:.1e}"
        )
    return "\n".join(lines)


def figure(result):
    """EOFs on the sphere, the traces' autocorrelation, the tuning curves, spread and RMSE,
    CRPS by lead, rank histograms; **returns** the matplotlib figure."""
    import matplotlib.pyplot as plt

    fit, t = result["fit"], result["lead_times"]
    scores = result["scores"]["degrees 2..N-1"]
    fig = plt.figure(figsize=(14, 8))
    grid = fig.add_gridspec(6, 4)
    top, bottom = (lambda c: fig.add_subplot(grid[:3, c])), (lambda c: fig.add_subplot(grid[3:, c]))
    theta, phi = zeitlin.grid(48)
    lat, lon = 90 - np.degrees(theta), np.degrees(phi)
    for j in range(min(3, fit.modes.shape[0])):
        ax = fig.add_subplot(grid[2 * j : 2 * j + 2, 0])
        f = np.asarray(zeitlin.field(zeitlin.mat2shr(fit.modes[j]), theta, phi))
        v = np.abs(f).max()
        im = ax.pcolormesh(lon, lat, f, cmap="RdBu_r", vmin=-v, vmax=v, shading="auto")
        fig.colorbar(im, ax=ax, label="stream (unit L²)", pad=0.02)
        ax.set_yticks([-90, 0, 90])
        ax.set(
            title=f"EOF {j + 1}: {100 * fit.explained[j]:.0f} % of the variance",
            ylabel="latitude (°)",
            xlabel="longitude (°)" if j == 2 else None,
        )
    ax = top(1)
    acf = fit.diagnostics(max_lag=int(2.0 / fit.window_time))[1]
    lags = fit.window_time * np.arange(acf.shape[0])
    for j in range(min(4, acf.shape[1])):
        ax.plot(lags, acf[:, j], label=f"EOF {j + 1}: T = {fit.correlation_time[j]:.2f} s")
    ax.axhline(0, color="k", lw=0.5)
    ax.set(xlabel="lag (s)", ylabel="autocorrelation", title="the traces in time")
    ax.legend(fontsize=7)
    ax = top(2)
    for name, tun in result["tuning"].items():
        ax.semilogx(tun.factors, tun.crps, ".-", label=f"{name} (best {tun.factor:.2g})", base=2)
    ax.set(
        xlabel="amplitude factor",
        ylabel="mean fair CRPS (training starts)",
        title="tuning one amplitude factor",
    )
    ax.legend(fontsize=7)
    ax = top(3)
    for name, s in scores.items():
        (line,) = ax.plot(t, s.rmse, label=f"{name}: RMSE of the mean")
        ax.plot(t, s.spread, ls="--", color=line.get_color(), label=f"{name}: spread")
    ax.set(
        xlabel="lead time (s)",
        ylabel="RMS over degrees 2..N-1",
        title="spread and error (held-out starts)",
    )
    ax.legend(fontsize=7)
    ax = bottom(1)
    for name, s in scores.items():
        ax.plot(t, s.crps.mean(axis=-1), label=name)
    ax.plot(t, result["deterministic_mae"]["degrees 2..N-1"], "k:", label="deterministic (MAE)")
    ax.set(xlabel="lead time (s)", ylabel="fair CRPS", title="CRPS, degrees 2..N-1")
    ax.legend(fontsize=7)
    ax = bottom(2)
    for name, s in scores.items():
        ranks = np.arange(len(s.rank_histogram))
        ax.step(ranks, s.rank_histogram / s.rank_histogram.sum(), where="mid", label=name)
    ax.axhline(1 / len(ranks), color="k", lw=0.8, ls=":", label="flat (calibrated)")
    ax.set(
        xlabel="rank of the truth among the members", ylabel="frequency", title="rank histograms"
    )
    ax.legend(fontsize=7)
    ax = bottom(3)
    for name, s in scores.items():
        ax.plot(t, s.ratio, ".-", label=name)
    ax.axhline(1, color="k", lw=0.8, ls=":")
    ax.set(xlabel="lead time (s)", ylabel="spread / RMSE", title="spread against error")
    ax.legend(fontsize=7)
    fig.suptitle(
        f"Data-driven transport noise, su({result['size']['M']}) → su({result['size']['N']}): "
        f"{result['size']['starts']} held-out starts, {result['size']['members']} members"
    )
    fig.tight_layout()
    return fig


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--small", action="store_true", help="M = 12, N = 6: seconds")
    p.add_argument("--seed", type=int, default=0, help="the fine run's initial state")
    p.add_argument("--out", default=".", help="folder for data_driven_noise.png")
    args = p.parse_args(argv)
    size = dict(SMALL if args.small else FULL)
    print("size:", size, "seed:", args.seed, flush=True)
    result = experiment(**size, seed=args.seed)
    print({k: round(v, 1) for k, v in result["seconds"].items()}, "seconds")
    print(summary(result), flush=True)
    os.makedirs(args.out, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    figure(result).savefig(os.path.join(args.out, "data_driven_noise.png"), dpi=110)
    return result


if __name__ == "__main__":
    main()
