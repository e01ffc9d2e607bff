"""The verification functions: a start's forecasts do not depend on the other starts; tuning
one amplitude factor recovers the factor of data drawn from the model itself."""

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z


@pytest.fixture(scope="module")
def model_world():
    """su(6) with two known transport noises; 6 starts; the truth of each start is one more
    draw of the model itself (another key)."""
    N, h, lead, every = 6, 0.05, 20, 10
    xi = np.stack(
        [
            0.4 * z.shr2mat(np.eye(36)[z.elm2ind(2, 1)], N),
            0.3 * z.shr2mat(np.eye(36)[z.elm2ind(3, -2)], N),
        ]
    )
    noise = sj.salt_noise(-xi)
    rng = np.random.default_rng(1)
    starts = z.shr2mat(np.concatenate([np.zeros((6, 1)), rng.normal(size=(6, 15)) / 2], 1), N)
    truth = sj.forecast_ensembles(
        sj.EulerZeitlin(N, noise=noise),
        starts,
        lead=lead,
        dt=h,
        every=every,
        members=1,
        key=jax.random.key(7),
    )[:, 0]
    return dict(N=N, h=h, lead=lead, every=every, noise=noise, starts=starts, truth=truth)


def test_forecast_ensembles_are_simulate_per_start(model_world):
    """One batched program gives what `simulate` gives for each start with `fold_in(key, s)`
    (increments and Lévy areas alike), Brownian or Ornstein–Uhlenbeck; a start's ensemble
    does not depend on the other starts; a failing member raises."""
    w = model_world
    system = sj.EulerZeitlin(w["N"], noise=w["noise"])
    kw = dict(lead=w["lead"], dt=w["h"], every=w["every"], members=3, key=jax.random.key(2))
    for driver in (sj.BrownianMotion(), sj.OrnsteinUhlenbeck([0.3, 0.6])):
        both = sj.forecast_ensembles(system, w["starts"][:2], driver=driver, **kw)
        assert both.shape == (2, 3, 2, w["N"], w["N"])
        for s in range(2):
            sol = sj.simulate(
                system,
                w["starts"][s],
                t1=w["lead"] * w["h"],
                dt=w["h"],
                n_samples=3,
                key=jax.random.fold_in(kw["key"], s),
                save_every=w["every"],
                driver=driver,
            )
            np.testing.assert_allclose(both[s], sol.ys[:, 1:], rtol=0, atol=1e-13)
    one = sj.forecast_ensembles(
        system, w["starts"][1:2], **(kw | dict(key=jax.random.fold_in(kw["key"], 1)))
    )
    assert one.shape == (1, 3, 2, w["N"], w["N"])
    with pytest.raises(ValueError, match="multiple"):
        sj.forecast_ensembles(system, w["starts"], **(kw | dict(every=3)))
    with pytest.raises(ValueError, match="starts must be"):
        sj.forecast_ensembles(system, w["starts"][0], **kw)
    loud = sj.EulerZeitlin(w["N"], noise=sj.scaled_noise(w["noise"], 1e3))
    with pytest.raises(RuntimeError):
        sj.forecast_ensembles(
            loud, w["starts"][:1], **kw, failures=sj.Failures(retry_substeps=None)
        )


def test_tuning_recovers_the_amplitude_of_data_from_the_model(model_world):
    """The truth is drawn from the model with factor 1: among 1/4 ... 4 the fair CRPS picks
    a factor within a factor 2 of 1, and the extremes score worse."""
    w = model_world
    tuned = sj.tune_amplitude(
        sj.EulerZeitlin(w["N"], noise=w["noise"]),
        w["starts"],
        w["truth"],
        observe=lambda s: z.mat2shr(s)[..., 1:],
        lead=w["lead"],
        dt=w["h"],
        every=w["every"],
        members=16,
        key=jax.random.key(3),
        search=sj.AmplitudeSearch(factors=[0.25, 0.5, 1.0, 2.0, 4.0]),
    )
    assert 0.5 <= tuned.factor <= 2.0, tuned
    assert tuned.crps[0] > tuned.crps.min() and tuned.crps[-1] > tuned.crps.min()
    with pytest.raises(ValueError, match="factors"):
        sj.tune_amplitude(
            sj.EulerZeitlin(w["N"], noise=w["noise"]),
            w["starts"],
            w["truth"],
            observe=lambda s: s,
            lead=w["lead"],
            dt=w["h"],
            every=w["every"],
            members=2,
            key=jax.random.key(3),
            search=sj.AmplitudeSearch(factors=[1.0]),
        )
    with pytest.raises(ValueError, match="no noise amplitudes"):
        sj.tune_amplitude(
            sj.EulerZeitlin(w["N"]),
            w["starts"],
            w["truth"],
            observe=lambda s: s,
            lead=w["lead"],
            dt=w["h"],
            every=w["every"],
            members=2,
            key=jax.random.key(3),
        )


def test_model_error_variance_recovers_a_shared_error():
    """Members and truth each spread with variance 1 about a centre, the members also
    sharing an error of variance 0.3 per start (the model's): the estimate is 0.3 within
    its standard error, not 0 or the raw excess; without the shared error (members and
    truth exchangeable: a calibrated ensemble) it is 0 within its standard error."""
    rng = np.random.default_rng(0)
    n, m, T, k = 4000, 5, 2, 3
    centre = rng.normal(size=(n, T, k))
    truth = centre + rng.normal(size=(n, T, k))
    spread = rng.normal(size=(n, m, T, k))
    shared = np.sqrt(0.3) * rng.normal(size=(n, 1, T, k))
    est = sj.model_error_variance(centre[:, None] + shared + spread, truth, lambda x: x)
    assert est.variance.shape == est.stderr.shape == (T, k)
    assert np.all(np.abs(est.variance - 0.3) < 4 * est.stderr) and np.all(est.stderr < 0.05)
    np.testing.assert_allclose(est.spread, 1.0, atol=0.06)
    est = sj.model_error_variance(centre[:, None] + spread, truth, lambda x: x)
    assert np.all(np.abs(est.variance) < 4 * est.stderr), est
    with pytest.raises(ValueError, match="2 or more"):
        sj.model_error_variance(spread[:, :1], truth, lambda x: x)
