"""weak_convergence: weak errors on coupled paths, exact weak reference for the paper's case.

Independent references: scipy's adaptive quadrature of the exact expectation (for the
Gauss–Hermite reference), the theorem that symmetric methods have weak order 1, and the
Itô limit of Euler–Maruyama (its weak error does not vanish).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

import slps_jax as sj

Y0 = jnp.asarray(sj.PAPER_Y0)


def observable(y):
    return jnp.concatenate([y, y**2])


@pytest.fixture(scope="module")
def study():
    """500 samples of the paper's setup; the coupled differences' CIs are 2-5% of the
    biases at every step, so the orders are fitted to about +-0.05."""
    return sj.weak_convergence(
        sj.RigidBody.paper(),
        Y0,
        t1=1.0,
        dts=[2.0**-k for k in range(4, 9)],
        n_samples=500,
        key=jax.random.key(0),
        observable=observable,
        methods={
            "LiePoisson": sj.LiePoisson(),
            "Midpoint": sj.Midpoint(),
            "EulerMaruyama": sj.EulerMaruyama(),
        },
        failures=sj.Failures(retry_substeps=4),
    )


def test_gauss_hermite_reference_is_the_exact_expectation(study):
    """E[g(phi_{1 + c z}(y0))], z ~ N(0, 1), by scipy's adaptive quadrature."""
    model = sj.RigidBody.paper()
    flow = jax.jit(lambda t: observable(sj.drift_flow(model, Y0, t)))

    def component(j):
        return quad(
            lambda z: float(flow(1.0 + 0.2 * z)[j]) * math.exp(-z * z / 2) / math.sqrt(2 * math.pi),
            -12,
            12,
            epsabs=1e-13,
            epsrel=1e-12,
            limit=200,
        )[0]

    expected = np.array([component(j) for j in range(6)])
    np.testing.assert_allclose(study.reference_mean, expected, atol=1e-12)
    # the quadrature's own error: its last two rules agree to round-off
    assert np.all(np.asarray(study.reference_error) < 1e-12), study.reference_error


@pytest.mark.parametrize("name", ["LiePoisson", "Midpoint"])
def test_weak_order_one(study, name):
    assert np.all(np.abs(study.bias[name]) > 5 * study.ci[name])  # the fit is meaningful
    assert np.all((0.85 < study.order[name]) & (study.order[name] < 1.3)), study.order[name]


def test_euler_maruyama_weak_error_does_not_vanish(study):
    """EM converges to the Itô equation: its bias levels off (fitted order 0.3)."""
    assert np.all(study.order["EulerMaruyama"] < 0.5)
    assert np.all(np.abs(study.bias["EulerMaruyama"][-1]) > 100 * study.ci["Midpoint"][-1])
    assert "| order |" in study.table()


def test_method_reference_reports_its_own_error():
    """Several noises: a fine Midpoint reference; its own weak error is reported, and the
    mean of the reference paths is the reference mean."""
    chi = 0.4 * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.5, 1.0]])
    model = sj.RigidBody([1.0, 2.0, 3.0], noise=sj.salt_noise(chi))
    result = sj.weak_convergence(
        model,
        [0.6, 0.5, 0.3],
        t1=0.5,
        dts=[2.0**-4, 2.0**-5],
        n_samples=64,
        key=jax.random.key(1),
        observable=model.hamiltonian,
        methods=sj.Midpoint(),
        reference=sj.Reference(sj.Midpoint(), factor=8),
    )
    assert result.bias["Midpoint"].shape == (2, 1)
    assert np.all(np.isfinite(result.reference_error)) and result.reference_error[0] > 0
    assert result.reference_error[0] < np.abs(result.bias["Midpoint"]).max()


def test_bad_input():
    kw = dict(t1=1.0, dts=[0.1, 0.05], n_samples=4, key=jax.random.key(0), methods=sj.Midpoint())
    model = sj.RigidBody.paper()
    with pytest.raises(TypeError, match="observable"):
        sj.weak_convergence(model, Y0, observable=3.0, **kw)
    with pytest.raises(ValueError, match="confidence"):
        sj.weak_convergence(model, Y0, observable=observable, confidence=1.5, **kw)
    with pytest.raises(ValueError, match=r"observable\(y\) must return"):
        sj.weak_convergence(model, Y0, observable=lambda y: jnp.outer(y, y), **kw)
