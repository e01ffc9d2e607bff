"""The driver: invariants, determinism, saving, failures (bad input: `test_robustness.py`)."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj

LP = sj.LiePoisson()  # these tests' claims (retry, failures, Newton statistics) are of (42)


# no retry of failing steps: raise (integrate's default), or freeze the path and flag it
RAISE = sj.Failures(retry_substeps=None, throw=True)
FREEZE = sj.Failures(retry_substeps=None)


def test_casimir_preserved_over_ten_thousand_steps(paper):
    model, y0 = paper
    dW = sj.BrownianMotion().increments(jax.random.key(3), 10_000, 0.01)
    ys_lp = sj.integrate(model, y0, dW, 0.01, save_every=100, method=LP)
    ys_em = sj.integrate(model, y0, dW, 0.01, method=sj.EulerMaruyama(), save_every=100)
    r0 = float(jnp.linalg.norm(y0))
    drift_lp = np.abs(np.linalg.norm(ys_lp, axis=-1) / r0 - 1.0)
    drift_em = np.abs(np.linalg.norm(ys_em, axis=-1) / r0 - 1.0)
    assert drift_lp.max() < 1e-13
    # Euler-Maruyama's |y| grows along the same path (its step adds f(y) orthogonal to y).
    assert drift_em[-1] > 1e-2
    assert drift_em[-1] > drift_em[len(drift_em) // 10] > 0


def test_midpoint_preserves_both_quadratic_invariants(paper):
    model, y0 = paper
    dW = sj.BrownianMotion().increments(jax.random.key(4), 2000, 0.01)
    ys = sj.integrate(model, y0, dW, 0.01, method=sj.Midpoint(), save_every=2000)
    np.testing.assert_allclose(model.casimir(ys[-1]), model.casimir(y0), rtol=1e-12)
    np.testing.assert_allclose(model.hamiltonian(ys[-1]), model.hamiltonian(y0), rtol=1e-12)


def test_simulate_matches_integrate_on_the_same_increments(paper):
    model, y0 = paper
    key = jax.random.key(5)
    sol = sj.simulate(model, y0, t1=0.5, dt=0.01, n_samples=4, key=key, save_every=10, method=LP)
    dW = sj.BrownianMotion().increments(key, 50, 0.01, n_samples=4)
    for i in range(4):
        ys = sj.integrate(model, y0, dW[i], 0.01, save_every=10, method=LP)
        np.testing.assert_allclose(sol.ys[i], ys, atol=1e-14)
    assert sol.ys.shape == (4, 6, 3)
    np.testing.assert_allclose(sol.ts, np.arange(6) * 0.1, atol=1e-15)
    np.testing.assert_allclose(sol.ys[:, 0], np.broadcast_to(y0, (4, 3)))
    # Noise as a vector: (n_steps, 1) is the same path; with several noises per step the
    # first component is the one-noise draw.
    dW1 = sj.BrownianMotion().increments(key, 50, 0.01, n_samples=4, n_noises=1)
    assert dW1.shape == (4, 50, 1)
    np.testing.assert_array_equal(dW1[..., 0], dW)
    np.testing.assert_allclose(
        sj.integrate(model, y0, dW1[0], 0.01, method=LP),
        sj.integrate(model, y0, dW[0], 0.01, method=LP),
        atol=0,
    )
    dW3 = sj.BrownianMotion().increments(key, 50, 0.01, n_samples=4, n_noises=3)
    assert dW3.shape == (4, 50, 3)
    np.testing.assert_array_equal(dW3[..., 0], dW)
    with pytest.raises(ValueError, match=r"shape \(n_steps, 1\)"):
        sj.integrate(model, y0, dW3[0], 0.01, method=LP)


def test_final_state_only_by_default(paper):
    model, y0 = paper
    key = jax.random.key(6)
    sol = sj.simulate(model, y0, t1=0.5, dt=0.01, n_samples=3, key=key, method=LP)
    full = sj.simulate(model, y0, t1=0.5, dt=0.01, n_samples=3, key=key, save_every=25, method=LP)
    assert sol.ys.shape == (3, 1, 3) and sol.ts.shape == (1,)
    np.testing.assert_allclose(sol.ys[:, 0], full.ys[:, -1], atol=0)
    assert set(sol.stats) == {"n_failed", "n_retried_steps"}
    assert int(sol.stats["n_failed"]) == 0 and np.all(sol.result == sj.RESULTS.successful)


def test_determinism_and_batch_independence(paper):
    model, y0 = paper
    key = jax.random.key(7)
    a = sj.simulate(model, y0, t1=0.25, dt=2**-6, n_samples=10, key=key, method=LP)
    b = sj.simulate(model, y0, t1=0.25, dt=2**-6, n_samples=10, key=key, method=LP)
    big = sj.simulate(model, y0, t1=0.25, dt=2**-6, n_samples=1000, key=key, method=LP)
    np.testing.assert_array_equal(a.ys, b.ys)
    np.testing.assert_allclose(big.ys[:10], a.ys, atol=1e-15)
    other = sj.simulate(
        model, y0, t1=0.25, dt=2**-6, n_samples=10, key=jax.random.key(8), method=LP
    )
    assert not np.allclose(other.ys, a.ys)


def test_legacy_keys_accepted_and_integers_rejected(paper):
    model, y0 = paper
    a = sj.simulate(model, y0, t1=0.1, dt=0.05, n_samples=2, key=jax.random.PRNGKey(1), method=LP)
    b = sj.simulate(
        model,
        y0,
        t1=0.1,
        dt=0.05,
        n_samples=2,
        key=jax.random.wrap_key_data(jax.random.PRNGKey(1)),
        method=LP,
    )
    np.testing.assert_array_equal(a.ys, b.ys)
    with pytest.raises(TypeError, match="jax.random.key"):
        sj.simulate(model, y0, t1=0.1, dt=0.05, n_samples=2, key=1, method=LP)


def test_newton_stats_only_when_asked(paper):
    model, y0 = paper
    sol = sj.simulate(
        model,
        y0,
        t1=1.0,
        dt=2**-5,
        n_samples=100,
        key=jax.random.key(9),
        newton_stats=True,
        method=LP,
    )
    s = sol.stats
    assert 1 <= float(s["newton_iterations_mean"]) <= int(s["newton_iterations_max"]) <= 12
    assert 0 < float(s["residual_max"]) <= 64 * np.finfo(np.float64).eps


def test_truncation(paper):
    model, _ = paper
    h = 0.01
    dW = sj.BrownianMotion(truncate_k=0.1).increments(jax.random.key(10), 20_000, h)
    bound = np.sqrt(2 * 0.1 * abs(np.log(h)))
    assert np.max(np.abs(dW)) == pytest.approx(np.sqrt(h) * bound, rel=1e-12)
    raw = sj.BrownianMotion(truncate_k=None).increments(jax.random.key(10), 20_000, h)
    np.testing.assert_allclose(
        np.clip(raw, -np.sqrt(h) * bound, np.sqrt(h) * bound), dW, atol=1e-15
    )
    assert abs(np.std(raw) / np.sqrt(h) - 1) < 0.03


def test_failed_sample_is_flagged_frozen_and_does_not_poison_others(paper):
    model, y0 = paper
    y0 = y0 * 0.99
    dW = sj.BrownianMotion().increments(jax.random.key(11), 40, 0.01, n_samples=3)
    dW = dW.at[1, 20].set(400.0)  # tau = 80 at step 20: no root on the branch theta < pi/2
    run = jax.jit(jax.vmap(lambda w: sj.integrate(model, y0, w, 0.01, method=LP, failures=FREEZE)))
    out = np.asarray(run(dW))
    assert np.all(np.isfinite(out))
    for i in (0, 2):
        np.testing.assert_allclose(
            out[i], sj.integrate(model, y0, dW[i], 0.01, method=LP), atol=1e-15
        )
    # Sample 1 keeps its last good state: the state after steps 0..19.
    np.testing.assert_allclose(
        out[1], sj.integrate(model, y0, dW[1, :20], 0.01, method=LP), atol=1e-15
    )
    with pytest.raises(RuntimeError, match="step 20"):
        sj.integrate(model, y0, dW[1], 0.01, method=LP, failures=RAISE)
    # By default that step is redone as 4, 16, 64 substeps: tau/64 = 1.25 has a root.
    y1 = sj.integrate(model, y0, dW[1], 0.01, method=LP)
    np.testing.assert_allclose(np.linalg.norm(y1), np.linalg.norm(y0), rtol=1e-13)


def test_vmapped_integrate_raises_once_for_the_batch(paper):
    # throw=True under jit(vmap(...)) reports through one host callback for the whole batch:
    # jax.debug.callback's own vmap rule would compile one callback per sample.
    model, y0 = paper
    dW = sj.BrownianMotion().increments(jax.random.key(11), 40, 0.01, n_samples=6)
    run = jax.jit(
        jax.vmap(lambda w: sj.integrate(model, y0 * 0.99, w, 0.01, method=LP, failures=RAISE))
    )
    assert run.lower(dW).as_text().count("callback") <= 2  # (the call and its declaration)
    assert np.all(np.isfinite(np.asarray(run(dW))))
    bad = dW.at[1, 20].set(400.0).at[4, 30].set(400.0)
    with pytest.raises(Exception, match=r"step 20 could not be solved \(first failure; 2 of 6"):
        jax.block_until_ready(run(bad))
    nested = jax.jit(
        jax.vmap(
            jax.vmap(lambda w: sj.integrate(model, y0 * 0.99, w, 0.01, method=LP, failures=RAISE))
        )
    )
    with pytest.raises(Exception, match="2 of 6 paths failed"):
        jax.block_until_ready(nested(bad.reshape(2, 3, 40)))


@pytest.mark.parametrize("n", [33, 65, 101, 500])
def test_loop_layout_takes_exactly_n_steps(paper, n):
    # Step counts that are not multiples of the draw block run with padding slots
    # (_integrate._layout); the final state must be that of n plain steps (one save per
    # step: no padding at all), and a failure must be reported at its own step.
    model, y0 = paper
    dW = sj.BrownianMotion().increments(jax.random.key(n), n, 1.0 / n)
    final = sj.integrate(model, y0, dW, 1.0 / n, method=LP)
    every = sj.integrate(model, y0, dW, 1.0 / n, save_every=1, method=LP)
    assert every.shape == (n + 1, 3)
    np.testing.assert_array_equal(final, every[-1])
    with pytest.raises(RuntimeError, match=f"step {n - 1} could not"):
        sj.integrate(
            model,
            y0 * 0.99,
            dW.at[n - 1].set(400.0),
            1.0 / n,
            method=LP,
            failures=sj.Failures(retry_substeps=None, throw=True),
        )


def test_the_step_is_compiled_once_whatever_the_step_count(paper):
    # A main loop plus a remainder loop would put the method's step (LiePoisson's takes
    # seconds to compile) into the program two or three times; the padded layout keeps one.
    model, y0 = paper

    def size(n):
        fn = jax.jit(lambda w: sj.integrate(model, y0, w, 0.01, method=sj.Midpoint()))
        return fn.lower(jnp.zeros(n)).compile().as_text().count(" multiply(")

    sizes = {n: size(n) for n in (32, 64, 65, 101, 1000)}
    assert max(sizes.values()) < 1.2 * min(sizes.values()), sizes


def test_simulate_reports_failures(paper):
    model, y0 = paper
    # Three Newton updates per parameterisation are too few for some steps at this size.
    method = sj.LiePoisson(max_iter=3)
    kwargs = dict(t1=1.0, dt=0.05, n_samples=50, key=jax.random.key(12), method=method)
    with pytest.raises(RuntimeError, match="samples failed"):
        sj.simulate(model, y0, **kwargs, failures=RAISE)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = sj.simulate(model, y0, **kwargs, failures=FREEZE)  # returned, with a warning
    assert any("samples failed" in str(w.message) for w in caught)
    failed = np.asarray(sol.result) != sj.RESULTS.successful
    assert 0 < failed.sum() < 50 and int(sol.stats["n_failed"]) == failed.sum()
    assert np.all(np.isfinite(sol.ys))
    assert np.all(np.asarray(sol.fail_step)[failed] >= 0)
    assert np.all(np.asarray(sol.fail_step)[~failed] == -1)
    good = sj.simulate(model, y0, t1=1.0, dt=0.05, n_samples=50, key=jax.random.key(12), method=LP)
    np.testing.assert_allclose(sol.ys[~failed], good.ys[~failed], atol=1e-14)
    # The reason is kept per sample: with max_iter=3 every attempt runs out of updates.
    codes = set(np.asarray(sol.result)[failed].tolist())
    assert codes == {sj.RESULTS.max_iterations_reached}, codes
    msg = sj.RESULTS.message(sj.RESULTS.max_iterations_reached)
    with pytest.raises(RuntimeError, match=f"{int(failed.sum())} x {msg}"):
        sj.simulate(model, y0, **kwargs, failures=RAISE)
    # Under jit the failures are traced: throw=True raises when the program runs.
    with pytest.raises(Exception, match="samples failed"):
        jax.block_until_ready(
            jax.jit(
                lambda c: (
                    sj.simulate(
                        sj.RigidBody(model.inertia, c),
                        y0,
                        **kwargs,
                        failures=RAISE,
                    ).ys
                )
            )(model.c)
        )


def test_scaling_option_handles_norm_above_one():
    model = sj.RigidBody.paper()
    y0 = jnp.array([1.4, 1.4, 0.0])
    with pytest.raises(ValueError, match="scale"):
        sj.simulate(model, y0, t1=0.1, dt=0.01, n_samples=2, key=jax.random.key(0), method=LP)
    dW = sj.BrownianMotion().increments(jax.random.key(13), 100, 0.01)
    y1 = sj.integrate(model, y0, dW, 0.01, method=sj.LiePoisson(scale=3.0))
    np.testing.assert_allclose(np.linalg.norm(y1), np.linalg.norm(y0), rtol=1e-14)
    # z = y / lambda solves the same SDE with time scaled by lambda.
    z1 = sj.integrate(model, y0 / 3.0, 3.0 * dW, 0.03, method=LP)
    np.testing.assert_allclose(y1, 3.0 * z1, atol=1e-14)


def test_float32(paper):
    model32 = sj.RigidBody(np.asarray(sj.RigidBody.paper().inertia, np.float32), 0.2)
    sol = sj.simulate(
        model32,
        sj.PAPER_Y0,
        t1=1.0,
        dt=2**-5,
        n_samples=64,
        key=jax.random.key(14),
        newton_stats=True,
        method=LP,
    )
    assert sol.ys.dtype == jnp.float32
    r = np.linalg.norm(np.asarray(sol.ys[:, -1], np.float64), axis=-1)
    np.testing.assert_allclose(r, np.linalg.norm(sj.PAPER_Y0), rtol=1e-5)
    assert int(sol.stats["n_failed"]) == 0
    # Same increments in both precisions: float32 stays within its round-off of float64.
    dW = sj.BrownianMotion().increments(jax.random.key(14), 32, 2**-5, n_samples=8)
    y32 = jax.vmap(
        lambda w: sj.integrate(model32, sj.PAPER_Y0, w.astype(jnp.float32), 2**-5, method=LP)
    )(dW)
    y64 = jax.vmap(lambda w: sj.integrate(sj.RigidBody.paper(), sj.PAPER_Y0, w, 2**-5, method=LP))(
        dW
    )
    assert y32.dtype == jnp.float32
    assert np.max(np.abs(np.asarray(y32, np.float64) - y64)) < 1e-5


def test_model_is_a_pytree_and_gradients_reach_it(paper):
    model, y0 = paper
    leaves = jax.tree_util.tree_leaves(model)
    assert len(leaves) == 2
    dW = sj.BrownianMotion().increments(jax.random.key(15), 16, 1 / 16)

    def final_energy(inertia, c):
        m = sj.RigidBody(inertia, c)
        return m.hamiltonian(sj.integrate(m, y0, dW, 1 / 16, method=sj.EulerMaruyama()))

    g = jax.grad(final_energy, argnums=(0, 1))(model.inertia, model.c)
    eps = 1e-6
    fd = (
        final_energy(model.inertia, model.c + eps) - final_energy(model.inertia, model.c - eps)
    ) / (2 * eps)
    np.testing.assert_allclose(g[1], fd, rtol=1e-6)
