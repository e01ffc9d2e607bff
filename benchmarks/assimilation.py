"""A twin experiment for the filters on the sphere (`particle_filter`, and
`ensemble_kalman_filter` without and with localisation by degree): the truth a run of su(M) coarse-grained
to su(N), the model su(N) with the transport noise `fit_transport_noise` fits to the truth's
spin-up, the degrees 1..3 observed every `every` steps with errors of 10 % of each coefficient's
standard deviation (over the training run; degree 1, conserved by the truth, gets that of degrees
2..3), `n` particles at the truth's first time: the noisy model run for one interval from the
truth an interval before (not from the first state, which would leave them an interval ahead of
the truth). pCN moves the increments of the last `lag` intervals (`jitter_lag`).

Against the free ensemble, the same particles run on without observations, for each filter:
the RMSE of the ensemble mean and the spread on the observed and the unobserved
coefficients, the paired gain in squared error at each observation time, a rank histogram of
the truth among the members on the observed coefficients with its chi-square p-value, every
member's Casimir drift, and the time; for the particle filter also the least stage ESS, the
tempering stages and pCN's acceptance. The Kalman filters run with `KalmanAnalysis()` and
with `KalmanAnalysis(localization=Localization.by_degree(N, degrees, 1.5))`, as in
`filters.py`.

    python benchmarks/assimilation.py                  # M = 32, N = 8, 64 particles, 20 obs.
    python benchmarks/assimilation.py --fast           # M = 10, N = 5, 8 particles, 2 obs.
    python benchmarks/assimilation.py --perfect-model  # the truth one more run of the model
    python benchmarks/assimilation.py --lag 1          # pCN on the last interval alone

Forecasts of one observation interval, 16 members from each of 24 starts of the training run
(before the assimilation window), tune the fitted noise's amplitude (`tune_amplitude`: least
CRPS over every coefficient; `--no-tune` keeps it as fitted) and measure the model's error
beyond its ensembles' spread (`model_error_variance`), whose variance the filter adds to the
observation errors' (`--no-model-error`: the observation errors alone).

Writes `assimilation.json` and `assimilation.md` into `--out`.
"""

import time

import _common
import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

jax.config.update("jax_enable_x64", True)

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin as z  # noqa: E402

FULL = dict(M=32, N=8, n=64, n_obs=20, lag=4)
# (the notebook's small size: compiling dominates, so it skips the tuning and the model error)
SMALL = dict(M=10, N=5, n=8, n_obs=2, every=25, spin=100, train=200, tune=False, model_error=False)


