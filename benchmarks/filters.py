#!/usr/bin/env python
"""Filters on forced-dissipative twins, side by side: the free ensemble, `particle_filter`
and `ensemble_kalman_filter` (a Kalman analysis applied as coadjoint actions), with the same
model, members, observations and errors.

Chosen before the runs. For each seed: the forced-dissipative su(32) truth of
`closure.py` (spun up 15 s, snapshots 0.05 s apart), coarse-grained to su(8); the model is
`fit_closure` on the first 4000 snapshots (200 s) with its noises' amplitude tuned
(`tune_amplitude`, the closure's factor, 8 starts inside the training period, 16 members,
one observation interval, degrees 2..7); then 40 observations 0.5 s apart after the training
period (20 s) of the degrees 1..3 (15 coefficients) with errors of 10 % of each
coefficient's standard deviation over the training period (degree 1, damped away, gets that
of degrees 2..3); every filter adds to their variance the model's error beyond its spread
(`model_error_variance`, 16 training starts, 16 members, one interval). 64 members, each the
model run for one interval from the truth's coarse graining an interval before the first
observation. The particle filter runs with `Tempering()` (pCN over the last interval), the
Kalman filter with `KalmanAnalysis()` and, localised by degree, with
`KalmanAnalysis(localization=Localization.by_degree(N, degrees, 1.5))`: the taper's length
of 1.5 degrees was the first one tried, on these seeds; 1 and 3 are a sensitivity.

Scores, at each observation: the RMSE of the ensemble mean against the coarse-grained truth
on the observed coefficients and on the unobserved ones (degrees 4..N-1), and the spread
($\\sqrt{(1 + 1/n)}$ times the members' standard deviation: the RMSE of a calibrated
ensemble). The paired gain in unobserved squared error over the free ensemble: the 40
observations in 8 blocks of 5 (2.5 s; block means, nearly independent), a paired bootstrap
90 % CI over the blocks of the seeds together. Rank histogram: the truth's rank among the
members, thinned to every other observation (1 s apart) and one coefficient per unobserved
degree (its order m turning with the observation), in 8 bins, chi-square over the seeds
together; the lag-one autocorrelation of the thinned ranks (per degree, over the kept
observations) says whether they are close to independent. Beside them: the particle
filter's least ESS, each filter's time, and, on the closure's conservative part alone
(gain and transport noise, fitted on the same data), every member's largest relative Casimir
change over 5 Kalman cycles.

`--inflations` runs the Kalman filter without localisation once for each inflation given
(default 1), `--localizations` once for each taper length given (default 1.5). `--M 64`
runs su(64) truths coarse-grained to su(16) (written as `filters_64.*`);
`--no-particle-filter` leaves the particle filter out.

Writes `filters.json` and `filters.md` into --out (default benchmarks/results).

    python benchmarks/filters.py [--fast] [--seeds 0 1 2] [--inflations 1 1.1 1.2]
        [--localizations 1 1.5 3] [--M 64] [--no-particle-filter] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import sys  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402
import closure  # noqa: E402

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin  # noqa: E402

H, EVERY = closure.H, closure.EVERY
FULL = dict(M=32, spin=15.0, train=4000, n_obs=40, interval=10, n=64, tune=8, block=5)
FAST = dict(M=20, spin=1.0, train=60, n_obs=4, interval=4, n=8, tune=2, block=2)


def _filter_driver(fit):
    """A closure's driver for the filters: its OU traces as fitted; white noise as the filters'
    default, Gaussian increments untruncated and without areas."""
    return fit.driver if isinstance(fit.driver, sj.OrnsteinUhlenbeck) else None


def _kalman_analyses(N, obs, inflations, lengths):
    """The Kalman filter's configurations by name: unlocalised for each inflation, localised
    by degree (inflation 1) for each taper length."""
    out = {}
    for inflation in inflations:
        name = "orbit Kalman" if inflation == 1.0 else f"orbit Kalman, inflation {inflation:g}"
        out[name] = sj.KalmanAnalysis(inflation=inflation)
    degrees = np.floor(np.sqrt(obs))
    for length in lengths:
        out[f"orbit Kalman, localised {length:g}"] = sj.KalmanAnalysis(
            localization=sj.Localization.by_degree(N, degrees, length)
        )
    return out


def case(seed, size, inflations=(1.0,), lengths=(1.5,), particle_filter=True):
    M, N, n = size["M"], size["M"] // 4, size["n"]
    linear, forcing = closure.terms(M)
    span, n_obs = size["interval"], size["n_obs"]
    every = span * EVERY  # (steps of H between observations)
    seconds = {}
    with _common.Stopwatch() as watch:
        ys = closure.truth(M, size["train"] + span * (n_obs + 1), seed, spin=size["spin"])
    seconds["truth"] = watch.seconds
    coarse_all = np.asarray(zeitlin.truncate(ys, N))
    train = ys[: size["train"]]
    fine = sj.EulerZeitlin(M, **linear)
    coarse = sj.EulerZeitlin(N, **linear, additive=forcing)
    fit = sj.fit_closure(train, dt=H * EVERY, fine=fine, coarse=coarse)
    # the noises' amplitude and the model's error beyond its spread, on training starts
    tune_at = np.linspace(0, size["train"] - span - 1, size["tune"]).astype(int)
    degrees_2_up = lambda w: zeitlin.mat2shr(w)[..., 4:]
    with _common.Stopwatch() as watch:
        factor = sj.tune_amplitude(
            fit.system,
            coarse_all[tune_at],
            coarse_all[tune_at + span][:, None],
            observe=degrees_2_up,
            lead=every,
            dt=H,
            every=every,
            members=16,
            key=jax.random.key(seed + 10),
            search=sj.AmplitudeSearch(closure.FACTORS, scale=lambda s, f: fit.scaled(f)),
            driver=fit.driver,
        ).factor
    seconds["tuning"] = watch.seconds
    model = fit.scaled(factor)
    driver = _filter_driver(fit)
    obs = np.arange(1, 16)  # degrees 1..3
    unobs = np.arange(16, N * N)
    observe = lambda w: jnp.real(zeitlin.mat2shr(w))[..., obs]
    sd = np.asarray(zeitlin.mat2shr(coarse_all[: size["train"] : 10])).real[:, obs].std(0)
    obs_std = 0.1 * np.maximum(sd, sd[3:].mean())
    error_at = np.linspace(0, size["train"] - span - 1, 16).astype(int)
    budget = sj.model_error_variance(
        sj.forecast_ensembles(
            model,
            coarse_all[error_at],
            lead=every,
            dt=H,
            every=every,
            members=16,
            key=jax.random.key(seed + 11),
            driver=fit.driver,
        ),
        coarse_all[error_at + span][:, None],
        observe,
    )
    filter_std = np.sqrt(obs_std**2 + np.maximum(np.asarray(budget.variance[0]), 0.0))
    # the window: observations after the training period
    first = size["train"] + span
    at = first + span * np.arange(n_obs)
    truth = coarse_all[at]
    rng = np.random.default_rng(seed)
    values = np.asarray(observe(truth)) + obs_std * rng.standard_normal((n_obs, obs.size))
    times = every * H * np.arange(1, n_obs + 1)
    observations = sj.Observations(values, observe=observe, std=filter_std, times=times)
    members = sj.simulate(
        model,
        coarse_all[first - 2 * span],
        t1=every * H,
        dt=H,
        n_samples=n,
        key=jax.random.key(seed + 12),
        driver=fit.driver,
    ).ys[:, -1]
    runs = {}
    with _common.Stopwatch() as watch:
        runs["free"] = np.asarray(
            sj.forecast_ensembles(
                model,
                members,
                lead=every * n_obs,
                dt=H,
                every=every,
                members=1,
                key=jax.random.key(seed + 13),
                driver=fit.driver,
            )
        )[:, 0].transpose(1, 0, 2, 3)
    seconds["free"] = watch.seconds
    least_ess = None
    if particle_filter:
        with _common.Stopwatch() as watch:
            pf = sj.particle_filter(
                model, members, observations, dt=H, key=jax.random.key(seed + 14), driver=driver
            )
            runs["particle filter"] = np.asarray(pf.particles)
        seconds["particle filter"] = watch.seconds
        least_ess = float(np.min(np.asarray(pf.ess))) / n
    off_orbit = {}
    for name, analysis in _kalman_analyses(N, obs, inflations, lengths).items():
        with _common.Stopwatch() as watch:
            kf = sj.ensemble_kalman_filter(
                model,
                members,
                observations,
                dt=H,
                key=jax.random.key(seed + 15),
                driver=driver,
                analysis=analysis,
            )
            runs[name] = np.asarray(kf.particles)
        seconds[name] = watch.seconds
        off_orbit[name] = float(np.mean(np.asarray(kf.off_orbit)))
    c_truth = np.asarray(zeitlin.mat2shr(truth)).real
    coeffs = {name: np.asarray(zeitlin.mat2shr(x)).real for name, x in runs.items()}
    scores = {name: _scores(c, c_truth, obs, unobs, n, size["block"]) for name, c in coeffs.items()}
    return dict(
        seed=seed,
        M=M,
        N=N,
        members=n,
        observations=n_obs,
        noise_factor=float(factor),
        model_error_share=float(np.mean(1 - obs_std**2 / filter_std**2)),
        scores=scores,
        least_ess_share=least_ess,
        kalman_off_orbit=off_orbit,
        casimir_drift_conservative=_conservative_drift(train, fine, N, members, observations, seed),
        seconds=seconds,
    )


def _scores(c, c_truth, obs, unobs, n, block):
    """One ensemble's scores per observation (`c` its coefficients, `(n_obs, n, N^2)`)."""
    err = lambda idx: np.mean((c[:, :, idx].mean(1) - c_truth[:, idx]) ** 2, 1)
    var = lambda idx: (1 + 1 / n) * np.mean(c[:, :, idx].var(1, ddof=1), 1)
    ranks = (c < c_truth[:, None]).sum(1)  # (n_obs, N^2)
    degree = np.floor(np.sqrt(np.arange(c.shape[-1]))).astype(int)
    kept = []
    for k in range(0, c.shape[0], 2):  # (every other observation)
        for ell in sorted(set(degree[unobs])):
            idx = np.flatnonzero(degree == ell)
            kept.append((k, ell, ranks[k, idx[(k // 2) % idx.size]]))
    blocks = lambda a: a[: a.size // block * block].reshape(-1, block).mean(1)
    return dict(
        sq_error_observed=err(obs).tolist(),
        sq_error_unobserved=err(unobs).tolist(),
        sq_error_unobserved_blocks=blocks(err(unobs)).tolist(),
        variance_observed=var(obs).tolist(),
        variance_unobserved=var(unobs).tolist(),
        thinned_ranks=[[int(k), int(ell), int(r)] for k, ell, r in kept],
    )


def _conservative_drift(train, fine, N, members, observations, seed):
    """Every member's largest relative change of tr W^2, tr W^4, ... over 5 Kalman cycles of
    the closure's conservative part alone (gain and transport noise): the moves' only."""
    part = sj.fit_closure(
        train,
        dt=H * EVERY,
        fine=fine,
        coarse=sj.EulerZeitlin(N),
        parts=("hamiltonian", "transport"),
    )
    five = sj.Observations(
        observations.values[:5],
        observe=observations.observe,
        std=observations.std,
        times=observations.times[:5],
    )
    res = sj.ensemble_kalman_filter(
        part.system, members, five, dt=H, key=jax.random.key(seed + 16), driver=_filter_driver(part)
    )
    c0 = np.asarray(sj.su(N).casimirs(members))[:, ::2]
    cs = np.asarray(sj.su(N).casimirs(res.particles))[..., ::2]
    return float(np.max(np.abs(cs / c0 - 1)))


def summary(rows):
    """The pooled table over the seeds, then one row per seed."""
    lines = []
    pooled = {}
    filters = list(rows[0]["scores"])
    # (the free ensemble's: unobserved by blocks of observations, observed per observation)
    free = {
        key: np.concatenate([r["scores"]["free"][key] for r in rows])
        for key in ("sq_error_unobserved_blocks", "sq_error_observed")
    }
    for name in filters:
        s = [r["scores"][name] for r in rows]
        cat = lambda key: np.concatenate([x[key] for x in s])
        ranks = np.concatenate([[t[2] for t in x["thinned_ranks"]] for x in s])
        n = rows[0]["members"]
        bins = np.bincount(np.minimum(ranks * 8 // (n + 1), 7), minlength=8)
        pooled[name] = dict(
            rmse_observed=float(np.sqrt(cat("sq_error_observed").mean())),
            rmse_unobserved=float(np.sqrt(cat("sq_error_unobserved").mean())),
            spread_rmse_unobserved=float(
                np.sqrt(cat("variance_unobserved").mean() / cat("sq_error_unobserved").mean())
            ),
            rank_bins=bins.tolist(),
            rank_p=float(stats.chisquare(bins).pvalue),
            rank_lag1=_lag_one(s),
        )
        if name != "free":
            for part, key in (
                ("unobserved", "sq_error_unobserved_blocks"),
                ("observed", "sq_error_observed"),
            ):
                c = sj.paired_comparison(cat(key), free[key])
                pooled[name][f"{part}_vs_free"] = dict(relative=c.relative, ci=[*c.relative_ci])
            pooled[name]["observed_rmse_ratio"] = float(
                np.sqrt(cat("sq_error_observed").mean() / free["sq_error_observed"].mean())
            )
    seeds = ", ".join(str(r["seed"]) for r in rows)
    lines.append(
        f"su({rows[0]['M']}) truth -> su({rows[0]['N']}), seeds {seeds}, "
        f"{rows[0]['members']} members, {rows[0]['observations']} observations each.\n\n"
    )
    table = []
    for name, p in pooled.items():
        gain = p.get("unobserved_vs_free")
        table.append(
            dict(
                filter=name,
                rmse_obs=p["rmse_observed"],
                obs_ratio=p.get("observed_rmse_ratio", 1.0),
                rmse_unobs=p["rmse_unobserved"],
                unobs_vs_free="" if gain is None else _ci(gain),
                spread_rmse_unobs=p["spread_rmse_unobserved"],
                rank_p=p["rank_p"],
                rank_lag1=p["rank_lag1"],
            )
        )
    lines.append(
        _common.markdown_table(
            table,
            list(table[0]),
            dict(
                rmse_obs=".4f",
                obs_ratio=".2f",
                rmse_unobs=".4f",
                spread_rmse_unobs=".2f",
                rank_p=".2g",
                rank_lag1=".2f",
            ),
        )
    )
    lines.append("\nPer seed:\n\n")
    per = []
    for r in rows:
        s = r["scores"]
        per.append(
            dict(
                seed=r["seed"],
                factor=r["noise_factor"],
                model_error_share=r["model_error_share"],
                **{
                    f"unobs {k}": float(np.sqrt(np.mean(s[k]["sq_error_unobserved"])))
                    for k in filters
                },
                **({} if r["least_ess_share"] is None else {"pf_least_ess": r["least_ess_share"]}),
                kalman_off_orbit=next(iter(r["kalman_off_orbit"].values())),
                casimir_drift=r["casimir_drift_conservative"],
                **{f"{k} s": r["seconds"][k] for k in filters},
            )
        )
    lines.append(_common.markdown_table(per, list(per[0]), {k: ".3g" for k in per[0]}))
    return "".join(lines), pooled


def _ci(c):
    return f"{100 * c['relative']:+.1f} % [{100 * c['ci'][0]:+.1f}, {100 * c['ci'][1]:+.1f}]"


def _lag_one(scores):
    """The mean lag-one autocorrelation of the thinned ranks, per seed and degree."""
    out = []
    for s in scores:
        t = np.asarray(s["thinned_ranks"])
        for ell in np.unique(t[:, 1]):
            r = t[t[:, 1] == ell, 2].astype(float)
            if r.size > 2 and r.std() > 0:
                out.append(np.corrcoef(r[:-1], r[1:])[0, 1])
    return float(np.mean(out)) if out else float("nan")


def main(argv=None):
    p = _common.parser(__doc__, "a smoke run: M = 20, N = 5, 8 members, 4 observations")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    for option, default, what in (
        ("--inflations", 1.0, "inflations (1: KalmanAnalysis()'s default)"),
        ("--localizations", 1.5, "taper lengths in degrees, localised"),
    ):
        p.add_argument(
            option, type=float, nargs="+", default=[default], help=f"the Kalman filter's {what}"
        )
    p.add_argument("--M", type=int, default=FULL["M"], help="the truth's su(M) (N = M/4)")
    p.add_argument(
        "--no-particle-filter", action="store_true", help="the free ensemble and Kalman filters"
    )
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    size = FAST if args.fast else dict(FULL, M=args.M)
    rows = []
    for seed in [0] if args.fast else args.seeds:
        rows.append(
            case(seed, size, args.inflations, args.localizations, not args.no_particle_filter)
        )
        print({k: rows[-1][k] for k in ("seed", "noise_factor", "seconds")}, flush=True)
    text, pooled = summary(rows)
    print(text, flush=True)
    stem = "filters" if size["M"] in (FULL["M"], FAST["M"]) else f"filters_{size['M']}"
    results.json(stem, dict(rows=rows, pooled=pooled))
    results.markdown(stem, text)


if __name__ == "__main__":
    main()
