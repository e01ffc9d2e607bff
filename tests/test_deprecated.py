"""Old public names keep working for one release, each with a `DeprecationWarning` that names
the new one and points at the caller's line; the new names give the same results."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import slps_jax as sj
from slps_jax.so3 import hat

jax.config.update("jax_enable_x64", True)

RB = sj.RigidBody.paper()
Y0 = jnp.asarray(sj.PAPER_Y0)


def deprecated(call, new):
    """`call()`'s result, checking it warned once, naming `new`, at this file's line."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = call()
    found = [w for w in caught if issubclass(w.category, DeprecationWarning)]
    assert len(found) == 1, [str(w.message) for w in caught]
    assert new in str(found[0].message), str(found[0].message)
    assert found[0].filename == __file__
    return out


def test_old_flow_names_are_the_drift_flow():
    times = np.array([0.3, -1.2])
    new = sj.drift_flow(RB, Y0, times)
    old = np.stack([deprecated(lambda t=t: sj.exact_flow(RB, Y0, t), "drift_flow") for t in times])
    np.testing.assert_array_equal(old, new)
    body = sj.GeneralisedRigidBody([1.0, 2.0, 3.0], c=0.2)
    Y = hat(Y0)
    old = deprecated(lambda: sj.deterministic_flow(body, Y, times), "drift_flow")
    np.testing.assert_array_equal(old, sj.drift_flow(body, Y, times))


# Every public function whose first argument was `model`: called with `model=` and a `y0` it
# refuses before compiling, it warns and then fails on `y0` (not on a missing `system`).
BAD_Y0 = [0.1, 0.2]
CALLS = {
    "integrate": lambda: sj.integrate(model=RB, y0=BAD_Y0, dW=jnp.zeros(4), dt=0.1),
    "simulate": lambda: sj.simulate(model=RB, y0=BAD_Y0, t1=1.0, dt=0.1, n_samples=2, key=KEY),
    "ensemble_statistics": lambda: sj.ensemble_statistics(
        model=RB, y0=BAD_Y0, t1=1.0, dt=0.1, n_samples=2, key=KEY, chunk_size=2
    ),
    "strong_convergence": lambda: sj.strong_convergence(
        model=RB, y0=BAD_Y0, t1=1.0, dts=[0.5, 0.25], n_samples=2, key=KEY, methods=sj.Strang()
    ),
    "weak_convergence": lambda: sj.weak_convergence(
        model=RB,
        y0=BAD_Y0,
        t1=1.0,
        dts=[0.5, 0.25],
        n_samples=2,
        key=KEY,
        methods=sj.Strang(),
        observable=lambda y: y,
    ),
    "drift_flow": lambda: sj.drift_flow(model=RB, y0=BAD_Y0, times=1.0),
    "exact_solution": lambda: sj.exact_solution(model=RB, y0=BAD_Y0, t=1.0, W_t=0.0),
}
KEY = jax.random.key(0)


@pytest.mark.parametrize("name", sorted(CALLS))
def test_model_keyword_is_system(name):
    with pytest.raises((ValueError, TypeError), match="y0") as err:
        deprecated(CALLS[name], "system=")
    assert "required positional argument" not in str(err.value)


def test_model_and_system_together_are_refused():
    with pytest.raises(TypeError, match="model=.*system="):
        sj.default_method(system=RB, model=RB)
    assert isinstance(deprecated(lambda: sj.default_method(model=RB), "system="), sj.Midpoint)


def test_flow_reference_is_the_exact_reference():
    kw = dict(t1=0.5, dts=[0.25, 0.125], n_samples=4, key=KEY, methods=sj.EulerMaruyama())
    system = sj.GeneralisedRigidBody([1.0, 2.0, 3.0], c=0.2)
    Y = hat(0.5 * Y0)
    new = sj.strong_convergence(system, Y, **kw)
    old = deprecated(lambda: sj.strong_convergence(system, Y, reference="flow", **kw), "exact")
    np.testing.assert_array_equal(old.errors["EulerMaruyama"], new.errors["EulerMaruyama"])


def test_calibration_result_model_is_system():
    res = sj.CalibrationResult(RB, np.zeros(1), None, np.ones(4))
    assert deprecated(lambda: res.model, ".system") is RB


@pytest.mark.parametrize("name", ["step_gradient", "step_hamiltonian", "step_gradient_of"])
def test_a_steps_noise_keyword_is_increments(name):
    # `noise` is the system's family of Hamiltonians; a step's increments are `increments`
    system = sj.RigidBody([1.0, 2.0, 3.0], noise=sj.salt_noise(0.3 * np.eye(3)))
    step = sj.BrownianStep(jnp.asarray([0.1, -0.2, 0.05]))
    method = getattr(system, name)
    new = method(Y0, 0.01, increments=step)
    old = deprecated(lambda: method(Y0, 0.01, noise=step), "increments=")
    if name == "step_gradient_of":
        new, old = new(Y0), old(Y0)
    np.testing.assert_array_equal(old, new)
    u = deprecated(lambda: system.noise_gradient(Y0, noise=step), "increments=")
    np.testing.assert_array_equal(u, system.noise_gradient(Y0, step))
