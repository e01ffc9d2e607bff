"""Lévy areas: the sampler, the driver's rules for them, and the API's checks.

Independent references: the exact moments of the Lévy area (characteristic function
`1/cosh(λh/2)`: `E A² = h²/4`, `E A⁴ = 5h⁴/16`; conditionally on the increments the
variance `h²/12 + h(ΔW_q² + ΔW_r²)/12`), Chen's relation written out here in NumPy, and the
linear bookkeeping of a method that records what it is given. The orders are in
`test_levy_order.py`.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax import RESULTS, _brownian
from slps_jax._methods.base import AbstractMethod, StepInfo, StrongOrders

CHI = 0.5 * np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.4, 0.0, 1.0]])
Y0 = jnp.asarray([0.45, -0.5, 0.4])


def salt_body():
    return sj.RigidBody([1.1, 1.7, 2.6], noise=sj.salt_noise(CHI))


@pytest.fixture(scope="module")
def sampled():
    """Areas of 3 noises at h = 2^-4 (p = 1 series term: the tail approximation carries the
    most weight there), 50 000 samples x 4 steps, untruncated."""
    h = 2.0**-4
    dW, A = sj.BrownianMotion(truncate_k=None).increments(
        jax.random.key(0), 4, h, n_samples=50_000, n_noises=3, levy_area=True
    )
    return h, np.asarray(dW).reshape(-1, 3), np.asarray(A).reshape(-1, 3, 3)


def test_areas_are_antisymmetric_with_the_exact_moments(sampled):
    h, dW, A = sampled
    assert np.array_equal(A, -np.swapaxes(A, 1, 2))
    n = A.shape[0]
    for q, r in ((0, 1), (0, 2), (1, 2)):
        a = A[:, q, r]
        for power, exact in ((1, 0.0), (2, h * h / 4), (4, 5 * h**4 / 16)):
            x = a**power
            se = x.std(ddof=1) / math.sqrt(n)
            assert abs(x.mean() - exact) < 4 * se, (q, r, power, x.mean(), exact, se)
    # A Gaussian with the right variance has E A^4 = 3 h^4/16: far outside those bounds.
    x = A[:, 0, 1] ** 4
    assert abs(3 * h**4 / 16 - x.mean()) > 10 * x.std() / math.sqrt(n)


def test_conditional_variance_recovered_by_regression(sampled):
    """E[A_qr^2 | dW] = h^2/12 + h (dW_q^2 + dW_r^2)/12: a sampler that ignores the
    increments fails this."""
    h, dW, A = sampled
    pairs = ((0, 1), (0, 2), (1, 2))  # pooled: 600 000 areas (intercept's std. error ~1%)
    x = np.concatenate(
        [np.stack([np.ones(len(A)), dW[:, q] ** 2 + dW[:, r] ** 2], axis=1) for q, r in pairs]
    )
    coef = np.linalg.lstsq(x, np.concatenate([A[:, q, r] ** 2 for q, r in pairs]), rcond=None)[0]
    np.testing.assert_allclose(coef, [h * h / 12, h / 12], rtol=0.05)


def test_terms_rule():
    # sqrt(s) h / (sqrt(12) pi p) <= h^(3/2), smallest p: the note's 18 and 42 normals for s = 3
    for h, p in ((2.0**-7, 2), (2.0**-8, 3), (2.0**-10, 6)):
        assert _brownian.levy_area_terms(h, 3) == p
        assert math.sqrt(3) * h / (math.sqrt(12) * math.pi * p) <= h**1.5
        assert math.sqrt(3) * h / (math.sqrt(12) * math.pi * (p - 1 or 0.5)) > h**1.5


def test_areas_do_not_depend_on_batch_and_increments_do_not_depend_on_areas():
    key = jax.random.key(3)
    dW5, A5 = sj.BrownianMotion().increments(key, 6, 0.1, n_samples=5, n_noises=3, levy_area=True)
    dW2, A2 = sj.BrownianMotion().increments(key, 9, 0.1, n_samples=2, n_noises=3, levy_area=True)
    np.testing.assert_array_equal(A5[:2], A2[:, :6])
    np.testing.assert_array_equal(dW5[:2], dW2[:, :6])
    plain = sj.BrownianMotion().increments(key, 6, 0.1, n_samples=5, n_noises=3)
    # the same draws; to rounding only, as they come from two compiled programs (with and
    # without the areas), whose fusions may round a product differently (seen: 1 ulp)
    np.testing.assert_allclose(plain, dW5, rtol=4 * np.finfo(plain.dtype).eps, atol=0)
    one = sj.BrownianMotion().increments(key, 6, 0.1, n_noises=3, levy_area=True)
    np.testing.assert_array_equal(one[1], A5[0])


def _chen(dW, A):
    """Chen's relation over consecutive steps, written out: A = sum A_j + 1/2 sum_{i<j}
    (d_i d_j^T - d_j d_i^T)."""
    total = A.sum(0)
    for j in range(len(dW)):
        for i in range(j):
            total = total + 0.5 * (np.outer(dW[i], dW[j]) - np.outer(dW[j], dW[i]))
    return dW.sum(0), total


def test_joined_steps_follow_chen_and_split_steps_give_the_step_back():
    key = jax.random.key(5)
    fine_dW, fine_A = (
        np.asarray(x)
        for x in sj.BrownianMotion().increments(key, 8, 2.0**-6, n_noises=3, levy_area=True)
    )
    sample_key = _brownian.sample_keys(key, 1)[0]
    terms = _brownian.levy_area_terms(2.0**-6, 3)
    for n, m in ((0, 8), (1, 4)):
        got = _brownian.draw_joined(
            sample_key, n, m, jnp.asarray(2.0**-6), jnp.inf, jnp.float64, 3, terms
        )
        want = _chen(fine_dW[n * m : (n + 1) * m], fine_A[n * m : (n + 1) * m])
        np.testing.assert_allclose(got.dW, want[0], rtol=0, atol=1e-15)
        np.testing.assert_allclose(got.area, want[1], rtol=0, atol=1e-15)
    # m equal substeps (dW/m, A/m) joined give the step back (parallel increments)
    step = _brownian.BrownianStep(jnp.asarray(fine_dW[0]), jnp.asarray(fine_A[0]))
    part = _brownian.scale_noise(step, 1 / 4)
    joined = part
    for _ in range(3):
        joined = _brownian.join(joined, part)
    np.testing.assert_allclose(joined.dW, step.dW, atol=1e-16)
    np.testing.assert_allclose(joined.area, step.area, atol=1e-16)


def test_simulate_uses_the_areas_the_driver_s_increments_give():
    """Row i of BrownianMotion().increments(levy_area=True) is what simulate draws for sample i."""
    model = salt_body()
    key = jax.random.key(11)
    sol = sj.simulate(model, Y0, t1=0.5, dt=1 / 16, n_samples=3, key=key, method=sj.Midpoint())
    dW, A = sj.BrownianMotion().increments(key, 8, 1 / 16, n_samples=3, n_noises=3, levy_area=True)
    for i in range(3):
        y = sj.integrate(model, Y0, dW[i], 1 / 16, areas=A[i], method=sj.Midpoint())
        np.testing.assert_allclose(sol.ys[i, -1], y, rtol=0, atol=1e-14)
    # chunked (ensemble_statistics, 2 samples a chunk): the same samples, areas included
    st = sj.ensemble_statistics(
        model,
        Y0,
        t1=0.5,
        dt=1 / 16,
        n_samples=3,
        key=key,
        method=sj.Midpoint(),
        chunks=sj.Chunks(2, progress=False),
    )
    np.testing.assert_allclose(st.mean[-1], np.mean(sol.ys[:, -1], axis=0), rtol=0, atol=1e-14)
    # and without them ("auto" draws them for Midpoint; False does not): a different path
    plain = sj.simulate(
        model,
        Y0,
        t1=0.5,
        dt=1 / 16,
        n_samples=3,
        key=key,
        method=sj.Midpoint(),
        driver=sj.BrownianMotion(levy_area=False),
    )
    y = sj.integrate(model, Y0, dW[0], 1 / 16, method=sj.Midpoint())
    np.testing.assert_allclose(plain.ys[0, -1], y, rtol=0, atol=1e-14)
    assert np.max(np.abs(plain.ys[0, -1] - sol.ys[0, -1])) > 1e-3


def test_one_noise_has_no_areas(paper):
    """With one noise nothing changes: levy_area=True and False give the same paths."""
    model, y0 = paper
    key = jax.random.key(2)

    def run(areas):
        driver = sj.BrownianMotion(levy_area=areas)
        return sj.simulate(
            model, y0, t1=0.25, dt=1 / 32, n_samples=2, key=key, method=sj.Midpoint(), driver=driver
        )

    a, b = run(True), run(False)
    np.testing.assert_array_equal(a.ys, b.ys)
    dW, A = sj.BrownianMotion().increments(key, 8, 1 / 32, n_noises=1, levy_area=True)
    assert A.shape == (8, 1, 1) and not np.any(A)


class _Recorder(AbstractMethod):
    """A 'method' on so(4) that adds its step's (dt, dW_1, dW_2, A_12) to the first four
    coordinates of the state, and fails any step longer than `longest`. (A method is an
    equinox Module whose options are static fields: the driver compiles it in.)"""

    longest: float = eqx.field(default=1.0, static=True)
    strong_orders = StrongOrders(one=None, increments=None, areas=1.0)

    def step(self, model, y, dt, dW):
        alg = model.algebra
        x = jnp.stack([dt, dW.dW[0], dW.dW[1], dW.area[0, 1], 0 * dt, 0 * dt])
        y_next = y + alg.from_coordinates(x.astype(y.dtype))
        ok = dt <= self.longest
        return y_next, StepInfo(
            jnp.where(ok, RESULTS.successful, RESULTS.max_iterations_reached).astype(jnp.int32),
            jnp.zeros((), jnp.int32),
            jnp.zeros((), y.dtype),
        )


def test_a_retried_step_keeps_its_increments_and_areas():
    alg = sj.so(4)
    chi = np.stack([alg.from_coordinates(jnp.eye(6)[i]) for i in (0, 5)])
    model = sj.LiePoissonSystem(
        lambda y, p: 0.5 * alg.norm_sq(y), None, noise=sj.salt_noise(chi), algebra=alg
    )
    dW = jnp.asarray([[0.3, -0.2], [0.1, 0.4]])
    A = jnp.asarray([[[0.0, 0.05], [-0.05, 0.0]], [[0.0, -0.02], [0.02, 0.0]]])
    y0 = jnp.zeros((4, 4))
    # the first attempt of each step (dt = 0.1) fails, its 4 substeps succeed
    y1 = sj.integrate(model, y0, dW, 0.1, areas=A, method=_Recorder(longest=0.05))
    x = np.asarray(alg.coordinates(y1))
    np.testing.assert_allclose(x[:4], [0.2, 0.4, 0.2, 0.03], rtol=1e-14)
    with pytest.raises(RuntimeError, match="could not be solved"):
        sj.integrate(
            model,
            y0,
            dW,
            0.1,
            areas=A,
            method=_Recorder(longest=0.05),
            failures=sj.Failures(retry_substeps=None, throw=True),
        )


def test_levy_area_arguments_are_checked():
    model = salt_body()
    dW, A = sj.BrownianMotion().increments(jax.random.key(0), 4, 0.1, n_noises=3, levy_area=True)
    with pytest.raises(TypeError, match="Heun does not use Lévy areas.*Midpoint"):
        sj.integrate(model, Y0, dW, 0.1, areas=A, method=sj.Heun())
    with pytest.raises(ValueError, match=r"shape \(n_steps, s, s\) = \(4, 3, 3\)"):
        sj.integrate(model, Y0, dW, 0.1, areas=A[:, :2], method=sj.Midpoint())
    with pytest.raises(ValueError, match="antisymmetric"):
        sj.integrate(model, Y0, dW, 0.1, areas=jnp.abs(A), method=sj.Midpoint())
    with pytest.raises(ValueError, match=r"finite; steps \[2\]"):
        sj.integrate(model, Y0, dW, 0.1, areas=A.at[2, 0, 1].set(np.nan), method=sj.Midpoint())
    for method, option, match in [
        (sj.Heun(), True, "levy_area=True: Heun"),
        (sj.Midpoint(), "yes", "'auto', True or False"),
    ]:
        with pytest.raises(TypeError, match=match):
            sj.simulate(
                model,
                Y0,
                t1=0.4,
                dt=0.1,
                n_samples=2,
                key=jax.random.key(0),
                method=method,
                driver=sj.BrownianMotion(levy_area=option),
            )
    with pytest.raises(ValueError, match="needs n_noises"):
        sj.BrownianMotion().increments(jax.random.key(0), 4, 0.1, levy_area=True)


def test_coarsen_is_join_over_blocks():
    dW, A = (
        np.asarray(x)
        for x in sj.BrownianMotion().increments(
            jax.random.key(9), 12, 0.05, n_samples=2, n_noises=3, levy_area=True
        )
    )
    cdW, cA = _brownian.coarsen(jnp.asarray(dW), jnp.asarray(A), 4)
    assert cdW.shape == (2, 3, 3) and cA.shape == (2, 3, 3, 3)
    for i in range(2):
        for n in range(3):
            want = _chen(dW[i, 4 * n : 4 * n + 4], A[i, 4 * n : 4 * n + 4])
            np.testing.assert_allclose(cdW[i, n], want[0], atol=1e-15)
            np.testing.assert_allclose(cA[i, n], want[1], atol=1e-15)
