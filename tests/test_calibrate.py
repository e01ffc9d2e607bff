"""`calibrate` refuses to fit samples whose Newton solve failed: `simulate` freezes them at
their last good state, and those states must never be used as data. The failures are made on
purpose: without the retry of failing steps (`retry_substeps=None`).

The paper's rigid body from y0 = (0.7, 0.7, 0) at h = 0.25 (coarse, cf. the benchmarks' stress
table): with these 8 samples (key 1) LiePoisson is clean for c <= 0.15 and loses samples from
c ~ 0.18 on (3 of 8 at c = 0.2, all 8 at c = 1). Only c is fitted (one parameter), at ts=[1].
"""

import warnings

import jax
import optax
import pytest

import slps_jax as sj

Y0 = (0.7, 0.7, 0.0)
DT, N, TS = 0.25, 8, [1.0]
KEY = 1
INERTIA = sj.RigidBody.paper().inertia
FIXED = ("I_1", "I_2", "I_3")


def simulate(c):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # simulate warns about the failures
        return sj.simulate(sj.RigidBody(INERTIA, c), Y0, t1=TS[-1], dt=DT, n_samples=N,
                           key=jax.random.key(KEY), retry_substeps=None)


def moments(sol):
    """The statistics `calibrate` fits, computed from the same ensemble (shape (1, 6))."""
    return sj.moments(sol.ys[:, -1])[None]


def fit(observed, c0, **kwargs):
    return sj.calibrate(observed, Y0, ts=TS, dt=DT, n_samples=N, key=jax.random.key(KEY),
                        init=sj.RigidBody(INERTIA, c0), fixed=FIXED, progress=False,
                        retry_substeps=None, **kwargs)


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


def test_failed_samples_during_the_fit_are_refused():
    """The start (c = 0.1) simulates cleanly, but the data are the ensemble's own statistics
    at c = 0.5, frozen failures included: a fit that used frozen states would happily land
    there. It must stop at the first accepted iterate where samples fail."""
    assert int(simulate(0.1).stats["n_failed"]) == 0
    target = simulate(0.5)
    assert int(target.stats["n_failed"]) > 0
    # (Adam: every iterate is accepted, and its program holds the simulation once; L-BFGS's
    # line search holds it three times and compiles 3-4x as long. The check is the same code
    # for every optimiser; the fits with L-BFGS are tested in test_gradients.py.)
    with pytest.raises(RuntimeError,
                       match=rf"[1-{N}] of {N} samples failed .*after optimiser step \d+, at "
                             r"I_1 .*, c "):
        fit(moments(target), 0.1, steps=10, optimizer=optax.adam(0.3))
