"""A twin experiment for `particle_filter` on the sphere: the truth a run of su(M) coarse-grained
to su(N), the model su(N) with the transport noise `fit_transport_noise` fits to the truth's
spin-up, the degrees 1..3 observed every `every` steps with errors of 10 % of each coefficient's
standard deviation (over the training run; degree 1, conserved by the truth, gets that of degrees
2..3), `n` particles started from the truth's first state spread by half a second of the noisy
model. Against a free ensemble of the same model from the same state: the RMSE of the ensemble
mean on the observed and the unobserved coefficients, the least stage ESS, the tempering stages,
pCN's acceptance, a rank histogram of the truth among the particles with its chi-square p-value,
every particle's Casimir drift, and the time.

    python benchmarks/assimilation.py            # M = 32, N = 8, 64 particles, 20 observations
    python benchmarks/assimilation.py --fast     # M = 12, N = 5, 8 particles, 2 observations

Writes `assimilation.json` and `assimilation.md` into `--out`.
"""

import os
import time

import _common
import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

jax.config.update("jax_enable_x64", True)

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin as z  # noqa: E402


def experiment(M, N, n, n_obs, every=50, h=0.01, spin=2000, train=3000, seed=0):
    start = time.perf_counter()
    rng = np.random.default_rng(seed)
    omega = np.r_[0, rng.normal(size=M * M - 1) / np.floor(np.sqrt(np.arange(1, M * M)))]
    omega[N * N :] *= 0.3  # (less energy below the coarse grid)
    steps = spin + train + every * n_obs
    fine = sj.integrate(
        sj.EulerZeitlin(M), z.shr2mat(omega, M), np.zeros((steps, 1)), h, save_every=1
    )
    fit = sj.fit_transport_noise(fine[spin : spin + train + 1], dt=h, N=N)
    model = sj.EulerZeitlin(N, noise=fit.noise)
    truth = z.truncate(fine[spin + train :: every][: n_obs + 1], N)
    c_truth = np.asarray(z.mat2shr(truth)).real
    obs = np.arange(1, min(16, N * N))  # degrees 1..3
    unobs = np.arange(obs[-1] + 1, N * N)
    c_train = np.asarray(z.mat2shr(z.truncate(fine[spin : spin + train : 10], N))).real
    sd = c_train[:, obs].std(0)
    sd = np.maximum(sd, sd[3:].mean())  # (degree 1 is conserved by the truth)
    obs_std = 0.1 * sd
    ys = c_truth[1:, obs] + obs_std * rng.normal(size=(n_obs, obs.size))
    init = sj.simulate(
        model,
        truth[0],
        t1=0.5,
        dt=h,
        n_samples=n,
        key=jax.random.key(9),
        driver=sj.BrownianMotion(levy_area=False),
    ).ys[:, -1]
    t0 = time.perf_counter()
    res = sj.particle_filter(
        model,
        init,
        ys,
        obs_times=every * h * np.arange(1, n_obs + 1),
        observe=lambda w: jnp.real(z.mat2shr(w))[obs],
        obs_std=obs_std,
        dt=h,
        key=jax.random.key(seed),
    )
    filter_s = time.perf_counter() - t0
    free = sj.simulate(
        model,
        truth[0],
        t1=every * h * n_obs,
        dt=h,
        n_samples=n,
        key=jax.random.key(1),
        save_every=every,
        driver=sj.BrownianMotion(levy_area=False),
    ).ys[:, 1:]
    ca = np.asarray(z.mat2shr(res.particles)).real
    cf = np.asarray(z.mat2shr(free)).real.transpose(1, 0, 2)

    def rmse(c, idx):
        return float(np.sqrt(((c[:, :, idx].mean(1) - c_truth[1:, idx]) ** 2).mean()))

    ranks = (ca[:, :, obs] < c_truth[1:, None, obs]).sum(1).ravel()
    bins = np.add.reduceat(
        np.bincount(ranks, minlength=n + 1), np.linspace(0, n + 1, 6, dtype=int)[:-1]
    )
    c0 = np.asarray(sj.su(N).casimirs(init))[:, None, ::2]  # tr W^2, tr W^4, ...
    cs = np.asarray(sj.su(N).casimirs(res.particles)).transpose(1, 0, 2)[..., ::2]
    return dict(
        M=M,
        N=N,
        particles=n,
        observations=n_obs,
        eofs=len(fit.std),
        rmse_observed=rmse(ca, obs),
        rmse_observed_free=rmse(cf, obs),
        rmse_unobserved=rmse(ca, unobs),
        rmse_unobserved_free=rmse(cf, unobs),
        least_ess_share=float(res.ess.min()) / n,
        stages_mean=float(np.mean([len(t) for t in res.temperatures])),
        acceptance=float(np.mean([a.mean() for a in res.acceptance])),
        rank_bins=bins.tolist(),
        rank_chi2_p=float(stats.chisquare(bins).pvalue),
        casimir_drift=float(np.max(np.abs(cs / c0.mean(0) - 1))),
        filter_s=filter_s,
        total_s=time.perf_counter() - start,
    )


def main(argv=None):
    p = _common.parser(__doc__, "M = 12, N = 5, 8 particles, 2 observations")
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    info = _common.machine_info()
    sizes = (
        dict(M=12, N=5, n=8, n_obs=2, spin=200, train=300)
        if args.fast
        else dict(M=32, N=8, n=64, n_obs=20)
    )
    row = experiment(**sizes)
    for k, v in row.items():
        print(f"{k}: {v}", flush=True)
    _common.write_json(os.path.join(args.out, "assimilation.json"), dict(machine=info, rows=[row]))
    with open(os.path.join(args.out, "assimilation.md"), "w") as fh:
        fh.write(
            f"Measured on {_common.device_name(info)}, jax {info['jax']}, {info['date'][:10]}.\n\n"
        )
        fh.write("\n".join(f"- {k}: {v}" for k, v in row.items()) + "\n")


if __name__ == "__main__":
    main()