def experiment(
    M,
    N,
    n,
    n_obs,
    every=50,
    h=0.01,
    spin=2000,
    train=3000,
    seed=0,
    model_error=True,
    tune=True,
    starts=24,
    lag=1,
    perfect=False,
):
    start = time.perf_counter()
    rng = np.random.default_rng(seed)
    omega = np.r_[0, rng.normal(size=M * M - 1) / np.floor(np.sqrt(np.arange(1, M * M)))]
    omega[N * N :] *= 0.3  # (less energy below the coarse grid)
    steps = spin + train + every * n_obs
    fine = sj.integrate(
        sj.EulerZeitlin(M), z.shr2mat(omega, M), np.zeros((steps, 1)), h, save_every=1
    )
    fit = sj.fit_transport_noise(fine[spin : spin + train + 1], dt=h, N=N)
    # Forecasts of one observation interval from starts of the training run (before the
    # assimilation window) tune the noise's amplitude (least CRPS over every coefficient)
    # and measure the model's error beyond its ensembles' spread.
    at = spin + np.linspace(0, train - every, starts).astype(int)
    starts_n, after_n = z.truncate(fine[at], N), z.truncate(fine[at + every], N)[:, None]
    factor = 1.0
    if tune:
        factor = sj.tune_amplitude(
            sj.EulerZeitlin(N, noise=fit.noise),
            starts_n,
            after_n,
            observe=lambda w: jnp.real(z.mat2shr(w))[..., 1:],
            lead=every,
            dt=h,
            every=every,
            members=16,
            key=jax.random.key(seed + 100),
        ).factor
    model = sj.EulerZeitlin(N, noise=sj.scaled_noise(fit.noise, factor))
    truth = z.truncate(fine[spin + train :: every][: n_obs + 1], N)
    if perfect:  # (a perfect-model twin: the truth one more run of the model)
        truth = sj.simulate(
            model,
            truth[0],
            t1=every * h * n_obs,
            dt=h,
            n_samples=1,
            key=jax.random.key(seed + 102),
            save_every=every,
            driver=sj.BrownianMotion(levy_area=False),
        ).ys[0]
    c_truth = np.asarray(z.mat2shr(truth)).real
    obs = np.arange(1, min(16, N * N))  # degrees 1..3
    unobs = np.arange(obs[-1] + 1, N * N)
    c_train = np.asarray(z.mat2shr(z.truncate(fine[spin : spin + train : 10], N))).real
    sd = c_train[:, obs].std(0)
    sd = np.maximum(sd, sd[3:].mean())  # (degree 1 is conserved by the truth)
    obs_std = 0.1 * sd
    ys = c_truth[1:, obs] + obs_std * rng.normal(size=(n_obs, obs.size))
    observe = lambda w: jnp.real(z.mat2shr(w))[..., obs]
    # (the model's error beyond its spread: the filter adds its variance to the observations')
    filter_std, share, z_score = obs_std, None, None
    if model_error:
        forecasts = sj.forecast_ensembles(
            model,
            starts_n,
            lead=every,
            dt=h,
            every=every,
            members=16,
            key=jax.random.key(seed + 101),
        )
        budget = sj.model_error_variance(forecasts, after_n, observe)
        excess = np.maximum(budget.variance[0], 0.0)
        filter_std = np.sqrt(obs_std**2 + excess)
        share = float(np.mean(excess / (obs_std**2 + excess)))
        z_score = float(np.mean(budget.variance[0] / budget.stderr[0]))
    # (the particles at the truth's first time: the noisy model run for one interval from the
    # truth an interval before it, so that their spread costs no lag behind the truth)
    init = sj.simulate(
        model,
        z.truncate(fine[spin + train - every], N),
        t1=every * h,
        dt=h,
        n_samples=n,
        key=jax.random.key(9),
        driver=sj.BrownianMotion(levy_area=False),
    ).ys[:, -1]
    observations = sj.Observations(
        ys, times=every * h * np.arange(1, n_obs + 1), observe=observe, std=filter_std
    )
    seconds, ensembles = {}, {}
    t0 = time.perf_counter()
    res = sj.particle_filter(
        model,
        init,
        observations,
        dt=h,
        key=jax.random.key(seed),
        tempering=sj.Tempering(jitter_lag=lag),
    )
    ensembles["particle filter"] = res.particles
    seconds["particle filter"] = time.perf_counter() - t0
    degrees = np.floor(np.sqrt(obs))
    for name, analysis in (
        ("orbit Kalman", sj.KalmanAnalysis()),
        (
            "orbit Kalman, localised 1.5",
            sj.KalmanAnalysis(localization=sj.Localization.by_degree(N, degrees, 1.5)),
        ),
    ):
        t0 = time.perf_counter()
        kf = sj.ensemble_kalman_filter(
            model, init, observations, dt=h, key=jax.random.key(seed + 3), analysis=analysis
        )
        ensembles[name] = kf.particles
        seconds[name] = time.perf_counter() - t0
    # (the free ensemble: the filter's initial particles run on without observations)
    free = sj.forecast_ensembles(
        model, init, lead=every * n_obs, dt=h, every=every, members=1, key=jax.random.key(1)
    )[:, 0]
    cf = np.asarray(z.mat2shr(free)).real.transpose(1, 0, 2)

    def rmse(c, idx, axis=None):  # (over times and coefficients, or per time: axis=1)
        return np.sqrt(((c[:, :, idx].mean(1) - c_truth[1:, idx]) ** 2).mean(axis))

    def spread(c, idx, axis=None):  # (sqrt((1 + 1/n) spread^2): the RMSE of a calibrated one)
        return np.sqrt((1 + 1 / n) * c[:, :, idx].var(1, ddof=1).mean(axis))

    def paired(c1, c2, idx):
        d = rmse(c1, idx, 1) ** 2 - rmse(c2, idx, 1) ** 2
        return [float(d.mean()), float(d.std(ddof=1) / np.sqrt(d.size))]

    c0 = np.asarray(sj.su(N).casimirs(init))[:, None, ::2]  # tr W^2, tr W^4, ...

    def scores(x):
        c = np.asarray(z.mat2shr(x)).real
        ranks = (c[:, :, obs] < c_truth[1:, None, obs]).sum(1).ravel()
        bins = np.add.reduceat(
            np.bincount(ranks, minlength=n + 1), np.linspace(0, n + 1, 6, dtype=int)[:-1]
        )
        cs = np.asarray(sj.su(N).casimirs(x)).transpose(1, 0, 2)[..., ::2]
        drift = np.abs(cs / c0.mean(0) - 1).max(axis=(1, 2))  # (per member slot, all times)
        table = dict(
            rmse_observed=rmse(c, obs),
            rmse_unobserved=rmse(c, unobs),
            # (free minus filter squared error, mean and standard error over the observation
            # times; the times are correlated, so the error bar is optimistic)
            gain_observed=paired(cf, c, obs),
            gain_unobserved=paired(cf, c, unobs),
            spread_observed=spread(c, obs),
            spread_unobserved=spread(c, unobs),
            rank_bins=bins.tolist(),
            rank_chi2_p=float(stats.chisquare(bins).pvalue),
            casimir_drift=float(drift.max()),
        )
        per_time = dict(
            rmse={
                part: rmse(c, idx, 1) for part, idx in (("observed", obs), ("unobserved", unobs))
            },
            spread={
                part: spread(c, idx, 1) for part, idx in (("observed", obs), ("unobserved", unobs))
            },
            ranks=np.bincount(ranks, minlength=n + 1),
            casimir_drift=drift,
        )
        return {
            k: float(v) if isinstance(v, np.floating) else v for k, v in table.items()
        }, per_time

    filters, per_time = {}, {}
    ensembles = {"free": jnp.swapaxes(free, 0, 1), **ensembles}
    for name, x in ensembles.items():
        filters[name], per_time[name] = scores(x)
    series = dict(
        times=every * h * np.arange(1, n_obs + 1),
        ensembles=per_time,
        ess_share=np.asarray(res.ess) / n,
        stages=np.array([len(t) for t in res.temperatures]),
        # (the last observation time's states: the truth, and each ensemble's mean)
        final=dict(
            truth=np.asarray(truth[-1]),
            **{name: np.asarray(x[-1]).mean(0) for name, x in ensembles.items()},
        ),
    )
    row = dict(
        M=M,
        N=N,
        particles=n,
        observations=n_obs,
        jitter_lag=lag,
        perfect_model=perfect,
        eofs=len(fit.std),
        noise_factor=factor,
        model_error=model_error,
        model_error_share=share,
        model_error_z=z_score,
        ensembles=filters,
        least_ess_share=float(res.ess.min()) / n,
        stages_mean=float(np.mean([len(t) for t in res.temperatures])),
        acceptance=float(np.mean([a.mean() for a in res.acceptance])),
        seconds=seconds,
        total_s=time.perf_counter() - start,
    )
    return {k: float(v) if isinstance(v, np.floating) else v for k, v in row.items()}, series


