"""`fit_closure`: its terms are the closed system's own (against `EulerZeitlin`'s stream and
damping, computed another way), a known closure is recovered from the tendency it makes, a
damping added to a finer truth is recovered from that truth's run, the shares add up, and
the closed system runs, keeps its Casimirs where it should, saves and loads
(`docs/data-driven-noise.md`)."""

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z
from slps_jax._forecasting import closure

M, N = 12, 4


def _states(size, count, degrees, seed=0, scale=1.0):
    """`count` random states of su(`size`) with coefficients on degrees 1..`degrees`."""
    rng = np.random.default_rng(seed)
    om = np.zeros((count, size * size))
    om[:, 1 : (degrees + 1) ** 2] = scale * rng.normal(size=(count, (degrees + 1) ** 2 - 1))
    return np.asarray(z.shr2mat(om, size))


@pytest.fixture(scope="module")
def run():
    """A forced-dissipative su(12) run, 96 snapshots 0.05 s apart after a 5 s spin-up."""
    kw = dict(nu=1e-4, p=2, alpha=0.1, additive=sj.AdditiveForcing((2, 3), 0.5))
    fine = sj.EulerZeitlin(M, **kw)
    w0 = _states(M, 1, 4, scale=0.3)[0]
    spin = sj.simulate(fine, w0, t1=5.0, dt=0.01, n_samples=1, key=jax.random.key(0))
    ys = sj.simulate(
        fine,
        spin.ys.reshape(M, M),
        t1=4.8,
        dt=0.01,
        n_samples=1,
        key=jax.random.key(1),
        save_every=5,
    ).ys
    return dict(kw=kw, states=np.asarray(ys)[0, 1:])


def test_the_closure_terms_are_the_systems_stream_gain_and_damping():
    """Each regressor is the tendency that a unit gain or damping of one degree adds to the
    system (`EulerZeitlin.tendency` with `Stream(gain=)` or `alpha=`, in the eigenbasis;
    the regressors are built from `mat2shr` coefficients), rotation included."""
    w = jnp.asarray(_states(N, 3, N - 1, seed=1))
    for coarse in (sj.EulerZeitlin(N), sj.EulerZeitlin(N, omega=0.7)):
        x = np.asarray(closure._regressors(w, coarse))
        assert x.shape == (3, 2 * (N - 1), N * N - 1)
        base = np.asarray(jax.vmap(coarse.tendency)(w))
        for ell in range(1, N):
            unit = np.eye(N)[ell]
            for k, kw in enumerate([dict(stream=sj.Stream(gain=unit)), dict(alpha=unit)]):
                other = sj.EulerZeitlin(N, omega=coarse.omega, **kw)
                want = np.asarray(z.mat2shr(jax.vmap(other.tendency)(w) - base))[:, 1:]
                got = x[:, k * (N - 1) + ell - 1]
                np.testing.assert_allclose(got, want, atol=1e-12 * np.abs(want).max())


def test_a_known_closure_is_recovered_from_the_tendency_it_makes(monkeypatch):
    """With the missed tendency made by a known gain and damping (the closed system's
    tendency minus the coarse one's), the fit returns them, and its system's tendency is
    the known system's."""
    rng = np.random.default_rng(2)
    g, d = np.r_[0.0, 0.1 * rng.normal(size=N - 1)], np.r_[0.0, rng.uniform(0.2, 1.0, N - 1)]
    known = sj.EulerZeitlin(N, stream=sj.Stream(gain=g), alpha=d)
    coarse = sj.EulerZeitlin(N)

    def missed(w, fine, coarse_):  # (known's tendency, not a finer system's)
        wbar = z.truncate(w, N)
        gap = jax.vmap(known.tendency)(wbar) - jax.vmap(coarse_.tendency)(wbar)
        return wbar, z.mat2shr(gap)[:, 1:]

    monkeypatch.setattr(closure, "missed_tendency", missed)
    states = _states(M, 12, N - 1, seed=3)  # (degrees below N: truncation keeps them)
    fit = sj.fit_closure(
        states, dt=0.1, fine=sj.EulerZeitlin(M), coarse=coarse, parts=("hamiltonian", "damping")
    )
    # (a gain is fixed up to a constant on a sphere at rest: the fit's has
    # sum_l g_l Z_l = 0, Z_l the data's mean enstrophy spectrum)
    Z = np.asarray(z.enstrophy_spectrum(z.truncate(states, N))).mean(axis=0)
    shift = np.sum(g[1:] * Z[1:]) / np.sum(Z[1:])
    np.testing.assert_allclose(fit.gain[1:], g[1:] - shift, atol=1e-10)
    np.testing.assert_allclose(fit.damping, d, atol=1e-10)
    assert fit.shares["closure"] == pytest.approx(1.0, abs=1e-12)
    assert fit.transport is None and not np.any(fit.additive_std)
    w = jnp.asarray(z.truncate(states[0], N))
    np.testing.assert_allclose(fit.system.tendency(w), known.tendency(w), atol=1e-12)


