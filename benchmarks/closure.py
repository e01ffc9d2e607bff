#!/usr/bin/env python
"""A fitted closure on forced-dissipative twins: `fit_closure`'s shares of the missed tendency
and its forecasts, against a tuned isotropic noise.

For each seed and size: a forced-dissipative su(M) truth (hyperviscosity p = 2, linear
damping 0.1 /s, white additive forcing on degrees 3..5), spun up for 15 s, then 5000
snapshots 0.05 s apart (h = 0.01 s); the coarse model su(N), N = M/4, has the same linear
terms and forcing. The closure is fitted on the first 4000 snapshots (200 s), and each
part's share of the missed tendency reported on them and on the last 1000 (held out), with
the Hamiltonian and the damping also fitted alone. Chosen before the runs: the coefficients
of degrees 2..N-1 at leads 0.4, 0.8, ..., 4 s; 8 tuning starts inside the training period
(16 members) for one amplitude factor each (1/32 ... 8 in ratios of sqrt 2, then the
midpoints beside the best) of the closure's noises (`ClosureFit.scaled`: transport and
additive together) and of an isotropic transport noise of degrees 2..N-1 on the coarse
model; 16 held-out starts spread over the held-out span, 32 members; and the closure trained
on the fair CRPS of forecasts from other training starts (`train_closure`: 8 members, 40 steps
from the tuned factor), twice: on 1 s forecasts from 32 starts (leads 0.2 ... 1 s) and on the
evaluation's leads (0.4 ... 4 s) from 16 starts, each one's factor then tuned as the others'.
Per held-out start the fair CRPS over the leads, paired bootstrap 90 % CIs of the closure
against the isotropic noise and against the coarse model with its forcing alone, and the
spread/RMSE at every lead. First, the fit's time alone at each size of `--cost` (run it
alone: it is a timing).

Writes `closure.json` and `closure.md` into --out (default benchmarks/results).

    python benchmarks/closure.py [--fast] [--seeds 0 1 2] [--sizes 32] [--out DIR]
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import os  # noqa: E402
import sys  # noqa: E402

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _common  # noqa: E402

import slps_jax as sj  # noqa: E402
from slps_jax import zeitlin  # noqa: E402

H, EVERY = 0.01, 5  # the truth's step and the snapshots' spacing in steps
FULL = dict(spin=15.0, train=4000, held=1000, tune=8, starts=16, lead=400, every=40, members=32)
TRAININGS = (  # (train_closure's: 1 s forecasts, and the evaluation's leads)
    dict(starts=32, lead=100, every=20, members=8, steps=40),
    dict(starts=16, lead=400, every=40, members=8, steps=40),
)
FACTORS = tuple(2.0 ** np.arange(-5.0, 3.25, 0.5))  # 1/32 ... 8 (the fitted noise's optimum
# can lie below the default grid's 1/8)
FAST = dict(spin=1.0, train=40, held=24, tune=2, starts=3, lead=20, every=10, members=4)
FAST_TRAININGS = (
    dict(starts=3, lead=10, every=5, members=3, steps=2),
    dict(starts=2, lead=20, every=10, members=3, steps=2),
)


def terms(M):
    """The truth's and the coarse model's linear terms and forcing (the same, in seconds;
    the smoke run's small sizes force degrees 2..3)."""
    nu = 1e-6 * (32 / M) ** 4
    return dict(nu=nu, p=2, alpha=0.1), sj.AdditiveForcing((3, 5) if M >= 24 else (2, 3), 0.5)


def truth(M, snapshots, seed, spin=15.0):
    """`snapshots` states of the forced-dissipative su(M) truth, 0.05 s apart, after `spin`
    seconds from a small random state."""
    linear, forcing = terms(M)
    system = sj.EulerZeitlin(M, **linear, additive=forcing)
    rng = np.random.default_rng(seed)
    w0 = zeitlin.shr2mat(np.r_[0.0, 0.01 * rng.normal(size=M * M - 1)], M)
    key = jax.random.key(seed)
    start = sj.simulate(system, w0, t1=spin, dt=H, n_samples=1, key=key).ys.reshape(M, M)
    ys = sj.simulate(
        system,
        start,
        t1=snapshots * EVERY * H,
        dt=H,
        n_samples=1,
        key=jax.random.fold_in(key, 1),
        save_every=EVERY,
    ).ys
    return np.asarray(ys)[0, 1:]


def isotropic(N, fit):
    """The coarse model with an isotropic transport noise of degrees 2..N-1 (every harmonic
    alike), of the closure's transport L2 to start from (its amplitude is tuned)."""
    basis = np.asarray(zeitlin.shr2mat(np.eye(N * N)[4:], N))
    total = float(np.sum(np.asarray(zeitlin.enstrophy(fit.transport.noise.chi))))
    scale = np.sqrt(total / float(np.sum(np.asarray(zeitlin.enstrophy(basis)))))
    linear, forcing = terms(4 * N)
    return sj.EulerZeitlin(N, **linear, additive=forcing, noise=sj.salt_noise(-scale * basis))


def _with_factor(system, factor):
    """`system` with its transport noise times `factor` (its forcing kept)."""
    return eqx.tree_at(lambda s: s.noise, system, sj.scaled_noise(system.noise, factor))


def case(M, seed, size):
    N = M // 4
    linear, forcing = terms(M)
    seconds = {}
    with _common.Stopwatch() as watch:
        ys = truth(M, size["train"] + size["held"], seed, spin=size["spin"])
    seconds["truth"] = watch.seconds
    train, held = ys[: size["train"]], ys[size["train"] :]
    fine = sj.EulerZeitlin(M, **linear)
    coarse = sj.EulerZeitlin(N, **linear, additive=forcing)
    with _common.Stopwatch() as watch:
        fit = sj.fit_closure(train, dt=H * EVERY, fine=fine, coarse=coarse)
    seconds["fit"] = watch.seconds
    shares = dict(training=fit.shares, held_out=fit.explained(held))
    alone = {
        part: sj.fit_closure(train, dt=H * EVERY, fine=fine, coarse=coarse, parts=(part,))
        for part in ("hamiltonian", "damping")
    }
    shares["held_out, fitted alone"] = {k: f.explained(held)["closure"] for k, f in alone.items()}
    # forecasts of the truth's coarse graining, chosen before the runs: degrees 2..N-1
    every, lead = size["every"], size["lead"]
    stride, span = every // EVERY, lead // EVERY
    times = stride * np.arange(1, lead // every + 1)
    lead_times = H * every * np.arange(1, lead // every + 1)  # (in seconds)

    def coarse_of(idx):
        return np.asarray(zeitlin.truncate(ys[idx.ravel()], N)).reshape(*idx.shape, N, N)

    tune_at = np.linspace(0, size["train"] - span - 1, size["tune"]).astype(int)
    test_at = size["train"] + np.linspace(0, size["held"] - span - 1, size["starts"]).astype(int)
    observe = lambda w: zeitlin.mat2shr(w)[..., 4:]
    forecast = dict(lead=lead, dt=H, every=every)
    baseline = isotropic(N, fit)
    searches = {
        "closure": (
            fit.system,
            sj.AmplitudeSearch(FACTORS, scale=lambda s, f: fit.scaled(f)),
            fit.driver,
        ),
        "isotropic": (baseline, sj.AmplitudeSearch(FACTORS), None),
    }
    with _common.Stopwatch() as watch:
        tuning = {
            name: sj.tune_amplitude(
                system,
                coarse_of(tune_at),
                coarse_of(tune_at[:, None] + times),
                observe=observe,
                members=max(2, size["members"] // 2),
                key=jax.random.key(seed + 10),
                search=search,
                driver=driver,
                **forecast,
            )
            for name, (system, search, driver) in searches.items()
        }
    seconds["tuning"] = watch.seconds
    # the closure trained on the CRPS of forecasts from other training starts (from the tuned
    # factor), at each protocol's leads, then its own factor tuned as the others'
    trained = {}
    for training in size["trainings"]:
        name = trained_name(training)
        t_span = training["lead"] // EVERY
        train_at = np.linspace(0, size["train"] - t_span - 1, training["starts"]).astype(int)
        t_times = (training["every"] // EVERY) * np.arange(
            1, training["lead"] // training["every"] + 1
        )
        with _common.Stopwatch() as watch:
            trained[name] = t = sj.train_closure(
                fit,
                coarse_of(train_at),
                coarse_of(train_at[:, None] + t_times),
                lead=training["lead"],
                dt=H,
                every=training["every"],
                members=training["members"],
                key=jax.random.key(seed + 30),
                observe=observe,
                factor=tuning["closure"].factor,
                optimisation=sj.Optimisation(steps=training["steps"], progress=False),
            )
        seconds[f"training, {name}"] = watch.seconds
        tuning[name] = sj.tune_amplitude(
            t.system,
            coarse_of(tune_at),
            coarse_of(tune_at[:, None] + times),
            observe=observe,
            members=max(2, size["members"] // 2),
            key=jax.random.key(seed + 10),
            search=sj.AmplitudeSearch(FACTORS, scale=lambda s, f, t=t: t.scaled(f)),
            driver=t.driver,
            **forecast,
        )
    systems = {
        "closure": (fit.scaled(tuning["closure"].factor), fit.driver),
        "closure, untuned": (fit.system, fit.driver),
        "closure, no noise": (fit.scaled(0.0), fit.driver),
        **{name: (t.system, t.driver) for name, t in trained.items()},
        "isotropic": (_with_factor(baseline, tuning["isotropic"].factor), None),
        "no closure": (coarse, None),
    }
    x0, y = coarse_of(test_at), coarse_of(test_at[:, None] + times)
    with _common.Stopwatch() as watch:
        ensembles = {
            name: sj.forecast_ensembles(
                system,
                x0,
                members=size["members"],
                key=jax.random.key(seed + 20),
                driver=driver,
                **forecast,
            )
            for name, (system, driver) in systems.items()
        }
    seconds["held-out forecasts"] = watch.seconds
    crps = {name: sj.start_crps(e, y, observe) for name, e in ensembles.items()}
    pooled = lambda a: np.moveaxis(a, 0, -2).reshape(*a.shape[1:-1], -1)
    truth_obs = np.asarray(observe(jnp.asarray(y)))
    ratio = {
        name: sj.forecast_scores(pooled(np.asarray(observe(e))), pooled(truth_obs)).ratio
        for name, e in ensembles.items()
    }
    pairs = [
        ("closure", "isotropic"),
        *((name, other) for name in trained for other in ("closure", "isotropic")),
        ("closure, untuned", "isotropic"),
        ("closure", "no closure"),
        ("closure, no noise", "no closure"),
        ("isotropic", "no closure"),
    ]
    comparisons = {}
    for a, b in pairs:
        c = sj.paired_comparison(crps[a], crps[b])
        comparisons[f"{a} vs {b}"] = dict(relative=c.relative, ci=[*c.relative_ci])
    # each trained closure at the leads it was trained on, where they are fewer than all
    for training, name in zip(size["trainings"], trained):
        short = int(np.sum(lead_times <= H * training["lead"] + 1e-9))
        if short == len(lead_times):
            continue
        early = {
            n: sj.start_crps(ensembles[n][:, :, :short], y[:, :short], observe)
            for n in (name, "closure")
        }
        c = sj.paired_comparison(early[name], early["closure"])
        comparisons[f"{name} vs closure, trained leads"] = dict(
            relative=c.relative, ci=[*c.relative_ci], leads=short
        )
    return dict(
        M=M,
        N=N,
        seed=seed,
        seconds=seconds,
        shares=shares,
        n_transport_modes=int(fit.transport.modes.shape[0]),
        gain=fit.gain.tolist(),
        damping=fit.damping.tolist(),
        factors={k: v.factor for k, v in tuning.items()},
        trained={
            name: dict(
                protocol=dict(training),
                start=dict(  # (the fit's, before the training's factor)
                    transport_scale=float(fit.transport_scale),
                    additive_std=fit.additive_std.tolist(),
                ),
                loss=t.training.tolist(),
                gain=t.gain.tolist(),
                damping=t.damping.tolist(),
                transport_scale=np.asarray(t.transport_scale).tolist(),
                additive_std=t.additive_std.tolist(),
                held_out_shares=t.explained(held),
            )
            for training, (name, t) in zip(size["trainings"], trained.items())
        },
        crps={k: float(np.mean(v)) for k, v in crps.items()},
        comparisons=comparisons,
        spread_rmse={k: [float(x) for x in v] for k, v in ratio.items()},
        lead_times=lead_times.tolist(),
    )


def trained_name(training):
    """The label of the closure trained with `training`'s protocol: by its forecasts' lead."""
    return f"closure, trained {H * training['lead']:g} s"


def fit_cost(sizes, snapshots):
    """The fit's time alone at each size, from `snapshots` snapshots (of a truth spun up
    for 1 s: for the time only), the first call in this process for each size (compilation
    included)."""
    rows = []
    for M in sizes:
        ys = truth(M, snapshots, seed=0, spin=1.0)
        linear, forcing = terms(M)
        fine = sj.EulerZeitlin(M, **linear)
        coarse = sj.EulerZeitlin(M // 4, **linear, additive=forcing)
        with _common.Stopwatch() as watch:
            sj.fit_closure(ys, dt=H * EVERY, fine=fine, coarse=coarse)
        rows.append(dict(M=M, N=M // 4, snapshots=snapshots, seconds=watch.seconds))
        print(rows[-1], flush=True)
    return rows


def summary(rows, cost):
    """The Markdown tables: shares, forecasts, cost."""
    pct = lambda x: f"{100 * x:.1f} %"
    ci = lambda c: (
        f"{100 * c['relative']:+.1f} % [{100 * c['ci'][0]:+.1f}, {100 * c['ci'][1]:+.1f}]"
    )
    parts = ("hamiltonian", "damping", "closure", "transport", "additive")
    text = "Shares of the missed tendency (training / held out):\n\n"
    text += "| M → N | seed | " + " | ".join(parts) + " |\n|" + "---|" * (len(parts) + 2) + "\n"
    for r in rows:
        s = r["shares"]
        cells = [f"{pct(s['training'][p])} / {pct(s['held_out'][p])}" for p in parts]
        text += f"| {r['M']} → {r['N']} | {r['seed']} | " + " | ".join(cells) + " |\n"
    text += "\nForecasts, held-out starts, fair CRPS of degrees 2..N-1 over the leads (paired "
    text += "bootstrap 90 % CI), tuned factors, spread/RMSE (least and largest over the leads):\n\n"
    text += (
        "| M → N | seed | closure vs isotropic | untuned closure vs isotropic | closure vs no "
        "closure | closure without its noises vs no closure | factor closure / isotropic | "
        "spread/RMSE closure | spread/RMSE isotropic |\n" + "|---" * 9 + "|\n"
    )
    for r in rows:
        c, f, q = r["comparisons"], r["factors"], r["spread_rmse"]
        span = lambda v: f"{min(v):.2f}–{max(v):.2f}"
        text += (
            f"| {r['M']} → {r['N']} | {r['seed']} | {ci(c['closure vs isotropic'])} | "
            f"{ci(c['closure, untuned vs isotropic'])} | {ci(c['closure vs no closure'])} | "
            f"{ci(c['closure, no noise vs no closure'])} | "
            f"{f['closure']:.2f} / {f['isotropic']:.2f} | {span(q['closure'])} | "
            f"{span(q['isotropic'])} |\n"
        )
    text += (
        "\nThe closure trained on the CRPS of forecasts (`train_closure`), by its training "
        "starts and leads, on the same held-out starts: paired 90 % CIs, its factor tuned after "
        "training, spread/RMSE, the training loss at its start and end, and its time:\n\n"
        "| M → N | seed | trained on | trained vs closure | the same, leads trained on | "
        "trained vs isotropic | factor trained | spread/RMSE trained | training loss | seconds "
        "|\n" + "|---" * 10 + "|\n"
    )
    for r in rows:
        for name, t in r.get("trained", {}).items():
            c, q, loss = r["comparisons"], r["spread_rmse"][name], t["loss"]
            early = c.get(f"{name} vs closure, trained leads")
            text += (
                f"| {r['M']} → {r['N']} | {r['seed']} | {t['protocol']['starts']} starts, "
                f"{H * t['protocol']['lead']:g} s | {ci(c[f'{name} vs closure'])} | "
                f"{ci(early) if early else 'all leads'} | {ci(c[f'{name} vs isotropic'])} | "
                f"{r['factors'][name]:.2f} | {min(q):.2f}–{max(q):.2f} | "
                f"{loss[0]:.4g} → {loss[-1]:.4g} | {r['seconds'][f'training, {name}']:.0f} |\n"
            )
    if cost:
        text += "\nThe fit's time alone (compilation included):\n\n"
        text += _common.markdown_table(cost, ["M", "N", "snapshots", "seconds"], {"seconds": ".3g"})
    return text


def main(argv=None):
    p = _common.parser(__doc__, "a smoke run: M = 16, N = 4, small sizes, one seed")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--sizes", type=int, nargs="+", default=[32], help="the truths' M")
    p.add_argument("--cost", type=int, nargs="*", default=[32, 64], help="M of the cost rows")
    args = p.parse_args(argv)
    results = _common.Output(args.out)
    size = dict(FAST, trainings=FAST_TRAININGS) if args.fast else dict(FULL, trainings=TRAININGS)
    sizes, seeds = ([16], [0]) if args.fast else (args.sizes, args.seeds)
    cost = fit_cost([16] if args.fast else args.cost, size["train"])  # (first: compiles)
    rows = []
    for M in sizes:
        for seed in seeds:
            rows.append(case(M, seed, size))
            print(
                {k: rows[-1][k] for k in ("M", "seed", "seconds", "factors", "comparisons")},
                flush=True,
            )
    results.json("closure", dict(rows=rows, cost=cost))
    results.markdown("closure", summary(rows, cost))


if __name__ == "__main__":
    main()