def main(argv=None):
    p = _common.parser(__doc__, "M = 10, N = 5, 8 particles, 2 observations, no tuning")
    p.add_argument(
        "--no-tune",
        action="store_true",
        help="the fitted noise as it is, not its amplitude tuned on the training forecasts",
    )
    p.add_argument(
        "--no-model-error",
        action="store_true",
        help="the filter with the observation errors alone, not the model's estimated error",
    )
    p.add_argument(
        "--lag",
        type=int,
        default=None,
        help="pCN's window in observation intervals (particle_filter's jitter_lag; 4, 1 with --fast)",
    )
    p.add_argument(
        "--perfect-model",
        action="store_true",
        help="a perfect-model twin: the truth one more run of the model, not the fine run",
    )
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    sizes = dict(SMALL if args.fast else FULL)
    if args.no_model_error:
        sizes["model_error"] = False
    if args.no_tune:
        sizes["tune"] = False
    if args.lag is not None:
        sizes["lag"] = args.lag
    row, _ = experiment(
        **sizes,
        perfect=args.perfect_model,
    )
    print(summary(row), flush=True)
    results.json("assimilation", dict(rows=[row]))
    results.markdown("assimilation", summary(row))


def summary(row):
    """The run's settings, then a table of the filters against the free ensemble."""
    lines = [f"- {k}: {v}" for k, v in row.items() if k not in ("ensembles", "seconds")]
    table = []
    for name, f in row["ensembles"].items():
        gain, se = f["gain_unobserved"]
        table.append(
            dict(
                ensemble=name,
                **{k: f[k] for k in ("rmse_observed", "rmse_unobserved")},
                gain_unobserved="" if name == "free" else f"{gain:+.5f} ± {se:.5f}",
                **{k: f[k] for k in ("spread_unobserved", "rank_chi2_p", "casimir_drift")},
                seconds=f"{row['seconds'][name]:.1f}" if name in row["seconds"] else "",
            )
        )
    formats = dict(
        rmse_observed=".4f",
        rmse_unobserved=".4f",
        spread_unobserved=".4f",
        rank_chi2_p=".2g",
        casimir_drift=".2g",
    )
    return "\n".join(lines) + "\n\n" + _common.markdown_table(table, list(table[0]), formats)


if __name__ == "__main__":
    main()