def test_a_damping_added_to_the_finer_truth_is_recovered():
    """A truth with a damping of its own on the degrees below N: the fit's damping grows by
    it (small states, whose missed bracket tendency, quadratic, is negligible beside the
    damping's, linear), and the gain does not move."""
    rng = np.random.default_rng(4)
    extra = np.zeros(M)
    extra[1:N] = rng.uniform(0.5, 2.0, N - 1)
    states = _states(M, 16, 6, seed=5, scale=1e-6)
    parts = ("hamiltonian", "damping")
    coarse = sj.EulerZeitlin(N)
    plain = sj.fit_closure(states, dt=0.1, fine=sj.EulerZeitlin(M), coarse=coarse, parts=parts)
    damped = sj.fit_closure(
        states, dt=0.1, fine=sj.EulerZeitlin(M, alpha=extra), coarse=coarse, parts=parts
    )
    np.testing.assert_allclose(damped.damping[1:], extra[1:N], rtol=1e-3)
    assert np.max(np.abs(plain.damping[1:])) < 1e-3
    np.testing.assert_allclose(damped.gain, plain.gain, atol=1e-3 * np.abs(plain.gain).max())


def test_shares_add_up_and_held_out_data_use_the_fitted_parts(run):
    kw = run["kw"]
    train, test = run["states"][:64], run["states"][64:]
    fit = sj.fit_closure(
        train, dt=0.05, fine=sj.EulerZeitlin(M, **kw), coarse=sj.EulerZeitlin(N, **kw), n_modes=3
    )
    s = fit.shares
    assert set(s) == {"hamiltonian", "damping", "closure", "transport", "additive"}
    # least squares: the joint closure explains at least each part alone, and the closure,
    # the transport (range of ad W) and the additive rest (its complement) are orthogonal
    assert 0 < s["closure"] <= 1 and s["closure"] >= max(s["hamiltonian"], s["damping"]) - 1e-12
    assert 0 < s["transport"] and 0 < s["additive"]
    assert s["closure"] + s["transport"] + s["additive"] <= 1 + 1e-9
    again = fit.explained(train)
    assert all(again[k] == pytest.approx(s[k], rel=1e-9, abs=1e-12) for k in s)
    held = fit.explained(test)
    assert all(np.isfinite(v) for v in held.values()) and held["closure"] < 1
    assert fit.transport.modes.shape == (3, N, N)
    assert np.all(fit.damping >= 0) and fit.damping[0] == 0 and fit.gain[0] == 0
    # (no additive noise on l = 1: both systems keep the angular momentum, R has none)
    assert fit.additive_std[1] == 0
    assert np.all(fit.additive_std[2:] > 0) and np.all(fit.additive_time[2:] >= 0.025)
    # the closed system: the coarse one's terms, the fitted parts added
    system = fit.system
    assert system.additive.band == (2, N - 1) and system.n_noises == 3 + (N * N - 4)
    np.testing.assert_allclose(system.linear.damping(jnp.float64), 0.1 + fit.damping, rtol=1e-12)
    own = np.zeros(N)
    own[2:4] = 0.5
    want = np.sqrt(own**2 + 2 * fit.additive_std**2 * fit.additive_time)[2:]
    np.testing.assert_allclose(system.additive.amplitude, want, rtol=1e-12)


def test_the_closed_system_runs_keeps_its_casimirs_and_saves(run, tmp_path):
    """Without its non-conservative terms (damping, additive noise) the closed system keeps
    every Casimir to 1e-12 in `simulate`; with OU traces it runs with its driver;
    `save`/`load` give the same paths bit for bit."""
    states = run["states"]
    fine = sj.EulerZeitlin(M, **run["kw"])
    for time_model in ("white", "ou"):
        fit = sj.fit_closure(
            states,
            dt=0.05,
            fine=fine,
            coarse=sj.EulerZeitlin(N),
            n_modes=2,
            parts=("hamiltonian", "transport"),
            time_model=time_model,
        )
        assert isinstance(
            fit.driver, sj.OrnsteinUhlenbeck if time_model == "ou" else sj.BrownianMotion
        )
        if time_model == "ou":  # (unit traces: X_r = -scale sigma_r e_r) the noise's mean
            # square tendency at the data's states is the part of R its modes represent
            wbar = np.asarray(z.truncate(states, N))
            chi = np.asarray(fit.system.noise.chi)
            t = chi[None] @ wbar[:, None] - wbar[:, None] @ chi[None]
            noise_ms = np.sum(np.asarray(z.inner(t, t))) / len(states)
            _, r = closure.missed_tendency(jnp.asarray(states), fine, sj.EulerZeitlin(N))
            represented = fit.shares["transport"] * float(np.sum(np.asarray(r) ** 2))
            assert noise_ms == pytest.approx(represented / len(states), rel=1e-9)
            assert 0 < fit.transport_scale < 1
        w0 = jnp.asarray(z.truncate(states[0], N))
        sol = sj.simulate(
            fit.system,
            w0,
            t1=1.0,
            dt=0.01,
            n_samples=3,
            key=jax.random.key(2),
            driver=fit.driver,
        )
        c0 = np.asarray(fit.system.algebra.casimirs(w0))[: N - 1]
        c1 = np.asarray(fit.system.algebra.casimirs(sol.ys))[..., : N - 1]
        assert np.max(np.abs(c1 - c0) / np.abs(c0)) < 1e-12
    path = sj.save(tmp_path / "closed.pickle", fit.system)
    again = sj.load(path)
    go = lambda s: (
        sj.simulate(
            s, w0, t1=0.2, dt=0.01, n_samples=2, key=jax.random.key(3), driver=fit.driver
        ).ys
    )
    np.testing.assert_array_equal(go(again), go(fit.system))


