"""The isospectral midpoint's fixed point at its economy: warm starts, a tolerance relative to
the step, the Cayley rotation that keeps the Casimirs whatever the tolerance, and the
statistics that report it. Euler–Zeitlin at h = 0.64/N s, the benchmarks' smooth state."""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import zeitlin as z
from slps_jax._support.solution import RESULTS


def smooth(N, seed=0):
    """A vorticity of degrees 1 ... 4, coefficients N(0, 1) (the benchmarks' state)."""
    om = np.zeros(25)
    om[1:] = np.random.default_rng(seed).normal(size=24)
    return z.shr2mat(om, N)


def casimir_drift(w0, w1):
    """The largest relative change of tr W^2 ... tr W^6 (the odd ones are imaginary)."""
    w0, w1 = np.asarray(w0, np.complex128), np.asarray(w1, np.complex128)
    out = 0.0
    for k in range(2, 7):
        c0 = np.trace(np.linalg.matrix_power(w0, k))
        c1 = np.trace(np.linalg.matrix_power(w1, k))
        assert abs(c0) > 1e-3 * np.linalg.norm(w0, 2) ** k  # (relative to a real size)
        out = max(out, abs(c1 - c0) / abs(c0))
    return out


def run(N, n_steps, method, *, dtype=jnp.complex128, c=None, n_samples=1, h=None, **kwargs):
    system = sj.EulerZeitlin(N, dtype=dtype, c=c)
    h = 0.64 / N if h is None else h
    return sj.simulate(
        system,
        smooth(N),
        t1=n_steps * h,
        dt=h,
        n_samples=n_samples,
        key=jax.random.key(1),
        method=method,
        newton_stats=True,
        **kwargs,
    )


@pytest.mark.parametrize(
    "dtype, bound",
    [(jnp.complex128, 1e-12), (jnp.complex64, 1e-5)],
)
@pytest.mark.parametrize(
    "n_steps", [1_000, pytest.param(10_000, marks=pytest.mark.full)], ids=["1e3", "1e4"]
)
def test_default_step_keeps_the_casimirs_over_long_runs(dtype, bound, n_steps):
    """N = 64, 10^4 steps of h = 0.005 s (50 s, a turbulent state by then; half the largest
    step, where the fixed point needs half the updates) in the second tier, 10^3 in the
    first: the default step keeps tr W^2 ... tr W^6 to 1e-12 relative in complex128 (the
    Cayley rotation after a solve to sqrt(eps) of the increment) and to 1e-5 in complex64
    (its round-off, 6e-8 a step)."""
    sol = run(64, n_steps, sj.IsospectralMidpoint(), dtype=dtype, h=0.005)
    assert int(sol.stats["n_failed"]) == 0
    assert casimir_drift(smooth(64), sol.ys[0, -1]) < bound


def test_warm_start_takes_at_most_six_updates_at_n_128():
    """N = 128, 16 steps from the smooth state: the default (a warm start extrapolated from
    three earlier increments) takes at most 6 updates per step, where a cold start to the
    same tolerance takes 9 (the contraction is about 0.075 per update here); the two agree
    to the tolerance, and neither hits `max_iter`."""
    warm = run(128, 16, sj.IsospectralMidpoint())
    cold = run(128, 16, sj.IsospectralMidpoint(warm_start=0))
    assert float(warm.stats["newton_iterations_mean"]) <= 6.0
    assert float(cold.stats["newton_iterations_mean"]) >= 8.0
    assert float(warm.stats["max_iter_share"]) == 0.0 == float(cold.stats["max_iter_share"])
    scale = float(jnp.max(jnp.abs(cold.ys[0, -1])))
    assert float(jnp.max(jnp.abs(warm.ys[0, -1] - cold.ys[0, -1]))) < 1e-9 * scale


def test_warm_start_does_not_change_the_root_solved_to_round_off():
    """Solved to round-off (rtol = 0), warm and cold starts find the same root: the final
    states of 24 steps at N = 16 agree to a few ulps, and both agree with quflow's form of
    the step (the explicit update) within its tolerance."""
    warm = run(16, 24, sj.IsospectralMidpoint(rtol=0.0))
    cold = run(16, 24, sj.IsospectralMidpoint(rtol=0.0, warm_start=0))
    np.testing.assert_allclose(warm.ys[0, -1], cold.ys[0, -1], rtol=0, atol=1e-13)


def test_paths_do_not_depend_on_the_loop_layout_or_the_ensemble():
    """With noise proportional to the drift (the increments scaled by the step's time
    h + c dW), sample 1's path is the same bit for bit whether 2 or 3 samples run and
    whether states are saved every 5 steps (another loop layout) or only at the end: the
    warm start is carried per sample over live steps."""
    method = sj.IsospectralMidpoint()
    a = run(16, 40, method, c=0.3, n_samples=2)
    b = run(16, 40, method, c=0.3, n_samples=3, save_every=5)
    np.testing.assert_array_equal(a.ys[1, -1], b.ys[1, -1])
    assert float(a.stats["newton_iterations_mean"]) < float(
        run(16, 40, sj.IsospectralMidpoint(warm_start=0), c=0.3, n_samples=2).stats[
            "newton_iterations_mean"
        ]
    )


