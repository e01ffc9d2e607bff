"""`calibrate` refuses to fit samples whose Newton solve failed: `simulate` freezes them at
their last good state, and those states must never be used as data. The failures are made on
purpose: without the retry of failing steps (`retry_substeps=None`).

The paper's rigid body from y0 = (0.7, 0.7, 0) at h = 0.25 (coarse, cf. the benchmarks' stress
table): with these 8 samples (key 1) LiePoisson is clean for c <= 0.15 and loses samples from
c ~ 0.18 on (3 of 8 at c = 0.2, all 8 at c = 1). Only c is fitted (one parameter), at ts=[1].

Then the default optimiser, Levenberg-Marquardt, on its own: problems with known minimisers.
"""

import warnings

import jax
import numpy as np
import optax
import pytest

import slps_jax as sj
from slps_jax._studies.calibrate import _levenberg_marquardt

Y0 = (0.7, 0.7, 0.0)
DT, N, TS = 0.25, 8, [1.0]
KEY = 1
INERTIA = sj.RigidBody.paper().inertia
FIXED = ("I_1", "I_2", "I_3")


def simulate(c):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # simulate warns about the failures
        return sj.simulate(
            sj.RigidBody(INERTIA, c),
            Y0,
            t1=TS[-1],
            dt=DT,
            n_samples=N,
            key=jax.random.key(KEY),
            method=sj.LiePoisson(),
            failures=sj.Failures(retry_substeps=None),
        )


def moments(sol):
    """The statistics `calibrate` fits, computed from the same ensemble (shape (1, 6))."""
    return sj.moments(sol.ys[:, -1])[None]


def fit(observed, c0, *, steps, optimizer=None):
    return sj.calibrate(
        sj.ObservedStatistics(observed, TS),
        Y0,
        dt=DT,
        n_samples=N,
        key=jax.random.key(KEY),
        init=sj.RigidBody(INERTIA, c0),
        fixed=FIXED,
        method=sj.LiePoisson(),
        failures=sj.Failures(retry_substeps=None),
        optimisation=sj.Optimisation(optimizer, steps=steps, progress=False),
    )


def test_failed_samples_at_init_are_refused():
    """At c = 1 samples fail from the first steps: `calibrate` raises at init, naming the
    count, instead of fitting the frozen states."""
    sol = simulate(1.0)
    k = int(sol.stats["n_failed"])
    assert k > 0  # the configuration does fail
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # calibrate's error alone, no warning from simulate
        with pytest.raises(RuntimeError, match=rf"{k} of {N} samples failed .*at init.*dt"):
            fit(moments(sol), 1.0, steps=3)


@pytest.mark.parametrize("optimizer", [None, optax.adam(0.3)], ids=["default", "adam"])
def test_failed_samples_during_the_fit_are_refused(optimizer):
    """The start (c = 0.1) simulates cleanly, but the data are the ensemble's own statistics
    at c = 0.5, frozen failures included: a fit that used frozen states would happily land
    there. It must stop at the first accepted iterate where samples fail, with the default
    Levenberg-Marquardt and with an optax optimiser (Adam: every iterate is accepted)."""
    assert int(simulate(0.1).stats["n_failed"]) == 0
    target = simulate(0.5)
    assert int(target.stats["n_failed"]) > 0
    with pytest.raises(
        RuntimeError,
        match=rf"[1-{N}] of {N} samples failed .*after optimiser step \d+, at "
        r"I_1 .*, c ",
    ):
        fit(moments(target), 0.1, steps=10, optimizer=optimizer)


def test_a_second_fit_with_the_same_settings_compiles_nothing():
    """Two fits with the same settings and shapes (other data, another start) share the
    compiled program: the second one traces and compiles nothing."""
    events = []
    counting = [False]

    def listener(name, seconds, **kwargs):
        if counting[0] and ("compile" in name or "trace" in name):
            events.append(name)

    jax.monitoring.register_event_duration_secs_listener(listener)
    first = fit(moments(simulate(0.12)), 0.1, steps=3)
    counting[0] = True
    second = fit(moments(simulate(0.13)), 0.11, steps=3)
    counting[0] = False
    assert events == []
    assert len(first.loss) > 1 and len(second.loss) > 1
    assert abs(float(second.system.c) - 0.13) < abs(0.11 - 0.13)


# --------------------------------------------------------------------------------------
# The default optimiser, Levenberg-Marquardt, on problems with known minimisers (NumPy only).


def _lm(residuals, jacobian, x0, steps=100):
    def evaluate(x):
        return jacobian(x), (residuals(x), 0)

    x0 = np.asarray(x0, float)
    return _levenberg_marquardt(
        evaluate,
        x0,
        jacobian(x0),
        residuals(x0),
        steps=steps,
        rtol=1e-14,
        eps=np.finfo(float).eps,
        accept=lambda *a: None,
        report=lambda *a: None,
    )


def test_levenberg_marquardt_finds_rosenbrocks_minimum():
    """Rosenbrock's function as residuals (10 (x_2 - x_1^2), 1 - x_1): zero at (1, 1) only."""
    x, history, _ = _lm(
        lambda x: np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]]),
        lambda x: np.array([[-20 * x[0], 10.0], [-1.0, 0.0]]),
        [-1.2, 1.0],
    )
    np.testing.assert_allclose(x, [1.0, 1.0], atol=1e-10)
    assert np.all(np.diff(history) < 0) and history[-1] < 1e-20


def test_levenberg_marquardt_matches_scipy_on_a_curve_fit():
    """A nonzero-residual fit, y ≈ a exp(b t) + c to noisy data: the minimiser that
    scipy.optimize.least_squares finds, and the Jacobian at it."""
    scipy_optimize = pytest.importorskip("scipy.optimize")
    t = np.linspace(0.0, 2.0, 25)
    y = 1.5 * np.exp(-1.3 * t) + 0.2 + 0.01 * np.random.default_rng(0).standard_normal(t.size)

    def residuals(p):
        return p[0] * np.exp(p[1] * t) + p[2] - y

    def jacobian(p):
        e = np.exp(p[1] * t)
        return np.stack([e, p[0] * t * e, np.ones_like(t)], axis=1)

    x, history, jac = _lm(residuals, jacobian, [1.0, -0.5, 0.0])
    ref = scipy_optimize.least_squares(
        residuals, [1.0, -0.5, 0.0], jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15
    )
    np.testing.assert_allclose(x, ref.x, rtol=1e-8)
    np.testing.assert_allclose(history[-1], 0.5 * np.sum(ref.fun**2), rtol=1e-12)
    np.testing.assert_allclose(jac, jacobian(x))