def test_bad_input_is_refused_before_any_work(run):
    states = run["states"][:16]
    fine, coarse = sj.EulerZeitlin(M), sj.EulerZeitlin(N)
    ok = dict(dt=0.05, fine=fine, coarse=coarse)
    for change, error, match in [
        (dict(fine=None), TypeError, "must be EulerZeitlin"),
        (dict(coarse=sj.EulerZeitlin(M)), ValueError, "must be below"),
        (dict(dt=-1.0), ValueError, "dt"),
        (dict(parts=("hamiltonian", "noise")), ValueError, "parts must be"),
        (dict(parts="hamiltonian"), ValueError, "parts must be"),
        (dict(parts=()), ValueError, "parts must be"),
        (dict(time_model="red"), ValueError, "time_model"),
        (dict(variance=1.5), ValueError, "variance"),
        (dict(n_modes=400), ValueError, "n_modes"),
        (dict(regularization="gcv"), ValueError, "regularization"),
        (dict(time_model="ou", parts=("hamiltonian",)), ValueError, "needs the 'transport'"),
        (
            dict(
                time_model="ou", coarse=sj.EulerZeitlin(N, additive=sj.AdditiveForcing((1, 2), 1.0))
            ),
            ValueError,
            "time_model='ou'",
        ),
    ]:
        with pytest.raises(error, match=match):
            sj.fit_closure(states, **{**ok, **change})
    bad = states.copy()
    bad[3, 0, 0] = np.nan
    for data, match in [
        (bad, "snapshots \\[3\\]"),
        (states[:5], "at least 8"),
        (states.real, "complex"),
        (states[:, :4, :4], "complex"),
    ]:
        with pytest.raises(ValueError, match=match):
            sj.fit_closure(data, **ok)


def test_scaled_closure_and_a_tuning_that_scales_both_noises(run):
    kw = run["kw"]
    fit = sj.fit_closure(
        run["states"],
        dt=0.05,
        fine=sj.EulerZeitlin(M, **kw),
        coarse=sj.EulerZeitlin(N, **kw),
        n_modes=2,
    )
    same = fit.scaled(1.0)
    for a, b in zip(jax.tree_util.tree_leaves(same), jax.tree_util.tree_leaves(fit.system)):
        np.testing.assert_array_equal(a, b)
    half = fit.scaled(0.5)
    np.testing.assert_allclose(half.noise.chi, 0.5 * np.asarray(fit.system.noise.chi), rtol=1e-15)
    own = np.zeros(N)
    own[2:4] = 0.5
    fitted = 2 * fit.additive_std**2 * fit.additive_time
    np.testing.assert_allclose(
        half.additive.amplitude, np.sqrt(own**2 + 0.25 * fitted)[2:], rtol=1e-12
    )
    # a search's `scale`: the default's own scaling given explicitly tunes the same
    starts = np.asarray(z.truncate(run["states"][[0, 40]], N))
    truth = np.asarray(z.truncate(run["states"][[2, 4, 42, 44]], N)).reshape(2, 2, N, N)
    common = dict(
        observe=lambda w: z.mat2shr(w)[..., 4:],
        lead=20,
        dt=0.01,
        every=10,
        members=3,
        key=jax.random.key(5),
    )
    factors = (0.5, 1.0, 2.0)
    system = fit.system
    default = sj.tune_amplitude(
        system, starts, truth, search=sj.AmplitudeSearch(factors, refine=False), **common
    )
    explicit = sj.tune_amplitude(
        system,
        starts,
        truth,
        **common,
        search=sj.AmplitudeSearch(
            factors,
            refine=False,
            scale=lambda s, f: eqx.tree_at(lambda s: s.noise, s, sj.scaled_noise(s.noise, f)),
        ),
    )
    np.testing.assert_array_equal(default.crps, explicit.crps)
    both = sj.tune_amplitude(
        system,
        starts,
        truth,
        **common,
        search=sj.AmplitudeSearch(factors, refine=False, scale=lambda s, f: fit.scaled(f)),
    )
    assert both.factor in factors and not np.array_equal(both.crps, default.crps)
    with pytest.raises(TypeError, match="scale must be a function"):
        sj.AmplitudeSearch(scale=0.5)
