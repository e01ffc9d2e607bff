"""Robustness: behaviour at the edges, retrying failed steps, bad input, properties, determinism.

References are independent of the code under test: scipy's DOP853 flow (`reference.py`), a
NumPy transcription of the in-map of `docs/scheme.md` solved by `scipy.optimize.root`, and
values known by construction (an injected increment, a fixed point).
"""

import math
import warnings
from unittest import mock

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import exact_sde_solution
from scipy.optimize import root
from scipy.spatial.transform import Rotation
from test_benchmarks import run_script

import slps_jax as sj

PAPER_DIR = np.array([0.7, 0.7, 0.0]) / math.hypot(0.7, 0.7)


def quiet_simulate(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return sj.simulate(*args, **{"method": sj.LiePoisson(), **kwargs})


# --------------------------------------------------------------------------------------
# Failures at the edges: flagged, frozen at the last good state, never NaN.


def test_simulate_failed_samples_frozen_at_last_good_state():
    # c = 1 and |y0| = 0.99: steps with tau < -0.1 have no root on the branch theta < pi/2
    # (the stress matrix: every sample fails within T = 1 at h = 2^-5).
    model = sj.RigidBody.paper()
    model = sj.RigidBody(model.inertia, 1.0)
    y0 = 0.99 * PAPER_DIR
    sol = quiet_simulate(
        model,
        y0,
        t1=0.5,
        dt=2**-5,
        n_samples=16,
        key=jax.random.key(20),
        save_every=1,
        failures=sj.Failures(retry_substeps=None),
    )
    ys, fail = np.asarray(sol.ys), np.asarray(sol.fail_step)
    failed = np.asarray(sol.result) != sj.RESULTS.successful
    assert failed.any() and (fail[failed] >= 0).all() and (fail[~failed] == -1).all()
    assert int(sol.stats["n_failed"]) == failed.sum()
    assert np.isfinite(ys).all()
    for i in np.flatnonzero(failed):
        f = fail[i]  # ys[:, j] is the state after j steps: ys[i, f] is the last good one
        np.testing.assert_array_equal(ys[i, f:], np.broadcast_to(ys[i, f], ys[i, f:].shape))
        np.testing.assert_allclose(np.linalg.norm(ys[i, : f + 1], axis=-1), 0.99, rtol=1e-13)
    # The unflagged samples' paths are close to the exact solution on the same increments.
    dW = np.asarray(sj.BrownianMotion().increments(jax.random.key(20), 16, 2**-5, n_samples=16))
    ok = np.flatnonzero(~failed)
    if ok.size:
        ref = exact_sde_solution(model.inertia, 1.0, y0, dW[ok].sum(1), 0.5)
        assert np.max(np.abs(ys[ok, -1] - ref)) < 0.05


@pytest.mark.parametrize(
    "method,step",
    [(sj.LiePoisson(), 7), (sj.Midpoint(), 7), (sj.EulerMaruyama(), 8)],
    ids=["LiePoisson", "Midpoint", "EulerMaruyama"],
)
def test_failure_at_an_injected_increment(paper, method, step):
    # dW = 1e300 at step 7: the implicit solves fail there; Euler-Maruyama's step is still
    # finite (about 1e299) and overflows at step 8.
    model, y0 = paper
    dW = np.array(sj.BrownianMotion().increments(jax.random.key(21), 12, 0.01))
    dW[7] = 1e300
    ys = np.asarray(
        sj.integrate(
            model, y0, dW, 0.01, method=method, save_every=1, failures=sj.Failures(throw=False)
        )
    )
    assert np.isfinite(ys).all()
    # Frozen from the failing step on at the state after steps 0 .. step-1, which is the
    # path of the first `step` increments.
    np.testing.assert_array_equal(ys[step:], np.broadcast_to(ys[step], ys[step:].shape))
    assert not np.array_equal(ys[step], ys[step - 1])
    with pytest.raises(RuntimeError, match=f"step {step}"):
        sj.integrate(model, y0, dW, 0.01, method=method)


# --------------------------------------------------------------------------------------
# retry_substeps: recovers failed steps, changes nothing else, keeps the order.


def test_the_streaming_example_s_hard_sample_succeeds_with_default_arguments(paper):
    # The streaming example of docs/scaling.md (paper setup, dt = 2^-5, key 0, 10^5 samples):
    # without the retry, sample 42821's second step has no root (a non-finite residual); by
    # default that step is split into substeps and the sample succeeds, with the error of a
    # good sample. (The example itself runs in tests/test_docs_blocks.py; the
    # failure counts with and without the retry are robust_default.py's, at h = 2^-4 in
    # tests/test_benchmarks.py.)
    model, y0 = paper
    key = jax.random.key(0)
    dW = np.asarray(sj.BrownianMotion().increments(key, 32, 2**-5, n_samples=42822)[42821])
    with pytest.raises(RuntimeError, match="step 1 could not be solved"):
        sj.integrate(
            model,
            y0,
            dW,
            2**-5,
            method=sj.LiePoisson(),
            failures=sj.Failures(retry_substeps=None, throw=True),
        )
    y1 = np.asarray(sj.integrate(model, y0, dW, 2**-5, method=sj.LiePoisson()))
    ref = exact_sde_solution(model.inertia, model.c, y0, [dW.sum()], 1.0)[0]
    assert np.linalg.norm(y1 - ref) < 1e-2
    np.testing.assert_allclose(np.linalg.norm(y1), np.linalg.norm(y0), rtol=1e-13)


def test_gradient_through_retried_steps_matches_finite_differences():
    # c = 1, |y0| = 0.99, h = 0.1: 66 of the 240 sample-steps fail at once and are redone as
    # substeps. The retry is differentiable: reverse and forward mode agree with central
    # differences (which do not cross a change of the substeps taken: h = 1e-6).
    inertia = sj.RigidBody.paper().inertia
    y0 = 0.99 * PAPER_DIR
    run = dict(t1=1.0, dt=0.1, n_samples=24, key=jax.random.key(23), method=sj.LiePoisson())
    sol = sj.simulate(sj.RigidBody(inertia, 1.0), y0, **run)
    assert int(sol.stats["n_retried_steps"]) > 30 and int(sol.stats["n_failed"]) == 0

    def f(inertia, c):
        throwing = sj.Failures(throw=True)
        ys = sj.simulate(sj.RigidBody(inertia, c), y0, **run, failures=throwing).ys[:, -1]
        return jnp.mean(ys[:, 0] ** 2 + 0.3 * ys[:, 2])

    g_inertia, g_c = jax.grad(f, argnums=(0, 1))(inertia, 1.0)
    eps, e = 1e-6, np.eye(3)
    fd = [
        (f(inertia + eps * e[i], 1.0) - f(inertia - eps * e[i], 1.0)) / (2 * eps) for i in range(3)
    ]
    np.testing.assert_allclose(g_inertia, fd, rtol=1e-6, atol=1e-9)
    fd_c = (f(inertia, 1.0 + eps) - f(inertia, 1.0 - eps)) / (2 * eps)
    np.testing.assert_allclose(g_c, fd_c, rtol=1e-6)
    np.testing.assert_allclose(jax.jacfwd(f, argnums=1)(inertia, 1.0), fd_c, rtol=1e-6)


def test_simulate_returns_failures_flagged_and_warns():
    # c = 1, |y0| = 0.99, h = 2^-3, no retry: samples fail. simulate returns them flagged
    # and warns (under jit too, through a callback); throw=True raises. (The studies:
    # test_retry_keeps_strong_order_one.)
    model = sj.RigidBody(sj.RigidBody.paper().inertia, 1.0)
    y0 = 0.99 * PAPER_DIR
    run = dict(
        t1=1.0,
        dt=2**-3,
        n_samples=24,
        key=jax.random.key(20),
        method=sj.LiePoisson(),
    )
    no_retry = sj.Failures(retry_substeps=None)
    with pytest.warns(RuntimeWarning, match=r"samples failed.*Solution.ok"):
        sol = sj.simulate(model, y0, **run, failures=no_retry)
    n_failed = int(sol.stats["n_failed"])
    assert 0 < n_failed < 24 and int((~sol.ok).sum()) == n_failed
    with pytest.raises(RuntimeError, match=f"{n_failed} of 24 samples failed"):
        sj.simulate(model, y0, **run, failures=sj.Failures(retry_substeps=None, throw=True))
    with pytest.warns(RuntimeWarning, match=f"{n_failed} of 24 samples failed"):
        jax.block_until_ready(
            jax.jit(lambda m: sj.simulate(m, y0, **run, failures=no_retry).ys)(model)
        )
        jax.effects_barrier()  # (the callback's warning may come after the result)


def test_the_run_store_reports_its_failed_samples(tmp_path):
    # simulate's failing run (c = 1, |y0| = 0.99, h = 2^-3, no retry) written to a store: the
    # same samples fail, flagged in the store's "ok", and the same report says how many
    pytest.importorskip("zarr")
    model = sj.RigidBody(sj.RigidBody.paper().inertia, 1.0)
    y0 = 0.99 * PAPER_DIR
    run = dict(t1=1.0, dt=2**-3, n_samples=24, key=jax.random.key(20), method=sj.LiePoisson())
    no_retry = sj.Failures(retry_substeps=None)
    sol = quiet_simulate(model, y0, **run, failures=no_retry)
    n_failed = int(sol.stats["n_failed"])
    assert n_failed > 0
    store = sj.Store(tmp_path / "run.zarr", progress=False)
    with pytest.warns(RuntimeWarning, match=f'{n_failed} of 24 samples failed.*store\'s "ok"'):
        stored = sj.simulate_to_store(model, y0, store, save_every=8, failures=no_retry, **run)
    np.testing.assert_array_equal(stored.read("ok")[-1], np.asarray(sol.ok))
    raising = sj.Failures(retry_substeps=None, throw=True)
    with pytest.raises(RuntimeError, match=f"{n_failed} of 24 samples failed"):
        sj.simulate_to_store(
            model,
            y0,
            sj.Store(tmp_path / "again.zarr", progress=False),
            save_every=8,
            failures=raising,
            **run,
        )


RETRY_RUN = dict(
    t1=1.0,
    dt=0.1,
    n_samples=24,
    key=jax.random.key(23),  # shared compilations
    method=sj.LiePoisson(),
)


def test_retry_changes_nothing_when_no_step_fails(paper):
    model, _ = paper
    y0 = 0.9 * PAPER_DIR
    a = sj.simulate(model, y0, **RETRY_RUN, failures=sj.Failures(retry_substeps=None))
    b = sj.simulate(model, y0, **RETRY_RUN)  # the default, retry_substeps=4
    np.testing.assert_array_equal(a.ys, b.ys)
    assert int(b.stats["n_retried_steps"]) == 0 and "n_retried_steps" not in a.stats


def test_retry_recovers_failed_samples_accurately():
    model = sj.RigidBody(sj.RigidBody.paper().inertia, 1.0)
    y0 = 0.99 * PAPER_DIR
    plain = quiet_simulate(model, y0, failures=sj.Failures(retry_substeps=None), **RETRY_RUN)
    assert int(plain.stats["n_failed"]) > 12
    # by default: none may fail
    sol = sj.simulate(model, y0, **RETRY_RUN, failures=sj.Failures(throw=True))
    assert int(sol.stats["n_failed"]) == 0 and int(sol.stats["n_retried_steps"]) > 0
    y1 = np.asarray(sol.ys[:, -1])
    np.testing.assert_allclose(np.linalg.norm(y1, axis=-1), 0.99, rtol=1e-13)
    dW = np.asarray(sj.BrownianMotion().increments(RETRY_RUN["key"], 10, 0.1, n_samples=24))
    ref = exact_sde_solution(model.inertia, 1.0, y0, dW.sum(1), 1.0)
    err = np.linalg.norm(y1 - ref, axis=-1)
    # Midpoint's error on the same paths is ~1e-2 at this step; Strang's ~4e-2. LiePoisson's
    # is 6.4e-2: its continuation solves some steps of tau ~ 1 whole, which the retry would
    # otherwise split into substeps.
    assert np.sqrt(np.mean(err**2)) < 0.08 and err.max() < 0.2


def test_retry_keeps_strong_order_one():
    # c = 0.2, |y0| = 0.999: without retry, steps fail at h = 2^-4 and 2^-5. With it, the
    # error keeps order 1 (and the retried samples' errors are no larger than the others').
    model = sj.RigidBody.paper()
    y0 = 0.999 * PAPER_DIR
    kwargs = dict(
        t1=1.0,
        dts=[2.0**-k for k in range(4, 9)],
        n_samples=200,
        key=jax.random.key(24),
        methods={"LP": sj.LiePoisson()},
        n_bootstrap=20,
    )
    # Without the retry, failed samples are left out of every step size, counted, and warned
    # about (never used as data, and the study returns).
    with pytest.warns(RuntimeWarning, match="left out of LP's estimates at every step size"):
        plain = sj.strong_convergence(
            model, y0, **kwargs, failures=sj.Failures(retry_substeps=None)
        )
    assert 0 < plain.n_failed["LP"] < 200 and np.all(np.isfinite(plain.errors["LP"]))
    res = sj.strong_convergence(model, y0, **kwargs, failures=sj.Failures(retry_substeps=2))
    assert res.n_failed == {"LP": 0}
    assert 0.85 < res.order["LP"] < 1.3, res.order
    assert res.errors["LP"][-1] < res.errors["LP"][0] / 10


# --------------------------------------------------------------------------------------
# Bad input: a clear error naming the argument, before anything compiles.


@pytest.fixture
def no_compile():
    """Fail if the driver would start compiling."""

    def boom(*args, **kwargs):
        raise AssertionError("compiled before validating")

    targets = ["ensemble_jit", "path_of_noise", "ensemble_dynamic_jit"]
    patches = [mock.patch(f"slps_jax._driver.integrate.{t}", boom) for t in targets]
    patches.append(mock.patch("slps_jax._studies.convergence.ensemble_dynamic_jit", boom))
    for p in patches:
        p.start()
    yield
    for p in patches:
        p.stop()


KEY = jax.random.key(0)
BAD_SIMULATE = [
    (dict(dt=0.0), ValueError, "dt"),
    (dict(dt=-0.1), ValueError, "dt"),
    (dict(dt=float("nan")), ValueError, "dt"),
    (dict(dt="0.1"), TypeError, "dt"),
    (dict(dt=True), TypeError, "dt"),
    (dict(dt=np.inf), ValueError, "dt"),
    (dict(dt=[0.1, 0.2]), ValueError, "dt"),
    (dict(t1=np.nan), ValueError, "t1"),
    (dict(t1=0.0), ValueError, "t1"),
    (dict(t1=-1.0), ValueError, "t1"),
    (dict(t1=1.0, dt=0.3), ValueError, r"multiple.*dt="),
    (dict(n_samples=-3), ValueError, "n_samples"),
    (dict(n_samples=0), ValueError, "n_samples"),
    (dict(n_samples=2.5), ValueError, "n_samples"),
    (dict(n_samples=True), ValueError, "n_samples"),
    (dict(n_samples=10.0), ValueError, r"n_samples.*int"),
    (dict(save_every=4), ValueError, r"save_every=4 must divide .* 10; the nearest divisors"),
    (dict(save_every=2.0), ValueError, "save_every"),
    (dict(save_every=0), ValueError, "save_every"),
    (dict(save_every=True), ValueError, "save_every"),
    (dict(driver="brownian"), TypeError, "driver must be"),
    (dict(driver=sj.BrownianMotion(levy_area={"LP": True})), TypeError, "a dict chooses"),
    (dict(dt=2.0, t1=4.0), ValueError, "truncate_k=None"),
    (dict(key=3), TypeError, r"jax.random.key\(3\)"),
    (dict(key=np.uint32(3)), TypeError, "jax.random.key"),
    (dict(key=True), TypeError, "jax.random.key"),
    (dict(key=jnp.zeros(2)), TypeError, "PRNG key"),
    (dict(key=jax.random.split(KEY, 3)), ValueError, "single key"),
    (dict(key=jnp.stack([jax.random.PRNGKey(0)] * 2)), ValueError, "single key"),
    (dict(y0=np.zeros((2, 3))), ValueError, r"y0.*\(3,\).*vmap"),
    (dict(y0=[0.1, 0.2]), ValueError, "y0"),
    (dict(y0=[0.1, np.inf, 0.0]), ValueError, "y0"),
    (dict(y0=[0.1, np.nan, 0.0]), ValueError, "y0"),
    (dict(y0=[0.1j, 0.2, 0.0]), TypeError, "y0"),
    (dict(y0="abc"), TypeError, "y0"),
    (dict(y0=[0.6, 0.6, 0.6]), ValueError, r"scale=s"),
    (dict(y0=[0.8, 0.8, 0.0]), ValueError, r"\|y0\|"),
    (dict(method=sj.Midpoint), TypeError, "call it"),
    (dict(method="LiePoisson"), TypeError, "method"),
    (dict(model=(1.0, 2.0, 3.0)), TypeError, "RigidBody"),
    (dict(failures=4), TypeError, r"failures must be a Failures"),
]


BAD_FAILURES = [
    (dict(throw="yes"), TypeError, "throw"),
    (dict(retry_substeps=1), ValueError, "retry_substeps"),
    (dict(retry_substeps=2.0), ValueError, "retry_substeps"),
    (dict(retry_substeps=0), ValueError, "retry_substeps"),
    (dict(retry_substeps=-1), ValueError, "retry_substeps"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_FAILURES)
def test_failures_rejects_bad_options(bad, exc, match):
    with pytest.raises(exc, match=match):
        sj.Failures(**bad)


BAD_REFERENCE = [
    (dict(method=sj.Midpoint(), dt=0.0), ValueError, "dt"),
    (dict(method=sj.Midpoint(), factor=1), ValueError, "factor"),
    (dict(method=sj.Midpoint(), dt=0.01, factor=4), ValueError, "not both"),
    (dict(method="midpoint"), TypeError, "method instance"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_REFERENCE)
def test_reference_rejects_bad_options(bad, exc, match):
    with pytest.raises(exc, match=match):
        sj.Reference(**bad)


BAD_BROWNIAN = [
    (dict(truncate_k=True), ValueError, "truncate_k"),
    (dict(truncate_k=np.inf), ValueError, "truncate_k"),
    (dict(truncate_k=-1), ValueError, "truncate_k"),
    (dict(levy_area="yes"), TypeError, "levy_area"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_BROWNIAN)
def test_brownian_motion_rejects_bad_options(bad, exc, match):
    with pytest.raises(exc, match=match):
        sj.BrownianMotion(**bad)


@pytest.mark.parametrize("bad,exc,match", BAD_SIMULATE)
def test_simulate_rejects_bad_input_before_compiling(paper, no_compile, bad, exc, match):
    model, y0 = paper
    kwargs = dict(model=model, y0=y0, t1=1.0, dt=0.1, n_samples=4, key=KEY, method=sj.LiePoisson())
    kwargs.update(bad)
    with pytest.raises(exc, match=match):
        sj.simulate(kwargs.pop("model"), kwargs.pop("y0"), **kwargs)


BAD_INTEGRATE = [
    (dict(dW=np.zeros((2, 5))), ValueError, r"dW.*vmap"),
    (dict(dW=np.zeros(0)), ValueError, "dW"),
    (dict(dW=np.array([0.1, np.nan, 0.0])), ValueError, r"dW must be finite.*\[1\]"),
    (dict(dW=np.array([1j, 0.0])), TypeError, "dW"),
    (dict(dt=-1.0), ValueError, "dt"),
    (dict(dt=None), TypeError, "dt"),
    (dict(save_every=0), ValueError, "save_every"),
    (dict(save_every=7), ValueError, "nearest divisors"),
    (dict(save_every=3), ValueError, "save_every"),
    (dict(y0=[0.1, 0.2, 0.3, 0.4]), ValueError, "y0"),
    (dict(failures=sj.Failures), TypeError, "failures must be a Failures"),
    (dict(dt=0.0), ValueError, "dt"),
    (dict(method=sj.LiePoisson), TypeError, "call it"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_INTEGRATE)
def test_integrate_rejects_bad_input_before_compiling(paper, no_compile, bad, exc, match):
    model, y0 = paper
    kwargs = dict(y0=y0, dW=np.zeros(10), dt=0.1, method=sj.LiePoisson())
    kwargs.update(bad)
    with pytest.raises(exc, match=match):
        sj.integrate(model, kwargs.pop("y0"), kwargs.pop("dW"), kwargs.pop("dt"), **kwargs)


BAD_CONVERGENCE = [
    (dict(dts=0.1), ValueError, "dts"),
    (dict(dts=[0.1]), ValueError, "dts"),
    (dict(dts=[0.1, np.nan]), ValueError, "dts"),
    (dict(dts=[0.1, 0.1]), ValueError, "distinct"),
    (dict(dts=[[0.1, 0.05]]), ValueError, "dts"),
    (dict(dts=["a", "b"]), TypeError, "dts"),
    (dict(t1=-1.0), ValueError, "t1"),
    (dict(t1=1.0, dts=[0.3, 0.15]), ValueError, "multiple"),
    (dict(n_samples=1), ValueError, "n_samples"),
    (dict(n_bootstrap=0), ValueError, "n_bootstrap"),
    (dict(methods={}), ValueError, "methods"),
    (dict(methods={"LP": sj.LiePoisson}), TypeError, "call it"),
    (dict(reference="scipy"), ValueError, "reference"),
    (dict(key=5), TypeError, "jax.random.key"),
    (dict(failures=None), TypeError, "failures must be a Failures"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_CONVERGENCE)
def test_strong_convergence_rejects_bad_input_before_compiling(paper, no_compile, bad, exc, match):
    model, y0 = paper
    kwargs = dict(t1=1.0, dts=[0.1, 0.05], n_samples=4, key=KEY, methods={"LP": sj.LiePoisson()})
    kwargs.update(bad)
    with pytest.raises(exc, match=match):
        sj.strong_convergence(model, y0, **kwargs)


BAD_INCREMENTS = [
    (dict(n_steps=0), ValueError, "n_steps"),
    (dict(n_steps=2.5), ValueError, "n_steps"),
    (dict(n_steps=True), ValueError, "n_steps"),
    (dict(dt=0.0), ValueError, "dt"),
    (dict(dt=np.inf, truncate_k=None), ValueError, "dt"),
    (dict(dt="x"), TypeError, "dt"),
    (dict(n_samples=0), ValueError, "n_samples"),
    (dict(n_samples=3.0), ValueError, "n_samples"),
    (dict(truncate_k=0), ValueError, "truncate_k"),
    (dict(dt=2.0), ValueError, "truncate_k=None"),
    (dict(dtype=jnp.int32), TypeError, "dtype"),
    (dict(dtype="banana"), TypeError, "dtype"),
    (dict(key=7), TypeError, r"jax.random.key\(7\)"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_INCREMENTS)
def test_brownian_motion_increments_reject_bad_input(bad, exc, match):
    kwargs = dict(key=KEY, n_steps=10, dt=0.1)
    kwargs.update(bad)
    with pytest.raises(exc, match=match):
        driver = sj.BrownianMotion(truncate_k=kwargs.pop("truncate_k", 4))
        driver.increments(kwargs.pop("key"), kwargs.pop("n_steps"), kwargs.pop("dt"), **kwargs)


BAD_FLOW = [
    (dict(y0=np.zeros((4, 3))), ValueError, r"y0.*vmap"),
    (dict(y0=[0.1, np.nan, 0.2]), ValueError, "y0"),
    (dict(times=[0.1, np.inf]), ValueError, "times must be finite"),
    (dict(times="1"), TypeError, "times"),
    (dict(system=object()), TypeError, "RigidBody"),
    (dict(system=sj.GeneralisedRigidBody([1.0, 2.0, 3.0], c=0.2)), ValueError, "y0"),
    (dict(max_step=0.0), ValueError, "max_step"),
]


@pytest.mark.parametrize("bad,exc,match", BAD_FLOW)
def test_drift_flow_rejects_bad_input(paper, bad, exc, match):
    model, y0 = paper
    kwargs = dict(system=model, y0=y0, times=0.5)
    kwargs.update(bad)
    if "max_step" in bad:  # (the Runge–Kutta path's own argument)
        kwargs.update(system=sj.GeneralisedRigidBody([1.0, 2.0, 3.0], c=0.2), y0=np.zeros((3, 3)))
    with pytest.raises(exc, match=match):
        sj.drift_flow(kwargs.pop("system"), kwargs.pop("y0"), kwargs.pop("times"), **kwargs)


def test_drift_flow_without_a_closed_form_needs_concrete_times():
    body = sj.GeneralisedRigidBody([1.0, 2.0, 3.0], c=0.2)
    with pytest.raises(TypeError, match="concrete times"):
        jax.jit(lambda t: sj.drift_flow(body, jnp.zeros((3, 3)), t))(0.5)


@pytest.mark.parametrize(
    "bad,exc,match",
    [
        (dict(W_t=np.zeros(3)), ValueError, r"W_t.*vmap"),
        (dict(W_t=np.nan), ValueError, "W_t"),
        (dict(t=[1.0, 2.0]), ValueError, r"t.*vmap"),
        (
            dict(model=sj.RigidBody([1.0, 2.0, 3.0], noise=sj.salt_noise(np.eye(3)))),
            ValueError,
            "c=",
        ),
        (dict(model=object()), TypeError, "RigidBody"),
    ],
)
def test_exact_solution_rejects_bad_input(paper, bad, exc, match):
    model, y0 = paper
    kwargs = dict(model=model, W_t=0.1, t=1.0)
    kwargs.update(bad)
    with pytest.raises(exc, match=match):
        sj.exact_solution(kwargs["model"], y0, kwargs["t"], kwargs["W_t"])


@pytest.mark.parametrize(
    "inertia,c,exc,match",
    [
        ("abc", 0.2, TypeError, "inertia"),
        ([1.0, 2.0, 3.0j], 0.2, TypeError, "inertia"),
        ([[1.0, 2.0, 3.0]], 0.2, ValueError, "inertia"),
        ([1.0, 2.0, 3.0], "0.2", TypeError, "c"),
        ([1.0, 2.0, 3.0], np.inf, ValueError, "c"),
        ([1.0, 2.0, 3.0], object(), TypeError, "c"),
        ([1.0, 2.0], 0.2, ValueError, "inertia"),
        ([1.0, -2.0, 3.0], 0.2, ValueError, "inertia"),
        ([1.0, np.inf, 3.0], 0.2, ValueError, "inertia"),
        ([1.0, 0.0, 3.0], 0.2, ValueError, "inertia"),
        ([1.0, 2.0, 3.0], np.nan, ValueError, "c"),
        ([1.0, 2.0, 3.0], [0.1, 0.2], ValueError, "c"),
    ],
)
def test_rigid_body_rejects_bad_input(inertia, c, exc, match):
    with pytest.raises(exc, match=match):
        sj.RigidBody(inertia, c)


@pytest.mark.parametrize(
    "ctor,kwargs,exc,match",
    [
        (sj.Midpoint, dict(tol="1e-9"), TypeError, "tol"),
        (sj.Midpoint, dict(tol=-1.0), ValueError, "tol"),
        (sj.Midpoint, dict(max_iter=True), ValueError, "max_iter"),
        (sj.Midpoint, dict(max_iter=2.0), ValueError, "max_iter"),
        (sj.LiePoisson, dict(tol=0.0), ValueError, "tol"),
        (sj.LiePoisson, dict(scale=-2.0), ValueError, "scale"),
        (sj.LiePoisson, dict(scale=np.nan), ValueError, "scale"),
        (sj.LiePoisson, dict(max_iter=0), ValueError, "max_iter"),
        (sj.LiePoisson, dict(max_iter=True), ValueError, "max_iter"),
        (sj.LiePoisson, dict(tol="1e-9"), TypeError, "tol"),
        (sj.LiePoissonSym2, dict(max_iter=np.int64(0)), ValueError, "max_iter"),
    ],
)
def test_method_constructors_reject_bad_options(ctor, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        ctor(**kwargs)


def test_drift_flow_of_the_rigid_body_works_under_jit_and_vmap(paper):
    model, y0 = paper
    ys = jax.jit(jax.vmap(lambda t: sj.drift_flow(model, y0, t)))(jnp.array([0.3, -0.7]))
    from reference import rigid_body_flow

    for t, y in zip((0.3, -0.7), np.asarray(ys)):
        np.testing.assert_allclose(y, rigid_body_flow(model.inertia, y0, t), atol=1e-12)


def test_dtype_policy_model_dtype_wins(paper):
    """float32 y0 + float64 model: promoted (exact); float64 y0 + float32 model: rounded."""
    model, _ = paper
    y0_32 = np.asarray([0.5, 0.4, 0.3], np.float32)
    dW = np.asarray(sj.BrownianMotion().increments(KEY, 8, 0.05))
    kwargs = dict(method=sj.Strang())
    a = sj.integrate(model, y0_32, dW, 0.05, **kwargs)
    b = sj.integrate(model, y0_32.astype(np.float64), dW, 0.05, **kwargs)
    assert a.dtype == jnp.float64
    np.testing.assert_array_equal(a, b)
    model32 = sj.RigidBody(np.asarray(model.inertia, np.float32), np.float32(0.2))
    c = sj.integrate(model32, y0_32.astype(np.float64), dW, 0.05, **kwargs)
    assert c.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(c, np.float64), np.asarray(a), atol=2e-6)


# --------------------------------------------------------------------------------------
# Properties (hypothesis): one jitted fixed-shape function, so examples do not recompile.


def inmap_residual_numpy(a, y, inertia, tau, kappa):
    """The in-map of docs/scheme.md, transcribed to NumPy from the formulas (not from the code)."""

    def vee(m):
        return np.array([m[2, 1], m[0, 2], m[1, 0]])

    def hat(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    def skew(m):
        return 0.5 * (m - m.T)

    v = vee(skew(a))
    w = v / inertia
    sym = 0.5 * (a + a.T)
    g = (sym - np.trace(a) * np.eye(3)) @ w
    big_g = 0.5 * (np.outer(w, w) - w @ w * np.eye(3)) + 0.5 * hat(g / inertia)
    return v + tau * vee(skew(a.T @ hat(w))) - kappa * vee(skew(a.T @ big_g)) - y


def solve_inmap_scipy(y, inertia, tau, kappa):
    """A on the branch theta < pi/2 by scipy, continued in s from the exact root at s = 0."""
    r = np.linalg.norm(y)
    x = y / r * np.arcsin(r)
    for s in np.linspace(0.0, 1.0, 21)[1:]:
        sol = root(
            lambda x: inmap_residual_numpy(
                Rotation.from_rotvec(x).as_matrix(), y, inertia, s * tau, s * s * kappa
            ),
            x,
            tol=1e-15,
        )
        x = sol.x
    a = Rotation.from_rotvec(x).as_matrix()
    return a, np.max(np.abs(inmap_residual_numpy(a, y, inertia, tau, kappa)))


@jax.jit
def lp_step(inertia, c, y, dt, dW):
    return sj.LiePoisson().step(sj.RigidBody(inertia, c), y, dt, dW)


@jax.jit
def all_steps(inertia, c, y, dt, dW):
    model = sj.RigidBody(inertia, c)
    return {
        name: m.step(model, y, dt, dW)
        for name, m in (
            ("Midpoint", sj.Midpoint()),
            ("Strang", sj.Strang()),
            ("Exact", sj.Exact()),
            ("EulerMaruyama", sj.EulerMaruyama()),
        )
    }


inertias = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(
    lambda e: 10.0 ** np.asarray(e)
)  # ratios up to 1e2
directions = (
    st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)
    .filter(lambda v: np.linalg.norm(v) > 0.1)
    .map(lambda v: np.asarray(v) / np.linalg.norm(v))
)
FAST = settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@FAST
@given(
    inertia=inertias,
    direction=directions,
    radius=st.floats(0.05, 0.95),
    c=st.floats(0.0, 1.0),
    h=st.floats(1e-3, 0.1),
    xi=st.floats(-3.0, 3.0),
)
def test_lie_poisson_step_properties(inertia, direction, radius, c, h, xi):
    y = radius * direction
    dW = xi * math.sqrt(h)
    y1, info = lp_step(inertia, c, y, h, dW)
    y1 = np.asarray(y1)
    assert np.isfinite(y1).all()
    if not bool(info.ok):
        return  # flagged: the driver keeps the last good state (tested above)
    # Casimir to round-off and |y| < 1 kept.
    assert abs(np.linalg.norm(y1) - radius) <= 1e-14 * 4
    assert np.linalg.norm(y1) < 1.0
    # y1 = A y with A in SO(3) on the branch theta < pi/2 solving the in-map (scipy).
    tau, kappa = h + c * dW, (c * dW) ** 2
    a, res = solve_inmap_scipy(y, inertia, tau, kappa)
    if res < 1e-12 and np.trace(a) > 1.0:
        np.testing.assert_allclose(y1, a @ y, atol=1e-11)


@FAST
@given(
    inertia=inertias,
    direction=directions,
    radius=st.floats(0.05, 3.0),
    c=st.floats(0.0, 3.0),
    h=st.floats(1e-3, 0.5),
    xi=st.floats(-4.0, 4.0),
)
def test_other_methods_step_properties(inertia, direction, radius, c, h, xi):
    y = radius * direction
    out = all_steps(inertia, c, y, h, xi * math.sqrt(h))
    for name, (y1, info) in out.items():
        y1 = np.asarray(y1)
        assert np.isfinite(y1).all() or not bool(info.ok), name  # finite or flagged
    for name in ("Strang", "Exact"):  # rotations: |y| to round-off
        assert abs(np.linalg.norm(out[name][0]) / radius - 1) < 1e-13, name
    if bool(out["Midpoint"][1].ok):  # |y| up to the Newton tolerance
        assert abs(np.linalg.norm(out["Midpoint"][0]) / radius - 1) < 1e-11


# --------------------------------------------------------------------------------------
# Determinism: jit or not, batch size, chunking of the saves, repeated runs.


def test_same_result_with_and_without_jit(paper):
    model, y0 = paper
    dW = sj.BrownianMotion().increments(jax.random.key(30), 3, 0.05)
    jitted = sj.integrate(model, y0, dW, 0.05, method=sj.Strang())
    step = sj.LiePoisson().step
    lp_jit = jax.jit(step)(model, y0, 0.05, dW[0])[0]
    with jax.disable_jit():
        eager = sj.integrate(model, y0, dW, 0.05, method=sj.Strang())
        lp_eager = step(model, y0, jnp.asarray(0.05), dW[0])[0]
    np.testing.assert_allclose(eager, jitted, rtol=0, atol=1e-15)
    np.testing.assert_allclose(lp_eager, lp_jit, rtol=0, atol=1e-15)


@pytest.mark.parametrize("method", [sj.Midpoint(), sj.Strang()], ids=lambda m: type(m).__name__)
def test_sample_paths_independent_of_batch_and_repeatable(paper, method):
    model, y0 = paper
    kwargs = dict(t1=0.25, dt=2**-5, key=jax.random.key(31), method=method)
    small = sj.simulate(model, y0, n_samples=7, save_every=2, **kwargs)
    again = sj.simulate(model, y0, n_samples=7, save_every=2, **kwargs)
    big = sj.simulate(model, y0, n_samples=300, **kwargs)
    np.testing.assert_array_equal(small.ys, again.ys)
    np.testing.assert_allclose(big.ys[:7, -1], small.ys[:, -1], rtol=0, atol=1e-15)


# --------------------------------------------------------------------------------------
# The stress matrix, fast: one hard corner with every method.


def test_stress_matrix_fast(tmp_path):
    run_script("stress.py", tmp_path)
    import csv
    import json

    rows = list(csv.DictReader(open(tmp_path / "stress.csv")))
    assert {r["method"] for r in rows} == {
        "LiePoisson",
        "LiePoisson+retry4",
        "Midpoint",
        "Strang",
        "EulerMaruyama",
        "Exact",
    }
    for r in rows:
        assert int(r["nonfinite_unflagged"]) == 0 and int(r["nonfinite_flagged"]) == 0
    by = {r["method"]: r for r in rows}
    # Recovery: the retry fixes most of what the plain scheme cannot do at this corner.
    assert int(by["LiePoisson+retry4"]["failed"]) < int(by["LiePoisson"]["failed"])
    assert int(by["LiePoisson+retry4"]["retried_steps"]) > 0
    for name in ("LiePoisson+retry4", "Strang", "Exact"):
        assert float(by[name]["casimir_drift"]) < 1e-13, name
    assert float(by["Exact"]["rms_error_vs_exact"]) < 1e-12
    summary = json.loads((tmp_path / "stress.json").read_text())
    assert summary["nonfinite_total"] == 0
    md = (tmp_path / "stress.md").read_text()
    assert "\\|y0\\|" in md and "LP+retry4 failed" in md
    # Several noises: no NaN/Inf anywhere, every failure with its reason, |y| kept by the
    # Poisson methods.
    noise = {r["method"]: r for r in csv.DictReader(open(tmp_path / "stress_noises.csv"))}
    assert set(noise) == {
        "LiePoisson",
        "LiePoisson+retry4",
        "Midpoint",
        "SaltSplitting",
        "Heun",
        "EulerMaruyama",
    }
    for r in noise.values():
        assert int(r["nonfinite_unflagged"]) == 0 and int(r["nonfinite_flagged"]) == 0
        assert (r["reasons"] == "-") == (int(r["failed"]) == 0), r
    assert int(noise["SaltSplitting"]["failed"]) == 0
    assert float(noise["SaltSplitting"]["casimir_drift"]) < 1e-13
    assert "Several noises" in md
