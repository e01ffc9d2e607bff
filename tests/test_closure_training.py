"""`train_closure`: its gradient is the loss's finite differences, a known noise amplitude is
recovered from forecasts of the model that has it, the trained closure's system is the one
it was trained as (and saves), the fair CRPS is `crps_ensemble`'s, and bad input is refused
before any work (`docs/data-driven-noise.md`)."""

import jax

jax.config.update("jax_enable_x64", True)

import dataclasses

import jax.numpy as jnp
import numpy as np
import optax
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z
from slps_jax._forecasting import closure_training

M, N = 12, 4
H, EVERY = 0.01, 5
OBSERVE = lambda w: z.mat2shr(w)[..., 4:]  # (degrees 2 and 3)
QUIET = dict(progress=False)


@pytest.fixture(scope="module")
def run():
    """A forced-dissipative su(12) run, 96 snapshots 0.05 s apart after a 5 s spin-up, and
    its closure at su(4)."""
    kw = dict(nu=1e-4, p=2, alpha=0.1, additive=sj.AdditiveForcing((2, 3), 0.5))
    fine = sj.EulerZeitlin(M, **kw)
    rng = np.random.default_rng(0)
    om = np.zeros((1, M * M))
    om[:, 1:25] = 0.3 * rng.normal(size=(1, 24))
    w0 = np.asarray(z.shr2mat(om, M))[0]
    spin = sj.simulate(fine, w0, t1=5.0, dt=H, n_samples=1, key=jax.random.key(0))
    ys = sj.simulate(
        fine, spin.ys.reshape(M, M), t1=4.8, dt=H, n_samples=1, key=jax.random.key(1), save_every=5
    ).ys
    states = np.asarray(ys)[0, 1:]
    fit = sj.fit_closure(
        states, dt=H * EVERY, fine=fine, coarse=sj.EulerZeitlin(N, **kw), n_modes=2
    )
    coarse = np.asarray(z.truncate(states, N))
    return dict(fit=fit, coarse=coarse, states=states)


def _starts(coarse, at, leads):
    """The coarse truth at the starts `at` and at `leads` snapshots after each."""
    return coarse[at], coarse[np.asarray(at)[:, None] + np.arange(1, leads + 1)]


def _problem(run):
    """The training problem of the closure at factor 0.5 on 5 starts, 3 members, 2 leads."""
    fit = run["fit"]
    starts, truth = _starts(run["coarse"], np.arange(0, 60, 12), 2)
    return closure_training._training(
        fit, starts, truth, 10, H, 5, 3, jax.random.key(4), OBSERVE, 0.5, fit.parts
    )


def test_the_gradient_is_the_losss_finite_differences(run):
    """Every part's gradient (pathwise, through the integrator's steps and the damping's
    bound) against central differences of the loss along a random direction."""
    loss, theta, _, _ = _problem(run)
    rng = np.random.default_rng(1)
    theta = {k: jnp.asarray(0.3 * rng.normal(size=v.shape)) for k, v in theta.items()}
    direction = {k: jnp.asarray(rng.normal(size=v.shape)) for k, v in theta.items()}
    value_and_grad = jax.jit(jax.value_and_grad(lambda t: loss(t)[0]))  # (one program)
    value = lambda t: value_and_grad(t)[0]
    grad = value_and_grad(theta)[1]
    along = sum(float(jnp.vdot(grad[k], direction[k])) for k in theta)
    eps = 1e-5
    moved = lambda s: {k: theta[k] + s * eps * direction[k] for k in theta}
    central = (float(value(moved(1.0))) - float(value(moved(-1.0)))) / (2 * eps)
    assert along == pytest.approx(central, rel=1e-5)
    assert all(float(jnp.max(jnp.abs(grad[k]))) > 0 for k in ("transport", "hamiltonian"))


def test_a_known_amplitude_is_recovered_from_the_forecasts_of_its_model(run):
    """Perfect-model twin: the truths are paths of the closure with its transport noise
    times 0.4; training that noise's amplitude from factor 1 on the CRPS (a proper score:
    the truth's law minimises it in expectation) finds 0.4 within sampling error (30
    starts, 6 members)."""
    fine = run["fit"].fine  # (a coarse model without forcing: its noise is all the spread)
    coarse = sj.EulerZeitlin(N, nu=fine.linear.nu, p=2, alpha=0.1)
    fit = sj.fit_closure(
        run["states"],
        dt=H * EVERY,
        fine=fine,
        coarse=coarse,
        n_modes=1,
        parts=("hamiltonian", "transport"),
    )
    starts = run["coarse"][np.arange(0, 90, 3)]
    paths = sj.forecast_ensembles(
        fit.scaled(0.4),
        starts,
        lead=30,
        dt=H,
        every=10,
        members=1,
        key=jax.random.key(7),
        driver=fit.driver,
    )[:, 0]
    trained = sj.train_closure(
        fit,
        starts,
        paths,
        lead=30,
        dt=H,
        every=10,
        members=6,
        key=jax.random.key(8),
        observe=OBSERVE,
        parts=("transport",),
        optimisation=sj.Optimisation(optax.adam(0.15, b1=0.5), steps=15, **QUIET),
    )
    found = trained.transport_scale / fit.transport_scale
    assert trained.training.shape == (16,) and trained.training[-1] < trained.training[0]
    assert trained.parts == fit.parts and trained.coarse is fit.coarse
    # (the sample's optimum, over a grid: 0.37 here; 0.34-0.57 with three other keys)
    assert 0.28 < float(found[0]) < 0.57
    np.testing.assert_array_equal(trained.gain, fit.gain)  # (not trained)