def test_max_iter_share_counts_the_steps_that_used_max_iter():
    """A cold start at N = 16 (h = 0.04 s) needs 12 updates, so `max_iter=7` fails every
    step: without retries the first step fails with `max_iterations_reached` and the share
    reported is that one step of 8; with retries every step is redone as 4 substeps (which
    converge in fewer), every step counts, and none fails."""
    method = sj.IsospectralMidpoint(warm_start=0, max_iter=7)
    one = run(16, 8, method, failures=sj.Failures(retry_substeps=None))
    assert int(one.result[0]) == RESULTS.max_iterations_reached and int(one.fail_step[0]) == 0
    assert float(one.stats["max_iter_share"]) == pytest.approx(1 / 8)
    many = run(16, 8, method)
    assert float(many.stats["max_iter_share"]) == 1.0
    assert int(many.stats["n_retried_steps"]) == 8 and int(many.stats["n_failed"]) == 0


def test_a_diverging_iteration_stops_as_stalled():
    """At a step far too large (h = 40 s at N = 16, a contraction factor above 1) the
    corrections grow: the fixed point stops at once with `RESULTS.stalled`, not after 48
    updates, and says why."""
    system = sj.EulerZeitlin(16)
    sol = sj.simulate(
        system,
        smooth(16),
        t1=40.0,
        dt=40.0,
        n_samples=1,
        key=jax.random.key(0),
        method=sj.IsospectralMidpoint(),
        driver=sj.BrownianMotion(truncate_k=None),
        newton_stats=True,
        failures=sj.Failures(retry_substeps=None, throw=False),
    )
    assert int(sol.result[0]) == RESULTS.stalled
    assert int(sol.stats["newton_iterations_max"]) < 10
    assert "stopped decreasing" in RESULTS.message(RESULTS.stalled)


def test_options_are_checked():
    with pytest.raises(ValueError, match="rtol"):
        sj.IsospectralMidpoint(rtol=1.5)
    with pytest.raises(ValueError, match="warm_start"):
        sj.IsospectralMidpoint(warm_start=4)
    with pytest.raises(ValueError, match="warm_start"):
        sj.IsospectralMidpoint(warm_start=True)


def _products(jaxpr):
    """The matrix products (`dot_general`) of a jaxpr, counted through every sub-jaxpr (the
    fixed point's `while_loop`, custom derivative rules) once each."""
    n = 0
    for eqn in jaxpr.eqns:
        n += eqn.primitive.name == "dot_general"
        for param in eqn.params.values():
            for sub in param if isinstance(param, (tuple, list)) else (param,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    n += _products(inner)
    return n


def test_the_area_term_is_one_product_per_step_outside_the_fixed_point():
    # With s transport noises, the Lévy-area term of a step, sum_q [X_q, sum_r A_qr X_r], is
    # one stacked product (s products' work), constant for a linear family: computed once a
    # step, not at every update of the fixed point nor again for the final rotation: the
    # step's program with areas has the products of one evaluation of the area term more
    # than without (a complex product is 3 real ones, `matmul`).
    N, s = 6, 4
    noise = sj.salt_noise(0.05 * z.shr2mat(np.eye(N * N)[1 : s + 1], N))
    system = sj.EulerZeitlin(N, noise=noise)
    y = z.shr2mat(np.eye(N * N)[z.elm2ind(1, 0)] + 0.3 * np.eye(N * N)[z.elm2ind(2, 1)], N)
    a = np.triu(np.arange(1.0, s * s + 1).reshape(s, s), 1) * 1e-3
    step = lambda dW, area: sj.IsospectralMidpoint().step(
        system, y, 0.01, sj.BrownianStep(dW, area) if area is not None else dW
    )
    dW = 0.01 * jnp.arange(1.0, s + 1)
    with_areas = _products(jax.make_jaxpr(step)(dW, jnp.asarray(a - a.T)).jaxpr)
    without = _products(jax.make_jaxpr(lambda d: step(d, None))(dW).jaxpr)
    area = jnp.asarray(a - a.T)
    once = _products(jax.make_jaxpr(lambda ar: system.area_gradient(y, ar))(area).jaxpr)
    assert once >= 2  # (the combination of the noises and their stacked product)
    assert with_areas == without + once
    # and the step is the one whose gradient is computed afresh at every evaluation
    u = system.step_gradient_of(y, 0.01, sj.BrownianStep(dW, jnp.asarray(a - a.T)))
    x = z.shr2mat(np.eye(N * N)[z.elm2ind(3, -2)], N) + y
    ref = system.step_gradient(x, 0.01, sj.BrownianStep(dW, jnp.asarray(a - a.T)))
    np.testing.assert_allclose(u(x), ref, rtol=0, atol=1e-15)
