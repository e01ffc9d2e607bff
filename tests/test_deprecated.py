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


# Every entry point whose `truncate_k=` and `levy_area=` are now its driver's options: called
# with them and an initial state it refuses before compiling, it warns, naming
# `BrownianMotion`, and then fails on the state (not on the keywords).
OLD_DRIVER_KEYWORDS = dict(truncate_k=None, levy_area=False)
DRIVER_CALLS = {
    "simulate": lambda kw: sj.simulate(RB, BAD_Y0, t1=1.0, dt=0.1, n_samples=2, key=KEY, **kw),
    "ensemble_statistics": lambda kw: sj.ensemble_statistics(
        RB, BAD_Y0, t1=1.0, dt=0.1, n_samples=2, key=KEY, chunk_size=2, **kw
    ),
    "simulate_to_store": lambda kw: sj.simulate_to_store(
        RB, BAD_Y0, "unused", t1=1.0, dt=0.1, n_samples=2, key=KEY, save_every=5, **kw
    ),
    "strong_convergence": lambda kw: sj.strong_convergence(
        RB, BAD_Y0, t1=1.0, dts=[0.5, 0.25], n_samples=2, key=KEY, methods=sj.Strang(), **kw
    ),
    "weak_convergence": lambda kw: sj.weak_convergence(
        RB,
        BAD_Y0,
        t1=1.0,
        dts=[0.5, 0.25],
        n_samples=2,
        key=KEY,
        methods=sj.Strang(),
        observable=lambda y: y,
        **kw,
    ),
    "calibrate": lambda kw: sj.calibrate(
        np.zeros((1, 6)), BAD_Y0, ts=[0.5], dt=0.1, n_samples=2, key=KEY, init=RB, **kw
    ),
    "forecast_ensembles": lambda kw: sj.forecast_ensembles(
        RB, np.zeros((2, 2)), lead=2, dt=0.1, every=1, members=2, key=KEY, **kw
    ),
}


@pytest.mark.parametrize("name", sorted(DRIVER_CALLS))
def test_truncate_k_and_levy_area_are_the_drivers_options(name):
    call = DRIVER_CALLS[name]
    with pytest.raises((ValueError, TypeError), match="y0|starts") as err:
        deprecated(lambda: call(OLD_DRIVER_KEYWORDS), "driver=sj.BrownianMotion(truncate_k=None")
    assert "truncate_k" not in str(err.value)
    with pytest.raises(TypeError, match="and driver="):
        call(dict(truncate_k=None, driver=sj.OrnsteinUhlenbeck(1.0)))


def test_old_driver_keywords_give_the_same_paths():
    """The deprecated keywords reach the driver: the same paths, bit for bit, with the Lévy
    areas of three non-commuting noises drawn and the increments untruncated."""
    system = sj.RigidBody([1.0, 2.0, 3.0], noise=sj.salt_noise(0.3 * np.eye(3)))
    kw = dict(t1=0.25, dt=1 / 16, n_samples=3, key=KEY, method=sj.Midpoint())
    new = sj.simulate(system, Y0, driver=sj.BrownianMotion(truncate_k=None, levy_area=True), **kw)
    old = deprecated(lambda: sj.simulate(system, Y0, truncate_k=None, levy_area=True, **kw), "")
    without = sj.simulate(system, Y0, driver=sj.BrownianMotion(levy_area=False), **kw)
    np.testing.assert_array_equal(old.ys, new.ys)
    assert np.max(np.abs(np.asarray(without.ys) - np.asarray(new.ys))) > 1e-8
    dW, A = sj.brownian_increments(KEY, 4, 1 / 16, n_noises=3, levy_area=True)
    areas = sj.integrate(system, Y0, dW, 1 / 16, areas=A, method=sj.Midpoint())
    old = deprecated(
        lambda: sj.integrate(system, Y0, dW, 1 / 16, levy_area=A, method=sj.Midpoint()), "areas="
    )
    np.testing.assert_array_equal(old, areas)


@pytest.mark.parametrize(
    "cls,old,new",
    [
        (sj.LiePoisson, "chart", "chord"),
        (sj.LiePoisson, "newton", "newton"),
        (sj.IsospectralMidpoint, "identity", "fixed_point"),
        (sj.IsospectralMidpoint, "newton", "newton"),
    ],
)
def test_a_methods_jacobian_option_is_its_iteration(cls, old, new):
    # A method is its static options: equal methods (and hashes) are the same compiled step.
    method = deprecated(lambda: cls(jacobian=old), f"iteration={new!r}")
    assert method == cls(iteration=new) and hash(method) == hash(cls(iteration=new))
    assert method.iteration == new and "jacobian" not in repr(method)
    with pytest.raises(TypeError, match="jacobian=.*iteration="):
        cls(jacobian=old, iteration=new)