def test_the_trained_closure_is_the_system_it_was_trained_as(run, tmp_path):
    """At random parameters, the `ClosureFit` the training returns builds (`system`, through
    `fit_closure`'s own construction) the system the loss differentiated, leaf for leaf;
    it saves, loads and scores held-out snapshots."""
    fit = run["fit"]
    _, theta, closure, _ = _problem(run)
    rng = np.random.default_rng(2)
    theta = {k: jnp.asarray(rng.normal(size=v.shape)) for k, v in theta.items()}
    theta["damping"] = theta["damping"].at[3].set(-30.0)  # (below the bound: 0)
    trained = closure_training._trained(fit, 0.5, closure, theta)
    traced = closure.system(fit.scaled(0.5), theta)
    built = trained.system
    for a, b in zip(jax.tree_util.tree_leaves(traced), jax.tree_util.tree_leaves(built)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-15)
    assert trained.damping[3] == 0.0 and trained.transport_scale.shape == (2,)
    assert trained.shares is None
    shares = trained.explained(run["states"][:32])
    assert set(shares) == {"hamiltonian", "damping", "closure", "transport", "additive"}
    again = sj.load(sj.save(tmp_path / "trained.pickle", built))
    for a, b in zip(jax.tree_util.tree_leaves(again), jax.tree_util.tree_leaves(built)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_training_loss_is_the_fair_crps_of_crps_ensemble():
    rng = np.random.default_rng(3)
    x, y = rng.normal(size=(4, 7, 3, 5)), rng.normal(size=(4, 3, 5))
    expected = np.mean(sj.crps_ensemble(np.moveaxis(x, 1, 0), y))
    assert float(closure_training.fair_crps(jnp.asarray(x), jnp.asarray(y))) == pytest.approx(
        expected, rel=1e-13
    )


def test_bad_input_is_refused_before_any_work(run):
    fit = run["fit"]
    starts, truth = _starts(run["coarse"], np.arange(0, 60, 12), 2)
    ok = dict(lead=10, dt=H, every=5, members=3, key=jax.random.key(0), observe=OBSERVE)
    only = sj.fit_closure(
        run["states"], dt=H * EVERY, fine=fit.fine, coarse=fit.coarse, parts=("hamiltonian",)
    )
    for args, change, error, match in [
        ((None, starts, truth), {}, TypeError, "must be a ClosureFit"),
        ((only, starts, truth), dict(parts=("transport",)), ValueError, "parts must be some"),
        ((fit, starts, truth), dict(parts="transport"), ValueError, "parts must be some"),
        ((fit, starts, truth), dict(factor=0.0), ValueError, "factor"),
        ((fit, starts, truth), dict(optimisation=optax.adam(0.1)), TypeError, "Optimisation"),
        ((fit, starts, truth), dict(observe=3), TypeError, "observe"),
        ((fit, starts, truth), dict(members=1), ValueError, "members >= 2"),
        ((fit, starts, truth), dict(lead=7), ValueError, "multiple of every"),
        ((fit, starts[:, :3, :3], truth), {}, ValueError, "starts must be"),
        ((fit, starts, truth[:, :1]), {}, ValueError, "truth must be"),
        ((fit, starts, np.full_like(truth, np.nan)), {}, ValueError, "truth must be finite"),
    ]:
        with pytest.raises(error, match=match):
            sj.train_closure(*args, **{**ok, **change})


def test_a_degree_without_any_additive_forcing_has_a_finite_gradient(run):
    """A degree inside the additive band with neither a fitted nor an own amplitude keeps
    amplitude 0 and a finite gradient (the square root's is infinite at 0)."""
    fit = run["fit"]
    fit = dataclasses.replace(
        fit,
        coarse=sj.EulerZeitlin(N, nu=1e-4, p=2, alpha=0.1),
        additive_std=np.array([0.0, 0.1, 0.0, 0.2]),
        additive_time=np.array([0.0, 0.5, 0.0, 0.5]),
    )
    base = fit.scaled(1.0)
    closure = closure_training._closure(fit, 1.0, ("additive",), base)
    theta = {"additive": jnp.zeros(N)}
    amplitude = lambda t: closure.system(base, t).additive.amplitude
    np.testing.assert_allclose(amplitude(theta), base.additive.amplitude, rtol=1e-15)
    assert float(amplitude(theta)[1]) == 0.0  # (degree 2 of the band 1..3)
    grad = jax.grad(lambda t: jnp.sum(amplitude(t)))(theta)["additive"]
    assert np.all(np.isfinite(grad)) and float(grad[2]) == 0.0 and float(grad[3]) > 0
